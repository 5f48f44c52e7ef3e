#!/usr/bin/env bash
# Writes the step-level parity fixtures of tests/parity.rs (issue 60; tests/fixtures/parity/
# README.md): SVRaster's training steps from one small model of ours, dumped tensor by
# tensor by tools/svraster_step_dump.py.
#
# usage: tools/parity_fixtures.sh OUTDIR [cpu|cuda]
#   cpu  (default): SVRaster's Python with tools/svraster_cpu/_C.py as its kernels (a dry
#        run; runs here). Folders OUTDIR/demo_{synthetic,synthetic_late,real_late,init}_cpu.
#   cuda: SVRaster's own CUDA extension, on a GPU machine after ../shared/gpu/svr/run_svr.sh
#        build (svraster_cuda in SVR_SITE=/tmp/site); folders ..._cuda. tools/gpu_check.sh
#        runs this there.
# env: BIN (target/release/svraster), SVR (SVRaster's checkout, ../shared/gpu/svr/src), PY
#      (python3 with torch), MODEL (the model.pt to start from: default the committed
#      fixture's, so that every kernel set starts from the same model; MODEL=train trains
#      a new one with BIN: 400 iterations of the demo scene, level-4 grid, SH degree 1).
# The demo scene (64 px, seed 0) is written by BIN; the dumps record each step's camera
# and photo, which the test uses, so the scene need not be bit-identical across machines.
set -euo pipefail
OUT=${1:?usage: tools/parity_fixtures.sh OUTDIR [cpu|cuda]}; KIND=${2:-cpu}
ROOT=$(cd "$(dirname "$0")/.." && pwd)
BIN=${BIN:-$ROOT/target/release/svraster}
SVR=${SVR:-$ROOT/../shared/gpu/svr/src}
PY=${PY:-python3}
MODEL=${MODEL:-$ROOT/tests/fixtures/parity/demo_synthetic_cpu/model.pt}
case $KIND in
  cpu) FLAG=--cpu ;;
  cuda) FLAG= ;;
  *) echo "parity_fixtures: kind must be cpu or cuda, not $KIND" >&2; exit 2 ;;
esac
[ -x "$BIN" ] || { echo "parity_fixtures: no binary at $BIN (cargo build --release --locked)" >&2; exit 1; }
W=$(mktemp -d); trap 'rm -rf "$W"' EXIT
mkdir -p "$OUT"
"$BIN" demo --out "$W/demo" --size 64 --iters 300 --seed 0 > "$W/demo.log" 2>&1 ||
  { tail -5 "$W/demo.log" >&2; exit 1; }
if [ "$MODEL" = train ]; then
  "$BIN" train "$W/demo/data" --out "$W/run" --iters 400 --preset synthetic \
    --set grid_level=4 --set sh_degree=1 --seed 3 > "$W/train.log" 2>&1 ||
    { tail -5 "$W/train.log" >&2; exit 1; }
  python3 "$ROOT/tools/svraster_checkpoint.py" "$W/run/model.safetensors" "$W/model.pt"
  MODEL=$W/model.pt
fi
dump() { # name, dump arguments... (--init: no model; --model otherwise)
  local d=$OUT/${1}_$KIND; shift
  [ -e "$d" ] && { echo "parity_fixtures: $d exists; remove it first" >&2; exit 1; }
  local from=(--model "$MODEL"); [ "$1" = --init ] && from=()
  "$PY" "$ROOT/tools/svraster_step_dump.py" $FLAG --svr "$SVR" --data "$W/demo/data" \
    "${from[@]}" --out "$W/dump_$(basename "$d")" --set sh_degree=1 "$@" 2>&1 |
    grep -v -i "warning\|^  " || true
  [ -f "$W/dump_$(basename "$d")/step.json" ] || { echo "parity_fixtures: the dump for $d failed" >&2; exit 1; }
  mkdir -p "$d"; [ ${#from[@]} -gt 0 ] && cp "$MODEL" "$d/model.pt"; mv "$W/dump_$(basename "$d")"/* "$d/"
  echo "parity_fixtures: $d ($(du -sh "$d" | cut -f1))"
}
# Early: the first iterations after the first adaptive step (Adam fresh, then its second
# step; ss 1 and 1.25; SSIM, T concentration, R concentration, TV on).
dump demo_synthetic --iteration 1001 --views 3,7 --ss 1.0,1.25
# Late: distortion on, TV off, then the adaptive step at 15 000 (prune and subdivide).
dump demo_synthetic_late --iteration 14999 --views 2,5 --ss 1.3,1.1 --adapt
# Real captures' rules (cfg/mipnerf360.yaml) on the same model and scene: each frame's
# mean colour behind the model, the inside loss, no T concentration; late, with the
# adaptive step.
dump demo_real_late --cfg cfg/mipnerf360.yaml --iteration 14999 --views 2,5 --ss 1.3,1.1 --adapt
# SVRaster's initial model (model_init on the training cameras, level-4 grid). The same with
# cfg/mipnerf360.yaml's 5 background shell levels differs from ours (docs/PARITY.md,
# step-level comparison): `dump demo_real_init --init --cfg cfg/mipnerf360.yaml --set
# init_n_level=4` writes it, for that work.
dump demo_init --init --set init_n_level=4
