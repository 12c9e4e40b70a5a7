#!/usr/bin/env python3
"""Train a tiny sparse U-Net layer stack with PyTorch on random data (needs torch).

    python examples/python/train_sparse_unet.py [--steps 30]

The task is made up but learnable: label each voxel of a random blob by whether its
neighbourhood (3x3x3 at the fine level and the coarse level's context) is denser than
average. The loss should fall steadily.
"""

import argparse
import time

import numpy as np
import torch
from torch import nn

import semrecon.torch as st


class TinyUNet(nn.Module):
    """Two levels: SubMConv3d blocks, a strided SparseConv3d down and SparseInverseConv3d up
    with a skip connection, then a pointwise classifier."""

    def __init__(self, c_in: int = 3, width: int = 16, classes: int = 2) -> None:
        super().__init__()
        self.enc = st.SubMConv3d(c_in, width)
        self.down = st.SparseConv3d(width, 2 * width)
        self.mid = st.SubMConv3d(2 * width, 2 * width)
        self.up = st.SparseInverseConv3d(2 * width, width)
        self.dec = st.SubMConv3d(2 * width, width)
        self.head = st.SubMConv3d(width, classes, kernel_size=1)

    def forward(self, x: st.SparseTensor) -> torch.Tensor:
        relu = lambda t: t.replace_feature(torch.relu(t.features))  # noqa: E731
        e = relu(self.enc(x))
        m = relu(self.mid(relu(self.down(e))))
        u = relu(self.up(m))
        d = relu(self.dec(u.replace_feature(torch.cat([u.features, e.features], dim=1))))
        return self.head(d).features


def random_scene(rng: np.random.Generator, n: int = 3000):
    """Voxels of two random blobs (batch 0 and 1) with RGB-like features and labels."""
    rows = []
    for b in (0, 1):
        centre = rng.integers(-20, 20, 3)
        pts = np.round(rng.normal(centre, 6.0, size=(n, 3))).astype(np.int32)
        pts = np.unique(pts, axis=0)
        rows.append(np.concatenate([np.full((len(pts), 1), b, np.int32), pts], axis=1))
    coords = np.ascontiguousarray(np.concatenate(rows))
    feats = rng.random((len(coords), 3)).astype(np.float32)
    # Label: more than the median number of occupied 3x3x3 neighbours.
    occupied = {tuple(c) for c in coords.tolist()}
    offsets = [(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)]
    counts = np.array([sum((b, x + dx, y + dy, z + dz) in occupied for dx, dy, dz in offsets)
                       for b, x, y, z in coords.tolist()])
    labels = (counts > np.median(counts)).astype(np.int64)
    return coords, torch.from_numpy(feats), torch.from_numpy(labels)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--steps", type=int, default=30)
    args = ap.parse_args()
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    coords, feats, labels = random_scene(rng)
    print(f"{len(coords)} voxels, {int(labels.sum())} dense")
    net = TinyUNet()
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    start = time.perf_counter()
    first = last = None
    for step in range(args.steps):
        # A new SparseTensor per step; its kernel maps are built on the first layer that
        # needs each one and shared by the rest, backward included.
        x = st.SparseTensor(feats, coords)
        loss = nn.functional.cross_entropy(net(x), labels)
        opt.zero_grad()
        loss.backward()
        opt.step()
        first = loss.item() if first is None else first
        last = loss.item()
        if step % 10 == 0 or step == args.steps - 1:
            print(f"step {step:3d}: loss {last:.4f}")
    print(f"loss {first:.4f} -> {last:.4f} in {time.perf_counter() - start:.2f} s")


if __name__ == "__main__":
    main()
