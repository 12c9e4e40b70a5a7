#!/usr/bin/env python3
"""Reconstruct a dataset folder and write the labelled mesh.

    python examples/python/reconstruct.py 7scenes:../shared/data/7scenes-redkitchen out/
    python examples/python/reconstruct.py synth:1 out/ --frames 60 --voxel 0.02

Writes OUT/mesh.ply (observed colours and a vertex `label` property), OUT/semantic.ply (class
colours) and OUT/trajectory.txt (TUM), as `semrecon run` does, and prints the timings.
Frames go through `Pipeline.push_frame` as numpy arrays, the way a live camera's would.
"""

import argparse
import os
import time

import numpy as np

import semrecon


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", help="KIND:PATH (7scenes:, tum:, redwood:, scannet:, replica:, synth:SEED)")
    ap.add_argument("out", help="output folder")
    ap.add_argument("--frames", type=int, default=None, help="first N frames only")
    ap.add_argument("--voxel", type=float, default=0.005, help="TSDF voxel size, metres")
    ap.add_argument("--semantics", default="incremental", choices=["incremental", "full", "off"])
    args = ap.parse_args()

    ds = semrecon.open_dataset(args.dataset)
    n = len(ds) if args.frames is None else min(args.frames, len(ds))
    print(f"{ds.name}: {n} of {len(ds)} frames, {ds.intrinsics}")
    pipeline = semrecon.Pipeline(ds.intrinsics, voxel_size=args.voxel, semantics=args.semantics)
    os.makedirs(args.out, exist_ok=True)

    start = time.perf_counter()
    lost = 0
    for i in range(n):
        frame = ds[i]
        # A dataset's ground-truth pose (when it has one) only sets where tracking starts.
        result = pipeline.push_frame(frame.depth, frame.color, pose=frame.pose, timestamp=frame.timestamp)
        lost += result.status == "lost"
        if result.keyframe and (i // 10) % 10 == 0:
            print(f"  frame {i}: {result.status}, {len(pipeline.mesh()['vertices'])} vertices so far")
    mesh = pipeline.finish()
    wall = time.perf_counter() - start

    semrecon.write_ply(os.path.join(args.out, "mesh.ply"), mesh)
    semrecon.write_ply(os.path.join(args.out, "semantic.ply"), semrecon.class_colored(mesh))
    pipeline.write_trajectory(os.path.join(args.out, "trajectory.txt"))

    labels = mesh["labels"]
    labelled = labels != semrecon.UNLABELED
    print(f"{len(mesh['vertices'])} vertices, {len(mesh['faces'])} triangles, {lost} frames lost")
    if labelled.any():
        counts = np.bincount(labels[labelled], minlength=len(semrecon.CLASSES))
        top = sorted(zip(counts, semrecon.CLASSES), reverse=True)[:5]
        print("classes: " + ", ".join(f"{name} {c / labelled.sum():.0%}" for c, name in top))
    seconds = n / ds.frame_rate
    print(f"front end {pipeline.front_end_seconds:.2f} s ({seconds / pipeline.front_end_seconds:.2f}x real time), "
          f"wall {wall:.2f} s including decoding the files")
    for stage, t in pipeline.timings().items():
        print(f"  {stage:>18}: median {t['median_ms']:7.2f} ms, p95 {t['p95_ms']:7.2f} ms, {t['count']} times")


if __name__ == "__main__":
    main()
