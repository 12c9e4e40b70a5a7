#!/usr/bin/env bash
# The demo's semantic mIoU over several seeds (the measure the demo target is held to: one
# seed swings by 10-20 points with the scan's path). Prints one line per seed, the mean, and
# the mIoU of the seeds' confusion matrices summed (pooled, as S3DIS and ScanNet score a set of
# rooms: a class a scan never sees but predicts on a few hundred vertices costs that seed a
# whole class at 0 % in its own mIoU, and the pooled figure counts those vertices instead).
# Usage: bench/demo_seeds.sh [MODEL] [SEEDS]   (default: the shipped model, seeds 1-10)
# Environment: SEMRECON_BIN (default target/release/semrecon, built if missing); DEMO_ARGS,
#   extra arguments for every `semrecon demo` (e.g. "--structure none").
set -euo pipefail
cd "$(dirname "$0")/.."
model=${1:-crates/net/models/s20.safetensors}
seeds=${2:-"1 2 3 4 5 6 7 8 9 10"}
bin=${SEMRECON_BIN:-target/release/semrecon}
[ -x "$bin" ] || cargo build --release -p semrecon
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
values=()
for s in $seeds; do
  v=$("$bin" demo --seed "$s" --model "$model" --out "$out/demo$s" --no-mesh-eval ${DEMO_ARGS:-} 2>&1 \
      | grep -o 'mIoU [0-9.]*%' | head -1 | grep -o '[0-9.]*' || true)
  echo "seed $s mIoU ${v:-?} %"
  [ -n "$v" ] && values+=("$v")
done
printf '%s\n' "${values[@]}" | awk '{s += $1; if (NR == 1 || $1 < lo) lo = $1; if ($1 > hi) hi = $1}
  END {if (NR) printf "mean %.1f %% (min %.1f, max %.1f) over %d seeds\n", s / NR, lo, hi, NR}'
python3 - "$out" $seeds <<'EOF'
import json, os, sys
out, seeds = sys.argv[1], sys.argv[2:]
total, per_present = None, []
def ious(cm):
    k = len(cm)
    tp = [cm[i][i] for i in range(k)]
    gt = [sum(cm[i]) for i in range(k)]
    pr = [sum(cm[i][j] for i in range(k)) for j in range(k)]
    return [tp[i] / (gt[i] + pr[i] - tp[i]) for i in range(k) if gt[i] > 0], sum(tp), sum(gt)
for s in seeds:
    path = os.path.join(out, f"demo{s}", "report.json")
    if not os.path.exists(path):
        continue
    cm = json.load(open(path))["confusion"]
    total = cm if total is None else [[a + b for a, b in zip(r, q)] for r, q in zip(total, cm)]
    present = ious(cm)[0]
    per_present.append(100 * sum(present) / len(present))
if total:
    pooled, right, all_ = ious(total)
    print("mean over the classes each seed's truth holds %.1f %%" % (sum(per_present) / len(per_present)))
    print("pooled mIoU %.1f %%, accuracy %.1f %% over %d seeds" % (100 * sum(pooled) / len(pooled), 100 * right / all_, len(per_present)))
EOF
