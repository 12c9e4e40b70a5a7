//! The `semrecon` Python package's native module, `semrecon._native` (PyO3, one abi3 wheel for
//! CPython 3.9+, built by maturin from `crates/python/pyproject.toml`). It wraps the public
//! Rust APIs and adds no reconstruction or convolution logic of its own:
//!
//! - [`pipeline`]: `Pipeline` around [`semrecon_pipeline::Pipeline`] (frames from numpy,
//!   trajectory, labelled mesh and timings back as numpy arrays);
//! - [`dataset`]: `open_dataset("KIND:PATH")`, `synthetic_scan(...)` and their frames
//!   ([`semrecon_data::FrameSource`]);
//! - [`segment`]: `segment(points, colors)` with the shipped network ([`semrecon_net`]);
//! - [`mesh_io`]: PLY reading and writing ([`semrecon_data::ply`]);
//! - [`classes`]: the 13 class names and colours ([`semrecon_data::SemanticClass`]);
//! - [`sparse`]: the sparse convolution engine's layers (`ConvGeometry`: submanifold,
//!   strided and transposed; forward and both gradients, [`semrecon_sparse::ChunkedConv`]);
//! - [`arrays`]: checked conversion of numpy arguments (dtype, shape, contiguity, finite);
//! - [`errors`]: the Rust errors as Python exceptions.
//!
//! Heavy work (tracking, fusion, meshing, the network, convolutions, file reading) runs with
//! the GIL released. Nothing panics across into Python: every argument is checked and every
//! Rust error becomes a `ValueError`, `TypeError`, `OSError` or `RuntimeError` naming the
//! argument or the file.
//!
//! Everything here is behind the cargo feature `python` (maturin turns it on): without it the
//! crate is empty, so the workspace's build and tests need no Python and never build PyO3.
#![cfg(feature = "python")]
#![warn(missing_docs)]

pub mod arrays;
pub mod classes;
pub mod dataset;
pub mod errors;
pub mod mesh_io;
pub mod model;
pub mod pipeline;
pub mod pose;
pub mod segment;
pub mod sparse;

use pyo3::prelude::*;

/// The native module `semrecon._native`; `semrecon/__init__.py` re-exports it.
#[pymodule]
#[pyo3(name = "_native")]
fn native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    classes::register(m)?;
    dataset::register(m)?;
    pipeline::register(m)?;
    segment::register(m)?;
    mesh_io::register(m)?;
    model::register(m)?;
    sparse::register(m)?;
    Ok(())
}
