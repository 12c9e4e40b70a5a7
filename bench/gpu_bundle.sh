#!/usr/bin/env bash
# Packs what a GPU machine without Rust needs to run the GPU tests and benchmarks
# (bench/gpu_bundle_run.sh there) into one folder, small enough for a remote-run tool that
# carries a few tens of MB:
#   - the release binary, the GPU test binaries and the call-cost example (`--features gpu`),
#     stripped and xz-compressed;
#   - with SPCONV=1, spconv 2.3.8 for CUDA 12.6 and its pure-Python dependencies for CPython
#     3.12, unpacked into one xz tarball; NVIDIA's 58 MB NVRTC library inside it is replaced
#     by a stub (spconv's precompiled convolution kernels never call it), which keeps the
#     tarball near 23 MB (its NVRTC builtins and CUDA headers, which only NVRTC reads, go too);
#   - with GL=1, Debian's libvulkan1 and glvnd libraries (a machine with NVIDIA's driver but
#     no Vulkan loader needs them beside the driver's ICD).
# Usage: bench/gpu_bundle.sh [OUT_DIR]   (default .gpu-bundle; add it to .git/info/exclude)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-.gpu-bundle}
mkdir -p "$OUT/t"
# Stripped, then compressed: the remote-run tool carries the repository too (about 27 MB).
pack() { strip -o "$OUT/.stripped" "$1" && xz -"$3" -T0 -c "$OUT/.stripped" > "$2" && rm "$OUT/.stripped"; }
cargo build --release -p semrecon --features gpu
pack target/release/semrecon "$OUT/semrecon.xz" 9e
cargo build --release -p semrecon-net --features gpu --example gpu_call_cost
pack target/release/examples/gpu_call_cost "$OUT/gpu_call_cost.xz" 6
# The test binaries' paths, from cargo's own listing.
cargo test --release -p semrecon-gpu -p semrecon-net --features semrecon-gpu/gpu,semrecon-net/gpu --no-run 2>&1 |
  sed -n 's/.*Executable tests\/\(device\|gpu\)[/a-z]*\.rs (\(.*\))/\1 \2/p' |
  while read -r name path; do pack "$path" "$OUT/t/$name.xz" 6; done
if [ "${GL:-0}" = 1 ]; then
  mkdir -p "$OUT/gl" /tmp/gpu-bundle-apt/partial
  o=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/gpu-bundle-apt)
  apt-get "${o[@]}" update -qq
  (cd "$OUT/gl" && apt-get "${o[@]}" download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
fi
if [ "${SPCONV:-0}" = 1 ]; then
  w=$(mktemp -d)
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
    --platform any -d "$w" spconv-cu126==2.3.8 'cumm-cu126<0.8.0,>=0.7.11' pccm ccimport fire lark termcolor
  mkdir -p "$w/site"
  for f in "$w"/*.whl; do python3 -m zipfile -e "$f" "$w/site"; done
  # The stub NVRTC: the same soname and symbol version, every entry point an error.
  cat > "$w/nvrtc_stub.c" <<'C'
static const char *msg = "nvrtc is not part of this benchmark bundle";
const char *nvrtcGetErrorString(int r) { (void)r; return msg; }
#define STUB(name) int name(void) { return 7; }
STUB(nvrtcAddNameExpression) STUB(nvrtcCompileProgram) STUB(nvrtcCreateProgram)
STUB(nvrtcDestroyProgram) STUB(nvrtcGetCUBIN) STUB(nvrtcGetCUBINSize) STUB(nvrtcGetLoweredName)
STUB(nvrtcGetPTX) STUB(nvrtcGetPTXSize) STUB(nvrtcGetProgramLog) STUB(nvrtcGetProgramLogSize)
STUB(nvrtcVersion)
C
  echo 'libnvrtc.so.12 { global: nvrtc*; local: *; };' > "$w/nvrtc.map"
  real=$(ls "$w"/site/cumm_cu126.libs/libnvrtc-*.so.* | grep -v builtins)
  gcc -shared -fPIC -O1 -o "$real" "$w/nvrtc_stub.c" -Wl,--version-script="$w/nvrtc.map" -Wl,-soname,"$(basename "$real")"
  # cumm links NVRTC's builtins library without calling it (only NVRTC does): an empty one.
  builtins=$(ls "$w"/site/cumm_cu126.libs/libnvrtc-builtins-*.so.*)
  echo 'int semrecon_builtins_stub;' > "$w/builtins_stub.c"
  gcc -shared -fPIC -O1 -o "$builtins" "$w/builtins_stub.c" -Wl,-soname,"$(basename "$builtins")"
  rm -rf "$w/site/cumm/include"
  tar -C "$w/site" -cf - . | xz -9e -T0 > "$OUT/site.tar.xz"
  rm -rf "$w"
fi
du -sh "$OUT"
