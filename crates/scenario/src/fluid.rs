//! The periodic DPD fluid scenario (`kind = "dpd-fluid"`), in model units: equilibrate, then
//! sample temperature and virial pressure; report means, block-averaged standard errors, and
//! the throughput in particle-steps per second.

use crate::file::FluidScenario;
use crate::{RunContext, RunError};
use glam::DVec3;
use hemodpd_engine::init::{self, FluidSpec, Placement};
use hemodpd_engine::{observe, ForceField, PairParams, SimConfig, Simulation};
use hemodpd_io::progress::{Progress, ProgressMode};
use serde_json::json;

/// Groot & Warren (1997), Fig. 4: measured pressure of the standard fluid (ρ = 3, a = 25, kBT = 1).
pub const GROOT_WARREN_PRESSURE_RHO3_A25: f64 = 23.7;

fn engine_err(e: hemodpd_engine::EngineError) -> RunError {
    RunError::Engine(e.to_string())
}

/// Builds the simulation of a fluid scenario.
pub fn build(s: &FluidScenario) -> Result<Simulation, RunError> {
    let f = &s.fluid;
    let mut config = SimConfig::new(DVec3::from_array(f.box_size), s.run.timestep, s.seed);
    config.lambda = s.run.lambda;
    let field = ForceField::single(PairParams { a: f.a, gamma: f.gamma, kbt: f.kbt, rc: f.cutoff, s: f.weight_exponent });
    let spec = FluidSpec { density: f.density, ptype: 0, kbt: f.kbt, placement: Placement::JitteredLattice { jitter: 0.1 }, first_id: 0 };
    let particles = init::fluid(&config, &field, &spec, s.seed).map_err(engine_err)?;
    Simulation::new(config, field, particles).map_err(engine_err)
}

/// Runs the scenario.
pub fn run(s: &FluidScenario, ctx: &RunContext) -> Result<serde_json::Value, RunError> {
    let mut sim = build(s)?;
    let n = sim.particles().len();
    let total = s.run.equilibration_steps + s.run.steps;
    let mode = if ctx.progress { ProgressMode::Auto } else { ProgressMode::Quiet };
    let mut progress = Progress::new(total, 0, mode, 1.0, "τ");
    let chunk = (total / 200).max(1);
    let mut done = 0;
    while done < s.run.equilibration_steps {
        let k = chunk.min(s.run.equilibration_steps - done);
        sim.run(k).map_err(engine_err)?;
        done += k;
        progress.update(done, sim.time());
    }
    let (mut temps, mut pressures) = (Vec::new(), Vec::new());
    let t0 = std::time::Instant::now();
    for i in 0..s.run.steps {
        if i % s.run.sample_every == 0 {
            let virial = sim.step_with_virial().map_err(engine_err)?;
            temps.push(observe::temperature(sim.particles(), sim.field()));
            pressures.push(observe::pressure(sim.particles(), sim.field(), sim.domain(), &virial));
        } else {
            sim.step().map_err(engine_err)?;
        }
        if (i + 1) % chunk == 0 {
            progress.update(done + i + 1, sim.time());
        }
    }
    let seconds = t0.elapsed().as_secs_f64();
    progress.finish(total, sim.time());
    let stats = |d: &[f64]| observe::block_error(d).or_else(|_| observe::block_average(d, 2)).ok();
    let (t_mean, t_se) = stats(&temps).unwrap_or((f64::NAN, f64::NAN));
    let (p_mean, p_se) = stats(&pressures).unwrap_or((f64::NAN, f64::NAN));
    let momentum = observe::momentum(sim.particles(), sim.field());
    let standard = (s.fluid.density - 3.0).abs() < 1e-12 && (s.fluid.a - 25.0).abs() < 1e-12 && (s.fluid.kbt - 1.0).abs() < 1e-12 && (s.fluid.cutoff - 1.0).abs() < 1e-12;
    Ok(json!({
        "particles": n,
        "units": "DPD model units: length rc, energy kBT, mass m",
        "temperature": { "mean": t_mean, "standard_error": t_se, "target": s.fluid.kbt, "relative_error": t_mean / s.fluid.kbt - 1.0, "samples": temps.len() },
        "pressure": {
            "mean": p_mean, "standard_error": p_se, "samples": pressures.len(),
            "groot_warren_measured": if standard { json!(GROOT_WARREN_PRESSURE_RHO3_A25) } else { serde_json::Value::Null },
        },
        "total_momentum": [momentum.x, momentum.y, momentum.z],
        "throughput_particle_steps_per_s": n as f64 * s.run.steps as f64 / seconds,
        "production_seconds": seconds,
        "threads": rayon::current_num_threads(),
    }))
}
