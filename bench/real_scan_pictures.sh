#!/usr/bin/env bash
# Side-by-side pictures of two models on the real scans of ../shared/data (none of them was
# used in training): the three ScanNet homes (point clouds, z up, floor near z = 0), Replica
# office0 (a mesh, z up, floor at z = -1.12 m) through `semrecon segment`, and the 7-Scenes
# kitchen through `semrecon run` (tracked, fused and labelled live; its mesh is turned to z up
# with the dataset's gravity direction for the picture). For every scan and model it writes
# OUTDIR/NAME_A.png and OUTDIR/NAME_B.png (`semrecon snapshot --classes`, ceilings cut away)
# and prints the share of vertices per class.
#
# Usage: bench/real_scan_pictures.sh MODEL_A MODEL_B OUTDIR
#   MODEL_*: a model file (safetensors), or `shipped` for the default model.
#   ARGS_A / ARGS_B (environment): extra arguments for `semrecon segment` of each model, e.g.
#     ARGS_B="--structure planes" bench/real_scan_pictures.sh shipped shipped /tmp/cmp
#   DATA (environment): the data folder (default ../shared/data next to the repository).
#   SKIP_KITCHEN=1 leaves out the 7-Scenes run (the slowest part, about a minute a model).
# Needs target/release/semrecon (built when missing). Skips with a message, successfully,
# when the data folder is absent.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ $# -ne 3 ]; then
    echo "usage: $0 MODEL_A MODEL_B OUTDIR" >&2
    exit 2
fi
model_a=$1
model_b=$2
out=$3
data=${DATA:-../shared/data}
if [ ! -d "$data" ]; then
    echo "skipping: no real data at $data (see ../shared/data/README.md on a development machine)"
    exit 0
fi
semrecon=target/release/semrecon
[ -x "$semrecon" ] || cargo build --release -p semrecon
mkdir -p "$out"
work="$out/work"
mkdir -p "$work"

model_args() {
    if [ "$1" = shipped ]; then
        echo ""
    else
        echo "--model $1"
    fi
}

# name, input, cut-above height (metres, in the scan's z-up frame)
scans=()
for f in "$data"/scannet-unlabelled/*.ply; do
    [ -e "$f" ] || continue
    # ScanNet homes: floor near z = 0; walls are cut at 1.9 m (few ceilings are scanned).
    scans+=("$(basename "$f" .ply)|$f|1.9")
done
office="$data/replica-office0/office0_mesh.ply"
# Office0: floor at z = -1.12 m, ceiling about 1.5 m; cut 2.8 m above the floor.
[ -e "$office" ] && scans+=("office0|$office|1.7")

for tag in A B; do
    if [ "$tag" = A ]; then model=$model_a; extra=${ARGS_A:-}; else model=$model_b; extra=${ARGS_B:-}; fi
    # shellcheck disable=SC2046
    margs=$(model_args "$model")
    echo "== model $tag: $model ${extra}"
    for entry in "${scans[@]}"; do
        IFS='|' read -r name input cut <<<"$entry"
        labelled="$work/${name}_$tag.ply"
        # shellcheck disable=SC2086
        "$semrecon" segment --input "$input" --out "$labelled" $margs $extra >"$work/${name}_$tag.segment.txt"
        timing=$(grep -E "^labelled" "$work/${name}_$tag.segment.txt" | sed -E 's/.* in ([0-9]+ ms).*/\1/')
        shares=$("$semrecon" snapshot "$labelled" --classes --cut-above "$cut" --out "$out/${name}_$tag.png" \
            | grep '^classes' | sed 's/^classes (share of vertices): //')
        printf '%-14s %s (%s): %s\n' "$name" "$tag" "$timing" "$shares"
    done
    kitchen="$data/7scenes-redkitchen"
    if [ -d "$kitchen" ] && [ -z "${SKIP_KITCHEN:-}" ]; then
        run_dir="$work/kitchen_$tag"
        # shellcheck disable=SC2086
        "$semrecon" run --dataset "7scenes:$kitchen" $margs --out "$run_dir" >"$work/kitchen_$tag.run.txt" 2>&1
        # The run's mesh is in the dataset's world frame; up is minus the gravity direction.
        up=$(awk 'NR<=3 {v[NR] = -$1} END {printf "%s,%s,%s", v[1], v[2], v[3]}' "$kitchen/gravity-direction.txt")
        shares=$("$semrecon" snapshot "$run_dir/mesh.ply" --classes --up "$up" --cut-above 0.3 \
            --out "$out/kitchen_$tag.png" | grep '^classes' | sed 's/^classes (share of vertices): //')
        printf '%-14s %s: %s\n' "kitchen" "$tag" "$shares"
    fi
done
echo "pictures in $out (NAME_A.png, NAME_B.png); labelled files and logs in $work"
