#!/usr/bin/env bash
# Parity variants for a lent GPU (issue 34, docs/PARITY.md): lego 400² from the GPU kit,
# ITERS iterations (default 6000, SVRaster's --sche_mult 0.3 run), one training per
# variant, each evaluated on the kit's 50 test views. The variants are SVRaster's rules
# that showed no difference at 100² on lavapipe and can only be told apart at 400²:
#   base       the synthetic preset
#   suball     subdivide every voxel at the first adaptive step (item 1)
#   adam       Adam moments reset at every layout change (item 4)
#   rcolour    SVRaster's colour-only per-point RGB loss (item 5)
#   tvl1       SVRaster's L1 TV with its tie rule (item 6)
#   dist       SVRaster's distortion: 0.1 from half the run, contracted axis (item 8)
#   straight   the colour gradient straight through the clamp, as SVRaster (item 3)
#   svrcolour  that with SVRaster's colour rates at 6 000 iterations (÷ sche_mult 0.3)
#   svrall     that with its density rate too (0.025 ÷ 0.3) and its Adam resets (item 4)
# Prepare here with ../shared/gpu/prepare.sh .gpu (../shared/gpu/README.md), then on the
# device, from the checkout's root:
#   bash tools/gpu_parity.sh .gpu [SECONDS] [VARIANTS...]
# It runs the variants in the order given (default: all, in the order above) while the
# wall budget SECONDS (default 540) allows another ~150 s training, so a short budget
# runs the first few. Writes $OUT/parity.jsonl (one line per variant: its settings,
# eval JSON without per-view rows, training wall time) and prints a table.
set -u
G=$(cd "${1:-.gpu}" && pwd); BUDGET=${2:-540}; shift 2 2>/dev/null || shift $#
O=${OUT:-/tmp/out}; mkdir -p "$O"; ITERS=${ITERS:-6000}
VARIANTS=("$@"); [ ${#VARIANTS[@]} -gt 0 ] || VARIANTS=(base suball adam rcolour tvl1 dist straight svrcolour svrall)
. "$(dirname "$0")/gpu_kit.sh"
kit_lego
start=$(date +%s); : > "$O/parity.jsonl"
for v in "${VARIANTS[@]}"; do
  case $v in
    base) S=() ;;
    suball) S=(--set subdivide_all_until=0.05) ;;
    adam) S=(--set reset_adam_at_adapt=true) ;;
    rcolour) S=(--set lambda_r=0 --set lambda_r_colour=0.01) ;;
    tvl1) S=(--set tv_form=l1) ;;
    dist) S=(--set lambda_dist=0.1 --set dist_from=0.5 --set dist_contracted=true) ;;
    straight) S=(--set colour_clamp_grad=straight) ;;
    svrcolour) S=(--set colour_clamp_grad=straight --set lr_sh0=0.0333 --set lr_shs=0.000833) ;;
    svrall) S=(--set colour_clamp_grad=straight --set lr_sh0=0.0333 --set lr_shs=0.000833
               --set lr_geo=0.0833 --set reset_adam_at_adapt=true) ;;
    *) echo "unknown variant $v"; continue ;;
  esac
  left=$(( BUDGET - ($(date +%s) - start) ))
  [ $left -ge 150 ] || { echo "budget: $left s left, stopping before $v"; break; }
  s=$(date +%s)
  timeout -s INT $(( left - 30 )) "$B" train /tmp/lego --out /tmp/runs/p_$v --iters $ITERS "${S[@]}" \
    > "$O/parity_$v.log" 2>&1 || { echo "$v: train failed: $(tail -2 "$O/parity_$v.log")"; continue; }
  wall=$(( $(date +%s) - s ))
  timeout 120 "$B" eval /tmp/runs/p_$v --data /tmp/lego --split test --json > "$O/parity_$v.json" 2>> "$O/parity.err" \
    || { echo "$v: eval failed"; continue; }
  python3 - "$v" "$wall" "$O/parity_$v.json" "${S[*]:-}" >> "$O/parity.jsonl" <<'PY'
import json, sys
d = json.load(open(sys.argv[3])); d.pop("per_view", None)
print(json.dumps({"variant": sys.argv[1], "set": sys.argv[4], "train_wall_s": int(sys.argv[2]), **d}))
PY
done
python3 - "$O/parity.jsonl" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
print("| variant | settings | test PSNR | SSIM | voxels | train wall s |")
print("|---|---|---|---|---|---|")
for r in rows:
    print(f"| {r['variant']} | {r['set'] or '(synthetic preset)'} | {r['psnr']:.2f} | {r['ssim']:.4f} | "
          f"{r['voxels']} | {r['train_wall_s']} |")
PY
