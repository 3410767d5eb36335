//! The library's error type: who is at fault, with paths and values.

use std::path::PathBuf;

/// Everything that can go wrong in the library.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// A parameter is out of range.
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
    /// The inputs given to the filter are inconsistent.
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// A file is not a valid or supported EXR image.
    #[error("{path}: {message}")]
    Exr {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// Channels the denoiser needs are missing or inconsistent.
    #[error(
        "{path}: {message}\n  channels found: {found}\n  to choose channels: --map ROLE=CH[,CH...] with ROLE one of color, variance, A, B, feature.NAME, feature-var.NAME, layer.NAME, layer-var.NAME"
    )]
    Channels {
        /// The file.
        path: PathBuf,
        /// What is missing or wrong.
        message: String,
        /// The channels present, comma-separated.
        found: String,
    },
    /// The memory limit is below what the smallest schedule needs.
    #[error(
        "memory limit {limit} bytes is below the minimum of {needed} bytes this {width}x{height} frame needs (smallest tiles); raise --memory-limit to at least {needed}"
    )]
    Budget {
        /// Bytes the smallest schedule needs.
        needed: u64,
        /// The limit given.
        limit: u64,
        /// Frame width.
        width: usize,
        /// Frame height.
        height: usize,
    },
    /// An error that arose while processing a file (names the file).
    #[error("{}: {source}", path.display())]
    InFile {
        /// The file being processed.
        path: PathBuf,
        /// What went wrong.
        source: Box<Error>,
    },
    /// A worker stopped unexpectedly (a bug); the run was abandoned cleanly.
    #[error("internal error: {0}")]
    Internal(String),
    /// An I/O error on a path.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
}

impl Error {
    /// Name `path` in errors that do not already name a file (parameters,
    /// inconsistent inputs, memory budget).
    pub fn in_file(self, path: &std::path::Path) -> Error {
        match self {
            e @ (Error::InvalidInput(_) | Error::Budget { .. } | Error::Internal(_)) => {
                Error::InFile { path: path.to_path_buf(), source: Box::new(e) }
            }
            other => other,
        }
    }
}

/// Result with the library error.
pub type Result<T> = std::result::Result<T, Error>;
