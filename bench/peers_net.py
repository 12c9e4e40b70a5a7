#!/usr/bin/env python3
"""Peer benchmark of the whole network: CBSCN in PyTorch on the CPU, with the same weights,
the same input and the same kernel maps as ours.

Loads what `semrecon bench net --export DIR` writes (see crates/cli/src/commands/bench_net.rs):
the room's voxels and colour features, the model (our safetensors file: f16 tensors with our
names and shapes, read here without the safetensors package and converted to f32), every
kernel map of the geometry (3x3x3 submanifold per level, the strided map to the next level and
its transpose) and the trilinear tables of the cross-scale fusion, and our logits.

The network is the one of crates/net/src/model.rs, written out in plain PyTorch:

    BN(x)        = relu(x * scale + shift), scale = gamma / sqrt(var + eps), shift = beta - mean * scale
    conv(x, map) = per kernel offset k: index_select the input rows, mm with W[k], index_add_ into
                   the output rows (MinkowskiEngine's CPU algorithm; int32 indices, preallocated
                   buffers, the submanifold centre offset as one addmm: a generous version)
    block(x)     = x + conv2(BN2(conv1(BN1(x))))
    E_0 = block(conv_input(x)); E_i = block(conv_down(BN(E_(i-1))))
    D_(L-1) = E_(L-1); D_t = block(conv_up(BN(D_(t+1))) + E_t W_skip) + sum_j interp(D_j b * sigmoid(D_j a))
    logits = BN(D_0) W_head + b_head

It checks that its logits agree with ours (max abs difference, relative to the largest logit),
then times the forward (the fastest of --repeats after a warm-up; the kernel maps are given,
not built, so the peer does less work than our timed call, which includes building them).

Usage:
  bench/.venv/bin/python bench/peers_net.py --export DIR [--threads 2] [--repeats 3] [--json FILE]
"""

import argparse
import json
import os
import sys
import time

import numpy as np
import torch


def read_safetensors(path):
    """{name: float32 tensor} of a safetensors file (f16 or f32 tensors) and its metadata."""
    with open(path, "rb") as f:
        data = f.read()
    n = int.from_bytes(data[:8], "little")
    header = json.loads(data[8:8 + n])
    meta = header.pop("__metadata__", {})
    base = 8 + n
    dtypes = {"F16": np.float16, "F32": np.float32}
    tensors = {}
    for name, t in header.items():
        if t["dtype"] not in dtypes:
            sys.exit(f"{path}: tensor {name} has dtype {t['dtype']}, expected F16 or F32")
        a, b = t["data_offsets"]
        v = np.frombuffer(data[base + a:base + b], dtype=dtypes[t["dtype"]]).astype(np.float32)
        tensors[name] = torch.from_numpy(v.reshape(t["shape"]).copy())
    return tensors, meta


class Map:
    """One kernel map: per offset k, (input rows, output rows) as int32 tensors."""

    def __init__(self, d, h, centre_identity):
        ins = torch.from_numpy(np.fromfile(os.path.join(d, h["in_rows"]), dtype="<u4").astype(np.int32))
        outs = torch.from_numpy(np.fromfile(os.path.join(d, h["out_rows"]), dtype="<u4").astype(np.int32))
        s = h["offset_start"]
        self.n_out = h["n_out"]
        kv = len(s) - 1
        # A submanifold map's centre offset pairs every voxel with itself (rows 0..n in order):
        # then it is one dense addmm.
        self.centre = kv // 2 if centre_identity else None
        if self.centre is not None:
            c = self.centre
            ci, co = ins[s[c]:s[c + 1]], outs[s[c]:s[c + 1]]
            n = h["n_in"]
            if not (len(ci) == n and torch.equal(ci, co) and torch.equal(ci, torch.arange(n, dtype=torch.int32))):
                self.centre = None
        self.offsets = [(k, ins[s[k]:s[k + 1]], outs[s[k]:s[k + 1]]) for k in range(kv) if s[k + 1] > s[k]]
        self.max_pairs = max((len(i) for k, i, _ in self.offsets if k != self.centre), default=0)


class Buffers:
    """Scratch for the gathers and products, grown once and reused (as ours)."""

    def __init__(self):
        self.a = torch.empty(0)
        self.b = torch.empty(0)

    def get(self, pa, pb):
        if self.a.numel() < pa:
            self.a = torch.empty(pa)
        if self.b.numel() < pb:
            self.b = torch.empty(pb)
        return self.a, self.b


def conv(x, m, w, buf):
    """Sparse convolution of x ([n_in, c_in]) on map m with weights w ([K, c_in, c_out])."""
    c_in, c_out = w.shape[1], w.shape[2]
    y = torch.zeros(m.n_out, c_out)
    a, b = buf.get(m.max_pairs * c_in, m.max_pairs * c_out)
    for k, ins, outs in m.offsets:
        if k == m.centre:
            y.addmm_(x, w[k])
            continue
        p = len(ins)
        g = a[:p * c_in].view(p, c_in)
        torch.index_select(x, 0, ins, out=g)
        r = b[:p * c_out].view(p, c_out)
        torch.mm(g, w[k], out=r)
        y.index_add_(0, outs, r)
    return y


class Net:
    def __init__(self, d, header):
        cfg = header["config"]
        self.levels = cfg["levels"]
        self.classes = cfg["classes"]
        eps = cfg.get("bn_eps", 1e-4)
        w, meta = read_safetensors(os.path.join(d, header["model"]))
        stored = json.loads(meta.get("semrecon.config", "null"))
        if stored is not None and any(stored[k] != cfg[k] for k in ("levels", "width", "in_channels", "classes")):
            sys.exit(f"the model's configuration {stored} is not the exported {cfg}")
        self.w = w
        self.bn = {}
        for name in w:
            if name.endswith(".running_var"):
                p = name[: -len(".running_var")]
                scale = w[p + ".weight"] / torch.sqrt(w[p + ".running_var"] + eps)
                self.bn[p] = (scale, w[p + ".bias"] - w[p + ".running_mean"] * scale)
        self.subm = [Map(d, lv["subm"], True) for lv in header["levels"]]
        self.down = [Map(d, lv["down"], False) if lv["down"] else None for lv in header["levels"]]
        self.up = [Map(d, lv["up"], False) if lv["up"] else None for lv in header["levels"]]
        self.interp = {}
        for ip in header["interp"]:
            rows = np.fromfile(os.path.join(d, ip["rows"]), dtype="<u4").astype(np.int64).reshape(-1, 8)
            wts = np.fromfile(os.path.join(d, ip["weights"]), dtype="<f4").reshape(-1, 8)
            self.interp[(ip["t"], ip["j"])] = (torch.from_numpy(rows), torch.from_numpy(wts.copy()))
        # Fusion maps as one [C_j, C_t + 1] matrix: value columns, then the attention column.
        self.fuse = {}
        for t in range(max(self.levels - 2, 0)):
            for j in range(t + 1, self.levels - 1):
                self.fuse[(t, j)] = torch.cat(
                    [w[f"fuse.{t}.{j}.value.weight"], w[f"fuse.{t}.{j}.attention.weight"]], dim=1
                ).contiguous()
        self.buf = Buffers()

    def bnrelu(self, x, prefix):
        scale, shift = self.bn[prefix]
        return torch.relu(torch.addcmul(shift, x, scale))

    def block(self, x, prefix, level):
        h = conv(self.bnrelu(x, prefix + ".bn1"), self.subm[level], self.w[prefix + ".conv1.weight"], self.buf)
        h = conv(self.bnrelu(h, prefix + ".bn2"), self.subm[level], self.w[prefix + ".conv2.weight"], self.buf)
        return x.add_(h)

    def forward(self, feats):
        L, w = self.levels, self.w
        enc = [self.block(conv(feats, self.subm[0], w["input.conv.weight"], self.buf), "extract.0", 0)]
        for i in range(1, L):
            h = conv(self.bnrelu(enc[i - 1], f"down.{i - 1}.bn"), self.down[i - 1], w[f"down.{i - 1}.conv.weight"], self.buf)
            enc.append(self.block(h, f"extract.{i}", i))
        dec = [None] * L
        dec[L - 1] = enc[L - 1]
        for t in range(L - 2, -1, -1):
            h = conv(self.bnrelu(dec[t + 1], f"up.{t}.bn"), self.up[t], w[f"up.{t}.conv.weight"], self.buf)
            h.addmm_(enc[t], w[f"up.{t}.skip.weight"])
            d = self.block(h, f"up.{t}", t)
            ct = d.shape[1]
            for j in range(t + 1, L - 1):
                g = dec[j] @ self.fuse[(t, j)]
                v = g[:, :ct] * torch.sigmoid(g[:, ct:])
                rows, wts = self.interp[(t, j)]
                # d[u] += sum_q wts[u, q] v[rows[u, q]]
                d.add_((v[rows] * wts.unsqueeze(2)).sum(dim=1))
            dec[t] = d
        d0 = dec[0] if L > 1 else enc[0]
        return torch.addmm(w["head.linear.bias"], self.bnrelu(d0, "head.bn"), w["head.linear.weight"])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--export", required=True, help="folder written by `semrecon bench net --export`")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", help="write the result row as JSON to this file")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    d = args.export
    with open(os.path.join(d, "net.json")) as f:
        header = json.load(f)
    n = header["n"]
    cfg = header["config"]
    feats = torch.from_numpy(np.fromfile(os.path.join(d, header["features"]), dtype="<f4").reshape(n, cfg["in_channels"]).copy())
    ours = np.fromfile(os.path.join(d, header["logits"]), dtype="<f4").reshape(n, cfg["classes"])
    net = Net(d, header)

    with torch.inference_mode():
        logits = net.forward(feats).numpy()
        diff = float(np.abs(logits - ours).max())
        scale = float(np.abs(ours).max())
        agree = float((logits.argmax(1) == ours.argmax(1)).mean())
        print(f"PyTorch vs ours: max |logit difference| {diff:.3g} (largest |logit| {scale:.3g}, "
              f"relative {diff / max(scale, 1e-12):.2e}); same class for {100 * agree:.3f}% of voxels")
        if diff > 1e-3 * max(scale, 1.0):
            sys.exit("PyTorch's logits disagree with ours")
        times = []
        for _ in range(max(args.repeats, 1)):
            t = time.perf_counter()
            net.forward(feats)
            times.append((time.perf_counter() - t) * 1e3)

    torch_ms = min(times)
    rows = {r["kernel"]: r for r in header.get("ours", [])}
    result = {
        "config": cfg["name"],
        "voxels": n,
        "threads": args.threads,
        "torch_version": torch.__version__,
        "torch_ms_per_room": torch_ms,
        "torch_mean_ms": sum(times) / len(times),
        "max_abs_diff": diff,
        "max_abs_logit": scale,
        "same_class": agree,
    }
    print(f"\n| network | voxels | kernel | ms per room | vs chunked |")
    print(f"|---|---|---|---|---|")
    chunked = rows.get("chunked")
    for name in ("chunked", "rulebook"):
        r = rows.get(name)
        if r:
            print(f"| {cfg['name']} | {n} | ours {name} (maps built in the call) | {r['ms_per_room']:.1f} | "
                  f"{r['ms_per_room'] / chunked['ms_per_room']:.2f}x |")
    line = f"| {cfg['name']} | {n} | PyTorch {torch.__version__} gather-mm-scatter (maps given) | {torch_ms:.1f} |"
    if chunked:
        result["torch_over_chunked"] = torch_ms / chunked["ms_per_room"]
        result["torch_over_chunked_layers"] = torch_ms / chunked["forward_ms"]
        line += f" {result['torch_over_chunked']:.2f}x |"
        print(line)
        print(f"\nPyTorch / ours chunked: {result['torch_over_chunked']:.2f}x per room "
              f"({result['torch_over_chunked_layers']:.2f}x against our layers alone, "
              f"{chunked['forward_ms']:.1f} ms)")
    else:
        print(line + " |")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)


if __name__ == "__main__":
    main()
