#!/usr/bin/env bash
# Runs on a GPU machine without Rust, from the repository root, with the folder that
# bench/gpu_bundle.sh made: sets up Vulkan (the bundle's loader beside NVIDIA's ICD, when
# present), unpacks the binaries (and spconv), runs the GPU tests and bench/run_gpu_bench.sh's
# benchmarks with the prebuilt binary. Output goes to OUT (default target/gpu_bench).
# Usage: bench/gpu_bundle_run.sh [BUNDLE_DIR]   (default .gpu-bundle)
set -uo pipefail
cd "$(dirname "$0")/.."
B=${1:-.gpu-bundle}
OUT=${OUT:-target/gpu_bench}
mkdir -p "$OUT"
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
if [ -d "$B/gl" ]; then
  for f in "$B"/gl/*.deb; do dpkg -x "$f" /; done
  ldconfig
fi
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
[ -f "$icd" ] && export VK_DRIVER_FILES=$icd
python3 - "$B" <<'PY'
import lzma, os, sys, tarfile
b = sys.argv[1]
def unpack(src, dst):
    with lzma.open(src) as f, open(dst, "wb") as g:
        g.write(f.read())
    os.chmod(dst, 0o755)
os.makedirs("/tmp/gpu-bundle-bin/tests", exist_ok=True)
unpack(os.path.join(b, "semrecon.xz"), "/tmp/gpu-bundle-bin/semrecon")
for name in os.listdir(os.path.join(b, "t")):
    unpack(os.path.join(b, "t", name), "/tmp/gpu-bundle-bin/tests/" + name[:-3])
if os.path.exists(os.path.join(b, "site.tar.xz")):
    tarfile.open(os.path.join(b, "site.tar.xz")).extractall("/tmp/gpu-bundle-site")
PY
[ -d /tmp/gpu-bundle-site ] && export PYTHONPATH=/tmp/gpu-bundle-site${PYTHONPATH:+:$PYTHONPATH}
# The network tests find the shipped model through the path the binary was built in.
built_in=$(strings /tmp/gpu-bundle-bin/tests/gpu 2>/dev/null | grep -m1 -o '/[^ ]*/crates/net/models/s20.safetensors' || true)
if [ -n "$built_in" ] && [ ! -e "$built_in" ]; then
  mkdir -p "${built_in%/crates/net/models/s20.safetensors}" 2>/dev/null &&
    rmdir "${built_in%/crates/net/models/s20.safetensors}" && ln -sfn "$PWD" "${built_in%/crates/net/models/s20.safetensors}"
fi
for t in /tmp/gpu-bundle-bin/tests/*; do echo "== $t"; timeout 120 "$t" --test-threads 4 2>&1 | grep -E "test result|FAILED|panicked|skipping"; done
BIN=/tmp/gpu-bundle-bin/semrecon REPEATS=${REPEATS:-3} bench/run_gpu_bench.sh "$OUT"
