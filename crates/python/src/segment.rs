//! `segment(points, colors, model=None)`: the class of every point of a coloured point cloud
//! by the segmentation network ([`semrecon_net::Segmenter::segment_points`]: voxelised at the
//! network's voxel size, 5 cm for the shipped model; metres, z up).

use numpy::PyArray1;
use pyo3::prelude::*;

use crate::arrays::{require_finite, typed};
use crate::errors::{net_err, value_error};

/// Labels `points` (float32 `(N, 3)` metres, z up) coloured `colors` (uint8 `(N, 3)` RGB):
/// uint8 `(N,)` class ids 0..12 (`CLASSES` order).
#[pyfunction]
#[pyo3(signature = (points, colors, *, model = None))]
fn segment<'py>(
    py: Python<'py>,
    points: &Bound<'py, PyAny>,
    colors: &Bound<'py, PyAny>,
    model: Option<String>,
) -> PyResult<Bound<'py, PyArray1<u8>>> {
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
            net.segment_points(&pts, &cols).map_err(|e| match e {
                semrecon_net::NetError::Sparse(s) => value_error("points", s),
                other => net_err(other),
            })
        })
    })?;
    Ok(PyArray1::from_vec(py, labels))
}

/// Adds the function to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(segment, m)?)?;
    Ok(())
}
