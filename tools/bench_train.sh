#!/usr/bin/env bash
# Training-iteration benchmark: `svraster bench train` on NeRF-synthetic lego
# (../shared/data/lego_400, or DATA=...) with the quick preset (level-6 grid, 262 144
# voxels) at downscale 4 (100²) and 2 (200²). Appends one JSON line per configuration
# to bench_train.jsonl and prints a table of the per-stage medians. SEGMENTS=N sets the
# entries per segment of the frame and backward walks (0: off; default: the device's).
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${DATA:-../shared/data/lego_400}
ITERS=${ITERS:-5}
LEVEL=${LEVEL:-6}
if [ ! -f "$DATA/transforms_train.json" ]; then
  echo "bench_train: $DATA/transforms_train.json not found (set DATA=<Blender dataset>)" >&2
  exit 1
fi
cargo build --release --quiet
: > bench_train.jsonl
for ds in 4 2; do
  target/release/svraster bench train "$DATA" --downscale "$ds" --preset quick \
    --set grid_level="$LEVEL" --iters "$ITERS" --warmup 1 ${SEGMENTS:+--segments "$SEGMENTS"} \
    --json | tee -a bench_train.jsonl
done
python3 - <<'PY'
import json
rows = [json.loads(l) for l in open("bench_train.jsonl")]
print("| image | voxels | ms/iter | preprocess | sort | forward | losses | backward | optimizer | trips / useful | full walk / useful |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
for r in rows:
    s = r["stages_median_ms"]
    w = r.get("work_per_iter", {}).get("forward", {})
    print(f"| {r['image'][0]}² | {r['voxels']} | {r['median_ms_per_iter']:.0f} | " +
          " | ".join(f"{s.get(k, 0):.1f}" for k in
                     ["preprocess", "sort", "forward", "losses", "backward", "optimizer"]) +
          f" | {w.get('trips_per_useful_trip', 0):.2f} | {w.get('full_walk_trips_per_useful_trip', 0):.1f} |")
PY
