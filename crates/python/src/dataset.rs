//! Datasets and frames: `open_dataset("KIND:PATH")` (7-Scenes, TUM, Redwood, ScanNet,
//! Replica, `synth:SEED`) and `synthetic_scan(seed, ...)` give a `Dataset` (a sequence of
//! `Frame`s, indexable and iterable) over [`semrecon_data::FrameSource`]; `Intrinsics` is the
//! pinhole camera. Frames are decoded on access, with the GIL released.

use std::sync::Arc;

use numpy::{PyArray2, PyArrayDyn};
use pyo3::exceptions::{PyIndexError, PyValueError};
use pyo3::prelude::*;
use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
use semrecon_data::synth::RoomStyle;
use semrecon_data::{DatasetSpec, FrameSource};

use crate::arrays::shaped;
use crate::errors::data_err;

/// Pinhole intrinsics of the depth image: `Intrinsics(width, height, fx, fy, cx, cy)`, pixels;
/// pixel centres at integer coordinates.
#[pyclass(frozen, module = "semrecon")]
#[derive(Clone)]
pub struct Intrinsics(pub semrecon_data::Intrinsics);

#[pymethods]
impl Intrinsics {
    #[new]
    fn new(width: u32, height: u32, fx: f32, fy: f32, cx: f32, cy: f32) -> PyResult<Self> {
        semrecon_data::Intrinsics::new(width, height, fx, fy, cx, cy).map(Self).map_err(data_err)
    }

    /// Image width, pixels.
    #[getter]
    fn width(&self) -> u32 {
        self.0.width
    }
    /// Image height, pixels.
    #[getter]
    fn height(&self) -> u32 {
        self.0.height
    }
    /// Focal length along x, pixels.
    #[getter]
    fn fx(&self) -> f32 {
        self.0.fx
    }
    /// Focal length along y, pixels.
    #[getter]
    fn fy(&self) -> f32 {
        self.0.fy
    }
    /// Principal point x, pixels.
    #[getter]
    fn cx(&self) -> f32 {
        self.0.cx
    }
    /// Principal point y, pixels.
    #[getter]
    fn cy(&self) -> f32 {
        self.0.cy
    }

    /// The 3x3 camera matrix `K` (float64).
    fn matrix<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let k = &self.0;
        let v = [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0].map(f64::from).to_vec();
        crate::arrays::rows(py, v, 3)
    }

    /// The same camera at another resolution.
    fn scaled(&self, width: u32, height: u32) -> PyResult<Self> {
        if width == 0 || height == 0 {
            return Err(PyValueError::new_err(format!("scaled: {width}x{height} is an empty image")));
        }
        Ok(Self(self.0.scaled(width, height)))
    }

    fn __repr__(&self) -> String {
        let k = &self.0;
        format!(
            "Intrinsics(width={}, height={}, fx={}, fy={}, cx={}, cy={})",
            k.width, k.height, k.fx, k.fy, k.cx, k.cy
        )
    }

    fn __eq__(&self, other: &Self) -> bool {
        self.0 == other.0
    }
}

/// Largest image side accepted for cameras made here (larger images would only exhaust
/// memory, which aborts the interpreter instead of raising).
pub const MAX_SIDE: u32 = 8192;

/// The intrinsics argument: an `Intrinsics` or a sequence `(width, height, fx, fy, cx, cy)`;
/// at most [`MAX_SIDE`] pixels a side.
pub fn intrinsics_arg(obj: &Bound<'_, PyAny>) -> PyResult<semrecon_data::Intrinsics> {
    let k = intrinsics_any(obj)?;
    if k.width > MAX_SIDE || k.height > MAX_SIDE {
        return Err(PyValueError::new_err(format!(
            "intrinsics: {}x{} images; at most {MAX_SIDE} pixels a side are supported",
            k.width, k.height
        )));
    }
    Ok(k)
}

fn intrinsics_any(obj: &Bound<'_, PyAny>) -> PyResult<semrecon_data::Intrinsics> {
    if let Ok(k) = obj.cast::<Intrinsics>() {
        return Ok(k.get().0);
    }
    let (w, h, fx, fy, cx, cy): (u32, u32, f32, f32, f32, f32) = obj.extract().map_err(|_| {
        pyo3::exceptions::PyTypeError::new_err(
            "intrinsics: expected semrecon.Intrinsics or (width, height, fx, fy, cx, cy)",
        )
    })?;
    semrecon_data::Intrinsics::new(w, h, fx, fy, cx, cy).map_err(data_err)
}

/// One RGB-D frame: `depth` float32 `(H, W)` metres (0 = missing), `color` uint8 `(H, W, 3)`,
/// `pose` float64 `(4, 4)` `world_from_camera` or `None`, `labels` uint8 `(H, W)` (rendered
/// data only) or `None`, `index`, `timestamp` seconds. Each access of an array attribute
/// returns a new array.
#[pyclass(frozen, module = "semrecon")]
pub struct Frame(pub semrecon_data::Frame);

#[pymethods]
impl Frame {
    /// Index in the dataset.
    #[getter]
    fn index(&self) -> usize {
        self.0.index
    }
    /// Capture time, seconds.
    #[getter]
    fn timestamp(&self) -> f64 {
        self.0.timestamp
    }
    /// Camera intrinsics.
    #[getter]
    fn intrinsics(&self) -> Intrinsics {
        Intrinsics(self.0.intrinsics)
    }
    /// Depth, float32 `(H, W)`, metres along the optical axis; 0 where missing.
    #[getter]
    fn depth<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let k = &self.0.intrinsics;
        shaped(py, self.0.depth.clone(), &[k.height as usize, k.width as usize])
    }
    /// Colour registered to the depth image, uint8 `(H, W, 3)` RGB.
    #[getter]
    fn color<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArrayDyn<u8>>> {
        let k = &self.0.intrinsics;
        let flat: Vec<u8> = self.0.color.iter().flatten().copied().collect();
        shaped(py, flat, &[k.height as usize, k.width as usize, 3])
    }
    /// Ground-truth `world_from_camera`, float64 `(4, 4)`, or `None`.
    #[getter]
    fn pose<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArray2<f64>>>> {
        self.0.world_from_camera.as_ref().map(|p| crate::pose::to_array(py, p)).transpose()
    }
    /// Per-pixel class ids, uint8 `(H, W)` (255 = nothing), or `None`.
    #[getter]
    fn labels<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArrayDyn<u8>>>> {
        let k = &self.0.intrinsics;
        self.0.labels.clone().map(|l| shaped(py, l, &[k.height as usize, k.width as usize])).transpose()
    }

    fn __repr__(&self) -> String {
        let k = &self.0.intrinsics;
        format!(
            "Frame(index={}, timestamp={:.3}, {}x{}, pose={})",
            self.0.index,
            self.0.timestamp,
            k.width,
            k.height,
            if self.0.world_from_camera.is_some() { "yes" } else { "None" }
        )
    }
}

/// A sequence of RGB-D frames with one camera: `len(ds)`, `ds[i]` (negative indices count
/// from the end), `for frame in ds`.
#[pyclass(frozen, module = "semrecon")]
pub struct Dataset {
    pub(crate) source: Arc<dyn FrameSource>,
}

impl Dataset {
    /// Frame `index` (negative: from the end), read with the GIL released.
    pub(crate) fn load(&self, py: Python<'_>, index: isize) -> PyResult<semrecon_data::Frame> {
        let n = self.source.len();
        let i = if index < 0 { index + n as isize } else { index };
        if i < 0 || i as usize >= n {
            return Err(PyIndexError::new_err(format!("frame {index} of a dataset of {n} frames")));
        }
        let source = &*self.source;
        py.detach(|| source.frame(i as usize)).map_err(data_err)
    }
}

#[pymethods]
impl Dataset {
    /// The dataset's description (`7scenes:/data/redkitchen`, `synth:1`).
    #[getter]
    fn name(&self) -> String {
        self.source.name()
    }
    /// Camera intrinsics of the depth images.
    #[getter]
    fn intrinsics(&self) -> Intrinsics {
        Intrinsics(self.source.intrinsics())
    }
    /// Whether frames carry ground-truth poses.
    #[getter]
    fn has_ground_truth(&self) -> bool {
        self.source.has_ground_truth()
    }
    /// Nominal frame rate, Hz.
    #[getter]
    fn frame_rate(&self) -> f64 {
        self.source.frame_rate()
    }

    fn __len__(&self) -> usize {
        self.source.len()
    }

    fn __getitem__(&self, py: Python<'_>, index: isize) -> PyResult<Frame> {
        self.load(py, index).map(Frame)
    }

    fn __iter__(slf: Bound<'_, Self>) -> FrameIter {
        FrameIter { source: slf.get().source.clone(), next: std::sync::atomic::AtomicUsize::new(0) }
    }

    fn __repr__(&self) -> String {
        format!("Dataset('{}', {} frames)", self.source.name(), self.source.len())
    }
}

/// Iterator over a dataset's frames.
#[pyclass(frozen, module = "semrecon")]
pub struct FrameIter {
    source: Arc<dyn FrameSource>,
    next: std::sync::atomic::AtomicUsize,
}

#[pymethods]
impl FrameIter {
    fn __iter__(slf: Bound<'_, Self>) -> Bound<'_, Self> {
        slf
    }

    fn __next__(&self, py: Python<'_>) -> PyResult<Option<Frame>> {
        let i = self.next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        if i >= self.source.len() {
            return Ok(None);
        }
        let source = &*self.source;
        py.detach(|| source.frame(i)).map(|f| Some(Frame(f))).map_err(data_err)
    }
}

/// `open_dataset(spec)`: the frames of `KIND:PATH` (`7scenes:`, `tum:`, `redwood:`,
/// `scannet:`, `replica:`, `synth:SEED`).
#[pyfunction]
fn open_dataset(py: Python<'_>, spec: &str) -> PyResult<Dataset> {
    let spec: DatasetSpec = spec.parse().map_err(data_err)?;
    let source = py.detach(|| semrecon_data::open_dataset(&spec)).map_err(data_err)?;
    Ok(Dataset { source: Arc::from(source) })
}

/// `synthetic_scan(seed, frames=300, width=640, height=480, style=None)`: a generated room
/// scanned along a handheld-like path, rendered through the Kinect-like sensor model on
/// access (ground-truth poses and per-pixel classes; no files needed).
#[pyfunction]
#[pyo3(signature = (seed, frames = 300, width = 640, height = 480, style = None))]
fn synthetic_scan_py(
    py: Python<'_>,
    seed: u64,
    frames: usize,
    width: u32,
    height: u32,
    style: Option<&str>,
) -> PyResult<Dataset> {
    if !(1..=100_000).contains(&frames) || !(8..=MAX_SIDE).contains(&width) || !(8..=MAX_SIDE).contains(&height) {
        return Err(PyValueError::new_err(format!(
            "synthetic_scan: {frames} frames of {width}x{height}; expected 1..100000 frames of 8x8..{MAX_SIDE}x{MAX_SIDE}"
        )));
    }
    let mut config = SyntheticScanConfig::new(seed);
    config.frames = frames;
    config.intrinsics = config.intrinsics.scaled(width, height);
    config.style = match style {
        None => None,
        Some(s) => Some(s.parse::<RoomStyle>().map_err(|e| PyValueError::new_err(format!("style: {e}")))?),
    };
    let (_room, scan) = py.detach(|| synthetic_scan(&config)).map_err(data_err)?;
    Ok(Dataset { source: Arc::new(scan) })
}

/// Adds the classes and functions to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Intrinsics>()?;
    m.add_class::<Frame>()?;
    m.add_class::<Dataset>()?;
    m.add_class::<FrameIter>()?;
    m.add_function(wrap_pyfunction!(open_dataset, m)?)?;
    let f = wrap_pyfunction!(synthetic_scan_py, m)?;
    m.add("synthetic_scan", f)?;
    Ok(())
}
