#!/usr/bin/env bash
# Segment sweep for a lent GPU (issue 32, "every SM busy"): `bench train` on the GPU kit's
# lego subset at 100², 200² and 400² (quick preset, level-6 grid) with segments off and
# of 512, 2048 and 8192 entries, in one process each, alternating. Prepare here with
# ../shared/gpu/prepare.sh .gpu (see ../shared/gpu/README.md), then on the device, from
# the checkout's root, in one call:   bash tools/gpu_segments.sh .gpu
# (~3 min on an H200; it can follow `bash .gpu/run.sh 360` in the same call). Writes
# $OUT/segments.jsonl (one bench JSON per line) and prints a table.
set -u
G=$(cd "${1:-.gpu}" && pwd); O=${OUT:-/tmp/out}; mkdir -p "$O"
. "$(dirname "$0")/gpu_kit.sh"
kit_lego
: > "$O/segments.jsonl"
for ds in 4 2 1; do
  for seg in 0 512 2048 8192; do
    timeout 90 "$B" bench train /tmp/lego --downscale $ds --preset quick --set grid_level=6 \
      --iters 10 --warmup 2 --segments $seg --json >> "$O/segments.jsonl" 2>> "$O/segments.err" \
      || echo "bench train downscale $ds segments $seg failed: $(tail -2 "$O/segments.err")"
  done
done
python3 - "$O/segments.jsonl" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
print("| image | segments | GPU ms/iter | wall ms/iter | forward | backward | walk workgroups | longest/mean |")
print("|---|---|---|---|---|---|---|---|")
for r in rows:
    s = r["stages_median_ms"]
    print(f"| {r['image'][0]}² | {r.get('segment_entries', '?')} | {r['median_ms_per_iter']:.2f} | "
          f"{r['wall_median_ms_per_iter']:.2f} | {s.get('forward', 0):.2f} | {s.get('backward', 0):.2f} | "
          f"{r['walk_workgroups_per_dispatch_median']:.0f} | {r['tile_balance_median']:.1f} |")
PY
