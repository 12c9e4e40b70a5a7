"""The sparse engine from numpy: forward and both gradients against a NumPy reference and
finite differences, for submanifold, strided and transposed layers."""

import numpy as np
import pytest

from semrecon.sparse import ConvGeometry
import sparse_reference as ref

RTOL, ATOL = 1e-5, 1e-5


def layers(rng, n=400):
    """(name, geometry, reference pairs) of every layer kind on random voxels."""
    fine = ref.random_coords(rng, n)
    coarse, down_pairs = ref.downsample(fine)
    out = []
    for k in (1, 3, 5):
        out.append((f"subm{k}", ConvGeometry.submanifold(fine, k), ref.submanifold_pairs(fine, k)))
    down = ConvGeometry.downsample(fine)
    assert np.array_equal(down.out_coords, coarse)
    out.append(("down", down, down_pairs))
    up_pairs = ref.upsample_pairs(coarse, fine)
    out.append(("up", ConvGeometry.upsample(coarse, fine), up_pairs))
    out.append(("down.T", down.transposed(), up_pairs))
    return out


@pytest.mark.parametrize("c_in,c_out", [(1, 1), (3, 8), (16, 5)])
def test_forward_and_gradients_match_numpy(c_in, c_out):
    rng = np.random.default_rng(c_in * 100 + c_out)
    for name, g, pairs in layers(rng):
        kv = g.kernel_volume
        x = rng.standard_normal((g.n_in, c_in)).astype(np.float32)
        w = rng.standard_normal((kv, c_in, c_out)).astype(np.float32)
        dy = rng.standard_normal((g.n_out, c_out)).astype(np.float32)
        y = g.forward(x, w)
        assert y.dtype == np.float32 and y.shape == (g.n_out, c_out), name
        np.testing.assert_allclose(y, ref.forward(pairs, x, w, g.n_out), rtol=RTOL, atol=ATOL, err_msg=name)
        dx = g.backward_input(dy, w)
        assert dx.shape == (g.n_in, c_in)
        np.testing.assert_allclose(dx, ref.backward_input(pairs, dy, w, g.n_in), rtol=RTOL, atol=ATOL, err_msg=name)
        dw = g.backward_weight(x, dy)
        assert dw.shape == (kv, c_in, c_out)
        np.testing.assert_allclose(dw, ref.backward_weight(pairs, x, dy, kv), rtol=1e-4, atol=1e-4, err_msg=name)
        assert g.num_pairs == len(pairs), name


def test_gradients_match_finite_differences():
    """<dL/dx, v> and <dL/dw, v> against central differences of L = <y, dy> (exact for a
    bilinear map up to float32 rounding, hence the large step)."""
    rng = np.random.default_rng(7)
    eps = 1e-2
    for name, g, _ in layers(rng, n=200):
        c_in, c_out = 4, 3
        x = rng.standard_normal((g.n_in, c_in)).astype(np.float32)
        w = rng.standard_normal((g.kernel_volume, c_in, c_out)).astype(np.float32)
        dy = rng.standard_normal((g.n_out, c_out)).astype(np.float32)

        def loss(x, w):
            return float(np.sum(g.forward(x, w).astype(np.float64) * dy))

        for _ in range(3):
            vx = rng.standard_normal(x.shape).astype(np.float32)
            fd = (loss(x + eps * vx, w) - loss(x - eps * vx, w)) / (2 * eps)
            an = float(np.sum(g.backward_input(dy, w).astype(np.float64) * vx))
            assert abs(fd - an) <= 1e-3 * max(1.0, abs(an)), (name, fd, an)
            vw = rng.standard_normal(w.shape).astype(np.float32)
            fd = (loss(x, w + eps * vw) - loss(x, w - eps * vw)) / (2 * eps)
            an = float(np.sum(g.backward_weight(x, dy).astype(np.float64) * vw))
            assert abs(fd - an) <= 1e-3 * max(1.0, abs(an)), (name, fd, an)


def test_geometry_attributes():
    rng = np.random.default_rng(1)
    fine = ref.random_coords(rng, 100)
    g = ConvGeometry.submanifold(fine)
    assert (g.kind, g.kernel_volume, g.n_in, g.n_out) == ("submanifold", 27, 100, 100)
    assert np.array_equal(g.in_coords, fine) and np.array_equal(g.out_coords, fine)
    ins, outs = g.pairs(13)  # the centre offset: the identity
    assert np.array_equal(ins, np.arange(100)) and np.array_equal(outs, np.arange(100))
    d = ConvGeometry.downsample(fine)
    assert d.kind == "down" and d.transposed().kind == "up" and d.kernel_volume == 8
    assert np.array_equal(d.transposed().out_coords, fine)
    assert "ConvGeometry(kind='down'" in repr(d) or "ConvGeometry(kind=\"down\"" in repr(d)
    # Negative coordinates floor (not truncate) on the way down.
    one = np.array([[0, -1, -3, 5]], dtype=np.int32)
    assert ConvGeometry.downsample(one).out_coords.tolist() == [[0, -1, -2, 2]]
    empty = ConvGeometry.submanifold(np.zeros((0, 4), np.int32))
    assert empty.forward(np.zeros((0, 2), np.float32), np.zeros((27, 2, 3), np.float32)).shape == (0, 3)


def test_forward_into_a_kept_buffer():
    rng = np.random.default_rng(2)
    g = ConvGeometry.submanifold(ref.random_coords(rng, 100))
    x = rng.standard_normal((100, 4)).astype(np.float32)
    w = rng.standard_normal((27, 4, 3)).astype(np.float32)
    out = np.full((100, 3), np.nan, np.float32)
    assert g.forward(x, w, out=out) is out
    np.testing.assert_array_equal(out, g.forward(x, w))
    with pytest.raises(ValueError, match=r"out: expected shape \(100, 3\)"):
        g.forward(x, w, out=np.zeros((100, 4), np.float32))
    frozen = np.zeros((100, 3), np.float32)
    frozen.flags.writeable = False
    with pytest.raises(ValueError, match="out: the array is not writeable"):
        g.forward(x, w, out=frozen)
    square = np.zeros((100, 4), np.float32)
    with pytest.raises(ValueError, match="out: the array is not writeable"):  # aliases the input
        g.forward(square, rng.standard_normal((27, 4, 4)).astype(np.float32), out=square)
