//! Wall-bounded validation flows, in model units (docs/walls.md):
//! `kind = "poiseuille-tube"` (body-force-driven flow in a tube, against the parabola) and
//! `kind = "couette"` (plates moving at ±U, against the line; viscosity from the wall stress).
//!
//! Both cut the walls out of an equilibrated fluid, then run one stepped schedule:
//!
//! | steps | phase |
//! |---|---|
//! | `[0, A)` | adaptation of the near-wall force with the flow on (A = adapt_iterations × update_every, 0 when not adaptive) |
//! | `[A, A + F)` | flow development, not sampled (F = `run.flow_steps`) |
//! | `[A + F, A + F + S)` | sampling (S = `run.steps`), split into [`BLOCKS`] blocks for standard errors |
//!
//! then fit, and time the same number of fluid particles in a periodic box for the wall overhead.
//! The force profile is written to the run directory (and, after adaptation, to the cache) when
//! adaptation ends. Frames go to `trajectory.h5` every
//! `output.trajectory_every_steps` steps; `checkpoint.h5` (particles, the wall state and the
//! sums sampled so far) is written every `output.checkpoint_every_steps` steps, at the end and on
//! Ctrl-C, and `hemodpd run --resume DIR` continues bit-identically. The stepping loop is
//! [`crate::driver`]'s; the phase changes happen at the step boundaries
//! ([`Stepper::at_boundary`]), the sampling and flow control after each step.

use crate::driver::{self, Stepper};
use crate::file::{
    f_dt, f_lambda, one_u64, validate_fluid_params, validate_output, validate_stepping, yes, Check, FluidSection,
    ScenarioError,
};
use crate::fluid::{out_err, particles_from_checkpoint, particles_into_checkpoint, CHECKPOINT_FILE, TRAJECTORY_FILE};
use crate::{RunContext, RunError};
use glam::DVec3;
use hemodpd_engine::walls::{
    self, ControlLaw, Reflection, WallConfig, WallForceProfile, WallSetup, WallShape, Walls, WallsState,
};
use hemodpd_engine::{init, ForceField, PairParams, PeriodicBox, SimConfig, SimState, Simulation};
use hemodpd_io::checkpoint::{Checkpoint, ScalarValue};
use hemodpd_io::{RunMetadata, TrajectoryWriter};
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;

// ---- the scenario files: `[fluid]` (shared, [`FluidSection`]), `[walls]`, `[run]`, `[output]`, `[tube]` or `[plates]` ----

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

fn hundred() -> u64 {
    100
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

/// Validates a `kind = "poiseuille-tube"` scenario.
pub fn validate_tube(s: &TubeScenario, file: &str) -> Result<(), ScenarioError> {
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

/// Validates a `kind = "couette"` scenario.
pub fn validate_couette(s: &CouetteScenario, file: &str) -> Result<(), ScenarioError> {
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

/// Blocks the sampled steps are split into; the standard errors of the fitted viscosity and of
/// the wall stress come from the scatter between blocks.
pub const BLOCKS: usize = 10;

/// Departure, in standard errors, of the next two edges' mean from the plateau so far that
/// ends the plateau: 3σ, a 0.27 % chance per step in the bulk.
const DEPARTURE_Z: f64 = 3.0;

/// Relative standard error of the plateau above which the summary warns that the wall layer
/// may be in it.
const WEAK_SIGNAL: f64 = 0.02;

/// Largest relative standard error of an edge's η for it to enter the plateau. η is a ratio
/// whose bias is about the squared relative error of its denominator, 1 % at this bound; near a
/// tube's axis edges of 15–20 % were seen to read 40–50 % low and seed a false plateau.
const MAX_RELATIVE_ERROR: f64 = 0.1;

/// Fewest bin edges the plateau of η(r) must hold; with fewer the viscosity is not reported.
const MIN_PLATEAU_EDGES: usize = 3;

fn engine_err(e: hemodpd_engine::EngineError) -> RunError {
    RunError::Engine(e.to_string())
}

fn pair(f: &FluidSection) -> PairParams {
    PairParams {
        a: f.a,
        gamma: f.gamma,
        kbt: f.kbt,
        rc: f.cutoff,
        s: f.weight_exponent,
    }
}

/// Weighted least squares y = c0 + c1 x (weights w): returns (c0, c1). Points of weight 0
/// (empty bins, whose y is NaN) are left out.
pub fn fit_line(x: &[f64], y: &[f64], w: &[f64]) -> (f64, f64) {
    let (mut s, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for i in (0..x.len()).filter(|&i| w[i] > 0.0) {
        s += w[i];
        sx += w[i] * x[i];
        sy += w[i] * y[i];
        sxx += w[i] * x[i] * x[i];
        sxy += w[i] * x[i] * y[i];
    }
    let c1 = (s * sxy - sx * sy) / (s * sxx - sx * sx);
    ((sy - c1 * sx) / s, c1)
}

/// Per-block sums of a profile across the channel: particle counts, the flow-direction
/// velocity and the squared velocity components, per bin.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ProfileSums {
    /// `count[block][bin]`.
    pub count: Vec<Vec<f64>>,
    /// `velocity[block][bin]`: Σ of the velocity component along the flow.
    pub velocity: Vec<Vec<f64>>,
    /// `square[block][bin]`: Σ of the squared velocity components (wall-normal, the other
    /// tangential direction, along the flow), for the temperature profile.
    #[serde(default)]
    pub square: Vec<Vec<[f64; 3]>>,
    /// Samples per block.
    pub samples: Vec<u64>,
}

/// Sums of a [`ProfileSums`] over a set of blocks.
struct BinSums {
    count: Vec<f64>,
    velocity: Vec<f64>,
    square: Vec<[f64; 3]>,
    samples: u64,
}

impl BinSums {
    /// Mean flow velocity per bin; NaN for a bin no particle visited.
    fn mean_velocity(&self) -> Vec<f64> {
        self.velocity
            .iter()
            .zip(&self.count)
            .map(|(v, &c)| if c > 0.0 { v / c } else { f64::NAN })
            .collect()
    }

    /// Peculiar kBT per bin and component (normal, other tangential, flow), mass `m`: the flow
    /// component about the bin's mean velocity. NaN for an empty bin.
    fn temperature(&self, m: f64) -> Vec<[f64; 3]> {
        (0..self.count.len())
            .map(|k| {
                let c = self.count[k];
                if c <= 0.0 {
                    return [f64::NAN; 3];
                }
                let u = self.velocity[k] / c;
                let q = self.square[k];
                [m * q[0] / c, m * q[1] / c, m * (q[2] / c - u * u)]
            })
            .collect()
    }
}

impl ProfileSums {
    fn new(bins: usize) -> Self {
        Self {
            count: vec![vec![0.0; bins]; BLOCKS],
            velocity: vec![vec![0.0; bins]; BLOCKS],
            square: vec![vec![[0.0; 3]; bins]; BLOCKS],
            samples: vec![0; BLOCKS],
        }
    }

    /// The sums over the blocks for which `take(block)` holds.
    fn sum(&self, take: impl Fn(usize) -> bool) -> BinSums {
        let nb = self.count[0].len();
        let mut s = BinSums {
            count: vec![0.0; nb],
            velocity: vec![0.0; nb],
            square: vec![[0.0; 3]; nb],
            samples: 0,
        };
        for b in (0..BLOCKS).filter(|&b| take(b)) {
            for k in 0..nb {
                s.count[k] += self.count[b][k];
                s.velocity[k] += self.velocity[b][k];
                for c in 0..3 {
                    s.square[k][c] += self.square[b][k][c];
                }
            }
            s.samples += self.samples[b];
        }
        s
    }

    /// (counts, mean velocity) over all blocks; the velocity of an empty bin is NaN.
    fn mean(&self) -> (Vec<f64>, Vec<f64>) {
        let s = self.sum(|_| true);
        let v = s.mean_velocity();
        (s.count, v)
    }

    fn total_samples(&self) -> u64 {
        self.samples.iter().sum()
    }
}

/// What a walled run accumulates while sampling; saved in checkpoints.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Measurement {
    /// Velocity and density profile across the channel.
    pub profile: ProfileSums,
    /// The wall shear stress summed over the sampled steps of each time block, and the steps
    /// summed (`[sum, steps]` per block; bounded size, whatever the run length): Couette, the
    /// mean of the two plates' stresses on the fluid; tube, the axial force of the fluid on the
    /// wall per wall area.
    pub stress: Vec<[f64; 2]>,
    /// The reflection impulse along the flow of each surface at the last step.
    pub impulse_prev: [f64; 2],
    /// Wall-clock seconds of the stepping so far (over all sessions of a resumed run).
    pub stepping_seconds: f64,
    /// The tube's flow controller, when the scenario asks for a mean velocity.
    pub flow_control: Option<FlowControl>,
}

/// Bessel J0's first zero: the slowest viscous mode of a tube decays as exp(−η j0² t/(n R²)).
const J0_FIRST_ZERO: f64 = 2.404_825_557_695_773;

/// The tube's flow controller: a proportional–integral law on the body force f that holds a
/// target mean axial velocity U of the fluid. With ū the fluid's mean axial velocity averaged
/// over the last M steps, every M steps:
///
/// e = U − ū,  I ← I + e·MΔt/τ_v,  f = 8η/(nR²) · (e + I),
///
/// where 8η/(nR²) is the force per unit mean velocity of Poiseuille flow and τ_v = nR²/(η j0²)
/// the tube's slowest viscous time. I starts at 0, so the first force is the Poiseuille estimate
/// 8ηU/(nR²). For a flow that responds like one lag of time τ_v the loop is critically damped
/// (a double pole at −1/τ_v): no overshoot, settled to 1% in about 7τ_v. The law acts on window
/// means, one window late, so the scenario keeps MΔt ≤ τ_v/2 (validated). η is the scenario's
/// reference viscosity, or 1 when none is given; a run whose mean velocity runs away stops with
/// an error.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FlowControl {
    /// Target mean velocity U.
    pub target: f64,
    /// Current body force f.
    pub force: f64,
    /// Integral term I (velocity units).
    pub integral: f64,
    /// Σ ū and steps of the current window.
    pub window_sum: f64,
    pub window_steps: u64,
    /// (step, ū over the window, f after the update) per update.
    pub history: Vec<[f64; 3]>,
    /// Σ f and steps over the sampling phase (the mean force the profile saw).
    pub sampling_force_sum: f64,
    pub sampling_steps: u64,
}

/// The geometry a walled run measures in.
#[derive(Clone, Copy, Debug)]
enum Channel {
    /// Tube of radius `radius` along z, length `length`, body force along z; the
    /// independently measured viscosity to compare with, if any.
    Tube {
        radius: f64,
        length: f64,
        /// `tube.body_force` as written (set unless `mean_velocity` is: validated).
        body_force: Option<f64>,
        reference_viscosity: Option<f64>,
        /// Target mean velocity and controller period, when controlled.
        mean_velocity: Option<(f64, u64)>,
    },
    /// Plates at z = `lower` and `lower + gap`, moving at ∓`speed` along x; `area` = Lx·Ly.
    Couette {
        lower: f64,
        gap: f64,
        speed: f64,
        area: f64,
    },
}

/// Everything one walled run needs, from either scenario kind.
struct Plan<'a> {
    kind: &'static str,
    toml: String,
    seed: u64,
    fluid: &'a FluidSection,
    walls: &'a WallsSection,
    run: &'a WallRunSection,
    output: &'a WallOutput,
    base_dir: &'a Path,
    shape: WallShape,
    box_lengths: DVec3,
    channel: Channel,
    /// µm per rc, for reporting lengths in µm too.
    length_scale_um_per_rc: Option<f64>,
}

impl Plan<'_> {
    /// Steps of adaptation A.
    fn adapt_steps(&self) -> u64 {
        if self.walls.adaptive {
            self.walls.adapt_iterations * self.walls.update_every
        } else {
            0
        }
    }
    /// First sampled step A + F.
    fn sampling_start(&self) -> u64 {
        self.adapt_steps() + self.run.flow_steps
    }
    /// All steps A + F + S.
    fn total(&self) -> u64 {
        self.sampling_start() + self.run.steps
    }
    fn body_force(&self) -> DVec3 {
        match self.channel {
            Channel::Tube {
                body_force,
                radius,
                reference_viscosity,
                mean_velocity,
                ..
            } => match mean_velocity {
                // the flow controller's first force (see FlowControl)
                Some((u, _)) => DVec3::new(
                    0.0,
                    0.0,
                    8.0 * reference_viscosity.unwrap_or(1.0) * u / (self.fluid.density * radius * radius),
                ),
                None => DVec3::new(0.0, 0.0, body_force.unwrap_or(0.0)),
            },
            Channel::Couette { .. } => DVec3::ZERO,
        }
    }
    fn config(&self) -> SimConfig {
        let mut config = SimConfig::new(self.box_lengths, self.run.timestep, self.seed);
        config.lambda = self.run.lambda;
        config
    }
    fn wall_config(&self) -> WallConfig {
        let w = self.walls;
        WallConfig {
            reflection: w.reflection,
            bins: w.bins,
            rc: self.fluid.cutoff,
            law: w.law,
            gain: w.gain,
            update_every: w.update_every,
            adapt: false,
            target_density: None,
        }
    }
    /// The axis the flow runs along (tube: z; Couette: x).
    fn flow_axis(&self) -> usize {
        match self.channel {
            Channel::Tube { .. } => 2,
            Channel::Couette { .. } => 0,
        }
    }
    fn flow_direction(&self) -> DVec3 {
        let mut e = DVec3::ZERO;
        e[self.flow_axis()] = 1.0;
        e
    }
    fn frame_due(&self, step: u64) -> bool {
        let every = self.output.trajectory_every_steps;
        every > 0 && step % every == 0
    }
    /// The profile bin of a fluid particle at `x`, if inside the profiled region.
    #[inline]
    fn bin(&self, x: DVec3) -> Option<usize> {
        let nb = self.run.profile_bins;
        let k = match self.channel {
            Channel::Tube { radius, .. } => (self.shape.signed_distance(x) + radius) / radius * nb as f64,
            Channel::Couette { lower, gap, .. } => (x.z - lower) / gap * nb as f64,
        };
        (k >= 0.0).then(|| (k as usize).min(nb - 1))
    }
}

/// The cache file of the converged wall-force profile for this plan's fluid, geometry, bins,
/// control law and reflection (in the mesh cache's directory; [`crate::mesh_cache::cache_dir`]).
fn wall_force_cache_path(plan: &Plan) -> std::path::PathBuf {
    let geometry = match plan.shape {
        WallShape::Cylinder { radius, .. } => format!("cylinder radius {radius:?}"),
        WallShape::Plates { lower, upper, .. } => format!("plates gap {:?}", upper - lower),
    };
    let w = plan.walls;
    let key = format!(
        "{:?} density {:?} | {geometry} | bins {} law {:?} reflection {:?}",
        pair(plan.fluid),
        plan.fluid.density,
        w.bins,
        w.law,
        w.reflection
    );
    // FNV-1a: a stable name for the key (std's hasher may change between releases)
    let hash = key.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    });
    crate::mesh_cache::cache_dir().join(format!("wall-force-{hash:016x}.csv"))
}

/// Reads a force profile; `None` when the file does not exist or is for another fluid or bin
/// layout (said in `source`).
fn read_profile(plan: &Plan, path: &Path, source: &mut String) -> Result<Option<WallForceProfile>, RunError> {
    if !path.exists() {
        return Ok(None);
    }
    let text = std::fs::read_to_string(path).map_err(|source| RunError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let prof = WallForceProfile::from_csv(&text).map_err(|e| RunError::Output(format!("{}: {e}", path.display())))?;
    if prof.matches(&pair(plan.fluid), plan.fluid.density, plan.walls.bins) {
        *source = format!("file {}", path.display());
        Ok(Some(prof))
    } else {
        *source = format!("{} is for another fluid or bin layout", path.display());
        Ok(None)
    }
}

/// Builds the walled simulation at step 0, with the initial force profile from
/// `walls.force_file`, the cache or `walls.initial`. Returns the simulation and where the
/// profile came from.
fn build(plan: &Plan) -> Result<(Simulation<Walls>, String), RunError> {
    let (f, w) = (plan.fluid, plan.walls);
    let config = plan.config();
    let p = pair(f);
    let setup = WallSetup {
        shape: plan.shape,
        pair: p,
        density: f.density,
        thickness: f.cutoff,
        equilibration_steps: plan.run.equilibration_steps,
    };
    let (field, particles) = walls::build(&config, &setup, plan.seed).map_err(engine_err)?;
    let mut ext = Walls::new(plan.shape, plan.wall_config()).map_err(engine_err)?;
    let mut note = String::new();
    let mut loaded = None;
    if let Some(file) = &w.force_file {
        loaded = read_profile(plan, &plan.base_dir.join(file), &mut note)?;
    }
    if loaded.is_none() && w.initial == InitialWallForce::Cached {
        loaded = read_profile(plan, &wall_force_cache_path(plan), &mut note)?;
    }
    let source = match loaded {
        Some(prof) => {
            ext = ext.with_profile(&prof).map_err(engine_err)?;
            note
        }
        None => {
            if w.initial == InitialWallForce::HalfSpace {
                ext = ext
                    .with_profile(&WallForceProfile::half_space(p, f.density, w.bins))
                    .map_err(engine_err)?;
            }
            let start = if w.initial == InitialWallForce::HalfSpace {
                "HalfSpace"
            } else {
                "Zero"
            };
            if note.is_empty() {
                start.to_string()
            } else {
                format!("{start} ({note})")
            }
        }
    };
    let mut sim = Simulation::with_extension(config, field, particles, ext).map_err(engine_err)?;
    sim.set_body_force(walls::FLUID_TYPE as usize, plan.body_force())
        .map_err(engine_err)?;
    Ok((sim, source))
}

pub(crate) fn json_into_checkpoint<T: Serialize>(ck: &mut Checkpoint, name: &str, value: &T) -> Result<(), RunError> {
    let bytes = serde_json::to_vec(value).map_err(|e| RunError::Output(format!("checkpoint {name}: {e}")))?;
    ck.insert_u8(name, bytes);
    Ok(())
}

pub(crate) fn json_from_checkpoint<T: for<'de> Deserialize<'de>>(ck: &Checkpoint, name: &str) -> Result<T, RunError> {
    let bytes = ck.u8s(name).map_err(|e| RunError::Output(format!("checkpoint: {e}")))?;
    serde_json::from_slice(bytes).map_err(|e| RunError::Output(format!("checkpoint {name}: {e}")))
}

fn save_checkpoint(
    plan: &Plan,
    ctx: &RunContext,
    sim: &Simulation<Walls>,
    m: &Measurement,
    source: &str,
) -> Result<(), RunError> {
    let mut ck = Checkpoint::new(sim.step_count(), sim.time(), plan.seed, plan.toml.clone());
    ck.set_scalar("scenario_kind", ScalarValue::Str(plan.kind.into()));
    ck.set_scalar(
        "base_dir",
        ScalarValue::Str(plan.base_dir.to_string_lossy().into_owned()),
    );
    ck.set_scalar("wall_force_source", ScalarValue::Str(source.into()));
    particles_into_checkpoint(&mut ck, sim.particles());
    json_into_checkpoint(&mut ck, "walls_state_json", &sim.extension().state())?;
    json_into_checkpoint(&mut ck, "measurement_json", m)?;
    ck.save_atomic(ctx.out_dir.join(CHECKPOINT_FILE)).map_err(out_err)
}

fn restore(plan: &Plan, ck: &Checkpoint) -> Result<(Simulation<Walls>, Measurement, String), RunError> {
    let kind = ck
        .scalar_str("scenario_kind")
        .map_err(|e| RunError::Output(format!("checkpoint: {e}")))?;
    if kind != plan.kind {
        return Err(RunError::Output(format!(
            "checkpoint of a {kind} run, not {}",
            plan.kind
        )));
    }
    let particles = particles_from_checkpoint(ck)?;
    let field = walls::wall_field(pair(plan.fluid)).map_err(engine_err)?;
    let state = SimState {
        config: plan.config(),
        field,
        particles,
        step: ck.step,
    };
    let ws: WallsState = json_from_checkpoint(ck, "walls_state_json")?;
    let domain = PeriodicBox::new(plan.box_lengths).map_err(engine_err)?;
    let ext = Walls::new(plan.shape, plan.wall_config())
        .and_then(|w| w.with_state(ws, &domain))
        .map_err(engine_err)?;
    let mut sim = Simulation::from_state(state, ext).map_err(engine_err)?;
    let m: Measurement = json_from_checkpoint(ck, "measurement_json")?;
    let force = m
        .flow_control
        .as_ref()
        .map_or(plan.body_force(), |c| DVec3::new(0.0, 0.0, c.force));
    sim.set_body_force(walls::FLUID_TYPE as usize, force)
        .map_err(engine_err)?;
    let nb = plan.run.profile_bins;
    let bins_ok = |v: &Vec<Vec<f64>>| v.len() == BLOCKS && v.iter().all(|c| c.len() == nb);
    let squares_ok =
        m.profile.square.len() == BLOCKS && m.profile.square.iter().all(|c| c.len() == nb) && m.stress.len() == BLOCKS;
    if !bins_ok(&m.profile.count) || !bins_ok(&m.profile.velocity) || m.profile.samples.len() != BLOCKS {
        return Err(RunError::Output(
            "checkpoint: the sampled profile does not match run.profile_bins".into(),
        ));
    }
    if !squares_ok {
        return Err(RunError::Output(
            "checkpoint: written by an earlier hemodpd without the temperature profile; start the run again".into(),
        ));
    }
    let source = ck
        .scalar_str("wall_force_source")
        .map_err(|e| RunError::Output(format!("checkpoint: {e}")))?
        .to_string();
    Ok((sim, m, source))
}

fn write_frame(plan: &Plan, w: &mut TrajectoryWriter, sim: &Simulation<Walls>) -> Result<(), RunError> {
    let p = sim.particles();
    let stride = plan.output.particle_stride as usize;
    let pos: Vec<DVec3> = p.pos.iter().step_by(stride).copied().collect();
    let vel: Vec<DVec3> = p.vel.iter().step_by(stride).copied().collect();
    let types: Vec<u16> = p.ptype.iter().step_by(stride).copied().collect();
    w.append_fluid_frame_u16(sim.step_count(), sim.time(), &pos, Some(&vel), Some(&types))
        .map_err(out_err)
}

/// Writes the force profile into the run directory (`wall_force.csv`) and, after adaptation,
/// into the cache for `walls.initial = "cached"` (atomically: a temporary file renamed, so
/// runs in parallel never read half a file). Nothing is written next to the scenario file.
fn write_force_files(plan: &Plan, sim: &Simulation<Walls>, ctx: &RunContext) -> Result<(), RunError> {
    let prof = sim.extension().profile(pair(plan.fluid), plan.fluid.density);
    let csv = prof.to_csv();
    let path = ctx.out_dir.join("wall_force.csv");
    std::fs::write(&path, &csv).map_err(|source| RunError::Io { path, source })?;
    if plan.adapt_steps() > 0 {
        // the cache is an optimisation: a read-only or missing cache directory is not an error
        let path = wall_force_cache_path(plan);
        if let Some(dir) = path.parent() {
            let tmp = dir.join(format!(
                ".wall-force-{}-{:?}.tmp",
                std::process::id(),
                std::thread::current().id()
            ));
            let stored = std::fs::create_dir_all(dir)
                .and_then(|_| std::fs::write(&tmp, &csv))
                .and_then(|_| std::fs::rename(&tmp, &path));
            if stored.is_err() {
                let _ = std::fs::remove_file(&tmp);
            }
        }
    }
    Ok(())
}

/// Samples after a step of the sampling phase (`i` steps of it done before this one): the
/// profile every `run.sample_every` steps, the wall shear stress every step.
fn sample(plan: &Plan, sim: &Simulation<Walls>, m: &mut Measurement, i: u64) {
    let r = plan.run;
    let block = ((i * BLOCKS as u64) / r.steps) as usize;
    let p = sim.particles();
    let profile = i % r.sample_every == 0;
    let dir = plan.flow_axis();
    // force of the fluid on each surface along the flow: pair forces on the wall particles
    let mut fw = [0.0f64; 2];
    for k in 0..p.len() {
        if p.ptype[k] == walls::FLUID_TYPE {
            if profile {
                if let Some(b) = plan.bin(p.pos[k]) {
                    let v = p.vel[k];
                    let (e_n, e_f) = (plan.shape.normal(p.pos[k]), plan.flow_direction());
                    let e_t = e_f.cross(e_n);
                    let (vn, vt) = (v.dot(e_n), v.dot(e_t));
                    m.profile.count[block][b] += 1.0;
                    m.profile.velocity[block][b] += v[dir];
                    let q = &mut m.profile.square[block][b];
                    q[0] += vn * vn;
                    q[1] += vt * vt;
                    q[2] += v[dir] * v[dir];
                }
            }
        } else {
            fw[plan.shape.side(p.pos[k])] += p.force[k][dir];
        }
    }
    if profile {
        m.profile.samples[block] += 1;
    }
    // plus the momentum the reflections gave each surface this step
    let imp = sim.extension().impulse();
    for k in 0..plan.shape.sides() {
        fw[k] += (imp[k][dir] - m.impulse_prev[k]) / r.timestep;
        m.impulse_prev[k] = imp[k][dir];
    }
    let stress = match plan.channel {
        // the stress on the fluid, averaged over the plates (the lower one drags it along −x)
        Channel::Couette { area, .. } => (fw[0] - fw[1]) / (2.0 * area),
        Channel::Tube { radius, length, .. } => fw[0] / (2.0 * std::f64::consts::PI * radius * length),
    };
    m.stress[block][0] += stress;
    m.stress[block][1] += 1.0;
}

/// The flow controller's part of a step: accumulates the fluid's mean axial velocity and, every
/// `every` steps, updates the body force (`step` steps done, the last one included).
fn control_flow(plan: &Plan, sim: &mut Simulation<Walls>, c: &mut FlowControl, step: u64) -> Result<(), RunError> {
    let Channel::Tube {
        radius,
        reference_viscosity,
        mean_velocity: Some((_, every)),
        ..
    } = plan.channel
    else {
        return Ok(());
    };
    let p = sim.particles();
    let (mut sum, mut n) = (0.0, 0usize);
    for k in 0..p.len() {
        if p.ptype[k] == walls::FLUID_TYPE {
            sum += p.vel[k].z;
            n += 1;
        }
    }
    c.window_sum += sum / n.max(1) as f64;
    c.window_steps += 1;
    if step % every == 0 {
        let mean = c.window_sum / c.window_steps as f64;
        let eta = reference_viscosity.unwrap_or(1.0);
        let n_r2 = plan.fluid.density * radius * radius;
        let tau_v = n_r2 / (eta * J0_FIRST_ZERO * J0_FIRST_ZERO);
        let e = c.target - mean;
        c.integral += e * every as f64 * plan.run.timestep / tau_v;
        c.force = 8.0 * eta / n_r2 * (e + c.integral);
        if !c.force.is_finite() || mean.abs() > 10.0 * c.target.abs() + 1.0 {
            return Err(RunError::Engine(format!(
                "flow controller diverged at step {step}: mean velocity {mean:.4} for a target of {}, body force {:.4e}; lower tube.flow_control_every or set tube.reference_viscosity closer to the fluid's viscosity",
                c.target, c.force
            )));
        }
        c.history.push([step as f64, mean, c.force]);
        c.window_sum = 0.0;
        c.window_steps = 0;
        sim.set_body_force(walls::FLUID_TYPE as usize, DVec3::new(0.0, 0.0, c.force))
            .map_err(engine_err)?;
    }
    Ok(())
}

/// A running wall scenario (the [`Stepper`] of [`driver::drive`]): the phases of the schedule
/// (adaptation, flow development, sampling), the sampling and the flow controller.
struct Run<'a> {
    plan: &'a Plan<'a>,
    /// Where the force profile is written when adaptation ends.
    ctx: &'a RunContext,
    sim: Simulation<Walls>,
    m: Measurement,
    /// Where the initial force profile came from (for the summary).
    source: String,
    traj: Option<TrajectoryWriter>,
    /// Stepping time since the start of this session or the last checkpoint.
    clock: Instant,
}

impl Stepper for Run<'_> {
    fn step_count(&self) -> u64 {
        self.sim.step_count()
    }
    fn max_steps(&self) -> u64 {
        self.plan.total()
    }
    fn time(&self) -> f64 {
        self.sim.time()
    }
    fn finished(&self) -> bool {
        self.sim.step_count() >= self.plan.total()
    }

    /// Phase changes at their boundaries; each is idempotent, so a run resumed at a phase
    /// boundary repeats it harmlessly.
    fn at_boundary(&mut self) -> Result<(), RunError> {
        let plan = self.plan;
        let step = self.sim.step_count();
        let adapt_end = plan.adapt_steps();
        if step == 0 && adapt_end > 0 {
            self.sim.extension_mut().set_adapt(true);
        }
        if step == adapt_end {
            if adapt_end > 0 {
                self.sim.extension_mut().set_adapt(false);
            }
            write_force_files(plan, &self.sim, self.ctx)?;
        }
        if step == plan.sampling_start() {
            self.sim.extension_mut().reset_measurements();
        }
        Ok(())
    }

    fn advance(&mut self) -> Result<(), RunError> {
        let plan = self.plan;
        let sample_start = plan.sampling_start();
        let step = self.sim.step_count();
        self.sim.step().map_err(engine_err)?;
        if step >= sample_start {
            sample(plan, &self.sim, &mut self.m, step - sample_start);
        }
        let step = step + 1;
        if let Some(c) = self.m.flow_control.as_mut() {
            if step > sample_start {
                // the force the step just done was driven by
                c.sampling_force_sum += self.sim.field().types()[walls::FLUID_TYPE as usize].body_force.z;
                c.sampling_steps += 1;
            }
            control_flow(plan, &mut self.sim, c, step)?;
        }
        Ok(())
    }

    fn frame_due(&self) -> bool {
        self.plan.frame_due(self.sim.step_count())
    }

    fn write_frame(&mut self) -> Result<(), RunError> {
        match self.traj.as_mut() {
            Some(w) => write_frame(self.plan, w, &self.sim),
            None => Ok(()),
        }
    }

    fn flush(&mut self) -> Result<(), RunError> {
        match self.traj.as_mut() {
            Some(w) => w.flush().map_err(out_err),
            None => Ok(()),
        }
    }

    fn save_checkpoint(&mut self, ctx: &RunContext) -> Result<(), RunError> {
        self.m.stepping_seconds += self.clock.elapsed().as_secs_f64();
        self.clock = Instant::now();
        save_checkpoint(self.plan, ctx, &self.sim, &self.m, &self.source)
    }
}

/// Runs the schedule from step 0 or from a checkpoint; returns the simulation after the last
/// step, the sampled sums and the force-profile source.
fn run_plan(
    plan: &Plan,
    ctx: &RunContext,
    checkpoint: Option<&Checkpoint>,
) -> Result<(Simulation<Walls>, Measurement, String), RunError> {
    let (sim, m, source) = match checkpoint {
        Some(ck) => restore(plan, ck)?,
        None => {
            let (sim, source) = build(plan)?;
            let flow_control = match plan.channel {
                Channel::Tube {
                    mean_velocity: Some((target, _)),
                    ..
                } => Some(FlowControl {
                    target,
                    force: plan.body_force().z,
                    integral: 0.0,
                    window_sum: 0.0,
                    window_steps: 0,
                    history: Vec::new(),
                    sampling_force_sum: 0.0,
                    sampling_steps: 0,
                }),
                _ => None,
            };
            let m = Measurement {
                profile: ProfileSums::new(plan.run.profile_bins),
                stress: vec![[0.0; 2]; BLOCKS],
                impulse_prev: [0.0; 2],
                stepping_seconds: 0.0,
                flow_control,
            };
            (sim, m, source)
        }
    };
    let total = plan.total();
    let start = sim.step_count();
    if start > total {
        return Err(RunError::Output(format!(
            "checkpoint at step {start} is past the end of the run ({total} steps)"
        )));
    }
    let traj_path = ctx.out_dir.join(TRAJECTORY_FILE);
    let every = plan.output.trajectory_every_steps;
    // frames are due at multiples of `every` (none when it is 0)
    let traj = match start.checked_div(every) {
        None => None,
        Some(scheduled) => Some(match checkpoint {
            // keep the frames up to the checkpoint; drop an off-schedule final frame of an interrupt
            Some(_) if traj_path.exists() => {
                TrajectoryWriter::open_append(&traj_path, scheduled * every).map_err(out_err)?
            }
            _ => {
                let mut meta = RunMetadata::new(plan.kind, plan.toml.clone(), plan.seed, crate::fluid::model_units());
                meta.extra.push((
                    "particle_types".into(),
                    hemodpd_io::MetaValue::Str("0 = fluid, 1 = frozen wall".into()),
                ));
                TrajectoryWriter::create(&traj_path, &meta).map_err(out_err)?
            }
        }),
    };
    let mut run = Run {
        plan,
        ctx,
        sim,
        m,
        source,
        traj,
        clock: Instant::now(),
    };
    driver::drive(&mut run, ctx, checkpoint.is_some(), plan.output.checkpoint_every_steps)?;
    if let Some(w) = run.traj.take() {
        w.close().map_err(out_err)?;
    }
    Ok((run.sim, run.m, run.source))
}

/// Seconds per (step × fluid particle) of the walled run and of a periodic box of the same
/// fluid with the same number of fluid particles.
fn overhead(plan: &Plan, sim: &mut Simulation<Walls>) -> Result<serde_json::Value, RunError> {
    let (f, r) = (plan.fluid, plan.run);
    let steps = 500u64;
    let nf = sim
        .particles()
        .ptype
        .iter()
        .filter(|&&t| t == walls::FLUID_TYPE)
        .count();
    sim.extension_mut().set_sampling(false);
    let t0 = Instant::now();
    sim.run(steps).map_err(engine_err)?;
    let tw = t0.elapsed().as_secs_f64() / (steps as f64 * nf as f64);
    sim.extension_mut().set_sampling(true);
    let l = (nf as f64 / f.density).cbrt().max(3.0 * f.cutoff);
    let mut config = SimConfig::new(DVec3::splat(l), r.timestep, plan.seed);
    config.lambda = r.lambda;
    let field = ForceField::single(pair(f));
    let spec = init::FluidSpec {
        density: f.density,
        kbt: f.kbt,
        ..init::FluidSpec::standard()
    };
    let p = init::fluid(&config, &field, &spec, plan.seed).map_err(engine_err)?;
    let n = p.len();
    let mut plain = Simulation::new(config, field, p).map_err(engine_err)?;
    plain.run(50).map_err(engine_err)?;
    let t0 = Instant::now();
    plain.run(steps).map_err(engine_err)?;
    let tp = t0.elapsed().as_secs_f64() / (steps as f64 * n as f64);
    Ok(json!({
        "seconds_per_fluid_particle_step_with_walls": tw,
        "seconds_per_particle_step_periodic": tp,
        "ratio": tw / tp,
        "fluid_particles": nf,
        "wall_particles": sim.particles().len() - nf,
        "periodic_particles": n,
        "steps_timed": steps,
        "threads": rayon::current_num_threads(),
    }))
}

fn write_csv(ctx: &RunContext, name: &str, header: &str, rows: &[Vec<f64>]) -> Result<(), RunError> {
    let mut s = String::from(header);
    s.push('\n');
    for r in rows {
        s += &r.iter().map(|x| format!("{x:e}")).collect::<Vec<_>>().join(",");
        s.push('\n');
    }
    let path = ctx.out_dir.join(name);
    std::fs::write(&path, s).map_err(|source| RunError::Io { path, source })
}

/// The adaptation table from the wall history.
fn adaptation(sim: &Simulation<Walls>) -> serde_json::Value {
    let table: Vec<_> = sim
        .extension()
        .history()
        .iter()
        .map(|h| json!({"iteration": h.iteration, "step": h.step, "max_density_deviation": h.max_deviation, "relative_density": h.relative_density, "forces": h.forces}))
        .collect();
    json!({ "iterations": table, "final_forces": sim.extension().forces(), "bin_centres": sim.extension().bin_centres() })
}

/// A parabola v = a − c r² fitted to the radial bins with centre r < `r_max`, weighted by
/// their counts; returns (a, c).
fn fit_parabola(r: &[f64], v: &[f64], count: &[f64], r_max: f64) -> (f64, f64) {
    let (mut x, mut y, mut w) = (Vec::new(), Vec::new(), Vec::new());
    for k in 0..r.len() {
        if r[k] < r_max {
            x.push(r[k] * r[k]);
            y.push(v[k]);
            w.push(count[k]);
        }
    }
    let (a, b) = fit_line(&x, &y, &w);
    (a, -b)
}

/// A local shear viscosity η at the bin edges across a channel, and its plateau.
///
/// η(x_e) = σ(x_e)/(dv/dx)(x_e) at the edge x_e between bins e − 1 and e, with the slope
/// (v_e − v_{e−1})/w from the measured bin means (exact for a parabola, because the bins hold
/// count-weighted means over their volume) and σ from an exact momentum balance (tube: the
/// body force inside the edge; Couette: the measured wall stress). The balance gives the
/// fluid's own shear stress only across edges at least rc from the wall: closer, fluid on the
/// inner side of the edge interacts with wall particles directly, so part of the force crosses
/// the edge through wall–fluid pairs. Those edges are reported but not part of the plateau. It
/// needs no model of the profile and no chosen window: η is flat in the bulk and departs from
/// it in the wall layers. The plateau grows from the centre of the channel towards each wall along `paths`
/// and stops on a path where the mean of its next two edges departs from the plateau's running
/// inverse-variance mean by more than [`DEPARTURE_Z`] jackknife standard errors. With too
/// little signal (a weak drive, a short run) no departure is significant and the plateau takes
/// in the wall layer: the summary reports its extent. Standard errors are jackknife estimates
/// over the time blocks.
struct ViscosityProfile {
    /// Edge positions x_e (e = 1 … bins − 1).
    r: Vec<f64>,
    /// η(x_e) from all blocks, and its jackknife standard error.
    eta: Vec<f64>,
    se: Vec<f64>,
    /// The edges (indices into `r`) of the plateau, in increasing order; empty when none.
    plateau_edges: Vec<usize>,
    /// Inverse-variance mean over the plateau, its jackknife standard error, χ²/dof.
    plateau: Option<(f64, f64, f64)>,
}

/// See [`ViscosityProfile`]. `eta_of(take)` computes η at every edge from the blocks for which
/// `take(block)` holds; each path lists edge indices from the centre towards a wall.
fn viscosity_profile(
    m: &Measurement,
    r: Vec<f64>,
    eta_of: impl Fn(&dyn Fn(usize) -> bool) -> Vec<f64>,
    paths: Vec<Vec<usize>>,
    fluid_stress: impl Fn(usize) -> bool,
) -> ViscosityProfile {
    let eta = eta_of(&|_| true);
    let used: Vec<usize> = (0..BLOCKS).filter(|&b| m.profile.samples[b] > 0).collect();
    let jack: Vec<Vec<f64>> = used.iter().map(|&out| eta_of(&|b| b != out)).collect();
    let jack_se =
        |values: &dyn Fn(&Vec<f64>) -> f64| -> f64 { jackknife_spread(&jack.iter().map(values).collect::<Vec<_>>()) };
    let se: Vec<f64> = (0..eta.len()).map(|k| jack_se(&|j: &Vec<f64>| j[k])).collect();
    // η = σ/(dv/dx) is a ratio; where dv/dx is poorly known (near the axis of a tube, dv/dx →
    // 0) it is biased by about the squared relative error of dv/dx and its jackknife error is
    // unreliable, so an edge known to worse than ±MAX_RELATIVE_ERROR is left out of the
    // plateau (it still appears in the profile)
    let ok = |k: usize| {
        eta[k].is_finite() && eta[k] > 0.0 && se[k].is_finite() && se[k] > 0.0 && se[k] < MAX_RELATIVE_ERROR * eta[k]
    };
    // the valid edges of each path; the first of each seeds the plateau
    let paths: Vec<Vec<usize>> = paths
        .into_iter()
        .map(|p| p.into_iter().filter(|&k| ok(k)).collect())
        .collect();
    let mut edges: Vec<usize> = paths.iter().filter_map(|p| p.first().copied()).collect();
    let mut next = vec![1usize; paths.len()];
    let mut open = vec![true; paths.len()];
    while open.iter().any(|&o| o) {
        for (p, path) in paths.iter().enumerate() {
            if !open[p] {
                continue;
            }
            let Some(&k) = path.get(next[p]).filter(|&&k| fluid_stress(k)) else {
                // the end of the path, or the first edge within rc of the wall
                open[p] = false;
                continue;
            };
            // the next two edges of the path (one at its end) against the plateau so far: the
            // difference of their mean from the plateau's inverse-variance mean, over its
            // jackknife standard error (neighbouring edges share a bin, so their errors are
            // anticorrelated and the pair is better determined than either edge). The second
            // may lie within rc of the wall: it tests, it is never added.
            let group: Vec<usize> = path[next[p]..path.len().min(next[p] + 2)].to_vec();
            let wsum: f64 = edges.iter().map(|&j| se[j].powi(-2)).sum();
            let weights: Vec<(usize, f64)> = edges.iter().map(|&j| (j, se[j].powi(-2) / wsum)).collect();
            let difference = |x: &Vec<f64>| {
                group.iter().map(|&j| x[j]).sum::<f64>() / group.len() as f64
                    - weights.iter().map(|&(j, w)| w * x[j]).sum::<f64>()
            };
            let z = difference(&eta) / jack_se(&difference);
            if z.abs() > DEPARTURE_Z {
                open[p] = false;
            } else {
                edges.push(k);
                next[p] += 1;
            }
        }
    }
    edges.sort_unstable();
    edges.dedup();
    let plateau = (edges.len() >= MIN_PLATEAU_EDGES).then(|| {
        let wsum: f64 = edges.iter().map(|&k| se[k].powi(-2)).sum();
        let weights: Vec<f64> = edges.iter().map(|&k| se[k].powi(-2) / wsum).collect();
        let mean: f64 = edges.iter().zip(&weights).map(|(&k, w)| w * eta[k]).sum();
        let chi2: f64 = edges.iter().map(|&k| ((eta[k] - mean) / se[k]).powi(2)).sum();
        let pse = jack_se(&|j: &Vec<f64>| edges.iter().zip(&weights).map(|(&k, w)| w * j[k]).sum());
        (mean, pse, chi2 / (edges.len() - 1) as f64)
    });
    ViscosityProfile {
        r,
        eta,
        se,
        plateau_edges: if plateau.is_some() { edges } else { Vec::new() },
        plateau,
    }
}

impl ViscosityProfile {
    /// The `viscosity` entry of a summary, with the extent of the plateau.
    fn summary(&self, value: &str) -> serde_json::Value {
        match self.plateau {
            Some((eta, se, chi2)) => {
                let (lo, hi) = (self.plateau_edges[0], self.plateau_edges[self.plateau_edges.len() - 1]);
                let mut out = json!({ "value": eta, "standard_error": se, "plateau_edges": self.plateau_edges.len(),
                        "plateau_from": self.r[lo], "plateau_to": self.r[hi], "chi2_per_dof": chi2,
                        "method": format!("η(x) = σ/(dv/dx) at each bin edge, dv/dx from adjacent bins, σ from {value}; the plateau runs over the edges at least rc from the walls and known to ±10 %, from the centre out to where the mean of the next two edges departs from the plateau so far by more than 3 standard errors; standard errors by jackknife over the time blocks") });
                if se > WEAK_SIGNAL * eta {
                    out["note"] = json!(format!("weak signal (±{:.1} %): the plateau test cannot tell the bulk from the wall layer, which reads 10–15 % low, so the value may be biased low; a stronger drive or more sampled steps resolve it (docs/walls.md)", 100.0 * se / eta));
                }
                out
            }
            None => {
                json!({ "value": null, "note": format!("η(x) has no plateau of {MIN_PLATEAU_EDGES} or more consistent bin edges (a longer run, a wider channel or more run.profile_bins)") })
            }
        }
    }

    /// Rows (x, η, standard error, in the plateau) for `viscosity_profile.csv`.
    fn rows(&self) -> Vec<Vec<f64>> {
        (0..self.r.len())
            .map(|k| {
                let inside = if self.plateau_edges.contains(&k) { 1.0 } else { 0.0 };
                vec![self.r[k], self.eta[k], self.se[k], inside]
            })
            .collect()
    }

    fn json(&self) -> serde_json::Value {
        json!({ "edge": self.r, "eta": self.eta, "standard_error": self.se })
    }
}

/// Jackknife standard error over the time blocks of a quantity computed from the blocks for
/// which `take(block)` holds.
fn jackknife_se(m: &Measurement, f: impl Fn(&dyn Fn(usize) -> bool) -> f64) -> f64 {
    let used: Vec<usize> = (0..BLOCKS).filter(|&b| m.profile.samples[b] > 0).collect();
    jackknife_spread(&used.iter().map(|&out| f(&|b| b != out)).collect::<Vec<_>>())
}

/// The jackknife standard error from the leave-one-out values `x`: √((n − 1)/n · Σ(x − x̄)²);
/// NaN with fewer than two.
fn jackknife_spread(x: &[f64]) -> f64 {
    if x.len() < 2 {
        return f64::NAN;
    }
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    ((n - 1.0) / n * x.iter().map(|v| (v - mean).powi(2)).sum::<f64>()).sqrt()
}

/// Mean of the per-step wall stress and its standard error over the [`BLOCKS`] time blocks of
/// the sampling phase. Not `observe::block_error` on the step series: the random force on the
/// wall particles makes the per-step stress a large white noise that the fluid gives back
/// within a few steps (the series is anticorrelated), so short blocks overstate the error
/// several times over; blocks of a tenth of the run do not.
fn stress_mean_se(blocks: &[[f64; 2]]) -> (f64, f64) {
    let means: Vec<f64> = blocks.iter().filter(|b| b[1] > 0.0).map(|b| b[0] / b[1]).collect();
    let mean = block_mean(blocks, &|_| true);
    if means.len() < 2 {
        return (mean, f64::NAN);
    }
    let n = means.len() as f64;
    let m = means.iter().sum::<f64>() / n;
    let var = means.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, (var / n).sqrt())
}

/// Mean wall stress over the blocks for which `take(block)` holds.
fn block_mean(blocks: &[[f64; 2]], take: &dyn Fn(usize) -> bool) -> f64 {
    let (sum, steps) = blocks
        .iter()
        .enumerate()
        .filter(|(b, _)| take(*b))
        .fold((0.0, 0.0), |(s, c), (_, x)| (s + x[0], c + x[1]));
    sum / steps.max(1.0)
}

/// The tube's η(r): σ_rz(r) = −g N(<r)/(2πrL) is the exact axial momentum balance of the fluid
/// inside r (σ_rz = −(g/r)∫₀ʳ n(r′)r′dr′ with the measured density). The plateau runs from the
/// axis out, dropping edges from the wall inwards.
fn tube_viscosity_profile(m: &Measurement, g: f64, radius: f64, length: f64, rc: f64) -> ViscosityProfile {
    let nb = m.profile.count[0].len();
    let w = radius / nb as f64;
    let eta_of = |take: &dyn Fn(usize) -> bool| -> Vec<f64> {
        let s = m.profile.sum(take);
        let v = s.mean_velocity();
        let mut inside = 0.0;
        (1..nb)
            .map(|e| {
                inside += s.count[e - 1] / s.samples.max(1) as f64;
                let re = e as f64 * w;
                let sigma = -g * inside / (2.0 * std::f64::consts::PI * re * length);
                sigma / ((v[e] - v[e - 1]) / w)
            })
            .collect()
    };
    // one path, from the axis out to the last edge at least rc from the wall: beyond it the
    // fluid inside r_e interacts with wall particles directly, and the balance no longer gives
    // the fluid's own stress (see `fluid_edges`)
    let r: Vec<f64> = (1..nb).map(|e| e as f64 * w).collect();
    let fluid_stress = |k: usize| radius - r[k] >= rc - 1e-9;
    viscosity_profile(m, r.clone(), eta_of, vec![(0..nb - 1).collect()], fluid_stress)
}

/// Tube results: the profile against the parabola, the viscosity profile η(r) from the momentum
/// balance and its plateau, the wall shear stress against n̄gR/2, slip, near-wall density, the
/// temperature profile.
fn tube_results(
    plan: &Plan,
    ctx: &RunContext,
    sim: &Simulation<Walls>,
    m: &Measurement,
) -> Result<serde_json::Value, RunError> {
    let Channel::Tube {
        radius,
        length,
        body_force,
        reference_viscosity,
        ..
    } = plan.channel
    else {
        unreachable!("tube results of a tube plan")
    };
    // with the flow controller on, the profile saw the mean force of the sampling phase
    let g = match &m.flow_control {
        Some(c) if c.sampling_steps > 0 => c.sampling_force_sum / c.sampling_steps as f64,
        _ => plan.body_force().z,
    };
    let nb = plan.run.profile_bins;
    let w = radius / nb as f64;
    let samples = m.profile.total_samples();
    let rc: Vec<f64> = (0..nb).map(|b| (b as f64 + 0.5) * w).collect();
    let (cnt, v) = m.profile.mean();
    let ring = |b: usize| std::f64::consts::PI * (((b + 1) as f64 * w).powi(2) - (b as f64 * w).powi(2)) * length;
    let rho: Vec<f64> = (0..nb).map(|b| cnt[b] / (samples.max(1) as f64 * ring(b))).collect();
    // whole profile: the parabola the slip is measured against
    let (a, curv) = fit_parabola(&rc, &v, &cnt, radius);
    let slip = (a - curv * radius * radius) / a;
    let fit: Vec<f64> = rc.iter().map(|x| a - curv * x * x).collect();
    // η(r) from the momentum balance
    let vp = tube_viscosity_profile(m, g, radius, length, plan.fluid.cutoff);
    // the analytic no-slip parabola for the independently measured viscosity, with the mean
    // density of the tube
    let n_mean = cnt.iter().sum::<f64>() / (samples.max(1) as f64 * std::f64::consts::PI * radius * radius * length);
    let reference: Vec<f64> = rc
        .iter()
        .map(|x| reference_viscosity.map_or(f64::NAN, |eta| n_mean * g * (radius * radius - x * x) / (4.0 * eta)))
        .collect();
    let reference_json = match reference_viscosity {
        Some(eta) => {
            let centre = n_mean * g * radius * radius / (4.0 * eta);
            let filled: Vec<usize> = (0..nb).filter(|&k| cnt[k] > 0.0).collect();
            let rms = (filled.iter().map(|&k| (v[k] - reference[k]).powi(2)).sum::<f64>() / filled.len().max(1) as f64)
                .sqrt();
            json!({ "viscosity": eta, "density": n_mean, "centre_velocity": centre, "centre_velocity_measured_over_reference": a / centre,
                    "rms_deviation_over_centre_velocity": rms / centre, "profile": reference,
                    "definition": "v = n g (R² − r²)/(4η): no slip at the geometric wall R, n the mean density in the tube" })
        }
        None => serde_json::Value::Null,
    };
    // temperature profile (peculiar: about each bin's mean velocity)
    let temp = m.profile.sum(|_| true).temperature(fluid_mass(sim));
    let rows: Vec<Vec<f64>> = (0..nb)
        .map(|k| {
            vec![
                rc[k],
                v[k],
                fit[k],
                reference[k],
                rho[k],
                temp[k][0],
                temp[k][1],
                temp[k][2],
            ]
        })
        .collect();
    write_csv(
        ctx,
        "velocity_profile.csv",
        "r,v_z,parabola,reference_parabola,density,kbt_radial,kbt_azimuthal,kbt_axial",
        &rows,
    )?;
    write_csv(
        ctx,
        "viscosity_profile.csv",
        "r,eta,standard_error,in_plateau",
        &vp.rows(),
    )?;
    // wall shear stress against the momentum balance n̄ g R / 2 (the wall carries the whole
    // body force in steady flow)
    let (tau, tau_se) = stress_mean_se(&m.stress);
    let tau_expected = n_mean * g * radius / 2.0;
    // the wall carries the whole body force only in steady flow: a stress short of it says
    // the flow was still developing (the slowest mode decays over τ_v = nR²/(η j0²))
    let tau_v =
        plan.fluid.density * radius * radius / (reference_viscosity.unwrap_or(1.0) * J0_FIRST_ZERO * J0_FIRST_ZERO);
    let steady_note = ((tau / tau_expected - 1.0).abs() > 0.01 && (tau - tau_expected).abs() > 3.0 * tau_se).then(|| {
        format!(
            "the wall stress is {:+.1} % off the body force it must carry: the flow was not steady while sampled; give it 5 viscous times τ_v ≈ {:.0} steps (adaptation + run.flow_steps)",
            100.0 * (tau / tau_expected - 1.0),
            5.0 * tau_v / plan.run.timestep
        )
    });
    let um = match plan.length_scale_um_per_rc {
        Some(l) => json!({ "diameter_um": 2.0 * radius * l, "length_um": length * l }),
        None => serde_json::Value::Null,
    };
    let viscosity = vp.summary("the axial momentum balance σ_rz(r) = −g N(<r)/(2πrL) with the measured density; the value is the inverse-variance mean of η over the plateau");
    let t_mean = mean_temperature(&cnt, &temp);
    Ok(json!({
        "geometry": { "radius": radius, "length": length, "si": um },
        "profile": { "r": rc, "v_z": v, "parabola": fit, "density": rho, "samples": samples,
                     "kbt": { "radial": temp.iter().map(|t| t[0]).collect::<Vec<_>>(), "azimuthal": temp.iter().map(|t| t[1]).collect::<Vec<_>>(), "axial": temp.iter().map(|t| t[2]).collect::<Vec<_>>() } },
        "parabola": { "centre_velocity": a, "curvature": curv, "slip_velocity": a - curv * radius * radius, "slip_fraction": slip, "viscosity_whole_profile": plan.fluid.density * g / (4.0 * curv) },
        "reference_parabola": reference_json,
        "flow_control": m.flow_control.as_ref().map(|c| {
            let (count, velocity) = (m.profile.count.iter().flatten().sum::<f64>(), m.profile.velocity.iter().flatten().sum::<f64>());
            json!({ "target_mean_velocity": c.target, "measured_mean_velocity": velocity / count.max(1.0),
                    "body_force_mean": g, "body_force_final": c.force, "updates": c.history.len(),
                    "tube_body_force_not_used": body_force,
                    "history": c.history.iter().map(|h| json!({"step": h[0], "mean_velocity": h[1], "body_force": h[2]})).collect::<Vec<_>>(),
                    "law": "PI every flow_control_every steps: e = U − ū, I += e·MΔt/τ_v, f = 8η/(nR²)·(e + I), τ_v = nR²/(η j0²)" })
        }),
        "body_force": g,
        "viscosity": viscosity,
        "viscosity_profile": vp.json(),
        "wall_shear_stress": { "measured": tau, "standard_error": tau_se, "expected": tau_expected,
                               "relative_deviation": tau / tau_expected - 1.0, "steady_flow_note": steady_note,
                               "viscous_time": tau_v,
                               "definition": "axial force of the fluid on the wall (pair forces on the wall particles + reflection impulses) per wall area 2πRL, against n̄gR/2 (the wall carries the body force on all fluid particles)" },
        "temperature": { "mean": (t_mean[0] + t_mean[1] + t_mean[2]) / 3.0, "radial": t_mean[0], "azimuthal": t_mean[1], "axial": t_mean[2],
                         "definition": "m⟨(v − ū(r))²⟩ per component over the sampled steps, ū(r) the measured mean velocity of the particle's radial bin" },
    }))
}

/// Couette results: the profile against the line, slip at each wall, η from the wall stress.
fn couette_results(
    plan: &Plan,
    ctx: &RunContext,
    sim: &Simulation<Walls>,
    m: &Measurement,
) -> Result<serde_json::Value, RunError> {
    let Channel::Couette {
        lower,
        gap,
        speed: u,
        area,
    } = plan.channel
    else {
        unreachable!("couette results of a couette plan")
    };
    let upper = lower + gap;
    let nb = plan.run.profile_bins;
    let samples = m.profile.total_samples();
    let (sigma, sigma_se) = stress_mean_se(&m.stress);
    let z: Vec<f64> = (0..nb).map(|b| lower + (b as f64 + 0.5) * gap / nb as f64).collect();
    let (cnt, v) = m.profile.mean();
    let rho: Vec<f64> = cnt
        .iter()
        .map(|c| c / (samples.max(1) as f64 * area * gap / nb as f64))
        .collect();
    let (c0, c1) = fit_line(&z, &v, &cnt);
    let fit: Vec<f64> = z.iter().map(|x| c0 + c1 * x).collect();
    let mass = fluid_mass(sim);
    let temp = m.profile.sum(|_| true).temperature(mass);
    let rows: Vec<Vec<f64>> = (0..nb)
        .map(|k| vec![z[k], v[k], fit[k], rho[k], temp[k][0], temp[k][1], temp[k][2]])
        .collect();
    write_csv(
        ctx,
        "velocity_profile.csv",
        "z,v_x,line,density,kbt_normal,kbt_spanwise,kbt_flow",
        &rows,
    )?;
    // η(z) at the bin edges from the measured wall stress (constant across the gap); the
    // plateau is trimmed symmetrically from both walls
    let w = gap / nb as f64;
    let eta_of = |take: &dyn Fn(usize) -> bool| -> Vec<f64> {
        let s = m.profile.sum(take);
        let v = s.mean_velocity();
        let sigma = block_mean(&m.stress, take);
        (1..nb).map(|e| sigma / ((v[e] - v[e - 1]) / w)).collect()
    };
    // two paths from the mid-plane, one towards each plate (edge k lies at (k + 1)·w), each
    // ending at the last edge at least rc from its plate (as in the tube: closer, the wall
    // particles act across the edge directly and σ is not the fluid's stress alone)
    let mid = (nb - 1) / 2;
    let rc = plan.fluid.cutoff;
    let fluid_stress = |k: usize| {
        let d = (k + 1) as f64 * w;
        d >= rc - 1e-9 && gap - d >= rc - 1e-9
    };
    let paths = vec![(mid..nb - 1).collect(), (0..mid).rev().collect()];
    let mut vp = viscosity_profile(
        m,
        (1..nb).map(|e| lower + e as f64 * w).collect(),
        eta_of,
        paths,
        fluid_stress,
    );
    // the stress is the same at every edge, so the plateau's viscosity is σ over the slope of
    // one line through the bins the plateau spans (bins k_lo … k_hi + 1 for edges k_lo … k_hi):
    // the mean slope there, far less noisy than a weighted mean of the edges' ratios
    if let (Some((_, _, chi2)), Some(&lo), Some(&hi)) = (vp.plateau, vp.plateau_edges.first(), vp.plateau_edges.last())
    {
        let line_eta = |take: &dyn Fn(usize) -> bool| {
            let s = m.profile.sum(take);
            let v = s.mean_velocity();
            let bins = lo..hi + 2;
            let (_, slope) = fit_line(&z[bins.clone()], &v[bins.clone()], &s.count[bins]);
            block_mean(&m.stress, take) / slope
        };
        vp.plateau = Some((line_eta(&|_| true), jackknife_se(m, line_eta), chi2));
    }
    write_csv(
        ctx,
        "viscosity_profile.csv",
        "z,eta,standard_error,in_plateau",
        &vp.rows(),
    )?;
    let slip_lo = ((c0 + c1 * lower) + u) / (2.0 * u);
    let slip_hi = (u - (c0 + c1 * upper)) / (2.0 * u);
    let t = mean_temperature(&cnt, &temp);
    Ok(json!({
        "geometry": { "gap": gap, "width": [plan.box_lengths.x, plan.box_lengths.y], "wall_speed": u },
        "profile": { "z": z, "v_x": v, "line": fit, "density": rho, "samples": samples,
                     "kbt": { "normal": temp.iter().map(|t| t[0]).collect::<Vec<_>>(), "spanwise": temp.iter().map(|t| t[1]).collect::<Vec<_>>(), "flow": temp.iter().map(|t| t[2]).collect::<Vec<_>>() } },
        "line": { "intercept": c0, "shear_rate": c1, "no_slip_shear_rate": 2.0 * u / gap, "slip_fraction_lower": slip_lo, "slip_fraction_upper": slip_hi },
        "shear_stress": { "mean": sigma, "standard_error": sigma_se, "samples": m.stress.iter().map(|b| b[1]).sum::<f64>() },
        "viscosity": vp.summary("the wall shear stress (pair forces on the wall particles + reflection impulses); the value is σ over the slope of a count-weighted line through the bins the plateau spans"),
        "viscosity_whole_line": { "value": sigma / c1, "standard_error": sigma_se / c1.abs() },
        "viscosity_profile": vp.json(),
        "temperature": { "mean": (t[0] + t[1] + t[2]) / 3.0, "normal": t[0], "spanwise": t[1], "flow": t[2],
                         "definition": "m⟨(v − ū(z))²⟩ per component over the sampled steps, ū(z) the measured mean velocity of the particle's bin" },
    }))
}

/// Mass of a fluid particle.
fn fluid_mass(sim: &Simulation<Walls>) -> f64 {
    sim.field().types()[walls::FLUID_TYPE as usize].mass
}

/// Count-weighted mean of a temperature profile per component (empty bins left out).
fn mean_temperature(count: &[f64], temp: &[[f64; 3]]) -> [f64; 3] {
    let n: f64 = count.iter().sum();
    std::array::from_fn(|c| {
        (0..count.len())
            .filter(|&k| count[k] > 0.0)
            .map(|k| count[k] * temp[k][c])
            .sum::<f64>()
            / n
    })
}

/// The results every wall scenario reports, added to the kind's own (`specific`): the schedule,
/// the adaptation, the near-wall density, reflections, timing, files; the overhead is timed last
/// (it steps the simulation on).
fn wall_results(
    plan: &Plan,
    ctx: &RunContext,
    mut sim: Simulation<Walls>,
    m: &Measurement,
    source: &str,
    resumed: Option<u64>,
    specific: serde_json::Value,
) -> Result<serde_json::Value, RunError> {
    let walls = sim.extension();
    let near = walls.relative_density();
    let dev = near.iter().map(|x| (x - 1.0).abs()).fold(0.0, f64::max);
    let mut out = json!({
        "units": "DPD model units: length rc, energy kBT, mass m",
        "steps": plan.total(),
        "resumed_from_step": resumed,
        "wall_force_source": source,
        "adaptation": adaptation(&sim),
        "near_wall": { "bin_centres": walls.bin_centres(), "relative_density": near, "max_density_deviation": dev, "target_density": walls.target_density() },
        "reflections": walls.reflections(),
        "stepping_seconds": m.stepping_seconds,
        "checkpoint_file": ctx.out_dir.join(CHECKPOINT_FILE),
        "trajectory_file": (plan.output.trajectory_every_steps > 0).then(|| ctx.out_dir.join(TRAJECTORY_FILE)),
    });
    if let (Some(o), serde_json::Value::Object(extra)) = (out.as_object_mut(), specific) {
        o.extend(extra);
    }
    out["overhead"] = if plan.run.measure_overhead {
        overhead(plan, &mut sim)?
    } else {
        serde_json::Value::Null
    };
    Ok(out)
}

fn tube_plan(s: &TubeScenario) -> Plan<'_> {
    let (f, t) = (&s.fluid, &s.tube);
    let side = 2.0 * (t.radius + f.cutoff) + 0.5;
    Plan {
        kind: "poiseuille-tube",
        toml: toml::to_string(s).unwrap_or_default(),
        seed: s.seed,
        fluid: f,
        walls: &s.walls,
        run: &s.run,
        output: &s.output,
        base_dir: &s.base_dir,
        shape: WallShape::Cylinder {
            axis: 2,
            centre: [0.5 * side; 2],
            radius: t.radius,
        },
        box_lengths: DVec3::new(side, side, t.length),
        channel: Channel::Tube {
            radius: t.radius,
            length: t.length,
            body_force: t.body_force,
            reference_viscosity: t.reference_viscosity,
            mean_velocity: t.mean_velocity.map(|u| (u, t.flow_control_every)),
        },
        length_scale_um_per_rc: t.length_scale_um_per_rc,
    }
}

fn couette_plan(s: &CouetteScenario) -> Plan<'_> {
    let (f, pl) = (&s.fluid, &s.plates);
    let rc = f.cutoff;
    let (lower, upper, period) = (rc, rc + pl.gap, pl.gap + 2.0 * rc);
    let u = pl.wall_speed;
    Plan {
        kind: "couette",
        toml: toml::to_string(s).unwrap_or_default(),
        seed: s.seed,
        fluid: f,
        walls: &s.walls,
        run: &s.run,
        output: &s.output,
        base_dir: &s.base_dir,
        shape: WallShape::Plates {
            axis: 2,
            lower,
            upper,
            period,
            lower_velocity: DVec3::new(-u, 0.0, 0.0),
            upper_velocity: DVec3::new(u, 0.0, 0.0),
        },
        box_lengths: DVec3::new(pl.width[0], pl.width[1], period),
        channel: Channel::Couette {
            lower,
            gap: pl.gap,
            speed: u,
            area: pl.width[0] * pl.width[1],
        },
        length_scale_um_per_rc: None,
    }
}

/// Runs `kind = "poiseuille-tube"`, from step 0 or from a checkpoint.
pub fn run_tube(
    s: &TubeScenario,
    ctx: &RunContext,
    checkpoint: Option<&Checkpoint>,
) -> Result<serde_json::Value, RunError> {
    let plan = tube_plan(s);
    let (sim, m, source) = run_plan(&plan, ctx, checkpoint)?;
    let specific = tube_results(&plan, ctx, &sim, &m)?;
    wall_results(&plan, ctx, sim, &m, &source, checkpoint.map(|c| c.step), specific)
}

/// Runs `kind = "couette"`, from step 0 or from a checkpoint.
pub fn run_couette(
    s: &CouetteScenario,
    ctx: &RunContext,
    checkpoint: Option<&Checkpoint>,
) -> Result<serde_json::Value, RunError> {
    let plan = couette_plan(s);
    let (sim, m, source) = run_plan(&plan, ctx, checkpoint)?;
    let specific = couette_results(&plan, ctx, &sim, &m)?;
    wall_results(&plan, ctx, sim, &m, &source, checkpoint.map(|c| c.step), specific)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Profile sums of a tube flow with a known viscosity profile: η = `bulk` for r < `layer`,
    /// `wall` beyond, uniform density n = 3, body force g; the velocity integrates
    /// dv/dr = σ_rz/η with σ_rz = −ngr/2 (no slip at R), and each bin holds the exact
    /// count-weighted mean over its annulus plus a deterministic noise of relative size
    /// `noise` per block.
    fn synthetic_tube(bulk: f64, wall: f64, layer: f64, noise: f64) -> (Measurement, f64, f64, f64) {
        let (radius, length, g, n, nb) = (5.0, 12.0, 0.1, 3.0, 20);
        let eta = |r: f64| if r < layer { bulk } else { wall };
        // v(r) = ∫_r^R n g s/(2η(s)) ds, on a fine grid
        let fine = 20_000;
        let h = radius / fine as f64;
        let mut v = vec![0.0; fine + 1];
        for i in (0..fine).rev() {
            let s = (i as f64 + 0.5) * h;
            v[i] = v[i + 1] + n * g * s / (2.0 * eta(s)) * h;
        }
        let w = radius / nb as f64;
        let mut m = Measurement {
            profile: ProfileSums::new(nb),
            stress: vec![[0.0; 2]; BLOCKS],
            impulse_prev: [0.0; 2],
            stepping_seconds: 0.0,
            flow_control: None,
        };
        let samples = 1000u64;
        let mut state = 12345u64;
        for b in 0..BLOCKS {
            m.profile.samples[b] = samples;
            for k in 0..nb {
                // annulus mean of v weighted by r
                let (i0, i1) = ((k as f64 * w / h) as usize, ((k + 1) as f64 * w / h) as usize);
                let (mut sv, mut sw) = (0.0, 0.0);
                for i in i0..i1 {
                    let r = (i as f64 + 0.5) * h;
                    sv += v[i] * r;
                    sw += r;
                }
                state = hemodpd_engine::rng::mix64(state.wrapping_add(0x9E37_79B9_7F4A_7C15));
                let xi = (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0;
                let count = n
                    * std::f64::consts::PI
                    * (((k + 1) as f64 * w).powi(2) - (k as f64 * w).powi(2))
                    * length
                    * samples as f64;
                m.profile.count[b][k] = count;
                m.profile.velocity[b][k] = count * (sv / sw) * (1.0 + noise * xi);
            }
        }
        (m, g, radius, length)
    }

    /// The plateau of η(r) finds the bulk viscosity and stops at the wall layer, with no window
    /// given: a layer of η = 0.72 beyond r = 3.75 under a bulk of 0.84 (as measured in the
    /// R = 5 tube), with 0.2 % noise per bin and block.
    #[test]
    fn plateau_finds_the_bulk_and_stops_at_the_wall_layer() {
        let (m, g, radius, length) = synthetic_tube(0.84, 0.72, 3.75, 0.002);
        let vp = tube_viscosity_profile(&m, g, radius, length, 1.0);
        let (eta, se, _) = vp.plateau.expect("a plateau");
        let last = vp.r[*vp.plateau_edges.last().unwrap()];
        assert!((eta / 0.84 - 1.0).abs() < 0.01, "plateau {eta} ± {se}");
        assert!(last <= 3.75 + 1e-9, "the plateau runs into the layer, to r = {last}");
        assert!(last >= 3.0, "the plateau stops early, at r = {last}");
        // without noise the edges reproduce η exactly where the bins are all in one region
        let (m, ..) = synthetic_tube(0.84, 0.84, 10.0, 0.0);
        let vp = tube_viscosity_profile(&m, g, radius, length, 1.0);
        for (r, e) in vp.r.iter().zip(&vp.eta) {
            assert!((e / 0.84 - 1.0).abs() < 1e-3, "η({r}) = {e}");
        }
    }
}
