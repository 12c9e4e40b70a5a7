//! The error type of the physics crate. Every variant says which file or argument is at
//! fault so that a `semrecon throw` user can fix the input without reading code.

use std::path::PathBuf;

use semrecon_data::DataError;

/// Result with [`PhysicsError`].
pub type Result<T, E = PhysicsError> = std::result::Result<T, E>;

/// Everything that can go wrong while loading materials or meshes or simulating a throw.
#[derive(Debug, thiserror::Error)]
pub enum PhysicsError {
    /// Reading the mesh (or another data file) failed: missing, unreadable or corrupt.
    #[error(transparent)]
    Data(#[from] DataError),
    /// The materials file is unreadable or not valid TOML.
    #[error("{path}: {message}")]
    MaterialsFile {
        /// The materials file.
        path: PathBuf,
        /// What is wrong (the TOML parser's message carries line and column).
        message: String,
    },
    /// A key of the materials file has an unknown name or a value out of range.
    #[error("{path}: {key}: {message}")]
    MaterialsKey {
        /// The materials file.
        path: PathBuf,
        /// Dotted key, e.g. `classes.sofa.restitution`.
        key: String,
        /// What is wrong.
        message: String,
    },
    /// The mesh cannot be turned into colliders (invalid indices, non-finite vertices).
    #[error("invalid mesh: {0}")]
    Mesh(String),
    /// An argument (position, direction, speed, duration, configuration) out of range.
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
}
