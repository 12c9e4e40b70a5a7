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


def best_interleaved(fs, repeats):
    """Fastest of `repeats` rounds of each function, run round-robin so that the load of other
    processes on a shared machine hits all alike."""
    for f in fs.values():
        f()
    t = {k: float("inf") for k in fs}
    for _ in range(repeats):
        for k, f in fs.items():
            s = time.perf_counter()
            f()
            t[k] = min(t[k], time.perf_counter() - s)
    return t


def dataset_up(spec):
    """The up direction `semrecon run` takes from a 7-Scenes style gravity-direction.txt."""
    folder = spec.split(":", 1)[1]
    path = os.path.join(folder, "gravity-direction.txt")
    if not os.path.isfile(path):
        return None
    # In float32 and in glam's order (`-g.normalize()`: g times the reciprocal of its length),
    # so that the direction has the CLI's bits.
    g = np.loadtxt(path, dtype=np.float32).reshape(3)
    length = np.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2], dtype=np.float32)
    up = -(g * (np.float32(1) / length))
    return tuple(float(v) for v in up)


def bench_pipeline(args):
    ds = semrecon.open_dataset(args.dataset)
    n = min(args.frames, len(ds))
    up = dataset_up(args.dataset)
    frames = [ds[i] for i in range(n)]
    arrays = [(f.depth, f.color, f.pose, f.timestamp) for f in frames]
    out = os.path.join(args.out, "cli_run")
    times = {"cli": [], "push_frame": [], "run": []}
    for _ in range(args.pipeline_rounds):
        # Alternated, so that the load of other processes hits all three alike.
        subprocess.run([args.cli, "run", "--dataset", args.dataset, "--frames", f"0..{n}", "--out", out],
                       check=True, stdout=subprocess.DEVNULL)
        with open(os.path.join(out, "report.json")) as f:
            times["cli"].append(json.load(f)["pipeline_s"])
        p = semrecon.Pipeline(ds.intrinsics, up=up)
        for d, c, pose, t in arrays:
            p.push_frame(d, c, pose=pose, timestamp=t)
        mesh = p.finish()
        times["push_frame"].append(p.front_end_seconds)
        q = semrecon.Pipeline(ds.intrinsics, up=up)
        q.run(ds, stop=n)
        q_mesh = q.finish()
        times["run"].append(q.front_end_seconds)
    cli_mesh = semrecon.read_ply(os.path.join(out, "mesh.ply"))
    same = {k: bool(np.array_equal(mesh[k], cli_mesh[k]) and np.array_equal(mesh[k], q_mesh[k]))
            for k in ("vertices", "faces", "colors", "labels")}
    best_s = {k: min(v) for k, v in times.items()}
    print(f"pipeline on {args.dataset}, {n} frames ({n / ds.frame_rate:.1f} s of input), "
          f"front-end seconds, fastest of {args.pipeline_rounds} alternated rounds (all: {times}):")
    print(f"  CLI `semrecon run`       {best_s['cli']:7.2f} s")
    for k in ("push_frame", "run"):
        print(f"  Python {k:<17} {best_s[k]:7.2f} s  ({best_s[k] / best_s['cli'] - 1:+.1%})")
    print(f"  meshes identical (CLI, push_frame, run): {same}")
    return {"times_s": times, "identical": same}


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
    xt = torch.from_numpy(x).requires_grad_()
    wt = torch.from_numpy(w).requires_grad_()
    dyt = torch.from_numpy(dy)
    out = np.empty((n, c), np.float32)

    def fwd_bwd():
        xt.grad = wt.grad = None
        st.sparse_conv(xt, wt, g).backward(dyt)

    gms = TorchGatherMmScatter(n, h["offset_start"], in_rows, out_rows, c, c)
    y = torch.empty(n, c)
    dx = torch.empty(n, c)
    dw = torch.empty(27, c, c)

    def gms_fwd():
        with torch.no_grad():
            gms.forward(xt.detach(), wt.detach(), y)

    def gms_fwd_bwd():
        with torch.no_grad():
            gms.forward(xt.detach(), wt.detach(), y)
            gms.backward_input(dyt, wt.detach(), dx)
            gms.backward_weight(xt.detach(), dyt, dw)

    rows = best_interleaved({
        "numpy forward, out= kept": lambda: g.forward(x, w, out=out),
        "numpy forward, new array": lambda: g.forward(x, w),
        "numpy input grad": lambda: g.backward_input(dy, w),
        "numpy weight grad": lambda: g.backward_weight(x, dy),
        "torch forward": lambda: st.sparse_conv(xt.detach(), wt.detach(), g),
        "torch forward+backward": fwd_bwd,
        "torch-gms forward": gms_fwd,
        "torch-gms forward+backward": gms_fwd_bwd,
    }, r)
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
              f"forward+backward {rows['torch forward+backward'] / fb:.3f} (separate processes)")
    numpy_fb = rows["numpy forward, new array"] + rows["numpy input grad"] + rows["numpy weight grad"]
    print(f"  in this process: torch forward / numpy forward into a kept buffer "
          f"{rows['torch forward'] / rows['numpy forward, out= kept']:.3f}, / numpy forward with a new array "
          f"{rows['torch forward'] / rows['numpy forward, new array']:.3f}; torch forward+backward / the three "
          f"numpy calls {rows['torch forward+backward'] / numpy_fb:.3f}")
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
    ap.add_argument("--pipeline-rounds", type=int, default=2)
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
