# Shared set-up of the tools/gpu_*.sh checks on a lent GPU, sourced with G = the GPU kit's
# folder (../shared/gpu/prepare.sh .gpu; ../shared/gpu/README.md): unpacks the kit's
# Vulkan loader and layers, points the loader at the NVIDIA ICD, unpacks our release
# binary at this checkout's own path unless it is there, and sets B to it; the examples
# of tools/gpu_prepare.sh likewise (SVRASTER_PREBUILT_EXAMPLES for tests/viewer.rs). `kit_lego`
# copies the kit's lego subset to /tmp/lego (once).
for f in "$G"/debs/*.deb; do dpkg -x "$f" /; done; ldconfig
ICD=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
[ -f $ICD ] && export VK_DRIVER_FILES=$ICD
[ -x "$(cat "$G/project_path")/target/release/svraster" ] || tar xJf "$G/ours.tar.xz" -C /
B=$(cat "$G/project_path")/target/release/svraster
# The examples the suite runs (tools/gpu_prepare.sh): no cargo on that machine.
if [ -f "$G/examples.tar.xz" ]; then
  [ -x "$(cat "$G/project_path")/target/release/examples/embed" ] || tar xJf "$G/examples.tar.xz" -C /
  export SVRASTER_PREBUILT_EXAMPLES=1
fi
kit_lego() {
  [ -d /tmp/lego ] || { mkdir -p /tmp/lego && cp -r "$G/lego/." /tmp/lego/; }
}
