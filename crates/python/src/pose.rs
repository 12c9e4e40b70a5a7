//! Poses between numpy and glam: a `world_from_camera` rigid transform is a `(4, 4)` float64
//! array (rotation and translation in metres, last row `0 0 0 1`). Poses given by the caller
//! are checked: finite, last row `0 0 0 1`, an orthonormal rotation with determinant +1.

use glam::{Affine3A, Mat3, Vec3};
use numpy::PyArray2;
use pyo3::prelude::*;

use crate::arrays::{rows, typed};
use crate::errors::value_error;

/// How far a given rotation may be from orthonormal (max entry of `R^T R - I`), and the last
/// row from `0 0 0 1`.
const TOLERANCE: f64 = 1e-3;

/// `pose` as a `(4, 4)` float64 array, row-major.
pub fn to_array<'py>(py: Python<'py>, pose: &Affine3A) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let m = glam::Mat4::from(*pose);
    let mut v = Vec::with_capacity(16);
    for r in 0..4 {
        let row = m.row(r);
        v.extend([row.x, row.y, row.z, row.w].map(f64::from));
    }
    rows(py, v, 4)
}

/// The pose argument `arg`: a `(4, 4)` float64 or float32 array.
///
/// # Errors
/// `TypeError`/`ValueError` for other arrays, non-finite values, a last row other than
/// `0 0 0 1` or a rotation that is not a rotation.
pub fn from_array(arg: &str, obj: &Bound<'_, PyAny>) -> PyResult<Affine3A> {
    let m: Vec<f64> = match typed::<f64>(arg, obj, "float64", &[Some(4), Some(4)], "(4, 4)") {
        Ok(a) => a.slice().to_vec(),
        Err(e64) => match typed::<f32>(arg, obj, "float32", &[Some(4), Some(4)], "(4, 4)") {
            Ok(a) => a.slice().iter().map(|&v| f64::from(v)).collect(),
            Err(_) => return Err(e64),
        },
    };
    if let Some(i) = m.iter().position(|v| !v.is_finite()) {
        return Err(value_error(arg, format!("entry ({}, {}) is {} (a pose must be finite)", i / 4, i % 4, m[i])));
    }
    let last = [m[12], m[13], m[14], m[15] - 1.0];
    if last.iter().any(|v| v.abs() > TOLERANCE) {
        return Err(value_error(arg, format!("last row is {:?}, expected [0, 0, 0, 1]", &m[12..16])));
    }
    let r = |i: usize, j: usize| m[i * 4 + j];
    let mut worst = 0f64;
    for i in 0..3 {
        for j in 0..3 {
            let dot: f64 = (0..3).map(|k| r(k, i) * r(k, j)).sum();
            worst = worst.max((dot - if i == j { 1.0 } else { 0.0 }).abs());
        }
    }
    let det = r(0, 0) * (r(1, 1) * r(2, 2) - r(1, 2) * r(2, 1)) - r(0, 1) * (r(1, 0) * r(2, 2) - r(1, 2) * r(2, 0))
        + r(0, 2) * (r(1, 0) * r(2, 1) - r(1, 1) * r(2, 0));
    if worst > TOLERANCE || det < 0.0 {
        return Err(value_error(
            arg,
            format!("the upper-left 3x3 block is not a rotation (R^T R - I up to {worst:.2e}, det {det:.3})"),
        ));
    }
    let col = |j: usize| Vec3::new(r(0, j) as f32, r(1, j) as f32, r(2, j) as f32);
    Ok(Affine3A::from_mat3_translation(Mat3::from_cols(col(0), col(1), col(2)), col(3)))
}
