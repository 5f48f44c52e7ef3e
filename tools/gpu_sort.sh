#!/usr/bin/env bash
# Sort sweep for a lent GPU (issue 33, "the onesweep sort at a GPU's speed"): `bench sort`
# of 2^24 u64 keys + u32 values with each pass kernel (direct = lavapipe's, c128 and c256
# = coalesced writes through shared memory, s128 and s256 = the same without look-back,
# reduce-then-scan), all 64 bits and a frame-like 0..40, then
# with keys that vary only in 0..40 (three passes skipped). One process per run,
# kernels alternating, 2 rounds. Prepare here with ../shared/gpu/prepare.sh .gpu (see
# ../shared/gpu/README.md), then on the device, from the checkout's root, in one call:
#   bash tools/gpu_sort.sh .gpu
# (~1–2 min on an H200; it can follow `bash .gpu/run.sh 360` in the same call). Writes
# $OUT/sort.jsonl (one bench JSON per line) and prints a table with GB/s per pass.
set -u
G=$(cd "${1:-.gpu}" && pwd); O=${OUT:-/tmp/out}; mkdir -p "$O"
. "$(dirname "$0")/gpu_kit.sh"
: > "$O/sort.jsonl"
for round in 1 2; do
  for args in "--bits 0..64" "--bits 0..40" "--bits 0..64 --vary 0..40"; do
    for pass in direct c128 c256 s128 s256; do
      timeout 60 "$B" bench sort --n 16777216 --runs 5 --warmup 2 --pass $pass $args --json \
        >> "$O/sort.jsonl" 2>> "$O/sort.err" \
        || echo "bench sort --pass $pass $args failed: $(tail -2 "$O/sort.err")"
    done
  done
done
python3 - "$O/sort.jsonl" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
print("| pass | bits | vary | skipped | ms | Gkeys/s | histogram GB/s | pass GB/s (median) | look-back words/digit, polls/tile, fallbacks/run | verified |")
print("|---|---|---|---|---|---|---|---|---|---|")
for r in rows:
    g = r["stages_gb_per_s"]
    ps = sorted(v for k, v in g.items() if k.startswith("sort.pass"))
    pm = ps[len(ps) // 2] if ps else 0
    lb = r.get("lookback") or {}
    print(f"| {r['pass_kernel']} | {r['bits']} | {r['vary']} | {bin(r['skipped_passes']).count('1')} | "
          f"{r['median_ms']:.2f} | {r['mkeys_per_s'] / 1e3:.2f} | {g.get('sort.histogram', 0):.0f} | "
          f"{pm:.0f} | {lb.get('steps_per_digit_tile', 0):.2f}, {lb.get('waits_per_tile', 0):.0f}, "
          f"{lb.get('fallbacks_per_run', 0):.0f} | {r['verified']} |")
PY
