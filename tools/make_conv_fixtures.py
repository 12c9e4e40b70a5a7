#!/usr/bin/env python3
"""Independent oracle for the sparse convolution engine (crates/sparse).

Small random sparse cases are densified onto a grid and convolved with PyTorch's *dense*
`conv3d` / `conv_transpose3d` (float64); the outputs are read back at the active sites and
the gradients w.r.t. the input features and the weights come from autograd for a given
upstream gradient. Nothing here shares code or conventions with the engine except the
documented ones, so the Rust test `crates/sparse/tests/torch_oracle.rs` that checks the
engine against these fixtures is an independent check of the index conventions.

Conventions (crates/sparse/src/kernel_map.rs):
- dense grid dims are ordered (batch, channel, z, y, x), so a torch kernel index
  (a, b, c) is the offset (dz, dy, dx);
- submanifold K = 3: engine offset k = ((dz + 1) * 3 + dy + 1) * 3 + dx + 1 and
  y_u = sum_k x_(u + o_k) W_k. Torch's conv3d is a cross-correlation
  (out[p] = sum w[a, b, c] x[p + (a, b, c) - 1] with padding 1), so
  W_engine[k, ci, co] = w_torch[co, ci, dz + 1, dy + 1, dx + 1];
- down (K = 2, stride 2): fine u feeds coarse v = floor(u / 2) through d = u - 2v,
  k = dx + 2 dy + 4 dz; W_engine[k, ci, co] = w_torch[co, ci, dz, dy, dx];
- up (transposed, K = 2, stride 2): coarse v feeds fine u = 2v + d with the same k;
  conv_transpose3d's weight is [c_in, c_out, kz, ky, kx], so
  W_engine[k, ci, co] = w_torch[ci, co, dz, dy, dx].

Output: crates/sparse/tests/fixtures/torch_oracle.json (cases: coordinates, shapes, and
(offset, length) of every array) and torch_oracle.bin (all arrays, little-endian f32).
Arrays: x [n_in, c_in], w [K^3, c_in, c_out] (engine layout), y [n_out, c_out],
dy [n_out, c_out] (the upstream gradient), dx [n_in, c_in], dw [K^3, c_in, c_out].
Rows follow the case's `in_coords` / `out_coords` lists. For the down case the engine
orders its coarse set itself: the test matches rows by coordinate.

Usage: python tools/make_conv_fixtures.py [--out DIR]   (needs torch and numpy; CI does not
run it, the fixtures are committed).
"""

import argparse
import json
import os

import numpy as np
import torch
import torch.nn.functional as F

BOX = 12  # coordinates in [-BOX/2, BOX/2): an even shift keeps floor(u / 2) intact


def random_coords(rng, n, batches=2):
    """`n` distinct voxels [x, y, z, batch] in the box, in random order."""
    seen = set()
    out = []
    while len(out) < n:
        c = (
            int(rng.integers(-BOX // 2, BOX // 2)),
            int(rng.integers(-BOX // 2, BOX // 2)),
            int(rng.integers(-BOX // 2, BOX // 2)),
            int(rng.integers(0, batches)),
        )
        if c not in seen:
            seen.add(c)
            out.append(c)
    return out


def plane_coords():
    """A surface-like set: a tilted plane voxelised in the box (batch 0)."""
    out = set()
    for i in range(-60, 60):
        for j in range(-60, 60):
            x, y = i / 10.0, j / 10.0
            z = 0.4 * x - 0.3 * y + 0.5
            c = (int(np.floor(x)), int(np.floor(y)), int(np.floor(z)), 0)
            if all(-BOX // 2 <= v < BOX // 2 for v in c[:3]):
                out.add(c)
    return sorted(out)


def parent(c):
    return (c[0] // 2, c[1] // 2, c[2] // 2, c[3])


def coarse_of(fine):
    seen = {}
    for c in fine:
        seen.setdefault(parent(c), None)
    return list(seen)


def densify(coords, feats, side, batches):
    """[n, C] rows at coords (shifted by side/2... handled by caller) -> [B, C, Z, Y, X]."""
    c = feats.shape[1]
    g = torch.zeros(batches, c, side, side, side, dtype=torch.float64)
    idx = torch.tensor(coords, dtype=torch.long)
    g[idx[:, 3], :, idx[:, 2], idx[:, 1], idx[:, 0]] = feats
    return g


def gather(grid, coords):
    idx = torch.tensor(coords, dtype=torch.long)
    return grid[idx[:, 3], :, idx[:, 2], idx[:, 1], idx[:, 0]]


def shifted(coords, s):
    return [(x + s, y + s, z + s, b) for (x, y, z, b) in coords]


def f32(rng, shape):
    """Values exactly representable in f32 (the engine's type), kept in float64."""
    return torch.tensor(rng.uniform(-1.0, 1.0, size=shape).astype(np.float32), dtype=torch.float64)


def run_case(rng, kind, in_coords, out_coords, c_in, c_out):
    batches = 1 + max(c[3] for c in in_coords)
    x = f32(rng, (len(in_coords), c_in)).requires_grad_(True)
    g = f32(rng, (len(out_coords), c_out))
    if kind == "submanifold":
        wt = f32(rng, (c_out, c_in, 3, 3, 3)).requires_grad_(True)
        s = BOX // 2
        grid = densify(shifted(in_coords, s), x, BOX, batches)
        y_grid = F.conv3d(grid, wt, padding=1)
        y = gather(y_grid, shifted(out_coords, s))
        to_engine = lambda t: t.reshape(c_out, c_in, 27).permute(2, 1, 0)
    elif kind == "down":
        wt = f32(rng, (c_out, c_in, 2, 2, 2)).requires_grad_(True)
        s = BOX // 2
        grid = densify(shifted(in_coords, s), x, BOX, batches)
        y_grid = F.conv3d(grid, wt, stride=2)
        y = gather(y_grid, shifted(out_coords, s // 2))
        to_engine = lambda t: t.reshape(c_out, c_in, 8).permute(2, 1, 0)
    elif kind == "up":
        wt = f32(rng, (c_in, c_out, 2, 2, 2)).requires_grad_(True)
        s = BOX // 2
        grid = densify(shifted(in_coords, s // 2), x, BOX // 2, batches)
        y_grid = F.conv_transpose3d(grid, wt, stride=2)
        y = gather(y_grid, shifted(out_coords, s))
        to_engine = lambda t: t.reshape(c_in, c_out, 8).permute(2, 0, 1)
    else:
        raise ValueError(kind)
    (y * g).sum().backward()
    return {
        "x": x.detach(),
        "w": to_engine(wt.detach()),
        "y": y.detach(),
        "dy": g,
        "dx": x.grad,
        "dw": to_engine(wt.grad),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    here = os.path.dirname(os.path.abspath(__file__))
    ap.add_argument("--out", default=os.path.join(here, "..", "crates", "sparse", "tests", "fixtures"))
    args = ap.parse_args()
    rng = np.random.default_rng(20240611)
    torch.set_num_threads(1)

    # One batch and a denser set, so that most coarse voxels gather several fine children.
    fine_random = random_coords(rng, 360, batches=1)
    plane = plane_coords()
    cases = [
        ("sub_random_3_16", "submanifold", random_coords(rng, 240), None, 3, 16),
        ("sub_random_16_16", "submanifold", random_coords(rng, 200), None, 16, 16),
        ("sub_random_32_8", "submanifold", random_coords(rng, 180), None, 32, 8),
        ("sub_plane_16_16", "submanifold", plane, None, 16, 16),
        ("down_random_16_16", "down", fine_random, coarse_of(fine_random), 16, 16),
        ("up_random_16_8", "up", coarse_of(fine_random), fine_random, 16, 8),
    ]
    blob = bytearray()
    meta = []
    for name, kind, cin_coords, cout_coords, c_in, c_out in cases:
        cout_coords = cin_coords if cout_coords is None else cout_coords
        arrays = run_case(rng, kind, cin_coords, cout_coords, c_in, c_out)
        entry = {
            "name": name,
            "kind": kind,
            "c_in": c_in,
            "c_out": c_out,
            "in_coords": [list(c) for c in cin_coords],
            "out_coords": [list(c) for c in cout_coords],
            "arrays": {},
        }
        for key, t in arrays.items():
            a = np.ascontiguousarray(t.numpy().astype("<f4")).reshape(-1)
            entry["arrays"][key] = [len(blob) // 4, int(a.size)]
            blob += a.tobytes()
        meta.append(entry)
        print(f"{name}: {kind} n_in={len(cin_coords)} n_out={len(cout_coords)} c={c_in}->{c_out}")
    os.makedirs(args.out, exist_ok=True)
    for fname, data in (
        ("torch_oracle.bin", bytes(blob)),
        ("torch_oracle.json", json.dumps(
            {"torch": torch.__version__, "dtype": "float64 computed, f32 stored", "cases": meta},
            separators=(",", ":")).encode()),
    ):
        path = os.path.join(args.out, fname)
        tmp = path + ".tmp"
        with open(tmp, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
        print(f"wrote {path} ({len(data)} bytes)")


if __name__ == "__main__":
    main()
