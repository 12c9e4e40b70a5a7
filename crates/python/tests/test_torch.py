"""semrecon.torch: gradcheck of the autograd Function in double precision, the modules
against the NumPy reference, the kernel-map cache, and the CPU-only error. Skipped when
PyTorch is not installed (CI does not install it: see docs/python.md)."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import semrecon.torch as st  # noqa: E402
from semrecon.sparse import ConvGeometry  # noqa: E402
import sparse_reference as ref  # noqa: E402


def geometries(n=60, seed=0):
    rng = np.random.default_rng(seed)
    fine = ref.random_coords(rng, n, extent=4)
    down = ConvGeometry.downsample(fine)
    return {"subm3": ConvGeometry.submanifold(fine, 3), "down": down, "up": down.transposed()}


@pytest.mark.parametrize("kind", ["subm3", "down", "up"])
def test_gradcheck_double(kind):
    """gradcheck in float64. The engine computes in float32, so the finite-difference step is
    large (1e-2): the convolution is linear in each argument, so central differences are
    exact but for float32 rounding, which the tolerances cover."""
    g = geometries()[kind]
    torch.manual_seed(0)
    x = torch.randn(g.n_in, 3, dtype=torch.float64, requires_grad=True)
    w = torch.randn(g.kernel_volume, 3, 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda x, w: st.sparse_conv(x, w, g), (x, w), eps=1e-2, atol=1e-3, rtol=1e-3
    )


def test_function_matches_numpy_reference():
    rng = np.random.default_rng(3)
    fine = ref.random_coords(rng, 200)
    g = ConvGeometry.submanifold(fine, 3)
    pairs = ref.submanifold_pairs(fine, 3)
    x = torch.randn(g.n_in, 5, requires_grad=True)
    w = torch.randn(27, 5, 4, requires_grad=True)
    y = st.sparse_conv(x, w, g)
    np.testing.assert_allclose(y.detach().numpy(), ref.forward(pairs, x.detach().numpy(), w.detach().numpy(), g.n_out),
                               rtol=1e-5, atol=1e-5)
    dy = torch.randn_like(y)
    y.backward(dy)
    np.testing.assert_allclose(x.grad.numpy(), ref.backward_input(pairs, dy.numpy(), w.detach().numpy(), g.n_in),
                               rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(w.grad.numpy(), ref.backward_weight(pairs, x.detach().numpy(), dy.numpy(), 27),
                               rtol=1e-4, atol=1e-4)


def unet(c=4):
    return torch.nn.ModuleList([
        st.SubMConv3d(3, c), st.SparseConv3d(c, 2 * c), st.SubMConv3d(2 * c, 2 * c),
        st.SparseInverseConv3d(2 * c, c), st.SubMConv3d(c, 2),
    ])


def test_modules_u_net_and_kernel_map_cache():
    rng = np.random.default_rng(5)
    coords = ref.random_coords(rng, 300)
    x = st.SparseTensor(torch.randn(300, 3), coords)
    layers = unet()
    h = layers[0](x)
    assert h.stride == 1 and h.coords is x.coords
    d = layers[1](h)
    assert d.stride == 2 and len(d) < len(h)
    np.testing.assert_array_equal(d.coords, ref.downsample(coords)[0])
    d = d.replace_feature(torch.relu(d.features))
    d = layers[2](d)
    u = layers[3](d)
    assert u.stride == 1 and np.array_equal(u.coords, coords)
    out = layers[4](u)
    assert out.features.shape == (300, 2)
    # One map per coordinate set and kind, shared by the chain: subm at strides 1 and 2, down, up.
    geometry_keys = {k for k, v in x.cache.items() if isinstance(v, ConvGeometry)}
    assert geometry_keys == {("subm", 1, 3), ("down", 1), ("subm", 2, 3), ("up", 1)}
    first = x.cache[("subm", 1, 3)]
    layers[4](u)  # a second layer on the same set reuses the map
    assert x.cache[("subm", 1, 3)] is first
    out.features.sum().backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in layers.parameters())


def test_cpu_only_and_bad_inputs():
    g = geometries()["subm3"]
    w = torch.randn(27, 3, 2)
    meta = torch.empty(g.n_in, 3, device="meta")
    with pytest.raises(TypeError, match=r"features: semrecon.torch runs on the CPU; got a tensor on meta"):
        st.sparse_conv(meta, w, g)
    if torch.cuda.is_available():
        with pytest.raises(TypeError, match="cuda"):
            st.sparse_conv(torch.randn(g.n_in, 3, device="cuda"), w, g)
    with pytest.raises(TypeError, match="features: expected dtype torch.float32"):
        st.sparse_conv(torch.zeros(g.n_in, 3, dtype=torch.int64), w, g)
    with pytest.raises(ValueError, match="features: expected shape"):
        st.sparse_conv(torch.randn(g.n_in + 1, 3), w, g)
    # A non-contiguous tensor is made contiguous, not misread.
    x = torch.randn(g.n_in, 6)[:, ::2]
    np.testing.assert_allclose(st.sparse_conv(x, w, g).numpy(), st.sparse_conv(x.contiguous(), w, g).numpy())
    with pytest.raises(TypeError, match="coords: expected dtype int32"):
        st.SparseTensor(torch.randn(2, 3), np.zeros((2, 4), np.int64))
    with pytest.raises(ValueError, match="only kernel 2 with stride 2"):
        st.SparseConv3d(3, 4, kernel_size=3, stride=1)
    with pytest.raises(ValueError, match="no SparseConv3d produced"):
        two = np.array([[0, 0, 0, 0], [0, 1, 0, 0]], np.int32)
        st.SparseInverseConv3d(3, 4)(st.SparseTensor(torch.randn(2, 3), two, stride=2))
    with pytest.raises(ValueError, match="3 channels, the layer takes 5"):
        st.SubMConv3d(5, 2)(st.SparseTensor(torch.randn(2, 3), np.array([[0, 0, 0, 0], [0, 1, 0, 0]], np.int32)))
