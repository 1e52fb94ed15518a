//! The layout of a trajectory file as both its writer and its XDMF companion read it: the
//! format tag and version, and the per-frame datasets (frame as the first, unlimited axis, a
//! group's `frames` attribute counting the complete frames). `docs/output.md` documents it.

use std::path::Path;

use hdf5::{H5Type, Hyperslab, Selection, SliceOrIndex};

use crate::error::{IoError, Result};
use crate::h5util::{dataset, expect_shape, get_attr, get_attr_opt, get_attr_str_opt};

/// Value of the root `format` attribute of a trajectory file.
pub const TRAJECTORY_FORMAT: &str = "hemodpd-trajectory";
/// Version of the trajectory layout this build writes and reads.
pub const TRAJECTORY_VERSION: u32 = 1;
/// The subgroup of a frame group that holds its per-frame scalars.
pub(crate) const SCALARS: &str = "scalars";

/// Checks the `format` tag and version of a trajectory file.
pub(crate) fn check_format(path: &Path, file: &hdf5::File) -> Result<()> {
    let format = get_attr_str_opt(path, file, "format")?;
    match format.as_deref() {
        Some(TRAJECTORY_FORMAT) => {}
        Some(other) => {
            return Err(IoError::Foreign {
                path: path.to_path_buf(),
                expected: "hemodpd trajectory",
                detail: format!("root attribute `format` is `{other}`, expected `{TRAJECTORY_FORMAT}`"),
            })
        }
        None => {
            return Err(IoError::Foreign {
                path: path.to_path_buf(),
                expected: "hemodpd trajectory",
                detail: "no root attribute `format`".to_string(),
            })
        }
    }
    let version: u32 = get_attr(path, file, "format_version")?;
    if version > TRAJECTORY_VERSION {
        return Err(IoError::UnsupportedVersion {
            path: path.to_path_buf(),
            kind: "trajectory",
            found: version,
            supported: TRAJECTORY_VERSION,
        });
    }
    Ok(())
}

/// The `frames` attribute of a group (0 when absent).
pub(crate) fn frames_of(path: &Path, group: &hdf5::Group) -> Result<u64> {
    Ok(get_attr_opt::<u64>(path, group, "frames")?.unwrap_or(0))
}

/// Complete frames of a group: its `frames` attribute, capped by the lengths of its per-frame
/// datasets (a killed writer may leave them out of step).
pub(crate) fn valid_frames(path: &Path, group: &hdf5::Group) -> Result<usize> {
    let mut frames = frames_of(path, group)? as usize;
    for ds in per_frame_datasets(path, group)? {
        frames = frames.min(ds.shape().first().copied().unwrap_or(0));
    }
    Ok(frames)
}

/// The datasets of a group (and its `scalars` subgroup) whose first axis is unlimited.
pub(crate) fn per_frame_datasets(path: &Path, group: &hdf5::Group) -> Result<Vec<hdf5::Dataset>> {
    let mut out = Vec::new();
    let gname = group.name();
    let err = |e| IoError::hdf5(path, gname.as_str(), e);
    for ds in group.datasets().map_err(err)? {
        let unlimited = ds
            .space()
            .map(|s| s.maxdims().first().is_some_and(|m| m.is_none()))
            .unwrap_or(false);
        if unlimited {
            out.push(ds);
        }
    }
    if group.link_exists(SCALARS) {
        let sg = group.group(SCALARS).map_err(err)?;
        for ds in sg.datasets().map_err(err)? {
            out.push(ds);
        }
    }
    Ok(out)
}

/// Reads the single value of row `i` of a 1-D per-frame dataset.
pub(crate) fn read_one<T: H5Type + Copy>(path: &Path, group: &hdf5::Group, name: &str, i: usize) -> Result<T> {
    read_rows::<T>(path, group, name, i, i + 1)?
        .first()
        .copied()
        .ok_or_else(|| IoError::invalid(path, format!("{}/{name}: row {i} is empty", group.name())))
}

/// Reads rows `[start, end)` of a per-frame dataset, flattened.
pub(crate) fn read_rows<T: H5Type>(
    path: &Path,
    group: &hdf5::Group,
    name: &str,
    start: usize,
    end: usize,
) -> Result<Vec<T>> {
    let full = format!("{}/{}", group.name(), name);
    let ds = dataset(path, group, name)?;
    let shape = expect_shape(path, &ds, "(frames, ...)", |s| !s.is_empty() && s[0] >= end)?;
    let mut sel = vec![SliceOrIndex::from(start..end)];
    sel.extend(shape[1..].iter().map(|_| SliceOrIndex::from(..)));
    let arr: ndarray::ArrayD<T> = ds
        .read_slice(Selection::Hyperslab(Hyperslab::from(sel)))
        .map_err(|e| IoError::hdf5(path, full, e))?;
    Ok(arr.into_iter().collect())
}

/// The times and steps of a group's complete frames (empty when it has none).
pub(crate) fn frame_clock(path: &Path, group: &hdf5::Group) -> Result<(Vec<f64>, Vec<u64>)> {
    let frames = valid_frames(path, group)?;
    if frames == 0 {
        return Ok((Vec::new(), Vec::new()));
    }
    Ok((
        read_rows(path, group, "time", 0, frames)?,
        read_rows(path, group, "step", 0, frames)?,
    ))
}
