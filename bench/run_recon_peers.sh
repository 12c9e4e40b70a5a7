#!/usr/bin/env bash
# Dense reconstruction against Open3D, in one go and on the same threads:
#   1. crates/recon/examples/peer_bench times our fusion, full-map meshing and tracking on
#      the 7-Scenes frames and writes its JSON;
#   2. bench/peers_recon.py times Open3D's VoxelBlockGrid, extract_triangle_mesh and tensor
#      RGB-D odometry (point-to-plane, hybrid) on the same frames and prints both with ratios.
# Usage: bench/run_recon_peers.sh [OUT_DIR]     (default target/recon_peers)
# Environment: THREADS (2), FRAMES (500), DATA (../shared/data/7scenes-redkitchen),
#   TRUNC (10 voxels), VENV (bench/.venv-open3d: created with open3d-cpu==0.19.0 when absent;
#   0.20.0's ScalableTSDFVolume returns empty meshes). Open3D needs Debian's libusb:
#   `sudo apt install libusb-1.0-0` when `import open3d` fails with libusb-1.0.so.0.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-target/recon_peers}
THREADS=${THREADS:-2}
FRAMES=${FRAMES:-500}
DATA=${DATA:-../shared/data/7scenes-redkitchen}
TRUNC=${TRUNC:-10}
VENV=${VENV:-bench/.venv-open3d}
export RAYON_NUM_THREADS=$THREADS OMP_NUM_THREADS=$THREADS MKL_NUM_THREADS=$THREADS
mkdir -p "$OUT"
if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install -q open3d-cpu==0.19.0
fi
if ! "$VENV/bin/python" -c "import open3d" 2>/dev/null; then
  echo "import open3d failed: install libusb (sudo apt install libusb-1.0-0)" >&2
  exit 1
fi
cargo build --release -p semrecon-recon --example peer_bench
lscpu | grep -E "Model name|^CPU\(s\)" || true
./target/release/examples/peer_bench "7scenes:$DATA" --frames "$FRAMES" --trunc "$TRUNC" > "$OUT/ours.json"
"$VENV/bin/python" bench/peers_recon.py --data "$DATA" --frames "$FRAMES" --trunc "$TRUNC" \
  --ours "$OUT/ours.json" --json "$OUT/peers.json" | tee "$OUT/table.md"
