//! Checkpoints: everything a run needs to continue bit-identically, in one HDF5 file written
//! atomically (temporary file, fsync, rename).
//!
//! Layout: root attributes `format = "hemodpd-checkpoint"`, `format_version`, `step`, `time`,
//! `seed`, `scenario` (TOML); `/arrays/<name>` one dataset per named array (f64, u64, u32 or u8,
//! any shape, Fletcher-32 checksummed so a corrupted block is detected on load); `/scalars`
//! attributes for named scalars. Values are stored exactly as given (model units, no conversion).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::DVec3;
use hdf5::types::{FloatSize, IntSize, TypeDescriptor};
use hdf5::H5Type;

use crate::error::{IoError, Result};
use crate::h5util::{
    fsync_path, get_attr, get_attr_str, get_attr_str_opt, parent_dir, set_attr, set_attr_str, with_suffix,
};

/// Value of the root `format` attribute of a checkpoint file.
pub const CHECKPOINT_FORMAT: &str = "hemodpd-checkpoint";
/// Version of the checkpoint layout this build writes and reads.
pub const CHECKPOINT_VERSION: u32 = 1;

/// Typed contents of a named array.
#[derive(Clone, Debug, PartialEq)]
pub enum ArrayData {
    F64(Vec<f64>),
    U64(Vec<u64>),
    U32(Vec<u32>),
    U8(Vec<u8>),
}

impl ArrayData {
    /// Number of elements.
    pub fn len(&self) -> usize {
        match self {
            ArrayData::F64(v) => v.len(),
            ArrayData::U64(v) => v.len(),
            ArrayData::U32(v) => v.len(),
            ArrayData::U8(v) => v.len(),
        }
    }

    /// Whether the array has no element.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn type_name(&self) -> &'static str {
        match self {
            ArrayData::F64(_) => "f64",
            ArrayData::U64(_) => "u64",
            ArrayData::U32(_) => "u32",
            ArrayData::U8(_) => "u8",
        }
    }
}

/// A named array: its shape (row-major) and data.
#[derive(Clone, Debug, PartialEq)]
pub struct NamedArray {
    pub shape: Vec<usize>,
    pub data: ArrayData,
}

/// A named scalar (controller state, counters, RNG state, flags...).
#[derive(Clone, Debug, PartialEq)]
pub enum ScalarValue {
    F64(f64),
    U64(u64),
    I64(i64),
    Bool(bool),
    Str(String),
}

/// The state of a run at one step.
#[derive(Clone, Debug, PartialEq)]
pub struct Checkpoint {
    /// Step the state belongs to (the run continues with step + 1).
    pub step: u64,
    /// Simulated time, model units.
    pub time: f64,
    /// Master random seed.
    pub seed: u64,
    /// Resolved scenario, TOML.
    pub scenario_toml: String,
    /// Named arrays (positions, velocities, forces, ids, types...).
    pub arrays: BTreeMap<String, NamedArray>,
    /// Named scalars.
    pub scalars: BTreeMap<String, ScalarValue>,
    /// File this checkpoint was loaded from, for error messages.
    pub source: Option<PathBuf>,
}

fn check_name(name: &str) {
    // Names are chosen by code, not users: a bad one is a programming error.
    assert!(
        !name.is_empty() && !name.contains('/') && !name.contains('\0'),
        "checkpoint names must be non-empty and contain no `/` or NUL: {name:?}"
    );
}

impl Checkpoint {
    /// An empty checkpoint.
    pub fn new(step: u64, time: f64, seed: u64, scenario_toml: impl Into<String>) -> Self {
        Checkpoint {
            step,
            time,
            seed,
            scenario_toml: scenario_toml.into(),
            arrays: BTreeMap::new(),
            scalars: BTreeMap::new(),
            source: None,
        }
    }

    fn insert(&mut self, name: &str, shape: Vec<usize>, data: ArrayData) {
        check_name(name);
        assert_eq!(
            shape.iter().product::<usize>(),
            data.len(),
            "checkpoint array `{name}`: shape {shape:?} does not match {} elements",
            data.len()
        );
        self.arrays.insert(name.to_string(), NamedArray { shape, data });
    }

    /// Stores a 1-D f64 array.
    pub fn insert_f64(&mut self, name: &str, data: Vec<f64>) {
        self.insert(name, vec![data.len()], ArrayData::F64(data));
    }

    /// Stores an f64 array with a shape (row-major). Panics if the shape does not match.
    pub fn insert_f64_shaped(&mut self, name: &str, shape: Vec<usize>, data: Vec<f64>) {
        self.insert(name, shape, ArrayData::F64(data));
    }

    /// Stores vectors as an `(n, 3)` f64 array.
    pub fn insert_vec3(&mut self, name: &str, data: &[DVec3]) {
        let flat = data.iter().flat_map(|v| v.to_array()).collect();
        self.insert(name, vec![data.len(), 3], ArrayData::F64(flat));
    }

    pub fn insert_u64(&mut self, name: &str, data: Vec<u64>) {
        self.insert(name, vec![data.len()], ArrayData::U64(data));
    }

    pub fn insert_u32(&mut self, name: &str, data: Vec<u32>) {
        self.insert(name, vec![data.len()], ArrayData::U32(data));
    }

    pub fn insert_u8(&mut self, name: &str, data: Vec<u8>) {
        self.insert(name, vec![data.len()], ArrayData::U8(data));
    }

    /// Stores a named scalar.
    pub fn set_scalar(&mut self, name: &str, value: ScalarValue) {
        check_name(name);
        self.scalars.insert(name.to_string(), value);
    }

    fn path_for_errors(&self) -> PathBuf {
        self.source.clone().unwrap_or_else(|| PathBuf::from("<checkpoint>"))
    }

    fn missing(&self, name: &str) -> IoError {
        IoError::MissingDataset {
            path: self.path_for_errors(),
            dataset: format!("/arrays/{name}"),
        }
    }

    fn wrong_type(&self, name: &str, want: &str, arr: &NamedArray) -> IoError {
        IoError::invalid(
            &self.path_for_errors(),
            format!("/arrays/{name} holds {} values, expected {want}", arr.data.type_name()),
        )
    }

    /// An array by name, any type.
    pub fn array(&self, name: &str) -> Result<&NamedArray> {
        self.arrays.get(name).ok_or_else(|| self.missing(name))
    }

    /// An f64 array by name (flat, row-major).
    pub fn f64s(&self, name: &str) -> Result<&[f64]> {
        let a = self.array(name)?;
        match &a.data {
            ArrayData::F64(v) => Ok(v),
            _ => Err(self.wrong_type(name, "f64", a)),
        }
    }

    pub fn u64s(&self, name: &str) -> Result<&[u64]> {
        let a = self.array(name)?;
        match &a.data {
            ArrayData::U64(v) => Ok(v),
            _ => Err(self.wrong_type(name, "u64", a)),
        }
    }

    pub fn u32s(&self, name: &str) -> Result<&[u32]> {
        let a = self.array(name)?;
        match &a.data {
            ArrayData::U32(v) => Ok(v),
            _ => Err(self.wrong_type(name, "u32", a)),
        }
    }

    pub fn u8s(&self, name: &str) -> Result<&[u8]> {
        let a = self.array(name)?;
        match &a.data {
            ArrayData::U8(v) => Ok(v),
            _ => Err(self.wrong_type(name, "u8", a)),
        }
    }

    /// An `(n, 3)` f64 array as vectors; `expected_len` (if given) must match n.
    pub fn vec3s(&self, name: &str, expected_len: Option<usize>) -> Result<Vec<DVec3>> {
        let a = self.array(name)?;
        let ok = a.shape.len() == 2 && a.shape[1] == 3 && expected_len.is_none_or(|n| n == a.shape[0]);
        if !ok {
            return Err(IoError::Shape {
                path: self.path_for_errors(),
                dataset: format!("/arrays/{name}"),
                found: a.shape.clone(),
                expected: match expected_len {
                    Some(n) => format!("({n}, 3)"),
                    None => "(n, 3)".to_string(),
                },
            });
        }
        let v = self.f64s(name)?;
        Ok(v.chunks_exact(3).map(|c| DVec3::new(c[0], c[1], c[2])).collect())
    }

    /// A scalar by name.
    pub fn scalar(&self, name: &str) -> Result<&ScalarValue> {
        self.scalars.get(name).ok_or_else(|| IoError::MissingAttribute {
            path: self.path_for_errors(),
            object: "/scalars".to_string(),
            attribute: name.to_string(),
        })
    }

    fn scalar_type_error(&self, name: &str, want: &str) -> IoError {
        IoError::invalid(&self.path_for_errors(), format!("/scalars@{name} is not {want}"))
    }

    pub fn scalar_f64(&self, name: &str) -> Result<f64> {
        match self.scalar(name)? {
            ScalarValue::F64(v) => Ok(*v),
            _ => Err(self.scalar_type_error(name, "f64")),
        }
    }

    pub fn scalar_u64(&self, name: &str) -> Result<u64> {
        match self.scalar(name)? {
            ScalarValue::U64(v) => Ok(*v),
            _ => Err(self.scalar_type_error(name, "u64")),
        }
    }

    pub fn scalar_i64(&self, name: &str) -> Result<i64> {
        match self.scalar(name)? {
            ScalarValue::I64(v) => Ok(*v),
            _ => Err(self.scalar_type_error(name, "i64")),
        }
    }

    pub fn scalar_bool(&self, name: &str) -> Result<bool> {
        match self.scalar(name)? {
            ScalarValue::Bool(v) => Ok(*v),
            _ => Err(self.scalar_type_error(name, "bool")),
        }
    }

    pub fn scalar_str(&self, name: &str) -> Result<&str> {
        match self.scalar(name)? {
            ScalarValue::Str(v) => Ok(v),
            _ => Err(self.scalar_type_error(name, "a string")),
        }
    }

    /// Writes the checkpoint to `path` atomically: `path.tmp` is written, fsynced and renamed
    /// over `path`, so `path` is always either the previous checkpoint or this one.
    pub fn save_atomic(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        let tmp = with_suffix(path, ".tmp");
        self.write_synced(&tmp)?;
        std::fs::rename(&tmp, path).map_err(|e| IoError::fs(path, e))?;
        let _ = fsync_path(parent_dir(path));
        Ok(())
    }

    /// Writes the checkpoint to `path` (replacing any file there) and fsyncs it: the first half
    /// of an atomic save, for callers that rename it into place themselves (and keep the file
    /// it replaces).
    pub fn write_synced(&self, path: impl AsRef<Path>) -> Result<()> {
        let path = path.as_ref();
        {
            let file = hdf5::File::create(path).map_err(|source| IoError::Open {
                path: path.to_path_buf(),
                action: "create",
                source,
            })?;
            self.write_to(path, &file)?;
            file.close().map_err(|e| IoError::hdf5(path, "/", e))?;
        }
        fsync_path(path)
    }

    fn write_to(&self, path: &Path, file: &hdf5::File) -> Result<()> {
        set_attr_str(path, file, "format", CHECKPOINT_FORMAT)?;
        set_attr(path, file, "format_version", CHECKPOINT_VERSION)?;
        set_attr_str(path, file, "hemodpd_version", env!("CARGO_PKG_VERSION"))?;
        set_attr(path, file, "step", self.step)?;
        set_attr(path, file, "time", self.time)?;
        set_attr(path, file, "seed", self.seed)?;
        set_attr_str(path, file, "scenario", &self.scenario_toml)?;
        let arrays = file
            .create_group("arrays")
            .map_err(|e| IoError::hdf5(path, "/arrays", e))?;
        for (name, arr) in &self.arrays {
            let full = format!("/arrays/{name}");
            let res = match &arr.data {
                ArrayData::F64(v) => write_array(&arrays, name, &arr.shape, v),
                ArrayData::U64(v) => write_array(&arrays, name, &arr.shape, v),
                ArrayData::U32(v) => write_array(&arrays, name, &arr.shape, v),
                ArrayData::U8(v) => write_array(&arrays, name, &arr.shape, v),
            };
            res.map_err(|e| IoError::hdf5(path, full, e))?;
        }
        let scalars = file
            .create_group("scalars")
            .map_err(|e| IoError::hdf5(path, "/scalars", e))?;
        for (name, v) in &self.scalars {
            match v {
                ScalarValue::F64(x) => set_attr(path, &scalars, name, *x)?,
                ScalarValue::U64(x) => set_attr(path, &scalars, name, *x)?,
                ScalarValue::I64(x) => set_attr(path, &scalars, name, *x)?,
                ScalarValue::Bool(x) => set_attr(path, &scalars, name, *x)?,
                ScalarValue::Str(x) => set_attr_str(path, &scalars, name, x)?,
            }
        }
        Ok(())
    }

    /// Loads and validates a checkpoint: the file must exist, be HDF5, carry
    /// `format = "hemodpd-checkpoint"` with a supported version, and every array must read back
    /// with its checksum intact.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        if !path.exists() {
            return Err(IoError::fs(
                path,
                std::io::Error::new(std::io::ErrorKind::NotFound, "no such checkpoint"),
            ));
        }
        let file = hdf5::File::open(path).map_err(|source| IoError::Open {
            path: path.to_path_buf(),
            action: "open",
            source,
        })?;
        match get_attr_str_opt(path, &file, "format")?.as_deref() {
            Some(CHECKPOINT_FORMAT) => {}
            Some(other) => {
                return Err(IoError::Foreign {
                    path: path.to_path_buf(),
                    expected: "hemodpd checkpoint",
                    detail: format!("root attribute `format` is `{other}`, expected `{CHECKPOINT_FORMAT}`"),
                })
            }
            None => {
                return Err(IoError::Foreign {
                    path: path.to_path_buf(),
                    expected: "hemodpd checkpoint",
                    detail: "no root attribute `format`".to_string(),
                })
            }
        }
        let version: u32 = get_attr(path, &file, "format_version")?;
        if version > CHECKPOINT_VERSION {
            return Err(IoError::UnsupportedVersion {
                path: path.to_path_buf(),
                kind: "checkpoint",
                found: version,
                supported: CHECKPOINT_VERSION,
            });
        }
        let mut ck = Checkpoint::new(
            get_attr(path, &file, "step")?,
            get_attr(path, &file, "time")?,
            get_attr(path, &file, "seed")?,
            get_attr_str(path, &file, "scenario")?,
        );
        ck.source = Some(path.to_path_buf());
        if !file.link_exists("arrays") {
            return Err(IoError::MissingDataset {
                path: path.to_path_buf(),
                dataset: "/arrays".to_string(),
            });
        }
        let arrays = file.group("arrays").map_err(|e| IoError::hdf5(path, "/arrays", e))?;
        let names = arrays.member_names().map_err(|e| IoError::hdf5(path, "/arrays", e))?;
        for name in names {
            let full = format!("/arrays/{name}");
            let err = |e| IoError::hdf5(path, full.as_str(), e);
            let ds = arrays.dataset(&name).map_err(err)?;
            let shape = ds.space().map_err(err)?.shape();
            let desc = ds.dtype().and_then(|t| t.to_descriptor()).map_err(err)?;
            let data = match desc {
                TypeDescriptor::Float(FloatSize::U8) => ArrayData::F64(ds.read_raw().map_err(err)?),
                TypeDescriptor::Unsigned(IntSize::U8) => ArrayData::U64(ds.read_raw().map_err(err)?),
                TypeDescriptor::Unsigned(IntSize::U4) => ArrayData::U32(ds.read_raw().map_err(err)?),
                TypeDescriptor::Unsigned(IntSize::U1) => ArrayData::U8(ds.read_raw().map_err(err)?),
                other => {
                    return Err(IoError::invalid(
                        path,
                        format!("{full}: unsupported element type {other:?}"),
                    ))
                }
            };
            if data.len() != shape.iter().product::<usize>() {
                return Err(IoError::Shape {
                    path: path.to_path_buf(),
                    dataset: full,
                    found: shape,
                    expected: format!("{} elements", data.len()),
                });
            }
            ck.arrays.insert(name, NamedArray { shape, data });
        }
        if file.link_exists("scalars") {
            let g = file.group("scalars").map_err(|e| IoError::hdf5(path, "/scalars", e))?;
            for name in g.attr_names().map_err(|e| IoError::hdf5(path, "/scalars", e))? {
                let full = format!("/scalars@{name}");
                let desc = g
                    .attr(&name)
                    .and_then(|a| a.dtype())
                    .and_then(|t| t.to_descriptor())
                    .map_err(|e| IoError::hdf5(path, full.as_str(), e))?;
                let v = match desc {
                    TypeDescriptor::Float(_) => ScalarValue::F64(get_attr(path, &g, &name)?),
                    TypeDescriptor::Unsigned(_) => ScalarValue::U64(get_attr(path, &g, &name)?),
                    TypeDescriptor::Integer(_) => ScalarValue::I64(get_attr(path, &g, &name)?),
                    TypeDescriptor::Boolean => ScalarValue::Bool(get_attr(path, &g, &name)?),
                    _ => ScalarValue::Str(get_attr_str(path, &g, &name)?),
                };
                ck.scalars.insert(name, v);
            }
        }
        Ok(ck)
    }

    /// Compares two checkpoints bit for bit (f64 by bit pattern, so NaN payloads and -0.0
    /// count), ignoring `source`. Returns the first difference, for test messages.
    pub fn bitwise_difference(&self, other: &Checkpoint) -> Option<String> {
        if self.step != other.step
            || self.time.to_bits() != other.time.to_bits()
            || self.seed != other.seed
            || self.scenario_toml != other.scenario_toml
        {
            return Some("step, time, seed or scenario differ".to_string());
        }
        if self.arrays.keys().ne(other.arrays.keys()) {
            return Some("array names differ".to_string());
        }
        for (name, a) in &self.arrays {
            let b = &other.arrays[name];
            if a.shape != b.shape {
                return Some(format!("array `{name}`: shapes differ"));
            }
            let same = match (&a.data, &b.data) {
                (ArrayData::F64(x), ArrayData::F64(y)) => x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits()),
                (x, y) => x == y,
            };
            if !same {
                return Some(format!("array `{name}` differs"));
            }
        }
        if self.scalars.keys().ne(other.scalars.keys()) {
            return Some("scalar names differ".to_string());
        }
        for (name, a) in &self.scalars {
            let b = &other.scalars[name];
            let same = match (a, b) {
                (ScalarValue::F64(x), ScalarValue::F64(y)) => x.to_bits() == y.to_bits(),
                (x, y) => x == y,
            };
            if !same {
                return Some(format!("scalar `{name}` differs"));
            }
        }
        None
    }
}

fn write_array<T: H5Type>(group: &hdf5::Group, name: &str, shape: &[usize], data: &[T]) -> hdf5::Result<()> {
    let view = ndarray::ArrayViewD::from_shape(ndarray::IxDyn(shape), data)
        .map_err(|e| hdf5::Error::from(e.to_string().as_str()))?;
    let mut b = group.new_dataset_builder().with_data(view);
    if !data.is_empty() && !shape.is_empty() {
        // One chunk of at most ~64 MiB rows, checksummed.
        let row: usize = shape[1..].iter().product::<usize>().max(1) * std::mem::size_of::<T>();
        let rows = (64 << 20) / row;
        let mut chunk = shape.to_vec();
        chunk[0] = chunk[0].min(rows.max(1));
        b = b.chunk(chunk).fletcher32();
    }
    b.create(name)?;
    Ok(())
}
