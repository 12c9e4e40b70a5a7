"""semrecon: live semantic 3D perception on the CPU, and its sparse convolution engine.

An RGB-D stream goes in; a camera trajectory, a dense coloured mesh and a semantic class
for every surface (the 13 S3DIS classes in ``CLASSES``) come out. Everything runs in Rust
with the GIL released; arrays go in and out as numpy arrays.

Conventions: metres; world frame z up; camera frame x right, y down, z forward; poses are
``world_from_camera`` float64 ``(4, 4)`` matrices; class ids 0..12 in ``CLASSES`` order,
255 (``UNLABELED``) for none.

Main entry points:

- :class:`Pipeline`: ``push_frame(depth, color)``, ``pose``, ``trajectory()``, ``mesh()``,
  ``timings()``, ``finish()``;
- :func:`open_dataset` (``"7scenes:PATH"``, ``"tum:PATH"``, ... ``"synth:SEED"``) and
  :func:`synthetic_scan`: :class:`Dataset`\\ s of :class:`Frame`\\ s;
- :func:`segment`: class ids of a coloured point cloud;
- :func:`read_ply`, :func:`write_ply`, :func:`class_colored`;
- :class:`ConvGeometry` (also as ``semrecon.sparse``): sparse convolution forward and both
  gradients on numpy arrays; ``semrecon.torch`` wraps it for PyTorch (CPU tensors).
"""

from __future__ import annotations

import os as _os

import numpy as _np

from . import _native
from ._native import (
    CLASS_COLORS,
    CLASSES,
    UNLABELED,
    ConvGeometry,
    Dataset,
    Frame,
    FrameResult,
    Intrinsics,
    Pipeline,
    __version__,
    default_model_path,
    open_dataset,
    read_ply,
    segment,
    synthetic_scan,
    write_ply,
)

__all__ = [
    "CLASSES",
    "CLASS_COLORS",
    "UNLABELED",
    "ConvGeometry",
    "Dataset",
    "Frame",
    "FrameResult",
    "Intrinsics",
    "Pipeline",
    "__version__",
    "class_colored",
    "default_model_path",
    "open_dataset",
    "read_ply",
    "segment",
    "synthetic_scan",
    "write_ply",
]

# The wheel carries the shipped model; the native module reads it when no model is named
# (SEMRECON_MODEL still takes precedence).
_PACKAGE_MODEL = _os.path.join(_os.path.dirname(__file__), "models", "s20.safetensors")
if _os.path.isfile(_PACKAGE_MODEL):
    _native._set_package_model(_PACKAGE_MODEL)

#: Grey of unlabelled vertices in :func:`class_colored`.
UNLABELED_COLOR = (160, 160, 160)


def class_colored(mesh: dict) -> dict:
    """A copy of ``mesh`` (a dict from :meth:`Pipeline.mesh`) with every vertex coloured by
    its class (``CLASS_COLORS``; unlabelled vertices grey), as ``semantic.ply`` of the CLI."""
    labels = _np.asarray(mesh["labels"])
    table = _np.tile(_np.array(UNLABELED_COLOR, dtype=_np.uint8), (256, 1))
    table[: len(CLASSES)] = CLASS_COLORS
    out = dict(mesh)
    out["colors"] = table[labels]
    return out
