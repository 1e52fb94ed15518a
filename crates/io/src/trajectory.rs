//! HDF5 trajectories: one file per run, frames appended and flushed as the run goes.
//!
//! The layout is documented in `docs/output.md`. In short: root attributes hold the format tag,
//! the run metadata and the unit system; `/membrane` holds the triangles once and the vertex
//! positions (and velocities) per frame; `/fluid` holds fluid particles every few frames;
//! `/fields/<name>` holds binned fields on a grid. Every per-frame dataset is chunked with the
//! frame as its first, unlimited axis. Values are stored in SI; the writer takes model units and
//! converts them with the run's [`UnitSystem`].

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use glam::DVec3;
use hdf5::{Extent, H5Type, Hyperslab, Selection, SimpleExtents, SliceOrIndex};
use serde::{Deserialize, Serialize};

use crate::error::{IoError, Result};
use crate::h5util::{
    dataset, expect_shape, get_attr, get_attr_array, get_attr_opt, get_attr_str, get_attr_str_opt, link_exists,
    set_attr, set_attr_array, set_attr_str,
};
use crate::layout::{check_format, frames_of, per_frame_datasets, read_one, read_rows, valid_frames, SCALARS};
use crate::units::{Quantity, UnitSystem};

pub use crate::layout::{TRAJECTORY_FORMAT, TRAJECTORY_VERSION};

const MEMBRANE: &str = "/membrane";
const FLUID: &str = "/fluid";
const FIELDS: &str = "/fields";

/// An extra run-level attribute (shear rate, flow kind, driver parameters...).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum MetaValue {
    F64(f64),
    I64(i64),
    Str(String),
}

/// What a trajectory records about its run, stored as root attributes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunMetadata {
    /// Scenario name (`capillary`, `shear`, `stretch`...).
    pub scenario_name: String,
    /// The resolved scenario, as TOML text, so the run can be reproduced from the file alone.
    pub scenario_toml: String,
    /// Master random seed.
    pub seed: u64,
    /// Version of hemodpd that wrote the file.
    pub hemodpd_version: String,
    /// Model → SI mapping used by the writer.
    pub units: UnitSystem,
    /// Extra root attributes, e.g. `("flow", Str("shear"))`, `("shear_rate", F64(..))` in SI.
    pub extra: Vec<(String, MetaValue)>,
}

impl RunMetadata {
    /// Metadata with this crate's version and no extra attributes.
    pub fn new(
        scenario_name: impl Into<String>,
        scenario_toml: impl Into<String>,
        seed: u64,
        units: UnitSystem,
    ) -> Self {
        RunMetadata {
            scenario_name: scenario_name.into(),
            scenario_toml: scenario_toml.into(),
            seed,
            hemodpd_version: env!("CARGO_PKG_VERSION").to_string(),
            units,
            extra: Vec::new(),
        }
    }

    /// Adds an extra root attribute (builder style).
    pub fn with_extra(mut self, name: impl Into<String>, value: MetaValue) -> Self {
        self.extra.push((name.into(), value));
        self
    }

    /// An extra attribute by name.
    pub fn extra(&self, name: &str) -> Option<&MetaValue> {
        self.extra.iter().find(|(n, _)| n == name).map(|(_, v)| v)
    }
}

/// A regular grid of bins, in model units when handed to the writer (SI when read back).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GridSpec {
    /// Lower corner of the first bin.
    pub origin: DVec3,
    /// Bin size along x, y, z.
    pub spacing: DVec3,
    /// Number of bins `[nx, ny, nz]`.
    pub shape: [usize; 3],
}

impl GridSpec {
    /// Number of bins.
    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }

    /// Whether the grid has no bin.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Flat index of bin `(i, j, k)`, x fastest: `(k·ny + j)·nx + i`.
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        (k * self.shape[1] + j) * self.shape[0] + i
    }
}

/// A named per-frame scalar stored beside the membrane frames (`/membrane/scalars/<name>`),
/// e.g. the stretching force. `value` is in model units of `quantity`.
#[derive(Clone, Copy, Debug)]
pub struct FrameScalar<'a> {
    pub name: &'a str,
    pub value: f64,
    pub quantity: Quantity,
}

/// Writer options.
#[derive(Clone, Debug)]
pub struct WriterOptions {
    /// gzip level (0–9) for the per-frame datasets; `None` stores them uncompressed.
    pub deflate: Option<u8>,
    /// Write `FILE.xmf` beside `FILE.h5` for ParaView.
    pub xdmf: bool,
    /// Regenerate the XDMF file at most this often while appending (always at close); the gap
    /// also grows to 20× the time a rewrite takes, so long runs spend under 5 % on it. Zero
    /// rewrites after every frame.
    pub xdmf_interval: Duration,
}

impl Default for WriterOptions {
    fn default() -> Self {
        WriterOptions {
            deflate: None,
            xdmf: true,
            xdmf_interval: Duration::from_secs(5),
        }
    }
}

/// Appends frames to a trajectory file. Every append ends with an HDF5 flush, so a run that is
/// killed leaves a file with every frame appended before the kill.
pub struct TrajectoryWriter {
    path: PathBuf,
    file: Option<hdf5::File>,
    units: UnitSystem,
    options: WriterOptions,
    last_xdmf: Option<Instant>,
    /// Wall time the last XDMF rewrite took: rewrites are spaced to keep them under ~5 %.
    xdmf_cost: Duration,
    xdmf_dirty: bool,
}

impl TrajectoryWriter {
    /// Creates (truncating) a trajectory file and writes the run metadata.
    pub fn create(path: impl AsRef<Path>, meta: &RunMetadata) -> Result<Self> {
        Self::create_with(path, meta, WriterOptions::default())
    }

    /// [`create`](Self::create) with options.
    pub fn create_with(path: impl AsRef<Path>, meta: &RunMetadata, options: WriterOptions) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let file = hdf5::File::create(&path).map_err(|source| IoError::Open {
            path: path.clone(),
            action: "create",
            source,
        })?;
        write_metadata(&path, &file, meta)?;
        file.flush().map_err(|e| IoError::hdf5(&path, "/", e))?;
        Ok(TrajectoryWriter {
            path,
            file: Some(file),
            units: meta.units.clone(),
            options,
            last_xdmf: None,
            xdmf_cost: Duration::ZERO,
            xdmf_dirty: true,
        })
    }

    /// Reopens a trajectory to continue a run resumed from the checkpoint taken at
    /// `truncate_after_step`: frames with a larger step (written after that checkpoint, before the
    /// run stopped) are dropped, so the resumed run neither duplicates nor loses frames.
    pub fn open_append(path: impl AsRef<Path>, truncate_after_step: u64) -> Result<Self> {
        Self::open_append_with(path, truncate_after_step, WriterOptions::default())
    }

    /// [`open_append`](Self::open_append) with options.
    pub fn open_append_with(path: impl AsRef<Path>, truncate_after_step: u64, options: WriterOptions) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let file = hdf5::File::open_rw(&path).map_err(|source| IoError::Open {
            path: path.clone(),
            action: "open for appending",
            source,
        })?;
        let meta = read_metadata(&path, &file)?;
        let mut groups: Vec<String> = Vec::new();
        for g in [MEMBRANE, FLUID] {
            if file.link_exists(g) {
                groups.push(g.to_string());
            }
        }
        for name in field_names(&path, &file)? {
            groups.push(format!("{FIELDS}/{name}"));
        }
        for g in &groups {
            let group = file.group(g).map_err(|e| IoError::hdf5(&path, g.as_str(), e))?;
            let frames = valid_frames(&path, &group)?;
            let keep = if frames == 0 {
                0
            } else {
                let steps: Vec<u64> = read_rows(&path, &group, "step", 0, frames)?;
                steps.iter().position(|&s| s > truncate_after_step).unwrap_or(frames)
            };
            truncate_group(&path, &group, keep)?;
        }
        file.flush().map_err(|e| IoError::hdf5(&path, "/", e))?;
        Ok(TrajectoryWriter {
            path,
            file: Some(file),
            units: meta.units,
            options,
            last_xdmf: None,
            xdmf_cost: Duration::ZERO,
            xdmf_dirty: true,
        })
    }

    /// The file being written.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The unit system the writer converts with.
    pub fn units(&self) -> &UnitSystem {
        &self.units
    }

    fn file(&self) -> Result<&hdf5::File> {
        self.file
            .as_ref()
            .ok_or_else(|| IoError::invalid(&self.path, "trajectory writer already closed"))
    }

    fn group(&self, name: &str) -> Result<hdf5::Group> {
        let file = self.file()?;
        if file.link_exists(name) {
            file.group(name)
        } else {
            file.create_group(name)
        }
        .map_err(|e| IoError::hdf5(&self.path, name, e))
    }

    /// Writes the membrane triangles (vertex indices, counter-clockwise seen from outside).
    /// Called once; calling again with the same triangles (after a resume) is a no-op.
    pub fn write_mesh(&mut self, triangles: &[[u32; 3]]) -> Result<()> {
        let group = self.group(MEMBRANE)?;
        let name = "/membrane/triangles";
        if group.link_exists("triangles") {
            let ds = dataset(&self.path, &group, "triangles")?;
            let old: Vec<u32> = ds.read_raw().map_err(|e| IoError::hdf5(&self.path, name, e))?;
            let new: Vec<u32> = triangles.iter().flatten().copied().collect();
            if old != new {
                return Err(IoError::invalid(
                    &self.path,
                    format!("{name} already written with other triangles"),
                ));
            }
            return Ok(());
        }
        if triangles.is_empty() {
            return Err(IoError::invalid(&self.path, "write_mesh: no triangles"));
        }
        let flat: Vec<u32> = triangles.iter().flatten().copied().collect();
        let arr = ndarray::ArrayView2::from_shape((triangles.len(), 3), &flat)
            .map_err(|e| IoError::invalid(&self.path, e.to_string()))?;
        let ds = group
            .new_dataset_builder()
            .with_data(arr)
            .create("triangles")
            .map_err(|e| IoError::hdf5(&self.path, name, e))?;
        set_attr_str(&self.path, &ds, "units", "1")?;
        set_attr_str(
            &self.path,
            &ds,
            "description",
            "vertex indices (0-based) of each membrane triangle",
        )?;
        set_attr(&self.path, &group, "n_triangles", triangles.len() as u64)?;
        self.flush()
    }

    /// Stores the reference (stress-free) membrane area and enclosed volume, in model units,
    /// as `/membrane` attributes `reference_area` and `reference_volume` (SI). Analysis reports
    /// area and volume deviations from them (from frame 0 when absent).
    pub fn set_membrane_reference(&mut self, area: f64, volume: f64) -> Result<()> {
        let group = self.group(MEMBRANE)?;
        let a = area * self.units.to_si(Quantity::Area);
        let v = volume * self.units.to_si(Quantity::Volume);
        set_attr(&self.path, &group, "reference_area", a)?;
        set_attr(&self.path, &group, "reference_volume", v)?;
        self.flush()
    }

    /// Appends a membrane frame: vertex positions, optional velocities (model units) and named
    /// scalars. The first frame fixes the vertex count and whether velocities are stored; steps
    /// must increase.
    pub fn append_membrane_frame(
        &mut self,
        step: u64,
        time: f64,
        positions: &[DVec3],
        velocities: Option<&[DVec3]>,
        scalars: &[FrameScalar],
    ) -> Result<()> {
        for sc in scalars {
            if sc.name.is_empty() || sc.name.contains('/') {
                return Err(IoError::invalid(&self.path, format!("bad scalar name `{}`", sc.name)));
            }
        }
        let group = self.group(MEMBRANE)?;
        let frame = self.begin_frame(&group, MEMBRANE, step)?;
        let n = positions.len();
        if n == 0 {
            return Err(IoError::invalid(&self.path, "membrane frame without vertices"));
        }
        if let Some(v) = velocities {
            if v.len() != n {
                return Err(IoError::invalid(
                    &self.path,
                    format!("membrane velocities: {} for {n} vertices", v.len()),
                ));
            }
        }
        if let Some(nv) = get_attr_opt::<u64>(&self.path, &group, "n_vertices")? {
            if nv as usize != n {
                return Err(IoError::invalid(
                    &self.path,
                    format!("membrane frame at step {step} has {n} vertices, the file has {nv}"),
                ));
            }
        } else {
            set_attr(&self.path, &group, "n_vertices", n as u64)?;
        }
        let has_vel = group.link_exists("velocities");
        if frame > 0 && has_vel != velocities.is_some() {
            return Err(IoError::invalid(
                &self.path,
                format!(
                    "membrane frame at step {step}: velocities {} but earlier frames {}",
                    if velocities.is_some() { "given" } else { "missing" },
                    if has_vel { "have them" } else { "do not" }
                ),
            ));
        }
        let len = self.units.to_si(Quantity::Length);
        self.append_vec3(&group, "positions", frame, positions, len, Quantity::Length)?;
        if let Some(v) = velocities {
            let s = self.units.to_si(Quantity::Velocity);
            self.append_vec3(&group, "velocities", frame, v, s, Quantity::Velocity)?;
        }
        if !scalars.is_empty() || group.link_exists(SCALARS) {
            let sg = if group.link_exists(SCALARS) {
                group.group(SCALARS)
            } else {
                group.create_group(SCALARS)
            }
            .map_err(|e| IoError::hdf5(&self.path, "/membrane/scalars", e))?;
            for sc in scalars {
                let si = sc.value * self.units.to_si(sc.quantity);
                self.append_rows(&sg, sc.name, frame, &[], &[si], Some(sc.quantity), true)?;
            }
            // Scalars not given in this frame read NaN (the datasets' fill value).
            for name in sg
                .member_names()
                .map_err(|e| IoError::hdf5(&self.path, "/membrane/scalars", e))?
            {
                if !scalars.iter().any(|s| s.name == name) {
                    let ds = dataset(&self.path, &sg, &name)?;
                    resize_first(&self.path, &ds, frame + 1)?;
                }
            }
        }
        self.end_frame(&group, frame, step, time)
    }

    /// As [`append_fluid_frame`](Self::append_fluid_frame), with the engine's `u16` particle
    /// types. The file stores types as `u8`: a type above 255 is an error
    /// ([`IoError::TypeOutOfRange`]), never a silent truncation, and nothing is written.
    pub fn append_fluid_frame_u16(
        &mut self,
        step: u64,
        time: f64,
        positions: &[DVec3],
        velocities: Option<&[DVec3]>,
        types: Option<&[u16]>,
    ) -> Result<()> {
        let narrow = match types {
            Some(t) => Some(types_to_u8(&self.path, t)?),
            None => None,
        };
        self.append_fluid_frame(step, time, positions, velocities, narrow.as_deref())
    }

    /// Appends a fluid frame (all particles or a fixed subset): positions, optional velocities
    /// (model units) and optional particle types. The particle count is fixed by the first frame.
    pub fn append_fluid_frame(
        &mut self,
        step: u64,
        time: f64,
        positions: &[DVec3],
        velocities: Option<&[DVec3]>,
        types: Option<&[u8]>,
    ) -> Result<()> {
        let group = self.group(FLUID)?;
        let frame = self.begin_frame(&group, FLUID, step)?;
        let n = positions.len();
        if n == 0 {
            return Err(IoError::invalid(&self.path, "fluid frame without particles"));
        }
        let consistent =
            group.link_exists("velocities") == velocities.is_some() && group.link_exists("types") == types.is_some();
        if frame > 0 && !consistent {
            return Err(IoError::invalid(
                &self.path,
                format!("fluid frame at step {step}: velocities/types differ from earlier frames"),
            ));
        }
        if velocities.is_some_and(|v| v.len() != n) || types.is_some_and(|t| t.len() != n) {
            return Err(IoError::invalid(
                &self.path,
                format!("fluid frame at step {step}: velocities or types not one per particle ({n})"),
            ));
        }
        let len = self.units.to_si(Quantity::Length);
        self.append_vec3(&group, "positions", frame, positions, len, Quantity::Length)?;
        if let Some(v) = velocities {
            let s = self.units.to_si(Quantity::Velocity);
            self.append_vec3(&group, "velocities", frame, v, s, Quantity::Velocity)?;
        }
        if let Some(t) = types {
            self.append_rows(&group, "types", frame, &[n], t, None, false)?;
        }
        self.end_frame(&group, frame, step, time)
    }

    /// Appends a frame of a binned field `name` (e.g. `velocity`, `density`) on `grid` (model
    /// units). `values` holds `components` numbers per bin, bins x fastest
    /// (`((k·ny + j)·nx + i)·components + c`), in model units of `quantity`.
    /// The grid and component count are fixed by the first frame of each field.
    pub fn append_field(
        &mut self,
        name: &str,
        step: u64,
        time: f64,
        grid: &GridSpec,
        components: usize,
        values: &[f64],
        quantity: Quantity,
    ) -> Result<()> {
        if name.is_empty() || name.contains('/') {
            return Err(IoError::invalid(&self.path, format!("bad field name `{name}`")));
        }
        if grid.is_empty() || components == 0 || values.len() != grid.len() * components {
            return Err(IoError::invalid(
                &self.path,
                format!(
                    "field `{name}`: {} values for grid {:?} × {components} components",
                    values.len(),
                    grid.shape
                ),
            ));
        }
        let gname = format!("{FIELDS}/{name}");
        self.group(FIELDS)?;
        let group = self.group(&gname)?;
        let frame = self.begin_frame(&group, &gname, step)?;
        let len = self.units.to_si(Quantity::Length);
        let origin = (grid.origin * len).to_array();
        let spacing = (grid.spacing * len).to_array();
        let shape = [grid.shape[0] as u64, grid.shape[1] as u64, grid.shape[2] as u64];
        if frame == 0 && !group.link_exists("values") {
            set_attr_array(&self.path, &group, "origin", &origin)?;
            set_attr_array(&self.path, &group, "spacing", &spacing)?;
            set_attr_array(&self.path, &group, "shape", &shape)?;
            set_attr(&self.path, &group, "components", components as u64)?;
            set_attr_str(&self.path, &group, "centering", "cell")?;
        } else {
            let old_shape: Vec<u64> = get_attr_array(&self.path, &group, "shape")?;
            let old_c: u64 = get_attr(&self.path, &group, "components")?;
            if old_shape != shape || old_c != components as u64 {
                return Err(IoError::invalid(
                    &self.path,
                    format!("field `{name}`: grid or component count changed at step {step}"),
                ));
            }
        }
        let scale = self.units.to_si(quantity);
        let si: Vec<f64> = values.iter().map(|v| v * scale).collect();
        let [nx, ny, nz] = grid.shape;
        self.append_rows(
            &group,
            "values",
            frame,
            &[nz, ny, nx, components],
            &si,
            Some(quantity),
            false,
        )?;
        self.end_frame(&group, frame, step, time)
    }

    /// Number of complete membrane frames in the file.
    pub fn membrane_frames(&self) -> Result<u64> {
        let file = self.file()?;
        if !file.link_exists(MEMBRANE) {
            return Ok(0);
        }
        let g = file
            .group(MEMBRANE)
            .map_err(|e| IoError::hdf5(&self.path, MEMBRANE, e))?;
        frames_of(&self.path, &g)
    }

    /// Step of the last complete membrane frame, if any (a resumed run uses it to decide whether
    /// the frame at the checkpoint step still has to be written).
    pub fn last_membrane_step(&self) -> Result<Option<u64>> {
        let file = self.file()?;
        if !file.link_exists(MEMBRANE) {
            return Ok(None);
        }
        let g = file
            .group(MEMBRANE)
            .map_err(|e| IoError::hdf5(&self.path, MEMBRANE, e))?;
        last_step(&self.path, &g)
    }

    /// Flushes HDF5 buffers to the file (done after every append).
    pub fn flush(&mut self) -> Result<()> {
        let file = self.file()?;
        file.flush().map_err(|e| IoError::hdf5(&self.path, "/", e))
    }

    /// Writes the XDMF companion file now.
    pub fn write_xdmf(&mut self) -> Result<PathBuf> {
        let file = self.file()?;
        let started = Instant::now();
        let out = crate::xdmf::write_xdmf_for(&self.path, file)?;
        self.xdmf_cost = started.elapsed();
        self.last_xdmf = Some(Instant::now());
        self.xdmf_dirty = false;
        Ok(out)
    }

    /// Flushes, writes the XDMF file and closes the HDF5 file.
    pub fn close(mut self) -> Result<()> {
        self.finish()
    }

    fn finish(&mut self) -> Result<()> {
        if self.file.is_none() {
            return Ok(());
        }
        self.flush()?;
        if self.options.xdmf && self.xdmf_dirty {
            self.write_xdmf()?;
        }
        if let Some(file) = self.file.take() {
            file.close().map_err(|e| IoError::hdf5(&self.path, "/", e))?;
        }
        Ok(())
    }

    fn begin_frame(&self, group: &hdf5::Group, gname: &str, step: u64) -> Result<usize> {
        let frame = frames_of(&self.path, group)? as usize;
        if let Some(last) = last_step(&self.path, group)? {
            if step <= last {
                return Err(IoError::invalid(
                    &self.path,
                    format!("{gname}: frame at step {step} after a frame at step {last}; steps must increase"),
                ));
            }
        }
        Ok(frame)
    }

    fn end_frame(&mut self, group: &hdf5::Group, frame: usize, step: u64, time: f64) -> Result<()> {
        self.append_rows(group, "step", frame, &[], &[step], None, false)?;
        let t = time * self.units.to_si(Quantity::Time);
        self.append_rows(group, "time", frame, &[], &[t], Some(Quantity::Time), false)?;
        // `frames` is written last: a reader trusts it over the dataset lengths.
        set_attr(&self.path, group, "frames", frame as u64 + 1)?;
        self.flush()?;
        self.xdmf_dirty = true;
        if self.options.xdmf {
            let due = self.last_xdmf.is_none_or(|t| t.elapsed() >= self.options.xdmf_interval);
            if due {
                self.write_xdmf()?;
            }
        }
        Ok(())
    }

    fn append_vec3(
        &self,
        group: &hdf5::Group,
        name: &str,
        frame: usize,
        data: &[DVec3],
        scale: f64,
        quantity: Quantity,
    ) -> Result<()> {
        let flat: Vec<f64> = data
            .iter()
            .flat_map(|v| [v.x * scale, v.y * scale, v.z * scale])
            .collect();
        self.append_rows(group, name, frame, &[data.len(), 3], &flat, Some(quantity), false)
    }

    /// Writes row `frame` of the per-frame dataset `name` (created on first use, chunked one
    /// frame per chunk), growing it to `frame + 1` rows.
    fn append_rows<T: H5Type + Copy>(
        &self,
        group: &hdf5::Group,
        name: &str,
        frame: usize,
        row: &[usize],
        data: &[T],
        quantity: Option<Quantity>,
        nan_fill: bool,
    ) -> Result<()> {
        let full = format!("{}/{}", group.name(), name);
        let err = |e: hdf5::Error| IoError::hdf5(&self.path, full.as_str(), e);
        let ds = if group.link_exists(name) {
            let ds = group.dataset(name).map_err(err)?;
            let shape = ds.shape();
            if shape.len() != row.len() + 1 || shape[1..] != *row {
                return Err(IoError::Shape {
                    path: self.path.clone(),
                    dataset: full.clone(),
                    found: shape,
                    expected: format!("(frames, {row:?}) as in this frame"),
                });
            }
            ds
        } else {
            let mut extents = vec![Extent::new(0, None)];
            extents.extend(row.iter().map(|&d| Extent::fixed(d)));
            let mut chunk = vec![if row.is_empty() { 256 } else { 1 }];
            chunk.extend_from_slice(row);
            let mut b = group.new_dataset::<T>().chunk(chunk);
            if let Some(level) = self.options.deflate {
                if !row.is_empty() {
                    b = b.deflate(level);
                }
            }
            if nan_fill {
                b = b.fill_value(f64::NAN);
            }
            let ds = b.shape(SimpleExtents::from_vec(extents)).create(name).map_err(err)?;
            if let Some(q) = quantity {
                set_attr_str(&self.path, &ds, "units", q.si_units())?;
                set_attr(&self.path, &ds, "model_to_si", self.units.to_si(q))?;
            }
            ds
        };
        resize_first(&self.path, &ds, frame + 1)?;
        let mut sel = vec![SliceOrIndex::from(frame..frame + 1)];
        sel.extend(row.iter().map(|_| SliceOrIndex::from(..)));
        let mut shape = vec![1];
        shape.extend_from_slice(row);
        let view = ndarray::ArrayViewD::from_shape(ndarray::IxDyn(&shape), data)
            .map_err(|e| IoError::invalid(&self.path, format!("{full}: {e}")))?;
        ds.write_slice(view, Selection::Hyperslab(Hyperslab::from(sel)))
            .map_err(err)
    }
}

impl Drop for TrajectoryWriter {
    fn drop(&mut self) {
        // Errors cannot be returned from drop; `close` reports them.
        let _ = self.finish();
    }
}

fn resize_first(path: &Path, ds: &hdf5::Dataset, rows: usize) -> Result<()> {
    let mut shape = ds.shape();
    if shape.is_empty() {
        return Err(IoError::invalid(path, format!("{}: scalar dataset", ds.name())));
    }
    if shape[0] != rows {
        shape[0] = rows;
        ds.resize(shape).map_err(|e| IoError::hdf5(path, ds.name(), e))?;
    }
    Ok(())
}

fn last_step(path: &Path, group: &hdf5::Group) -> Result<Option<u64>> {
    let frames = valid_frames(path, group)?;
    if frames == 0 {
        return Ok(None);
    }
    read_one::<u64>(path, group, "step", frames - 1).map(Some)
}

fn truncate_group(path: &Path, group: &hdf5::Group, keep: usize) -> Result<()> {
    for ds in per_frame_datasets(path, group)? {
        if ds.shape().first().copied().unwrap_or(0) > keep {
            resize_first(path, &ds, keep)?;
        }
    }
    set_attr(path, group, "frames", keep as u64)
}

fn write_metadata(path: &Path, file: &hdf5::File, meta: &RunMetadata) -> Result<()> {
    set_attr_str(path, file, "format", TRAJECTORY_FORMAT)?;
    set_attr(path, file, "format_version", TRAJECTORY_VERSION)?;
    set_attr_str(path, file, "hemodpd_version", &meta.hemodpd_version)?;
    set_attr_str(path, file, "scenario_name", &meta.scenario_name)?;
    set_attr_str(path, file, "scenario", &meta.scenario_toml)?;
    set_attr(path, file, "seed", meta.seed)?;
    set_attr_str(path, file, "value_units", "SI")?;
    let u = &meta.units;
    set_attr(path, file, "unit_length_m", u.length_m)?;
    set_attr(path, file, "unit_time_s", u.time_s)?;
    set_attr(path, file, "unit_energy_j", u.energy_j)?;
    set_attr(path, file, "unit_force_n", u.force_n())?;
    set_attr(path, file, "unit_mass_kg", u.mass_kg())?;
    set_attr(path, file, "unit_velocity_m_per_s", u.velocity_m_per_s())?;
    set_attr_str(path, file, "unit_label", &u.label)?;
    if !meta.extra.is_empty() {
        let extra = file
            .create_group("extra")
            .map_err(|e| IoError::hdf5(path, "/extra", e))?;
        for (name, value) in &meta.extra {
            match value {
                MetaValue::F64(v) => set_attr(path, &extra, name, *v)?,
                MetaValue::I64(v) => set_attr(path, &extra, name, *v)?,
                MetaValue::Str(v) => set_attr_str(path, &extra, name, v)?,
            }
        }
    }
    Ok(())
}

fn read_metadata(path: &Path, file: &hdf5::File) -> Result<RunMetadata> {
    check_format(path, file)?;
    let mut extra = Vec::new();
    if file.link_exists("extra") {
        let g = file.group("extra").map_err(|e| IoError::hdf5(path, "/extra", e))?;
        for name in g.attr_names().map_err(|e| IoError::hdf5(path, "/extra", e))? {
            let v = if let Ok(s) = get_attr_str(path, &g, &name) {
                MetaValue::Str(s)
            } else if let Ok(a) = g.attr(&name) {
                let is_int = a.dtype().map(|t| t.is::<i64>()).unwrap_or(false);
                if is_int {
                    MetaValue::I64(get_attr(path, &g, &name)?)
                } else {
                    MetaValue::F64(get_attr(path, &g, &name)?)
                }
            } else {
                continue;
            };
            extra.push((name, v));
        }
    }
    Ok(RunMetadata {
        scenario_name: get_attr_str(path, file, "scenario_name")?,
        scenario_toml: get_attr_str(path, file, "scenario")?,
        seed: get_attr(path, file, "seed")?,
        hemodpd_version: get_attr_str(path, file, "hemodpd_version")?,
        units: UnitSystem {
            length_m: get_attr(path, file, "unit_length_m")?,
            time_s: get_attr(path, file, "unit_time_s")?,
            energy_j: get_attr(path, file, "unit_energy_j")?,
            label: get_attr_str(path, file, "unit_label")?,
        },
        extra,
    })
}

fn field_names(path: &Path, file: &hdf5::File) -> Result<Vec<String>> {
    if !file.link_exists(FIELDS) {
        return Ok(Vec::new());
    }
    let g = file.group(FIELDS).map_err(|e| IoError::hdf5(path, FIELDS, e))?;
    let mut names = g.member_names().map_err(|e| IoError::hdf5(path, FIELDS, e))?;
    names.sort();
    Ok(names)
}

/// A membrane frame read back, in SI.
#[derive(Clone, Debug, PartialEq)]
pub struct MembraneFrame {
    pub step: u64,
    /// Simulated time, s.
    pub time: f64,
    /// Vertex positions, m.
    pub positions: Vec<DVec3>,
    /// Vertex velocities, m/s, when stored.
    pub velocities: Option<Vec<DVec3>>,
}

/// A fluid frame read back, in SI.
#[derive(Clone, Debug, PartialEq)]
pub struct FluidFrame {
    pub step: u64,
    pub time: f64,
    pub positions: Vec<DVec3>,
    pub velocities: Option<Vec<DVec3>>,
    pub types: Option<Vec<u8>>,
}

/// Description of a binned field, in SI.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldInfo {
    pub name: String,
    pub grid: GridSpec,
    pub components: usize,
    pub units: String,
    pub frames: usize,
}

/// A field frame read back: `values` x fastest, `components` per bin, SI.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldFrame {
    pub step: u64,
    pub time: f64,
    pub values: Vec<f64>,
}

/// Reads a trajectory file. Every accessor validates what it reads: a foreign, truncated or
/// inconsistent file gives an [`IoError`], never a panic.
pub struct TrajectoryReader {
    path: PathBuf,
    file: hdf5::File,
    meta: RunMetadata,
}

fn to_vec3(flat: &[f64]) -> Vec<DVec3> {
    flat.chunks_exact(3).map(|c| DVec3::new(c[0], c[1], c[2])).collect()
}

impl TrajectoryReader {
    /// Opens a trajectory read-only and checks its format tag and metadata.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        if !path.exists() {
            return Err(IoError::fs(
                &path,
                std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
            ));
        }
        let file = hdf5::File::open(&path).map_err(|source| IoError::Open {
            path: path.clone(),
            action: "open",
            source,
        })?;
        let meta = read_metadata(&path, &file)?;
        Ok(TrajectoryReader { path, file, meta })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn metadata(&self) -> &RunMetadata {
        &self.meta
    }

    /// The underlying HDF5 file, for anything the accessors do not cover.
    pub fn hdf5_file(&self) -> &hdf5::File {
        &self.file
    }

    fn group(&self, name: &str) -> Result<hdf5::Group> {
        if !self.file.link_exists(name) {
            return Err(IoError::MissingDataset {
                path: self.path.clone(),
                dataset: name.to_string(),
            });
        }
        self.file.group(name).map_err(|e| IoError::hdf5(&self.path, name, e))
    }

    fn frames(&self, group: &str) -> Result<usize> {
        if !self.file.link_exists(group) {
            return Ok(0);
        }
        valid_frames(&self.path, &self.group(group)?)
    }

    fn check_frame(&self, group: &str, i: usize) -> Result<hdf5::Group> {
        let n = self.frames(group)?;
        if i >= n {
            return Err(IoError::invalid(
                &self.path,
                format!("{group}: frame {i} requested, the file has {n}"),
            ));
        }
        self.group(group)
    }

    /// Whether the file holds a membrane mesh.
    pub fn has_membrane(&self) -> bool {
        link_exists(&self.file, "/membrane/triangles")
    }

    /// Membrane triangles, validated: shape `(n, 3)`.
    pub fn triangles(&self) -> Result<Vec<[u32; 3]>> {
        let name = "/membrane/triangles";
        let ds = dataset(&self.path, &self.file, name)?;
        expect_shape(&self.path, &ds, "(n_triangles, 3)", |s| s.len() == 2 && s[1] == 3)?;
        let flat: Vec<u32> = ds.read_raw().map_err(|e| IoError::hdf5(&self.path, name, e))?;
        Ok(flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
    }

    /// Number of complete membrane frames.
    pub fn membrane_frames(&self) -> Result<usize> {
        self.frames(MEMBRANE)
    }

    /// Steps of the membrane frames.
    pub fn membrane_steps(&self) -> Result<Vec<u64>> {
        let n = self.membrane_frames()?;
        if n == 0 {
            return Ok(Vec::new());
        }
        read_rows(&self.path, &self.group(MEMBRANE)?, "step", 0, n)
    }

    /// Times of the membrane frames, s.
    pub fn membrane_times(&self) -> Result<Vec<f64>> {
        let n = self.membrane_frames()?;
        if n == 0 {
            return Ok(Vec::new());
        }
        read_rows(&self.path, &self.group(MEMBRANE)?, "time", 0, n)
    }

    /// Membrane frame `i` (0-based), SI.
    pub fn membrane_frame(&self, i: usize) -> Result<MembraneFrame> {
        let g = self.check_frame(MEMBRANE, i)?;
        let pos = dataset(&self.path, &g, "positions")?;
        expect_shape(&self.path, &pos, "(frames, n_vertices, 3)", |s| {
            s.len() == 3 && s[2] == 3
        })?;
        let positions = to_vec3(&read_rows::<f64>(&self.path, &g, "positions", i, i + 1)?);
        let velocities = if g.link_exists("velocities") {
            let v = dataset(&self.path, &g, "velocities")?;
            expect_shape(&self.path, &v, "same as positions", |s| s == pos.shape())?;
            Some(to_vec3(&read_rows::<f64>(&self.path, &g, "velocities", i, i + 1)?))
        } else {
            None
        };
        let step = read_one::<u64>(&self.path, &g, "step", i)?;
        let time = read_one::<f64>(&self.path, &g, "time", i)?;
        Ok(MembraneFrame {
            step,
            time,
            positions,
            velocities,
        })
    }

    /// Names of the per-frame membrane scalars.
    pub fn membrane_scalar_names(&self) -> Result<Vec<String>> {
        if !link_exists(&self.file, "/membrane/scalars") {
            return Ok(Vec::new());
        }
        let g = self.group("/membrane/scalars")?;
        g.member_names()
            .map_err(|e| IoError::hdf5(&self.path, "/membrane/scalars", e))
    }

    /// A per-frame membrane scalar (SI), one value per membrane frame (NaN where not given).
    pub fn membrane_scalar(&self, name: &str) -> Result<Vec<f64>> {
        let n = self.membrane_frames()?;
        let g = self.group("/membrane/scalars")?;
        let mut v: Vec<f64> = if n == 0 {
            Vec::new()
        } else {
            read_rows(&self.path, &g, name, 0, n)?
        };
        v.truncate(n);
        Ok(v)
    }

    /// Reference area (m²) and volume (m³) of the membrane, when stored.
    pub fn membrane_reference(&self) -> Result<Option<(f64, f64)>> {
        if !self.file.link_exists(MEMBRANE) {
            return Ok(None);
        }
        let g = self.group(MEMBRANE)?;
        let a = get_attr_opt::<f64>(&self.path, &g, "reference_area")?;
        let v = get_attr_opt::<f64>(&self.path, &g, "reference_volume")?;
        Ok(a.zip(v))
    }

    /// Number of complete fluid frames.
    pub fn fluid_frames(&self) -> Result<usize> {
        self.frames(FLUID)
    }

    /// Fluid frame `i`, SI.
    pub fn fluid_frame(&self, i: usize) -> Result<FluidFrame> {
        let g = self.check_frame(FLUID, i)?;
        let pos = dataset(&self.path, &g, "positions")?;
        expect_shape(&self.path, &pos, "(frames, n_particles, 3)", |s| {
            s.len() == 3 && s[2] == 3
        })?;
        let positions = to_vec3(&read_rows::<f64>(&self.path, &g, "positions", i, i + 1)?);
        let velocities = if g.link_exists("velocities") {
            Some(to_vec3(&read_rows::<f64>(&self.path, &g, "velocities", i, i + 1)?))
        } else {
            None
        };
        let types = if g.link_exists("types") {
            Some(read_rows::<u8>(&self.path, &g, "types", i, i + 1)?)
        } else {
            None
        };
        Ok(FluidFrame {
            step: read_one::<u64>(&self.path, &g, "step", i)?,
            time: read_one::<f64>(&self.path, &g, "time", i)?,
            positions,
            velocities,
            types,
        })
    }

    /// Names of the binned fields, sorted.
    pub fn field_names(&self) -> Result<Vec<String>> {
        field_names(&self.path, &self.file)
    }

    /// Grid and size of field `name`, SI.
    pub fn field_info(&self, name: &str) -> Result<FieldInfo> {
        let gname = format!("{FIELDS}/{name}");
        let g = self.group(&gname)?;
        let origin: Vec<f64> = get_attr_array(&self.path, &g, "origin")?;
        let spacing: Vec<f64> = get_attr_array(&self.path, &g, "spacing")?;
        let shape: Vec<u64> = get_attr_array(&self.path, &g, "shape")?;
        let components: u64 = get_attr(&self.path, &g, "components")?;
        if origin.len() != 3 || spacing.len() != 3 || shape.len() != 3 {
            return Err(IoError::invalid(
                &self.path,
                format!("{gname}: origin, spacing and shape must have 3 entries"),
            ));
        }
        let ds = dataset(&self.path, &g, "values")?;
        let expected = [
            shape[2] as usize,
            shape[1] as usize,
            shape[0] as usize,
            components as usize,
        ];
        expect_shape(&self.path, &ds, &format!("(frames, {expected:?})"), |s| {
            s.len() == 5 && s[1..] == expected
        })?;
        let units = get_attr_str_opt(&self.path, &ds, "units")?.unwrap_or_default();
        Ok(FieldInfo {
            name: name.to_string(),
            grid: GridSpec {
                origin: DVec3::new(origin[0], origin[1], origin[2]),
                spacing: DVec3::new(spacing[0], spacing[1], spacing[2]),
                shape: [shape[0] as usize, shape[1] as usize, shape[2] as usize],
            },
            components: components as usize,
            units,
            frames: valid_frames(&self.path, &g)?,
        })
    }

    /// Frame `i` of field `name`.
    pub fn field_frame(&self, name: &str, i: usize) -> Result<FieldFrame> {
        let gname = format!("{FIELDS}/{name}");
        self.field_info(name)?;
        let g = self.check_frame(&gname, i)?;
        Ok(FieldFrame {
            step: read_one::<u64>(&self.path, &g, "step", i)?,
            time: read_one::<f64>(&self.path, &g, "time", i)?,
            values: read_rows(&self.path, &g, "values", i, i + 1)?,
        })
    }
}

/// Reads the run metadata of a trajectory file.
pub fn read_trajectory_metadata(path: impl AsRef<Path>) -> Result<RunMetadata> {
    Ok(TrajectoryReader::open(path)?.meta)
}

/// Converts particle types to the `u8` the trajectory stores, refusing any above 255
/// ([`IoError::TypeOutOfRange`] names `path`, the particle index and its type).
pub fn types_to_u8(path: &Path, types: &[u16]) -> Result<Vec<u8>> {
    types
        .iter()
        .enumerate()
        .map(|(index, &t)| {
            u8::try_from(t).map_err(|_| IoError::TypeOutOfRange {
                path: path.to_path_buf(),
                index,
                value: t as u64,
                max: u8::MAX,
            })
        })
        .collect()
}
