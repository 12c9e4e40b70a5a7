//! Which network labels: a model file the caller names, else the default model of
//! [`semrecon_net::shipped`] (`SEMRECON_MODEL`, then the copy the wheel carries, whose path
//! `semrecon/__init__.py` registers at import, then the source tree's file).

use std::path::PathBuf;
use std::sync::Mutex;

use pyo3::prelude::*;
use semrecon_net::{shipped, Segmenter};

use crate::errors::net_err;

/// The model file inside the installed package (registered by `semrecon/__init__.py`).
static PACKAGE_MODEL: Mutex<Option<PathBuf>> = Mutex::new(None);

/// The file the default model is read from: `SEMRECON_MODEL` when set, else the package's
/// copy when the wheel has one, else [`shipped::default_model_path`].
pub fn default_model_path() -> PathBuf {
    let env_set = std::env::var_os(shipped::MODEL_ENV).is_some_and(|p| !p.is_empty());
    if !env_set {
        let packaged = PACKAGE_MODEL.lock().ok().and_then(|p| p.clone());
        if let Some(p) = packaged.filter(|p| p.is_file()) {
            return p;
        }
    }
    shipped::default_model_path()
}

/// The network of `model` (a safetensors file written by `semrecon train`), or the default
/// model. Call with the GIL released: loading reads ~11 MB.
///
/// # Errors
/// `FileNotFoundError` for a missing file; `ValueError` for a file that is not a model.
pub fn load(model: Option<&str>) -> PyResult<Segmenter> {
    let path = model.map_or_else(default_model_path, PathBuf::from);
    if !path.is_file() {
        return Err(pyo3::exceptions::PyFileNotFoundError::new_err(format!(
            "model: no file at {} (pass model=PATH to a safetensors model, or set {})",
            path.display(),
            shipped::MODEL_ENV
        )));
    }
    shipped::load(&path, None).map_err(net_err)
}

/// `_set_package_model(path)`: registers the package's copy of the shipped model.
#[pyfunction]
#[pyo3(name = "_set_package_model")]
fn set_package_model(path: PathBuf) {
    if let Ok(mut p) = PACKAGE_MODEL.lock() {
        *p = Some(path);
    }
}

/// `default_model_path() -> str`: the model file used when no `model=` is given.
#[pyfunction]
#[pyo3(name = "default_model_path")]
fn default_model_path_py() -> String {
    default_model_path().display().to_string()
}

/// Adds the functions to the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(set_package_model, m)?)?;
    m.add_function(wrap_pyfunction!(default_model_path_py, m)?)?;
    Ok(())
}
