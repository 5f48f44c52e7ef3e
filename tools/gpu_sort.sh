#!/usr/bin/env bash
# The sort on a lent GPU in one short call (issue 33, "the onesweep sort at a GPU's
# speed"; ~3 min on an H200 with a warm start). Prepare here with tools/gpu_prepare.sh
# .gpu, then on the device, from the checkout's root, carry .gpu:
#   bash tools/gpu_sort.sh .gpu [A_ARGS] [B_ARGS]
# 1. `bench sort` of 2^24 u64 keys + u32 values (8 passes, every run verified, each its
#    own process): the default against A_ARGS and B_ARGS (default "--window 4" and
#    "--pass s256"), alternating, 2 rounds; then 40 bits (5 passes) and 2^22 keys;
#    the SM clock logged throughout (--heat-ms keeps the card busy before each run)
# 2. while a lego 400² model trains (3 000 iterations; its time is not a result): the
#    suite's sort tests and the bench sort cli tests, on this card's defaults
# 3. `bench render` of that model's 20 test views with each pass kernel
#    (SVRASTER_SORT_PASS direct, c256, s256, alternating): the frame's sort stage
# $OUT: run.log, sort.jsonl, render_*.json, test logs. A dry run on lavapipe (small):
# SORT_N=65536 SORT_SMALL=16384 ITERS=60 OUT=/tmp/o bash tools/gpu_sort.sh .gpu "--pass c128" "--pass s128"
set -u
G=$(cd "${1:-.gpu}" && pwd); A=${2:---window 4}; BB=${3:---pass s256}
O=${OUT:-/tmp/out}; mkdir -p "$O"
N=${SORT_N:-16777216}; N2=${SORT_SMALL:-4194304}; ITERS=${ITERS:-3000}
exec > >(tee -a "$O/run.log") 2>&1
t0=$(date +%s); stamp() { echo "### t=$(( $(date +%s) - t0 ))s :: $*"; }
. "$(dirname "$0")/gpu_kit.sh"
kit_lego
P=$(cat "$G/project_path")
stamp "bench sort"
nvidia-smi --query-gpu=timestamp,clocks.sm --format=csv,noheader -lms 200 > "$O/clocks.csv" 2>&1 &
SMI=$!
for round in 1 2; do
  for a in "" "$A" "$BB"; do
    timeout 40 "$B" bench sort --n $N --runs 5 --warmup 2 --no-baseline $a --json >> "$O/sort.jsonl" 2>> "$O/sort.err"
  done
done
timeout 40 "$B" bench sort --n $N --runs 5 --warmup 2 --no-baseline --bits 0..40 --json >> "$O/sort.jsonl" 2>> "$O/sort.err"
timeout 40 "$B" bench sort --n $N2 --runs 5 --warmup 2 --no-baseline --json >> "$O/sort.jsonl" 2>> "$O/sort.err"
kill $SMI 2>/dev/null
python3 - "$O/sort.jsonl" "$O/clocks.csv" <<'PY'
import json, sys
for l in open(sys.argv[1]):
    d = json.loads(l)
    p = sorted(v for k, v in d['stages_median_ms'].items() if k.startswith('sort.pass'))
    g = sorted(v for k, v in d['stages_gb_per_s'].items() if k.startswith('sort.pass'))
    print('sort', d['n'], d['pass_kernel'], d['bits'], 'window', d.get('lookback_window'), 'heat', d.get('heat_ms'), 'ms /', d.get('heat_sorts'),
          'runs', [round(x, 2) for x in d.get('runs_ms') or []], '->', round(d['median_ms'], 3), 'ms =', round(d['mkeys_per_s'] / 1e3, 2), 'Gkeys/s;',
          'pass', round(p[len(p) // 2], 3) if p else '-', 'ms', round(g[len(g) // 2]) if g else '-', 'GB/s; histogram', round(d['stages_median_ms'].get('sort.histogram', 0), 3),
          'ms; look-back', d.get('lookback'), 'verified', d['verified'])
sm = []
for l in open(sys.argv[2]):
    try: sm.append(float(l.split(',')[1].split()[0]))
    except (IndexError, ValueError): pass
sm.sort()
if sm: print('SM clock (MHz): min', sm[0], 'median', sm[len(sm) // 2], 'max', sm[-1], 'of', len(sm))
PY
stamp "train (tests beside it)"
( timeout 120 "$B" train /tmp/lego --out /tmp/runs/m --iters $ITERS > "$O/train.log" 2>&1; echo "train rc=$?" >> "$O/train.log" ) &
TR=$!
cd "$P"
for t in target/release/deps/suite-* target/release/deps/cli-*; do
  case $t in *.*) continue;; esac
  n=$(basename "$t"); f=sort; [ "${n%-*}" = cli ] && f=bench_sort
  timeout 100 "$t" "$f" --test-threads=4 > "$O/test_${n%-*}.log" 2>&1
  echo "TEST ${n%-*} ($f) rc=$? $(grep -E '^test result' "$O/test_${n%-*}.log" | tail -1)"
  grep -h -E "^test .* FAILED|panicked at" "$O/test_${n%-*}.log" | head -10
done
wait $TR; tail -2 "$O/train.log"
stamp "bench render"
for round in 1 2; do
  for p in direct c256 s256; do
    SVRASTER_SORT_PASS=$p timeout 40 "$B" bench render /tmp/runs/m --data /tmp/lego --split test --views 20 --runs 3 --json > "$O/render_${p}_$round.json" 2> "$O/render_$p.err"
    echo "exit $? (124: timed out)" >> "$O/render_$p.err"
    python3 2>/dev/null -c "import json; d=json.load(open('$O/render_${p}_$round.json')); print('render', d.get('sort_pass'), 'voxels', d.get('voxels'), 'GPU', round(d['median_ms'], 3), 'ms, wall', round(d['wall_median_ms'], 3), 'ms;', {k: round(v, 3) for k, v in d['stages_median_ms'].items() if 'sort' in k})" ||
      { echo "bench render ($p) failed:"; tail -3 "$O/render_$p.err"; }
  done
done
stamp done
