//! Typed errors of the io crate. Every variant names the file, and the dataset or attribute where
//! one is involved, so a message is enough to find the problem without a debugger.

use std::path::PathBuf;

/// Result alias of the io crate.
pub type Result<T, E = IoError> = std::result::Result<T, E>;

/// Everything that can go wrong reading or writing hemodpd files.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    /// The file could not be opened or created as HDF5 (missing, garbage bytes, truncated...).
    #[error("{path}: cannot {action} HDF5 file: {source}")]
    Open {
        path: PathBuf,
        action: &'static str,
        #[source]
        source: hdf5::Error,
    },
    /// A valid HDF5 file that is not the kind of hemodpd file expected.
    #[error("{path}: not a {expected} file: {detail}")]
    Foreign {
        path: PathBuf,
        expected: &'static str,
        detail: String,
    },
    /// A hemodpd file written by a newer format version than this build reads.
    #[error("{path}: {kind} format version {found} is not supported (this build reads version {supported})")]
    UnsupportedVersion {
        path: PathBuf,
        kind: &'static str,
        found: u32,
        supported: u32,
    },
    /// A dataset the file should hold is absent.
    #[error("{path}: missing dataset `{dataset}`")]
    MissingDataset { path: PathBuf, dataset: String },
    /// An attribute the file should hold is absent or has the wrong type.
    #[error("{path}: missing or unreadable attribute `{attribute}` on `{object}`")]
    MissingAttribute {
        path: PathBuf,
        object: String,
        attribute: String,
    },
    /// A dataset with a shape other than the one required.
    #[error("{path}: dataset `{dataset}` has shape {found:?}, expected {expected}")]
    Shape {
        path: PathBuf,
        dataset: String,
        found: Vec<usize>,
        expected: String,
    },
    /// An HDF5 call failed on a named dataset, attribute or group.
    #[error("{path}: `{object}`: {source}")]
    Hdf5 {
        path: PathBuf,
        object: String,
        #[source]
        source: hdf5::Error,
    },
    /// Input that does not fit what the file holds or what the call needs
    /// (a frame with another vertex count, an index out of range, too few frames...).
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    /// A particle type that the trajectory's `u8` types array cannot hold (never truncated).
    #[error("{path}: particle {index} has type {value}: trajectories store particle types as u8 (0 to {max}); refusing to truncate it")]
    TypeOutOfRange {
        path: PathBuf,
        index: usize,
        value: u64,
        max: u8,
    },
    /// A file-system error (temporary file, rename, fsync, CSV or JSON output).
    #[error("{path}: {source}")]
    Fs {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// JSON serialisation failed.
    #[error("{path}: JSON: {source}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    /// Drawing a chart failed.
    #[error("{path}: plot: {message}")]
    Plot { path: PathBuf, message: String },
}

impl IoError {
    pub(crate) fn hdf5(path: &std::path::Path, object: impl Into<String>, source: hdf5::Error) -> Self {
        IoError::Hdf5 {
            path: path.to_path_buf(),
            object: object.into(),
            source,
        }
    }

    pub(crate) fn invalid(path: &std::path::Path, message: impl Into<String>) -> Self {
        IoError::Invalid {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }

    pub(crate) fn fs(path: &std::path::Path, source: std::io::Error) -> Self {
        IoError::Fs {
            path: path.to_path_buf(),
            source,
        }
    }
}
