#!/usr/bin/env bash
# One device call that checks this engine on a lent GPU beside the official SVRaster
# (issues "Real GPUs", "The onesweep sort", "Quality"; what the 2026-11-27 H200 run did).
# Prepare here: apt-get update; tools/gpu_prepare.sh .gpu (the shared kit,
# ../shared/gpu/README.md, plus the examples the suite runs). On the device, from the
# checkout's root, carry .gpu:
#   bash tools/gpu_check.sh .gpu [SECONDS=570] [VARIANT...]
# VARIANT: NAME:key=value[,key=value...] (a bare key=value[,...] is named variantN; the key
# `preset` picks the preset, e.g. svr:preset=svraster-synthetic), one training each, in
# order, while time is left; SKIP_SVR=1 leaves SVRaster out (its build,
# fixture and run: ~170 s more for the variants).
# Steps (each capped so later ones still run; outputs go to $OUT as they are made):
#   1. Vulkan info; SVRaster's CUDA build, then its small fixture model (300 iterations,
#      1/4 size, its own test renders: $OUT/svr_tiny.tgz, for
#      `cli import::svraster_s_own_renders_match_ours` with SVRASTER_SVR_FIXTURE), and the
#      step-level parity fixtures with its CUDA kernels (tools/parity_fixtures.sh:
#      $OUT/parity_fixtures.tgz, for tests/fixtures/parity/)
#   2. the test binaries (4 at a time, 6 threads each) while that builds
#   3. bench sort 2^24 (auto, reduce-then-scan s256 and s128, direct pass, 40 bits, spin limits 64 and 10^6, histogram
#      workgroups uncapped and 256, look-back windows 1 and 8, back-off 64 and 512 ALU
#      rounds between polls, the pass's copy and tile probes: its cost taken apart) and
#      2^20 and 2^22, with look-back counters;
#      bench train lego 100²/200²/400² level 6 (auto segments) and 400² level 7
#   4. lego 400², 6 000 iterations, the default preset (timed alone), eval on the 50
#      test views, bench render of that model
#   5. SVRaster on the same data and card, 6 000 iterations (timed alone)
#   6. with what is left: the same training per VARIANT (e.g.
#      straight:colour_clamp_grad=straight), eval
# $OUT: run.log (everything), res.tgz (logs, JSON, stats), svr_tiny.tgz, parity_fixtures.tgz.
# A dry run of the flow on any machine: SKIP_TESTS=1 ITERS=60 OUT=/tmp/o bash tools/gpu_check.sh .gpu
# (on lavapipe with small benches, so that the trainings run too: SORT_N=262144
# SORT_SMALL=65536 BENCH_TRAIN='4 4' SKIP_SVR=1; at 8 lanes the 16-lane passes c256/s256
# and the probes, which the device's pass (direct) lacks, fail and say so in sort.err).
set -u
G=$(cd "${1:-.gpu}" && pwd); BUDGET=${2:-570}; shift 2 2>/dev/null || shift $#
VARIANTS=("$@"); ITERS=${ITERS:-6000}
SORT_N=${SORT_N:-16777216}; SORT_SMALL=${SORT_SMALL:-"1048576 4194304"}
BENCH_TRAIN=${BENCH_TRAIN:-"4 6;2 6;1 6;1 7"} # downscale and grid level per bench train
O=${OUT:-/tmp/out}; X=/tmp/x; mkdir -p "$O" "$X"
exec > >(tee -a "$O/run.log") 2>&1
t0=$(date +%s)
left() { echo $(( BUDGET - ($(date +%s) - t0) )); }
stamp() { echo "### t=$(( $(date +%s) - t0 ))s left=$(left)s :: $*"; }
pack() { (cd $X && tar czf "$O/res.tgz" --exclude=svr_tiny . 2>/dev/null); }
cap() { local want=$1 l; l=$(( $(left) - ${2:-0} )); [ $l -lt $want ] && want=$l; [ $want -lt 5 ] && want=5; echo $want; }
stamp setup
. "$(dirname "$0")/gpu_kit.sh"
kit_lego
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
P=$(cat "$G/project_path")
if [ -f "$G/svr/run_svr.sh" ] && [ -z "${SKIP_SVR:-}" ]; then
  ( bash "$G/svr/run_svr.sh" build > $X/svr_build.log 2>&1; echo "svr build rc=$?" >> $X/svr_build.log
    SVR_SLIM=0 SVR_TRAIN_EXTRA_ARGS="--init_n_level 4 --res_downscale 4" timeout -s INT 150 \
      bash "$G/svr/run_svr.sh" run /tmp/lego /tmp/svr_tiny 300 > $X/svr_tiny.log 2>&1
    echo "svr tiny rc=$?" >> $X/svr_tiny.log ) &
  SVR=$!
fi
timeout 60 "$B" info || { VK_LOADER_DEBUG=error,warn timeout 60 "$B" info 2>&1 | tail -30; pack; exit 1; }
timeout 60 "$B" info --json > $X/info.json
stamp tests
cd "$P"; PIDS=()
for t in target/release/deps/*; do
  [ -n "${SKIP_TESTS:-}" ] && break
  n=$(basename $t); case $n in *.*) continue;; esac; [ -x $t ] || continue; n=${n%-*}
  ( s=$(date +%s); timeout 170 $t --test-threads=6 > $X/test_$n.log 2>&1; rc=$?
    echo "TEST $n rc=$rc $(( $(date +%s) - s ))s $(grep -E '^test result' $X/test_$n.log | tail -1)" ) &
  PIDS+=($!)
  while [ $(jobs -r | wc -l) -ge 5 ]; do sleep 1; done
done
for p in "${PIDS[@]}"; do wait $p; done
grep -h -E "^test .* FAILED|panicked at" $X/test_*.log | head -40
cd /tmp; pack
if [ -n "${SVR:-}" ]; then
  stamp "waiting for SVRaster's fixture (the timed steps run alone)"
  for i in $(seq 120); do kill -0 $SVR 2>/dev/null || break; sleep 1; done
  kill -0 $SVR 2>/dev/null && { echo "svr tiny still running: stopped"; pkill -INT -f run_svr.sh; sleep 5; }
  tail -1 $X/svr_build.log $X/svr_tiny.log 2>/dev/null
  mkdir -p $X/svr_tiny && (cd /tmp/svr_tiny/lego 2>/dev/null &&
    find . -name '*.pt' -size -15M -exec cp --parents {} $X/svr_tiny/ \; ;
    find . -path '*test*renders*' -name '*.png' | head -20 | xargs -r cp --parents -t $X/svr_tiny/
    cp config.yaml $X/svr_tiny/ 2>/dev/null)
  (cd $X && tar czf "$O/svr_tiny.tgz" svr_tiny svr_tiny.log 2>/dev/null)
  # The step-level parity fixtures with SVRaster's own CUDA kernels (issue 60;
  # tests/fixtures/parity/README.md): → $OUT/parity_fixtures.tgz, to commit.
  stamp "parity fixtures (SVRaster's CUDA kernels)"
  PYX=python3; [ -x /opt/torch/.venv/bin/python3 ] && PYX=/opt/torch/.venv/bin/python3
  SSIMP=/tmp/svr_build/fused_ssim_site; [ -d $SSIMP ] || SSIMP=
  PYTHONPATH=/tmp/site${SSIMP:+:$SSIMP}:$G/svr/stubs PY=$PYX SVR=$G/svr/src BIN=$B \
    timeout $(cap 90) bash "$P/tools/parity_fixtures.sh" $X/parity cuda > $X/parity_fixtures.log 2>&1
  echo "parity fixtures rc=$?"; grep "^parity_fixtures\|^step\|^adapt" $X/parity_fixtures.log
  (cd $X && tar czf "$O/parity_fixtures.tgz" parity parity_fixtures.log 2>/dev/null)
fi
stamp bench
# The card's clocks while the benches run (bench sort heats the device before each
# run: --heat-ms; the "--heat-ms 0" row is the same sort without it).
nvidia-smi --query-gpu=timestamp,clocks.sm,clocks.mem,power.draw,utilization.gpu --format=csv,noheader -lms 200 > $X/clocks.csv 2>&1 &
SMI=$!
for a in "--pass auto" "--pass auto --heat-ms 0" "--pass s256" "--pass s128" "--pass direct" "--bits 0..40" "--spin 64" "--spin 1000000" "--hist-groups 0" "--hist-groups 256" "--window 1" "--window 8" "--backoff 64" "--backoff 512" "--probe copy" "--probe tile"; do
  nb=--no-baseline; [ "$a" = "--pass auto" ] && nb=
  timeout 40 "$B" bench sort --n $SORT_N --runs 5 --warmup 2 $a $nb --json >> $X/sort.jsonl 2>>$X/sort.err
done
for n in $SORT_SMALL; do
  timeout 40 "$B" bench sort --n $n --runs 5 --warmup 2 --json >> $X/sort.jsonl 2>>$X/sort.err
  timeout 40 "$B" bench sort --n $n --runs 5 --warmup 2 --pass s256 --no-baseline --json >> $X/sort.jsonl 2>>$X/sort.err
done
python3 - $X/sort.jsonl <<'PY'
import json, sys
for l in open(sys.argv[1]):
    d = json.loads(l); g = sorted(v for k, v in d['stages_gb_per_s'].items() if k.startswith('sort.pass'))
    c = sorted(v for k, v in d['stages_median_ms'].items() if k.startswith('sort.count'))
    r = d.get('runs_ms') or []
    print('sort', d['n'], d['pass_kernel'], d['bits'], 'heat', d.get('heat_ms'), 'ms =', d.get('heat_sorts'), 'sorts, runs', [round(x, 2) for x in r], 'spin', d.get('spin_limit'), 'hist groups', d.get('hist_groups'), 'window', d.get('lookback_window'), 'backoff', d.get('lookback_backoff'), 'probe', d.get('probe'), 'hist ms', round(d['stages_median_ms'].get('sort.histogram', 0), 3), round(d['median_ms'], 2), 'ms', round(d['mkeys_per_s'] / 1e3, 2),
          'Gkeys/s, pass GB/s', round(g[len(g) // 2]) if g else '-', 'copy floor GB/s', round(d.get('copy_floor_gb_per_s') or 0), 'count ms', round(c[len(c) // 2], 3) if c else '-', 'look-back', d.get('lookback'), 'verified', d['verified'])
PY
kill $SMI 2>/dev/null
python3 - $X/clocks.csv <<'PY'
import sys
sm = []
for l in open(sys.argv[1]):
    f = [x.strip() for x in l.split(',')]
    try: sm.append(float(f[1].split()[0]))
    except (IndexError, ValueError): pass
sm.sort()
print('SM clock during the sort benches (MHz): min', sm[0], 'median', sm[len(sm) // 2], 'max', sm[-1], 'of', len(sm), 'samples') if sm else print('no clock samples:', open(sys.argv[1]).read()[:200])
PY
IFS=';' read -ra BT <<< "$BENCH_TRAIN"
for cfg in "${BT[@]}"; do set -- $cfg
  timeout 40 "$B" bench train /tmp/lego --downscale $1 --preset quick --set grid_level=$2 --iters 10 --warmup 2 --json >> $X/bench_train.jsonl 2>>$X/bench_train.err
done
python3 - $X/bench_train.jsonl <<'PY'
import json, sys
for l in open(sys.argv[1]):
    d = json.loads(l)
    print('bench train', d['image'], d['voxels'], 'segments', d.get('segment_entries'), 'GPU', round(d['median_ms_per_iter'], 2),
          'wall', round(d['wall_median_ms_per_iter'], 2), 'queue', d['queue_per_iter'].get('submits_median'), d['queue_per_iter'].get('fence_waits_median'))
PY
pack
train() { # name, settings...
  local v=$1; shift; stamp "train $v"; local s=$(date +%s) S=()
  for kv in "$@"; do case $kv in preset=*) S+=(--preset "${kv#preset=}") ;; *) S+=(--set "$kv") ;; esac; done
  timeout -s INT $(cap 170 $RES) "$B" train /tmp/lego --out /tmp/runs/$v --iters $ITERS "${S[@]}" > $X/train_$v.log 2>&1
  echo "train $v rc=$? wall $(( $(date +%s) - s ))s"; tail -1 $X/train_$v.log
  cp /tmp/runs/$v/stats.jsonl $X/stats_$v.jsonl 2>/dev/null
  timeout 60 "$B" eval /tmp/runs/$v --data /tmp/lego --split test --json > $X/eval_$v.json 2>$X/eval_$v.err
  echo "exit $? (124: timed out)" >> $X/eval_$v.err
  python3 -c "import json; d=json.load(open('$X/eval_$v.json')); print('eval $v', {k: x for k, x in d.items() if k != 'per_view'})" 2>/dev/null ||
    { echo "eval $v failed:"; tail -3 $X/eval_$v.err; }
  pack
}
# Time kept back for what follows the default training: SVRaster's 6 000 iterations took
# 114 s in all on the H200 (2026-11-29: 82 s of training); without it, the render benches.
RES=$([ -n "${SVR:-}" ] && echo 125 || echo 40); train base
timeout 40 "$B" bench render /tmp/runs/base --data /tmp/lego --split test --views 20 --runs 3 --json > $X/render_base.json 2>$X/render_base.err
echo "exit $? (124: timed out)" >> $X/render_base.err
python3 -c "import json; d=json.load(open('$X/render_base.json')); print('render: GPU', d['median_ms'], 'ms, wall', d['wall_median_ms'], 'ms, segments', d.get('segment_entries'), 'sort', d.get('sort_pass'), {k: round(v, 3) for k, v in d['stages_median_ms'].items() if 'sort' in k})" 2>/dev/null ||
  { echo "bench render failed:"; tail -3 $X/render_base.err; }
# The same frames with the reduce-then-scan sort passes (issue 33: is the look-back what a pass waits on?)
SVRASTER_SORT_PASS=s256 timeout 40 "$B" bench render /tmp/runs/base --data /tmp/lego --split test --views 20 --runs 3 --json > $X/render_base_s256.json 2>$X/render_base_s256.err
echo "exit $? (124: timed out)" >> $X/render_base_s256.err
python3 -c "import json; d=json.load(open('$X/render_base_s256.json')); print('render: GPU', d['median_ms'], 'ms, wall', d['wall_median_ms'], 'ms, sort', d.get('sort_pass'), {k: round(v, 3) for k, v in d['stages_median_ms'].items() if 'sort' in k})" 2>/dev/null ||
  { echo "bench render (s256) failed:"; tail -3 $X/render_base_s256.err; }
if [ -n "${SVR:-}" ]; then
  stamp "SVRaster, $ITERS iterations"
  timeout -s INT $(cap 170 20) bash "$G/svr/run_svr.sh" run /tmp/lego /tmp/svr $ITERS > $X/svr_run.log 2>&1; echo "svr rc=$?"
  cp /tmp/svr/svr_result.json $X/ 2>/dev/null
  python3 -c "import json; d=json.load(open('$X/svr_result.json')); print('SVRaster', {k: d.get(k) for k in ('train_wall_s', 'train_iter_time_s', 'n_voxels', 'fps', 'psnr', 'ssim')})" || tail -8 $X/svr_run.log
  pack
fi
i=0
for spec in "${VARIANTS[@]}"; do
  case $spec in *:*) name=${spec%%:*}; kvs=${spec#*:};; *) name=variant$i; kvs=$spec;; esac
  i=$((i + 1)); IFS=, read -ra KV <<< "$kvs"
  [ $(left) -gt 110 ] || { echo "no time left for variant $name (${KV[*]})"; continue; }
  RES=40; train "$name" "${KV[@]}"
done
stamp done; pack
