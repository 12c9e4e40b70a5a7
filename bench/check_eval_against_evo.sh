#!/usr/bin/env bash
# Checks `semrecon eval traj` against evo (https://github.com/MichaelGrupp/evo), the
# reference implementation of the TUM RGB-D trajectory metrics:
#   ATE: evo_ape tum GT EST --align            (SE(3) Umeyama alignment, no scale)
#   RPE: evo_rpe tum GT EST --delta 30 --delta_unit f --all_pairs
#        (evo has no time unit for delta: 30 frames of the 30 Hz synthetic scan = 1 s,
#        every pose starting a pair, as `semrecon eval traj` pairs them)
# on a synthetic ground truth (`semrecon synth`) and a perturbed copy of it (random-walk drift,
# jitter, rotation noise, then a global rigid motion that the alignment must undo).
#
# Usage: bench/check_eval_against_evo.sh [FRAMES]   (needs target/release/semrecon; installs
# evo into bench/.venv on first use). Exits non-zero when any number differs by more than
# 1e-4 relative.
set -euo pipefail
cd "$(dirname "$0")/.."
frames="${1:-200}"
venv=bench/.venv
if [ ! -x "$venv/bin/evo_ape" ]; then
    python3 -m venv "$venv"
    "$venv/bin/pip" install --quiet evo
fi
semrecon=target/release/semrecon
[ -x "$semrecon" ] || cargo build --release -p semrecon
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

"$semrecon" synth --out "$work/scan" --frames "$frames" --size 64x48 > /dev/null
gt="$work/scan/groundtruth.txt"
est="$work/est.txt"
"$venv/bin/python" - "$gt" "$est" <<'EOF'
import sys
import numpy as np
from scipy.spatial.transform import Rotation as R

gt, est = sys.argv[1], sys.argv[2]
data = np.loadtxt(gt)
rng = np.random.default_rng(7)
t, p, q = data[:, 0], data[:, 1:4], data[:, 4:8]
drift = np.cumsum(rng.normal(0, 0.002, p.shape), axis=0)
p = p + drift + rng.normal(0, 0.003, p.shape)
rot = R.from_quat(q) * R.from_rotvec(rng.normal(0, 0.01, p.shape))
world = R.from_euler("zyx", [0.7, -0.2, 0.1])
p = world.apply(p) + np.array([1.0, -2.0, 0.5])
rot = world * rot
np.savetxt(est, np.column_stack([t, p, rot.as_quat()]), fmt="%.9f")
EOF

stat() { # zip stat-name
    "$venv/bin/python" -c "import json,sys,zipfile; print(json.load(zipfile.ZipFile(sys.argv[1]).open('stats.json'))[sys.argv[2]])" "$1" "$2"
}
"$venv/bin/evo_ape" tum "$gt" "$est" --align --save_results "$work/ape.zip" > /dev/null
"$venv/bin/evo_rpe" tum "$gt" "$est" --delta 30 --delta_unit f --all_pairs --save_results "$work/rpe_t.zip" > /dev/null
"$venv/bin/evo_rpe" tum "$gt" "$est" --delta 30 --delta_unit f --all_pairs --pose_relation angle_deg --save_results "$work/rpe_r.zip" > /dev/null
"$semrecon" eval traj --gt "$gt" --est "$est" --json > "$work/ours.json"

"$venv/bin/python" - "$work/ours.json" \
    "$(stat "$work/ape.zip" rmse)" "$(stat "$work/ape.zip" mean)" "$(stat "$work/ape.zip" median)" \
    "$(stat "$work/ape.zip" max)" "$(stat "$work/rpe_t.zip" rmse)" "$(stat "$work/rpe_r.zip" rmse)" <<'EOF'
import json, sys
ours = json.load(open(sys.argv[1]))
evo = [float(v) for v in sys.argv[2:]]
keys = ["ate_rmse_m", "ate_mean_m", "ate_median_m", "ate_max_m", "rpe_trans_m_per_s", "rpe_rot_deg_per_s"]
worst = 0.0
print(f"{'metric':<20} {'semrecon':>14} {'evo':>14} {'rel. diff':>10}")
for k, e in zip(keys, evo):
    o = ours[k]
    rel = abs(o - e) / max(abs(e), 1e-12)
    worst = max(worst, rel)
    print(f"{k:<20} {o:>14.9f} {e:>14.9f} {rel:>10.2e}")
print(f"pairs: ATE {ours['pairs']}, RPE {ours['rpe_pairs']}; worst relative difference {worst:.2e}")
sys.exit(0 if worst <= 1e-4 else 1)
EOF
