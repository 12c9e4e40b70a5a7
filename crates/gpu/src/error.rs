//! The one error type of the GPU engine. Everything that can go wrong on a machine without a
//! usable GPU (no adapter, a missing limit, a lost device, a buffer over the device's limit)
//! is an error value naming what was needed, never a panic, so callers can fall back to the
//! CPU engine with a message.

use semrecon_sparse::SparseError;

/// Result with [`GpuError`].
pub type Result<T, E = GpuError> = std::result::Result<T, E>;

/// Everything that can go wrong in the GPU engine.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// The crate was built without its `gpu` cargo feature.
    #[error("semrecon was built without GPU support (rebuild with `--features gpu`)")]
    NotBuilt,
    /// No Vulkan adapter could be opened.
    #[error("no GPU adapter found ({0}); on Debian, `apt-get install mesa-vulkan-drivers` provides a software one (lavapipe)")]
    NoAdapter(String),
    /// The adapter lacks a limit the engine needs.
    #[error("the GPU adapter {adapter} lacks {what}: it has {has}, the engine needs {needs}")]
    MissingCapability {
        /// The adapter's name.
        adapter: String,
        /// Which limit or feature.
        what: &'static str,
        /// What the adapter offers.
        has: u64,
        /// What the engine needs.
        needs: u64,
    },
    /// Opening the device failed.
    #[error("could not open the GPU device: {0}")]
    RequestDevice(String),
    /// The device was lost (driver reset, removed GPU, out of memory on the device).
    #[error("the GPU device was lost: {0}")]
    DeviceLost(String),
    /// A buffer larger than the device allows.
    #[error("{what} needs {bytes} bytes, more than the device's limit of {limit} bytes")]
    TooLarge {
        /// Which buffer.
        what: &'static str,
        /// Its size.
        bytes: u64,
        /// The device limit.
        limit: u64,
    },
    /// A validation or out-of-memory error reported by wgpu (a bug of the engine, or memory).
    #[error("GPU error: {0}")]
    Device(String),
    /// Reading a result back from the device failed.
    #[error("reading back from the GPU failed: {0}")]
    Readback(String),
    /// A pass needs a part of the layer that its import left out.
    #[error("the layer was imported for the other algorithm's forward and lacks {0} (make it with the engine, or import it with this algorithm)")]
    LayerPart(&'static str),
    /// Bad shapes, coordinates or kernel sizes.
    #[error(transparent)]
    Sparse(#[from] SparseError),
}
