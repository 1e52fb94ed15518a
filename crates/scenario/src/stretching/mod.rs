//! The optical-tweezers stretching scenario (SPEC §2): no fluid, static equilibrium per force,
//! diameters compared with Mills et al. (2004); optionally released after the last force, its
//! recovery compared with Hochmuth et al. (1979) ([`recovery`]).

pub mod recovery;

use crate::cell::section::{MAX_EXTENSION_ALLOWED, MAX_EXTENSION_RANGE};
use crate::context::{RunContext, RunError};
use crate::file::{one, yes, Check, ScenarioError};
use crate::mesh_cache::{self, constants_um_pn};
use crate::run_dir::{self, out_err};
use hemodpd_io::checkpoint::{Checkpoint, ScalarValue};
use hemodpd_io::{FrameScalar, Quantity, RunMetadata, TrajectoryWriter, UnitSystem};
use hemodpd_membrane::params::ModelParams;
use hemodpd_membrane::stretch::{self, Preconditioning, StretchOptions, StretchPoint};
use hemodpd_membrane::{MembraneModel, Mesh, ReferenceState};
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::path::PathBuf;

// ---- the scenario file: `[membrane]`, `[stretching]`, `[output]` ----

fn default_temperature() -> f64 {
    300.0
}
fn default_max_extension() -> f64 {
    hemodpd_membrane::params::fine::LMAX_OVER_L0
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

/// `[membrane]`: the cell model.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct MembraneSection {
    /// Number of mesh vertices N (≥ 100): sets the level of coarse-graining (Eqs. 8, 9, 12).
    pub vertices: i64,
    /// Temperature, K (default 300).
    #[serde(default = "default_temperature")]
    pub temperature_k: f64,
    /// A named membrane parameter set (`"paper"`, `"calibrated"`, `"calibrated-x0"`;
    /// crate::parameter_sets) whose values fill `reference`, `persistence_scale`,
    /// `max_extension_ratio` and, with `[recovery]`, its membrane viscosity where the file gives
    /// none. Absent: the keys' own defaults, the paper's set.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parameters: Option<String>,
    /// `"stress-free"` (default: each link and triangle unstrained at rest), `"uniform"` (the
    /// paper's one L0), or `{ spheroid = { reduced_volume = v } }` (unstrained on the oblate
    /// spheroid of the cell's area and reduced volume v, 0.65–1).
    #[serde(default)]
    pub reference: ReferenceState,
    /// Multiplies the Eq. 12 persistence length (the paper's ±10 % sensitivity study). Default 1.
    #[serde(default = "one")]
    pub persistence_scale: f64,
    /// Explicit persistence length in nm, replacing Eq. 12 (e.g. the fine model's 7.5).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub persistence_length_nm: Option<f64>,
    /// Lmax/L0, the WLC links' maximum extension over their rest length (default 3.17, the
    /// paper's; x0 = 1/ratio). Smaller stiffens the links sooner as they stretch; μ0 and K follow
    /// (Eqs. 10, 11) at the same persistence length.
    #[serde(default = "default_max_extension")]
    pub max_extension_ratio: f64,
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
    /// The solver's preconditioner: `"gauss-newton"` (default: the sparse Gauss–Newton
    /// Hessian, factorised once per force; ~20 s for N = 23867) or `"none"` (plain L-BFGS, for
    /// comparison; ~400 s for N = 23867).
    #[serde(default)]
    pub preconditioner: Preconditioning,
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
    /// Release after the last force and follow the recovery (optional).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub recovery: Option<recovery::RecoverySection>,
    #[serde(default)]
    pub output: StretchingOutput,
    /// Directory of the scenario file (to resolve relative paths); not part of the file.
    #[serde(skip)]
    pub base_dir: PathBuf,
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
    crate::cell::section::validate_reference(&m.reference, "membrane.reference", c)?;
    c.range(
        "membrane.persistence_scale",
        m.persistence_scale,
        0.1,
        10.0,
        "a factor between 0.1 and 10 multiplying the Eq. 12 persistence length",
    )?;
    c.range(
        "membrane.max_extension_ratio",
        m.max_extension_ratio,
        MAX_EXTENSION_RANGE.0,
        MAX_EXTENSION_RANGE.1,
        MAX_EXTENSION_ALLOWED,
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

/// Validates a `kind = "stretching"` scenario.
pub fn validate(s: &StretchingScenario, file: &str) -> Result<(), ScenarioError> {
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
    if let Some(r) = &s.recovery {
        recovery::validate(r, &c)?;
    }
    Ok(())
}

/// The mesh file the scenario names, if any, must exist, be readable and have
/// `membrane.vertices` vertices (relative to `base_dir`, which [`crate::load`](crate::registry::load) sets).
pub(crate) fn check_files(st: &StretchingScenario, file: &str) -> Result<(), ScenarioError> {
    let Some(m) = &st.membrane.mesh_file else {
        return Ok(());
    };
    let full = st.base_dir.join(m);
    if !full.exists() {
        return Err(ScenarioError::Value {
            file: file.into(),
            key: "membrane.mesh_file".into(),
            value: format!("{:?}", m.display().to_string()),
            allowed: format!("an existing mesh file ({} does not exist)", full.display()),
        });
    }
    // the model's parameters come from membrane.vertices (coarse-graining from N, Eqs. 8,
    // 9, 12): a file with another vertex count would get another cell's parameters
    let mesh = hemodpd_membrane::meshio::read_mesh(&full).map_err(|e| ScenarioError::Value {
        file: file.into(),
        key: "membrane.mesh_file".into(),
        value: format!("{:?}", m.display().to_string()),
        allowed: format!(
            "a readable closed triangle mesh in µm (OFF, PLY or NAME.vertices.csv + NAME.triangles.csv): {e}"
        ),
    })?;
    let nv = mesh.vertices.len();
    if nv as i64 != st.membrane.vertices {
        return Err(ScenarioError::Value {
            file: file.into(),
            key: "membrane.mesh_file".into(),
            value: format!("{:?} (with {nv} vertices)", m.display().to_string()),
            allowed: format!(
                "a mesh with membrane.vertices = {} vertices: the model parameters are coarse-grained from N (Eqs. 8, 9, 12), so the file's {nv} vertices and membrane.vertices = {} must agree (set membrane.vertices = {nv})",
                st.membrane.vertices, st.membrane.vertices
            ),
        });
    }
    Ok(())
}

/// Mills, Qie, Dao, Lim, Suresh (2004), healthy RBC (korali digitisation, see the file's first line):
/// force pN, D_T, D_A, then error-bar ends D_T lo/hi, D_A lo/hi, µm.
pub const MILLS_2004_CSV: &str = include_str!("../../data/mills2004_stretching_korali.csv");

/// One row of the Mills et al. data.
#[derive(Clone, Copy, Debug)]
pub struct MillsPoint {
    pub force_pn: f64,
    pub dt_um: f64,
    pub da_um: f64,
    pub dt_lo: f64,
    pub dt_hi: f64,
    pub da_lo: f64,
    pub da_hi: f64,
}

/// The Mills et al. (2004) data.
pub fn mills_2004() -> Vec<MillsPoint> {
    MILLS_2004_CSV
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("force"))
        .filter_map(|l| {
            let v: Vec<f64> = l.split(',').filter_map(|x| x.trim().parse().ok()).collect();
            (v.len() == 7).then(|| MillsPoint {
                force_pn: v[0],
                dt_um: v[1],
                da_um: v[2],
                dt_lo: v[3],
                dt_hi: v[4],
                da_lo: v[5],
                da_hi: v[6],
            })
        })
        .collect()
}

/// Linear interpolation of y(x) at `at` (x increasing); None outside the range.
pub fn interpolate(x: &[f64], y: &[f64], at: f64) -> Option<f64> {
    if x.is_empty() || at < x[0] - 1e-9 || at > x[x.len() - 1] + 1e-9 {
        return None;
    }
    let k = x.partition_point(|&v| v < at).clamp(1, x.len().max(2) - 1);
    if x.len() == 1 {
        return Some(y[0]);
    }
    let w = (at - x[k - 1]) / (x[k] - x[k - 1]);
    Some(y[k - 1] + w * (y[k] - y[k - 1]))
}

/// Comparison of a stretching curve with Mills et al.: RMS deviations (µm) over the experimental
/// forces inside the simulated range, and per force whether each diameter lies inside the error bars.
pub fn compare_with_mills(force: &[f64], da: &[f64], dt: &[f64]) -> serde_json::Value {
    let (mut sa, mut st, mut n) = (0.0, 0.0, 0usize);
    let mut rows = Vec::new();
    for m in mills_2004() {
        let (Some(a), Some(t)) = (interpolate(force, da, m.force_pn), interpolate(force, dt, m.force_pn)) else {
            continue;
        };
        sa += (a - m.da_um).powi(2);
        st += (t - m.dt_um).powi(2);
        n += 1;
        rows.push(json!({
            "force_pn": m.force_pn,
            "axial_diameter_um": a, "mills_axial_um": m.da_um, "axial_inside_error_bars": a >= m.da_lo && a <= m.da_hi,
            "transverse_diameter_um": t, "mills_transverse_um": m.dt_um, "transverse_inside_error_bars": t >= m.dt_lo && t <= m.dt_hi,
        }));
    }
    let nn = n.max(1) as f64;
    json!({
        "reference": "Mills et al. 2004 (korali digitisation), shared/reference/mills2004_stretching_korali.csv",
        "points_compared": n,
        "rms_axial_um": (sa / nn).sqrt(),
        "rms_transverse_um": (st / nn).sqrt(),
        "rms_both_um": ((sa + st) / (2.0 * nn)).sqrt(),
        "per_force": rows,
    })
}

/// Parameters of a stretching scenario (Eq. 12 p, scaled, or explicit).
pub fn params_of(s: &StretchingScenario) -> Result<ModelParams, RunError> {
    let m = &s.membrane;
    let n = m.vertices as usize;
    let params = match m.persistence_length_nm {
        Some(p_nm) => ModelParams::with_persistence_length(n, m.temperature_k, p_nm * 1e-9)?,
        None => ModelParams::with_persistence_scale(n, m.temperature_k, m.persistence_scale)?,
    };
    Ok(params.with_max_extension(m.max_extension_ratio)?)
}

/// The resting mesh (µm) of a scenario: the user's file or the cached relaxed mesh.
pub fn mesh_of(s: &StretchingScenario) -> Result<(Mesh, serde_json::Value), RunError> {
    match &s.membrane.mesh_file {
        Some(f) => {
            let path = s.base_dir.join(f);
            // centred and on its principal axes, as the generated mesh is (the pose is reported)
            let (mesh, pose) = mesh_cache::user_mesh(&path)?;
            Ok((mesh, json!({ "source": "file", "path": path, "pose_change": pose })))
        }
        None => {
            let (mesh, origin) = mesh_cache::relaxed_mesh(s.membrane.vertices as usize, s.seed)?;
            Ok((mesh, json!({ "source": "generated", "origin": origin })))
        }
    }
}

/// Builds the membrane model of a scenario on its resting mesh, in µm/pN units.
pub fn model_of(s: &StretchingScenario, params: &ModelParams, mesh: &Mesh) -> Result<MembraneModel, RunError> {
    let c = constants_um_pn(
        params,
        s.membrane.area_constraint_n_per_m,
        s.membrane.volume_constraint_n_per_m2,
    );
    let topo = mesh.topology()?;
    Ok(match s.membrane.reference {
        ReferenceState::Uniform => MembraneModel::uniform(&topo, &c, mesh.area(), mesh.volume())?,
        ReferenceState::StressFree => MembraneModel::stress_free(&topo, &mesh.vertices, &c)?,
        ReferenceState::Spheroid { reduced_volume } => {
            MembraneModel::spheroidal(&topo, &mesh.vertices, &c, reduced_volume)?
        }
    })
}

/// A stretching scenario ready to solve: parameters, resting mesh (µm) and model.
pub struct Prepared {
    pub params: ModelParams,
    pub mesh: Mesh,
    pub model: MembraneModel,
    /// Where the mesh came from, its quality and the parameters (for `summary.json`).
    pub info: serde_json::Value,
}

/// Builds the parameters, the resting mesh and the model of a scenario.
pub fn prepare(s: &StretchingScenario) -> Result<Prepared, RunError> {
    let params = params_of(s)?;
    let (mesh, mesh_info) = mesh_of(s)?;
    let model = model_of(s, &params, &mesh)?;
    let quality = mesh.quality()?;
    let mut info =
        json!({ "mesh": mesh_info, "mesh_quality": quality, "parameters": params, "reference": s.membrane.reference });
    if s.membrane.reference != ReferenceState::Uniform {
        info["tension_ratio_distribution"] = json!(model.tension_ratio_distribution());
    }
    Ok(Prepared {
        params,
        mesh,
        model,
        info,
    })
}

/// Runs the stretching protocol; `observer` sees each equilibrium as it is reached.
pub fn solve(
    s: &StretchingScenario,
    p: &Prepared,
    observer: impl FnMut(&StretchPoint),
) -> Result<Vec<StretchPoint>, RunError> {
    let opts = StretchOptions {
        forces: s.stretching.forces_pn.clone(),
        end_fraction: s.stretching.end_fraction,
        tolerance: s.stretching.tolerance_pn,
        max_iterations: s.stretching.max_iterations as usize,
        preconditioning: s.stretching.preconditioner,
    };
    Ok(stretch::stretch(&p.model, &p.mesh.vertices, &opts, observer)?)
}

/// One equilibrium as a frame of `shapes.h5`: step = time = the frame's index (the force's
/// position in the protocol), the force and diameters as frame scalars.
fn write_shape(w: &mut TrajectoryWriter, frame: u64, p: &StretchPoint) -> Result<(), hemodpd_io::IoError> {
    let scalars = [
        FrameScalar {
            name: "force",
            value: p.force,
            quantity: Quantity::Force,
        },
        FrameScalar {
            name: "axial_diameter",
            value: p.axial_diameter,
            quantity: Quantity::Length,
        },
        FrameScalar {
            name: "transverse_diameter",
            value: p.transverse_diameter,
            quantity: Quantity::Length,
        },
    ];
    w.append_membrane_frame(frame, frame as f64, &p.positions, None, &scalars)
}

/// Saves the equilibria reached so far: their results, the last two shapes (the next force
/// starts from the line through them) and the solve time. The checkpoint's step is the number of forces done.
fn save_checkpoint(
    s: &StretchingScenario,
    ctx: &RunContext,
    points: &[StretchPoint],
    seconds: f64,
) -> Result<(), RunError> {
    save_checkpoint_marked(s, ctx, points, seconds, false)
}

/// [`save_checkpoint`], marked finished when `finished` (after the recovery: a resume then says
/// the run is done instead of redoing the release).
fn save_checkpoint_marked(
    s: &StretchingScenario,
    ctx: &RunContext,
    points: &[StretchPoint],
    seconds: f64,
    finished: bool,
) -> Result<(), RunError> {
    let mut ck = Checkpoint::new(
        points.len() as u64,
        points.len() as f64,
        s.seed,
        toml::to_string(s).unwrap_or_default(),
    );
    ck.set_scalar("scenario_kind", ScalarValue::Str("stretching".into()));
    ck.set_scalar("base_dir", ScalarValue::Str(s.base_dir.to_string_lossy().into_owned()));
    ck.set_scalar("solve_seconds", ScalarValue::F64(seconds));
    if finished {
        ck.set_scalar("finished", ScalarValue::Str("yes".into()));
    }
    let json = serde_json::to_vec(points).map_err(|e| RunError::Output(format!("checkpoint: {e}")))?;
    ck.insert_u8("points_json", json);
    if let Some(last) = points.last() {
        ck.insert_vec3("positions", &last.positions);
    }
    if let [.., before, _] = points {
        ck.insert_vec3("previous_positions", &before.positions);
    }
    run_dir::save_checkpoint(&ck, ctx)
}

/// The equilibria a checkpoint holds (the last two with their shapes; a checkpoint written
/// before the shape of the one before the last was kept has only the last) and the solve time so far.
fn restore(ck: &Checkpoint, vertices: usize) -> Result<(Vec<StretchPoint>, f64), RunError> {
    let bad = |e: hemodpd_io::IoError| RunError::Output(format!("checkpoint: {e}"));
    let mut points: Vec<StretchPoint> = serde_json::from_slice(ck.u8s("points_json").map_err(bad)?)
        .map_err(|e| RunError::Output(format!("checkpoint points_json: {e}")))?;
    if points.len() as u64 != ck.step {
        return Err(RunError::Output(format!(
            "checkpoint: step {} but {} equilibria",
            ck.step,
            points.len()
        )));
    }
    if let Some(last) = points.last_mut() {
        last.positions = ck.vec3s("positions", Some(vertices)).map_err(bad)?;
    }
    let n = points.len();
    if n >= 2 && ck.array("previous_positions").is_ok() {
        points[n - 2].positions = ck.vec3s("previous_positions", Some(vertices)).map_err(bad)?;
    }
    Ok((points, ck.scalar_f64("solve_seconds").map_err(bad)?))
}

/// The scenario's run: solves, writes the shapes, returns the results object.
pub fn run(s: &StretchingScenario, ctx: &RunContext) -> Result<serde_json::Value, RunError> {
    run_from(s, ctx, None)
}

/// Runs the scenario, or continues it from a checkpoint. A checkpoint is written after every
/// force. On Ctrl-C (or at `ctx.stop_at_step` forces done) the force in progress is abandoned
/// and the run returns [`RunError::Interrupted`]; `hemodpd run --resume DIR` redoes that force
/// from the last equilibrium and ends with the same results, bit for bit.
pub fn run_from(
    s: &StretchingScenario,
    ctx: &RunContext,
    checkpoint: Option<&Checkpoint>,
) -> Result<serde_json::Value, RunError> {
    let t0 = std::time::Instant::now();
    let prepared = prepare(s)?;
    let nv = prepared.mesh.vertices.len();
    let (mut points, earlier_seconds) = match checkpoint {
        Some(ck) => restore(ck, nv)?,
        None => (Vec::new(), 0.0),
    };
    let done = points.len();
    let total = s.stretching.forces_pn.len();
    if done > total {
        return Err(RunError::Output(format!(
            "checkpoint with {done} forces done, but the protocol has {total}"
        )));
    }
    let shapes_path = ctx.out_dir.join("shapes.h5");
    let mut shapes = if !s.output.shapes {
        None
    } else {
        // a resumed run keeps the frames of the equilibria in the checkpoint, drops any later one
        let create = |path: &std::path::Path| -> Result<TrajectoryWriter, hemodpd_io::IoError> {
            let meta = RunMetadata::new(
                "stretching",
                toml::to_string(s).unwrap_or_default(),
                s.seed,
                stretching_units(),
            );
            let mut w = TrajectoryWriter::create(path, &meta)?;
            w.write_mesh(&prepared.mesh.triangles)?;
            w.set_membrane_reference(prepared.model.area0(), prepared.model.volume0())?;
            for (k, p) in points.iter().enumerate() {
                // resumed without the shapes file: only the last two shapes are known
                if !p.positions.is_empty() {
                    write_shape(&mut w, k as u64, p)?;
                }
            }
            Ok(w)
        };
        let last_frame = (done as u64).checked_sub(1);
        Some(run_dir::open_trajectory_at(
            &shapes_path,
            checkpoint.is_some(),
            last_frame,
            create,
        )?)
    };
    let opts = StretchOptions {
        forces: s.stretching.forces_pn[done..].to_vec(),
        end_fraction: s.stretching.end_fraction,
        tolerance: s.stretching.tolerance_pn,
        max_iterations: s.stretching.max_iterations as usize,
        preconditioning: s.stretching.preconditioner,
    };
    let completed = std::cell::Cell::new(done);
    let failed = std::cell::Cell::new(false);
    let stop = || {
        failed.get()
            || crate::context::INTERRUPTED.load(std::sync::atomic::Ordering::Relaxed)
            || ctx.stop_at_step == Some(completed.get() as u64)
    };
    let mut step_error = None;
    // the last two equilibria with a shape (forces from the protocol, as in one uninterrupted run)
    let before: Vec<stretch::Equilibrium> = points
        .iter()
        .enumerate()
        .skip(done.saturating_sub(2))
        .filter(|(_, p)| !p.positions.is_empty())
        .map(|(k, p)| stretch::Equilibrium {
            force: s.stretching.forces_pn[k],
            positions: &p.positions,
        })
        .collect();
    // the checkpoint keeps only the last two shapes: earlier equilibria are saved without positions
    let mut saved: Vec<StretchPoint> = points
        .iter()
        .enumerate()
        .map(|(k, p)| if k + 2 >= done { p.clone() } else { without_positions(p) })
        .collect();
    let new_points = stretch::stretch_from(&prepared.model, &prepared.mesh.vertices, &before, &opts, stop, |p| {
        if ctx.progress {
            eprintln!(
                "  F = {:7.2} pN  D_A = {:6.3} µm  D_T = {:6.3} µm  ({} iterations, residual {:.1e} pN)",
                p.force, p.axial_diameter, p.transverse_diameter, p.iterations, p.residual
            );
        }
        if step_error.is_some() {
            return;
        }
        let k = completed.get();
        if let Some(w) = shapes.as_mut() {
            if let Err(e) = write_shape(w, k as u64, p).and_then(|_| w.flush()) {
                step_error = Some(out_err(e));
                failed.set(true); // stop the solver: no force is solved past an output error
                return;
            }
        }
        saved.push(p.clone());
        if let Err(e) = save_checkpoint(s, ctx, &saved, earlier_seconds + t0.elapsed().as_secs_f64()) {
            step_error = Some(e);
            failed.set(true);
            return;
        }
        if let [.., before, _] = saved.as_mut_slice() {
            before.positions = Vec::new();
        }
        completed.set(k + 1);
    })?;
    if let Some(e) = step_error {
        return Err(e);
    }
    points.extend(new_points);
    if points.len() < total {
        if let Some(w) = shapes.as_mut() {
            w.flush().map_err(out_err)?;
        }
        if points.is_empty() {
            save_checkpoint(s, ctx, &points, earlier_seconds + t0.elapsed().as_secs_f64())?;
        }
        return Err(RunError::Interrupted {
            step: points.len() as u64,
            dir: ctx.out_dir.clone(),
        });
    }
    let shapes_file = match shapes {
        Some(w) => {
            let path = w.path().to_path_buf();
            w.close().map_err(out_err)?;
            Some(path)
        }
        None => None,
    };
    let recovery_json = match &s.recovery {
        None => serde_json::Value::Null,
        Some(r) => {
            let last = points.last().expect("a non-empty protocol");
            let mu0 = prepared.params.shear_modulus_n_per_m * 1e6;
            let stop = || {
                crate::context::INTERRUPTED.load(std::sync::atomic::Ordering::Relaxed)
                    || ctx.stop_at_step == Some(total as u64)
            };
            if ctx.progress {
                eprintln!(
                    "  released at {:.2} pN: following the recovery for {} s",
                    last.force, r.duration_s
                );
            }
            match recovery::run(r, &prepared.model, &prepared.mesh.vertices, &last.positions, mu0, stop)? {
                Some(rec) => {
                    recovery::write_csv(&ctx.out_dir.join("recovery.csv"), &rec)?;
                    let j = recovery::results(r, &rec, last.force);
                    let mut kept: Vec<StretchPoint> = points.iter().map(without_positions).collect();
                    if let Some(k) = kept.last_mut() {
                        k.positions = last.positions.clone();
                    }
                    save_checkpoint_marked(s, ctx, &kept, earlier_seconds + t0.elapsed().as_secs_f64(), true)?;
                    if ctx.progress {
                        eprintln!(
                            "  recovery: t_c = {} s (Hochmuth 1979: {:.3} ± {:.3} s), {} steps",
                            j["t_c_s"].as_f64().map(|v| format!("{v:.4}")).unwrap_or("-".into()),
                            j["hochmuth1979"]["mean_t_c_s"].as_f64().unwrap_or(f64::NAN),
                            j["hochmuth1979"]["sd_t_c_s"].as_f64().unwrap_or(f64::NAN),
                            j["integration"]["steps"]
                        );
                    }
                    j
                }
                // stopped: the checkpoint holds every force, a resume redoes the release
                None => {
                    return Err(RunError::Interrupted {
                        step: total as u64,
                        dir: ctx.out_dir.clone(),
                    })
                }
            }
        }
    };
    let force: Vec<f64> = points.iter().map(|p| p.force).collect();
    let da: Vec<f64> = points.iter().map(|p| p.axial_diameter).collect();
    let dt: Vec<f64> = points.iter().map(|p| p.transverse_diameter).collect();
    Ok(json!({
        "force_pn": force,
        "axial_diameter_um": da,
        "transverse_diameter_um": dt,
        "iterations": points.iter().map(|p| p.iterations).collect::<Vec<_>>(),
        "residual_force_pn": points.iter().map(|p| p.residual).collect::<Vec<_>>(),
        "area_deviation": points.iter().map(|p| p.area_deviation).collect::<Vec<_>>(),
        "volume_deviation": points.iter().map(|p| p.volume_deviation).collect::<Vec<_>>(),
        "mills2004": compare_with_mills(&force, &da, &dt),
        "convergence": format!("static equilibrium by L-BFGS ({} preconditioner): largest net vertex force < {} pN", match s.stretching.preconditioner {
            Preconditioning::GaussNewton => "Gauss-Newton",
            Preconditioning::None => "no",
        }, s.stretching.tolerance_pn),
        "preconditioned": points.iter().map(|p| p.preconditioned).collect::<Vec<_>>(),
        "model": prepared.info,
        "shapes_file": shapes_file,
        "resumed_from_step": checkpoint.map(|c| c.step),
        "checkpoint_file": ctx.out_dir.join(crate::run_dir::CHECKPOINT_FILE),
        "solve_seconds": earlier_seconds + t0.elapsed().as_secs_f64(),
    }))
    .map(|mut out: serde_json::Value| {
        if !recovery_json.is_null() {
            out["recovery"] = recovery_json;
        }
        out
    })
}

fn without_positions(p: &StretchPoint) -> StretchPoint {
    StretchPoint {
        positions: Vec::new(),
        ..p.clone()
    }
}

/// The stretching run's units: lengths in µm, energies in pN·µm (so forces in pN); the
/// trajectory converts to SI. Frames are static equilibria: their time is the frame index.
pub fn stretching_units() -> UnitSystem {
    UnitSystem {
        length_m: 1e-6,
        time_s: 1.0,
        energy_j: 1e-18,
        label: "um, pN*um (forces in pN); static frames: time = frame index, force in /membrane/scalars/force".into(),
    }
}

impl crate::kind::Kind for StretchingScenario {
    const NAME: &'static str = "stretching";
    const SWEEP_COLUMNS: &'static [crate::kind::SweepColumn] = &[
        ("RMS D_A (um)", "/mills2004/rms_axial_um", false),
        ("RMS D_T (um)", "/mills2004/rms_transverse_um", false),
    ];
    fn validate(&self, file: &str) -> Result<(), ScenarioError> {
        validate(self, file)
    }
    fn seed(&self) -> u64 {
        self.seed
    }
    fn set_base_dir(&mut self, dir: PathBuf) {
        self.base_dir = dir;
    }
    fn check_files(&self, file: &str) -> Result<(), ScenarioError> {
        check_files(self, file)
    }
    /// Forces done (and the release, one more, when there is a `[recovery]`).
    fn schedule_end(&self) -> (u64, &'static str) {
        match self.recovery {
            Some(_) => (self.stretching.forces_pn.len() as u64 + 1, "forces and the release"),
            None => (self.stretching.forces_pn.len() as u64, "forces"),
        }
    }
    fn run_from(&self, ctx: &RunContext, checkpoint: Option<&Checkpoint>) -> Result<serde_json::Value, RunError> {
        run_from(self, ctx, checkpoint)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mills_data_and_interpolation() {
        let m = mills_2004();
        assert_eq!(m.len(), 13);
        assert_eq!(m[12].force_pn, 192.688);
        assert_eq!(m[12].da_um, 15.261);
        let x = [0.0, 10.0, 20.0];
        let y = [1.0, 2.0, 4.0];
        assert_eq!(interpolate(&x, &y, 15.0), Some(3.0));
        assert_eq!(interpolate(&x, &y, 0.0), Some(1.0));
        assert_eq!(interpolate(&x, &y, 20.0), Some(4.0));
        assert_eq!(interpolate(&x, &y, 21.0), None);
    }

    #[test]
    fn rms_against_mills_is_zero_for_mills_itself() {
        let m = mills_2004();
        let f: Vec<f64> = m.iter().map(|p| p.force_pn).collect();
        let da: Vec<f64> = m.iter().map(|p| p.da_um).collect();
        let dt: Vec<f64> = m.iter().map(|p| p.dt_um).collect();
        let c = compare_with_mills(&f, &da, &dt);
        assert_eq!(c["points_compared"], 13);
        assert!(c["rms_both_um"].as_f64().unwrap() < 1e-12);
        // shifting D_A by 0.5 µm gives an axial RMS of exactly 0.5
        let da2: Vec<f64> = da.iter().map(|v| v + 0.5).collect();
        let c = compare_with_mills(&f, &da2, &dt);
        assert!((c["rms_axial_um"].as_f64().unwrap() - 0.5).abs() < 1e-12);
    }
}
