"""Bad input becomes a Python exception naming the argument and what was expected: never a
crash, never silently wrong results (a strided view is refused, not read as contiguous)."""

import numpy as np
import pytest

import semrecon
from semrecon.sparse import ConvGeometry

K = semrecon.Intrinsics(32, 24, 30.0, 30.0, 15.5, 11.5)


@pytest.fixture(scope="module")
def pipeline():
    return semrecon.Pipeline(K, semantics=False, voxel_size=0.02, truncation=4.0)


def depth(dtype=np.float32, value=1.5):
    return np.full((24, 32), value, dtype=dtype)


def color():
    return np.zeros((24, 32, 3), np.uint8)


@pytest.mark.parametrize(
    "make,error,match",
    [
        (lambda: (depth(np.int32), color()), TypeError, r"depth: expected uint16 .* or float32"),
        (lambda: (depth(np.float64), color()), TypeError, r"depth: .*float64"),
        (lambda: (depth().tolist(), color()), TypeError, r"depth: .*got list"),
        (lambda: (np.zeros((24, 31), np.float32), color()), ValueError, r"depth: expected shape \(24, 32\)"),
        (lambda: (np.zeros((24, 32, 1), np.float32), color()), ValueError, r"depth: expected shape"),
        (lambda: (np.zeros((24, 64), np.float32)[:, ::2], color()), ValueError, r"depth: .*not C-contiguous"),
        (lambda: (np.asfortranarray(np.zeros((24, 32), np.float32)), color()), ValueError, "not C-contiguous"),
        (lambda: (depth(value=np.nan), color()), ValueError, r"depth: pixel \(0, 0\) is NaN"),
        (lambda: (depth(value=-1.0), color()), ValueError, r"depth: pixel \(0, 0\) is -1"),
        (lambda: (depth(value=np.inf), color()), ValueError, r"depth: pixel \(0, 0\) is inf"),
        (lambda: (depth(), color().astype(np.float32)), TypeError, r"color: expected dtype uint8"),
        (lambda: (depth(), np.zeros((24, 32, 4), np.uint8)), ValueError, r"color: expected shape \(24, 32, 3\)"),
        (lambda: (depth(), np.zeros((24, 32, 6), np.uint8)[:, :, ::2]), ValueError, "color: .*not C-contiguous"),
        (lambda: (depth().astype(">f4"), color()), TypeError, "depth"),
    ],
)
def test_bad_frames(pipeline, make, error, match):
    d, c = make()
    with pytest.raises(error, match=match):
        pipeline.push_frame(d, c)


@pytest.mark.parametrize(
    "pose,match",
    [
        (np.full((4, 4), np.nan), r"pose: entry \(0, 0\) is NaN"),
        (np.eye(3), r"pose: expected shape \(4, 4\)"),
        (np.diag([2.0, 1.0, 1.0, 1.0]), "pose: the upper-left 3x3 block is not a rotation"),
        (np.diag([-1.0, 1.0, 1.0, 1.0]), "not a rotation"),
        (np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]], float), "pose: last row"),
    ],
)
def test_bad_poses(pipeline, pose, match):
    with pytest.raises(ValueError, match=match):
        pipeline.push_frame(depth(), color(), pose=pose)


def test_bad_pose_dtype(pipeline):
    with pytest.raises(TypeError, match="pose: expected dtype float64"):
        pipeline.push_frame(depth(), color(), pose=np.eye(4, dtype=np.int64))


def test_a_valid_frame_still_works_after_errors(pipeline):
    statuses = {"initialized", "fused", "lost"}  # a flat wall is too plain to track: lost is fine
    assert pipeline.push_frame(depth(), color()).status in statuses
    assert pipeline.push_frame(depth(np.uint16, 1500), color(), pose=np.eye(4, dtype=np.float32)).status in statuses


@pytest.mark.parametrize(
    "kwargs,error,match",
    [
        (dict(voxel_size=0.5), ValueError, "voxel_size: .*outside 0.002..0.05"),
        (dict(voxel_size=float("nan")), ValueError, "voxel_size"),
        (dict(semantics="maybe"), ValueError, "semantics: expected True, False"),
        (dict(poses="magic"), ValueError, "poses: expected"),
        (dict(structure="planes"), ValueError, "structure: expected"),
        (dict(keyframe_every=0), ValueError, "keyframe_every"),
        (dict(up=(0, 0, float("nan"))), ValueError, "up: value NaN"),
        (dict(model="/no/such/model.safetensors"), FileNotFoundError, "model: no file at /no/such"),
        (dict(truncation=1000.0), ValueError, "truncation"),
    ],
)
def test_bad_pipeline_options(kwargs, error, match):
    with pytest.raises(error, match=match):
        semrecon.Pipeline(K, **kwargs)


def test_bad_intrinsics():
    with pytest.raises(ValueError, match="not a valid camera"):
        semrecon.Intrinsics(0, 24, 30.0, 30.0, 15.5, 11.5)
    with pytest.raises(TypeError, match="intrinsics: expected"):
        semrecon.Pipeline("640x480")
    assert semrecon.Pipeline((32, 24, 30.0, 30.0, 15.5, 11.5), semantics=False).intrinsics == K


def test_a_model_file_that_is_not_a_model(tmp_path):
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a model")
    with pytest.raises(ValueError, match="bad.safetensors"):
        semrecon.segment(np.zeros((1, 3), np.float32), np.zeros((1, 3), np.uint8), model=str(bad))


def test_bad_segment_input():
    pts = np.zeros((5, 3), np.float32)
    cols = np.zeros((5, 3), np.uint8)
    with pytest.raises(TypeError, match="points: expected dtype float32"):
        semrecon.segment(pts.astype(np.float64), cols)
    with pytest.raises(ValueError, match=r"colors: expected shape \(5, 3\), one per point"):
        semrecon.segment(pts, cols[:4])
    with pytest.raises(ValueError, match="points: value NaN at flat index 4"):
        bad = pts.copy()
        bad[1, 1] = np.nan
        semrecon.segment(bad, cols)
    with pytest.raises(ValueError, match="points: .*not C-contiguous"):
        semrecon.segment(np.zeros((3, 5), np.float32).T, cols)
    with pytest.raises(ValueError, match="structure: `bogus`: expected one of none, segments, planes, all"):
        semrecon.segment(pts, cols, structure="bogus")


def test_bad_ply(tmp_path):
    v = np.zeros((3, 3), np.float32)
    with pytest.raises(ValueError, match=r"mesh\['faces'\]: face 0 has vertex index 3, outside 0..3"):
        semrecon.write_ply(tmp_path / "m.ply", {"vertices": v, "faces": np.array([[0, 1, 3]], np.int32)})
    with pytest.raises(KeyError, match="vertices"):
        semrecon.write_ply(tmp_path / "m.ply", {"faces": np.zeros((0, 3), np.int32)})
    with pytest.raises(TypeError, match="mesh: expected a dict"):
        semrecon.write_ply(tmp_path / "m.ply", v)
    with pytest.raises(FileNotFoundError):
        semrecon.read_ply(tmp_path / "missing.ply")
    (tmp_path / "junk.ply").write_text("not a ply")
    with pytest.raises(ValueError, match="junk.ply"):
        semrecon.read_ply(tmp_path / "junk.ply")
    with pytest.raises(FileNotFoundError):
        semrecon.write_ply(tmp_path / "no" / "dir" / "m.ply", {"vertices": v})


def coords(rows):
    return np.array(rows, dtype=np.int32)


@pytest.mark.parametrize(
    "c,error,match",
    [
        (coords([[0, 0, 0, 0], [2, 0, 0, 0]]), ValueError, r"coordinate \[0, 0, 0, 2\] at row 1 is outside .*batch in \[0, 1\]"),
        (coords([[0, 1 << 20, 0, 0]]), ValueError, "at row 0 is outside the key range"),
        (coords([[0, 0, 0, 0], [-1, 0, 0, 0]]), ValueError, "outside the key range"),
        (coords([[0, 1, 2, 3], [0, 1, 2, 3]]), ValueError, "duplicate coordinate"),
        (np.zeros((3, 4), np.int64), TypeError, r"coords: expected dtype int32 with shape \(N, 4\)"),
        (np.zeros((3, 3), np.int32), ValueError, r"coords: expected shape \(N, 4\)"),
        (np.zeros((4, 8), np.int32)[:, ::2], ValueError, "coords: .*not C-contiguous"),
    ],
)
def test_bad_coordinates(c, error, match):
    for build in (ConvGeometry.submanifold, ConvGeometry.downsample):
        with pytest.raises(error, match=match):
            build(c)


def test_bad_conv_arrays():
    rng = np.random.default_rng(0)
    c = np.unique(rng.integers(0, 6, (50, 4)).astype(np.int32) % [2, 6, 6, 6], axis=0).astype(np.int32)
    g = ConvGeometry.submanifold(c)
    n = g.n_in
    x = rng.standard_normal((n, 4)).astype(np.float32)
    w = rng.standard_normal((27, 4, 2)).astype(np.float32)
    with pytest.raises(ValueError, match=rf"features: expected shape \({n}, C\), one row per input voxel"):
        g.forward(x[:-1], w)
    with pytest.raises(ValueError, match=r"weight: expected shape \(27, 4, C_out\)"):
        g.forward(x, w[:, :3])
    with pytest.raises(ValueError, match="weight: expected shape"):
        g.forward(x, w.reshape(27, 8))
    with pytest.raises(TypeError, match="weight: expected dtype float32"):
        g.forward(x, w.astype(np.float64))
    # A strided view of the right shape is refused, not read as if contiguous.
    wide = np.repeat(x, 2, axis=1)
    with pytest.raises(ValueError, match="features: .*not C-contiguous"):
        g.forward(wide[:, ::2], w)
    with pytest.raises(ValueError, match=r"weight: expected shape \(27, C_in, 3\)"):
        g.backward_input(np.zeros((n, 3), np.float32), w)
    with pytest.raises(ValueError, match=r"grad_out: expected shape"):
        g.backward_input(np.zeros((n + 1, 2), np.float32), w)
    with pytest.raises(ValueError, match=r"grad_out: expected shape"):
        g.backward_weight(x, np.zeros((n + 1, 2), np.float32))
    with pytest.raises(ValueError, match="k: offset 27 of a kernel with 27 offsets"):
        g.pairs(27)
    with pytest.raises(ValueError, match="kernel size 4 is not supported"):
        ConvGeometry.submanifold(c, 4)
    fine = coords([[0, 4, 4, 4]])
    with pytest.raises(ValueError, match="has no parent in the coarse set"):
        ConvGeometry.upsample(coords([[0, 0, 0, 0]]), fine)


def test_unaligned_arrays_are_refused(pipeline):
    raw = np.zeros(24 * 32 * 4 + 1, np.uint8)
    unaligned = np.frombuffer(raw.data, dtype=np.float32, count=24 * 32, offset=1).reshape(24, 32)
    assert not unaligned.flags.aligned
    with pytest.raises(ValueError, match="depth: the array's data is not aligned"):
        pipeline.push_frame(unaligned, color())


def test_sizes_that_would_exhaust_memory_are_refused():
    with pytest.raises(ValueError, match="intrinsics: 100000x100000 images; at most 8192"):
        semrecon.Pipeline((100000, 100000, 500.0, 500.0, 0.0, 0.0), semantics=False)
    with pytest.raises(ValueError, match="synthetic_scan: 2 frames of 100000x48"):
        semrecon.synthetic_scan(1, frames=2, width=100000, height=48)
