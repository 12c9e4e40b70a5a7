#!/usr/bin/env bash
# Two models side by side on every measure of issue 18 ("real rooms"), in one run:
#   - the real labelled S3DIS fragment (../shared/data; skipped when absent),
#   - generated test rooms (synth:2000000..2000040), the held-out classroom style,
#   - rooms furnished with furniture training never saw (synth-lib:...:held-out; needs
#     Debian's sweethome3d-furniture) and with training furniture (seeds training never drew),
#   - reconstructions of rendered scans (make-scans, 8 full + 8 partial, seeds training never
#     drew), of procedural rooms and of library rooms furnished with held-out furniture,
#   - the demo (seed 1, the default `semrecon demo`), its semantic mIoU.
# Usage: bench/real_rooms_eval.sh MODEL_A MODEL_B [OUT_DIR]   (default target/real_rooms_eval)
# Environment: STRUCTURE (segments, the default of `segment` and `eval seg`; `none` for the
#   network alone), SKIP_DEMO=1 to leave the demo out.
# Writes OUT_DIR/NAME_{a,b}.json (eval seg reports) and OUT_DIR/table.md, and prints the table.
set -euo pipefail
cd "$(dirname "$0")/.."
A=${1:?usage: bench/real_rooms_eval.sh MODEL_A MODEL_B [OUT_DIR]}
B=${2:?usage: bench/real_rooms_eval.sh MODEL_A MODEL_B [OUT_DIR]}
OUT=${3:-target/real_rooms_eval}
SHARED=${SEMRECON_SHARED_DATA:-../shared/data}
STRUCTURE=${STRUCTURE:-segments}
mkdir -p "$OUT"
cargo build --release -p semrecon
bin=./target/release/semrecon
sets=(
  "synth_test synth:2000000..2000040"
  "classroom synth:2000000..2000040:classroom"
)
# The scans are made once per OUT_DIR (make-scans --keep-existing).
"$bin" make-scans --seeds 1000200..1000208 --out "$OUT/scans_test" --keep-existing > /dev/null
"$bin" make-scans --seeds 1000300..1000308 --partial --out "$OUT/scans_test" --keep-existing > /dev/null
sets+=("scans_test ply:$OUT/scans_test")
if [ -d /usr/share/sweethome3d/furniture ] || [ -n "${SEMRECON_FURNITURE_DIR:-}" ]; then
  sets+=("lib_held_out synth-lib:2000000..2000040:held-out" "lib_test synth-lib:2000000..2000040")
  "$bin" make-scans --library --held-out --seeds 1000200..1000208 --out "$OUT/lib_scans_test" --keep-existing > /dev/null
  "$bin" make-scans --library --held-out --seeds 1000300..1000308 --partial --out "$OUT/lib_scans_test" --keep-existing > /dev/null
  sets+=("lib_scans_held_out ply:$OUT/lib_scans_test")
else
  echo "skipping the library rooms: sweethome3d-furniture is not installed (apt-get install sweethome3d-furniture)"
fi
if [ -d "$SHARED/s3dis-area1-conferenceRoom1-partial" ]; then
  sets=("s3dis_fragment s3dis:$SHARED/s3dis-area1-conferenceRoom1-partial" "${sets[@]}")
else
  echo "skipping the S3DIS fragment: $SHARED/s3dis-area1-conferenceRoom1-partial not found"
fi
miou() { python3 -c "import json,sys; r=json.load(open(sys.argv[1])); print('%.1f / %.1f' % (100*r['miou'], 100*r['accuracy']))" "$1"; }
{
  echo "| set (structure $STRUCTURE) | A: $(basename "$A") mIoU / acc % | B: $(basename "$B") mIoU / acc % |"
  echo "|---|---|---|"
  for s in "${sets[@]}"; do
    name=${s%% *}; data=${s#* }
    "$bin" eval seg --structure "$STRUCTURE" --model "$A" --data "$data" --json "$OUT/${name}_a.json" > "$OUT/${name}_a.txt"
    "$bin" eval seg --structure "$STRUCTURE" --model "$B" --data "$data" --json "$OUT/${name}_b.json" > "$OUT/${name}_b.txt"
    echo "| $name | $(miou "$OUT/${name}_a.json") | $(miou "$OUT/${name}_b.json") |"
  done
  [ "${SKIP_DEMO:-0}" = 1 ] && exit 0
  for m in a b; do
    model=$A; [ $m = b ] && model=$B
    SEMRECON_MODEL=$model "$bin" demo --out "$OUT/demo_$m" > "$OUT/demo_$m.txt" 2>&1
  done
  da=$(grep -o 'mIoU [0-9.]*' "$OUT/demo_a.txt" | head -1 || true)
  db=$(grep -o 'mIoU [0-9.]*' "$OUT/demo_b.txt" | head -1 || true)
  echo "| demo seed 1 | $da | $db |"
} | tee "$OUT/table.md"
