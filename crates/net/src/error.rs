//! The one error type of the network crate. Weight files are the input users get wrong most
//! (a checkpoint of another configuration, a truncated download), so every weight error names
//! the file and the tensor concerned.

use std::path::PathBuf;

/// Result with [`NetError`].
pub type Result<T, E = NetError> = std::result::Result<T, E>;

/// Everything that can go wrong while configuring, loading or running the network.
#[derive(Debug, thiserror::Error)]
pub enum NetError {
    /// An I/O failure on a file.
    #[error("{path}: {source}")]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A configuration file or name that cannot be understood, or invalid values.
    #[error("configuration {source_name}: {message}")]
    Config {
        /// The file or name concerned.
        source_name: String,
        /// What is wrong.
        message: String,
    },
    /// A weight file that cannot be read as safetensors (truncated, corrupt header, ...).
    #[error("weights {file}: {message}")]
    WeightFile {
        /// The file (or `<memory>`).
        file: String,
        /// What is wrong.
        message: String,
    },
    /// A tensor that the configuration needs is absent.
    #[error("weights {file}: tensor `{tensor}` is missing")]
    MissingTensor {
        /// The file (or `<memory>`).
        file: String,
        /// Tensor name.
        tensor: String,
    },
    /// A tensor that the configuration does not have.
    #[error("weights {file}: unexpected tensor `{tensor}` (weights of another configuration?)")]
    UnexpectedTensor {
        /// The file (or `<memory>`).
        file: String,
        /// Tensor name.
        tensor: String,
    },
    /// A tensor with the wrong shape.
    #[error("weights {file}: tensor `{tensor}` has shape {got:?}, the configuration needs {expected:?}")]
    TensorShape {
        /// The file (or `<memory>`).
        file: String,
        /// Tensor name.
        tensor: String,
        /// Shape the configuration needs.
        expected: Vec<usize>,
        /// Shape found.
        got: Vec<usize>,
    },
    /// A tensor stored with a dtype other than f16 or f32.
    #[error("weights {file}: tensor `{tensor}` has dtype {dtype}, expected F16 or F32")]
    TensorDtype {
        /// The file (or `<memory>`).
        file: String,
        /// Tensor name.
        tensor: String,
        /// Dtype found.
        dtype: String,
    },
    /// Weights saved for another configuration.
    #[error("weights {file}: saved for configuration {saved}, not {wanted}")]
    ConfigMismatch {
        /// The file.
        file: String,
        /// Summary of the configuration stored in the file.
        saved: String,
        /// Summary of the configuration asked for.
        wanted: String,
    },
    /// Input buffers that do not fit the network (shape, channels).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// A number of test-time augmentation views other than 1, 2, 4 or 8 ([`crate::tta::Tta`]).
    #[error(
        "test-time augmentation takes 1, 2, 4 or 8 views (1 = off, 2 = half turn, 4 = the four 90-degree yaws, \
         8 = the four yaws x a mirror), not {0}"
    )]
    TtaViews(usize),
    /// An error reading training or evaluation data (names the file).
    #[error(transparent)]
    Data(#[from] semrecon_data::DataError),
    /// An error of the sparse convolution engine.
    #[error(transparent)]
    Sparse(#[from] semrecon_sparse::SparseError),
    /// The GPU engine failed (no adapter, lost device, a buffer over the device's limit).
    #[error(transparent)]
    Gpu(#[from] semrecon_gpu::GpuError),
}

impl NetError {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io { path: path.into(), source }
    }
}
