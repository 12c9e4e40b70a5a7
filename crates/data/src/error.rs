//! The one error type of this crate. Every variant names the file (and line where there is
//! one) so that a user can find what is wrong without a debugger.

use std::path::PathBuf;

/// Result with [`DataError`].
pub type Result<T, E = DataError> = std::result::Result<T, E>;

/// Everything that can go wrong while reading, parsing or writing data.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// An I/O failure on a file (missing, unreadable, unwritable).
    #[error("{path}: {source}")]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// A text or binary file whose content cannot be understood.
    #[error("{path}{}: {message}", line.map(|l| format!(":{l}")).unwrap_or_default())]
    Parse {
        /// The file concerned.
        path: PathBuf,
        /// 1-based line number, where the format has lines.
        line: Option<usize>,
        /// What is wrong.
        message: String,
    },
    /// An image that cannot be decoded or has the wrong kind or size.
    #[error("{path}: {message}")]
    Image {
        /// The file concerned.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A dataset folder that lacks what its layout needs, or an unknown `KIND:PATH`.
    #[error("{path}: {message}")]
    Dataset {
        /// The folder or specification concerned.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// An argument out of its valid range (not tied to a file).
    #[error("invalid argument: {0}")]
    InvalidArgument(String),
    /// OpenNI2 missing, or a device or `.oni` recording it cannot open or read.
    #[error(transparent)]
    OpenNi(#[from] crate::openni::OpenNiError),
}

impl DataError {
    /// An I/O error on `path`.
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io { path: path.into(), source }
    }

    /// A parse error in `path`, optionally at a 1-based `line`.
    pub fn parse(path: impl Into<PathBuf>, line: Option<usize>, message: impl Into<String>) -> Self {
        Self::Parse { path: path.into(), line, message: message.into() }
    }

    /// An image error on `path`.
    pub fn image(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Image { path: path.into(), message: message.into() }
    }

    /// A dataset layout error on `path`.
    pub fn dataset(path: impl Into<PathBuf>, message: impl Into<String>) -> Self {
        Self::Dataset { path: path.into(), message: message.into() }
    }
}
