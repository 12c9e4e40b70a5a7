#!/usr/bin/env python3
"""Benchmarks and torch checks of the Python package (issue 22's targets), beside the CLI
and the Rust kernels. Run by bench/python_package.sh, which builds what it needs.

1. `pipeline`: the Python pipeline on a dataset (7-Scenes) against `semrecon run` on the
   same frames: front-end seconds (the CLI's `pipeline_s`, what its real-time factor
   divides) of both, Python feeding numpy frames through `push_frame` and through
   `Pipeline.run`; the meshes must be identical.
2. `conv`: on a voxel set exported by `semrecon bench conv --export DIR` (the 2 cm room),
   the Rust kernels' own times (`ours.json`), the same kernels through numpy
   (`ConvGeometry`) and through `semrecon.torch` (autograd Function, forward and backward),
   and PyTorch gather-mm-scatter (bench/peers_conv.py) on the same pairs.

Every time is the fastest of --repeats rounds after a warm-up.
"""

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

import semrecon


def best(f, repeats):
    f()
    t = []
    for _ in range(repeats):
        s = time.perf_counter()
        f()
        t.append(time.perf_counter() - s)
    return min(t)


def bench_pipeline(args):
    ds = semrecon.open_dataset(args.dataset)
    n = min(args.frames, len(ds))
    out = os.path.join(args.out, "cli_run")
    subprocess.run([args.cli, "run", "--dataset", args.dataset, "--frames", f"0..{n}", "--out", out],
                   check=True, stdout=subprocess.DEVNULL)
    with open(os.path.join(out, "report.json")) as f:
        cli_s = json.load(f)["pipeline_s"]
    frames = [ds[i] for i in range(n)]
    arrays = [(f.depth, f.color, f.pose, f.timestamp) for f in frames]
    p = semrecon.Pipeline(ds.intrinsics)
    start = time.perf_counter()
    for d, c, pose, t in arrays:
        p.push_frame(d, c, pose=pose, timestamp=t)
    mesh = p.finish()
    wall = time.perf_counter() - start
    q = semrecon.Pipeline(ds.intrinsics)
    q.run(ds, stop=n)
    q_mesh = q.finish()
    cli_mesh = semrecon.read_ply(os.path.join(out, "mesh.ply"))
    same = all(np.array_equal(mesh[k], cli_mesh[k]) and np.array_equal(mesh[k], q_mesh[k])
               for k in ("vertices", "faces", "colors", "labels"))
    print(f"pipeline on {args.dataset}, {n} frames ({n / ds.frame_rate:.1f} s of input):")
    print(f"  CLI front end            {cli_s:7.2f} s")
    print(f"  Python push_frame        {p.front_end_seconds:7.2f} s  ({p.front_end_seconds / cli_s - 1:+.1%}); "
          f"wall of the push_frame loop and finish {wall:.2f} s")
    print(f"  Python Pipeline.run      {q.front_end_seconds:7.2f} s  ({q.front_end_seconds / cli_s - 1:+.1%})")
    print(f"  meshes identical (CLI, push_frame, run): {same}")
    return {"cli_s": cli_s, "push_frame_s": p.front_end_seconds, "push_frame_wall_s": wall,
            "run_s": q.front_end_seconds, "identical": same}


def bench_conv(args):
    import torch

    sys.path.insert(0, os.path.dirname(__file__))
    from peers_conv import TorchGatherMmScatter, load_set

    import semrecon.torch as st
    from semrecon.sparse import ConvGeometry

    torch.set_num_threads(args.threads)
    header = os.path.join(args.export, "conv_20mm.json")
    h, coords_xyzb, in_rows, out_rows = load_set(header)
    coords = np.ascontiguousarray(coords_xyzb[:, [3, 0, 1, 2]].astype(np.int32))
    n, c = len(coords), args.channels
    g = ConvGeometry.submanifold(coords, 3)
    assert g.num_pairs == h["offset_start"][-1], "the map differs from the exported one"
    rng = np.random.default_rng(0)
    x = rng.standard_normal((n, c)).astype(np.float32)
    w = (rng.standard_normal((27, c, c)) / np.sqrt(27 * c)).astype(np.float32)
    dy = rng.standard_normal((n, c)).astype(np.float32)
    r = args.repeats
    rows = {}
    rows["numpy forward"] = best(lambda: g.forward(x, w), r)
    rows["numpy input grad"] = best(lambda: g.backward_input(dy, w), r)
    rows["numpy weight grad"] = best(lambda: g.backward_weight(x, dy), r)
    xt = torch.from_numpy(x).requires_grad_()
    wt = torch.from_numpy(w).requires_grad_()
    dyt = torch.from_numpy(dy)
    rows["torch forward"] = best(lambda: st.sparse_conv(xt.detach(), wt.detach(), g), r)

    def fwd_bwd():
        xt.grad = wt.grad = None
        st.sparse_conv(xt, wt, g).backward(dyt)

    rows["torch forward+backward"] = best(fwd_bwd, r)
    gms = TorchGatherMmScatter(n, h["offset_start"], in_rows, out_rows, c, c)
    y = torch.empty(n, c)
    dx = torch.empty(n, c)
    dw = torch.empty(27, c, c)
    with torch.no_grad():
        rows["torch-gms forward"] = best(lambda: gms.forward(xt.detach(), wt.detach(), y), r)
        rows["torch-gms forward+backward"] = best(
            lambda: (gms.forward(xt.detach(), wt.detach(), y), gms.backward_input(dyt, wt.detach(), dx),
                     gms.backward_weight(xt.detach(), dyt, dw)), r)
    ours = {}
    if args.ours:
        with open(args.ours) as f:
            for row in json.load(f):
                if abs(row["voxel_size"] - 0.02) < 1e-6 and row["c_in"] == c and row["kernel"] == "chunked":
                    ours[row["pass"]] = row["ms"] / 1e3
    print(f"conv on the 2 cm room: {n} voxels, {g.num_pairs} pairs, C = {c}, {args.threads} threads")
    for k, v in rows.items():
        print(f"  {k:28s} {v * 1e3:8.2f} ms")
    if ours:
        fb = sum(ours.get(p, float("nan")) for p in ("forward", "backward_input", "backward_weight"))
        print(f"  Rust kernels (bench conv)  forward {ours.get('forward', float('nan')) * 1e3:.2f} ms, "
              f"forward+backward {fb * 1e3:.2f} ms")
        print(f"  torch wrapper / Rust: forward {rows['torch forward'] / ours['forward']:.3f}, "
              f"forward+backward {rows['torch forward+backward'] / fb:.3f}")
    print(f"  torch-gms / torch wrapper: forward {rows['torch-gms forward'] / rows['torch forward']:.2f}x, "
          f"forward+backward {rows['torch-gms forward+backward'] / rows['torch forward+backward']:.2f}x")
    return {"ms": {k: v * 1e3 for k, v in rows.items()}, "rust_s": ours}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cli", default="target/release/semrecon")
    ap.add_argument("--dataset", default="7scenes:../shared/data/7scenes-redkitchen")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--export", help="folder of `semrecon bench conv --export` (conv benchmark)")
    ap.add_argument("--ours", help="JSON of `semrecon bench conv --json`")
    ap.add_argument("--channels", type=int, default=64)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default="target/python_bench")
    ap.add_argument("--skip-pipeline", action="store_true")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    result = {}
    if not args.skip_pipeline:
        result["pipeline"] = bench_pipeline(args)
    if args.export:
        result["conv"] = bench_conv(args)
    with open(os.path.join(args.out, "python_bench.json"), "w") as f:
        json.dump(result, f, indent=1)


if __name__ == "__main__":
    main()
