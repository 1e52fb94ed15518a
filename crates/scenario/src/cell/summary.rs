//! The blocks every cell-in-flow kind writes into `summary.json`: the unit mapping and fluid,
//! membrane viscosity, crossings, and the run's performance with the shares of a step's time.

use super::build::{cell_membrane_viscosity, CellPlan, CellSetup, CellSim};
use super::VERTEX_MASS;
use crate::units;
use hemodpd_membrane::coupling::{CellStats, CellTimers};
use hemodpd_membrane::viscosity::MembraneViscosity;
use serde_json::json;
use std::time::Instant;

/// The `membrane_viscosity` block of a cell run's summary: η_m in SI and model units, the
/// friction coefficients, the sub-steps, and the effective link friction of the scheme
/// γ_eff = μ/(h(a/(1 − a) + ½)), a = exp(−(γ_T + γ_C)h/μ), h = Δt/k, as a fraction of γ_T + γ_C.
pub(crate) fn membrane_viscosity_summary(
    eta_si: f64,
    shear_modulus_n_per_m: f64,
    visc: Option<&MembraneViscosity>,
    form: serde_json::Value,
    substeps: u32,
    substep_forces: serde_json::Value,
    dt: f64,
) -> serde_json::Value {
    let mu = 0.5 * VERTEX_MASS;
    let h = dt / substeps as f64;
    let fraction = visc.map(|v| {
        let g = v.gamma_t + v.gamma_c;
        let a = (-g * h / mu).exp();
        mu / (h * (a / (1.0 - a) + 0.5)) / g
    });
    json!({
        "pa_s_m": eta_si,
        "model": visc.map(|v| v.eta()).unwrap_or(0.0),
        "gamma_t": visc.map(|v| v.gamma_t).unwrap_or(0.0),
        "gamma_c": visc.map(|v| v.gamma_c).unwrap_or(0.0),
        "kelvin_voigt_time_s": eta_si / shear_modulus_n_per_m,
        "form": form,
        "substeps": substeps,
        "substep_forces": substep_forces,
        "effective_friction_fraction": fraction,
        "note": "2D membrane viscosity η_m (0: off, the paper's model); model units E τ/r²; link friction in the form given (\"fedosov\": γ_C = γ_T/3; \"central\": γ_T = 0), η_m = √3 γ_T + √3 γ_C/4; η_m/μ0 is the Kelvin–Voigt time of the membrane alone (η_m is the simple-shear viscosity; without rotation, as in a stretch relaxation, Fedosov's form acts as 7/13 η_m and the central form as η_m); substeps: membrane sub-steps per fluid step (model.membrane_substeps), substep_forces: where the membrane's elastic forces act with sub-steps (model.membrane_substep_forces); effective_friction_fraction: the link friction the scheme acts with on slow motion, over γ_T + γ_C (null without viscosity; docs/model.md §7b)",
    })
}

/// The cell's crossing statistics for `summary.json`.
pub(crate) fn crossings_json(stats: &CellStats) -> serde_json::Value {
    json!({
        "bounces": stats.bounces,
        "checks": stats.checks,
        "misplaced_total": stats.misplaced,
        "misplaced_last_check": stats.misplaced_last,
        "checked_last": stats.checked_last,
        "note": "fluid particles found on the wrong side of the membrane by the inside test every model.crossing_check_every_steps steps (target 0)",
    })
}

/// Shares of `session_s` seconds of stepping: the cell's timers, the walls, sampling and
/// frames, and the remainder (the fluid's pair forces, the integrator, the cell lists).
pub(crate) fn step_shares(session_s: f64, timers: &CellTimers, walls_s: f64, output_s: f64) -> serde_json::Value {
    let known = timers.bounce_s + timers.membrane_forces_s + timers.checks_s + timers.viscosity_s + walls_s + output_s;
    json!({
        "fluid_pairs_and_integration": (session_s - known) / session_s,
        "bounce_back": timers.bounce_s / session_s,
        "membrane_forces": timers.membrane_forces_s / session_s,
        "membrane_viscosity": timers.viscosity_s / session_s,
        "walls": walls_s / session_s,
        "crossing_checks": timers.checks_s / session_s,
        "sampling_and_frames": output_s / session_s,
    })
}

/// The blocks of `summary.json` that every cell run writes alike: `unit_mapping`, `fluid`,
/// `groups_si`, `groups_model`, `membrane_viscosity`, `mesh` and `crossings`. A kind adds its own
/// blocks to the returned object (`out["model"] = …`).
pub(crate) fn common_blocks(
    plan: &impl CellPlan,
    stats: &CellStats,
    mesh_info: &serde_json::Value,
) -> serde_json::Value {
    let CellSetup {
        sys,
        map: m,
        fluid,
        dt,
        substeps,
    } = plan.setup();
    let visc = cell_membrane_viscosity(plan.cell(), m);
    json!({
        "unit_mapping": {
            "length_m": m.length_m, "energy_j": m.energy_j, "time_s": m.time_s,
            "thermal_factor": m.thermal_factor, "warnings": m.warnings,
            "timestep_s": dt * m.time_s,
        },
        "fluid": units::fluid_json(fluid, *dt),
        "groups_si": units::groups_si(sys),
        "groups_model": units::groups_model(sys, m, fluid),
        "membrane_viscosity": membrane_viscosity_summary(
            plan.cell().membrane_viscosity_pa_s_m,
            sys.shear_modulus_n_per_m,
            visc.as_ref(),
            serde_json::to_value(plan.cell().membrane_viscosity_form).unwrap_or_default(),
            *substeps,
            serde_json::to_value(plan.model_keys().membrane_substep_forces).unwrap_or_default(),
            *dt,
        ),
        "mesh": mesh_info,
        "crossings": crossings_json(stats),
    })
}

/// The unit mapping of a cell scenario as data, before any run: scales, thermal factor, the
/// chosen fluid (at its own time step) with the reason, and the groups in SI and in the model.
pub(crate) fn mapping_json(sys: &units::PhysicalSystem, d: &crate::fluid_choice::FluidDecision) -> serde_json::Value {
    let m = &d.map;
    json!({
        "length_m": m.length_m, "energy_j": m.energy_j, "time_s": m.time_s,
        "thermal_factor": m.thermal_factor, "warnings": m.warnings,
        "fluid": crate::fluid_choice::fluid_json(&d.fluid, d.fluid.timestep),
        "fluid_reason": d.reason,
        "groups_si": units::groups_si(sys),
        "groups_model": units::groups_model(sys, m, &d.fluid),
    })
}

/// A cell run's clocks: stepping time since the last checkpoint (the time before it is saved in
/// the checkpoint), this session's start (step and instant), and its seconds in sampling and
/// frames.
pub(crate) struct StepClock {
    since_checkpoint: Instant,
    session_step0: u64,
    session_t0: Instant,
    /// Seconds of this session spent sampling and writing frames.
    pub output_s: f64,
}

impl StepClock {
    /// Clocks started now, for a session that starts at `step`.
    pub fn start(step: u64) -> Self {
        let now = Instant::now();
        Self {
            since_checkpoint: now,
            session_step0: step,
            session_t0: now,
            output_s: 0.0,
        }
    }

    /// At a checkpoint: adds the stepping time since the last one to `saved_s` (what the
    /// checkpoint stores) and restarts that clock.
    pub fn checkpoint(&mut self, saved_s: &mut f64) {
        *saved_s += self.since_checkpoint.elapsed().as_secs_f64();
        self.since_checkpoint = Instant::now();
    }
}

/// The `performance` block of a cell run's summary: steps, stepping seconds (`saved_s` from the
/// last checkpoint on) and rate over the whole run, and this session's steps, seconds, rate
/// and the shares of its time ([`step_shares`]).
pub(crate) fn performance_json(sim: &CellSim, saved_s: f64, clock: &StepClock) -> serde_json::Value {
    let timers = sim.extension().1.timers();
    let secs = saved_s + clock.since_checkpoint.elapsed().as_secs_f64();
    let steps = sim.step_count() as f64;
    let session_s = clock.session_t0.elapsed().as_secs_f64().max(1e-9);
    let session_steps = (sim.step_count() - clock.session_step0) as f64;
    let walls_s = sim.extension().0.as_ref().map_or(0.0, |w| w.seconds);
    json!({
        "steps": steps,
        "stepping_seconds": secs,
        "steps_per_second": steps / secs.max(1e-9),
        "threads": rayon::current_num_threads(),
        "this_session": {
            "steps": session_steps,
            "seconds": session_s,
            "steps_per_second": session_steps / session_s,
            "share": step_shares(session_s, &timers, walls_s, clock.output_s),
        },
    })
}
