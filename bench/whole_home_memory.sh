#!/usr/bin/env bash
# A whole home's memory: runs the generated five-room flat (true poses; semantics off unless asked) under a
# map budget with one or two binaries side by side, and prints a table of the process's
# resident peak (`/usr/bin/time`), the map's and the live mesh's bytes at the end (report.json)
# and whether the written meshes are the same bytes (or differ only in their normals, and by
# how much); writes the table as JSON.
# Usage: [SEMANTICS=incremental] bench/whole_home_memory.sh [DATASET] [BUDGET]   (default: synth-flat:1 700M; the
#   first two minutes are synth-flat:1:120s)
# Environment: SEMRECON_BIN (default target/release/semrecon, built if missing); BASELINE_BIN,
#   a second binary to run beside it (e.g. an older build kept in /tmp); SEMANTICS (off by
#   default; `incremental`, the default of `run`, labels the scan too and adds the semantic map's bytes); OUT (default a
#   temporary folder; the meshes are about 1 GB each for the whole flat).
set -euo pipefail
cd "$(dirname "$0")/.."
dataset=${1:-synth-flat:1}
budget=${2:-700M}
semantics=${SEMANTICS:-off}
bin=${SEMRECON_BIN:-target/release/semrecon}
[ -x "$bin" ] || cargo build --release -p semrecon
command -v /usr/bin/time >/dev/null || { echo "needs /usr/bin/time (apt install time)" >&2; exit 1; }
out=${OUT:-$(mktemp -d)}
mkdir -p "$out"
[ -n "${OUT:-}" ] || trap 'rm -rf "$out"' EXIT
names=(current)
bins=("$bin")
if [ -n "${BASELINE_BIN:-}" ]; then names+=(baseline); bins+=("$BASELINE_BIN"); fi
for i in "${!bins[@]}"; do
  n=${names[$i]}
  echo "running $n: ${bins[$i]} run --dataset $dataset --max-memory $budget" >&2
  /usr/bin/time -v "${bins[$i]}" run --dataset "$dataset" --poses ground-truth --semantics "$semantics" \
    --max-memory "$budget" --out "$out/$n" >"$out/$n.log" 2>"$out/$n.time"
done
python3 - "$out" "$dataset" "$budget" "$semantics" "${names[@]}" <<'PY'
import filecmp, json, os, re, sys
out, dataset, budget, semantics, names = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5:]
rows = []
for n in names:
    peak_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", open(f"{out}/{n}.time").read()).group(1))
    r = json.load(open(f"{out}/{n}/report.json"))
    pm = r.get("process_memory") or {}
    rows.append({
        "binary": n,
        "peak_resident_mb": peak_kb * 1024 / 1e6,
        "map_mb": r["map_memory"]["bytes_in_memory"] / 1e6,
        "spilled_mb": r["map_memory"]["spilled_bytes"] / 1e6,
        "live_mesh_mb": pm["mesh_store_bytes"] / 1e6 if pm else None,
        "semantic_map_mb": pm["semantic_map_bytes"] / 1e6 if pm.get("semantic_map_bytes") is not None else None,
        "miou": r.get("miou"),
        "mesh_vertices": r["mesh_vertices"],
        "realtime_factor": r["realtime_factor"],
    })
def normals_only(a_path, b_path):
    # Binary PLYs with x y z nx ny nz (float) and 4 bytes of colour and label a vertex: the
    # largest angle between normals when everything else is the same bytes, else None.
    import math, struct
    def load(p):
        b = open(p, "rb").read()
        h = b.index(b"end_header\n") + len(b"end_header\n")
        return b, h, int(b[:h].decode().split("element vertex ")[1].split()[0])
    (a, ha, na), (b, hb, nb) = load(a_path), load(b_path)
    if na != nb or a[ha + 28 * na:] != b[hb + 28 * nb:]:
        return None
    worst = 0.0
    for i in range(na):
        x, y = a[ha + 28 * i:ha + 28 * i + 28], b[hb + 28 * i:hb + 28 * i + 28]
        if x[:12] != y[:12] or x[24:] != y[24:]:
            return None
        if x[12:24] != y[12:24]:
            n, m = struct.unpack("<3f", x[12:24]), struct.unpack("<3f", y[12:24])
            c = (n[1] * m[2] - n[2] * m[1], n[2] * m[0] - n[0] * m[2], n[0] * m[1] - n[1] * m[0])
            worst = max(worst, math.degrees(math.asin(min(1.0, math.sqrt(sum(t * t for t in c))))))
    return worst
same = None
normal_angle = None
if len(names) == 2:
    files = [(f"{out}/{names[0]}/{f}", f"{out}/{names[1]}/{f}") for f in ("mesh.ply", "semantic.ply")]
    same = all(filecmp.cmp(a, b, shallow=False) for a, b in files)
    if not same:
        angles = [normals_only(a, b) for a, b in files]
        normal_angle = None if None in angles else max(angles)
print(f"{dataset}, --max-memory {budget}, true poses, semantics {semantics}")
print(f"{'binary':<10} {'peak MB':>9} {'map MB':>8} {'spilled MB':>11} {'live mesh MB':>13} {'semantic MB':>12} {'vertices':>11} {'RTF':>6} {'mIoU':>6}")
na = lambda v, f: "n/a" if v is None else f.format(v)
for x in rows:
    print(f"{x['binary']:<10} {x['peak_resident_mb']:>9.0f} {x['map_mb']:>8.0f} {x['spilled_mb']:>11.0f} "
          f"{na(x['live_mesh_mb'], '{:.0f}'):>13} {na(x['semantic_map_mb'], '{:.0f}'):>12} {x['mesh_vertices']:>11} "
          f"{x['realtime_factor']:>6.2f} {na(x['miou'] and x['miou'] * 100, '{:.1f}'):>6}")
if same:
    print("written meshes: the same bytes")
elif normal_angle is not None:
    print(f"written meshes: the same positions, colours, labels and triangles; normals within {normal_angle:.4f} degrees")
elif same is not None:
    print("written meshes: DIFFERENT")
os.makedirs("bench/results", exist_ok=True)
path = "bench/results/whole_home_memory.json" if semantics == "off" else "bench/results/whole_home_memory_semantics.json"
with open(path + ".tmp", "w") as f:
    json.dump({"dataset": dataset, "budget": budget, "semantics": semantics, "rows": rows, "same_bytes": same,
               "max_normal_angle_degrees": normal_angle}, f, indent=2)
os.replace(path + ".tmp", path)
print(f"wrote {path}")
PY
