#!/usr/bin/env bash
# The demo's semantic mIoU over several seeds (the measure the demo target is held to: one
# seed swings by 10-20 points with the scan's path). Prints one line per seed and the mean.
# Usage: bench/demo_seeds.sh [MODEL] [SEEDS]   (default: the shipped model, seeds 1-10)
# Environment: SEMRECON_BIN (default target/release/semrecon, built if missing).
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
  v=$("$bin" demo --seed "$s" --model "$model" --out "$out/demo" --no-mesh-eval 2>&1 \
      | grep -o 'mIoU [0-9.]*%' | head -1 | grep -o '[0-9.]*' || true)
  echo "seed $s mIoU ${v:-?} %"
  [ -n "$v" ] && values+=("$v")
done
printf '%s\n' "${values[@]}" | awk '{s += $1; if (NR == 1 || $1 < lo) lo = $1; if ($1 > hi) hi = $1}
  END {if (NR) printf "mean %.1f %% (min %.1f, max %.1f) over %d seeds\n", s / NR, lo, hi, NR}'
