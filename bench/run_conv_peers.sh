#!/usr/bin/env bash
# Sparse convolution against its peers, in one go and on the same threads:
#   1. `semrecon bench conv` times our chunked and rulebook kernels on voxelised synthetic
#      rooms and exports the voxel sets and kernel maps it used;
#   2. bench/peers_conv.py times PyTorch gather-mm-scatter (MinkowskiEngine's CPU algorithm)
#      and, when installed, spconv on exactly those voxels, and prints the ratios.
# Usage: bench/run_conv_peers.sh [OUT_DIR]     (default target/conv_peers)
# Environment: THREADS (2), VOXEL (0.05,0.02), CHANNELS (32,64,128), REPEATS (3),
#   PYTHON (bench/.venv/bin/python; needs torch and numpy, optionally spconv: see
#   docs/benchmarks.md), SPCONV (1 to time spconv too, default 1 when importable).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-target/conv_peers}
THREADS=${THREADS:-2}
VOXEL=${VOXEL:-0.05,0.02}
CHANNELS=${CHANNELS:-32,64,128}
REPEATS=${REPEATS:-3}
PYTHON=${PYTHON:-bench/.venv/bin/python}
export RAYON_NUM_THREADS=$THREADS OMP_NUM_THREADS=$THREADS MKL_NUM_THREADS=$THREADS
mkdir -p "$OUT"
if [ -z "${SPCONV:-}" ]; then
  if "$PYTHON" -c "import spconv.pytorch" 2>/dev/null; then SPCONV=1; else SPCONV=0; fi
fi
cargo build --release -p semrecon
lscpu | grep -E "Model name|^CPU\(s\)" || true
./target/release/semrecon bench conv --voxel "$VOXEL" --channels "$CHANNELS" \
  --repeats "$REPEATS" --export "$OUT" --json "$OUT/ours.json"
extra=()
[ "$SPCONV" = 1 ] && extra+=(--spconv)
"$PYTHON" bench/peers_conv.py --export "$OUT" --ours "$OUT/ours.json" --channels "$CHANNELS" \
  --threads "$THREADS" --repeats "$REPEATS" --json "$OUT/peers.json" "${extra[@]}" \
  2> >(grep -v is_fx_tracing >&2) | tee "$OUT/table.md"
