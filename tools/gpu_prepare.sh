#!/usr/bin/env bash
# Prepares a GPU check: the shared kit (../shared/gpu/prepare.sh DEST: release and test
# binaries, Vulkan loader and layers, lego subset, SVRaster), plus what our tests need
# there that the kit does not pack: the examples the suite runs (`embed`, the host
# embedding; `viewer`, skipped there without xvfb-run), built as tests/viewer.rs builds
# them and stripped, at this checkout's own path → DEST/examples.tar.xz. tools/gpu_kit.sh
# unpacks it and sets SVRASTER_PREBUILT_EXAMPLES, so those tests run without cargo.
# usage, from the checkout: tools/gpu_prepare.sh .gpu   (then carry .gpu; see gpu_check.sh)
set -euo pipefail
DEST=${1:?usage: tools/gpu_prepare.sh DEST}
ROOT=$(git rev-parse --show-toplevel)
cd "$ROOT"
bash "$ROOT/../shared/gpu/prepare.sh" "$DEST"
DEST=$(cd "$DEST" && pwd)
cargo build --release --locked -q --workspace --features svraster-vk/viewer --example embed --example viewer
T=$(mktemp -d); R=$T$ROOT/target/release/examples; mkdir -p "$R"
for e in embed viewer; do strip -o "$R/$e" "$ROOT/target/release/examples/$e"; done
(cd "$T" && tar cJf "$DEST/examples.tar.xz" .); rm -rf "$T"
mkdir -p .git/info; grep -qx '/.gpu/' .git/info/exclude || echo /.gpu/ >> .git/info/exclude
echo "gpu_prepare: examples → $DEST/examples.tar.xz ($(du -h "$DEST/examples.tar.xz" | cut -f1)); $(du -sh "$DEST" | cut -f1) in $DEST"
