#!/usr/bin/env bash
# The Python package's checks that CI leaves out, and its benchmarks (docs/python.md):
#   1. builds the wheel, installs it and PyTorch into bench/.venv (PyPI's torch: the 3 GB CUDA
#      build, which runs on the CPU), runs the whole pytest suite there, torch gradcheck
#      included, and the CLI comparison test (SEMRECON_CLI);
#   2. runs both examples;
#   3. bench/python_package.py: the Python pipeline against `semrecon run` on 7-Scenes, and
#      semrecon.torch against the Rust kernels and PyTorch gather-mm-scatter on the 2 cm room.
# Usage: bench/python_package.sh [OUT_DIR]   (default target/python_bench)
# Environment: THREADS (2), FRAMES (300), DATA (../shared/data/7scenes-redkitchen),
#   CHANNELS (64), PYTHON (bench/.venv/bin/python).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-target/python_bench}
THREADS=${THREADS:-2}
FRAMES=${FRAMES:-300}
DATA=${DATA:-../shared/data/7scenes-redkitchen}
CHANNELS=${CHANNELS:-64}
PYTHON=${PYTHON:-bench/.venv/bin/python}
export RAYON_NUM_THREADS=$THREADS OMP_NUM_THREADS=$THREADS
mkdir -p "$OUT"
[ -x "$PYTHON" ] || python3 -m venv "$(dirname "$(dirname "$PYTHON")")"
"$PYTHON" -m pip install -q numpy pytest torch maturin
rm -rf "$OUT/wheels"
"$PYTHON" -m maturin build --release -m crates/python/Cargo.toml -o "$OUT/wheels"
"$PYTHON" -m pip install -q --force-reinstall --no-deps "$OUT"/wheels/semrecon-*.whl
cargo build --release -p semrecon
repo="$PWD"
(cd "$OUT" && SEMRECON_CLI="$repo/target/release/semrecon" "$repo/$PYTHON" -m pytest -q "$repo/crates/python/tests")
"$PYTHON" examples/python/train_sparse_unet.py --steps 30
"$PYTHON" examples/python/reconstruct.py synth:1 "$OUT/example" --frames 60 --voxel 0.01
./target/release/semrecon bench conv --voxel 0.02 --channels "$CHANNELS" --repeats 5 \
  --export "$OUT/conv" --json "$OUT/conv/ours.json" > /dev/null
pipeline=()
[ -d "$DATA" ] || pipeline=(--skip-pipeline)
"$PYTHON" bench/python_package.py --cli target/release/semrecon --dataset "7scenes:$DATA" --frames "$FRAMES" \
  --export "$OUT/conv" --ours "$OUT/conv/ours.json" --channels "$CHANNELS" --threads "$THREADS" \
  --out "$OUT" "${pipeline[@]}"
