#!/usr/bin/env python3
"""Which trajectory agrees better with the depth images: ours or the dataset's reference?

ATE against the 7-Scenes reference poses assumes the reference is right. This script asks
the depth images instead. For frame pairs (k, k + GAP) it moves frame k+GAP's depth points
into frame k's camera with each trajectory's relative pose and measures

  rmse     RMS distance of the points that find a partner within 2 cm (Open3D's
           evaluate_registration), lower = the pose lines the two surfaces up better;
  icp_mm   how far an independent Open3D point-to-plane ICP of the pair, started from the
           reference's relative pose, ends up from that trajectory's relative pose.

Trajectories are TUM files (`timestamp tx ty tz qx qy qz qw`, as `semrecon run` writes
them; timestamps at 30 fps give the frame index) or, with --reference, the dataset's
frame-NNNNNN.pose.txt files. Intrinsics are the dataset README's (585, centre 320, 240).

Usage:
  python3 bench/pose_depth_agreement.py --data ../shared/data/7scenes-redkitchen \
      --est OUT/trajectory.txt [--est OTHER.txt ...] [--gap 30] [--every 20] [--frames 500]
Needs: pip install open3d-cpu==0.19.0 numpy (Debian libusb-1.0-0), as bench/peers_recon.py.
"""
import argparse
import os
import sys

import numpy as np
import open3d as o3d


def rotation_from_quaternion(x, y, z, w):
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def read_tum(path, fps=30.0):
    """Frame index -> world_from_camera (4x4)."""
    poses = {}
    with open(path) as f:
        for line in f:
            if line.startswith("#") or not line.strip():
                continue
            v = [float(x) for x in line.split()]
            if len(v) != 8:
                sys.exit(f"{path}: expected 8 numbers per line, got {len(v)}: {line.strip()}")
            m = np.eye(4)
            m[:3, :3] = rotation_from_quaternion(*v[4:8])
            m[:3, 3] = v[1:4]
            poses[int(round(v[0] * fps))] = m
    return poses


def read_reference(data, frames):
    poses = {}
    for i in range(frames):
        p = os.path.join(data, f"frame-{i:06d}.pose.txt")
        if os.path.exists(p):
            poses[i] = np.loadtxt(p)
    return poses


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="7-Scenes sequence folder (frame-NNNNNN.depth.png, .pose.txt)")
    ap.add_argument("--est", action="append", default=[], help="TUM trajectory to judge (repeatable)")
    ap.add_argument("--gap", type=int, default=30, help="frames between the two of a pair")
    ap.add_argument("--every", type=int, default=20, help="first frames of the pairs are this far apart")
    ap.add_argument("--frames", type=int, default=500)
    args = ap.parse_args()

    trajectories = {"reference": read_reference(args.data, args.frames)}
    for p in args.est:
        trajectories[os.path.basename(os.path.dirname(os.path.abspath(p))) or p] = read_tum(p)
    intrinsic = o3d.camera.PinholeCameraIntrinsic(640, 480, 585.0, 585.0, 320.0, 240.0)
    cache = {}

    def cloud(i):
        if i not in cache:
            depth = o3d.io.read_image(os.path.join(args.data, f"frame-{i:06d}.depth.png"))
            pc = o3d.geometry.PointCloud.create_from_depth_image(depth, intrinsic, depth_scale=1000.0,
                                                                depth_trunc=3.5, stride=2)
            pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.03, max_nn=30))
            cache[i] = pc
        return cache[i]

    names = list(trajectories)
    rows = []
    for k in range(0, args.frames - args.gap, args.every):
        j = k + args.gap
        if not all(k in t and j in t for t in trajectories.values()):
            continue
        a, b = cloud(k), cloud(j)
        relative = {n: np.linalg.inv(t[k]) @ t[j] for n, t in trajectories.items()}
        icp = o3d.pipelines.registration.registration_icp(
            b, a, 0.02, relative["reference"], o3d.pipelines.registration.TransformationEstimationPointToPlane())
        row = {}
        for n in names:
            ev = o3d.pipelines.registration.evaluate_registration(b, a, 0.02, relative[n])
            off = np.linalg.inv(icp.transformation) @ relative[n]
            row[n] = (ev.inlier_rmse * 1e3, np.linalg.norm(off[:3, 3]) * 1e3)
        rows.append(row)
        print(f"{k:4d}-{j:4d}  " + "  ".join(f"{n}: rmse {r[0]:.2f} mm, icp {r[1]:.1f} mm" for n, r in row.items()),
              flush=True)
    if not rows:
        sys.exit("no frame pair has a pose in every trajectory")
    print(f"\n{len(rows)} pairs {args.gap} frames apart")
    print("| trajectory | mean rmse (mm) | mean distance from ICP (mm) | pairs with the lowest rmse |")
    print("|---|---|---|---|")
    best = [min(names, key=lambda n: r[n][0]) for r in rows]
    for n in names:
        print(f"| {n} | {np.mean([r[n][0] for r in rows]):.2f} | {np.mean([r[n][1] for r in rows]):.1f} | "
              f"{best.count(n)} |")


if __name__ == "__main__":
    sys.exit(main())
