#!/usr/bin/env bash
# The whole network against PyTorch, in one go and on the same threads:
#   1. `semrecon bench net` times CBSCN (s20 by default) on a voxelised synthetic room with our
#      chunked and rulebook kernels side by side, and exports the room, the model, the kernel
#      maps and its logits;
#   2. bench/peers_net.py runs the same network with the same weights in PyTorch on exactly
#      those maps, checks that its logits agree with ours, times it and prints the ratios.
# Usage: bench/run_net_peers.sh [OUT_DIR]     (default target/net_peers)
# Environment: THREADS (2), CONFIG (s20), MODEL (a trained safetensors file; default random
#   weights), SEED (0), REPEATS (3), PYTHON (bench/.venv/bin/python; needs torch and numpy:
#   see docs/benchmarks.md).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-target/net_peers}
THREADS=${THREADS:-2}
CONFIG=${CONFIG:-s20}
SEED=${SEED:-0}
REPEATS=${REPEATS:-3}
PYTHON=${PYTHON:-bench/.venv/bin/python}
export RAYON_NUM_THREADS=$THREADS OMP_NUM_THREADS=$THREADS MKL_NUM_THREADS=$THREADS
mkdir -p "$OUT"
cargo build --release -p semrecon
lscpu | grep -E "Model name|^CPU\(s\)" || true
model=()
[ -n "${MODEL:-}" ] && model=(--model "$MODEL")
./target/release/semrecon bench net --config "$CONFIG" --seed "$SEED" --repeats "$REPEATS" \
  --export "$OUT" --json "$OUT/ours.json" "${model[@]}"
"$PYTHON" bench/peers_net.py --export "$OUT" --threads "$THREADS" --repeats "$REPEATS" \
  --json "$OUT/peers.json" | tee "$OUT/table.md"
