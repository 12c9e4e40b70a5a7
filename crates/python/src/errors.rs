//! The Rust errors of the wrapped crates as Python exceptions: bad arguments and bad data
//! become `ValueError`, a missing file `FileNotFoundError`, other I/O failures `OSError`,
//! failures that are not the caller's (a stopped back end) `RuntimeError`. The message is the
//! Rust error's, which names the file, the row or the field.

use pyo3::exceptions::{PyFileNotFoundError, PyOSError, PyRuntimeError, PyValueError};
use pyo3::PyErr;
use semrecon_data::DataError;
use semrecon_net::NetError;
use semrecon_pipeline::PipelineError;
use semrecon_sparse::SparseError;

/// An I/O error as `FileNotFoundError` (missing file) or `OSError`.
fn io_err(message: String, kind: std::io::ErrorKind) -> PyErr {
    if kind == std::io::ErrorKind::NotFound {
        PyFileNotFoundError::new_err(message)
    } else {
        PyOSError::new_err(message)
    }
}

/// A data-crate error (files, formats, datasets).
pub fn data_err(e: DataError) -> PyErr {
    match &e {
        DataError::Io { source, .. } => io_err(e.to_string(), source.kind()),
        // A dataset folder that does not exist is a missing file too.
        DataError::Dataset { message, .. } if message.contains("does not exist") => {
            PyFileNotFoundError::new_err(e.to_string())
        }
        _ => PyValueError::new_err(e.to_string()),
    }
}

/// A sparse-engine error (coordinates, shapes): always the caller's arguments.
pub fn sparse_err(e: SparseError) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// A network error (model files, inputs).
pub fn net_err(e: NetError) -> PyErr {
    match e {
        NetError::Io { ref source, .. } => io_err(e.to_string(), source.kind()),
        NetError::Data(d) => data_err(d),
        other => PyValueError::new_err(other.to_string()),
    }
}

/// A pipeline error (configuration, frames, the back end).
pub fn pipeline_err(e: PipelineError) -> PyErr {
    match e {
        PipelineError::Net(n) => net_err(n),
        PipelineError::Backend(_) => PyRuntimeError::new_err(e.to_string()),
        other => PyValueError::new_err(other.to_string()),
    }
}

/// `ValueError("{arg}: {message}")`.
pub fn value_error(arg: &str, message: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(format!("{arg}: {message}"))
}
