"""Type stubs of the native module ``semrecon._native`` (re-exported by ``semrecon``).

Units: metres, seconds, pixels. Poses: ``world_from_camera`` float64 ``(4, 4)``.
"""

from os import PathLike
from typing import Dict, Iterator, List, Literal, Optional, Sequence, Tuple, TypedDict, Union, final

import numpy as np
import numpy.typing as npt

__version__: str
__all__ = [
    "__version__",
    "CLASSES",
    "CLASS_COLORS",
    "UNLABELED",
    "Intrinsics",
    "Frame",
    "Dataset",
    "FrameIter",
    "open_dataset",
    "synthetic_scan",
    "Pipeline",
    "FrameResult",
    "segment",
    "write_ply",
    "read_ply",
    "_set_package_model",
    "default_model_path",
    "ConvGeometry",
]

CLASSES: Tuple[str, ...]
"""The 13 class names; index = class id (ceiling, floor, wall, beam, column, window, door,
chair, table, bookcase, sofa, board, clutter)."""
CLASS_COLORS: npt.NDArray[np.uint8]
"""uint8 ``(13, 3)`` RGB colour of each class (read-only)."""
UNLABELED: int
"""The class id of unlabelled vertices and pixels (255)."""

_Path = Union[str, "PathLike[str]"]

class _Mesh(TypedDict):
    """A labelled triangle mesh."""

    vertices: npt.NDArray[np.float32]
    """float32 ``(V, 3)``, metres, world frame."""
    faces: npt.NDArray[np.int32]
    """int32 ``(F, 3)`` vertex indices, counter-clockwise seen from outside."""
    colors: npt.NDArray[np.uint8]
    """uint8 ``(V, 3)`` observed RGB."""
    labels: npt.NDArray[np.uint8]
    """uint8 ``(V,)`` class ids (``CLASSES`` order; 255 = unlabelled)."""
    normals: npt.NDArray[np.float32]
    """float32 ``(V, 3)`` unit normals, or ``(0, 3)`` when the mesh has none."""

class _Trajectory(TypedDict):
    timestamps: npt.NDArray[np.float64]
    """float64 ``(N,)`` seconds."""
    poses: npt.NDArray[np.float64]
    """float64 ``(N, 4, 4)`` ``world_from_camera``."""

class _StageTiming(TypedDict):
    median_ms: float
    p95_ms: float
    max_ms: float
    count: int
    total_ms: float

@final
class Intrinsics:
    """Pinhole intrinsics of the depth image, pixels; pixel centres at integer coordinates."""

    def __new__(cls, width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> "Intrinsics": ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def fx(self) -> float: ...
    @property
    def fy(self) -> float: ...
    @property
    def cx(self) -> float: ...
    @property
    def cy(self) -> float: ...
    def matrix(self) -> npt.NDArray[np.float64]:
        """The 3x3 camera matrix K, float64."""
    def scaled(self, width: int, height: int) -> "Intrinsics":
        """The same camera at another resolution."""

@final
class Frame:
    """One RGB-D frame of a :class:`Dataset`. Array attributes return a new array each time."""

    @property
    def index(self) -> int: ...
    @property
    def timestamp(self) -> float:
        """Capture time, seconds."""
    @property
    def intrinsics(self) -> Intrinsics: ...
    @property
    def depth(self) -> npt.NDArray[np.float32]:
        """float32 ``(H, W)`` metres along the optical axis; 0 where missing."""
    @property
    def color(self) -> npt.NDArray[np.uint8]:
        """uint8 ``(H, W, 3)`` RGB registered to the depth image."""
    @property
    def pose(self) -> Optional[npt.NDArray[np.float64]]:
        """Ground-truth ``world_from_camera`` float64 ``(4, 4)``, or None."""
    @property
    def labels(self) -> Optional[npt.NDArray[np.uint8]]:
        """uint8 ``(H, W)`` class ids (rendered data only; 255 = nothing), or None."""

@final
class Dataset:
    """A sequence of RGB-D frames with one camera; frames are decoded on access."""

    @property
    def name(self) -> str: ...
    @property
    def intrinsics(self) -> Intrinsics: ...
    @property
    def has_ground_truth(self) -> bool: ...
    @property
    def frame_rate(self) -> float:
        """Nominal frame rate, Hz."""
    def __len__(self) -> int: ...
    def __getitem__(self, index: int, /) -> Frame:
        """Frame ``index`` (negative counts from the end); IndexError past the end."""
    def __iter__(self) -> Iterator[Frame]: ...

@final
class FrameIter(Iterator[Frame]):
    def __next__(self) -> Frame: ...

def open_dataset(spec: str) -> Dataset:
    """The frames of ``KIND:PATH``: ``7scenes:``, ``tum:``, ``redwood:``, ``scannet:``,
    ``replica:`` folders, or ``synth:SEED`` (a generated room, 300 frames at 640x480).

    Raises FileNotFoundError for a missing folder, ValueError for a bad specification or layout.
    """

def synthetic_scan(
    seed: int, frames: int = 300, width: int = 640, height: int = 480, style: Optional[str] = None
) -> Dataset:
    """A generated room (``style``: office, conference, lounge, hallway, classroom; drawn from
    the seed when None) scanned along a handheld-like path through a Kinect-like sensor
    model, rendered on access: ground-truth poses and per-pixel classes, no files."""

_FrameStatus = Literal["initialized", "fused", "relocalised", "lost", "no_pose"]

@final
class FrameResult:
    """What :meth:`Pipeline.push_frame` did with one frame."""

    @property
    def status(self) -> _FrameStatus: ...
    @property
    def lost_reason(self) -> Optional[str]:
        """Why tracking failed (no_depth, no_model, few_inliers, large_residual, pose_jump,
        degenerate) for lost frames, else None."""
    @property
    def fused(self) -> bool: ...
    @property
    def pose(self) -> Optional[npt.NDArray[np.float64]]:
        """``world_from_camera`` float64 ``(4, 4)`` when fused, else None."""
    @property
    def keyframe(self) -> bool: ...
    @property
    def semantic_pass(self) -> bool: ...
    @property
    def index(self) -> int: ...

@final
class Pipeline:
    """The live pipeline: frame-to-model tracking and TSDF fusion on every frame, meshing and
    a semantic pass (in a back-end thread) every ``keyframe_every`` frames.

    Args (defaults as ``semrecon run``):
        intrinsics: an :class:`Intrinsics` or ``(width, height, fx, fy, cx, cy)``.
        voxel_size: TSDF voxel, metres (0.002..0.05).
        semantics: True / "incremental" (changed tiles and ``context`` metres around them),
            "full" (the whole map each keyframe), False / "off" (no network).
        model: a safetensors model file; default the shipped model
            (``default_model_path()``, ``SEMRECON_MODEL`` overrides).
        keyframe_every: frames between keyframes.
        truncation: TSDF truncation, voxels.
        max_depth: farthest depth fused, metres (default 5, as the CLI).
        poses: "track" (ICP tracking) or "ground_truth" (the ``pose`` given with each frame).
        mesh_budget: most chunks re-meshed per keyframe (default 3072; labels read the map,
            not the mesh, so it costs none); 0 = none.
        realtime: never wait for the semantic back end (results depend on timing).
        up: the map's up direction when known (three numbers); estimated otherwise.
        context: incremental semantics' context, metres.
        min_label_island: label islands smaller than this (m^2) take their surroundings' class.
        structure: "segments" (the map's labels voted over its geometric segments, normals
            and colour, as ``semrecon segment``) or "none" (each 5 cm cell its own class).
        photometric_weight: weight of the colour term in tracking (0: depth only).
        degenerate_photometric_weight: weight of the colour term only for frames that depth
            alone leaves poorly conditioned (a bare wall, a door); 0: off. Default (None): 0.1, as
            the CLI for colour registered to depth; give 0 for frames whose colour is not (7-Scenes).
        min_mesh_weight, min_mesh_piece: meshing thresholds (defaults as the CLI).
        frame_rate: Hz, for timestamps of frames pushed without one.

    Raises ValueError for out-of-range options, FileNotFoundError for a missing model file.
    """

    def __new__(
        cls,
        intrinsics: Union[Intrinsics, Sequence[float]],
        *,
        voxel_size: float = 0.005,
        semantics: Union[bool, Literal["incremental", "full", "off"], None] = None,
        model: Optional[str] = None,
        keyframe_every: int = 10,
        truncation: float = 10.0,
        max_depth: Optional[float] = None,
        poses: Literal["track", "ground_truth"] = "track",
        mesh_budget: Optional[int] = None,
        realtime: bool = False,
        up: Optional[Sequence[float]] = None,
        context: float = 1.0,
        min_label_island: float = 0.06,
        structure: Literal["segments", "none"] = "segments",
        photometric_weight: float = 0.0,
        degenerate_photometric_weight: Optional[float] = None,
        min_mesh_weight: Optional[float] = None,
        min_mesh_piece: Optional[int] = None,
        frame_rate: float = 30.0,
    ) -> "Pipeline": ...
    def push_frame(
        self,
        depth: Union[npt.NDArray[np.uint16], npt.NDArray[np.float32]],
        color: npt.NDArray[np.uint8],
        *,
        pose: Optional[npt.NDArray[np.floating]] = None,
        timestamp: Optional[float] = None,
        depth_scale: float = 1000.0,
    ) -> FrameResult:
        """Tracks and fuses one frame (GIL released).

        Args:
            depth: uint16 ``(H, W)`` in ``1 / depth_scale`` metres (millimetres by default) or
                float32 ``(H, W)`` metres; 0 = missing. C-contiguous.
            color: uint8 ``(H, W, 3)`` RGB registered to depth. C-contiguous.
            pose: ``world_from_camera`` ``(4, 4)`` (needed with ``poses="ground_truth"``).
            timestamp: seconds (default: frames pushed / ``frame_rate``).
            depth_scale: units per metre of uint16 depth.

        Raises TypeError for a wrong dtype, ValueError for a wrong shape, a non-contiguous
        array, negative or NaN depth, a non-rigid or non-finite pose.
        """
    def push(self, frame: Frame) -> FrameResult:
        """Pushes a :class:`Frame` of a :class:`Dataset` (with its ground-truth pose)."""
    def run(self, dataset: Dataset, start: int = 0, stop: Optional[int] = None, step: int = 1) -> List[FrameResult]:
        """Pushes frames ``start:stop:step`` of ``dataset``, decoding and processing each with
        the GIL released (the fastest way to process a dataset)."""
    @property
    def pose(self) -> Optional[npt.NDArray[np.float64]]:
        """``world_from_camera`` of the last fused frame, or None before the first."""
    @property
    def intrinsics(self) -> Intrinsics: ...
    @property
    def has_semantics(self) -> bool: ...
    def trajectory(self) -> _Trajectory:
        """Poses of the fused frames."""
    def write_trajectory(self, path: _Path) -> None:
        """Writes the trajectory as TUM text (``timestamp tx ty tz qx qy qz qw``)."""
    def mesh(self) -> _Mesh:
        """The mesh as of the last keyframe, with per-vertex classes."""
    def finish(self) -> _Mesh:
        """Ends the stream: waits for the semantic back end, runs a last pass, brings the mesh
        up to date and returns it."""
    def timings(self) -> Dict[str, _StageTiming]:
        """Per-stage timings in milliseconds: tracking, fusion (per frame), meshing, semantic
        snapshot (per keyframe), semantic (per pass, back end), semantic wait, final meshing."""
    @property
    def front_end_seconds(self) -> float:
        """Seconds of front-end work and waits (what the CLI's real-time factor divides)."""
    @property
    def frame_counts(self) -> Tuple[int, int, int]:
        """(pushed, fused, not fused) frames."""
    @property
    def warnings(self) -> List[str]: ...

def segment(
    points: npt.NDArray[np.float32],
    colors: npt.NDArray[np.uint8],
    *,
    model: Optional[str] = None,
    structure: Literal["none", "segments", "planes", "all"] = "segments",
) -> npt.NDArray[np.uint8]:
    """Class ids uint8 ``(N,)`` of a coloured point cloud: ``points`` float32 ``(N, 3)``
    metres, z up; ``colors`` uint8 ``(N, 3)`` RGB. The network (the shipped model by
    default) labels 5 cm voxels, then ``structure`` refines them as ``semrecon segment
    --structure`` does (default: labels voted over geometric segments, and beam faces); every
    point takes its voxel's class."""

def write_ply(path: _Path, mesh: _Mesh, *, binary: bool = True) -> None:
    """Writes a mesh dict (``vertices`` required; ``faces`` int32/int64/uint32, ``colors``,
    ``labels`` (as a vertex ``label`` property), ``normals`` optional) as PLY, atomically;
    ``up`` (3 floats) and ``floor_height`` (float), when present, are recorded in the header."""

def read_ply(path: _Path) -> _Mesh:
    """Reads a PLY mesh or point cloud (``faces`` empty for a point cloud; ``labels`` 255
    where the file has none); ``up`` and ``floor_height`` (or ``None``) when the file records
    where gravity points (meshes of ``semrecon run``)."""

def default_model_path() -> str:
    """The model file used when no ``model=`` is given."""

def _set_package_model(path: str) -> None: ...

@final
class ConvGeometry:
    """One sparse convolution layer's geometry: the kernel map between an input and an output
    voxel set and the chunk plans of the kernels. Build once per coordinate set; reuse for
    every layer and for the backward pass.

    Coordinates: int32 ``(N, 4)`` rows ``(batch, x, y, z)``, batch 0 or 1, x, y, z in
    ``[-2**20, 2**20 - 1]``, rows distinct, C-contiguous. Weights: float32
    ``(K**3, C_in, C_out)`` (offset numbering in ``semrecon.sparse``).
    """

    @staticmethod
    def submanifold(coords: npt.NDArray[np.int32], kernel_size: int = 3) -> "ConvGeometry":
        """Submanifold convolution on ``coords`` (output set = input set), odd kernel 1..9."""
    @staticmethod
    def downsample(coords: npt.NDArray[np.int32]) -> "ConvGeometry":
        """Strided convolution (kernel 2, stride 2) to the coarse set ``coords // 2``
        (``out_coords``; batch kept, order of first appearance)."""
    @staticmethod
    def upsample(coarse: npt.NDArray[np.int32], fine: npt.NDArray[np.int32]) -> "ConvGeometry":
        """Transposed convolution (kernel 2) from ``coarse`` to ``fine``; every fine voxel's
        parent must be in ``coarse``."""
    def transposed(self) -> "ConvGeometry":
        """The transposed layer (down <-> up between the same sets); submanifold: itself."""
    @property
    def kind(self) -> Literal["submanifold", "down", "up"]: ...
    @property
    def kernel_volume(self) -> int: ...
    @property
    def n_in(self) -> int: ...
    @property
    def n_out(self) -> int: ...
    @property
    def num_pairs(self) -> int: ...
    @property
    def in_coords(self) -> npt.NDArray[np.int32]: ...
    @property
    def out_coords(self) -> npt.NDArray[np.int32]: ...
    def pairs(self, k: int) -> Tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """``(in_rows, out_rows)`` of offset ``k``."""
    def forward(
        self,
        features: npt.NDArray[np.float32],
        weight: npt.NDArray[np.float32],
        *,
        out: Optional[npt.NDArray[np.float32]] = None,
    ) -> npt.NDArray[np.float32]:
        """``features`` ``(n_in, C_in)``, ``weight`` ``(K**3, C_in, C_out)`` -> ``(n_out, C_out)``,
        written into ``out`` (C-contiguous, writeable, not ``features``) when given."""
    def backward_input(
        self, grad_out: npt.NDArray[np.float32], weight: npt.NDArray[np.float32]
    ) -> npt.NDArray[np.float32]:
        """``grad_out`` ``(n_out, C_out)``, ``weight`` -> gradient of the features ``(n_in, C_in)``."""
    def backward_weight(
        self, features: npt.NDArray[np.float32], grad_out: npt.NDArray[np.float32]
    ) -> npt.NDArray[np.float32]:
        """``features`` ``(n_in, C_in)``, ``grad_out`` ``(n_out, C_out)`` -> gradient of the
        weight ``(K**3, C_in, C_out)``."""
