//! Parsing, overriding and validating scenario files.

use crate::FORMAT_VERSION;
use hemodpd_engine::walls::{ControlLaw, Reflection};
use hemodpd_membrane::ReferenceState;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// A bad scenario: always names the file and, where it applies, the key, the value and what is allowed.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    #[error("{file}: cannot read: {source}")]
    Read { file: String, source: std::io::Error },
    #[error("{file}: {message}")]
    Syntax { file: String, message: String },
    #[error("{file}: key `{key}` = {value} is not allowed: {allowed}")]
    Value {
        file: String,
        key: String,
        value: String,
        allowed: String,
    },
    #[error("{file}: missing key `{key}` ({what})")]
    Missing { file: String, key: String, what: String },
    #[error("--set {assignment}: {message}")]
    Override { assignment: String, message: String },
}

/// A validated scenario.
#[derive(Clone, Debug, Serialize)]
#[serde(untagged)]
pub enum Scenario {
    Stretching(StretchingScenario),
    DpdFluid(FluidScenario),
    PoiseuilleTube(TubeScenario),
    Couette(CouetteScenario),
    Capillary(crate::capillary::CapillaryScenario),
}

impl Scenario {
    pub fn seed(&self) -> u64 {
        match self {
            Scenario::Stretching(s) => s.seed,
            Scenario::DpdFluid(s) => s.seed,
            Scenario::PoiseuilleTube(s) => s.seed,
            Scenario::Couette(s) => s.seed,
            Scenario::Capillary(s) => s.seed,
        }
    }
    pub fn kind(&self) -> &'static str {
        match self {
            Scenario::Stretching(_) => "stretching",
            Scenario::DpdFluid(_) => "dpd-fluid",
            Scenario::PoiseuilleTube(_) => "poiseuille-tube",
            Scenario::Couette(_) => "couette",
            Scenario::Capillary(_) => "capillary",
        }
    }
    /// The resolved scenario (defaults filled in, overrides applied) as TOML text.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_default()
    }
}

fn default_temperature() -> f64 {
    300.0
}
fn one() -> f64 {
    1.0
}
fn default_k_area() -> f64 {
    hemodpd_membrane::forces::DEFAULT_K_AREA_N_PER_M
}
fn default_k_volume() -> f64 {
    hemodpd_membrane::forces::DEFAULT_K_VOLUME_N_PER_M2
}
fn default_end_fraction() -> f64 {
    0.05
}
fn default_tolerance() -> f64 {
    1e-4
}
fn default_max_iterations() -> u64 {
    100_000
}
fn yes() -> bool {
    true
}

/// `[membrane]`: the cell model.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MembraneSection {
    /// Number of mesh vertices N (≥ 100): sets the level of coarse-graining (Eqs. 8, 9, 12).
    pub vertices: i64,
    /// Temperature, K (default 300).
    #[serde(default = "default_temperature")]
    pub temperature_k: f64,
    /// `"stress-free"` (default: each link and triangle unstrained at rest) or `"uniform"` (the paper's one L0).
    #[serde(default)]
    pub reference: ReferenceState,
    /// Multiplies the Eq. 12 persistence length (the paper's ±10 % sensitivity study). Default 1.
    #[serde(default = "one")]
    pub persistence_scale: f64,
    /// Explicit persistence length in nm, replacing Eq. 12 (e.g. the fine model's 7.5).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub persistence_length_nm: Option<f64>,
    /// Global area constraint k_a, N/m (default 2e-3 = 2000 pN/µm ≈ 240 μ0).
    #[serde(default = "default_k_area")]
    pub area_constraint_n_per_m: f64,
    /// Global volume constraint k_v, N/m² (default 1e3 = 1000 pN/µm²).
    #[serde(default = "default_k_volume")]
    pub volume_constraint_n_per_m2: f64,
    /// A user's mesh (OFF, PLY or NAME.vertices.csv with NAME.triangles.csv, lengths in µm),
    /// relative to the scenario file. Default: generate (and cache) the relaxed Evans–Fung mesh.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh_file: Option<PathBuf>,
}

/// `[stretching]`: the optical-tweezers protocol.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct StretchingSection {
    /// Total stretching forces, pN, increasing, within [0, 500].
    pub forces_pn: Vec<f64>,
    /// Fraction of vertices loaded at each end (default 0.05, the paper's).
    #[serde(default = "default_end_fraction")]
    pub end_fraction: f64,
    /// Static equilibrium: the largest net force on any vertex below this, pN (default 1e-4).
    #[serde(default = "default_tolerance")]
    pub tolerance_pn: f64,
    /// Iteration cap per force (default 100000); not converging is an error.
    #[serde(default = "default_max_iterations")]
    pub max_iterations: u64,
}

/// `[output]`
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct StretchingOutput {
    /// Write the shape at each force to `shapes.h5` (+ `.xmf`). Default true.
    #[serde(default = "yes")]
    pub shapes: bool,
}

impl Default for StretchingOutput {
    fn default() -> Self {
        Self { shapes: true }
    }
}

/// `kind = "stretching"`
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct StretchingScenario {
    pub format_version: u32,
    pub kind: String,
    /// Seed of everything random (mesh point jitter).
    pub seed: u64,
    pub membrane: MembraneSection,
    pub stretching: StretchingSection,
    #[serde(default)]
    pub output: StretchingOutput,
    /// Directory of the scenario file (to resolve relative paths); not part of the file.
    #[serde(skip)]
    pub base_dir: PathBuf,
}

/// `kind = "dpd-fluid"`: the standard periodic DPD fluid, in model (DPD) units.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FluidScenario {
    pub format_version: u32,
    pub kind: String,
    pub seed: u64,
    pub fluid: FluidSection,
    pub run: FluidRunSection,
    #[serde(default)]
    pub output: FluidOutput,
}

/// `[output]` of the fluid scenario. Steps count from the start of production.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FluidOutput {
    /// Write a frame (particles and binned density/velocity) to `trajectory.h5` every this many
    /// production steps; 0 (default) writes no trajectory.
    #[serde(default)]
    pub trajectory_every_steps: u64,
    /// Store every this-many-th particle in a frame (default 1: all).
    #[serde(default = "one_u64")]
    pub particle_stride: u64,
    /// Bins of the density/velocity field along z (default 20; 0: no field).
    #[serde(default = "twenty")]
    pub field_bins: u64,
    /// Write `checkpoint.h5` every this many steps (counting equilibration); 0 (default): only
    /// at the end and on Ctrl-C.
    #[serde(default)]
    pub checkpoint_every_steps: u64,
}

impl Default for FluidOutput {
    fn default() -> Self {
        Self {
            trajectory_every_steps: 0,
            particle_stride: 1,
            field_bins: 20,
            checkpoint_every_steps: 0,
        }
    }
}

/// `[output]` of the wall scenarios (optional). Steps count from the start of the walled run
/// (adaptation included).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct WallOutput {
    /// Write a frame (fluid and wall particles, with types) to `trajectory.h5` every this many
    /// steps; 0 (default) writes no trajectory.
    #[serde(default)]
    pub trajectory_every_steps: u64,
    /// Store every this-many-th particle in a frame (default 1: all).
    #[serde(default = "one_u64")]
    pub particle_stride: u64,
    /// Write `checkpoint.h5` every this many steps; 0 (default): only at the end and on Ctrl-C.
    #[serde(default)]
    pub checkpoint_every_steps: u64,
}

impl Default for WallOutput {
    fn default() -> Self {
        Self {
            trajectory_every_steps: 0,
            particle_stride: 1,
            checkpoint_every_steps: 0,
        }
    }
}

fn one_u64() -> u64 {
    1
}
fn hundred() -> u64 {
    100
}
fn twenty() -> u64 {
    20
}

fn f_rho() -> f64 {
    3.0
}
fn f_a() -> f64 {
    25.0
}
fn f_gamma() -> f64 {
    4.5
}
fn f_cut() -> f64 {
    1.0
}
fn f_lambda() -> f64 {
    0.5
}
fn f_dt() -> f64 {
    0.01
}

/// `[fluid]`, model units: lengths in rc, energies in kBT, masses in m.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FluidSection {
    /// Number density, particles per rc³ (default 3).
    #[serde(default = "f_rho")]
    pub density: f64,
    /// Box edges, rc (each ≥ 3 rc). Required by `dpd-fluid`; the wall scenarios size their box
    /// from `[tube]` or `[plates]` and reject it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub box_size: Option<[f64; 3]>,
    /// Conservative amplitude a (default 25).
    #[serde(default = "f_a")]
    pub a: f64,
    /// Dissipative coefficient γ (default 4.5).
    #[serde(default = "f_gamma")]
    pub gamma: f64,
    /// Thermal energy kBT (default 1).
    #[serde(default = "one")]
    pub kbt: f64,
    /// Cut-off radius (default 1).
    #[serde(default = "f_cut")]
    pub cutoff: f64,
    /// Random-weight exponent s, w^R = (1 − r/rc)^s (default 1; 0.5 and 0.25 raise the Schmidt number).
    #[serde(default = "one")]
    pub weight_exponent: f64,
}

/// `[run]` of the fluid scenario.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct FluidRunSection {
    /// Time step (default 0.01).
    #[serde(default = "f_dt")]
    pub timestep: f64,
    /// Groot–Warren λ (default 0.5).
    #[serde(default = "f_lambda")]
    pub lambda: f64,
    /// Equilibration steps (not sampled).
    pub equilibration_steps: u64,
    /// Production steps.
    pub steps: u64,
    /// Sample T and p every this many steps.
    pub sample_every: u64,
}

fn w_bins() -> usize {
    5
}
fn w_gain() -> f64 {
    3.0
}
fn w_every() -> u64 {
    500
}
fn w_iters() -> u64 {
    10
}
fn w_equil() -> u64 {
    300
}
fn w_profile_bins() -> usize {
    16
}

/// Initial near-wall force of the adaptive control, when no saved profile is loaded.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum InitialWallForce {
    /// Start from zero (the frozen wall particles already supply the repulsion).
    #[default]
    Zero,
    /// The integrated conservative force of a half-space of fluid, πρa(rc − h)³(rc + 3h)/(12 rc).
    HalfSpace,
    /// The converged profile of an earlier adaptive run of the same fluid, geometry, bins,
    /// control law and reflection, from the cache directory (zero when there is none). The
    /// summary names the file it came from.
    Cached,
}

/// `[walls]`: reflection and the adaptive near-wall force (docs/walls.md).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct WallsSection {
    /// `"bounce-back"` (default, no slip) or `"specular"`.
    #[serde(default)]
    pub reflection: Reflection,
    /// Adaptive control on (default true).
    #[serde(default = "yes")]
    pub adaptive: bool,
    /// `"gradient"` (default: F_k += α(e_k − e_{k+1})) or `"local"` (F_k += α e_k).
    #[serde(default)]
    pub law: ControlLaw,
    /// Bins of the near-wall layer 0 ≤ h < rc (default 5).
    #[serde(default = "w_bins")]
    pub bins: usize,
    /// Gain α, force units (default 3).
    #[serde(default = "w_gain")]
    pub gain: f64,
    /// Steps averaged per update M (default 500).
    #[serde(default = "w_every")]
    pub update_every: u64,
    /// Number of updates (default 10); the flow is on during adaptation.
    #[serde(default = "w_iters")]
    pub adapt_iterations: u64,
    /// Initial force profile: `"zero"` (default; the frozen wall particles supply the
    /// repulsion), `"half-space"` (πρa(rc − h)³(rc + 3h)/(12rc)) or `"cached"` (the converged
    /// profile of an earlier adaptive run with the same fluid, geometry, bins, law and
    /// reflection, from the cache directory; zero when there is none).
    #[serde(default)]
    pub initial: InitialWallForce,
    /// A force-profile CSV to start from (e.g. a previous run's `wall_force.csv`), relative to
    /// the scenario file: used instead of `initial` when it matches the fluid and bins. Only
    /// read, never written.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force_file: Option<PathBuf>,
}

/// `[run]` of the wall scenarios (model units).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct WallRunSection {
    /// Time step (default 0.01).
    #[serde(default = "f_dt")]
    pub timestep: f64,
    /// Groot–Warren λ (default 0.5).
    #[serde(default = "f_lambda")]
    pub lambda: f64,
    /// Steps of the periodic fluid before the walls are cut out of it (default 300).
    #[serde(default = "w_equil")]
    pub equilibration_steps: u64,
    /// Steps of flow development after adaptation, not sampled.
    pub flow_steps: u64,
    /// Sampled steps.
    pub steps: u64,
    /// Sample the profiles every this many steps.
    pub sample_every: u64,
    /// Bins of the velocity/density profile across the channel (default 16).
    #[serde(default = "w_profile_bins")]
    pub profile_bins: usize,
    /// Also time the same number of fluid particles in a periodic box, for the wall overhead
    /// (default true).
    #[serde(default = "yes")]
    pub measure_overhead: bool,
}

/// `[tube]`: the capillary, in rc. The paper's 10 µm × 45 µm tube is radius 5, length 22.5 at
/// `length_scale_um_per_rc = 1`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TubeSection {
    /// Radius of the fluid region, rc (≥ 2).
    pub radius: f64,
    /// Length along the (periodic) axis z, rc (≥ 3).
    pub length: f64,
    /// Body force per fluid particle along the axis (model units; drives the flow). Needed
    /// unless `mean_velocity` is set, which takes precedence (the controller sets the force).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub body_force: Option<f64>,
    /// Target mean axial velocity of the fluid (model units, optional). When set, a controller
    /// adjusts the body force every `flow_control_every` steps to hold it (docs/walls.md).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mean_velocity: Option<f64>,
    /// Steps between updates of the flow controller (default 100).
    #[serde(default = "hundred")]
    pub flow_control_every: u64,
    /// µm per rc, to report lengths in µm as well (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub length_scale_um_per_rc: Option<f64>,
    /// Viscosity of the fluid measured independently (model units; 0.842 for the standard
    /// fluid by reverse Poiseuille, docs/engine.md). Optional: when given, the results compare the
    /// profile with the analytic no-slip parabola v = n g (R² − r²)/(4η) for it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_viscosity: Option<f64>,
}

/// `kind = "poiseuille-tube"`: body-force-driven flow in a tube with adaptive walls.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TubeScenario {
    pub format_version: u32,
    pub kind: String,
    pub seed: u64,
    pub fluid: FluidSection,
    pub tube: TubeSection,
    pub walls: WallsSection,
    pub run: WallRunSection,
    #[serde(default)]
    pub output: WallOutput,
    /// Directory of the scenario file (for `walls.force_file`); not part of the file.
    #[serde(skip)]
    pub base_dir: PathBuf,
}

/// `[plates]`: two plates normal to z moving along x at −speed (lower) and +speed (upper).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PlatesSection {
    /// Distance between the surfaces, rc (≥ 3).
    pub gap: f64,
    /// Box edges along x and y, rc (each ≥ 3).
    pub width: [f64; 2],
    /// Plate speed U: the lower plate moves at −U, the upper at +U along x.
    pub wall_speed: f64,
}

/// `kind = "couette"`: plane Couette flow between moving plates.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct CouetteScenario {
    pub format_version: u32,
    pub kind: String,
    pub seed: u64,
    pub fluid: FluidSection,
    pub plates: PlatesSection,
    pub walls: WallsSection,
    pub run: WallRunSection,
    #[serde(default)]
    pub output: WallOutput,
    /// Directory of the scenario file; not part of the file.
    #[serde(skip)]
    pub base_dir: PathBuf,
}

fn syntax(file: &str, e: impl std::fmt::Display) -> ScenarioError {
    ScenarioError::Syntax {
        file: file.to_string(),
        message: e.to_string().trim_end().to_string(),
    }
}

/// Reads, overrides (`key=value`, dotted keys) and validates a scenario file.
pub fn load(path: &Path, sets: &[String]) -> Result<Scenario, ScenarioError> {
    let file = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| ScenarioError::Read {
        file: file.clone(),
        source,
    })?;
    let mut s = load_str(&text, &file, sets)?;
    // absolute, so that a checkpoint resumed from another working directory still finds the
    // files the scenario names
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let dir = std::path::absolute(&dir).unwrap_or(dir);
    match &mut s {
        Scenario::PoiseuilleTube(t) => t.base_dir = dir.clone(),
        Scenario::Couette(t) => t.base_dir = dir.clone(),
        Scenario::Capillary(t) => t.base_dir = dir.clone(),
        _ => {}
    }
    if let Scenario::Capillary(c) = &s {
        if let Some(m) = &c.cell.mesh_file {
            check_mesh_file(&file, "cell.mesh_file", &c.base_dir, m, c.cell.vertices)?;
        }
    }
    if let Scenario::Stretching(st) = &mut s {
        st.base_dir = dir.clone();
        if let Some(m) = &st.membrane.mesh_file {
            let full = st.base_dir.join(m);
            if !full.exists() {
                return Err(ScenarioError::Value {
                    file,
                    key: "membrane.mesh_file".into(),
                    value: format!("{:?}", m.display().to_string()),
                    allowed: format!("an existing mesh file ({} does not exist)", full.display()),
                });
            }
            // the model's parameters come from membrane.vertices (coarse-graining from N, Eqs. 8,
            // 9, 12): a file with another vertex count would get another cell's parameters
            let mesh = hemodpd_membrane::meshio::read_mesh(&full).map_err(|e| ScenarioError::Value {
                file: file.clone(),
                key: "membrane.mesh_file".into(),
                value: format!("{:?}", m.display().to_string()),
                allowed: format!(
                    "a readable closed triangle mesh in µm (OFF, PLY or NAME.vertices.csv + NAME.triangles.csv): {e}"
                ),
            })?;
            let nv = mesh.vertices.len();
            if nv as i64 != st.membrane.vertices {
                return Err(ScenarioError::Value {
                    file,
                    key: "membrane.mesh_file".into(),
                    value: format!("{:?} (with {nv} vertices)", m.display().to_string()),
                    allowed: format!(
                        "a mesh with membrane.vertices = {} vertices: the model parameters are coarse-grained from N (Eqs. 8, 9, 12), so the file's {nv} vertices and membrane.vertices = {} must agree (set membrane.vertices = {nv})",
                        st.membrane.vertices, st.membrane.vertices
                    ),
                });
            }
        }
    }
    Ok(s)
}

/// A mesh file named under `key` must exist, be readable and have `vertices` vertices.
fn check_mesh_file(file: &str, key: &str, base: &Path, m: &Path, vertices: i64) -> Result<(), ScenarioError> {
    let full = base.join(m);
    let name = format!("{:?}", m.display().to_string());
    if !full.exists() {
        return Err(ScenarioError::Value {
            file: file.into(),
            key: key.into(),
            value: name,
            allowed: format!("an existing mesh file ({} does not exist)", full.display()),
        });
    }
    let mesh = hemodpd_membrane::meshio::read_mesh(&full).map_err(|e| ScenarioError::Value {
        file: file.into(),
        key: key.into(),
        value: name.clone(),
        allowed: format!(
            "a readable closed triangle mesh in µm (OFF, PLY or NAME.vertices.csv + NAME.triangles.csv): {e}"
        ),
    })?;
    let nv = mesh.vertices.len();
    if nv as i64 != vertices {
        return Err(ScenarioError::Value {
            file: file.into(),
            key: key.into(),
            value: format!("{name} (with {nv} vertices)"),
            allowed: format!(
                "a mesh with {vertices} vertices: the model parameters are coarse-grained from N (Eqs. 8, 9, 12), so the file and the vertex count must agree"
            ),
        });
    }
    Ok(())
}

/// As [`load`], from text; `file` names it in messages.
pub fn load_str(text: &str, file: &str, sets: &[String]) -> Result<Scenario, ScenarioError> {
    let mut table: toml::Table = text.parse().map_err(|e| syntax(file, e))?;
    for a in sets {
        apply_set(&mut table, a)?;
    }
    let version = match table.get("format_version") {
        None => {
            return Err(ScenarioError::Missing {
                file: file.into(),
                key: "format_version".into(),
                what: format!("the file format version, {FORMAT_VERSION} for this build"),
            })
        }
        Some(v) => v.as_integer(),
    };
    if version != Some(FORMAT_VERSION as i64) {
        return Err(ScenarioError::Value {
            file: file.into(),
            key: "format_version".into(),
            value: table["format_version"].to_string(),
            allowed: format!("{FORMAT_VERSION} (the only version this build reads)"),
        });
    }
    let kind = match table.get("kind").and_then(|k| k.as_str()) {
        Some(k) => k.to_string(),
        None => {
            return Err(ScenarioError::Missing {
                file: file.into(),
                key: "kind".into(),
                what: "one of \"stretching\", \"dpd-fluid\", \"poiseuille-tube\", \"couette\", \"capillary\"".into(),
            })
        }
    };
    let value = toml::Value::Table(table);
    match kind.as_str() {
        "stretching" => {
            let s: StretchingScenario = value.try_into().map_err(|e| syntax(file, e))?;
            validate_stretching(&s, file)?;
            Ok(Scenario::Stretching(s))
        }
        "dpd-fluid" => {
            let s: FluidScenario = value.try_into().map_err(|e| syntax(file, e))?;
            validate_fluid(&s, file)?;
            Ok(Scenario::DpdFluid(s))
        }
        "poiseuille-tube" => {
            let s: TubeScenario = value.try_into().map_err(|e| syntax(file, e))?;
            validate_tube(&s, file)?;
            Ok(Scenario::PoiseuilleTube(s))
        }
        "couette" => {
            let s: CouetteScenario = value.try_into().map_err(|e| syntax(file, e))?;
            validate_couette(&s, file)?;
            Ok(Scenario::Couette(s))
        }
        "capillary" => {
            let s: crate::capillary::CapillaryScenario = value.try_into().map_err(|e| syntax(file, e))?;
            crate::capillary::validate(&s, file)?;
            Ok(Scenario::Capillary(s))
        }
        other => Err(ScenarioError::Value {
            file: file.into(),
            key: "kind".into(),
            value: format!("{other:?}"),
            allowed: "one of \"stretching\", \"dpd-fluid\", \"poiseuille-tube\", \"couette\", \"capillary\"".into(),
        }),
    }
}

/// Applies `a.b.c=value` to the table. The value is parsed as TOML (numbers, booleans, arrays,
/// quoted strings); anything that does not parse is taken as a bare string.
fn apply_set(table: &mut toml::Table, assignment: &str) -> Result<(), ScenarioError> {
    let bad = |m: &str| ScenarioError::Override {
        assignment: assignment.to_string(),
        message: m.to_string(),
    };
    let (key, raw) = assignment.split_once('=').ok_or_else(|| bad("expected key=value"))?;
    let key = key.trim();
    if key.is_empty() || key.split('.').any(str::is_empty) {
        return Err(bad("empty key"));
    }
    let value = match format!("v = {}", raw.trim()).parse::<toml::Table>() {
        Ok(mut t) => t.remove("v").unwrap(),
        Err(_) => toml::Value::String(raw.trim().to_string()),
    };
    let parts: Vec<&str> = key.split('.').collect();
    let mut cur = table;
    for p in &parts[..parts.len() - 1] {
        cur = cur
            .entry(p.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
            .as_table_mut()
            .ok_or_else(|| bad(&format!("`{p}` is not a table")))?;
    }
    cur.insert(parts[parts.len() - 1].to_string(), value);
    Ok(())
}

#[derive(Clone, Copy)]
struct Check<'a> {
    file: &'a str,
}

impl Check<'_> {
    fn range(&self, key: &str, v: f64, lo: f64, hi: f64, allowed: &str) -> Result<(), ScenarioError> {
        if v.is_finite() && v >= lo && v <= hi {
            Ok(())
        } else {
            Err(ScenarioError::Value {
                file: self.file.into(),
                key: key.into(),
                value: format!("{v}"),
                allowed: allowed.into(),
            })
        }
    }
    fn fail(&self, key: &str, value: impl std::fmt::Display, allowed: &str) -> ScenarioError {
        ScenarioError::Value {
            file: self.file.into(),
            key: key.into(),
            value: value.to_string(),
            allowed: allowed.into(),
        }
    }
}

fn validate_membrane(m: &MembraneSection, c: &Check) -> Result<(), ScenarioError> {
    use hemodpd_membrane::params::MIN_VERTICES;
    if m.vertices < MIN_VERTICES as i64 || m.vertices > 2_000_000 {
        return Err(c.fail(
            "membrane.vertices",
            m.vertices,
            &format!("an integer from {MIN_VERTICES} to 2000000 (the coarse-grained model needs at least {MIN_VERTICES} vertices to mesh and represent the cell)"),
        ));
    }
    c.range(
        "membrane.temperature_k",
        m.temperature_k,
        200.0,
        400.0,
        "a temperature in kelvin between 200 and 400 (room temperature is 300)",
    )?;
    c.range(
        "membrane.persistence_scale",
        m.persistence_scale,
        0.1,
        10.0,
        "a factor between 0.1 and 10 multiplying the Eq. 12 persistence length",
    )?;
    if let Some(p) = m.persistence_length_nm {
        c.range(
            "membrane.persistence_length_nm",
            p,
            0.01,
            1000.0,
            "a length in nm between 0.01 and 1000 (the fine model's is 7.5)",
        )?;
    }
    c.range(
        "membrane.area_constraint_n_per_m",
        m.area_constraint_n_per_m,
        0.0,
        10.0,
        "k_a in N/m between 0 and 10 (default 2e-3; the shear modulus is 8.3e-6)",
    )?;
    c.range(
        "membrane.volume_constraint_n_per_m2",
        m.volume_constraint_n_per_m2,
        0.0,
        1e7,
        "k_v in N/m² between 0 and 1e7 (default 1e3)",
    )?;
    Ok(())
}

fn validate_stretching(s: &StretchingScenario, file: &str) -> Result<(), ScenarioError> {
    let c = Check { file };
    if s.kind != "stretching" {
        return Err(c.fail("kind", &s.kind, "\"stretching\""));
    }
    validate_membrane(&s.membrane, &c)?;
    let st = &s.stretching;
    if st.forces_pn.is_empty() {
        return Err(c.fail("stretching.forces_pn", "[]", "a non-empty list of forces in pN"));
    }
    for (i, &f) in st.forces_pn.iter().enumerate() {
        c.range(
            &format!("stretching.forces_pn[{i}]"),
            f,
            0.0,
            500.0,
            "a force in pN between 0 and 500",
        )?;
        if i > 0 && f <= st.forces_pn[i - 1] {
            return Err(c.fail(
                &format!("stretching.forces_pn[{i}]"),
                f,
                "forces in strictly increasing order (each equilibrium continues from the previous one)",
            ));
        }
    }
    c.range(
        "stretching.end_fraction",
        st.end_fraction,
        0.001,
        0.25,
        "a fraction of the vertices between 0.001 and 0.25 (the paper's is 0.05)",
    )?;
    c.range(
        "stretching.tolerance_pn",
        st.tolerance_pn,
        1e-9,
        1.0,
        "a force in pN between 1e-9 and 1",
    )?;
    if st.max_iterations == 0 {
        return Err(c.fail("stretching.max_iterations", 0, "a positive integer"));
    }
    Ok(())
}

fn validate_fluid(s: &FluidScenario, file: &str) -> Result<(), ScenarioError> {
    let c = Check { file };
    let f = &s.fluid;
    validate_fluid_params(f, &c)?;
    if f.gamma <= 0.0 {
        // σ² = 2γkBT: γ = 0 switches the thermostat off, and the reported temperature would be
        // compared with a kBT nothing imposes
        return Err(c.fail(
            "fluid.gamma",
            f.gamma,
            "a positive dissipative coefficient up to 1e4 (γ = 0 switches the DPD thermostat off, so the temperature would not be fluid.kbt; standard: 4.5)",
        ));
    }
    let Some(box_size) = f.box_size else {
        return Err(ScenarioError::Missing {
            file: file.into(),
            key: "fluid.box_size".into(),
            what: "the box edges in rc, e.g. [10.0, 10.0, 10.0]".into(),
        });
    };
    for (k, &l) in box_size.iter().enumerate() {
        c.range(
            &format!("fluid.box_size[{k}]"),
            l,
            3.0 * f.cutoff,
            1e4,
            "a box edge of at least 3 cut-offs",
        )?;
    }
    let n = f.density * box_size.iter().product::<f64>();
    if n > 5e8 {
        return Err(c.fail(
            "fluid.box_size",
            format!("{box_size:?}"),
            "a box holding at most 5e8 particles at this density",
        ));
    }
    let r = &s.run;
    validate_stepping(c, r.timestep, 0.2, r.lambda, r.steps, r.sample_every)?;
    validate_output(&c, s.output.particle_stride)?;
    if s.output.field_bins > 1_000_000 {
        return Err(c.fail(
            "output.field_bins",
            s.output.field_bins,
            "an integer from 0 (no field) to 1000000",
        ));
    }
    Ok(())
}

/// `[output]` keys every time-stepping scenario shares.
fn validate_output(c: &Check, particle_stride: u64) -> Result<(), ScenarioError> {
    if particle_stride == 0 || particle_stride > 1_000_000_000 {
        return Err(c.fail(
            "output.particle_stride",
            particle_stride,
            "a positive stride (1: every particle, 10: every tenth)",
        ));
    }
    Ok(())
}

/// `[run]` keys every time-stepping scenario shares: Δt up to `max_dt`, λ, steps, sampling.
fn validate_stepping(
    c: Check,
    dt: f64,
    max_dt: f64,
    lambda: f64,
    steps: u64,
    sample_every: u64,
) -> Result<(), ScenarioError> {
    c.range(
        "run.timestep",
        dt,
        1e-6,
        max_dt,
        &format!("a time step between 1e-6 and {max_dt} (standard: 0.01)"),
    )?;
    c.range(
        "run.lambda",
        lambda,
        0.0,
        1.0,
        "a Groot–Warren λ between 0 and 1 (0.5 standard)",
    )?;
    if steps == 0 {
        return Err(c.fail("run.steps", 0, "a positive number of steps"));
    }
    if sample_every == 0 || sample_every > steps {
        return Err(c.fail(
            "run.sample_every",
            sample_every,
            "a positive interval no longer than run.steps",
        ));
    }
    Ok(())
}

/// The `[fluid]` parameters every scenario with a DPD fluid shares.
fn validate_fluid_params(f: &FluidSection, c: &Check) -> Result<(), ScenarioError> {
    c.range(
        "fluid.density",
        f.density,
        0.1,
        30.0,
        "a number density between 0.1 and 30 per rc³ (standard: 3)",
    )?;
    c.range("fluid.cutoff", f.cutoff, 0.1, 10.0, "a cut-off between 0.1 and 10")?;
    c.range("fluid.a", f.a, 0.0, 1e4, "a conservative amplitude between 0 and 1e4")?;
    c.range(
        "fluid.gamma",
        f.gamma,
        0.0,
        1e4,
        "a dissipative coefficient between 0 and 1e4",
    )?;
    c.range("fluid.kbt", f.kbt, 1e-6, 1e3, "a thermal energy between 1e-6 and 1e3")?;
    c.range(
        "fluid.weight_exponent",
        f.weight_exponent,
        0.05,
        4.0,
        "an exponent between 0.05 and 4 (1 standard; 0.5, 0.25 for higher Schmidt number)",
    )
}

fn validate_wall_common(
    kind: &str,
    want: &str,
    f: &FluidSection,
    w: &WallsSection,
    r: &WallRunSection,
    output: &WallOutput,
    c: &Check,
) -> Result<(), ScenarioError> {
    if kind != want {
        return Err(c.fail("kind", kind, &format!("{want:?}")));
    }
    validate_fluid_params(f, c)?;
    if f.gamma <= 0.0 {
        return Err(c.fail(
            "fluid.gamma",
            f.gamma,
            "a positive dissipative coefficient (walls need dissipation for no slip)",
        ));
    }
    if let Some(b) = f.box_size {
        return Err(c.fail(
            "fluid.box_size",
            format!("{b:?}"),
            "no box: the wall scenarios size it from [tube] or [plates]",
        ));
    }
    if w.bins == 0 || w.bins > 100 {
        return Err(c.fail("walls.bins", w.bins, "an integer from 1 to 100"));
    }
    c.range(
        "walls.gain",
        w.gain,
        0.0,
        100.0,
        "a gain between 0 and 100 (stable below ≈ kBT·bins/rc; default 3)",
    )?;
    if w.update_every == 0 {
        return Err(c.fail("walls.update_every", 0, "a positive number of steps"));
    }
    if w.adaptive && w.adapt_iterations == 0 {
        return Err(c.fail(
            "walls.adapt_iterations",
            0,
            "a positive number of updates when walls.adaptive = true (zero adapts nothing; set walls.adaptive = false for no adaptation)",
        ));
    }
    if w.adaptive && w.gain == 0.0 {
        return Err(c.fail(
            "walls.gain",
            0,
            "a positive gain up to 100 when walls.adaptive = true (zero changes nothing; set walls.adaptive = false for no adaptation)",
        ));
    }
    validate_stepping(*c, r.timestep, 0.05, r.lambda, r.steps, r.sample_every)?;
    let adapt = if w.adaptive {
        w.adapt_iterations.checked_mul(w.update_every)
    } else {
        Some(0)
    };
    let total = adapt
        .and_then(|a| a.checked_add(r.flow_steps))
        .and_then(|a| a.checked_add(r.steps));
    if total.is_none_or(|t| t > 1_000_000_000_000) {
        return Err(c.fail(
            "walls.adapt_iterations",
            w.adapt_iterations,
            "a schedule of at most 1e12 steps in all (adapt_iterations × update_every + run.flow_steps + run.steps)",
        ));
    }
    if r.profile_bins < 2 || r.profile_bins > 1000 {
        return Err(c.fail("run.profile_bins", r.profile_bins, "an integer from 2 to 1000"));
    }
    validate_output(c, output.particle_stride)
}

fn validate_tube(s: &TubeScenario, file: &str) -> Result<(), ScenarioError> {
    let c = Check { file };
    validate_wall_common(&s.kind, "poiseuille-tube", &s.fluid, &s.walls, &s.run, &s.output, &c)?;
    let rc = s.fluid.cutoff;
    c.range(
        "tube.radius",
        s.tube.radius,
        2.0 * rc,
        200.0,
        "a radius between 2 cut-offs and 200 rc",
    )?;
    c.range(
        "tube.length",
        s.tube.length,
        3.0 * rc,
        1e4,
        "a length of at least 3 cut-offs",
    )?;
    match (s.tube.body_force, s.tube.mean_velocity) {
        (None, None) => {
            return Err(ScenarioError::Missing {
                file: file.into(),
                key: "tube.body_force".into(),
                what: "the body force per fluid particle (model units, e.g. 0.05), or tube.mean_velocity for a flow held at a mean velocity".into(),
            })
        }
        (Some(g), mean) => {
            c.range(
                "tube.body_force",
                g,
                -10.0,
                10.0,
                "a body force between −10 and 10 (model units; 0.05–0.2 keeps the flow laminar and the shear rate moderate)",
            )?;
            // no drive, no flow: the viscosity from the profile's curvature would be 0/0
            if g == 0.0 && mean.is_none() {
                return Err(c.fail(
                    "tube.body_force",
                    g,
                    "a non-zero body force between −10 and 10 (zero drives no flow: the viscosity and the parabola fit would be meaningless), or tube.mean_velocity for a flow held at a mean velocity",
                ));
            }
        }
        (None, Some(_)) => {}
    }
    if let Some(l) = s.tube.length_scale_um_per_rc {
        c.range(
            "tube.length_scale_um_per_rc",
            l,
            1e-3,
            1e3,
            "µm per rc between 1e-3 and 1e3",
        )?;
    }
    if let Some(u) = s.tube.mean_velocity {
        if !(u.is_finite() && u != 0.0 && u.abs() <= 10.0) {
            return Err(c.fail(
                "tube.mean_velocity",
                u,
                "a non-zero mean velocity between −10 and 10 (model units; ≲ 1 keeps the Mach number low)",
            ));
        }
    }
    if s.tube.flow_control_every == 0 || s.tube.flow_control_every > 1_000_000 {
        return Err(c.fail(
            "tube.flow_control_every",
            s.tube.flow_control_every,
            "a number of steps from 1 to 1000000",
        ));
    }
    if s.tube.mean_velocity.is_some() {
        // the controller's window must be short against the tube's viscous time τ_v = nR²/(η j0²),
        // or its one-window delay makes the loop oscillate (docs/walls.md)
        let eta = s.tube.reference_viscosity.unwrap_or(1.0);
        let tau_v = s.fluid.density * s.tube.radius * s.tube.radius / (eta * 2.404_825_557_695_773f64.powi(2));
        let max_every = (0.5 * tau_v / s.run.timestep).floor().max(1.0) as u64;
        if s.tube.flow_control_every > max_every {
            return Err(c.fail(
                "tube.flow_control_every",
                s.tube.flow_control_every,
                &format!(
                    "at most {max_every} steps here: half the tube's viscous time nR²/(η j0²) = {tau_v:.3} over Δt"
                ),
            ));
        }
    }
    if let Some(eta) = s.tube.reference_viscosity {
        c.range(
            "tube.reference_viscosity",
            eta,
            1e-3,
            1e4,
            "a viscosity between 1e-3 and 1e4 in model units (0.842 for the standard fluid)",
        )?;
    }
    let side = 2.0 * (s.tube.radius + rc) + 0.5;
    if s.fluid.density * side * side * s.tube.length > 5e8 {
        return Err(c.fail("tube.radius", s.tube.radius, "a tube holding at most 5e8 particles"));
    }
    Ok(())
}

fn validate_couette(s: &CouetteScenario, file: &str) -> Result<(), ScenarioError> {
    let c = Check { file };
    validate_wall_common(&s.kind, "couette", &s.fluid, &s.walls, &s.run, &s.output, &c)?;
    let rc = s.fluid.cutoff;
    c.range(
        "plates.gap",
        s.plates.gap,
        3.0 * rc,
        1e4,
        "a gap of at least 3 cut-offs",
    )?;
    for (k, &w) in s.plates.width.iter().enumerate() {
        c.range(
            &format!("plates.width[{k}]"),
            w,
            3.0 * rc,
            1e4,
            "a box edge of at least 3 cut-offs",
        )?;
    }
    let speed_allowed = "a non-zero plate speed between −5 and 5 (model units; |U|·Δt must stay well below the cell size; zero shears nothing, so the viscosity, stress over shear rate, would be 0/0)";
    c.range("plates.wall_speed", s.plates.wall_speed, -5.0, 5.0, speed_allowed)?;
    if s.plates.wall_speed == 0.0 {
        return Err(c.fail("plates.wall_speed", s.plates.wall_speed, speed_allowed));
    }
    if s.fluid.density * s.plates.width[0] * s.plates.width[1] * (s.plates.gap + 2.0 * rc) > 5e8 {
        return Err(c.fail("plates.gap", s.plates.gap, "a channel holding at most 5e8 particles"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = r#"
format_version = 1
kind = "stretching"
seed = 3
[membrane]
vertices = 500
[stretching]
forces_pn = [0, 100, 200]
"#;

    #[test]
    fn good_file_and_overrides() {
        let s = load_str(
            GOOD,
            "good.toml",
            &[
                "membrane.vertices=800".into(),
                "stretching.forces_pn=[0, 50]".into(),
                "membrane.reference=uniform".into(),
            ],
        )
        .unwrap();
        let Scenario::Stretching(s) = s else { panic!() };
        assert_eq!(s.membrane.vertices, 800);
        assert_eq!(s.stretching.forces_pn, vec![0.0, 50.0]);
        assert_eq!(s.membrane.reference, ReferenceState::Uniform);
        assert_eq!(s.membrane.temperature_k, 300.0);
    }

    #[test]
    fn resolved_scenario_round_trips() {
        let s = load_str(GOOD, "good.toml", &[]).unwrap();
        let again = load_str(&s.to_toml(), "resolved.toml", &[]).unwrap();
        assert_eq!(s.to_toml(), again.to_toml());
    }
}
