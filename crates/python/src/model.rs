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
    load_path(&model.map_or_else(default_model_path, PathBuf::from))
}

/// The network of the model file `path`.
fn load_path(path: &std::path::Path) -> PyResult<Segmenter> {
    if !path.is_file() {
        return Err(pyo3::exceptions::PyFileNotFoundError::new_err(format!(
            "model: no file at {} (pass model=PATH to a safetensors model, or set {})",
            path.display(),
            shipped::MODEL_ENV
        )));
    }
    shipped::load(path, None).map_err(net_err)
}

/// The network `segment` used last, with the file and modification time it was read from.
type CachedNet = (PathBuf, Option<std::time::SystemTime>, Segmenter);
static SEGMENT_NET: Mutex<Option<CachedNet>> = Mutex::new(None);

/// Runs `f` on the network of `model` (see [`load`]), kept between calls while the file
/// stays the same, so that repeated `segment` calls do not re-read ~11 MB of weights. Call
/// with the GIL released.
///
/// # Errors
/// Those of [`load`] and of `f`.
pub fn with_cached<R>(model: Option<&str>, f: impl FnOnce(&mut Segmenter) -> PyResult<R>) -> PyResult<R> {
    let path = model.map_or_else(default_model_path, PathBuf::from);
    let modified = std::fs::metadata(&path).and_then(|m| m.modified()).ok();
    let mut cache = SEGMENT_NET
        .lock()
        .map_err(|_| pyo3::exceptions::PyRuntimeError::new_err("the network failed in an earlier call"))?;
    let fresh = matches!(&*cache, Some((p, m, _)) if *p == path && *m == modified && m.is_some());
    if !fresh {
        *cache = None;
        let net = load_path(&path)?;
        *cache = Some((path, modified, net));
    }
    match cache.as_mut() {
        Some((_, _, net)) => f(net),
        None => Err(pyo3::exceptions::PyRuntimeError::new_err("no network")),
    }
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
