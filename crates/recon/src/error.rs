//! The error type of the reconstruction: what a caller can get wrong (a configuration out of
//! range, a frame whose buffers do not match its camera, a pose that is not finite). Bad depth
//! values are not errors: fusion skips them, because real sensors produce them every frame.

/// Result with [`ReconError`].
pub type Result<T, E = ReconError> = std::result::Result<T, E>;

/// Everything the reconstruction refuses.
#[derive(Debug, thiserror::Error)]
pub enum ReconError {
    /// A configuration value out of its valid range.
    #[error("invalid reconstruction configuration: {0}")]
    InvalidConfig(String),
    /// A frame that cannot be fused (buffer sizes, pose); the message names the frame.
    #[error("frame {index}: {message}")]
    InvalidFrame {
        /// The frame's index in its source.
        index: usize,
        /// What is wrong.
        message: String,
    },
    /// The spill file of a map under a memory budget failed (see [`crate::map::SpillError`]).
    #[error(transparent)]
    Spill(#[from] crate::map::SpillError),
}
