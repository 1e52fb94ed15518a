//! The periodic DPD fluid scenario (`kind = "dpd-fluid"`), in model units: equilibrate, then
//! sample temperature and virial pressure; report means, block-averaged standard errors, and
//! the throughput in particle-steps per second.
//!
//! Output and restarts: frames (particles, binned density and velocity) go to `trajectory.h5`
//! every `output.trajectory_every_steps` production steps; `checkpoint.h5` is written atomically
//! every `output.checkpoint_every_steps` steps, at the end, and on an interrupt (Ctrl-C). A run
//! resumed from a checkpoint continues bit-identically: the engine's pair noise is a function of
//! (seed, step, ids), the saved state includes the last forces, and the sampled series are saved
//! with it. On resume the trajectory is cut back to the last scheduled frame at or before the
//! checkpoint, so it ends up with exactly the frames of an uninterrupted run.
//!
//! The stepping loop (frame and checkpoint cadence, Ctrl-C, progress) is [`crate::driver`]'s;
//! this module supplies the build, the phases and sampling ([`Stepper::advance`]), the frame and
//! the checkpoint.

use crate::context::{RunContext, RunError};
use crate::driver::{self, Stepper};
use crate::file::{
    f_dt, f_lambda, one_u64, validate_fluid_params, validate_output, validate_stepping, Check, FluidSection,
    ScenarioError,
};
use crate::run_dir::{
    self, engine_err, out_err, particles_from_checkpoint, particles_into_checkpoint, CHECKPOINT_FILE, TRAJECTORY_FILE,
};
use glam::DVec3;
use hemodpd_engine::init::{self, FluidSpec, Placement};
use hemodpd_engine::{observe, ForceField, PairParams, SimConfig, SimState, Simulation};
use hemodpd_io::checkpoint::{Checkpoint, ScalarValue};
use hemodpd_io::{GridSpec, RunMetadata, TrajectoryWriter, UnitSystem};
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::time::Instant;

// ---- the scenario file: `[fluid]` (shared, [`FluidSection`]), `[run]`, `[output]` ----

fn twenty() -> u64 {
    20
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

/// Validates a `kind = "dpd-fluid"` scenario.
pub fn validate(s: &FluidScenario, file: &str) -> Result<(), ScenarioError> {
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

/// Groot & Warren (1997), Fig. 4: measured pressure of the standard fluid (ρ = 3, a = 25, kBT = 1).
pub const GROOT_WARREN_PRESSURE_RHO3_A25: f64 = 23.7;

fn config_and_field(s: &FluidScenario) -> (SimConfig, ForceField) {
    let f = &s.fluid;
    let mut config = SimConfig::new(
        DVec3::from_array(f.box_size.unwrap_or([0.0; 3])), /* required by validation */
        s.run.timestep,
        s.seed,
    );
    config.lambda = s.run.lambda;
    // A plain fluid can have its storage kept in cell order, every 10 steps: the fastest setting
    // we measured (docs/performance.md, "Changes tried").
    // Frames are written in id order, so the output does not see it.
    config.sort_every = 10;
    let field = ForceField::single(PairParams {
        a: f.a,
        gamma: f.gamma,
        kbt: f.kbt,
        rc: f.cutoff,
        s: f.weight_exponent,
    });
    (config, field)
}

/// Builds the simulation of a fluid scenario at step 0.
pub fn build(s: &FluidScenario) -> Result<Simulation, RunError> {
    let (config, field) = config_and_field(s);
    let f = &s.fluid;
    let spec = FluidSpec {
        density: f.density,
        ptype: 0,
        kbt: f.kbt,
        placement: Placement::JitteredLattice { jitter: 0.1 },
        first_id: 0,
    };
    let particles = init::fluid(&config, &field, &spec, s.seed).map_err(engine_err)?;
    Simulation::new(config, field, particles).map_err(engine_err)
}

/// The fluid trajectory's units: DPD model units, stored as they are (no SI mapping).
pub fn model_units() -> UnitSystem {
    UnitSystem {
        length_m: 1.0,
        time_s: 1.0,
        energy_j: 1.0,
        label: "DPD model units (rc, kBT, m); no SI mapping".into(),
    }
}

/// Is `step` (counted from 0, equilibration included) a frame of the trajectory schedule?
fn frame_due(s: &FluidScenario, step: u64) -> bool {
    let every = s.output.trajectory_every_steps;
    let eq = s.run.equilibration_steps;
    every > 0 && step >= eq && (step - eq).is_multiple_of(every)
}

/// Sampled series and timing that a checkpoint carries.
#[derive(Default)]
struct Series {
    temperature: Vec<f64>,
    pressure: Vec<f64>,
    production_seconds: f64,
}

fn save_checkpoint(s: &FluidScenario, ctx: &RunContext, sim: &Simulation, series: &Series) -> Result<(), RunError> {
    let p = sim.particles();
    let mut ck = Checkpoint::new(
        sim.step_count(),
        sim.time(),
        s.seed,
        toml::to_string(s).unwrap_or_default(),
    );
    ck.set_scalar("scenario_kind", ScalarValue::Str("dpd-fluid".into()));
    particles_into_checkpoint(&mut ck, p);
    ck.insert_f64("temperature_samples", series.temperature.clone());
    ck.insert_f64("pressure_samples", series.pressure.clone());
    ck.set_scalar("production_seconds", ScalarValue::F64(series.production_seconds));
    run_dir::save_checkpoint(&ck, ctx)
}

fn restore(s: &FluidScenario, ck: &Checkpoint) -> Result<(Simulation, Series), RunError> {
    let (config, field) = config_and_field(s);
    let bad = |e: hemodpd_io::IoError| RunError::Output(format!("checkpoint: {e}"));
    let particles = particles_from_checkpoint(ck)?;
    let state = SimState {
        config,
        field,
        particles,
        step: ck.step,
    };
    let sim = Simulation::from_state(state, ()).map_err(engine_err)?;
    let series = Series {
        temperature: ck.f64s("temperature_samples").map_err(bad)?.to_vec(),
        pressure: ck.f64s("pressure_samples").map_err(bad)?.to_vec(),
        production_seconds: ck.scalar_f64("production_seconds").map_err(bad)?,
    };
    Ok((sim, series))
}

/// Instantaneous density and mean velocity in `bins` slabs along z, as grid fields.
fn binned_fields(sim: &Simulation, bins: usize) -> (GridSpec, Vec<f64>, Vec<f64>) {
    let l = sim.config().box_lengths;
    let dz = l.z / bins as f64;
    let mut count = vec![0.0; bins];
    let mut vel = vec![0.0; 3 * bins];
    let p = sim.particles();
    for (x, v) in p.pos.iter().zip(&p.vel) {
        let k = ((x.z / dz) as usize).min(bins - 1);
        count[k] += 1.0;
        vel[3 * k] += v.x;
        vel[3 * k + 1] += v.y;
        vel[3 * k + 2] += v.z;
    }
    let slab = l.x * l.y * dz;
    for k in 0..bins {
        if count[k] > 0.0 {
            for c in 0..3 {
                vel[3 * k + c] /= count[k];
            }
        }
        count[k] /= slab;
    }
    (
        GridSpec {
            origin: DVec3::ZERO,
            spacing: DVec3::new(l.x, l.y, dz),
            shape: [1, 1, bins],
        },
        count,
        vel,
    )
}

fn write_frame(s: &FluidScenario, w: &mut TrajectoryWriter, sim: &Simulation) -> Result<(), RunError> {
    let p = sim.particles();
    let stride = s.output.particle_stride as usize;
    // In id order: the engine reorders storage now and then (`SimConfig::sort_every`), and a
    // frame's rows must be the same particles in every frame.
    let mut order: Vec<usize> = (0..p.len()).collect();
    order.sort_unstable_by_key(|&i| p.id[i]);
    let rows = || order.iter().step_by(stride).copied();
    let pos: Vec<DVec3> = rows().map(|i| p.pos[i]).collect();
    let vel: Vec<DVec3> = rows().map(|i| p.vel[i]).collect();
    // u16 engine types; a type the file's u8 cannot hold is an error, not a truncation
    let types: Vec<u16> = rows().map(|i| p.ptype[i]).collect();
    w.append_fluid_frame_u16(sim.step_count(), sim.time(), &pos, Some(&vel), Some(&types))
        .map_err(out_err)?;
    if s.output.field_bins > 0 {
        let (grid, rho, vel) = binned_fields(sim, s.output.field_bins as usize);
        w.append_field(
            "density",
            sim.step_count(),
            sim.time(),
            &grid,
            1,
            &rho,
            hemodpd_io::Quantity::NumberDensity,
        )
        .map_err(out_err)?;
        w.append_field(
            "velocity",
            sim.step_count(),
            sim.time(),
            &grid,
            3,
            &vel,
            hemodpd_io::Quantity::Velocity,
        )
        .map_err(out_err)?;
    }
    Ok(())
}

/// A running fluid scenario (the [`Stepper`] of [`driver::drive`]): equilibration, then
/// production with T and p sampled every `run.sample_every` steps.
struct Run<'a> {
    s: &'a FluidScenario,
    sim: Simulation,
    series: Series,
    traj: Option<TrajectoryWriter>,
    /// Production timing: since the later of the production start and the last checkpoint.
    clock: Instant,
}

impl Stepper for Run<'_> {
    fn step_count(&self) -> u64 {
        self.sim.step_count()
    }
    fn max_steps(&self) -> u64 {
        self.s.run.equilibration_steps + self.s.run.steps
    }
    fn time(&self) -> f64 {
        self.sim.time()
    }
    fn finished(&self) -> bool {
        self.sim.step_count() >= self.max_steps()
    }

    fn advance(&mut self) -> Result<(), RunError> {
        let (sim, series) = (&mut self.sim, &mut self.series);
        let step = sim.step_count();
        let eq = self.s.run.equilibration_steps;
        if step == eq {
            self.clock = Instant::now();
        }
        let sample = step >= eq && (step - eq).is_multiple_of(self.s.run.sample_every);
        if sample {
            let virial = sim.step_with_virial().map_err(engine_err)?;
            series
                .temperature
                .push(observe::temperature(sim.particles(), sim.field()));
            series
                .pressure
                .push(observe::pressure(sim.particles(), sim.field(), sim.domain(), &virial));
        } else {
            sim.step().map_err(engine_err)?;
        }
        Ok(())
    }

    fn frame_due(&self) -> bool {
        frame_due(self.s, self.sim.step_count())
    }

    fn write_frame(&mut self) -> Result<(), RunError> {
        match self.traj.as_mut() {
            Some(w) => write_frame(self.s, w, &self.sim),
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
        // production time only: nothing before the first production step
        if self.sim.step_count() > self.s.run.equilibration_steps {
            self.series.production_seconds += self.clock.elapsed().as_secs_f64();
        }
        self.clock = Instant::now();
        save_checkpoint(self.s, ctx, &self.sim, &self.series)
    }
}

/// Runs the scenario from step 0.
pub fn run(s: &FluidScenario, ctx: &RunContext) -> Result<serde_json::Value, RunError> {
    run_from(s, ctx, None)
}

/// Runs the scenario, from a checkpoint when one is given.
pub fn run_from(
    s: &FluidScenario,
    ctx: &RunContext,
    checkpoint: Option<&Checkpoint>,
) -> Result<serde_json::Value, RunError> {
    let (sim, series) = match checkpoint {
        Some(ck) => restore(s, ck)?,
        None => (build(s)?, Series::default()),
    };
    let n = sim.particles().len();
    let total = s.run.equilibration_steps + s.run.steps;
    let start = sim.step_count();
    if start > total {
        return Err(RunError::Output(format!(
            "checkpoint at step {start} is past the end of the run ({total} steps)"
        )));
    }
    let traj_path = ctx.out_dir.join(TRAJECTORY_FILE);
    let traj = if s.output.trajectory_every_steps > 0 {
        let last_frame =
            run_dir::last_scheduled_frame(start, s.run.equilibration_steps, s.output.trajectory_every_steps);
        Some(run_dir::open_trajectory(
            ctx,
            checkpoint.is_some(),
            last_frame,
            |path| {
                let meta = RunMetadata::new(
                    "dpd-fluid",
                    toml::to_string(s).unwrap_or_default(),
                    s.seed,
                    model_units(),
                );
                TrajectoryWriter::create(path, &meta)
            },
        )?)
    } else {
        None
    };
    let mut run = Run {
        s,
        sim,
        series,
        traj,
        clock: Instant::now(),
    };
    driver::drive(&mut run, ctx, checkpoint.is_some(), s.output.checkpoint_every_steps)?;
    if let Some(w) = run.traj.take() {
        w.close().map_err(out_err)?;
    }
    let Run { sim, series, .. } = run;
    let stats = |d: &[f64]| observe::block_error(d).or_else(|_| observe::block_average(d, 2)).ok();
    let (t_mean, t_se) = stats(&series.temperature).unwrap_or((f64::NAN, f64::NAN));
    let (p_mean, p_se) = stats(&series.pressure).unwrap_or((f64::NAN, f64::NAN));
    let momentum = observe::momentum(sim.particles(), sim.field());
    let f = &s.fluid;
    let warnings = temperature_warnings(t_mean, t_se, f.kbt, s.run.timestep);
    if ctx.progress {
        for w in &warnings {
            eprintln!("warning: {w}");
        }
    }
    let standard = (f.density - 3.0).abs() < 1e-12
        && (f.a - 25.0).abs() < 1e-12
        && (f.kbt - 1.0).abs() < 1e-12
        && (f.cutoff - 1.0).abs() < 1e-12;
    let p0 = sim.particles();
    // a fingerprint of the final state: equal for runs that are bit-identical
    let fingerprint = p0.pos.iter().chain(&p0.vel).fold(0u64, |h, v| {
        [v.x, v.y, v.z]
            .iter()
            .fold(h, |h, c| (h ^ c.to_bits()).wrapping_mul(0x100000001b3))
    });
    Ok(json!({
        "particles": n,
        "units": "DPD model units: length rc, energy kBT, mass m",
        "steps": total,
        "resumed_from_step": checkpoint.map(|c| c.step),
        "temperature": { "mean": t_mean, "standard_error": t_se, "target": f.kbt, "relative_error": t_mean / f.kbt - 1.0, "samples": series.temperature.len() },
        "pressure": {
            "mean": p_mean, "standard_error": p_se, "samples": series.pressure.len(),
            "groot_warren_measured": if standard { json!(GROOT_WARREN_PRESSURE_RHO3_A25) } else { serde_json::Value::Null },
        },
        "warnings": warnings,
        "total_momentum": [momentum.x, momentum.y, momentum.z],
        "throughput_particle_steps_per_s": n as f64 * s.run.steps as f64 / series.production_seconds.max(1e-12),
        "production_seconds": series.production_seconds,
        "final_state_fingerprint": format!("{fingerprint:016x}"),
        "threads": rayon::current_num_threads(),
        "trajectory_file": (s.output.trajectory_every_steps > 0).then(|| traj_path.clone()),
        "checkpoint_file": ctx.out_dir.join(CHECKPOINT_FILE),
    }))
}

impl crate::kind::Kind for FluidScenario {
    const NAME: &'static str = "dpd-fluid";
    const SWEEP_COLUMNS: &'static [crate::kind::SweepColumn] = &[
        ("kBT", "/temperature/mean", false),
        ("pressure", "/pressure/mean", false),
        ("fingerprint", "/final_state_fingerprint", false),
        ("particle-steps/s", "/throughput_particle_steps_per_s", true),
    ];
    fn validate(&self, file: &str) -> Result<(), ScenarioError> {
        validate(self, file)
    }
    fn seed(&self) -> u64 {
        self.seed
    }
    /// Steps, equilibration included.
    fn schedule_end(&self) -> (u64, &'static str) {
        (self.run.equilibration_steps.saturating_add(self.run.steps), "steps")
    }
    fn run_from(&self, ctx: &RunContext, checkpoint: Option<&Checkpoint>) -> Result<serde_json::Value, RunError> {
        run_from(self, ctx, checkpoint)
    }
}

/// Relative temperature error above which a fluid run is flagged: the standard fluid runs 3 %
/// hot at Δt = 0.04 and 6 % at 0.06 (Groot & Warren 1997; docs/stability.md), and goes on,
/// finite but hotter, up to Δt ≈ 0.1 (34 %) before the engine stops it.
pub const TEMPERATURE_WARNING: f64 = 0.05;

/// A warning when the measured ⟨T⟩ misses the target kBT by more than
/// [`TEMPERATURE_WARNING`] and by more than 3 standard errors (a run that is finite but wrong).
fn temperature_warnings(mean: f64, se: f64, kbt: f64, dt: f64) -> Vec<String> {
    let rel = mean / kbt - 1.0;
    // a NaN standard error (too few samples) does not excuse a large deviation
    let resolved = se.is_nan() || (mean - kbt).abs() > 3.0 * se;
    if !mean.is_finite() || (rel.abs() > TEMPERATURE_WARNING && resolved) {
        vec![format!(
            "measured temperature {mean:.4} is {:+.1} % off the target kBT = {kbt} (more than {:.0} %): the time step {dt} is too large for these forces (docs/stability.md); lower run.timestep",
            100.0 * rel,
            100.0 * TEMPERATURE_WARNING
        )]
    } else {
        Vec::new()
    }
}
