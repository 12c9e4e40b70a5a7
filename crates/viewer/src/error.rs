//! The error type of the viewer: loading the folder, binding the port, writing an export.
//! Each variant names the file or address at fault.

use std::path::PathBuf;

use semrecon_data::DataError;
use semrecon_physics::PhysicsError;

/// Result with [`ViewerError`].
pub type Result<T, E = ViewerError> = std::result::Result<T, E>;

/// Everything that can stop the viewer from starting or an export from being written.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    /// Reading the mesh or trajectory failed.
    #[error(transparent)]
    Data(#[from] DataError),
    /// The mesh cannot become collision geometry, or the materials file is invalid.
    #[error(transparent)]
    Physics(#[from] PhysicsError),
    /// The folder holds no mesh the viewer can show.
    #[error("{dir}: {message}")]
    NoMesh {
        /// The folder given.
        dir: PathBuf,
        /// What was looked for.
        message: String,
    },
    /// The HTTP server could not bind its address.
    #[error("cannot listen on {addr}: {message}")]
    Bind {
        /// The address asked for.
        addr: String,
        /// The system's reason.
        message: String,
    },
}
