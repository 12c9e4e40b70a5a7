//! Errors of the pipeline: bad configuration, frames that do not match the camera, and the
//! errors of the reconstruction and of the network, each saying what failed.

use thiserror::Error;

/// What can go wrong in [`crate::Pipeline`].
#[derive(Debug, Error)]
pub enum PipelineError {
    /// A configuration value is out of range.
    #[error("invalid pipeline configuration: {0}")]
    InvalidConfig(String),
    /// A frame's buffers do not match the pipeline's camera (the frame was skipped).
    #[error("frame {index}: {message}")]
    InvalidFrame {
        /// The frame's index.
        index: usize,
        /// What is wrong with it.
        message: String,
    },
    /// Tracking, fusion or map configuration.
    #[error(transparent)]
    Recon(#[from] semrecon_recon::ReconError),
    /// The network.
    #[error(transparent)]
    Net(#[from] semrecon_net::NetError),
    /// The semantic back end stopped (its thread panicked or failed).
    #[error("semantic back end stopped: {0}")]
    Backend(String),
}

/// Result with [`PipelineError`].
pub type Result<T> = std::result::Result<T, PipelineError>;
