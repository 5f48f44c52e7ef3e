#!/usr/bin/env bash
# The lavapipe runs behind docs/PARITY.md: lego_400 at 1/DOWNSCALE, ITERS iterations,
# the synthetic preset plus each variant's --set switches, one training after the
# other (they would compete for the cores), each evaluated on the 100 val views; then
# every variant against the first (the baseline): PSNR, SSIM, voxels, training time,
# and per view how many are better, the median and the range of the difference.
#
# usage: tools/parity_lavapipe.sh OUTDIR DOWNSCALE NAME[:key=value[,key=value...]]...
#   e.g. tools/parity_lavapipe.sh /tmp/par 4 base clamp:clamp_rgb_loss=true
#   (preset=NAME among them trains with --preset NAME instead of the synthetic preset)
# env:   ITERS (3000), DATA (../shared/data/lego_400), BIN (target/release/svraster)
# A variant whose evaluation is already in OUTDIR is not trained again, so a stopped
# run resumes, and a later call can add variants to the same baseline. The table goes
# to stdout and OUTDIR/summary.md; each run's log, model and eval JSON stay in OUTDIR.
set -euo pipefail
if [ $# -lt 3 ]; then
  sed -n '2,14p' "$0" | sed 's/^# \{0,1\}//'
  exit 2
fi
OUT=$1; DS=$2; shift 2
ROOT=$(cd "$(dirname "$0")/.." && pwd)
BIN=${BIN:-$ROOT/target/release/svraster}
DATA=${DATA:-$ROOT/../shared/data/lego_400}
ITERS=${ITERS:-3000}
[ -x "$BIN" ] || { echo "no binary at $BIN: cargo build --release --locked first" >&2; exit 1; }
[ -d "$DATA" ] || { echo "no data at $DATA (set DATA=...)" >&2; exit 1; }
mkdir -p "$OUT"
NAMES=()
for v in "$@"; do
  name=${v%%:*}; sets=()
  case $v in *:*) IFS=, read -ra kv <<< "${v#*:}"; for s in "${kv[@]}"; do
    case $s in preset=*) sets+=(--preset "${s#preset=}") ;; *) sets+=(--set "$s") ;; esac
  done ;; esac
  NAMES+=("$name")
  if [ -s "$OUT/$name.eval.json" ]; then
    echo "$name: evaluated already ($OUT/$name.eval.json)"; continue
  fi
  echo "$name: training ${sets[*]:-(preset)} → $OUT/$name.train.log"
  s=$(date +%s)
  "$BIN" train "$DATA" --out "$OUT/$name" --downscale "$DS" --iters "$ITERS" "${sets[@]}" \
    > "$OUT/$name.train.log" 2>&1
  echo $(( $(date +%s) - s )) > "$OUT/$name.train_s"
  "$BIN" eval "$OUT/$name" --data "$DATA" --json > "$OUT/$name.eval.json.tmp" 2> "$OUT/$name.eval.err"
  mv "$OUT/$name.eval.json.tmp" "$OUT/$name.eval.json"
done
python3 - "$OUT" "$DS" "$ITERS" "${NAMES[@]}" <<'EOF' | tee "$OUT/summary.md"
import json, os, statistics, sys
out, ds, iters, names = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:]
def load(n):
    d = json.load(open(os.path.join(out, n + ".eval.json")))
    t = os.path.join(out, n + ".train_s")
    d["train_s"] = int(open(t).read()) if os.path.exists(t) else None
    d["views"] = {v[0]: v[1] for v in d["per_view"]}
    return d
runs = [load(n) for n in names]
base = runs[0]
print(f"lego 1/{ds}, {iters} iterations, {len(base['views'])} val views; baseline {names[0]}\n")
print("| run | PSNR | SSIM | voxels | train | better views | median Δ dB | range Δ dB |")
print("|---|---|---|---|---|---|---|---|")
for n, r in zip(names, runs):
    t = f"{r['train_s'] // 60} m {r['train_s'] % 60:02d} s" if r["train_s"] else "?"
    row = f"| {n} | {r['psnr']:.2f} | {r['ssim']:.4f} | {r['voxels']} | {t} |"
    if r is base:
        print(row + " | | |")
        continue
    d = [r["views"][k] - base["views"][k] for k in base["views"]]
    better = sum(x > 0 for x in d)
    print(row + f" {better} of {len(d)} | {statistics.median(d):+.3f} | "
          f"{min(d):+.2f} … {max(d):+.2f} |")
EOF
