//! `Pipeline`: the live system ([`semrecon_pipeline::Pipeline`]) for Python. Frames come in as
//! numpy arrays (or `Frame`s of a `Dataset`), tracking, fusion, meshing and the semantic back
//! end run in Rust with the GIL released, and the trajectory, the labelled mesh and the
//! timings come back as numpy arrays and dicts.
//!
//! The options and their defaults are those of `semrecon run` (5 mm voxels, a keyframe every
//! 10 frames, incremental semantics with the shipped model, no mesh budget with semantics and
//! 3072 chunks without), so that the same data gives the same mesh and labels as the CLI.

use std::num::NonZeroUsize;
use std::sync::{Mutex, MutexGuard};

use glam::Vec3;
use numpy::{PyArray1, PyArray2, PyArrayDyn};
use pyo3::exceptions::{PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use semrecon_data::{Frame as RustFrame, LabeledMesh};
use semrecon_pipeline::{
    FrameResult as RustResult, FrameStatus, PipelineConfig, PoseMode, SemanticMode, DEFAULT_MESH_BUDGET,
};
use semrecon_recon::{LostReason, MeshConfig, TrackerConfig, TsdfConfig};

use crate::arrays::{require_finite, rows, typed};
use crate::dataset::{intrinsics_arg, Dataset, Frame};
use crate::errors::{pipeline_err, value_error};

/// What happened to one frame: `status` (`"initialized"`, `"fused"`, `"relocalised"`,
/// `"lost"`, `"no_pose"`), `lost_reason` (why tracking failed, or `None`), `pose`
/// (`world_from_camera` float64 `(4, 4)` when fused, else `None`), `keyframe`,
/// `semantic_pass`, `index`.
#[pyclass(frozen, module = "semrecon")]
pub struct FrameResult(RustResult);

fn status_name(s: FrameStatus) -> &'static str {
    match s {
        FrameStatus::Initialized => "initialized",
        FrameStatus::Fused => "fused",
        FrameStatus::Relocalised => "relocalised",
        FrameStatus::Lost(_) => "lost",
        FrameStatus::NoPose => "no_pose",
    }
}

fn lost_reason_name(r: LostReason) -> &'static str {
    match r {
        LostReason::NoDepth => "no_depth",
        LostReason::NoModel => "no_model",
        LostReason::FewInliers => "few_inliers",
        LostReason::LargeResidual => "large_residual",
        LostReason::PoseJump => "pose_jump",
        LostReason::Degenerate => "degenerate",
    }
}

#[pymethods]
impl FrameResult {
    /// `"initialized"`, `"fused"`, `"relocalised"`, `"lost"` or `"no_pose"`.
    #[getter]
    fn status(&self) -> &'static str {
        status_name(self.0.status)
    }
    /// Why tracking failed (`"few_inliers"`, ...) for lost frames, else `None`.
    #[getter]
    fn lost_reason(&self) -> Option<&'static str> {
        match self.0.status {
            FrameStatus::Lost(r) => Some(lost_reason_name(r)),
            _ => None,
        }
    }
    /// Whether the frame was fused into the map.
    #[getter]
    fn fused(&self) -> bool {
        self.0.pose.is_some()
    }
    /// `world_from_camera` float64 `(4, 4)` when fused, else `None`.
    #[getter]
    fn pose<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArray2<f64>>>> {
        self.0.pose.as_ref().map(|p| crate::pose::to_array(py, p)).transpose()
    }
    /// Whether the frame was a keyframe (mesh updated, semantics considered).
    #[getter]
    fn keyframe(&self) -> bool {
        self.0.keyframe
    }
    /// Whether a semantic pass started at this frame.
    #[getter]
    fn semantic_pass(&self) -> bool {
        self.0.semantic_pass
    }
    /// The frame's index (frames pushed before it).
    #[getter]
    fn index(&self) -> usize {
        self.0.index
    }

    fn __repr__(&self) -> String {
        let reason = self.lost_reason().map(|r| format!(" ({r})")).unwrap_or_default();
        let keyframe = if self.0.keyframe { "True" } else { "False" };
        format!("FrameResult(index={}, status='{}'{reason}, keyframe={keyframe})", self.0.index, self.status())
    }
}

/// Pipeline(intrinsics, *, voxel_size=0.005, semantics=True, model=None, keyframe_every=10, ...)
///
/// The live pipeline: frame-to-model tracking and TSDF fusion of every frame, meshing and a
/// semantic pass (the network, in a back-end thread) every `keyframe_every` frames. Options
/// and defaults are those of `semrecon run`: `voxel_size` metres (0.002..0.05); `semantics`
/// True/"incremental", "full" or False/"off"; `model` a safetensors file (default: the shipped
/// model); `truncation` voxels; `max_depth` metres; `poses` "track" or "ground_truth";
/// `mesh_budget` chunks per keyframe; `realtime`; `up` (x, y, z); `context` metres;
/// `min_label_island` m^2; `structure` "segments" or "none"; `photometric_weight`; `degenerate_photometric_weight`; `min_mesh_weight`; `min_mesh_piece`
/// triangles; `frame_rate` Hz. `intrinsics`: an `Intrinsics` or (width, height, fx, fy, cx, cy)
/// in pixels. Full reference: semrecon/_native.pyi and docs/python.md.
#[pyclass(module = "semrecon")]
pub struct Pipeline {
    inner: Mutex<semrecon_pipeline::Pipeline>,
    intrinsics: semrecon_data::Intrinsics,
    /// Frames pushed so far (the next frame's index).
    pushed: Mutex<usize>,
    frame_rate: f64,
}

/// `semantics=`: `True`/`"incremental"`, `"full"`, `False`/`"off"`.
fn semantic_mode(obj: &Bound<'_, PyAny>, context: f32) -> PyResult<Option<SemanticMode>> {
    if let Ok(b) = obj.extract::<bool>() {
        return Ok(b.then_some(SemanticMode::Incremental { context_m: context }));
    }
    match obj.extract::<String>().ok().as_deref() {
        Some("incremental") => Ok(Some(SemanticMode::Incremental { context_m: context })),
        Some("full") => Ok(Some(SemanticMode::Full)),
        Some("off") => Ok(None),
        _ => Err(PyValueError::new_err(format!(
            "semantics: expected True, False, \"incremental\", \"full\" or \"off\", got {}",
            obj.repr().map(|r| r.to_string()).unwrap_or_default()
        ))),
    }
}

/// A `(3,)` direction argument.
fn vec3_arg(arg: &str, obj: &Bound<'_, PyAny>) -> PyResult<Vec3> {
    let v: [f32; 3] = obj.extract().map_err(|_| PyTypeError::new_err(format!("{arg}: expected three numbers")))?;
    require_finite(arg, &v)?;
    Ok(Vec3::from(v))
}

impl Pipeline {
    fn lock(&self) -> PyResult<MutexGuard<'_, semrecon_pipeline::Pipeline>> {
        self.inner.lock().map_err(|_| PyRuntimeError::new_err("the pipeline failed in an earlier call"))
    }

    /// Pushes one frame with the GIL released.
    fn push_rust(&self, py: Python<'_>, frame: RustFrame) -> PyResult<FrameResult> {
        let mut guard = self.lock()?;
        // `&mut` moves into the closure: the pipeline is `Send`, not `Sync`.
        let pipeline = &mut *guard;
        let result = py.detach(move || pipeline.push_frame(&frame)).map_err(pipeline_err)?;
        if let Ok(mut n) = self.pushed.lock() {
            *n += 1;
        }
        Ok(FrameResult(result))
    }

    fn next_index(&self) -> usize {
        self.pushed.lock().map_or(0, |n| *n)
    }
}

/// Depth argument: uint16 `(H, W)` in `1 / depth_scale` metres, or float32 `(H, W)` metres.
fn depth_arg(obj: &Bound<'_, PyAny>, h: usize, w: usize, depth_scale: f32) -> PyResult<Vec<f32>> {
    let shape = [Some(h), Some(w)];
    let expected = format!("({h}, {w})");
    if let Ok(d) = typed::<u16>("depth", obj, "uint16", &shape, &expected) {
        // As the dataset readers convert (`semrecon_data::depth_image::load_depth`): a division,
        // so that uint16 frames give the same metres as the files would.
        return Ok(d.slice().iter().map(|&v| if v == 0 { 0.0 } else { v as f32 / depth_scale }).collect());
    }
    let d = typed::<f32>("depth", obj, "float32", &shape, &expected).map_err(|e| {
        // Name both accepted dtypes when the dtype was the problem.
        if e.is_instance_of::<PyTypeError>(obj.py()) {
            PyTypeError::new_err(format!(
                "depth: expected uint16 (millimetres, or 1/depth_scale m) or float32 (metres) with shape {expected}; {}",
                e.value(obj.py())
            ))
        } else {
            e
        }
    })?;
    let v = d.slice();
    if let Some(i) = v.iter().position(|d| !(d.is_finite() && *d >= 0.0)) {
        return Err(value_error(
            "depth",
            format!(
                "pixel ({}, {}) is {} metres (expected finite and >= 0; 0 marks missing depth)",
                i / w,
                i % w,
                v[i]
            ),
        ));
    }
    Ok(v.to_vec())
}

/// The mesh as a dict of numpy arrays.
pub fn mesh_dict<'py>(py: Python<'py>, mesh: LabeledMesh) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let n = mesh.positions.len();
    let v: Vec<f32> = mesh.positions.iter().flat_map(|p| p.to_array()).collect();
    d.set_item("vertices", rows(py, v, 3)?)?;
    let faces = mesh
        .triangles
        .iter()
        .flatten()
        .map(|&i| i32::try_from(i))
        .collect::<Result<Vec<i32>, _>>()
        .map_err(|_| PyValueError::new_err("mesh: more than 2^31 vertices"))?;
    d.set_item("faces", rows(py, faces, 3)?)?;
    let colors: Vec<u8> =
        if mesh.colors.len() == n { mesh.colors.iter().flatten().copied().collect() } else { vec![128; n * 3] };
    d.set_item("colors", rows(py, colors, 3)?)?;
    let labels =
        if mesh.vertex_labels.len() == n { mesh.vertex_labels } else { vec![semrecon_data::class::UNLABELED; n] };
    d.set_item("labels", PyArray1::from_vec(py, labels))?;
    let normals: Vec<f32> =
        if mesh.normals.len() == n { mesh.normals.iter().flat_map(|p| p.to_array()).collect() } else { Vec::new() };
    d.set_item("normals", rows(py, normals, 3)?)?;
    Ok(d)
}

#[pymethods]
impl Pipeline {
    #[new]
    #[pyo3(signature = (
        intrinsics, *, voxel_size = 0.005, semantics = None, model = None, keyframe_every = 10,
        truncation = 10.0, max_depth = None, poses = "track", mesh_budget = None, realtime = false,
        up = None, context = 1.0, min_label_island = 0.06, structure = "segments", photometric_weight = 0.0,
        degenerate_photometric_weight = None, min_mesh_weight = None, min_mesh_piece = None, frame_rate = 30.0
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        intrinsics: &Bound<'_, PyAny>,
        voxel_size: f32,
        semantics: Option<&Bound<'_, PyAny>>,
        model: Option<String>,
        keyframe_every: usize,
        truncation: f32,
        max_depth: Option<f32>,
        poses: &str,
        mesh_budget: Option<usize>,
        realtime: bool,
        up: Option<&Bound<'_, PyAny>>,
        context: f32,
        min_label_island: f32,
        structure: &str,
        photometric_weight: f32,
        degenerate_photometric_weight: Option<f32>,
        min_mesh_weight: Option<f32>,
        min_mesh_piece: Option<usize>,
        frame_rate: f64,
    ) -> PyResult<Self> {
        let intrinsics = intrinsics_arg(intrinsics)?;
        let mode = match semantics {
            None => Some(SemanticMode::Incremental { context_m: context }),
            Some(s) => semantic_mode(s, context)?,
        };
        if keyframe_every == 0 {
            return Err(value_error("keyframe_every", "must be at least 1"));
        }
        if !(frame_rate.is_finite() && frame_rate > 0.0) {
            return Err(value_error("frame_rate", format!("{frame_rate} Hz is not positive")));
        }
        let mut tsdf = TsdfConfig::with_voxel_size(voxel_size).map_err(|e| value_error("voxel_size", e.to_string()))?;
        tsdf.truncation_voxels = truncation;
        if let Some(d) = max_depth {
            tsdf.max_depth = d;
        }
        let poses = match poses {
            "track" => PoseMode::Track,
            "ground_truth" => PoseMode::GroundTruth,
            other => {
                return Err(value_error("poses", format!("expected \"track\" or \"ground_truth\", got {other:?}")))
            }
        };
        // As `semrecon run`: the same budget with semantics (the network reads the map).
        let default_budget = DEFAULT_MESH_BUDGET;
        let mesh = MeshConfig {
            min_weight: min_mesh_weight.unwrap_or(MeshConfig::RECOMMENDED.min_weight),
            min_component_triangles: min_mesh_piece.unwrap_or(MeshConfig::RECOMMENDED.min_component_triangles),
        };
        let mut config = PipelineConfig {
            tsdf,
            mesh,
            mesh_budget: NonZeroUsize::new(mesh_budget.unwrap_or(default_budget)),
            tracker: TrackerConfig {
                keyframe_interval: keyframe_every,
                photometric_weight,
                // Frames pushed from Python come from cameras that register colour to depth.
                degenerate_photometric_weight: degenerate_photometric_weight
                    .unwrap_or_else(|| TrackerConfig::colour_fallback_weight(true)),
                ..TrackerConfig::default()
            },
            poses,
            initial_pose: None,
            keyframe_every,
            ..PipelineConfig::default()
        };
        if let Some(m) = mode {
            config.semantics.mode = m;
        }
        config.semantics.realtime = realtime;
        config.semantics.up = up.map(|u| vec3_arg("up", u)).transpose()?;
        config.semantics.min_island_m2 = min_label_island;
        config.semantics.segment_vote = match structure {
            "segments" => true,
            "none" => false,
            other => return Err(value_error("structure", format!("expected \"segments\" or \"none\", got {other:?}"))),
        };
        config.validate().map_err(pipeline_err)?;
        let pipeline = py.detach(|| {
            let net = match mode {
                Some(_) => Some(crate::model::load(model.as_deref())?),
                None => None,
            };
            semrecon_pipeline::Pipeline::new(config, intrinsics, net).map_err(pipeline_err)
        })?;
        Ok(Self { inner: Mutex::new(pipeline), intrinsics, pushed: Mutex::new(0), frame_rate })
    }

    /// push_frame(depth, color, *, pose=None, timestamp=None, depth_scale=1000.0) -> FrameResult
    ///
    /// Tracks and fuses one frame (GIL released). `depth`: uint16 (H, W) in 1/depth_scale
    /// metres (millimetres by default) or float32 (H, W) metres, 0 = missing; `color`: uint8
    /// (H, W, 3) RGB registered to depth; both C-contiguous. `pose`: world_from_camera (4, 4)
    /// float64/float32 (every frame's pose with poses="ground_truth"; with tracking, where the
    /// first frame starts). `timestamp`: seconds (default: frames pushed / frame_rate).
    /// Raises TypeError (dtype) or ValueError (shape, strides, NaN or negative depth, a pose
    /// that is not rigid) naming the argument.
    #[pyo3(signature = (depth, color, *, pose = None, timestamp = None, depth_scale = 1000.0))]
    fn push_frame(
        &self,
        py: Python<'_>,
        depth: &Bound<'_, PyAny>,
        color: &Bound<'_, PyAny>,
        pose: Option<&Bound<'_, PyAny>>,
        timestamp: Option<f64>,
        depth_scale: f32,
    ) -> PyResult<FrameResult> {
        let (h, w) = (self.intrinsics.height as usize, self.intrinsics.width as usize);
        if !(depth_scale.is_finite() && depth_scale > 0.0) {
            return Err(value_error("depth_scale", format!("{depth_scale} units per metre is not positive")));
        }
        let depth = depth_arg(depth, h, w, depth_scale)?;
        let color = typed::<u8>("color", color, "uint8", &[Some(h), Some(w), Some(3)], &format!("({h}, {w}, 3)"))?;
        let color: Vec<[u8; 3]> = color.slice().chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let world_from_camera = pose.map(|p| crate::pose::from_array("pose", p)).transpose()?;
        let index = self.next_index();
        let timestamp = timestamp.unwrap_or(index as f64 / self.frame_rate);
        if !timestamp.is_finite() {
            return Err(value_error("timestamp", format!("{timestamp} is not finite")));
        }
        let frame =
            RustFrame { index, timestamp, depth, color, intrinsics: self.intrinsics, world_from_camera, labels: None };
        self.push_rust(py, frame)
    }

    /// Pushes a `Frame` of a `Dataset` (its ground-truth pose included).
    fn push(&self, py: Python<'_>, frame: &Bound<'_, Frame>) -> PyResult<FrameResult> {
        let f = &frame.get().0;
        if f.intrinsics.width != self.intrinsics.width || f.intrinsics.height != self.intrinsics.height {
            return Err(value_error(
                "frame",
                format!(
                    "{}x{} frame for a {}x{} pipeline",
                    f.intrinsics.width, f.intrinsics.height, self.intrinsics.width, self.intrinsics.height
                ),
            ));
        }
        self.push_rust(py, f.clone())
    }

    /// Runs frames `start..stop` (step `step`) of `dataset` through the pipeline, reading
    /// each with the GIL released; returns the frames' results.
    #[pyo3(signature = (dataset, start = 0, stop = None, step = 1))]
    fn run(
        &self,
        py: Python<'_>,
        dataset: &Bound<'_, Dataset>,
        start: usize,
        stop: Option<usize>,
        step: usize,
    ) -> PyResult<Vec<FrameResult>> {
        if step == 0 {
            return Err(value_error("step", "must be at least 1"));
        }
        let source = dataset.get().source.clone();
        let stop = stop.unwrap_or(source.len()).min(source.len());
        let mut results = Vec::new();
        for i in (start..stop).step_by(step) {
            let frame = py.detach(|| source.frame(i)).map_err(crate::errors::data_err)?;
            results.push(self.push_rust(py, frame)?);
            py.check_signals()?;
        }
        Ok(results)
    }

    /// The pose of the last fused frame, float64 `(4, 4)`, or `None` before the first.
    #[getter]
    fn pose<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArray2<f64>>>> {
        let pose = self.lock()?.pose();
        pose.as_ref().map(|p| crate::pose::to_array(py, p)).transpose()
    }

    /// The camera intrinsics.
    #[getter]
    fn intrinsics(&self) -> crate::dataset::Intrinsics {
        crate::dataset::Intrinsics(self.intrinsics)
    }

    /// Whether a network labels the map.
    #[getter]
    fn has_semantics(&self) -> PyResult<bool> {
        Ok(self.lock()?.has_semantics())
    }

    /// Poses of the fused frames: `{"timestamps": float64 (N,), "poses": float64 (N, 4, 4)}`.
    fn trajectory<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let t = self.lock()?.trajectory().clone();
        let d = PyDict::new(py);
        d.set_item("timestamps", PyArray1::from_vec(py, t.timestamps.clone()))?;
        let mut flat = Vec::with_capacity(t.poses.len() * 16);
        for p in &t.poses {
            let m = glam::Mat4::from(*p);
            for r in 0..4 {
                flat.extend(m.row(r).to_array().map(f64::from));
            }
        }
        let poses: Bound<'py, PyArrayDyn<f64>> = crate::arrays::shaped(py, flat, &[t.poses.len(), 4, 4])?;
        d.set_item("poses", poses)?;
        Ok(d)
    }

    /// Writes the trajectory as TUM text (`timestamp tx ty tz qx qy qz qw`).
    fn write_trajectory(&self, py: Python<'_>, path: std::path::PathBuf) -> PyResult<()> {
        let t = self.lock()?.trajectory().clone();
        py.detach(|| t.write_tum(&path)).map_err(crate::errors::data_err)
    }

    /// The mesh as of the last keyframe: {"vertices": float32 (V, 3) metres, "faces": int32
    /// (F, 3), "colors": uint8 (V, 3) RGB, "labels": uint8 (V,) class ids (255 = unlabelled),
    /// "normals": float32 (V, 3)}.
    fn mesh<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let mut guard = self.lock()?;
        let pipeline = &mut *guard;
        let mesh = py.detach(move || pipeline.mesh());
        drop(guard);
        mesh_dict(py, mesh)
    }

    /// Ends the stream (waits for the back end, runs a last semantic pass, brings the mesh up to
    /// date) and returns the mesh dict of `mesh()`.
    fn finish<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let mut guard = self.lock()?;
        let pipeline = &mut *guard;
        let mesh = py.detach(move || pipeline.finish()).map_err(pipeline_err)?;
        drop(guard);
        mesh_dict(py, mesh)
    }

    /// Per-stage timings: `{stage: {"median_ms", "p95_ms", "max_ms", "count", "total_ms"}}`.
    fn timings<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let pipeline = self.lock()?;
        let d = PyDict::new(py);
        for (stage, s) in pipeline.timings().summaries() {
            let e = PyDict::new(py);
            e.set_item("median_ms", s.median_ms)?;
            e.set_item("p95_ms", s.p95_ms)?;
            e.set_item("max_ms", s.max_ms)?;
            e.set_item("count", s.count)?;
            e.set_item("total_ms", s.total_ms)?;
            d.set_item(stage, e)?;
        }
        Ok(d)
    }

    /// Seconds the front end spent (tracking, fusion, meshing, semantic snapshots and waits):
    /// what the CLI's real-time factor divides.
    #[getter]
    fn front_end_seconds(&self) -> PyResult<f64> {
        Ok(self.lock()?.front_end_seconds())
    }

    /// `(pushed, fused, not fused)` frame counts.
    #[getter]
    fn frame_counts(&self) -> PyResult<(usize, usize, usize)> {
        Ok(self.lock()?.frame_counts())
    }

    /// Problems that did not stop the pipeline (failed semantic passes).
    #[getter]
    fn warnings(&self) -> PyResult<Vec<String>> {
        Ok(self.lock()?.warnings().to_vec())
    }

    fn __repr__(&self) -> String {
        let k = &self.intrinsics;
        format!("Pipeline({}x{}, {} frames pushed)", k.width, k.height, self.next_index())
    }
}

/// Adds the classes to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Pipeline>()?;
    m.add_class::<FrameResult>()?;
    Ok(())
}
