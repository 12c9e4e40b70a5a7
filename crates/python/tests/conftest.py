"""Shared fixtures: small generated scans (no files needed) and pipeline options small enough
for a 2-core CI machine."""

import numpy as np
import pytest

import semrecon

# A 160x120 scan at 2 cm voxels: a few seconds for the whole module on 2 cores.
SCAN = dict(seed=3, frames=24, width=160, height=120)
OPTIONS = dict(voxel_size=0.02, truncation=4.0, keyframe_every=6)


@pytest.fixture(scope="session")
def scan():
    return semrecon.synthetic_scan(**SCAN)


@pytest.fixture(scope="session")
def frames(scan):
    """The scan's frames as numpy arrays (depth, color, pose, labels)."""
    return [(f.depth, f.color, f.pose, f.labels) for f in scan]


def assert_meshes_identical(a, b, keys=("vertices", "faces", "colors", "labels")):
    """Bit-for-bit equality of mesh dicts (floats compared as their bits)."""
    for k in keys:
        x, y = np.asarray(a[k]), np.asarray(b[k])
        assert x.dtype == y.dtype and x.shape == y.shape, (k, x.dtype, x.shape, y.dtype, y.shape)
        if x.dtype.kind == "f":
            x, y = x.view(np.uint32 if x.itemsize == 4 else np.uint64), y.view(np.uint32 if y.itemsize == 4 else np.uint64)
        assert np.array_equal(x, y), f"{k} differs at {np.argwhere(x != y)[:5].tolist()}"
