//! One walled run, for either kind: the build (walls cut out of an equilibrated fluid, the
//! initial near-wall force), checkpoints, frames, the phases, sampling and flow control of the
//! [`Stepper`], and the results every wall kind reports.

use crate::context::{RunContext, RunError};
use crate::driver::{self, Stepper};
use crate::run_dir::{
    self, engine_err, json_from_checkpoint, json_into_checkpoint, out_err, particles_from_checkpoint,
    particles_into_checkpoint, CHECKPOINT_FILE, TRAJECTORY_FILE,
};
use glam::DVec3;
use hemodpd_engine::walls::{self, WallForceProfile, WallSetup, WallShape, Walls, WallsState};
use hemodpd_engine::{init, ForceField, PeriodicBox, SimConfig, SimState, Simulation};
use hemodpd_io::checkpoint::{Checkpoint, ScalarValue};
use hemodpd_io::{RunMetadata, TrajectoryWriter};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::measure::{FlowControl, Measurement, ProfileSums, BLOCKS, J0_FIRST_ZERO};
use super::{pair, Channel, InitialWallForce, Plan};

/// The cache file of the converged wall-force profile for this plan's fluid, geometry, bins,
/// control law and reflection (in the mesh cache's directory; [`crate::mesh_cache::cache_dir`]).
fn wall_force_cache_path(plan: &Plan) -> PathBuf {
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
    run_dir::save_checkpoint(&ck, ctx)
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
    let profile = i.is_multiple_of(r.sample_every);
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
    if step.is_multiple_of(every) {
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
pub(super) fn run_plan(
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
    let every = plan.output.trajectory_every_steps;
    // frames are due at multiples of `every` (none when it is 0)
    let traj = if every > 0 {
        let last_frame = run_dir::last_scheduled_frame(start, 0, every);
        Some(run_dir::open_trajectory(
            ctx,
            checkpoint.is_some(),
            last_frame,
            |path| {
                let mut meta = RunMetadata::new(plan.kind, plan.toml.clone(), plan.seed, crate::fluid::model_units());
                meta.extra.push((
                    "particle_types".into(),
                    hemodpd_io::MetaValue::Str("0 = fluid, 1 = frozen wall".into()),
                ));
                TrajectoryWriter::create(path, &meta)
            },
        )?)
    } else {
        None
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

pub(super) fn write_csv(ctx: &RunContext, name: &str, header: &str, rows: &[Vec<f64>]) -> Result<(), RunError> {
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

/// The results every wall scenario reports, added to the kind's own (`specific`): the schedule,
/// the adaptation, the near-wall density, reflections, timing, files; the overhead is timed last
/// (it steps the simulation on).
pub(super) fn wall_results(
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
