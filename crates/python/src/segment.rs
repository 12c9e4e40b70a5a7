//! `segment(points, colors, model=None, structure="segments")`: the class of every point of a
//! coloured point cloud by the segmentation network (voxelised at the network's voxel size, 5
//! cm for the shipped model; metres, z up), then the room structure of `semrecon segment`
//! ([`semrecon_net::structure`]: the segment vote and beam faces by default), so that Python
//! and the command line give the same labels.

use numpy::PyArray1;
use pyo3::prelude::*;
use semrecon_net::structure::{refine_labels, softmax_rows, StructureConfig, StructureMode};

use crate::arrays::{require_finite, typed};
use crate::errors::{net_err, value_error};

/// Labels `points` (float32 `(N, 3)` metres, z up) coloured `colors` (uint8 `(N, 3)` RGB):
/// uint8 `(N,)` class ids 0..12 (`CLASSES` order). `structure`: "none" (the network alone),
/// "segments" (the default of `semrecon segment`), "planes" or "all".
#[pyfunction]
#[pyo3(signature = (points, colors, *, model = None, structure = "segments"))]
fn segment<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    colors: &Bound<'py, PyAny>,
    model: Option<String>,
    structure: &str,
) -> PyResult<Bound<'py, PyArray1<u8>>> {
    let mode: StructureMode = structure.parse().map_err(|e: String| value_error("structure", e))?;
    let p = typed::<f32>("points", points, "float32", &[None, Some(3)], "(N, 3)")?;
    let n = p.shape[0];
    let c = typed::<u8>("colors", colors, "uint8", &[Some(n), Some(3)], &format!("({n}, 3), one per point"))?;
    require_finite("points", p.slice())?;
    let pts: Vec<[f32; 3]> = p.slice().chunks_exact(3).map(|v| [v[0], v[1], v[2]]).collect();
    let cols: Vec<[u8; 3]> = c.slice().chunks_exact(3).map(|v| [v[0], v[1], v[2]]).collect();
    if pts.is_empty() {
        return Ok(PyArray1::from_vec(py, Vec::new()));
    }
    let labels = py.detach(|| {
        crate::model::with_cached(model.as_deref(), |net| {
            let as_py = |e: semrecon_net::NetError| match e {
                semrecon_net::NetError::Sparse(s) => value_error("points", s),
                other => net_err(other),
            };
            let scores = net.segment_points_scores(&pts, &cols).map_err(as_py)?;
            let k = net.config().classes;
            let mut probs = scores.logits;
            softmax_rows(&mut probs, k);
            let config = StructureConfig::new(mode);
            let voxel = refine_labels(&scores.coords, &scores.features, &probs, k, net.config().voxel_size, &config)
                .map_err(as_py)?;
            Ok(scores.point_to_voxel.iter().map(|&v| voxel[v as usize]).collect::<Vec<u8>>())
        })
    })?;
    Ok(PyArray1::from_vec(py, labels))
}

/// Adds the function to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(segment, m)?)?;
    Ok(())
}
