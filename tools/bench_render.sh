#!/usr/bin/env bash
# Forward-rendering benchmark on the demo scene: voxelized at level 7 (~6.6e4 voxels)
# and level 9 (~1.1e6 voxels), rendered at 200² and 400² (test-split cameras).
# Appends one JSON line per configuration to bench_render.jsonl and prints a table.
# SEGMENTS=N sets the entries per segment of the composite (0: off; default: the
# device's).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet
BIN=target/release/svraster
WORK=${WORK:-target/bench-render}
VIEWS=${VIEWS:-3}
RUNS=${RUNS:-3}
mkdir -p "$WORK"
for level in 7 9; do
  if [ ! -f "$WORK/l$level/run/model.safetensors" ]; then
    "$BIN" demo --out "$WORK/l$level" --size 400 --level "$level" --voxelize >/dev/null
  fi
done
: > bench_render.jsonl
for level in 7 9; do
  for ds in 2 1; do
    "$BIN" bench render "$WORK/l$level/run" --data "$WORK/l$level/data" --downscale "$ds" \
      --views "$VIEWS" --runs "$RUNS" ${SEGMENTS:+--segments "$SEGMENTS"} --json | tee -a bench_render.jsonl
  done
done
