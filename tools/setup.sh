#!/usr/bin/env bash
# Installs what svraster-vk needs on Debian bookworm (idempotent; run as root or with sudo).
#  - libvulkan1 + mesa-vulkan-drivers: the Vulkan loader and lavapipe (CPU Vulkan)
#  - vulkan-validationlayers: the Khronos validation layer the tests run under
#  - libshaderc-dev glslang-dev spirv-tools: shaderc and the static glslang/SPIRV-Tools
#    archives build.rs links (see .cargo/config.toml)
#  - vulkan-tools: vulkaninfo, handy for diagnosing a driver
set -euo pipefail
PKGS=(mesa-vulkan-drivers libvulkan1 libvulkan-dev libshaderc-dev glslang-dev spirv-tools
      vulkan-validationlayers vulkan-tools g++ pkg-config)
missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all packages present"
  exit 0
fi
SUDO=""
[ "$(id -u)" -ne 0 ] && SUDO="sudo"
echo "setup: installing ${missing[*]}"
$SUDO apt-get update -q
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
