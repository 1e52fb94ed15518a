//! `kind = "capillary"`: one red blood cell in a tube of plasma (Pivkin & Karniadakis 2008,
//! Fig. 3), in SI units (docs/capillary.md); a kind of the cell-in-flow family ([`crate::cell`]:
//! the `[cell]` section, the particle types, the force field, placing the cell, checkpoints).
//!
//! Here is what is the capillary's own: its sections (`[tube]`, `[plasma]`, `[[stage]]`, the
//! flow controller's key of `[model]`), read and validated in `scenario_file.rs`; the plan (the
//! unit mapping of [`crate::units`], the tube's walls cut from an equilibrated fluid, the cell
//! placed on the axis with its symmetry axis along the tube); the stages and the flow
//! controller; the observation (shape measures, velocities, area, volume, membrane temperature,
//! the plasma's density either side of the cell, crossings) and the results, with the Hochmuth
//! fit (`measures.rs`). The stepping loop, frames, checkpoints and Ctrl-C are
//! [`crate::driver`]'s.

mod measures;
mod scenario_file;
pub use measures::{
    analyze_trajectory, decay_time, density_across_cell, fit_hochmuth, length_over_width, shape_class,
    write_measures_csv, FrameMeasures, HochmuthFit, DISC_DISTANCE_UM, PARACHUTE_ROUNDNESS, SLIPPER_OFFSET,
};
pub use scenario_file::{
    validate, CapillaryOutput, CapillaryScenario, CapillaryTube, Drive, PlasmaSection, StageSection,
};

use crate::cell::build::{
    cell_membrane_viscosity, cell_mesh_um, check_membrane_timestep, membrane_model, place_cell, CellPlan, CellSetup,
};
use crate::cell::checkpoint::{open_cell_trajectory, restore_cell_run, save_cell_run, CheckpointHead, Restored};
use crate::cell::placement::{capsule_radius, press_into_tube, CAPSULE_MARGIN, CLEARANCE_RC};
use crate::cell::section::{cell_mapping, cell_params, validate_cell, validate_model, ModelKeys};
use crate::cell::summary::{common_blocks, performance_json, StepClock};
use crate::cell::{CellOrientation, CellSection, CellSim};
use crate::context::{RunContext, RunError};
use crate::driver::{self, Stepper};
use crate::file::ScenarioError;
use crate::run_dir::{engine_err, out_err, TRAJECTORY_FILE};
use crate::units::{self, um_to_m, FluidDecision, FluidModel, PhysicalSystem, MMHG_PER_MM_IN_PA_PER_M};
use glam::DVec3;
use hemodpd_engine::walls::{self, WallSetup, WallShape};
use hemodpd_engine::SimConfig;
use hemodpd_io::checkpoint::Checkpoint;
use hemodpd_io::{FrameScalar, GridSpec, MetaValue, Quantity, RunMetadata, TrajectoryWriter, UnitSystem};
use hemodpd_membrane::cellshape::{self, RestProfile, ShapeMetrics};
use hemodpd_membrane::params::ModelParams;
use hemodpd_membrane::shape::EvansFung;
use hemodpd_membrane::viscosity::MembraneViscosity;
use hemodpd_membrane::{MembraneModel, Mesh};
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::path::PathBuf;

pub use crate::cell::{describe_engine_error, INNER, MEMBRANE, OUTER, WALL};

/// Axis of the tube (z).
const AXIS: usize = 2;

// ---------------------------------------------------------------------------------------------
// The build

/// Everything derived from the file: the mapping and the model-unit geometry.
pub struct Plan<'a> {
    pub s: &'a CapillaryScenario,
    /// The system, the fluid and mapping chosen for it, the time step and the sub-steps.
    pub setup: CellSetup,
    /// Tube radius (the physical one mapped) and length, rc.
    pub radius: f64,
    /// Radius of the wall surface, rc: the effective no-slip radius of the flow is `radius`
    /// ([`wall_radius`]).
    pub wall_radius: f64,
    pub length: f64,
    pub box_lengths: DVec3,
    pub shape: WallShape,
    /// Steps of each stage (its longest duration).
    pub stage_steps: Vec<u64>,
    pub frame_every: u64,
    toml: String,
}

impl<'a> Plan<'a> {
    pub fn new(s: &'a CapillaryScenario) -> Result<Self, RunError> {
        let mut setup = CellSetup::new(s.physical()?, s.model.shared(), &s.cell)?;
        if let Some(w) = pressed_compression_warning(s.tube.diameter_m(), &setup) {
            setup.map.warnings.push(w);
        }
        let (map, fluid, dt) = (&setup.map, &setup.fluid, setup.dt);
        let radius = map.length_to_model(0.5 * s.tube.diameter_m());
        let length = map.length_to_model(s.tube.length_m());
        let rc = fluid.pair.rc;
        let wall_r = wall_radius(radius, fluid.wall_slip);
        // wall thickness rc plus half an rc of margin on each side
        let side = 2.0 * (wall_r + 1.5 * rc);
        let box_lengths = DVec3::new(side, side, length);
        let shape = WallShape::Cylinder {
            axis: AXIS,
            centre: [0.5 * side, 0.5 * side],
            radius: wall_r,
        };
        let steps = |t_s: f64| (map.time_to_model(t_s) / dt).round().max(1.0) as u64;
        let stage_steps = s.stage.iter().map(|st| steps(st.duration_s)).collect();
        let frame_every = if s.output.frame_every_s > 0.0 {
            steps(s.output.frame_every_s)
        } else {
            0
        };
        Ok(Plan {
            s,
            setup,
            radius,
            wall_radius: wall_r,
            length,
            box_lengths,
            shape,
            stage_steps,
            frame_every,
            toml: toml::to_string(s).unwrap_or_default(),
        })
    }

    /// Steps of the whole protocol at most.
    pub fn max_steps(&self) -> u64 {
        self.stage_steps.iter().sum()
    }

    /// The tube axis point (x, y) the cell is centred on, and the z of its centre.
    fn cell_centre(&self) -> DVec3 {
        DVec3::new(0.5 * self.box_lengths.x, 0.5 * self.box_lengths.y, 0.5 * self.length)
    }

    /// The resting mesh in µm (generated and cached, or the user's), on its principal axes.
    fn mesh_um(&self) -> Result<(Mesh, serde_json::Value), RunError> {
        cell_mesh_um(&self.s.cell, self.s.seed, &self.s.base_dir)
    }

    /// The resting mesh in model units, turned to `tube.cell_orientation` (face-on: symmetry
    /// axis along the tube), centred on the axis.
    fn rest_mesh(&self) -> Result<(Mesh, serde_json::Value), RunError> {
        let (mut mesh, info) = self.mesh_um()?;
        let scale = 1e-6 / self.setup.map.length_m;
        let c = self.cell_centre();
        let turn = self.s.tube.cell_orientation.turn(self.s.seed);
        for v in mesh.vertices.iter_mut() {
            *v = turn(*v) * scale + c;
        }
        Ok((mesh, info))
    }

    /// Where the vertices start: the resting mesh when it fits the tube (within the wall's
    /// repulsion range of the wall surface), else the cell pressed into the radius that leaves
    /// the range and a clearance of [`CLEARANCE_RC`] free ([`press_into_tube`]). With what was
    /// done, for `summary.json`.
    fn start_positions(&self, model: &MembraneModel, rest: &Mesh) -> Result<(Vec<DVec3>, serde_json::Value), RunError> {
        let c = self.cell_centre();
        let centre = [c.x, c.y];
        let rc = self.setup.fluid.pair.rc;
        let range = self.s.model.wall_repulsion_range_rc * rc;
        let orientation = serde_json::to_value(self.s.tube.cell_orientation).unwrap_or_default();
        let widest = hemodpd_membrane::confine::widest(&rest.vertices, centre);
        if widest <= self.wall_radius - range {
            return Ok((
                rest.vertices.clone(),
                json!({ "orientation": orientation, "pressed": false, "widest_at_rest_rc": widest }),
            ));
        }
        let radius = self.wall_radius - range - CLEARANCE_RC * rc;
        let (x, mut info) = press_into_tube(model, &rest.vertices, centre, radius)?;
        info["orientation"] = orientation;
        Ok((x, info))
    }

    fn model(&self, rest: &Mesh) -> Result<MembraneModel, RunError> {
        membrane_model(&self.s.cell, &self.setup.map, rest)
    }

    /// The membrane viscosity in model units (Fedosov's γ_C = γ_T/3), or `None` when
    /// `cell.membrane_viscosity_pa_s_m` is 0.
    pub fn membrane_viscosity(&self) -> Option<MembraneViscosity> {
        cell_membrane_viscosity(&self.s.cell, &self.setup.map)
    }

    /// Body force per fluid particle (model) for a pressure gradient (SI): f = ∇p/n.
    fn body_force_for_gradient(&self, g_pa_per_m: f64) -> f64 {
        self.setup.map.pressure_gradient_to_model(g_pa_per_m) / self.setup.fluid.density
    }

    /// Poiseuille body force for a mean velocity U (model): f = 8ηU/(nR²).
    fn poiseuille_force(&self, u: f64) -> f64 {
        8.0 * self.setup.fluid.viscosity * u / (self.setup.fluid.density * self.radius * self.radius)
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
        self.s.plasma.viscosity_ratio
    }
    fn seed(&self) -> u64 {
        self.s.seed
    }
    fn box_lengths(&self) -> DVec3 {
        self.box_lengths
    }
    fn sim_config(&self) -> SimConfig {
        self.setup.sim_config(self.box_lengths, self.s.seed)
    }
    fn wall_shape(&self) -> Option<WallShape> {
        Some(self.shape)
    }
}

/// The wall radius R_w whose flow carries the flux of a no-slip tube of radius `radius` when
/// the fluid slips by `slip` at the wall: R_w⁴ (1 + 4b/R_w) = R⁴ (Newton; R_w ≈ R − b).
pub fn wall_radius(radius: f64, slip: f64) -> f64 {
    let target = radius.powi(4);
    let mut r = radius - slip;
    for _ in 0..20 {
        let f = r.powi(4) + 4.0 * slip * r.powi(3) - target;
        let df = 4.0 * r.powi(3) + 12.0 * slip * r * r;
        r -= f / df;
    }
    r
}

/// Mean axial velocity of the flow over the tube's cross-section πR² (the flux over the area):
/// the particles' mean velocity fills πR_w², so ū·(R_w/R)².
fn flux_velocity(plan: &Plan, particle_mean: f64) -> f64 {
    particle_mean * (plan.wall_radius / plan.radius).powi(2)
}

/// The simulation of a capillary run (its walls are always there).
pub type CapillarySim = CellSim;

/// Fraction of the vertices at each end that a stage's `stretch_force_n` pulls (the paper's
/// optical-tweezers contact, as in the stretching scenario).
const STRETCH_END_FRACTION: f64 = 0.05;

/// Builds the simulation at step 0: the tube's walls cut from an equilibrated fluid, the cell
/// on the axis.
fn build(plan: &Plan) -> Result<(CapillarySim, Mesh, serde_json::Value), RunError> {
    // before the fluid is built: cheap, and a failure names the fix
    let (rest, mut info) = plan.rest_mesh()?;
    let model = plan.model(&rest)?;
    check_membrane_timestep(plan, &model, &rest)?;
    let (start, placement) = plan.start_positions(&model, &rest)?;
    info["placement"] = placement;
    let setup = WallSetup {
        shape: plan.shape,
        pair: plan.setup.fluid.pair,
        density: plan.setup.fluid.density,
        thickness: plan.setup.fluid.pair.rc,
        equilibration_steps: 200,
    };
    let (_, base) = walls::build(&plan.sim_config(), &setup, plan.s.seed).map_err(engine_err)?;
    let sim = place_cell(plan, &base, &rest, &start, model, None)?;
    Ok((sim, rest, info))
}

// ---------------------------------------------------------------------------------------------
// Observation

/// One sample, model units.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    pub step: u64,
    pub stage: usize,
    /// Time since the stage began.
    pub stage_time: f64,
    pub shape: ShapeMetrics,
    /// Mean axial velocity of the vertices.
    pub cell_velocity: f64,
    /// Mean axial velocity of all fluid (plasma and cytosol).
    pub fluid_velocity: f64,
    /// (A − A0)/A0 and (V − V0)/V0.
    pub area_deviation: f64,
    pub volume_deviation: f64,
    /// kBT of the vertices (peculiar to their mean velocity), model energy units.
    pub membrane_kbt: f64,
    /// Body force per fluid particle.
    pub body_force: f64,
    /// In-plane length over width of the cell, L/W ([`length_over_width`]).
    #[serde(default)]
    pub length_over_width: f64,
    /// Distance of the cell's centroid from the tube axis.
    #[serde(default)]
    pub axis_offset: f64,
    /// Plasma density behind and ahead of the cell over the fluid's
    /// ([`density_across_cell`]).
    #[serde(default)]
    pub density_behind: f64,
    #[serde(default)]
    pub density_ahead: f64,
}

fn observe(
    plan: &Plan,
    sim: &CapillarySim,
    rest: &RestProfile,
    stage: usize,
    stage_time: f64,
    body_force: f64,
) -> Sample {
    let cell = &sim.extension().1;
    let x = cell.vertices();
    let p = sim.particles();
    let vr = cell.vertex_range();
    let n = x.len() as f64;
    let vmean = p.vel[vr.clone()].iter().fold(DVec3::ZERO, |a, v| a + *v) / n;
    let m = sim.field().types()[MEMBRANE as usize].mass;
    let kin: f64 = p.vel[vr.clone()].iter().map(|v| (*v - vmean).length_squared()).sum();
    let membrane_kbt = m * kin / (3.0 * (n - 1.0));
    let (mut sum, mut count) = (0.0, 0usize);
    for (v, &t) in p.vel.iter().zip(&p.ptype) {
        if t == OUTER || t == INNER {
            sum += v[AXIS];
            count += 1;
        }
    }
    let model = cell.model();
    let (a, vol) = model.area_volume(x).unwrap_or((f64::NAN, f64::NAN));
    let shape = cellshape::metrics(x, AXIS, rest);
    let axis = plan.cell_centre();
    let (density_behind, density_ahead) = density_across_cell(
        (plan.length, plan.wall_radius, plan.setup.fluid.density),
        &p.pos,
        &p.ptype,
        x,
    );
    Sample {
        step: sim.step_count(),
        stage,
        stage_time,
        axis_offset: (shape.centroid[0] - axis.x).hypot(shape.centroid[1] - axis.y),
        shape,
        length_over_width: length_over_width(x),
        cell_velocity: vmean[AXIS],
        fluid_velocity: flux_velocity(plan, sum / count.max(1) as f64),
        area_deviation: a / model.area0() - 1.0,
        volume_deviation: vol / model.volume0() - 1.0,
        membrane_kbt,
        body_force,
        density_behind,
        density_ahead,
    }
}

/// The mean-velocity controller of a stage: the law of the tube scenario (docs/walls.md) on the
/// body force f: every M steps, e = U − ū (ū: the fluid's mean velocity over the window),
/// I ← I + e·MΔt/τ_v, f = 8η/(nR²)·(e + I), τ_v = nR²/(η j0²). It starts from the Poiseuille
/// force; the integral term supplies the extra force the cell's resistance needs.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Controller {
    pub target: f64,
    pub integral: f64,
    pub window_sum: f64,
    pub window_steps: u64,
}

/// The run's evolving state besides the simulation (checkpointed as JSON).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct ProtocolState {
    pub stage: usize,
    /// Step at which the current stage began.
    pub stage_start: u64,
    /// Body force per fluid particle now.
    pub body_force: f64,
    pub controller: Option<Controller>,
    pub samples: Vec<Sample>,
    /// Steps each finished stage took, and whether it ended steady.
    pub stage_ends: Vec<(u64, bool)>,
    pub finished: bool,
    /// Binned fluid sums since the last frame: count and velocity per bin.
    pub field_count: Vec<f64>,
    pub field_velocity: Vec<f64>,
    pub stepping_seconds: f64,
}

/// Bins of the fluid field: ~1 rc in each direction.
fn field_grid(plan: &Plan) -> GridSpec {
    let b = plan.box_lengths;
    let shape = [0, 1, 2].map(|k| (b[k].round() as usize).max(1));
    GridSpec {
        origin: DVec3::ZERO,
        spacing: DVec3::new(b.x / shape[0] as f64, b.y / shape[1] as f64, b.z / shape[2] as f64),
        shape,
    }
}

/// One measure of a [`Sample`], for the steadiness test.
type Measure<'a> = &'a dyn Fn(&Sample) -> f64;

/// A running capillary scenario (the [`Stepper`] of [`driver::drive`]).
pub struct Run<'a> {
    plan: &'a Plan<'a>,
    sim: CapillarySim,
    rest: Mesh,
    profile: RestProfile,
    st: ProtocolState,
    traj: Option<TrajectoryWriter>,
    grid: GridSpec,
    mesh_info: serde_json::Value,
    clock: StepClock,
}

impl Run<'_> {
    fn stage(&self) -> &StageSection {
        &self.plan.s.stage[self.st.stage]
    }

    /// Sets the stage's drive at its start.
    fn start_stage(&mut self) -> Result<(), RunError> {
        let plan = self.plan;
        let drive = self.stage().drive();
        let (force, ctl) = match drive {
            Drive::Off => (0.0, None),
            Drive::PressureGradient(g) => (plan.body_force_for_gradient(g), None),
            Drive::MeanVelocity(u) => {
                let um = plan.setup.map.velocity_to_model(u);
                (
                    plan.poiseuille_force(um),
                    Some(Controller {
                        target: um,
                        ..Default::default()
                    }),
                )
            }
        };
        self.st.body_force = force;
        self.st.controller = ctl;
        self.apply_stretch()?;
        self.apply_force()
    }

    /// Sets the stage's optical-tweezers forces on the cell (a function of the stage alone, so
    /// it is set again on resume).
    fn apply_stretch(&mut self) -> Result<(), RunError> {
        let f_n = self.stage().stretch_force_n.unwrap_or(0.0);
        let forces = if f_n > 0.0 {
            let (high, low) = hemodpd_membrane::stretch::loaded_vertices(&self.rest.vertices, STRETCH_END_FRACTION);
            let f = self.plan.setup.map.force_to_model(f_n);
            let mut v: Vec<(u32, DVec3)> = high
                .iter()
                .map(|&k| (k as u32, DVec3::new(f / high.len() as f64, 0.0, 0.0)))
                .collect();
            v.extend(
                low.iter()
                    .map(|&k| (k as u32, DVec3::new(-f / low.len() as f64, 0.0, 0.0))),
            );
            v
        } else {
            Vec::new()
        };
        self.sim
            .extension_mut()
            .1
            .set_external_forces(forces)
            .map_err(engine_err)
    }

    fn apply_force(&mut self) -> Result<(), RunError> {
        let f = DVec3::new(0.0, 0.0, self.st.body_force);
        self.sim.set_body_force(OUTER as usize, f).map_err(engine_err)?;
        self.sim.set_body_force(INNER as usize, f).map_err(engine_err)
    }

    fn control(&mut self) -> Result<(), RunError> {
        let plan = self.plan;
        let every = plan.s.model.flow_control_every_steps;
        let Some(c) = self.st.controller.as_mut() else {
            return Ok(());
        };
        let p = self.sim.particles();
        let (mut sum, mut n) = (0.0, 0usize);
        for (v, &t) in p.vel.iter().zip(&p.ptype) {
            if t == OUTER || t == INNER {
                sum += v[AXIS];
                n += 1;
            }
        }
        c.window_sum += flux_velocity(plan, sum / n.max(1) as f64);
        c.window_steps += 1;
        if c.window_steps >= every {
            let mean = c.window_sum / c.window_steps as f64;
            let (eta, nr2) = (
                plan.setup.fluid.viscosity,
                plan.setup.fluid.density * plan.radius * plan.radius,
            );
            let tau_v = nr2 / (eta * 2.404_825_557_695_773_f64.powi(2));
            let e = c.target - mean;
            c.integral += e * every as f64 * plan.setup.dt / tau_v;
            self.st.body_force = 8.0 * eta / nr2 * (e + c.integral);
            c.window_sum = 0.0;
            c.window_steps = 0;
            if !self.st.body_force.is_finite() || mean.abs() > 10.0 * c.target.abs() + 1.0 {
                return Err(RunError::Engine(format!(
                    "flow controller diverged at step {}: mean velocity {mean:.4} (model) for a target of {:.4}",
                    self.sim.step_count(),
                    c.target
                )));
            }
            self.apply_force()?;
        }
        Ok(())
    }

    /// Whether the current stage is steady: the last two windows' means of its measures differ
    /// by less than the tolerance times their scales (velocities: the stage's or the run's
    /// characteristic velocity; lengths: D0).
    fn steady(&self) -> bool {
        let st = self.stage();
        if !st.until_steady {
            return false;
        }
        let plan = self.plan;
        let window_s = st.steady_window_s.unwrap_or(0.1 * st.duration_s);
        let w = (plan.setup.map.time_to_model(window_s) / plan.setup.dt / plan.s.output.sample_every_steps as f64)
            .round() as usize;
        let w = w.max(2);
        let cur: Vec<&Sample> = self.st.samples.iter().filter(|s| s.stage == self.st.stage).collect();
        if cur.len() < 2 * w {
            return false;
        }
        let (a, b) = (&cur[cur.len() - 2 * w..cur.len() - w], &cur[cur.len() - w..]);
        let mean = |s: &[&Sample], f: &dyn Fn(&Sample) -> f64| s.iter().map(|x| f(x)).sum::<f64>() / s.len() as f64;
        let u = plan
            .setup
            .map
            .velocity_to_model(plan.s.characteristic_velocity())
            .max(1e-12);
        let d0 = plan.setup.map.length_to_model(plan.setup.sys.cell_diameter_m);
        let measures: [(Measure, f64); 4] = [
            (&|s| s.cell_velocity, u),
            (&|s| s.fluid_velocity, u),
            (&|s| s.shape.axial_length, d0),
            (&|s| s.shape.distance_from_rest, d0),
        ];
        measures
            .iter()
            .all(|(f, scale)| (mean(b, *f) - mean(a, *f)).abs() <= st.steady_tolerance * scale)
    }

    fn accumulate_field(&mut self) {
        let g = self.grid;
        let p = self.sim.particles();
        if self.st.field_count.len() != g.len() {
            self.st.field_count = vec![0.0; g.len()];
            self.st.field_velocity = vec![0.0; 3 * g.len()];
        }
        for (i, (x, v)) in p.pos.iter().zip(&p.vel).enumerate() {
            let t = p.ptype[i];
            if t != OUTER && t != INNER {
                continue;
            }
            let ijk = [0, 1, 2].map(|k| ((x[k] / g.spacing[k]) as usize).min(g.shape[k] - 1));
            let b = g.index(ijk[0], ijk[1], ijk[2]);
            self.st.field_count[b] += 1.0;
            for k in 0..3 {
                self.st.field_velocity[3 * b + k] += v[k];
            }
        }
    }
}

impl Stepper for Run<'_> {
    fn step_count(&self) -> u64 {
        self.sim.step_count()
    }
    fn max_steps(&self) -> u64 {
        self.plan.max_steps()
    }
    fn time(&self) -> f64 {
        self.sim.time()
    }
    fn finished(&self) -> bool {
        self.st.finished
    }

    fn advance(&mut self) -> Result<(), RunError> {
        self.sim.step().map_err(describe_engine_error)?;
        self.control()?;
        let step = self.sim.step_count();
        let plan = self.plan;
        let done_in_stage = step - self.st.stage_start;
        if step.is_multiple_of(plan.s.output.sample_every_steps) {
            let t_obs = std::time::Instant::now();
            let t = done_in_stage as f64 * plan.setup.dt;
            let smp = observe(plan, &self.sim, &self.profile, self.st.stage, t, self.st.body_force);
            if !(smp.shape.axial_length.is_finite() && smp.area_deviation.is_finite()) {
                return Err(RunError::Engine(format!(
                    "step {step}: the cell's shape is no longer finite (membrane vertices); likely cause: the time step is too large for the membrane"
                )));
            }
            self.st.samples.push(smp);
            if plan.frame_every > 0 {
                self.accumulate_field();
            }
            self.clock.output_s += t_obs.elapsed().as_secs_f64();
        }
        let stage_over = done_in_stage >= plan.stage_steps[self.st.stage];
        let steady = step.is_multiple_of(plan.s.output.sample_every_steps) && self.steady();
        if stage_over || steady {
            self.st.stage_ends.push((done_in_stage, steady));
            self.st.stage += 1;
            self.st.stage_start = step;
            if self.st.stage == plan.s.stage.len() {
                self.st.finished = true;
            } else {
                self.start_stage()?;
            }
        }
        Ok(())
    }

    fn frame_due(&self) -> bool {
        let every = self.plan.frame_every;
        every > 0 && self.sim.step_count().is_multiple_of(every)
    }

    fn write_frame(&mut self) -> Result<(), RunError> {
        let t0 = std::time::Instant::now();
        let r = self.write_frame_inner();
        self.clock.output_s += t0.elapsed().as_secs_f64();
        r
    }

    fn flush(&mut self) -> Result<(), RunError> {
        if let Some(w) = self.traj.as_mut() {
            w.flush().map_err(out_err)?;
        }
        Ok(())
    }

    fn save_checkpoint(&mut self, ctx: &RunContext) -> Result<(), RunError> {
        self.save(ctx)
    }
}

impl Run<'_> {
    fn write_frame_inner(&mut self) -> Result<(), RunError> {
        let Some(w) = self.traj.as_mut() else {
            return Ok(());
        };
        let cell = &self.sim.extension().1;
        let vr = cell.vertex_range();
        let p = self.sim.particles();
        let smp = observe(
            self.plan,
            &self.sim,
            &self.profile,
            self.st.stage.min(self.plan.s.stage.len() - 1),
            0.0,
            self.st.body_force,
        );
        let scalars = [
            FrameScalar {
                name: "cell_velocity",
                value: smp.cell_velocity,
                quantity: Quantity::Velocity,
            },
            FrameScalar {
                name: "fluid_velocity",
                value: smp.fluid_velocity,
                quantity: Quantity::Velocity,
            },
            FrameScalar {
                name: "axial_length",
                value: smp.shape.axial_length,
                quantity: Quantity::Length,
            },
            FrameScalar {
                name: "deformation_index",
                value: smp.shape.deformation_index,
                quantity: Quantity::Dimensionless,
            },
            FrameScalar {
                name: "stage",
                value: smp.stage as f64,
                quantity: Quantity::Dimensionless,
            },
        ];
        let (step, time) = (self.sim.step_count(), self.sim.time());
        w.append_membrane_frame(step, time, cell.vertices(), Some(&p.vel[vr]), &scalars)
            .map_err(out_err)?;
        let g = self.grid;
        if self.st.field_count.len() == g.len() {
            let mut vel = vec![0.0; 3 * g.len()];
            let mut dens = vec![0.0; g.len()];
            let nsamples = (self.plan.frame_every / self.plan.s.output.sample_every_steps).max(1) as f64;
            let vol = g.spacing.x * g.spacing.y * g.spacing.z;
            for b in 0..g.len() {
                let c = self.st.field_count[b];
                dens[b] = c / (nsamples * vol);
                for k in 0..3 {
                    vel[3 * b + k] = if c > 0.0 {
                        self.st.field_velocity[3 * b + k] / c
                    } else {
                        0.0
                    };
                }
            }
            w.append_field("density", step, time, &g, 1, &dens, Quantity::NumberDensity)
                .map_err(out_err)?;
            w.append_field("velocity", step, time, &g, 3, &vel, Quantity::Velocity)
                .map_err(out_err)?;
            self.st.field_count.iter_mut().for_each(|x| *x = 0.0);
            self.st.field_velocity.iter_mut().for_each(|x| *x = 0.0);
        }
        Ok(())
    }

    fn save(&mut self, ctx: &RunContext) -> Result<(), RunError> {
        self.clock.checkpoint(&mut self.st.stepping_seconds);
        let head = CheckpointHead {
            kind: "capillary",
            seed: self.plan.s.seed,
            toml: &self.plan.toml,
            base_dir: &self.plan.s.base_dir,
            finished: Some(self.st.finished),
        };
        save_cell_run(&self.sim, &head, &self.st, &self.rest, &self.mesh_info, ctx)
    }
}

/// The run saved in `ck`, with the body force of its protocol state set again.
fn restore(plan: &Plan, ck: &Checkpoint) -> Result<Restored<ProtocolState>, RunError> {
    let mut r: Restored<ProtocolState> = restore_cell_run(plan, "capillary", ck)?;
    let f = DVec3::new(0.0, 0.0, r.progress.body_force);
    r.sim.set_body_force(OUTER as usize, f).map_err(engine_err)?;
    r.sim.set_body_force(INNER as usize, f).map_err(engine_err)?;
    Ok(r)
}

// ---------------------------------------------------------------------------------------------
// Results

/// Mean of `f` over the last quarter of a stage's samples.
fn tail_mean(samples: &[&Sample], f: impl Fn(&Sample) -> f64) -> f64 {
    let n = samples.len();
    if n == 0 {
        return f64::NAN;
    }
    let tail = &samples[n - (n / 4).max(1)..];
    tail.iter().map(|s| f(s)).sum::<f64>() / tail.len() as f64
}

/// Writes `cell.csv`, the time series in SI, from the samples taken so far (also when the run
/// stops on an error: what was measured up to it is kept).
fn write_time_series(run: &Run, ctx: &RunContext) -> Result<(), RunError> {
    let plan = run.plan;
    let m = &plan.setup.map;
    let (l, v, t) = (m.length_m * 1e6, m.velocity_to_si(1.0), m.time_s);
    let fluid_kbt = plan.setup.fluid.pair.kbt;
    let mut csv = String::from(
        "time_s,stage,stage_time_s,cell_velocity_m_per_s,fluid_velocity_m_per_s,axial_length_um,max_radius_um,deformation_index,concavity_depth_um,distance_from_rest_um,area_deviation,volume_deviation,membrane_temperature_ratio,body_force_n,length_over_width,silhouette_width_um,silhouette_deformation_index,symmetry_axis_tilt_deg,axis_offset_um,cross_section_roundness\n",
    );
    for s in &run.st.samples {
        csv += &format!(
            "{:e},{},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e},{:e}\n",
            s.step as f64 * plan.setup.dt * t,
            s.stage,
            s.stage_time * t,
            s.cell_velocity * v,
            s.fluid_velocity * v,
            s.shape.axial_length * l,
            s.shape.max_radius * l,
            s.shape.deformation_index,
            s.shape.concavity_depth * l,
            s.shape.distance_from_rest * l,
            s.area_deviation,
            s.volume_deviation,
            s.membrane_kbt / fluid_kbt,
            s.body_force * m.force_unit_n(),
            s.length_over_width,
            s.shape.silhouette_width * l,
            s.shape.silhouette_deformation_index,
            s.shape.symmetry_axis_tilt_deg,
            s.axis_offset * l,
            s.shape.cross_section_roundness,
        );
    }
    let path = ctx.out_dir.join("cell.csv");
    std::fs::write(&path, csv).map_err(|source| RunError::Io { path, source })?;
    Ok(())
}

fn results(run: &Run, ctx: &RunContext) -> Result<serde_json::Value, RunError> {
    let plan = run.plan;
    let m = &plan.setup.map;
    let (l, v, t) = (m.length_m * 1e6, m.velocity_to_si(1.0), m.time_s);
    let cell = &run.sim.extension().1;
    let stats = cell.stats();
    let fluid_kbt = plan.setup.fluid.pair.kbt;
    let mut stages = Vec::new();
    write_time_series(run, ctx)?;
    for (k, st) in plan.s.stage.iter().enumerate() {
        let smp: Vec<&Sample> = run.st.samples.iter().filter(|s| s.stage == k).collect();
        let (steps, steady) = run.st.stage_ends.get(k).copied().unwrap_or((0, false));
        let ts: Vec<f64> = smp.iter().map(|s| s.stage_time * t).collect();
        let dist: Vec<f64> = smp.iter().map(|s| s.shape.distance_from_rest * l).collect();
        let di: Vec<f64> = smp.iter().map(|s| s.shape.deformation_index).collect();
        let lw: Vec<f64> = smp.iter().map(|s| s.length_over_width).collect();
        let hochmuth = fit_hochmuth(&ts, &lw);
        let (a_max, v_max) = smp.iter().fold((0.0f64, 0.0f64), |(a, b), s| {
            (a.max(s.area_deviation.abs()), b.max(s.volume_deviation.abs()))
        });
        let shape = if st.drive() == Drive::Off {
            "rest"
        } else {
            shape_class(
                tail_mean(&smp, |s| s.axis_offset),
                plan.radius,
                tail_mean(&smp, |s| s.shape.cross_section_roundness),
                tail_mean(&smp, |s| s.shape.distance_from_rest) * l,
            )
        };
        stages.push(json!({
            "name": st.name,
            "duration_s": steps as f64 * plan.setup.dt * t,
            "ended_steady": steady,
            "drive": match st.drive() {
                Drive::Off => json!("off"),
                Drive::MeanVelocity(u) => json!({ "mean_velocity_m_per_s": u }),
                Drive::PressureGradient(g) => json!({ "pressure_gradient_pa_per_m": g, "pressure_gradient_mmhg_per_mm": g / MMHG_PER_MM_IN_PA_PER_M }),
            },
            "final_quarter_means": {
                "cell_velocity_m_per_s": tail_mean(&smp, |s| s.cell_velocity) * v,
                "fluid_mean_velocity_m_per_s": tail_mean(&smp, |s| s.fluid_velocity) * v,
                "axial_length_um": tail_mean(&smp, |s| s.shape.axial_length) * l,
                "max_radial_extent_um": tail_mean(&smp, |s| s.shape.max_radius) * l,
                "deformation_index": tail_mean(&smp, |s| s.shape.deformation_index),
                "silhouette_width_um": tail_mean(&smp, |s| s.shape.silhouette_width) * l,
                "silhouette_deformation_index": tail_mean(&smp, |s| s.shape.silhouette_deformation_index),
                "symmetry_axis_tilt_deg": tail_mean(&smp, |s| s.shape.symmetry_axis_tilt_deg),
                "axis_offset_um": tail_mean(&smp, |s| s.axis_offset) * l,
                "cross_section_roundness": tail_mean(&smp, |s| s.shape.cross_section_roundness),
                "shape": shape,
                "concavity_depth_um": tail_mean(&smp, |s| s.shape.concavity_depth) * l,
                "distance_from_rest_um": tail_mean(&smp, |s| s.shape.distance_from_rest) * l,
                "membrane_temperature_ratio": tail_mean(&smp, |s| s.membrane_kbt) / fluid_kbt,
                "body_force_n": tail_mean(&smp, |s| s.body_force) * m.force_unit_n(),
                "pressure_gradient_pa_per_m": m.pressure_gradient_to_si(tail_mean(&smp, |s| s.body_force) * plan.setup.fluid.density),
                "plasma_density_behind_cell": tail_mean(&smp, |s| s.density_behind),
                "plasma_density_ahead_of_cell": tail_mean(&smp, |s| s.density_ahead),
            },
            "recovery_time_s": {
                "distance_from_rest": decay_time(&ts, &dist),
                "deformation_index": decay_time(&ts, &di),
            },
            "length_over_width": {
                "first": lw.first().copied().unwrap_or(f64::NAN),
                "final_quarter_mean": tail_mean(&smp, |s| s.length_over_width),
                "stretch_force_n": st.stretch_force_n.unwrap_or(0.0),
                "hochmuth_fit": hochmuth.map(|h| json!({
                    "recovery_time_s": h.t_c, "lambda_0": h.lambda_0, "lambda_inf": h.lambda_inf, "rms": h.rms,
                })),
                "note": "in-plane L/W across the tube (capillary::length_over_width); the fit is Hochmuth 1979's Kelvin–Voigt recovery ((λ²−λ∞²)(λ0²+λ∞²))/((λ²+λ∞²)(λ0²−λ∞²)) = exp(−t/t_c) from the stage's first sample (meaningful for a stage that releases a stretch)",
            },
            "max_abs_area_deviation": a_max,
            "max_abs_volume_deviation": v_max,
        }));
    }
    // the last driven stage's means: the headline of a run (what sweeps tabulate)
    let driven = plan
        .s
        .stage
        .iter()
        .rposition(|st| st.drive() != Drive::Off)
        .map(|k| {
            let mut d = stages[k]["final_quarter_means"].clone();
            d["stage"] = json!(plan.s.stage[k].name);
            d
        })
        .unwrap_or(serde_json::Value::Null);
    let mut out = common_blocks(plan, stats, &run.mesh_info);
    let mut performance = performance_json(&run.sim, run.st.stepping_seconds, &run.clock);
    performance["this_session"]["note"] = json!("shares of this session's wall time (since the run started or resumed); the fluid's pair forces, the integrator and the cell lists are the remainder");
    out["model"] = json!({
        "tube_radius_rc": plan.radius, "tube_length_rc": plan.length, "box_rc": plan.box_lengths.to_array(),
        "particles": run.sim.particles().len(), "vertices": cell.vertices().len(), "timestep": plan.setup.dt,
    });
    out["stages"] = json!(stages);
    out["driven"] = driven;
    out["performance"] = performance;
    out["files"] =
        json!({ "time_series": "cell.csv", "trajectory": (plan.frame_every > 0).then_some(TRAJECTORY_FILE) });
    Ok(out)
}

/// Ma²/Re (model) above which a cell pressed into a tube narrower than it is warned of before
/// the run: the capillary fluid's 0.059 in the 4.7 µm tube compressed the fluid by 30 % across
/// the cell and halved its velocity; the dense fluid's 0.0013 held it to 5 % (docs/capillary.md,
/// "Compression across the cell").
const PRESSED_MACH2_OVER_RE_WARNING: f64 = 0.01;

/// The warning, before any work, for a tube of `diameter_m` narrower than the resting cell
/// when the chosen fluid's Ma²/Re exceeds [`PRESSED_MACH2_OVER_RE_WARNING`].
fn pressed_compression_warning(diameter_m: f64, setup: &CellSetup) -> Option<String> {
    if diameter_m >= setup.sys.cell_diameter_m {
        return None;
    }
    let g = units::groups_model(&setup.sys, &setup.map, &setup.fluid);
    let k = g.mach * g.mach / g.reynolds;
    (k > PRESSED_MACH2_OVER_RE_WARNING).then(|| {
        format!(
            "the tube ({:.1} µm) is narrower than the cell ({:.1} µm), and the {} fluid's Ma²/Re = {k:.3} lets the pressure the cell holds compress it (in the 4.7 µm tube by 30 %, which halved the cell's velocity); model.fluid = \"dense\" keeps Ma²/Re below {PRESSED_MACH2_OVER_RE_WARNING} (docs/capillary.md, \"Compression across the cell\")",
            diameter_m * 1e6,
            setup.sys.cell_diameter_m * 1e6,
            setup.fluid.name
        )
    })
}

/// Plasma density difference across the cell (behind less ahead, over the fluid's density)
/// above which a run warns. Measured: 0.16 in the shipped 10 µm default, 0.30 in the 6.6 and
/// 4.7 µm tubes at 10 mmHg/mm, where a lower Mach bound or the dense fluid moved the cell's
/// velocity by 17–28 % (docs/capillary.md, "Compression across the cell").
const COMPRESSION_WARNING: f64 = 0.2;

/// The warning for the last driven stage's means `driven` when the fluid is compressed across
/// the cell by more than [`COMPRESSION_WARNING`].
fn compression_warning(driven: &serde_json::Value) -> Option<String> {
    let behind = driven["plasma_density_behind_cell"].as_f64()?;
    let ahead = driven["plasma_density_ahead_of_cell"].as_f64()?;
    (behind - ahead > COMPRESSION_WARNING).then(|| {
        format!(
            "the plasma is {behind:.2} × its density behind the cell and {ahead:.2} × ahead of it: the model fluid is compressed by the pressure the cell holds, and the cell's velocity may depend on it; compare with a lower model.max_mach or model.fluid = \"dense\" (docs/capillary.md, \"Compression across the cell\")"
        )
    })
}

/// Model → SI units of a capillary run (for the trajectory).
fn unit_system(plan: &Plan) -> UnitSystem {
    plan.setup.map.unit_system()
}

/// Runs (or, with a checkpoint, resumes) a capillary scenario.
pub fn run_from(
    s: &CapillaryScenario,
    ctx: &RunContext,
    checkpoint: Option<&Checkpoint>,
) -> Result<serde_json::Value, RunError> {
    let plan = Plan::new(s)?;
    let (sim, rest, st, info) = match checkpoint {
        Some(ck) => {
            let r = restore(&plan, ck)?;
            (r.sim, r.rest, r.progress, r.mesh_info)
        }
        None => {
            let (sim, rest, info) = build(&plan)?;
            (sim, rest, ProtocolState::default(), info)
        }
    };
    let traj = if plan.frame_every > 0 {
        let meta = || {
            RunMetadata::new("capillary", plan.toml.clone(), s.seed, unit_system(&plan)).with_extra(
                "particle_types",
                MetaValue::Str(
                    "fields from plasma (0) and cytosol (2); membrane frames are the cell's vertices".into(),
                ),
            )
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
    let scale = 1e-6 / plan.setup.map.length_m;
    let profile = RestProfile::new(&EvansFung::healthy_um().scaled(scale), 400);
    let grid = field_grid(&plan);
    let clock = StepClock::start(sim.step_count());
    let mut run = Run {
        plan: &plan,
        sim,
        rest,
        profile,
        st,
        traj,
        grid,
        mesh_info: info,
        clock,
    };
    let resumed = checkpoint.is_some();
    if !resumed {
        run.start_stage()?;
    } else if run.st.stage < plan.s.stage.len() {
        run.apply_stretch()?;
    }
    for w in &plan.setup.map.warnings {
        if ctx.progress {
            eprintln!("warning: {w}");
        }
    }
    if let Err(e) = driver::drive(&mut run, ctx, resumed, s.output.checkpoint_every_steps) {
        // keep what was measured: the time series up to the error (the trajectory holds its
        // frames, the last checkpoint the state before it)
        if !matches!(e, RunError::Interrupted { .. }) && write_time_series(&run, ctx).is_ok() && ctx.progress {
            eprintln!(
                "the time series up to the error is in {}",
                ctx.out_dir.join("cell.csv").display()
            );
        }
        return Err(e);
    }
    let r = results(&run, ctx)?;
    if let Some(w) = compression_warning(&r["driven"]) {
        if ctx.progress {
            eprintln!("warning: {w}");
        }
    }
    if let Some(w) = run.traj.take() {
        w.close().map_err(out_err)?;
    }
    Ok(r)
}

// ---------------------------------------------------------------------------------------------
// Analysis of a trajectory after the run

impl crate::kind::Kind for CapillaryScenario {
    const NAME: &'static str = "capillary";
    const SWEEP_COLUMNS: &'static [crate::kind::SweepColumn] = &[
        ("cell velocity (m/s)", "/driven/cell_velocity_m_per_s", false),
        ("fluid velocity (m/s)", "/driven/fluid_mean_velocity_m_per_s", false),
        ("length (um)", "/driven/axial_length_um", false),
        ("DI", "/driven/deformation_index", false),
        ("DI side view", "/driven/silhouette_deformation_index", false),
        ("shape", "/driven/shape", false),
        ("misplaced", "/crossings/misplaced_total", false),
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
    /// Steps of the longest schedule (stages that end when steady end earlier).
    fn schedule_end(&self) -> (u64, &'static str) {
        (Plan::new(self).map(|p| p.max_steps()).unwrap_or(u64::MAX), "steps")
    }
    fn run_from(
        &self,
        ctx: &RunContext,
        checkpoint: Option<&hemodpd_io::checkpoint::Checkpoint>,
    ) -> Result<serde_json::Value, RunError> {
        run_from(self, ctx, checkpoint)
    }
    fn explain_units(&self) -> Option<Result<String, RunError>> {
        Some(CapillaryScenario::explain_units(self))
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

    /// Hochmuth's form is inverted exactly: a synthetic Kelvin–Voigt recovery (λ0 = 2,
    /// λ∞ = 1.1, t_c = 0.12 s, 25 points over 0.4 s like the experimental series) gives back
    /// t_c and λ∞ to 1e-4; a rising series gives no fit. L/W of a disc is 1, of an ellipse
    /// a/b whatever its angle about the tube axis.
    #[test]
    fn hochmuth_fit_and_length_over_width() {
        let (l0, li, tc) = (2.0f64, 1.1f64, 0.12);
        let k = (l0 * l0 - li * li) / (l0 * l0 + li * li);
        let t: Vec<f64> = (0..25).map(|i| 0.001 + i as f64 * 0.4 / 24.0).collect();
        let lam: Vec<f64> = t
            .iter()
            .map(|&tt| {
                let y = k * (-(tt - 0.001) / tc).exp();
                li * ((1.0 + y) / (1.0 - y)).sqrt()
            })
            .collect();
        let h = fit_hochmuth(&t, &lam).unwrap();
        assert!((h.t_c / tc - 1.0).abs() < 1e-4, "{h:?}");
        assert!((h.lambda_inf / li - 1.0).abs() < 1e-4, "{h:?}");
        let rising: Vec<f64> = lam.iter().rev().cloned().collect();
        assert!(fit_hochmuth(&t, &rising).is_none());
        for angle in [0.0f64, 0.4, 1.3] {
            let pts: Vec<DVec3> = (0..360)
                .map(|i| {
                    let p = (i as f64).to_radians();
                    let (x, y) = (3.0 * p.cos(), 1.5 * p.sin());
                    DVec3::new(
                        x * angle.cos() - y * angle.sin(),
                        x * angle.sin() + y * angle.cos(),
                        0.1 * p.cos(),
                    )
                })
                .collect();
            assert!((length_over_width(&pts) - 2.0).abs() < 1e-3, "angle {angle}");
        }
    }

    /// The 1/e time of an exponential decay towards a level, from samples.
    #[test]
    fn decay_time_of_an_exponential() {
        let t: Vec<f64> = (0..400).map(|k| 0.1 + k as f64 * 1e-4).collect();
        let y: Vec<f64> = t.iter().map(|&t| 0.2 + 0.5 * (-(t - 0.1) / 0.004).exp()).collect();
        let tau = decay_time(&t, &y);
        assert!((tau - 0.004).abs() < 2e-5, "{tau}");
        // a flat series does not decay
        assert!(decay_time(&t, &vec![1.0; 400]).is_nan());
    }

    /// A tube narrower than the cell warns before the run when the fluid's Ma²/Re lets the
    /// cell's pressure compress it: the capillary fluid at 4.7 and 6.6 µm does, the dense
    /// fluid at 4.7 µm and the capillary fluid in the 10 µm default do not.
    #[test]
    fn a_pressed_cell_in_a_compressible_fluid_is_warned_of() {
        let file = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenarios/capillary-tomaiuolo.toml");
        let text = std::fs::read_to_string(file).unwrap();
        let warned = |text: &str, sets: &[&str]| {
            let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
            let crate::registry::Scenario::Capillary(s) = crate::registry::load_str(text, "t.toml", &sets).unwrap()
            else {
                panic!("not a capillary scenario")
            };
            let plan = Plan::new(&s).unwrap();
            plan.setup.map.warnings.iter().any(|w| w.contains("Ma²/Re"))
        };
        let narrow = ["tube.diameter_um=4.7", "model.length_um_per_rc=0.5"];
        assert!(warned(&text, &narrow));
        assert!(warned(&text, &[]));
        assert!(!warned(
            &text,
            &[
                narrow[0],
                narrow[1],
                "model.fluid=\"dense\"",
                "model.thermal_factor=2.08"
            ]
        ));
        let default =
            std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenarios/capillary.toml")).unwrap();
        assert!(!warned(&default, &[]));
    }

    /// The wall radius carries the no-slip flux of the physical radius: R_w⁴(1 + 4b/R_w) = R⁴.
    #[test]
    fn wall_radius_carries_the_physical_flux() {
        for (r, b) in [(5.0, 0.194), (3.0, 0.1), (10.0, 0.3)] {
            let w = wall_radius(r, b);
            let lhs = w.powi(4) * (1.0 + 4.0 * b / w);
            assert!((lhs / r.powi(4) - 1.0).abs() < 1e-12, "{r} {b}: {w}");
            assert!(w < r && w > r - 1.5 * b);
        }
    }
}
