"""A plain NumPy reference of the sparse convolutions, written from the documented
conventions alone (coordinates (batch, x, y, z); weights (K^3, C_in, C_out); offset
numbering of semrecon.sparse): the oracle of test_sparse.py and test_torch.py."""

import numpy as np


def random_coords(rng, n, extent=10, batches=2):
    """`n` distinct voxels (batch, x, y, z) in [0, batches) x [-extent, extent)^3, int32."""
    seen = set()
    rows = []
    while len(rows) < n:
        c = (int(rng.integers(batches)), *map(int, rng.integers(-extent, extent, 3)))
        if c not in seen:
            seen.add(c)
            rows.append(c)
    return np.array(rows, dtype=np.int32)


def submanifold_pairs(coords, k):
    """[(offset, in_row, out_row)] of the submanifold map with odd kernel size k."""
    r = (k - 1) // 2
    index = {tuple(c): i for i, c in enumerate(coords.tolist())}
    pairs = []
    for dz in range(-r, r + 1):
        for dy in range(-r, r + 1):
            for dx in range(-r, r + 1):
                off = ((dz + r) * k + dy + r) * k + dx + r
                for u, (b, x, y, z) in enumerate(coords.tolist()):
                    i = index.get((b, x + dx, y + dy, z + dz))
                    if i is not None:
                        pairs.append((off, i, u))
    return pairs


def downsample(fine):
    """Coarse set (first-appearance order) and the [(offset, in_row, out_row)] of the
    strided map (kernel 2, stride 2)."""
    coarse, index, pairs = [], {}, []
    for u, (b, x, y, z) in enumerate(fine.tolist()):
        p = (b, x // 2, y // 2, z // 2)
        if p not in index:
            index[p] = len(coarse)
            coarse.append(p)
        off = (x - 2 * p[1]) + 2 * (y - 2 * p[2]) + 4 * (z - 2 * p[3])
        pairs.append((off, u, index[p]))
    return np.array(coarse, dtype=np.int32).reshape(-1, 4), pairs


def upsample_pairs(coarse, fine):
    """[(offset, in_row, out_row)] of the transposed map coarse -> fine."""
    index = {tuple(c): i for i, c in enumerate(coarse.tolist())}
    pairs = []
    for u, (b, x, y, z) in enumerate(fine.tolist()):
        p = (b, x // 2, y // 2, z // 2)
        off = (x - 2 * p[1]) + 2 * (y - 2 * p[2]) + 4 * (z - 2 * p[3])
        pairs.append((off, index[p], u))
    return pairs


def forward(pairs, x, w, n_out):
    y = np.zeros((n_out, w.shape[2]), dtype=np.float64)
    for k, i, o in pairs:
        y[o] += x[i].astype(np.float64) @ w[k].astype(np.float64)
    return y


def backward_input(pairs, dy, w, n_in):
    dx = np.zeros((n_in, w.shape[1]), dtype=np.float64)
    for k, i, o in pairs:
        dx[i] += w[k].astype(np.float64) @ dy[o].astype(np.float64)
    return dx


def backward_weight(pairs, x, dy, kv):
    dw = np.zeros((kv, x.shape[1], dy.shape[1]), dtype=np.float64)
    for k, i, o in pairs:
        dw[k] += np.outer(x[i].astype(np.float64), dy[o].astype(np.float64))
    return dw
