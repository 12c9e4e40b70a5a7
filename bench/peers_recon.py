#!/usr/bin/env python3
"""Peer benchmark of dense reconstruction: Open3D (tensor API, CPU) on the same 7-Scenes
frames as ours, on the same threads, with ratios.

Stages, each timed per call (wall ms, median over the frames):

- `fusion`: `VoxelBlockGrid` (tsdf, weight, colour; 8^3 blocks at the same voxel size and
  truncation as ours) `compute_unique_block_coordinates` + `integrate` of every frame at its
  reference pose. Ours: chunk selection + integration.
- `mesh_full`: `extract_triangle_mesh()` of the whole grid after the last frame (fastest of
  `--mesh-repeats`). Ours: `extract_mesh`.
- `tracking`: `t.pipelines.odometry.rgbd_odometry_multi_scale` frame to frame (each frame
  against the previous one, its default three levels), `PointToPlane` and `Hybrid`, poses
  chained from the first reference pose, ATE = RMS position error after a rigid (no scale)
  alignment. Ours: frame-to-model tracking (`Tracker::track`, ray-cast included) feeding its
  own map.

Our numbers come from `crates/recon/examples/peer_bench.rs` (`--ours FILE`, its JSON), run
on the same frames just before (bench/run_recon_peers.sh does both). Timings on a shared
machine are noisy: compare ratios from one run.

Usage:
  python bench/peers_recon.py --data DIR [--frames N] [--voxel 0.005] [--trunc 10]
      [--max-depth 5.0] [--ours ours.json] [--json peers.json] [--skip-odometry]
"""

import argparse
import json
import os
import statistics
import sys
import time

import numpy as np
import open3d as o3d
import open3d.core as o3c

FX = FY = 585.0
CX, CY = 320.0, 240.0


def read_pose(path):
    """4x4 camera-to-world pose (7-Scenes `.pose.txt`)."""
    return np.loadtxt(path, dtype=np.float64).reshape(4, 4)


def load_frames(data, n):
    frames = []
    for i in range(n):
        stem = os.path.join(data, f"frame-{i:06d}")
        if not os.path.exists(stem + ".depth.png"):
            break
        depth = o3d.t.io.read_image(stem + ".depth.png")
        # 65535 marks invalid depth in 7-Scenes: zero it (Open3D treats 0 as missing).
        d = depth.as_tensor().numpy().copy()
        d[d == 65535] = 0
        depth = o3d.t.geometry.Image(o3c.Tensor(d))
        color_path = stem + (".color.png" if os.path.exists(stem + ".color.png") else ".color.jpg")
        color = o3d.t.io.read_image(color_path)
        frames.append((depth, color, read_pose(stem + ".pose.txt")))
    return frames


def ate_rmse(est, ref):
    """RMS distance after the rigid alignment (rotation + translation, no scale) of est onto ref."""
    est, ref = np.asarray(est), np.asarray(ref)
    ce, cr = est.mean(0), ref.mean(0)
    h = (est - ce).T @ (ref - cr)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    aligned = (r @ (est - ce).T).T + cr
    return float(np.sqrt(((aligned - ref) ** 2).sum(1).mean()))


def median(v):
    return statistics.median(v) if v else float("nan")


def bench_fusion(frames, k, voxel, trunc, max_depth, mesh_repeats):
    vbg = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"),
        attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=((1), (1), (3)),
        voxel_size=voxel,
        block_resolution=8,
        block_count=200000,
        device=o3c.Device("CPU:0"),
    )
    wall, cpu = [], []
    for depth, color, pose in frames:
        extrinsic = o3c.Tensor(np.linalg.inv(pose))  # world-to-camera
        c0, t0 = time.process_time(), time.perf_counter()
        blocks = vbg.compute_unique_block_coordinates(depth, k, extrinsic, 1000.0, max_depth, trunc)
        vbg.integrate(blocks, depth, color, k, k, extrinsic, 1000.0, max_depth, trunc)
        wall.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
    mesh_wall, mesh_cpu, triangles = [], [], 0
    for _ in range(max(1, mesh_repeats)):
        c0, t0 = time.process_time(), time.perf_counter()
        mesh = vbg.extract_triangle_mesh()
        mesh_wall.append((time.perf_counter() - t0) * 1e3)
        mesh_cpu.append((time.process_time() - c0) * 1e3)
        triangles = int(mesh.triangle.indices.shape[0])
    blocks = int(vbg.hashmap().size())
    return {
        "fusion": {"median_ms": median(wall), "mean_ms": statistics.fmean(wall), "cpu_median_ms": median(cpu)},
        "mesh_full": {"median_ms": min(mesh_wall), "cpu_median_ms": min(mesh_cpu), "triangles": triangles},
        "blocks": blocks,
        # tsdf + weight + rgb as float32: 20 bytes per voxel, 512 voxels per block.
        "bytes_per_block": 512 * 20,
    }


def bench_odometry(frames, k, max_depth, method):
    rgbd = [o3d.t.geometry.RGBDImage(color, depth) for depth, color, _ in frames]
    pose = frames[0][2].copy()
    est, ref = [pose[:3, 3].copy()], [frames[0][2][:3, 3].copy()]
    wall, cpu = [], []
    for i in range(1, len(frames)):
        c0, t0 = time.process_time(), time.perf_counter()
        result = o3d.t.pipelines.odometry.rgbd_odometry_multi_scale(
            rgbd[i], rgbd[i - 1], k, o3c.Tensor(np.eye(4)), 1000.0, max_depth, method=method
        )
        wall.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
        # source = current, target = previous: the result maps current into previous.
        pose = pose @ result.transformation.numpy()
        est.append(pose[:3, 3].copy())
        ref.append(frames[i][2][:3, 3].copy())
    return {"median_ms": median(wall), "cpu_median_ms": median(cpu), "ate_mm": ate_rmse(est, ref) * 1e3}


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, help="7-Scenes sequence folder")
    p.add_argument("--frames", type=int, default=500)
    p.add_argument("--voxel", type=float, default=0.005)
    p.add_argument("--trunc", type=float, default=10.0, help="truncation in voxels")
    p.add_argument("--max-depth", type=float, default=5.0)
    p.add_argument("--mesh-repeats", type=int, default=3)
    p.add_argument("--ours", help="JSON of crates/recon/examples/peer_bench.rs")
    p.add_argument("--json", help="write the peers' numbers here")
    p.add_argument("--skip-odometry", action="store_true")
    a = p.parse_args()

    threads = os.environ.get("OMP_NUM_THREADS", "(unset)")
    frames = load_frames(a.data, a.frames)
    if len(frames) < 3:
        sys.exit(f"{a.data}: fewer than 3 frames")
    k = o3c.Tensor([[FX, 0.0, CX], [0.0, FY, CY], [0.0, 0.0, 1.0]], dtype=o3c.float64)
    peers = {"open3d": o3d.__version__, "frames": len(frames), "omp_threads": threads}
    peers.update(bench_fusion(frames, k, a.voxel, a.trunc, a.max_depth, a.mesh_repeats))
    if not a.skip_odometry:
        for name, method in [
            ("point_to_plane", o3d.t.pipelines.odometry.Method.PointToPlane),
            ("hybrid", o3d.t.pipelines.odometry.Method.Hybrid),
        ]:
            peers["odometry_" + name] = bench_odometry(frames, k, a.max_depth, method)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(peers, f, indent=1)

    ours = None
    if a.ours:
        with open(a.ours) as f:
            ours = json.load(f)
    print(f"\n{len(frames)} frames of {a.data}, voxel {a.voxel * 1e3:g} mm, truncation {a.trunc:g} voxels, "
          f"max depth {a.max_depth:g} m, OMP_NUM_THREADS={threads}"
          + (f", RAYON threads {ours['threads']}" if ours else ""))
    print("\n| stage | Open3D median ms | semrecon median ms | Open3D / semrecon |")
    print("|---|---|---|---|")

    def row(label, theirs, mine):
        ratio = theirs / mine if mine and mine > 0 else float("nan")
        print(f"| {label} | {theirs:.1f} | {mine:.1f} | {ratio:.1f}x |" if ours else f"| {label} | {theirs:.1f} | - | - |")

    ours_or = lambda path: (ours or {}).get(path[0], {}).get(path[1], float("nan"))  # noqa: E731
    row("fusion (blocks + integrate)", peers["fusion"]["median_ms"], ours_or(("fusion", "median_ms")))
    row("fusion, CPU ms", peers["fusion"]["cpu_median_ms"], ours_or(("fusion", "cpu_median_ms")))
    row("full-map meshing", peers["mesh_full"]["median_ms"], ours_or(("mesh_full", "median_ms")))
    for name in ("point_to_plane", "hybrid"):
        key = "odometry_" + name
        if key in peers:
            row(f"tracking vs odometry {name}", peers[key]["median_ms"], ours_or(("tracking", "median_ms")))
    print()
    if ours:
        print(f"semrecon: ATE {ours['ate_mm']:.1f} mm ({ours['lost']} lost), {ours['chunks']} chunks, "
              f"{ours['map_bytes'] / 1e6:.1f} MB ({ours['bytes_per_chunk']} B/chunk), "
              f"{ours['mesh_full']['triangles']} triangles")
    for name in ("point_to_plane", "hybrid"):
        key = "odometry_" + name
        if key in peers:
            print(f"Open3D odometry {name}: ATE {peers[key]['ate_mm']:.1f} mm")
    print(f"Open3D: {peers['blocks']} blocks, {peers['blocks'] * peers['bytes_per_block'] / 1e6:.1f} MB of voxels "
          f"({peers['bytes_per_block']} B/block), {peers['mesh_full']['triangles']} triangles")


if __name__ == "__main__":
    main()
