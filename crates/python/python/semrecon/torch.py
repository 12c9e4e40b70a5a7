"""PyTorch wrappers of the sparse convolution engine (CPU tensors).

Importing this module needs PyTorch; the rest of ``semrecon`` does not.

- :class:`SparseTensor`: features ``(N, C)`` on voxels ``coords`` (int32 ``(N, 4)`` rows
  ``(batch, x, y, z)``, batch 0 or 1) at a grid ``stride``, with a cache of the kernel maps
  built for its coordinate sets, shared by every tensor derived from it;
- :class:`SubMConv3d`, :class:`SparseConv3d` (kernel 2, stride 2, down to ``coords // 2``),
  :class:`SparseInverseConv3d` (kernel 2, back to the finer set the matching
  ``SparseConv3d`` came from): ``nn.Module``\\ s in the spirit of spconv's, weights
  ``(K**3, C_in, C_out)``;
- :class:`SparseConvFunction`: the ``torch.autograd.Function`` under them (forward, input
  and weight gradients from the Rust kernels; not twice differentiable).

Each coordinate set's kernel map is built once (the first layer that needs it) and reused by
every later layer, the backward pass included. Tensors must live on the CPU: a CUDA tensor
raises a ``TypeError``. The engine computes in float32; float64 tensors are converted (and
the results cast back), so their precision is float32's.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Dict, Hashable, Optional, Tuple

import numpy as np

try:
    import torch
    from torch import nn
except ImportError as e:  # pragma: no cover - depends on the environment
    raise ImportError("semrecon.torch needs PyTorch (pip install torch); the rest of semrecon does not") from e

from ._native import ConvGeometry

__all__ = [
    "SparseConvFunction",
    "SparseInverseConv3d",
    "SparseConv3d",
    "SparseTensor",
    "SubMConv3d",
    "sparse_conv",
]


def _check_tensor(name: str, t: torch.Tensor) -> None:
    if not isinstance(t, torch.Tensor):
        raise TypeError(f"{name}: expected a torch.Tensor, got {type(t).__name__}")
    if t.device.type != "cpu":
        raise TypeError(
            f"{name}: semrecon.torch runs on the CPU; got a tensor on {t.device} (move it with .cpu())"
        )
    if t.dtype not in (torch.float32, torch.float64):
        raise TypeError(f"{name}: expected dtype torch.float32 (or float64), got {t.dtype}")


def _numpy32(t: torch.Tensor) -> np.ndarray:
    """A float32 C-contiguous numpy view (or copy) of a CPU tensor, without autograd."""
    return t.detach().to(torch.float32).contiguous().numpy()


class SparseConvFunction(torch.autograd.Function):
    """``y = conv(features, weight)`` over a :class:`semrecon.ConvGeometry`.

    Shapes: ``features`` ``(n_in, C_in)``, ``weight`` ``(K**3, C_in, C_out)``, result
    ``(n_out, C_out)``, all on the CPU, float32 (or float64, computed in float32).
    """

    @staticmethod
    def forward(ctx, features: torch.Tensor, weight: torch.Tensor, geometry: ConvGeometry) -> torch.Tensor:
        _check_tensor("features", features)
        _check_tensor("weight", weight)
        if not isinstance(geometry, ConvGeometry):
            raise TypeError(f"geometry: expected semrecon.ConvGeometry, got {type(geometry).__name__}")
        x, w = _numpy32(features), _numpy32(weight)
        y = geometry.forward(x, w)
        ctx.geometry = geometry
        ctx.save_for_backward(features, weight)
        return torch.from_numpy(y).to(features.dtype)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_out: torch.Tensor):
        features, weight = ctx.saved_tensors
        geometry: ConvGeometry = ctx.geometry
        g = _numpy32(grad_out)
        grad_x = grad_w = None
        if ctx.needs_input_grad[0]:
            grad_x = torch.from_numpy(geometry.backward_input(g, _numpy32(weight))).to(features.dtype)
        if ctx.needs_input_grad[1]:
            grad_w = torch.from_numpy(geometry.backward_weight(_numpy32(features), g)).to(weight.dtype)
        return grad_x, grad_w, None


def sparse_conv(features: torch.Tensor, weight: torch.Tensor, geometry: ConvGeometry) -> torch.Tensor:
    """Functional form of :class:`SparseConvFunction`."""
    return SparseConvFunction.apply(features, weight, geometry)


class SparseTensor:
    """Features on sparse voxels, with the kernel-map cache of its coordinate sets.

    Args:
        features: ``(N, C)`` float tensor on the CPU.
        coords: int32 ``(N, 4)`` rows ``(batch, x, y, z)`` (a numpy array or a CPU tensor),
            distinct rows; batch 0 or 1; x, y, z in grid units of ``stride``.
        stride: the grid's stride relative to the finest level (1, 2, 4, ...).
        cache: shared kernel-map cache (internal: layers pass it on to their outputs).
    """

    def __init__(
        self,
        features: torch.Tensor,
        coords,
        stride: int = 1,
        cache: Optional[Dict[Hashable, Any]] = None,
    ) -> None:
        _check_tensor("features", features)
        if isinstance(coords, torch.Tensor):
            if coords.device.type != "cpu":
                raise TypeError(f"coords: expected a CPU tensor, got one on {coords.device}")
            coords = coords.detach().numpy()
        coords = np.asarray(coords)
        if coords.dtype != np.int32:
            raise TypeError(f"coords: expected dtype int32 with shape (N, 4), got {coords.dtype}")
        if coords.ndim != 2 or coords.shape[1] != 4:
            raise ValueError(f"coords: expected shape (N, 4) rows (batch, x, y, z), got {coords.shape}")
        if features.ndim != 2 or features.shape[0] != coords.shape[0]:
            raise ValueError(
                f"features: expected shape ({coords.shape[0]}, C), one row per voxel, got {tuple(features.shape)}"
            )
        self.features = features
        self.coords = np.ascontiguousarray(coords)
        self.stride = int(stride)
        self.cache: Dict[Hashable, Any] = {} if cache is None else cache

    def replace_feature(self, features: torch.Tensor) -> "SparseTensor":
        """The same voxels (and cache) with other features (e.g. after a ReLU)."""
        return SparseTensor(features, self.coords, self.stride, self.cache)

    def geometry(self, key: Tuple, build: Callable[[], Any]) -> Any:
        """The cached geometry under ``key``, built by ``build()`` the first time."""
        g = self.cache.get(key)
        if g is None:
            g = build()
            self.cache[key] = g
        return g

    def __len__(self) -> int:
        return int(self.coords.shape[0])

    def __repr__(self) -> str:
        return f"SparseTensor(voxels={len(self)}, channels={self.features.shape[1]}, stride={self.stride})"


class _SparseConvBase(nn.Module):
    def __init__(self, in_channels: int, out_channels: int, kernel_volume: int, bias: bool) -> None:
        super().__init__()
        if in_channels <= 0 or out_channels <= 0:
            raise ValueError(f"channels must be positive, got in={in_channels}, out={out_channels}")
        self.in_channels = in_channels
        self.out_channels = out_channels
        self.weight = nn.Parameter(torch.empty(kernel_volume, in_channels, out_channels))
        self.bias = nn.Parameter(torch.empty(out_channels)) if bias else None
        self.reset_parameters()

    def reset_parameters(self) -> None:
        # Kaiming-uniform as nn.Conv3d: bound 1 / sqrt(fan_in), fan_in = K^3 * C_in.
        fan_in = self.weight.shape[0] * self.weight.shape[1]
        bound = 1.0 / math.sqrt(fan_in)
        nn.init.uniform_(self.weight, -bound, bound)
        if self.bias is not None:
            nn.init.uniform_(self.bias, -bound, bound)

    def _apply_conv(self, x: SparseTensor, geometry: ConvGeometry, coords: np.ndarray, stride: int) -> SparseTensor:
        if not isinstance(x, SparseTensor):
            raise TypeError(f"input: expected semrecon.torch.SparseTensor, got {type(x).__name__}")
        if x.features.shape[1] != self.in_channels:
            raise ValueError(f"input: {x.features.shape[1]} channels, the layer takes {self.in_channels}")
        y = sparse_conv(x.features, self.weight, geometry)
        if self.bias is not None:
            y = y + self.bias.to(y.dtype)
        return SparseTensor(y, coords, stride, x.cache)


class SubMConv3d(_SparseConvBase):
    """Submanifold convolution: output voxels = input voxels, odd ``kernel_size`` (3)."""

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int = 3, bias: bool = True) -> None:
        if kernel_size % 2 != 1 or not 1 <= kernel_size <= 9:
            raise ValueError(f"kernel_size: expected an odd size in 1..9, got {kernel_size}")
        self.kernel_size = kernel_size
        super().__init__(in_channels, out_channels, kernel_size**3, bias)

    def forward(self, x: SparseTensor) -> SparseTensor:
        g = x.geometry(
            ("subm", x.stride, self.kernel_size), lambda: ConvGeometry.submanifold(x.coords, self.kernel_size)
        )
        return self._apply_conv(x, g, x.coords, x.stride)


class SparseConv3d(_SparseConvBase):
    """Strided convolution, kernel 2 and stride 2: voxels ``u`` to ``u // 2`` (spatially;
    the batch is kept). Its output remembers the way back for :class:`SparseInverseConv3d`."""

    def __init__(
        self, in_channels: int, out_channels: int, kernel_size: int = 2, stride: int = 2, bias: bool = True
    ) -> None:
        if kernel_size != 2 or stride != 2:
            raise ValueError(
                f"kernel_size={kernel_size}, stride={stride}: only kernel 2 with stride 2 is supported"
            )
        super().__init__(in_channels, out_channels, 8, bias)

    def forward(self, x: SparseTensor) -> SparseTensor:
        g = x.geometry(("down", x.stride), lambda: ConvGeometry.downsample(x.coords))
        # The fine and coarse sets, for the inverse layer that comes back to this stride.
        x.cache[("fine", x.stride)] = x.coords
        coarse = x.geometry(("coarse", x.stride), lambda: g.out_coords)
        return self._apply_conv(x, g, coarse, x.stride * 2)


class SparseInverseConv3d(_SparseConvBase):
    """Transposed convolution, kernel 2: back from a :class:`SparseConv3d`'s output to the
    voxels that layer read (the set of stride ``x.stride // 2`` in the tensor's cache)."""

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int = 2, bias: bool = True) -> None:
        if kernel_size != 2:
            raise ValueError(f"kernel_size={kernel_size}: only kernel 2 is supported")
        super().__init__(in_channels, out_channels, 8, bias)

    def forward(self, x: SparseTensor) -> SparseTensor:
        fine_stride = x.stride // 2
        down = x.cache.get(("down", fine_stride))
        if x.stride < 2 or down is None:
            raise ValueError(
                f"input: no SparseConv3d produced this stride-{x.stride} tensor from a finer one "
                "(an inverse layer must follow a strided layer of the same network pass)"
            )
        coarse = x.cache[("coarse", fine_stride)]
        if x.coords is not coarse and not np.array_equal(x.coords, coarse):
            raise ValueError(
                f"input: its {len(x)} voxels are not the {len(coarse)} the strided layer to stride {x.stride} made"
            )
        g = x.geometry(("up", fine_stride), down.transposed)
        return self._apply_conv(x, g, x.cache[("fine", fine_stride)], fine_stride)
