//! The blocks every cell-in-flow kind writes into `summary.json`: membrane viscosity,
//! crossings, and the shares of a step's time.

use super::VERTEX_MASS;
use hemodpd_membrane::coupling::{CellStats, CellTimers};
use hemodpd_membrane::viscosity::MembraneViscosity;
use serde_json::json;

/// The `membrane_viscosity` block of a cell run's summary: η_m in SI and model units, the
/// friction coefficients, the sub-steps, and the effective link friction of the scheme
/// γ_eff = μ/(h(a/(1 − a) + ½)), a = exp(−(γ_T + γ_C)h/μ), h = Δt/k, as a fraction of γ_T + γ_C.
pub(crate) fn membrane_viscosity_summary(
    eta_si: f64,
    shear_modulus_n_per_m: f64,
    visc: Option<&MembraneViscosity>,
    substeps: u32,
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
        "substeps": substeps,
        "effective_friction_fraction": fraction,
        "note": "2D membrane viscosity η_m (0: off, the paper's model); model units E τ/r²; Fedosov's link friction with γ_C = γ_T/3, η_m = √3 γ_T + √3 γ_C/4; η_m/μ0 is the Kelvin–Voigt time of the membrane alone; substeps: membrane sub-steps per fluid step (model.membrane_substeps); effective_friction_fraction: the link friction the scheme acts with on slow motion, over γ_T + γ_C (null without viscosity; docs/model.md §7b)",
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
