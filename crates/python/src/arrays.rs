//! Checked conversion of numpy arguments. Every array argument goes through [`typed`]: it
//! must be a numpy array of exactly the expected dtype (native byte order), C-contiguous (a
//! strided view is refused rather than read as if it were contiguous) and of the expected
//! shape; errors name the argument and what was expected. Outputs are new numpy arrays that
//! own their data.

use numpy::{
    Element, PyArray1, PyArray2, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;

/// A numpy argument after its checks: the shape and a read-only view of the data.
pub struct Checked<'py, T: Element> {
    array: PyReadonlyArrayDyn<'py, T>,
    /// The array's shape.
    pub shape: Vec<usize>,
}

impl<'py, T: Element> Checked<'py, T> {
    /// The data in C order.
    pub fn slice(&self) -> &[T] {
        // `typed` checked C-contiguity and alignment, under which `as_slice` cannot fail (an
        // empty slice, which every caller's length checks reject, should it ever).
        self.array.as_slice().unwrap_or(&[])
    }
}

/// The numpy array `obj` (argument `arg`) as an array of `T` (`dtype` names it in messages),
/// C-contiguous, with `shape` (`None` entries match any size; `expected` describes the shape
/// in messages, e.g. "(H, W)").
///
/// # Errors
/// `TypeError` for something that is not a numpy array or has another dtype; `ValueError`
/// for another number of dimensions, another size or a non-contiguous array.
pub fn typed<'py, T: Element>(
    arg: &str,
    obj: &Bound<'py, PyAny>,
    dtype: &str,
    shape: &[Option<usize>],
    expected: &str,
) -> PyResult<Checked<'py, T>> {
    let untyped = obj.cast::<PyUntypedArray>().map_err(|_| {
        let ty = obj.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "?".into());
        PyTypeError::new_err(format!("{arg}: expected a numpy array of {dtype} with shape {expected}, got {ty}"))
    })?;
    let got_shape = untyped.shape().to_vec();
    let array = obj.cast::<PyArrayDyn<T>>().map_err(|_| {
        PyTypeError::new_err(format!(
            "{arg}: expected dtype {dtype} with shape {expected}, got dtype {} (use .astype(np.{dtype}))",
            untyped.dtype()
        ))
    })?;
    let shape_ok =
        got_shape.len() == shape.len() && got_shape.iter().zip(shape).all(|(g, e)| e.is_none_or(|e| *g == e));
    if !shape_ok {
        return Err(PyValueError::new_err(format!("{arg}: expected shape {expected}, got {got_shape:?}")));
    }
    if !untyped.is_c_contiguous() {
        return Err(PyValueError::new_err(format!(
            "{arg}: the array is not C-contiguous (strides {:?}); pass np.ascontiguousarray({arg})",
            untyped.strides()
        )));
    }
    if !untyped.is_aligned() {
        return Err(PyValueError::new_err(format!(
            "{arg}: the array's data is not aligned for {dtype}; pass np.require({arg}, requirements='CA')"
        )));
    }
    Ok(Checked { array: array.readonly(), shape: got_shape })
}

/// Fails with a `ValueError` naming `arg` and the first non-finite value's flat index.
pub fn require_finite(arg: &str, values: &[f32]) -> PyResult<()> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(i) => Err(PyValueError::new_err(format!("{arg}: value {} at flat index {i} is not finite", values[i]))),
    }
}

/// A `[n, cols]` numpy array from row-major `data`.
pub fn rows<'py, T: Element>(py: Python<'py>, data: Vec<T>, cols: usize) -> PyResult<Bound<'py, PyArray2<T>>> {
    let n = data.len().checked_div(cols).unwrap_or(0);
    PyArray1::from_vec(py, data).reshape([n, cols])
}

/// A numpy array of `shape` from row-major `data` (whose length is the shape's product).
pub fn shaped<'py, T: Element>(py: Python<'py>, data: Vec<T>, shape: &[usize]) -> PyResult<Bound<'py, PyArrayDyn<T>>> {
    PyArray1::from_vec(py, data).reshape(shape)
}
