#!/usr/bin/env bash
# Installs what svraster-vk needs on Debian bookworm (idempotent; run as root or with sudo).
#  - mesa-vulkan-drivers 25.x from bookworm-backports: lavapipe (CPU Vulkan). It runs our
#    training kernels ~7x faster than bookworm's stock 22.3 (README, "Drivers"). The
#    backports entry is added to /etc/apt/sources.list.d when missing. MESA=stock keeps
#    bookworm's 22.3 (the suite passes on both).
#  - libvulkan1: the Vulkan loader
#  - vulkan-validationlayers: the Khronos validation layer the tests run under
#  - libshaderc-dev glslang-dev spirv-tools: shaderc and the static glslang/SPIRV-Tools
#    archives build.rs links (see .cargo/config.toml)
#  - vulkan-tools: vulkaninfo, handy for diagnosing a driver
#  - python3-numpy: tools/ply_read.py, the independent PLY reader the mesh tests check
#    our PLY output with; python3 alone: tools/svraster_checkpoint.py, which writes the
#    SVRaster checkpoints the import tests read
#  - ffmpeg: `render --path … --out X.mp4` encodes with it (and ffprobe reads the video
#    back in cli/tests/cli/features.rs)
#  - xvfb xauth and the X11 client libraries winit opens at run time (libx11-6 libx11-xcb1
#    libxcursor1 libxrandr2 libxi6 libxkbcommon-x11-0): svraster view and examples/viewer.rs run under a
#    virtual X server in tests/viewer.rs
set -euo pipefail
MESA=${MESA:-backports}
PKGS=(mesa-vulkan-drivers libvulkan1 libvulkan-dev libshaderc-dev glslang-dev spirv-tools
      vulkan-validationlayers vulkan-tools g++ pkg-config python3 python3-numpy ffmpeg
      xvfb xauth libx11-6 libx11-xcb1 libxcursor1 libxrandr2 libxi6 libxkbcommon-x11-0)
SUDO=""
[ "$(id -u)" -ne 0 ] && SUDO="sudo"
missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
mesa_version() { dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true; }
want_backports=0
if [ "$MESA" = backports ]; then
  case "$(mesa_version)" in
    2[5-9].*|[3-9][0-9].*) ;;  # already 25 or newer
    *) want_backports=1 ;;
  esac
fi
if [ ${#missing[@]} -eq 0 ] && [ $want_backports -eq 0 ]; then
  echo "setup: all packages present (mesa-vulkan-drivers $(mesa_version))"
  exit 0
fi
if [ $want_backports -eq 1 ]; then
  . /etc/os-release
  if [ "${VERSION_CODENAME:-}" != bookworm ]; then
    echo "setup: not Debian bookworm (${VERSION_CODENAME:-unknown}): using the distribution's Mesa" >&2
    want_backports=0
  elif ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
    echo "setup: adding the bookworm-backports apt source"
    printf '%s\n' "Types: deb" "URIs: http://deb.debian.org/debian" "Suites: bookworm-backports" \
      "Components: main" "Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg" |
      $SUDO tee /etc/apt/sources.list.d/bookworm-backports.sources >/dev/null
  fi
fi
$SUDO apt-get update -q
if [ ${#missing[@]} -gt 0 ]; then
  echo "setup: installing ${missing[*]}"
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
fi
if [ $want_backports -eq 1 ]; then
  echo "setup: installing mesa-vulkan-drivers from bookworm-backports"
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends \
    -t bookworm-backports mesa-vulkan-drivers
fi
echo "setup: mesa-vulkan-drivers $(mesa_version)"
