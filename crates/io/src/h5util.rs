//! Small HDF5 helpers: attributes by name, with errors that carry the file path.

use std::path::Path;
use std::str::FromStr;

use hdf5::types::VarLenUnicode;
use hdf5::{H5Type, Location};

use crate::error::{IoError, Result};

fn replace_attr(loc: &Location, name: &str) -> hdf5::Result<()> {
    if loc.attr_names()?.iter().any(|n| n == name) {
        loc.delete_attr(name)?;
    }
    Ok(())
}

fn object_name(loc: &Location, name: &str) -> String {
    format!("{}@{name}", loc.name())
}

/// Writes (or replaces) a scalar attribute.
pub(crate) fn set_attr<T: H5Type>(path: &Path, loc: &Location, name: &str, value: T) -> Result<()> {
    let run = || -> hdf5::Result<()> {
        // Rewrite in place when the attribute exists as a scalar (the per-frame `frames`
        // counter): no object-header churn; otherwise replace it.
        if has_attr(loc, name) {
            if let Ok(a) = loc.attr(name) {
                if a.is_scalar() && a.write_scalar(&value).is_ok() {
                    return Ok(());
                }
            }
        }
        replace_attr(loc, name)?;
        loc.new_attr::<T>().shape(()).create(name)?.write_scalar(&value)
    };
    run().map_err(|e| IoError::hdf5(path, object_name(loc, name), e))
}

/// Writes (or replaces) a 1-D array attribute.
pub(crate) fn set_attr_array<T: H5Type>(path: &Path, loc: &Location, name: &str, value: &[T]) -> Result<()> {
    let run = || -> hdf5::Result<()> {
        replace_attr(loc, name)?;
        loc.new_attr_builder().with_data(value).create(name)?;
        Ok(())
    };
    run().map_err(|e| IoError::hdf5(path, object_name(loc, name), e))
}

/// Writes (or replaces) a UTF-8 string attribute (variable length, read by h5py as `str`).
pub(crate) fn set_attr_str(path: &Path, loc: &Location, name: &str, value: &str) -> Result<()> {
    // HDF5 strings end at NUL: refuse them rather than silently cut the text.
    let v = VarLenUnicode::from_str(value)
        .map_err(|e| IoError::invalid(path, format!("attribute `{}`: {e}", object_name(loc, name))))?;
    set_attr(path, loc, name, v)
}

pub(crate) fn has_attr(loc: &Location, name: &str) -> bool {
    loc.attr_names()
        .map(|names| names.iter().any(|n| n == name))
        .unwrap_or(false)
}

fn missing(path: &Path, loc: &Location, name: &str) -> IoError {
    IoError::MissingAttribute {
        path: path.to_path_buf(),
        object: loc.name(),
        attribute: name.to_string(),
    }
}

/// Reads a scalar attribute; a missing or mistyped one is [`IoError::MissingAttribute`].
pub(crate) fn get_attr<T: H5Type>(path: &Path, loc: &Location, name: &str) -> Result<T> {
    if !has_attr(loc, name) {
        return Err(missing(path, loc, name));
    }
    loc.attr(name)
        .and_then(|a| a.read_scalar::<T>())
        .map_err(|_| missing(path, loc, name))
}

/// Reads an optional scalar attribute: `Ok(None)` when absent, an error when present but unreadable.
pub(crate) fn get_attr_opt<T: H5Type>(path: &Path, loc: &Location, name: &str) -> Result<Option<T>> {
    if !has_attr(loc, name) {
        return Ok(None);
    }
    get_attr(path, loc, name).map(Some)
}

/// Reads a 1-D array attribute.
pub(crate) fn get_attr_array<T: H5Type>(path: &Path, loc: &Location, name: &str) -> Result<Vec<T>> {
    if !has_attr(loc, name) {
        return Err(missing(path, loc, name));
    }
    loc.attr(name)
        .and_then(|a| a.read_raw::<T>())
        .map_err(|_| missing(path, loc, name))
}

/// Reads a string attribute, variable- or fixed-length, UTF-8 or ASCII.
pub(crate) fn get_attr_str(path: &Path, loc: &Location, name: &str) -> Result<String> {
    if !has_attr(loc, name) {
        return Err(missing(path, loc, name));
    }
    let attr = loc.attr(name).map_err(|_| missing(path, loc, name))?;
    if let Ok(v) = attr.read_scalar::<VarLenUnicode>() {
        return Ok(v.as_str().to_string());
    }
    if let Ok(v) = attr.read_scalar::<hdf5::types::VarLenAscii>() {
        return Ok(v.as_str().to_string());
    }
    Err(missing(path, loc, name))
}

/// Reads an optional string attribute.
pub(crate) fn get_attr_str_opt(path: &Path, loc: &Location, name: &str) -> Result<Option<String>> {
    if !has_attr(loc, name) {
        return Ok(None);
    }
    get_attr_str(path, loc, name).map(Some)
}

/// Opens a dataset by absolute name, mapping absence to [`IoError::MissingDataset`].
pub(crate) fn dataset(path: &Path, file: &hdf5::Group, name: &str) -> Result<hdf5::Dataset> {
    if !link_exists(file, name) {
        return Err(IoError::MissingDataset {
            path: path.to_path_buf(),
            dataset: name.to_string(),
        });
    }
    file.dataset(name).map_err(|e| IoError::hdf5(path, name, e))
}

/// Whether a (possibly nested, absolute) link exists; checks each component so that HDF5 does
/// not fail on a missing intermediate group.
pub(crate) fn link_exists(group: &hdf5::Group, name: &str) -> bool {
    let mut prefix = String::new();
    for part in name.trim_start_matches('/').split('/') {
        if part.is_empty() {
            continue;
        }
        if name.starts_with('/') || !prefix.is_empty() {
            prefix.push('/');
        }
        prefix.push_str(part);
        if !group.link_exists(&prefix) {
            return false;
        }
    }
    !prefix.is_empty()
}

/// Shape of a dataset, as a `Result` with context.
pub(crate) fn shape_of(path: &Path, ds: &hdf5::Dataset) -> Result<Vec<usize>> {
    ds.space()
        .map(|s| s.shape())
        .map_err(|e| IoError::hdf5(path, ds.name(), e))
}

/// Fails with [`IoError::Shape`] unless `check` accepts the dataset's shape.
pub(crate) fn expect_shape(
    path: &Path,
    ds: &hdf5::Dataset,
    expected: &str,
    check: impl Fn(&[usize]) -> bool,
) -> Result<Vec<usize>> {
    let shape = shape_of(path, ds)?;
    if check(&shape) {
        Ok(shape)
    } else {
        Err(IoError::Shape {
            path: path.to_path_buf(),
            dataset: ds.name(),
            found: shape,
            expected: expected.to_string(),
        })
    }
}

/// fsync a path (file or directory); errors are reported with the path.
pub(crate) fn fsync_path(path: &Path) -> Result<()> {
    std::fs::File::open(path)
        .and_then(|f| f.sync_all())
        .map_err(|e| IoError::fs(path, e))
}

/// Directory part of a path, `.` for a bare file name.
pub(crate) fn parent_dir(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// `path` with `suffix` appended to the file name (`traj.h5` → `traj.h5.tmp`).
pub(crate) fn with_suffix(path: &Path, suffix: &str) -> std::path::PathBuf {
    let mut s = path.as_os_str().to_os_string();
    s.push(suffix);
    std::path::PathBuf::from(s)
}

/// Writes `bytes` to `path` atomically: temporary file, fsync, rename, fsync of the directory.
pub(crate) fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    let tmp = with_suffix(path, ".tmp");
    {
        let mut f = std::fs::File::create(&tmp).map_err(|e| IoError::fs(&tmp, e))?;
        f.write_all(bytes).map_err(|e| IoError::fs(&tmp, e))?;
        f.sync_all().map_err(|e| IoError::fs(&tmp, e))?;
    }
    std::fs::rename(&tmp, path).map_err(|e| IoError::fs(path, e))?;
    // Directory fsync makes the rename durable; not every platform supports it, so ignore errors.
    let _ = fsync_path(parent_dir(path));
    Ok(())
}
