#!/usr/bin/env python3
"""Peer benchmark of the sparse convolution engine: the same voxel sets, the same threads.

Loads the voxel sets and K = 3 submanifold kernel maps written by
`semrecon bench conv --export DIR` and times, for C_in = C_out = C:

- `torch-gms`: PyTorch gather-mm-scatter on BLAS, MinkowskiEngine's CPU algorithm: per kernel
  offset `index_select` the input rows, `mm` with W_k, `index_add_` into the outputs (input
  gradient: the same with swapped lists and W_k^T; weight gradient: gathered x^T . gathered
  dy). It runs on exactly our pairs, with preallocated buffers, and the centre offset as a
  plain `addmm` (no gather): a generous version of the algorithm.
- `spconv` (optional, `--spconv`): spconv 2.x `SubMConv3d` on the CPU, its own kernel map
  (built once in a warm-up, cached through `indice_key`, not timed); its backward computes
  both gradients in one call, reported as `backward` (compare with our input + weight
  gradients together). Its forward and backward are checked against torch-gms on our pairs
  before timing (weights `[c_out, kz, ky, kx, c_in]`).

Every measurement is the fastest of `--repeats` rounds after a warm-up, measurements
interleaved round-robin like ours (the machine is shared: compare ratios). With `--ours
FILE` (the JSON of `semrecon bench conv --json FILE`) it prints our chunked / rulebook rows
beside the peers with ratios. GFLOP/s count useful work: 2 x pairs x C_in x C_out.

Usage:
  bench/.venv/bin/python bench/peers_conv.py --export DIR [--ours ours.json] \
      [--channels 32,64,128] [--threads 2] [--repeats 3] [--spconv] [--json peers.json]
"""

import argparse
import glob
import json
import os
import sys
import time

import numpy as np
import torch


def load_set(header_path):
    """Coordinates [n, 4] (x, y, z, batch) and the kernel map of one exported voxel set."""
    with open(header_path) as f:
        h = json.load(f)
    d = os.path.dirname(header_path)
    coords = np.fromfile(os.path.join(d, h["coords"]), dtype="<i4").reshape(-1, 4)
    # int32 indices: torch 2.15's CPU index_add_ is several times faster with them than with
    # int64 (measured here: 13-22 ms against 156 ms for 85k rows of 32 channels).
    in_rows = np.fromfile(os.path.join(d, h["in_rows"]), dtype="<u4").astype(np.int32)
    out_rows = np.fromfile(os.path.join(d, h["out_rows"]), dtype="<u4").astype(np.int32)
    if len(coords) != h["n"] or len(in_rows) != h["offset_start"][-1]:
        sys.exit(f"{header_path}: arrays do not match the header")
    return h, coords, in_rows, out_rows


class TorchGatherMmScatter:
    """Per-offset gather, BLAS mm, scatter-add (MinkowskiEngine's CPU convolution)."""

    def __init__(self, n, offset_start, in_rows, out_rows, c_in, c_out):
        kv = len(offset_start) - 1
        self.centre = kv // 2
        self.n, self.c_in, self.c_out = n, c_in, c_out
        ins = torch.from_numpy(in_rows)
        outs = torch.from_numpy(out_rows)
        self.offsets = [
            (k, ins[offset_start[k]:offset_start[k + 1]], outs[offset_start[k]:offset_start[k + 1]])
            for k in range(kv)
            if offset_start[k + 1] > offset_start[k]
        ]
        self.pairs = len(in_rows)
        p = max((len(i) for k, i, _ in self.offsets if k != self.centre), default=0)
        c = max(c_in, c_out)
        self.buf_a = torch.empty(p * c)
        self.buf_b = torch.empty(p * c)

    def forward(self, x, w, y):
        y.zero_()
        for k, ins, outs in self.offsets:
            if k == self.centre:
                y.addmm_(x, w[k])
                continue
            p = len(ins)
            g = self.buf_a[: p * self.c_in].view(p, self.c_in)
            torch.index_select(x, 0, ins, out=g)
            m = self.buf_b[: p * self.c_out].view(p, self.c_out)
            torch.mm(g, w[k], out=m)
            y.index_add_(0, outs, m)

    def backward_input(self, dy, w, dx):
        dx.zero_()
        for k, ins, outs in self.offsets:
            if k == self.centre:
                dx.addmm_(dy, w[k].t())
                continue
            p = len(ins)
            g = self.buf_a[: p * self.c_out].view(p, self.c_out)
            torch.index_select(dy, 0, outs, out=g)
            m = self.buf_b[: p * self.c_in].view(p, self.c_in)
            torch.mm(g, w[k].t(), out=m)
            dx.index_add_(0, ins, m)

    def backward_weight(self, x, dy, dw):
        dw.zero_()
        for k, ins, outs in self.offsets:
            if k == self.centre:
                torch.mm(x.t(), dy, out=dw[k])
                continue
            p = len(ins)
            a = self.buf_a[: p * self.c_in].view(p, self.c_in)
            b = self.buf_b[: p * self.c_out].view(p, self.c_out)
            torch.index_select(x, 0, ins, out=a)
            torch.index_select(dy, 0, outs, out=b)
            torch.mm(a.t(), b, out=dw[k])


def check_torch_gms(coords, offset_start, in_rows, out_rows):
    """The gather-mm-scatter result equals a direct evaluation on a few outputs (so that the
    timed code computes the convolution it claims to)."""
    c = 4
    g = torch.Generator().manual_seed(0)
    n = len(coords)
    x = torch.rand(n, c, generator=g) - 0.5
    w = torch.rand(len(offset_start) - 1, c, c, generator=g) - 0.5
    y = torch.empty(n, c)
    TorchGatherMmScatter(n, offset_start, in_rows, out_rows, c, c).forward(x, w, y)
    index = {tuple(p): i for i, p in enumerate(coords.tolist())}
    for o in range(0, n, max(1, n // 50)):
        u = coords[o]
        want = torch.zeros(c, dtype=torch.float64)
        k = 0
        for dz in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    i = index.get((u[0] + dx, u[1] + dy, u[2] + dz, u[3]))
                    if i is not None:
                        want += x[i].double() @ w[k].double()
                    k += 1
        if not torch.allclose(y[o].double(), want, atol=1e-4):
            sys.exit(f"torch gather-mm-scatter disagrees with the direct sum at output {o}")


def spconv_runner(coords, c, gms):
    """Closures timing spconv's SubMConv3d forward and backward on `coords`, or None.
    `gms` (a TorchGatherMmScatter on our pairs) checks spconv's results first."""
    try:
        import spconv.pytorch as spconv
        import spconv.pytorch.ops as spconv_ops
    except Exception as e:  # noqa: BLE001 - any import failure means "not available"
        print(f"spconv not available: {e}", file=sys.stderr)
        return None
    if not torch.cuda.is_available():
        # spconv 2.3.8's backward asks torch for the current CUDA stream even for CPU
        # tensors, which fails without a GPU; the CPU code ignores the stream, so 0 does.
        spconv_ops.get_current_stream = lambda: 0
    # spconv wants (batch, z, y, x) int32 rows, non-negative, and C-contiguous: a strided
    # array is read as if it were contiguous (silently wrong kernel maps).
    lo = coords[:, :3].min(axis=0)
    zyx = (coords[:, [2, 1, 0]] - lo[[2, 1, 0]]).astype(np.int32)
    idx = np.ascontiguousarray(np.concatenate([coords[:, 3:4].astype(np.int32), zyx], axis=1))
    shape = (zyx.max(axis=0) + 1).tolist()
    batch = int(coords[:, 3].max()) + 1
    g = torch.Generator().manual_seed(1)
    feats = torch.rand(len(coords), c, generator=g) - 0.5
    dy = torch.rand(len(coords), c, generator=g) - 0.5
    conv = spconv.SubMConv3d(c, c, 3, bias=False, indice_key="subm")
    x = spconv.SparseConvTensor(feats, torch.from_numpy(idx), shape, batch)
    w = lambda: conv.weight.detach().reshape(c, 27, c).permute(1, 2, 0).contiguous()

    def check():
        """Max relative error of spconv's forward and input gradient against gms."""
        f = feats.clone().requires_grad_(True)
        out = conv(x.replace_feature(f))
        out.features.backward(dy)
        want_y, want_dx = torch.empty(len(coords), c), torch.empty(len(coords), c)
        with torch.no_grad():
            gms.forward(feats, w(), want_y)
            gms.backward_input(dy, w(), want_dx)
        return max(
            (got - want).abs().max().item() / max(want.abs().max().item(), 1e-6)
            for got, want in ((out.features.detach(), want_y), (f.grad, want_dx))
        )

    # The first call builds and caches the kernel map in x.indice_dict. spconv 2.3.8's CPU
    # path gives wrong results now and then with more than one thread (measured here: up to
    # 20 % off on 1 call in 2, never with one thread): then spconv is timed on one thread.
    threads = torch.get_num_threads()
    errs = [check() for _ in range(3)]
    if max(errs) > 1e-4:
        print(f"spconv C={c}: wrong results on {threads} threads (max relative error "
              f"{max(errs):.2e}); timing it on 1 thread", file=sys.stderr, flush=True)
        threads = 1
    gms_threads = torch.get_num_threads()
    torch.set_num_threads(threads)
    errs = [check() for _ in range(3)]
    torch.set_num_threads(gms_threads)
    if max(errs) > 1e-4:
        sys.exit(f"spconv disagrees with gather-mm-scatter on our pairs ({max(errs):.2e})")

    def on_threads(f):
        def run():
            torch.set_num_threads(threads)
            try:
                return f()
            finally:
                torch.set_num_threads(gms_threads)
        return run

    def forward():
        with torch.no_grad():
            return conv(x).features[0, 0].item()

    def backward():
        f = feats.clone().requires_grad_(True)
        xt = x.replace_feature(f)
        out = conv(xt)
        conv.zero_grad(set_to_none=True)
        # Only the backward call is timed (the forward that records the graph is not).
        t = time.perf_counter()
        out.features.backward(dy)
        return time.perf_counter() - t

    return on_threads(forward), on_threads(backward), threads


def fill(n, seed):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, generator=g) - 0.5


def bench_set(h, coords, in_rows, out_rows, channels, repeats, use_spconv):
    rows = []
    n, offset_start = h["n"], h["offset_start"]
    pairs = len(in_rows)
    for c in channels:
        gms = TorchGatherMmScatter(n, offset_start, in_rows, out_rows, c, c)
        x = fill(n * c, 3).view(n, c)
        dy = fill(n * c, 4).view(n, c)
        w = fill(27 * c * c, 5).view(27, c, c)
        y, dx, dw = torch.empty(n, c), torch.empty(n, c), torch.empty(27, c, c)
        passes = [
            ("torch-gms", "forward", lambda: gms.forward(x, w, y)),
            ("torch-gms", "backward_input", lambda: gms.backward_input(dy, w, dx)),
            ("torch-gms", "backward_weight", lambda: gms.backward_weight(x, dy, dw)),
        ]
        sp = spconv_runner(coords, c, gms) if use_spconv else None
        threads_of = {}
        if sp is not None:
            passes.append(("spconv", "forward", sp[0]))
            passes.append(("spconv", "backward", sp[1]))
            threads_of["spconv"] = sp[2]
        best = [float("inf")] * len(passes)
        with torch.no_grad():
            for rnd in range(repeats + 1):
                for i, (kernel, _, f) in enumerate(passes):
                    t = time.perf_counter()
                    if kernel == "spconv" and passes[i][1] == "backward":
                        with torch.enable_grad():
                            ms = f() * 1e3
                    else:
                        f()
                        ms = (time.perf_counter() - t) * 1e3
                    if rnd > 0:
                        best[i] = min(best[i], ms)
        flop = 2.0 * pairs * c * c
        for (kernel, p, _), ms in zip(passes, best):
            rows.append({
                "scene": h["scene"],
                "voxel_size": h["voxel_size"],
                "n": n,
                "mean_neighbours": pairs / max(n, 1),
                "c_in": c,
                "c_out": c,
                "kernel": kernel,
                "pass": p,
                "ms": ms,
                # spconv's backward does both gradients: twice the useful work.
                "gflops": flop * (2 if p == "backward" else 1) / (ms * 1e6),
                "threads": threads_of.get(kernel, torch.get_num_threads()),
            })
            r = rows[-1]
            print(f"{h['voxel_size'] * 100:5.1f} cm {n:8d} C={c:4d} {kernel:>10} {p:>16} "
                  f"{ms:10.2f} ms {r['gflops']:7.1f} GFLOP/s  {r['threads']} threads", flush=True)
    return rows


def key(r):
    return (round(r["voxel_size"] * 1000), r["c_in"], r["c_out"])


def ratio_table(ours, peers):
    """Markdown table: ours (chunked, rulebook) against the peers, per set, C and pass."""
    by = {}
    for r in ours + peers:
        by[(key(r), r["kernel"], r["pass"])] = r
    lines = [
        "| voxel | voxels | C | pass | chunked ms | rulebook ms | torch-gms ms | rulebook / chunked | torch-gms / chunked | chunked % sgemm |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for k in sorted({key(r) for r in ours}, key=lambda k: (-k[0], k[1])):
        for p in ("forward", "backward_input", "backward_weight"):
            ch = by.get((k, "chunked", p))
            if ch is None:
                continue
            rb = by.get((k, "rulebook", p))
            tg = by.get((k, "torch-gms", p))
            fmt = lambda r: f"{r['ms']:.1f}" if r else "-"
            rat = lambda r: f"{r['ms'] / ch['ms']:.2f}x" if r else "-"
            roof = f"{100 * ch['gflops'] / ch['sgemm_gflops']:.0f}%" if "sgemm_gflops" in ch else "-"
            lines.append(f"| {k[0] / 10:g} cm | {ch['n']} | {k[1]} | {p} | {fmt(ch)} | {fmt(rb)} | "
                         f"{fmt(tg)} | {rat(rb)} | {rat(tg)} | {roof} |")
    sp = [r for r in peers if r["kernel"] == "spconv"]
    if sp:
        lines += ["", "| voxel | C | pass | spconv threads | spconv ms | chunked ms | spconv / chunked |",
                  "|---|---|---|---|---|---|---|"]
        for r in sp:
            k = key(r)
            if r["pass"] == "forward":
                ch = by.get((k, "chunked", "forward"))
                ours_ms = ch["ms"] if ch else None
            else:
                a, b = by.get((k, "chunked", "backward_input")), by.get((k, "chunked", "backward_weight"))
                ours_ms = a["ms"] + b["ms"] if a and b else None
            lines.append(f"| {k[0] / 10:g} cm | {k[1]} | {r['pass']} | {r['threads']} | {r['ms']:.1f} | "
                         + (f"{ours_ms:.1f} | {r['ms'] / ours_ms:.2f}x |" if ours_ms else "- | - |"))
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description="Sparse convolution peers on exported voxel sets")
    ap.add_argument("--export", required=True, help="folder written by `semrecon bench conv --export`")
    ap.add_argument("--ours", help="JSON rows of `semrecon bench conv --json` (for the ratios)")
    ap.add_argument("--channels", default="32,64,128")
    ap.add_argument("--threads", type=int, default=int(os.environ.get("OMP_NUM_THREADS", "2")))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--spconv", action="store_true", help="also time spconv's SubMConv3d")
    ap.add_argument("--json", help="write the peers' rows here")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    channels = [int(c) for c in args.channels.split(",")]
    headers = sorted(glob.glob(os.path.join(args.export, "conv_*mm.json")), reverse=True)
    if not headers:
        sys.exit(f"no conv_*mm.json in {args.export}: run `semrecon bench conv --export {args.export}`")
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, "
          f"{torch.backends.cpu.get_cpu_capability()}", flush=True)
    rows = []
    for hp in headers:
        h, coords, in_rows, out_rows = load_set(hp)
        check_torch_gms(coords, h["offset_start"], in_rows, out_rows)
        rows += bench_set(h, coords, in_rows, out_rows, channels, args.repeats, args.spconv)
    if args.json:
        tmp = args.json + ".tmp"
        with open(tmp, "w") as f:
            json.dump(rows, f, indent=1)
        os.replace(tmp, args.json)
        print(f"wrote {args.json}")
    if args.ours:
        with open(args.ours) as f:
            ours = json.load(f)
        print()
        print(ratio_table(ours, rows))


if __name__ == "__main__":
    main()
