//! Run summaries: one JSON file per run directory, written atomically.

use std::path::{Path, PathBuf};

use crate::error::{IoError, Result};
use crate::h5util::write_atomic;

/// File name of the summary inside a run directory.
pub const SUMMARY_FILE: &str = "summary.json";

/// Writes `value` as pretty JSON to `dir/summary.json` atomically (temporary file, fsync,
/// rename); creates `dir` if needed. Returns the path written.
pub fn write_summary_json(dir: impl AsRef<Path>, value: &serde_json::Value) -> Result<PathBuf> {
    let dir = dir.as_ref();
    std::fs::create_dir_all(dir).map_err(|e| IoError::fs(dir, e))?;
    let path = dir.join(SUMMARY_FILE);
    write_json_atomic(&path, value)?;
    Ok(path)
}

/// Writes any serialisable value as pretty JSON to `path` atomically.
pub fn write_json_atomic<T: serde::Serialize + ?Sized>(path: impl AsRef<Path>, value: &T) -> Result<()> {
    let path = path.as_ref();
    let mut text = serde_json::to_string_pretty(value).map_err(|source| IoError::Json {
        path: path.to_path_buf(),
        source,
    })?;
    text.push('\n');
    write_atomic(path, text.as_bytes())
}

/// Reads `dir/summary.json`.
pub fn read_summary_json(dir: impl AsRef<Path>) -> Result<serde_json::Value> {
    let path = dir.as_ref().join(SUMMARY_FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| IoError::fs(&path, e))?;
    serde_json::from_str(&text).map_err(|source| IoError::Json { path, source })
}
