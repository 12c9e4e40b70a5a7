#!/usr/bin/env bash
# The GPU engine against its peers, on one machine with a GPU, in one go:
#   1. `semrecon bench conv --device gpu` times our chunked and rulebook GPU kernels (forward,
#      input and weight gradient, whole calls) on voxelised synthetic rooms and exports the
#      voxel sets;
#   2. `semrecon bench net --device gpu` (and `--device cpu` for the ratio) times the whole
#      network per room (s20 on a generated office-sized room, the size of an S3DIS room) and
#      exports room, model, maps and logits;
#   3. bench/gpu_peers.py times spconv 2.x (CUDA) on the same voxel sets and PyTorch's
#      gather-mm-scatter CBSCN (CUDA) on the same room, checks both against our results,
#      prints the tables and writes everything to OUT/gpu_bench.json.
# Without PyTorch, CUDA or spconv the peers skip with a message and our rows still print (so
# the script also runs on lavapipe, a CPU software Vulkan driver: correctness only, with tiny
# sizes, e.g. VOXEL=0.25 CHANNELS=16 REPEATS=1 CROP=1.0).
# Usage: bench/run_gpu_bench.sh [OUT_DIR]     (default target/gpu_bench)
# Environment: VOXEL (0.05,0.02), CHANNELS (32,64,128), REPEATS (5), CONFIG (s20), CROP (metres
#   of the room's corner for `bench net`; default the whole room), BIN (a semrecon binary
#   built with `--features gpu` elsewhere, for a machine without cargo: no build), PYTHON (bench/.venv/bin/python
#   when it exists, else python3; needs numpy, optionally torch with CUDA and spconv-cu12x).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-target/gpu_bench}
VOXEL=${VOXEL:-0.05,0.02}
CHANNELS=${CHANNELS:-32,64,128}
REPEATS=${REPEATS:-5}
CONFIG=${CONFIG:-s20}
CROP=${CROP:-}
if [ -z "${PYTHON:-}" ]; then
  if [ -x bench/.venv/bin/python ]; then PYTHON=bench/.venv/bin/python; else PYTHON=python3; fi
fi
# Mesa (lavapipe) wants a private runtime folder; Debian's old validation layer stays off.
if [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "${XDG_RUNTIME_DIR}" ]; then
  XDG_RUNTIME_DIR="$(mktemp -d)"
  chmod 700 "$XDG_RUNTIME_DIR"
  export XDG_RUNTIME_DIR
fi
export WGPU_DEBUG=${WGPU_DEBUG:-0}
mkdir -p "$OUT"
if [ -n "${BIN:-}" ]; then
  bin=$BIN
else
  cargo build --release -p semrecon --features gpu
  bin=./target/release/semrecon
fi
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv || true
crop=()
[ -n "$CROP" ] && crop=(--crop "$CROP")
"$bin" bench conv --device gpu --voxel "$VOXEL" --channels "$CHANNELS" --repeats "$REPEATS" \
  --export "$OUT/conv" --json "$OUT/ours_conv.json"
"$bin" bench net --device gpu --config "$CONFIG" --repeats "$REPEATS" "${crop[@]}" \
  --export "$OUT/net" --json "$OUT/ours_net.json"
"$bin" bench net --device cpu --config "$CONFIG" --repeats "$REPEATS" "${crop[@]}" \
  --json "$OUT/ours_net_cpu.json"
"$PYTHON" bench/gpu_peers.py --ours-conv "$OUT/ours_conv.json" --conv-export "$OUT/conv" \
  --ours-net "$OUT/ours_net.json" --ours-net-cpu "$OUT/ours_net_cpu.json" --net-export "$OUT/net" \
  --repeats "$REPEATS" --json "$OUT/gpu_bench.json"
