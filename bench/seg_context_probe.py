#!/usr/bin/env python3
"""Why does the demo's semantic mesh score lower than whole rooms? This probe separates the
three things a live map lacks, using the files `semrecon demo` writes:

  whole room   the ground-truth mesh, densely sampled, true colours       (what training sees)
  seen part    the same samples cropped to within 5 cm of the demo's mesh (missing context)
  seen, recon colours  the cropped samples coloured from the nearest reconstructed vertex
                       (context and the fused colours)

Each set is labelled by `semrecon segment` and scored against the true class of its sample
(mIoU over every class present in the truth or the prediction, as the demo's report; and
over the classes of the truth alone). The demo's own figure adds the reconstruction's holes
and noise on top of the last row.

Usage: python3 bench/seg_context_probe.py DEMO_OUT [--model FILE] [--semrecon BIN]
Needs: pip install numpy scipy plyfile
"""
import argparse
import os
import subprocess
import sys
import tempfile

import numpy as np
from plyfile import PlyData, PlyElement
from scipy.spatial import cKDTree

NAMES = "ceiling floor wall beam column window door chair table bookcase sofa board clutter".split()


def sample_mesh(gt, per_cm2, rng):
    v = gt["vertex"]
    p = np.stack([v["x"], v["y"], v["z"]], 1).astype(np.float64)
    c = np.stack([v["red"], v["green"], v["blue"]], 1).astype(np.float64)
    f = np.stack(gt["face"]["vertex_indices"])
    lab = np.asarray(gt["face"]["label"])
    a, b, cc = p[f[:, 0]], p[f[:, 1]], p[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, cc - a), axis=1)
    n = np.round(area * 1e4 * per_cm2).astype(int)
    fi = np.repeat(np.arange(len(f)), n)
    u, w = rng.random(len(fi)), rng.random(len(fi))
    flip = u + w > 1
    u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
    pts = a[fi] + (b[fi] - a[fi]) * u[:, None] + (cc[fi] - a[fi]) * w[:, None]
    col = c[f[fi, 0]] * (1 - u - w)[:, None] + c[f[fi, 1]] * u[:, None] + c[f[fi, 2]] * w[:, None]
    return pts, col, lab[fi]


def write(path, p, c, truth):
    arr = np.zeros(len(p), dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"),
                                  ("blue", "u1"), ("truth", "u1")])
    arr["x"], arr["y"], arr["z"] = p.T
    arr["red"], arr["green"], arr["blue"] = np.clip(np.round(c), 0, 255).T
    arr["truth"] = truth
    PlyData([PlyElement.describe(arr, "vertex")], text=False).write(path)


def score(path):
    v = PlyData.read(path)["vertex"]
    t, p = np.asarray(v["truth"]), np.asarray(v["label"])
    ious, gt_ious, per = [], [], []
    for k in range(13):
        inter, union = ((t == k) & (p == k)).sum(), ((t == k) | (p == k)).sum()
        if union == 0:
            continue
        ious.append(inter / union)
        per.append(f"{NAMES[k]} {100 * inter / union:.0f}")
        if (t == k).any():
            gt_ious.append(inter / union)
    return 100 * np.mean(ious), 100 * np.mean(gt_ious), 100 * (t == p).mean(), ", ".join(per)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("demo_out")
    ap.add_argument("--model")
    ap.add_argument("--semrecon", default="target/release/semrecon")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    gt = PlyData.read(os.path.join(args.demo_out, "ground_truth.ply"))
    rc = PlyData.read(os.path.join(args.demo_out, "mesh.ply"))["vertex"]
    recon = np.stack([rc["x"], rc["y"], rc["z"]], 1)
    recon_col = np.stack([rc["red"], rc["green"], rc["blue"]], 1)
    pts, col, lab = sample_mesh(gt, 2.0, rng)
    sub = recon[rng.choice(len(recon), min(len(recon), 400_000), replace=False)]
    seen = cKDTree(sub).query(pts, distance_upper_bound=0.05)[0] < 0.05
    nearest = cKDTree(recon).query(pts[seen])[1]
    sets = [
        ("whole room, true colours", pts, col, lab),
        ("seen part, true colours", pts[seen], col[seen], lab[seen]),
        ("seen part, reconstructed colours", pts[seen], recon_col[nearest], lab[seen]),
    ]
    print(f"{len(pts)} ground-truth samples, {seen.sum()} within 5 cm of the demo's mesh")
    print("| set | mIoU | mIoU over the true classes | accuracy | per class |")
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name, p, c, t in sets:
            src, dst = os.path.join(tmp, "in.ply"), os.path.join(tmp, "out.ply")
            write(src, p, c, t)
            cmd = [args.semrecon, "segment", "--input", src, "--out", dst]
            if args.model:
                cmd += ["--model", args.model]
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            m, mg, acc, per = score(dst)
            print(f"| {name} | {m:.1f} % | {mg:.1f} % | {acc:.1f} % | {per} |")


if __name__ == "__main__":
    sys.exit(main())
