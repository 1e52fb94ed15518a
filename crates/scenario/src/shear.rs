//! `kind = "shear"`: one red blood cell in simple shear flow u = γ̇ y x̂ (flow x, gradient y,
//! vorticity z), the paper's Fig. 4, in SI units (docs/shear.md).
//!
//! The shear is imposed by Lees–Edwards boundaries in y (the default: no walls at all) or by
//! two plates moving at ±U/2 (the frozen-particle walls of the Couette scenario, set back by
//! the fluid's slip length so that the no-slip planes are `box_um[1]` apart). The cell starts
//! at the centre of the box, its symmetry axis in the shear plane, its diameter at
//! `initial_inclination_deg` from the flow. Inner and outer fluid, the membrane–fluid coupling
//! and the `[cell]` and shared `[model]` keys are the cell-in-flow family's ([`crate::cell`]); the
//! characteristic velocity of the mapping is γ̇ D0/2, the velocity of the membrane relative to
//! the fluid around it (a linear shear flow is an exact solution at any streaming velocity, so
//! the Mach number that matters is that of the disturbance the cell makes, not of the box edge).
//!
//! The motion (tumbling, tank-treading, swinging, intermittent) is measured while the run goes
//! on by [`hemodpd_membrane::motion`] and classified over the window after
//! `analysis_start_strain`; `hemodpd analyze` does the same from a trajectory.

use crate::cell::build::{cell_mesh_um, check_membrane_timestep, membrane_model, place_cell, CellPlan, CellSetup};
use crate::cell::checkpoint::{open_cell_trajectory, restore_cell_run, save_cell_run, CheckpointHead};
use crate::cell::section::{cell_mapping, cell_params, validate_cell, validate_model, ModelKeys};
use crate::cell::summary::{common_blocks, performance_json, StepClock};
use crate::cell::{describe_engine_error, CellSection, CellSim, OUTER};
use crate::context::{RunContext, RunError};
use crate::driver::{self, Stepper};
use crate::file::ScenarioError;
use crate::run_dir::{engine_err, out_err, TRAJECTORY_FILE};
use crate::units::{self, um_to_m, FluidDecision, PhysicalSystem};
use glam::DVec3;
use hemodpd_engine::walls::{self, WallSetup, WallShape};
use hemodpd_engine::{init, SimConfig};
use hemodpd_io::checkpoint::Checkpoint;
use hemodpd_io::{FrameScalar, MetaValue, Quantity, RunMetadata, TrajectoryWriter};
use hemodpd_membrane::motion::{self, FrameMotion, MotionAnalysis, MotionThresholds, MotionTracker, TrackerSnapshot};
use hemodpd_membrane::shape::EvansFung;
use hemodpd_membrane::Mesh;
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::path::PathBuf;

fn d_box() -> [f64; 3] {
    [24.0, 20.0, 16.0]
}
fn d_incl() -> f64 {
    45.0
}
fn d_outer() -> f64 {
    28.9e-3
}
fn d_inner() -> f64 {
    6e-3
}
fn d_sample() -> f64 {
    0.05
}
fn d_frame() -> f64 {
    1.0
}

/// How the shear is imposed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum ShearDriver {
    /// Lees–Edwards boundaries in y: unbounded shear, no walls (default).
    #[default]
    LeesEdwards,
    /// Two frozen-particle plates normal to y moving at ∓U/2 along x.
    Plates,
}

/// `[shear]`: the flow.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ShearSection {
    /// Shear rate γ̇, 1/s (exactly one of this and `shear_stress_pa`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shear_rate_per_s: Option<f64>,
    /// Shear stress η_out γ̇, Pa.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shear_stress_pa: Option<f64>,
    /// "lees-edwards" (default) or "plates".
    #[serde(default)]
    pub driver: ShearDriver,
    /// Box along x (flow), y (gradient: between the no-slip planes for plates), z, µm
    /// (default [24, 20, 16]: about 3, 2.5 and 2 cell diameters).
    #[serde(default = "d_box")]
    pub box_um: [f64; 3],
    /// Angle of the cell's diameter from the flow direction at the start, degrees; its symmetry
    /// axis lies in the shear plane (default 45).
    #[serde(default = "d_incl")]
    pub initial_inclination_deg: f64,
    /// Length of the run as strain γ̇ t (exactly one of this and `duration_s`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub duration_strain: Option<f64>,
    /// Length of the run, s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub duration_s: Option<f64>,
    /// Strain after which the motion is classified (default: a third of the run).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub analysis_start_strain: Option<f64>,
}

/// `[fluid]`: the suspending medium and the cytosol.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ShearFluidSection {
    /// Outer (suspending medium) viscosity, Pa·s (default 28.9e-3: the dextran solution of
    /// Fischer's tank-treading frequencies).
    #[serde(default = "d_outer")]
    pub outer_viscosity_pa_s: f64,
    /// Inner (cytosol) viscosity, Pa·s (default 6e-3).
    #[serde(default = "d_inner")]
    pub inner_viscosity_pa_s: f64,
}

crate::cell::section::model_section! {
    /// `[model]`: how SI maps onto the DPD model (docs/units.md): the keys of every cell-in-flow
    /// kind (the membrane–wall repulsion acts with plates only).
    ShearModelSection {}
}

/// `[output]`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ShearOutput {
    /// Strain between samples of the motion (default 0.05; at most 0.5 so that the classifier
    /// can unwrap the angles).
    #[serde(default = "d_sample")]
    pub sample_every_strain: f64,
    /// Strain between membrane frames in the trajectory; 0: none (default 1).
    #[serde(default = "d_frame")]
    pub frame_every_strain: f64,
    /// Steps between checkpoints; 0 (default): only at the end and on Ctrl-C.
    #[serde(default)]
    pub checkpoint_every_steps: u64,
}

/// `kind = "shear"`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ShearScenario {
    pub format_version: u32,
    pub kind: String,
    pub seed: u64,
    pub shear: ShearSection,
    #[serde(default = "default_fluid")]
    pub fluid: ShearFluidSection,
    #[serde(default = "default_cell")]
    pub cell: CellSection,
    #[serde(default = "default_model")]
    pub model: ShearModelSection,
    #[serde(default = "default_output")]
    pub output: ShearOutput,
    /// Directory of the scenario file; not part of the file.
    #[serde(skip)]
    pub base_dir: PathBuf,
}

fn default_fluid() -> ShearFluidSection {
    toml::from_str("").expect("defaults")
}
fn default_cell() -> CellSection {
    toml::from_str("").expect("defaults")
}
fn default_model() -> ShearModelSection {
    toml::from_str("").expect("defaults")
}
fn default_output() -> ShearOutput {
    toml::from_str("").expect("defaults")
}

/// Resting cell diameter D0, µm.
fn d0_um() -> f64 {
    2.0 * EvansFung::healthy_um().r
}

impl ShearScenario {
    /// The shear rate γ̇, 1/s.
    pub fn shear_rate(&self) -> f64 {
        match (self.shear.shear_rate_per_s, self.shear.shear_stress_pa) {
            (Some(r), _) => r,
            (None, Some(t)) => t / self.fluid.outer_viscosity_pa_s,
            (None, None) => f64::NAN,
        }
    }

    /// Total strain of the run.
    pub fn duration_strain(&self) -> f64 {
        match (self.shear.duration_strain, self.shear.duration_s) {
            (Some(g), _) => g,
            (None, Some(t)) => t * self.shear_rate(),
            (None, None) => 60.0,
        }
    }

    /// Strain from which the motion is classified.
    pub fn analysis_start_strain(&self) -> f64 {
        self.shear.analysis_start_strain.unwrap_or(self.duration_strain() / 3.0)
    }

    /// The physical system of the unit mapping: characteristic velocity γ̇ D0/2, length scale of
    /// the Reynolds number D0 (Re = ρ γ̇ D0²/(2η)), viscosity ratio η_in/η_out.
    pub fn physical(&self) -> Result<PhysicalSystem, RunError> {
        let p = cell_params(&self.cell)?;
        let d0 = um_to_m(d0_um());
        let mut sys = PhysicalSystem::new(
            &p,
            d0,
            um_to_m(self.shear.box_um[0]),
            self.fluid.outer_viscosity_pa_s,
            self.shear_rate() * 0.5 * d0,
        );
        sys.viscosity_ratio = self.fluid.inner_viscosity_pa_s / self.fluid.outer_viscosity_pa_s;
        Ok(sys)
    }

    /// The unit mapping (errors name the scenario key).
    pub fn mapping(&self) -> Result<(PhysicalSystem, FluidDecision), RunError> {
        let sys = self.physical()?;
        let d = cell_mapping(&sys, self.model.shared())?;
        Ok((sys, d))
    }

    /// The `--explain-units` text: scales, the shear in both systems and the groups.
    pub fn explain_units(&self) -> Result<String, RunError> {
        let (sys, d) = self.mapping()?;
        let (m, fluid) = (&d.map, &d.fluid);
        let plan = Plan::new(self)?;
        let (gs, gm) = (units::groups_si(&sys), units::groups_model(&sys, m, fluid));
        let mut s = String::new();
        use std::fmt::Write as _;
        let _ = writeln!(
            s,
            "Unit mapping of a shear run (model units: length rc, energy kBT of the fluid, mass of a fluid particle)"
        );
        let _ = writeln!(
            s,
            "  length r = {:.4e} m, energy E = {:.4e} J (thermal factor f = {:.4}), time τ = {:.4e} s",
            m.length_m, m.energy_j, m.thermal_factor, m.time_s
        );
        let _ = writeln!(
            s,
            "  shear rate           {:>12.4e} 1/s   {:>12.4e} model",
            self.shear_rate(),
            plan.rate
        );
        let _ = writeln!(
            s,
            "  shear stress η_out γ̇ {:>12.4e} Pa    {:>12.4e} model",
            self.shear_rate() * self.fluid.outer_viscosity_pa_s,
            plan.rate * fluid.viscosity
        );
        let _ = writeln!(
            s,
            "  time step            {:>12.4e} s     {:>12.4e} model ({:.0} steps per unit strain)",
            plan.setup.dt * m.time_s,
            plan.setup.dt,
            1.0 / (plan.rate * plan.setup.dt)
        );
        let _ = writeln!(
            s,
            "  run                  {:>12.4e} s     {} steps ({} strain)",
            self.duration_strain() / self.shear_rate(),
            plan.steps,
            self.duration_strain()
        );
        let _ = writeln!(
            s,
            "  box (x, y, z)        {:?} µm = {:.2?} rc, driver {:?}",
            self.shear.box_um,
            plan.box_lengths.to_array(),
            self.shear.driver
        );
        let _ = writeln!(s, "  groups                     SI            model");
        let row = |s: &mut String, n: &str, a: f64, b: f64| {
            let _ = writeln!(s, "    {n:<22} {a:>12.4e}  {b:>12.4e}");
        };
        row(&mut s, "Ca = η_out γ̇ R/μ0", gs.capillary_number, gm.capillary_number);
        row(&mut s, "κ/(μ0 D0²)", gs.bending_ratio, gm.bending_ratio);
        row(&mut s, "λ = η_in/η_out", gs.viscosity_ratio, gm.viscosity_ratio);
        row(&mut s, "κ/kBT", gs.kappa_over_kbt, gm.kappa_over_kbt);
        row(&mut s, "Re = ρ γ̇ D0²/(2η)", gs.reynolds, gm.reynolds);
        row(&mut s, "Mach (γ̇ D0/2)/c", gs.mach, gm.mach);
        for w in &m.warnings {
            let _ = writeln!(s, "  warning: {w}");
        }
        s.push_str(&units::explain_fluid(&d));
        s.push_str(&self.cell.explain_parameters());
        Ok(s)
    }
}

/// Validates a `kind = "shear"` scenario, the unit mapping included, before any work.
pub fn validate(s: &ShearScenario, file: &str) -> Result<(), ScenarioError> {
    let c = crate::file::Check { file };
    let fail = |key: &str, value: String, allowed: &str| c.fail(key, value, allowed);
    let range = |key: &str, v: f64, lo: f64, hi: f64, allowed: &str| c.range(key, v, lo, hi, allowed);
    let sh = &s.shear;
    match (sh.shear_rate_per_s, sh.shear_stress_pa) {
        (Some(r), None) => range("shear.shear_rate_per_s", r, 1e-3, 1e5, "1e-3–1e5 1/s")?,
        (None, Some(t)) => range("shear.shear_stress_pa", t, 1e-5, 1e3, "1e-5–1e3 Pa")?,
        (Some(_), Some(_)) => {
            return Err(fail(
                "shear.shear_rate_per_s",
                "both shear_rate_per_s and shear_stress_pa".into(),
                "exactly one of them",
            ))
        }
        (None, None) => {
            return Err(ScenarioError::Missing {
                file: file.into(),
                key: "shear.shear_rate_per_s".into(),
                what: "the shear: shear_rate_per_s (1/s) or shear_stress_pa (Pa)".into(),
            })
        }
    }
    range(
        "fluid.outer_viscosity_pa_s",
        s.fluid.outer_viscosity_pa_s,
        1e-4,
        1.0,
        "1e-4–1 Pa·s",
    )?;
    range(
        "fluid.inner_viscosity_pa_s",
        s.fluid.inner_viscosity_pa_s,
        1e-4,
        1.0,
        "1e-4–1 Pa·s",
    )?;
    let ratio = s.fluid.inner_viscosity_pa_s / s.fluid.outer_viscosity_pa_s;
    if !(0.05..=20.0).contains(&ratio) {
        return Err(fail(
            "fluid.inner_viscosity_pa_s",
            format!(
                "{} (ratio {ratio} to fluid.outer_viscosity_pa_s = {})",
                s.fluid.inner_viscosity_pa_s, s.fluid.outer_viscosity_pa_s
            ),
            "an inner/outer ratio in 0.05–20 (the inner fluid's γ is the outer's times the ratio)",
        ));
    }
    let d0 = d0_um();
    for (k, name) in ["x", "y", "z"].iter().enumerate() {
        range(
            &format!("shear.box_um[{k}]"),
            sh.box_um[k],
            1.25 * d0,
            200.0,
            &format!("{:.1}–200 µm ({name}: at least 1.25 cell diameters, so that the cell does not meet its periodic image)", 1.25 * d0),
        )?;
    }
    if sh.driver == ShearDriver::Plates {
        let margin = 2.0 * (s.model.wall_repulsion_range_rc + 1.0) * s.model.length_um_per_rc;
        range(
            "shear.box_um[1]",
            sh.box_um[1],
            d0 + margin,
            200.0,
            &format!(
                "at least the cell diameter plus twice (repulsion range + 1 rc) = {:.1} µm between the plates",
                d0 + margin
            ),
        )?;
    }
    range(
        "shear.initial_inclination_deg",
        sh.initial_inclination_deg,
        -90.0,
        90.0,
        "−90–90°",
    )?;
    match (sh.duration_strain, sh.duration_s) {
        (Some(_), Some(_)) => {
            return Err(fail(
                "shear.duration_strain",
                "both duration_strain and duration_s".into(),
                "at most one of them (default: 60 strain units)",
            ))
        }
        (Some(g), None) => range("shear.duration_strain", g, 0.1, 1e5, "0.1–1e5")?,
        (None, Some(t)) => range("shear.duration_s", t, 1e-6, 1e3, "1e-6–1000 s")?,
        (None, None) => {}
    }
    if let Some(a) = sh.analysis_start_strain {
        range(
            "shear.analysis_start_strain",
            a,
            0.0,
            s.duration_strain() * 0.9,
            "0 to 90 % of the run's strain",
        )?;
    }
    validate_cell(&s.cell, file)?;
    validate_model(
        s.model.shared(),
        "1e-4–0.004 model units (default: the fluid's, 0.0025 for \"capillary\", 0.003 for \"dense\", divided by a viscosity ratio above 1)",
        file,
    )?;
    range(
        "output.sample_every_strain",
        s.output.sample_every_strain,
        1e-4,
        0.5,
        "1e-4–0.5 (the motion analysis unwraps angles between samples)",
    )?;
    range(
        "output.frame_every_strain",
        s.output.frame_every_strain,
        0.0,
        1e4,
        "0 (none) to 1e4",
    )?;
    // the unit mapping's own bounds (Mach, Reynolds), with the key of the scenario
    if let Err(e) = Plan::new(s) {
        return Err(fail(
            "shear.shear_rate_per_s",
            format!("{} 1/s", s.shear_rate()),
            &e.to_string(),
        ));
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// The build

/// Everything derived from the file, model units.
pub struct Plan<'a> {
    pub s: &'a ShearScenario,
    /// The system, the fluid and mapping chosen for it, the time step and the sub-steps.
    pub setup: CellSetup,
    /// Shear rate γ̇ (model).
    pub rate: f64,
    pub box_lengths: DVec3,
    /// Plates (None: Lees–Edwards).
    pub plates: Option<WallShape>,
    /// Centre of the cell (and the streaming velocity's zero).
    pub centre: DVec3,
    pub steps: u64,
    pub sample_every: u64,
    pub frame_every: u64,
    toml: String,
}

impl<'a> Plan<'a> {
    pub fn new(s: &'a ShearScenario) -> Result<Self, RunError> {
        let setup = CellSetup::new(s.physical()?, s.model.shared(), &s.cell)?;
        let (map, fluid, dt) = (&setup.map, &setup.fluid, setup.dt);
        let rate = s.shear_rate() * map.time_s;
        let mut l = DVec3::from_array(s.shear.box_um.map(|x| map.length_to_model(um_to_m(x))));
        let rc = fluid.pair.rc;
        let plates = match s.shear.driver {
            ShearDriver::LeesEdwards => None,
            ShearDriver::Plates => {
                // the no-slip planes lie b beyond the wall surfaces: surfaces H − 2b apart,
                // each plate moving at ∓γ̇H/2; a wall slab of 2 rc across the periodic boundary
                let h = l.y;
                let b = fluid.wall_slip;
                let gap = h - 2.0 * b;
                l.y = gap + 2.0 * rc;
                let u = 0.5 * rate * h;
                Some(WallShape::Plates {
                    axis: 1,
                    lower: rc,
                    upper: rc + gap,
                    period: l.y,
                    lower_velocity: DVec3::new(-u, 0.0, 0.0),
                    upper_velocity: DVec3::new(u, 0.0, 0.0),
                })
            }
        };
        let per_strain = 1.0 / (rate * dt);
        let steps = (s.duration_strain() * per_strain).round().max(1.0) as u64;
        let sample_every = (s.output.sample_every_strain * per_strain).round().max(1.0) as u64;
        let frame_every = if s.output.frame_every_strain > 0.0 {
            (s.output.frame_every_strain * per_strain).round().max(1.0) as u64
        } else {
            0
        };
        Ok(Plan {
            s,
            setup,
            rate,
            box_lengths: l,
            plates,
            centre: 0.5 * l,
            steps,
            sample_every,
            frame_every,
            toml: toml::to_string(s).unwrap_or_default(),
        })
    }

    /// Streaming velocity at `x`: γ̇ (y − y_c) x̂ (zero at the cell's centre).
    fn streaming(&self, x: DVec3) -> DVec3 {
        DVec3::new(self.rate * (x.y - self.centre.y), 0.0, 0.0)
    }

    /// The resting mesh in model units: symmetry axis in the shear plane, the diameter at the
    /// initial inclination from x, centred in the box.
    fn rest_mesh(&self) -> Result<(Mesh, serde_json::Value), RunError> {
        let (mut mesh, info) = cell_mesh_um(&self.s.cell, self.s.seed, &self.s.base_dir)?;
        let scale = 1e-6 / self.setup.map.length_m;
        let (sn, cs) = self.s.shear.initial_inclination_deg.to_radians().sin_cos();
        // the generated shape's symmetry axis is y: a rotation about z by θ0 puts its diameter
        // (x) at θ0 from the flow
        for v in mesh.vertices.iter_mut() {
            let p = *v * scale;
            *v = DVec3::new(cs * p.x - sn * p.y, sn * p.x + cs * p.y, p.z) + self.centre;
        }
        Ok((mesh, info))
    }
}

impl CellPlan for Plan<'_> {
    fn cell(&self) -> &CellSection {
        &self.s.cell
    }
    fn model_keys(&self) -> ModelKeys<'_> {
        self.s.model.shared()
    }
    fn setup(&self) -> &CellSetup {
        &self.setup
    }
    fn viscosity_ratio(&self) -> f64 {
        self.s.fluid.inner_viscosity_pa_s / self.s.fluid.outer_viscosity_pa_s
    }
    fn seed(&self) -> u64 {
        self.s.seed
    }
    fn box_lengths(&self) -> DVec3 {
        self.box_lengths
    }
    /// Lees–Edwards boundaries carry the shear rate; plates need none.
    fn sim_config(&self) -> SimConfig {
        let c = self.setup.sim_config(self.box_lengths, self.s.seed);
        match self.plates {
            None => c.with_shear_rate(self.rate),
            Some(_) => c,
        }
    }
    fn wall_shape(&self) -> Option<WallShape> {
        self.plates
    }
}

/// The simulation of a shear run: plates (or none) and the cell.
pub type ShearSim = CellSim;

fn build(plan: &Plan) -> Result<(ShearSim, Mesh, serde_json::Value), RunError> {
    let (rest, info) = plan.rest_mesh()?;
    let model = membrane_model(&plan.s.cell, &plan.setup.map, &rest)?;
    check_membrane_timestep(plan, &model, &rest)?;
    let base = match plan.plates {
        Some(shape) => {
            let setup = WallSetup {
                shape,
                pair: plan.setup.fluid.pair,
                density: plan.setup.fluid.density,
                thickness: plan.setup.fluid.pair.rc,
                equilibration_steps: 200,
            };
            walls::build(
                &SimConfig::new(plan.box_lengths, plan.setup.dt, plan.s.seed),
                &setup,
                plan.s.seed,
            )
            .map_err(engine_err)?
            .1
        }
        None => {
            let spec = init::FluidSpec {
                density: plan.setup.fluid.density,
                ..init::FluidSpec::standard()
            };
            let field = hemodpd_engine::ForceField::single(plan.setup.fluid.pair);
            init::fluid(&plan.sim_config(), &field, &spec, plan.s.seed ^ 0x5EA4).map_err(engine_err)?
        }
    };
    let streaming = |x: DVec3| plan.streaming(x);
    let sim = place_cell(plan, &base, &rest, &rest.vertices, model, Some(&streaming))?;
    Ok((sim, rest, info))
}

// ---------------------------------------------------------------------------------------------
// Observation

/// One sample, model units.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ShearSample {
    pub step: u64,
    pub motion: FrameMotion,
    /// Taylor deformation (L − B)/(L + B) of the cell's section in the shear plane.
    pub taylor_deformation: f64,
    pub area_deviation: f64,
    pub volume_deviation: f64,
    /// Least-squares slope dv_x/dy of the outer fluid's particles (the shear rate it carries).
    pub fluid_shear_rate: f64,
}

/// The run's evolving state besides the simulation (checkpointed as JSON).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct ShearState {
    pub samples: Vec<ShearSample>,
    /// The motion tracker and the vertices of its last frame.
    pub tracker: TrackerSnapshot,
    pub tracker_vertices: Vec<[f64; 3]>,
    pub stepping_seconds: f64,
}

/// Taylor deformation from the in-plane anisotropy a = (λ1 − λ2)/(λ1 + λ2) of the gyration
/// tensor: L/B = √(λ1/λ2) = √((1 + a)/(1 − a)).
fn taylor_deformation(a: f64) -> f64 {
    let r = ((1.0 + a) / (1.0 - a).max(1e-12)).sqrt();
    (r - 1.0) / (r + 1.0)
}

/// A running shear scenario (the [`Stepper`] of [`driver::drive`]).
pub struct Run<'a> {
    plan: &'a Plan<'a>,
    sim: ShearSim,
    rest: Mesh,
    tracker: MotionTracker,
    st: ShearState,
    traj: Option<TrajectoryWriter>,
    mesh_info: serde_json::Value,
    clock: StepClock,
}

impl Run<'_> {
    fn sample(&mut self) -> Result<(), RunError> {
        let cell = &self.sim.extension().1;
        let x = cell.vertices();
        let t = self.sim.time();
        let m = self.tracker.push(t, x).map_err(|e| {
            RunError::Engine(format!(
                "step {}: motion of the cell: {e}; likely cause: the membrane became unstable (lower model.timestep)",
                self.sim.step_count()
            ))
        })?;
        let model = cell.model();
        let (a, v) = model.area_volume(x).unwrap_or((f64::NAN, f64::NAN));
        if !(a.is_finite() && v.is_finite()) {
            return Err(RunError::Engine(format!(
                "step {}: the cell's shape is no longer finite (membrane vertices); likely cause: the time step is too large for the membrane",
                self.sim.step_count()
            )));
        }
        let p = self.sim.particles();
        let (mut n, mut sy, mut syy, mut sv, mut syv) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for ((x, v), &t) in p.pos.iter().zip(&p.vel).zip(&p.ptype) {
            if t == OUTER {
                n += 1.0;
                sy += x.y;
                syy += x.y * x.y;
                sv += v.x;
                syv += x.y * v.x;
            }
        }
        let fluid_shear_rate = (n * syv - sy * sv) / (n * syy - sy * sy);
        self.st.samples.push(ShearSample {
            step: self.sim.step_count(),
            motion: m,
            taylor_deformation: taylor_deformation(m.in_plane_anisotropy),
            area_deviation: a / model.area0() - 1.0,
            volume_deviation: v / model.volume0() - 1.0,
            fluid_shear_rate,
        });
        self.st.tracker = self.tracker.snapshot();
        self.st.tracker_vertices.clear();
        self.st.tracker_vertices.extend(x.iter().map(|p| p.to_array()));
        Ok(())
    }
}

impl Stepper for Run<'_> {
    fn step_count(&self) -> u64 {
        self.sim.step_count()
    }
    fn max_steps(&self) -> u64 {
        self.plan.steps
    }
    fn time(&self) -> f64 {
        self.sim.time()
    }
    fn finished(&self) -> bool {
        self.sim.step_count() >= self.plan.steps
    }

    fn advance(&mut self) -> Result<(), RunError> {
        self.sim.step().map_err(describe_engine_error)?;
        if self.sim.step_count().is_multiple_of(self.plan.sample_every) {
            let t0 = std::time::Instant::now();
            self.sample()?;
            self.clock.output_s += t0.elapsed().as_secs_f64();
        }
        Ok(())
    }

    fn frame_due(&self) -> bool {
        let every = self.plan.frame_every;
        every > 0 && self.sim.step_count().is_multiple_of(every)
    }

    fn write_frame(&mut self) -> Result<(), RunError> {
        let t0 = std::time::Instant::now();
        let Some(w) = self.traj.as_mut() else {
            return Ok(());
        };
        let cell = &self.sim.extension().1;
        let x = cell.vertices();
        let p = self.sim.particles();
        let vr = cell.vertex_range();
        let scalars = [FrameScalar {
            name: "inclination_deg",
            value: motion::inclination_deg(x),
            quantity: Quantity::Dimensionless,
        }];
        let (step, time) = (self.sim.step_count(), self.sim.time());
        // velocities in the frame of the unwrapped vertices: an image k periods up moves with +kU
        let (l, u) = (self.plan.box_lengths.y, self.sim.domain().shear_velocity());
        let vel: Vec<DVec3> = p.vel[vr.clone()]
            .iter()
            .zip(&p.pos[vr])
            .zip(x)
            .map(|((v, w), xu)| *v + DVec3::X * (u * ((xu.y - w.y) / l).round()))
            .collect();
        w.append_membrane_frame(step, time, x, Some(&vel), &scalars)
            .map_err(out_err)?;
        self.clock.output_s += t0.elapsed().as_secs_f64();
        Ok(())
    }

    fn flush(&mut self) -> Result<(), RunError> {
        if let Some(w) = self.traj.as_mut() {
            w.flush().map_err(out_err)?;
        }
        Ok(())
    }

    fn save_checkpoint(&mut self, ctx: &RunContext) -> Result<(), RunError> {
        self.clock.checkpoint(&mut self.st.stepping_seconds);
        let head = CheckpointHead {
            kind: "shear",
            seed: self.plan.s.seed,
            toml: &self.plan.toml,
            base_dir: &self.plan.s.base_dir,
            finished: None,
        };
        save_cell_run(&self.sim, &head, &self.st, &self.rest, &self.mesh_info, ctx)
    }
}

// ---------------------------------------------------------------------------------------------
// Results

/// The motion analysis of `samples` after `start_strain` (model time), as JSON in SI.
fn motion_json(a: &MotionAnalysis, rate_si: f64, time_s: f64) -> serde_json::Value {
    let per_s = |x: Option<f64>| x.map(|v| v / time_s);
    json!({
        "class": a.class,
        "undetermined_reason": a.undetermined_reason,
        "window_strain": a.strain,
        "flips": a.flips,
        "tank_treading_half_revolutions": a.tt_half_revolutions,
        // a fraction of the labelled time: none when nothing was labelled (Undetermined)
        "tumbling_fraction": (a.class != motion::MotionClass::Undetermined).then_some(a.tumbling_fraction),
        "tumbling_rate_flips_per_s": per_s(a.tumbling_rate),
        "tank_treading_frequency_hz": per_s(a.tank_treading_frequency),
        "tank_treading_frequency_over_shear_rate": per_s(a.tank_treading_frequency).map(|f| f / rate_si),
        "mean_inclination_deg": a.mean_inclination_deg,
        "inclination_amplitude_deg": a.inclination_amplitude_deg,
        "swing_frequency_hz": per_s(a.swing_frequency),
        "swing_to_tank_treading_ratio": a.swing_to_tt_ratio,
    })
}

/// The membrane's mean rotation over the window, whatever the class: the least-squares slope of
/// the tank-treading phase Φ(t) as a frequency (Hz, positive in the vorticity sense) and over
/// γ̇. Defined even when the window is too short for a complete half revolution (the class is
/// then Undetermined); for a tumbling cell it is the small residual rotation of the membrane
/// relative to the body.
fn membrane_rotation_json(window: &[FrameMotion], rate_si: f64, time_s: f64) -> serde_json::Value {
    let n = window.len() as f64;
    if n < 3.0 {
        return serde_json::Value::Null;
    }
    let (st, sp) = window
        .iter()
        .fold((0.0, 0.0), |(a, b), m| (a + m.time, b + m.tt_phase_rad));
    let (mt, mp) = (st / n, sp / n);
    let (mut num, mut den) = (0.0, 0.0);
    for m in window {
        num += (m.time - mt) * (m.tt_phase_rad - mp);
        den += (m.time - mt).powi(2);
    }
    let hz = -(num / den) / std::f64::consts::TAU / time_s;
    json!({ "frequency_hz": hz, "over_shear_rate": hz / rate_si })
}

fn results(run: &Run, ctx: &RunContext) -> Result<serde_json::Value, RunError> {
    let plan = run.plan;
    let m = &plan.setup.map;
    let (l_um, t_s) = (m.length_m * 1e6, m.time_s);
    let rate_si = plan.s.shear_rate();
    let cell = &run.sim.extension().1;
    let stats = cell.stats();
    let mut csv = String::from(
        "time_s,strain,centroid_x_um,centroid_y_um,centroid_z_um,inclination_deg,in_plane_anisotropy,taylor_deformation,tt_phase_rad,area_deviation,volume_deviation\n",
    );
    for s in &run.st.samples {
        let c = s.motion.centroid;
        csv += &format!(
            "{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e}\n",
            s.motion.time * t_s,
            s.motion.time * plan.rate,
            c[0] * l_um,
            c[1] * l_um,
            c[2] * l_um,
            s.motion.inclination_deg,
            s.motion.in_plane_anisotropy,
            s.taylor_deformation,
            s.motion.tt_phase_rad,
            s.area_deviation,
            s.volume_deviation,
        );
    }
    let path = ctx.out_dir.join("motion.csv");
    std::fs::write(&path, csv).map_err(|source| RunError::Io { path, source })?;
    let start = plan.s.analysis_start_strain() / plan.rate;
    let window: Vec<FrameMotion> = run
        .st
        .samples
        .iter()
        .filter(|s| s.motion.time >= start)
        .map(|s| s.motion)
        .collect();
    let analysis = if window.len() >= 2 {
        motion::classify(&window, plan.rate, &MotionThresholds::default())
            .map(|a| motion_json(&a, rate_si, t_s))
            .unwrap_or_else(|e| json!({ "class": "Undetermined", "error": e.to_string() }))
    } else {
        json!({ "class": "Undetermined", "error": "fewer than 2 samples in the analysis window" })
    };
    let in_window: Vec<&ShearSample> = run.st.samples.iter().filter(|s| s.motion.time >= start).collect();
    let mean =
        |f: &dyn Fn(&ShearSample) -> f64| in_window.iter().map(|s| f(s)).sum::<f64>() / in_window.len().max(1) as f64;
    let (a_max, v_max) = run.st.samples.iter().fold((0.0f64, 0.0f64), |(a, b), s| {
        (a.max(s.area_deviation.abs()), b.max(s.volume_deviation.abs()))
    });
    let y0 = run.st.samples.first().map(|s| s.motion.centroid[1]).unwrap_or(f64::NAN);
    let y1 = run.st.samples.last().map(|s| s.motion.centroid[1]).unwrap_or(f64::NAN);
    let steps = run.sim.step_count() as f64;
    let sim_s = steps * plan.setup.dt * t_s;
    let mut performance = performance_json(&run.sim, run.st.stepping_seconds, &run.clock);
    let secs = performance["stepping_seconds"].as_f64().unwrap_or(f64::NAN);
    performance["seconds_per_simulated_second"] = json!(secs / sim_s.max(1e-300));
    performance["seconds_per_unit_strain"] = json!(secs / (steps * plan.setup.dt * plan.rate).max(1e-300));
    let mut out = common_blocks(plan, stats, &run.mesh_info);
    out["shear"] = json!({
        "driver": plan.s.shear.driver,
        "shear_rate_per_s": rate_si,
        "shear_stress_pa": rate_si * plan.s.fluid.outer_viscosity_pa_s,
        "outer_viscosity_pa_s": plan.s.fluid.outer_viscosity_pa_s,
        "inner_viscosity_pa_s": plan.s.fluid.inner_viscosity_pa_s,
        "strain": steps * plan.setup.dt * plan.rate,
        "analysis_start_strain": plan.s.analysis_start_strain(),
        "model_shear_rate": plan.rate,
        "measured_fluid_shear_rate_per_s": mean(&|s| s.fluid_shear_rate) / t_s,
        "measured_note": "least-squares slope dv_x/dy of the plasma particles, mean over the analysis window (the cell disturbs it locally)",
    });
    out["motion"] = analysis;
    out["membrane_rotation"] = membrane_rotation_json(&window, rate_si, t_s);
    out["cell"] = json!({
        "mean_taylor_deformation": mean(&|s| s.taylor_deformation),
        "max_abs_area_deviation": a_max,
        "max_abs_volume_deviation": v_max,
        "centroid_drift_y_um": (y1 - y0) * l_um,
    });
    out["model"] = json!({
        "box_rc": plan.box_lengths.to_array(), "particles": run.sim.particles().len(),
        "vertices": cell.vertices().len(), "timestep": plan.setup.dt,
    });
    out["performance"] = performance;
    out["files"] =
        json!({ "time_series": "motion.csv", "trajectory": (plan.frame_every > 0).then_some(TRAJECTORY_FILE) });
    Ok(out)
}

/// Runs (or, with a checkpoint, resumes) a shear scenario.
pub fn run_from(
    s: &ShearScenario,
    ctx: &RunContext,
    checkpoint: Option<&Checkpoint>,
) -> Result<serde_json::Value, RunError> {
    let plan = Plan::new(s)?;
    let (sim, rest, st, info) = match checkpoint {
        Some(ck) => {
            let r = restore_cell_run::<ShearState>(&plan, "shear", ck)?;
            (r.sim, r.rest, r.progress, r.mesh_info)
        }
        None => {
            let (sim, rest, info) = build(&plan)?;
            (sim, rest, ShearState::default(), info)
        }
    };
    let motion_err = |e: motion::MotionError| RunError::Output(format!("motion tracker: {e}"));
    let tracker = if st.tracker.frames > 0 {
        let x: Vec<DVec3> = st.tracker_vertices.iter().map(|p| DVec3::from_array(*p)).collect();
        MotionTracker::resume(&x, &st.tracker).map_err(motion_err)?
    } else {
        MotionTracker::new(&rest.vertices).map_err(motion_err)?
    };
    let traj = if plan.frame_every > 0 {
        let meta = || {
            RunMetadata::new("shear", plan.toml.clone(), s.seed, plan.setup.map.unit_system())
                .with_extra("shear_rate_per_s", MetaValue::F64(s.shear_rate()))
                .with_extra("particle_types", MetaValue::Str("membrane frames only".into()))
        };
        Some(open_cell_trajectory(
            ctx,
            checkpoint,
            plan.frame_every,
            meta,
            &sim,
            &rest,
        )?)
    } else {
        None
    };
    let clock = StepClock::start(sim.step_count());
    let mut run = Run {
        plan: &plan,
        sim,
        rest,
        tracker,
        st,
        traj,
        mesh_info: info,
        clock,
    };
    if ctx.progress {
        for w in &plan.setup.map.warnings {
            eprintln!("warning: {w}");
        }
    }
    driver::drive(&mut run, ctx, checkpoint.is_some(), s.output.checkpoint_every_steps)?;
    let r = results(&run, ctx)?;
    if let Some(w) = run.traj.take() {
        w.close().map_err(out_err)?;
    }
    Ok(r)
}

// ---------------------------------------------------------------------------------------------
// Analysis of a trajectory after the run

/// The motion of a shear trajectory's membrane frames (SI: seconds, µm, degrees), per frame,
/// and its classification over the frames after `start_strain` (default: a third of the run).
/// The material reference is the first frame.
pub fn analyze_trajectory(
    path: &std::path::Path,
    start_strain: Option<f64>,
) -> Result<(Vec<FrameMotion>, serde_json::Value), RunError> {
    use hemodpd_io::TrajectoryReader;
    let r = TrajectoryReader::open(path).map_err(out_err)?;
    let meta = r.metadata();
    if meta.scenario_name != "shear" {
        return Err(RunError::Output(format!(
            "{}: a {} trajectory, not a shear one",
            path.display(),
            meta.scenario_name
        )));
    }
    let rate = match meta.extra("shear_rate_per_s") {
        Some(MetaValue::F64(r)) => *r,
        _ => {
            return Err(RunError::Output(format!(
                "{}: no shear_rate_per_s attribute",
                path.display()
            )))
        }
    };
    let n = r.membrane_frames().map_err(out_err)?;
    let mut times = Vec::with_capacity(n);
    let mut frames = Vec::with_capacity(n);
    for i in 0..n {
        let fr = r.membrane_frame(i).map_err(out_err)?;
        times.push(fr.time);
        frames.push(fr.positions.iter().map(|p| *p * 1e6).collect::<Vec<DVec3>>());
    }
    if frames.len() < 2 {
        return Err(RunError::Output(format!(
            "{}: {} membrane frames; the motion needs at least 2",
            path.display(),
            frames.len()
        )));
    }
    let err = |e: motion::MotionError| RunError::Output(format!("{}: {e}", path.display()));
    let series = motion::motion_series(&times, &frames, &frames[0]).map_err(err)?;
    let t_end = times[times.len() - 1] - times[0];
    let start = start_strain.unwrap_or(rate * t_end / 3.0) / rate + times[0];
    let window: Vec<FrameMotion> = series.iter().filter(|m| m.time >= start).copied().collect();
    let a = motion::classify(&window, rate, &MotionThresholds::default()).map_err(err)?;
    Ok((series, motion_json(&a, rate, 1.0)))
}

/// Writes per-frame motion (SI) as CSV.
pub fn write_motion_csv(path: &std::path::Path, rows: &[FrameMotion]) -> Result<(), RunError> {
    let mut s = String::from(
        "time_s,centroid_x_um,centroid_y_um,centroid_z_um,inclination_deg,in_plane_anisotropy,tt_phase_rad\n",
    );
    for m in rows {
        s += &format!(
            "{:e},{:e},{:e},{:e},{:e},{:e},{:e}\n",
            m.time,
            m.centroid[0],
            m.centroid[1],
            m.centroid[2],
            m.inclination_deg,
            m.in_plane_anisotropy,
            m.tt_phase_rad
        );
    }
    std::fs::write(path, s).map_err(|source| RunError::Io {
        path: path.to_path_buf(),
        source,
    })
}

impl crate::kind::Kind for ShearScenario {
    const NAME: &'static str = "shear";
    const SWEEP_COLUMNS: &'static [crate::kind::SweepColumn] = &[
        ("stress (Pa)", "/shear/shear_stress_pa", false),
        ("Ca", "/groups_si/capillary_number", false),
        ("class", "/motion/class", false),
        ("TTF/rate", "/motion/tank_treading_frequency_over_shear_rate", false),
        ("flips/s", "/motion/tumbling_rate_flips_per_s", false),
        ("incl (deg)", "/motion/mean_inclination_deg", false),
        ("swing (deg)", "/motion/inclination_amplitude_deg", false),
    ];
    fn validate(&self, file: &str) -> Result<(), ScenarioError> {
        validate(self, file)
    }
    fn seed(&self) -> u64 {
        self.seed
    }
    fn set_base_dir(&mut self, dir: std::path::PathBuf) {
        self.base_dir = dir;
    }
    fn check_files(&self, file: &str) -> Result<(), ScenarioError> {
        self.cell.check_mesh_file(file, &self.base_dir)
    }
    fn schedule_end(&self) -> (u64, &'static str) {
        (Plan::new(self).map(|p| p.steps).unwrap_or(u64::MAX), "steps")
    }
    fn run_from(
        &self,
        ctx: &RunContext,
        checkpoint: Option<&hemodpd_io::checkpoint::Checkpoint>,
    ) -> Result<serde_json::Value, RunError> {
        run_from(self, ctx, checkpoint)
    }
    fn explain_units(&self) -> Option<Result<String, RunError>> {
        Some(ShearScenario::explain_units(self))
    }
    fn unit_mapping_json(&self) -> Option<Result<serde_json::Value, RunError>> {
        Some(
            self.mapping()
                .map(|(sys, d)| crate::cell::summary::mapping_json(&sys, &d)),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn taylor_deformation_of_an_ellipse() {
        // L/B = 2: λ1/λ2 = 4, a = 3/5, D = 1/3
        assert!((taylor_deformation(0.6) - 1.0 / 3.0).abs() < 1e-12);
        assert_eq!(taylor_deformation(0.0), 0.0);
    }
}
