#!/usr/bin/env bash
# Runs on a GPU machine without Rust, from the repository root, with the folder that
# bench/gpu_bundle.sh made: sets up Vulkan (the bundle's loader beside NVIDIA's ICD, when
# present), unpacks the binaries (and spconv), then in one go, each step under a timeout:
#   1. the GPU tests (the device binary three times with four threads: session 17 saw it stall);
#   2. `bench net --device gpu` on the whole s20 room: as built, submitting every 256
#      operations (SEMRECON_GPU_SUBMIT_EVERY), with kernel timestamps (SEMRECON_GPU_PROFILE);
#      the 1 m corner (the fixed cost per call) both ways; the `live` network;
#   3. the call-cost example (host CPU of the hierarchy and of whole calls);
#   4. bench/run_gpu_bench.sh with the prebuilt binary (conv kernels, spconv and PyTorch peers);
#   5. `demo --device gpu`.
# Output: OUT/log.txt and OUT/results.tgz (every JSON), two files, so that a remote-run tool
# that returns few files returns them all. QUICK=1 shrinks every size for a dry run on
# lavapipe (correctness of the script only).
# Usage: OUT=DIR bench/gpu_bundle_run.sh [BUNDLE_DIR]   (default .gpu-bundle; OUT default target/gpu_bench)
set -uo pipefail
cd "$(dirname "$0")/.."
B=${1:-.gpu-bundle}
OUT=${OUT:-target/gpu_bench}
mkdir -p "$OUT/results"
exec > >(tee -a "$OUT/log.txt") 2>&1
t0=$SECONDS
stamp() { echo "## [$((SECONDS - t0)) s] $*"; }
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv,noheader
if [ -d "$B/gl" ]; then
  for f in "$B"/gl/*.deb; do dpkg -x "$f" /; done
  ldconfig
fi
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
[ -f "$icd" ] && export VK_DRIVER_FILES=$icd
if [ -z "${XDG_RUNTIME_DIR:-}" ] || [ ! -d "${XDG_RUNTIME_DIR}" ]; then
  XDG_RUNTIME_DIR="$(mktemp -d)"
  chmod 700 "$XDG_RUNTIME_DIR"
  export XDG_RUNTIME_DIR
fi
export WGPU_DEBUG=${WGPU_DEBUG:-0}
command -v vulkaninfo >/dev/null && vulkaninfo --summary 2>&1 | head -40
bin=/tmp/gpu-bundle-bin
python3 - "$B" "$bin" <<'PY'
import lzma, os, sys, tarfile
b, out = sys.argv[1], sys.argv[2]
def unpack(src, dst):
    with lzma.open(src) as f, open(dst, "wb") as g:
        g.write(f.read())
    os.chmod(dst, 0o755)
os.makedirs(os.path.join(out, "tests"), exist_ok=True)
for name in os.listdir(b):
    if name.endswith(".xz") and not name.endswith(".tar.xz"):
        unpack(os.path.join(b, name), os.path.join(out, name[:-3]))
for name in os.listdir(os.path.join(b, "t")):
    unpack(os.path.join(b, "t", name), os.path.join(out, "tests", name[:-3]))
if os.path.exists(os.path.join(b, "site.tar.xz")):
    tarfile.open(os.path.join(b, "site.tar.xz")).extractall("/tmp/gpu-bundle-site")
PY
[ -d /tmp/gpu-bundle-site ] && export PYTHONPATH=/tmp/gpu-bundle-site${PYTHONPATH:+:$PYTHONPATH}
# The network tests find the shipped model through the path the binary was built in.
built_in=$(strings "$bin/tests/gpu" 2>/dev/null | grep -m1 -o '/[^ ]*/crates/net/models/s20.safetensors' || true)
if [ -n "$built_in" ] && [ ! -e "$built_in" ]; then
  d=${built_in%/crates/net/models/s20.safetensors}
  mkdir -p "$(dirname "$d")" && ln -sfn "$PWD" "$d"
fi
stamp "set up"

if [ "${QUICK:-0}" = 1 ]; then
  size=(--crop 0.5) corner=(--crop 0.25) repeats=2 cost_crop=0.25 full_crop=0.5
  conv_env=(VOXEL=0.25 CHANNELS=16 CROP=0.5)
else
  size=() corner=(--crop 1.0) repeats=7 cost_crop=1.0 full_crop=20
  conv_env=()
fi
S=$bin/semrecon

stamp "1. tests"
for t in "$bin"/tests/*; do
  echo "== $t"
  timeout 120 "$t" --test-threads 4 2>&1 | grep -E "test result|FAILED|panicked|skipping"
done
for i in 1 2; do
  echo "== device tests again ($i)"
  timeout 60 "$bin/tests/device" --test-threads 4 2>&1 | grep -E "test result|FAILED"
done

j=0
net() {
  j=$((j + 1))
  stamp "net $j: ${SEMRECON_GPU_SUBMIT_EVERY:+SUBMIT_EVERY=$SEMRECON_GPU_SUBMIT_EVERY }${SEMRECON_GPU_PROFILE:+PROFILE }$*"
  timeout 120 "$S" bench net "$@" --json "$OUT/results/net_$j.json" 2>&1 | grep -v '^\s*$'
}
stamp "2. the network"
net --device gpu --config s20 --repeats "$repeats" "${size[@]}"
SEMRECON_GPU_SUBMIT_EVERY=256 net --device gpu --config s20 --repeats "$repeats" "${size[@]}"
SEMRECON_GPU_PROFILE=1 net --device gpu --config s20 --repeats "$repeats" "${size[@]}"
net --device gpu --config s20 --repeats "$repeats" "${corner[@]}"
SEMRECON_GPU_SUBMIT_EVERY=256 net --device gpu --config s20 --repeats "$repeats" "${corner[@]}"
net --device gpu --config live --repeats "$repeats" "${size[@]}"

stamp "3. call cost"
if [ -x "$bin/gpu_call_cost" ]; then
  timeout 60 "$bin/gpu_call_cost" "$cost_crop" 30
  timeout 60 "$bin/gpu_call_cost" "$full_crop" 10
  SEMRECON_GPU_SUBMIT_EVERY=256 timeout 60 "$bin/gpu_call_cost" "$full_crop" 10
fi

stamp "4. convolution and peers"
env "${conv_env[@]}" BIN="$S" REPEATS=${REPEATS:-3} timeout 240 bench/run_gpu_bench.sh /tmp/gpu-bundle-bench 2>&1 |
  grep -v '^\s*$'
cp /tmp/gpu-bundle-bench/*.json "$OUT/results/" 2>/dev/null

stamp "5. demo"
demo_frames=()
[ "${QUICK:-0}" = 1 ] && demo_frames=(--frames 20)
timeout 90 "$S" demo --device gpu --out /tmp/gpu-bundle-demo "${demo_frames[@]}" 2>&1 | tail -n 30
cp /tmp/gpu-bundle-demo/report.json "$OUT/results/demo_report.json" 2>/dev/null

(cd "$OUT" && tar czf results.tgz results && rm -rf results)
stamp "done"
