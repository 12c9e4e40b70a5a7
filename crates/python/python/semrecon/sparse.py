"""The sparse convolution engine on numpy arrays (see :class:`ConvGeometry`).

Coordinates are int32 ``(N, 4)`` rows ``(batch, x, y, z)`` (batch 0 or 1; x, y, z in
``[-2**20, 2**20 - 1]``; rows distinct), features float32 ``(N, C)``, weights float32
``(K**3, C_in, C_out)``. Submanifold offset ``(dx, dy, dz)`` in ``[-r, r]**3`` has index
``((dz + r) * K + dy + r) * K + dx + r`` and output ``u`` reads input ``u + (dx, dy, dz)``;
strided (kernel 2, stride 2): fine ``u`` feeds coarse ``u // 2`` through offset
``dx + 2 dy + 4 dz`` with ``d = u - 2 (u // 2)``; transposed: the same pairs, coarse to fine.
"""

from ._native import ConvGeometry

__all__ = ["ConvGeometry"]
