#!/usr/bin/env bash
# Runs `svraster bench sort` at n = 2^20, 2^22, 2^24 for bits 0..64 and 0..40 and prints
# a Markdown table (and the raw JSON lines to bench_sort.jsonl).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --quiet
out=${1:-bench_sort.jsonl}
: > "$out"
for n in 1048576 4194304 16777216; do
  for bits in 0..64 0..40; do
    ./target/release/svraster bench sort --n "$n" --bits "$bits" --runs "${RUNS:-7}" --warmup 2 --json | tee -a "$out" >&2
  done
done
python3 - "$out" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
print("| n | bits | passes | GPU median ms | Mkeys/s | histogram ms | median pass ms | CPU sort_unstable ms | GPU/CPU | verified |")
print("|---|---|---|---|---|---|---|---|---|---|")
for r in rows:
    st = r["stages_median_ms"]
    passes = sorted(v for k, v in st.items() if k.startswith("sort.pass"))
    mp = passes[len(passes)//2]
    print(f"| 2^{r['n'].bit_length()-1} | {r['bits']} | {r['passes']} | {r['median_ms']:.1f} | {r['mkeys_per_s']:.2f} | {st['sort.histogram']:.1f} | {mp:.1f} | {r['cpu_median_ms']:.1f} | {r['speedup_vs_cpu']:.3f} | {r['verified']} ({r['failed_runs']} wrong) |")
PY
