//! `[recovery]` of the stretching scenario: the cell is released from the last force and
//! recovers at the rate its membrane viscosity sets, as in Hochmuth, Worthy & Evans (1979);
//! L/W against time is fitted with their Kelvin–Voigt form and compared with their four cells
//! (docs/model.md §7c; docs/validation.md, "Recovery after release").

use crate::capillary::fit_hochmuth;
use crate::cell::ViscosityForm;
use crate::context::RunError;
use crate::file::{Check, ScenarioError};
use glam::DVec3;
use hemodpd_membrane::recovery::{self, Recovery, RecoveryOptions, RecoverySample, DEFAULT_INERTIA};
use hemodpd_membrane::viscosity::MembraneViscosity;
use hemodpd_membrane::MembraneModel;
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::path::Path;

fn default_medium() -> f64 {
    1e-3
}
fn default_samples() -> u64 {
    100
}
fn default_inertia() -> f64 {
    DEFAULT_INERTIA
}

/// `[recovery]`: release after the last force of `stretching.forces_pn`.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RecoverySection {
    /// How long the cell is followed after release, s.
    pub duration_s: f64,
    /// The 2D membrane viscosity η_m, N·s/m (Hochmuth 1979: ≈ 6e-7).
    pub membrane_viscosity_pa_s_m: f64,
    /// How the link friction carries η_m: `"fedosov"` (default) or `"central"` (docs/model.md §7b).
    #[serde(default)]
    pub membrane_viscosity_form: ViscosityForm,
    /// Viscosity of the still medium the cell recovers in, Pa·s (default 1e-3, a saline buffer):
    /// each vertex gets the drag 16 η R/N, a disc of the cell's radius R shared among the vertices.
    #[serde(default = "default_medium")]
    pub medium_viscosity_pa_s: f64,
    /// Samples of the shape over `duration_s` (default 100), the release being sample 0.
    #[serde(default = "default_samples")]
    pub samples: u64,
    /// The vertices' fictitious inertial time as a fraction of the friction time Γ/μ0
    /// (default 5e-4). The shapes converge linearly as it shrinks, so the run is made at it and at
    /// half of it and extrapolated to zero (docs/validation.md, "Recovery after release").
    #[serde(default = "default_inertia")]
    pub inertia_fraction: f64,
}

/// Checks `[recovery]`.
pub(crate) fn validate(r: &RecoverySection, c: &Check) -> Result<(), ScenarioError> {
    c.range(
        "recovery.duration_s",
        r.duration_s,
        1e-4,
        10.0,
        "a time in s between 1e-4 and 10 (Hochmuth's cells recover over ≈ 0.4 s)",
    )?;
    c.range(
        "recovery.membrane_viscosity_pa_s_m",
        r.membrane_viscosity_pa_s_m,
        0.0,
        1e-4,
        "a 2D viscosity in N·s/m between 0 and 1e-4 (Hochmuth 1979: ≈ 6e-7)",
    )?;
    c.range(
        "recovery.medium_viscosity_pa_s",
        r.medium_viscosity_pa_s,
        0.0,
        10.0,
        "a viscosity in Pa·s between 0 and 10 (a saline buffer: 1e-3)",
    )?;
    if r.membrane_viscosity_pa_s_m == 0.0 && r.medium_viscosity_pa_s == 0.0 {
        return Err(c.fail(
            "recovery.membrane_viscosity_pa_s_m",
            0,
            "a positive value, or a positive recovery.medium_viscosity_pa_s: with neither, nothing dissipates and the released cell never settles",
        ));
    }
    if !(4..=100_000).contains(&r.samples) {
        return Err(c.fail(
            "recovery.samples",
            r.samples,
            "an integer from 4 to 100000 (the Kelvin–Voigt fit needs at least 4)",
        ));
    }
    c.range(
        "recovery.inertia_fraction",
        r.inertia_fraction,
        1e-6,
        1e-2,
        "a fraction between 1e-6 and 1e-2 (default 5e-4; smaller is more exact and slower)",
    )?;
    Ok(())
}

/// Hochmuth et al. 1979 (tRBC-UQ's digitisation, see the file's first line): cell, t s, L/W.
pub const HOCHMUTH_1979_CSV: &str = include_str!("../../data/relaxation_hochmuth1979_trbcuq.csv");

/// Hochmuth's cells, each as (t, λ) series.
pub fn hochmuth_1979() -> Vec<(u32, Vec<f64>, Vec<f64>)> {
    let mut cells: Vec<(u32, Vec<f64>, Vec<f64>)> = Vec::new();
    for l in HOCHMUTH_1979_CSV
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("cell"))
    {
        let c: Vec<f64> = l.split(',').filter_map(|x| x.trim().parse().ok()).collect();
        if c.len() != 3 {
            continue;
        }
        let id = c[0] as u32;
        match cells.iter_mut().find(|e| e.0 == id) {
            Some(e) => {
                e.1.push(c[1]);
                e.2.push(c[2]);
            }
            None => cells.push((id, vec![c[1]], vec![c[2]])),
        }
    }
    cells
}

/// Hochmuth's four cells fitted as the simulation is: per cell t_c, λ0, λ∞; the mean and the
/// sample SD of t_c (s).
pub fn hochmuth_reference() -> serde_json::Value {
    let fits: Vec<(u32, crate::capillary::HochmuthFit)> = hochmuth_1979()
        .into_iter()
        .filter_map(|(id, t, l)| fit_hochmuth(&t, &l).map(|f| (id, f)))
        .collect();
    let tc: Vec<f64> = fits.iter().map(|f| f.1.t_c).collect();
    let n = tc.len() as f64;
    let mean = tc.iter().sum::<f64>() / n;
    let sd = (tc.iter().map(|t| (t - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    json!({
        "reference": "Hochmuth, Worthy & Evans 1979 (tRBC-UQ digitisation), shared/reference/relaxation_hochmuth1979_trbcuq.csv",
        "cells": fits.iter().map(|(id, f)| json!({"cell": id, "t_c_s": f.t_c, "lambda_0": f.lambda_0, "lambda_inf": f.lambda_inf, "rms": f.rms})).collect::<Vec<_>>(),
        "mean_t_c_s": mean,
        "sd_t_c_s": sd,
    })
}

/// The friction of the scenario's membrane viscosity in the stretching units (pN·s/µm; 1 N·s/m
/// = 1e6 pN·s/µm).
pub fn link_friction(r: &RecoverySection) -> MembraneViscosity {
    let eta = r.membrane_viscosity_pa_s_m * 1e6;
    match r.membrane_viscosity_form {
        ViscosityForm::Fedosov => MembraneViscosity::from_eta(eta),
        ViscosityForm::Central => MembraneViscosity::central_from_eta(eta),
    }
}

/// The recovery options: `mu0` in pN/µm, `radius` the cell's resting radius in µm, `n` vertices.
pub fn options(r: &RecoverySection, mu0: f64, radius: f64, n: usize) -> RecoveryOptions {
    // 16 η R is a disc's translational drag; η Pa·s × R µm = 1e-6 N·s/m = 1 pN·s/µm
    let drag = 16.0 * r.medium_viscosity_pa_s * radius / n as f64;
    RecoveryOptions {
        viscosity: link_friction(r),
        drag,
        shear_modulus: mu0,
        duration: r.duration_s,
        samples: r.samples as usize,
        inertia: r.inertia_fraction,
    }
}

/// A recovery extrapolated to massless vertices: the samples and the two runs behind them.
pub struct Extrapolated {
    /// 2·fine − coarse per sample ([`recovery::extrapolate`]).
    pub samples: Vec<RecoverySample>,
    /// The run at the scenario's inertial fraction ε, and at ε/2.
    pub coarse: Recovery,
    pub fine: Recovery,
    pub options: RecoveryOptions,
}

/// Releases the cell at `start` (the last equilibrium, µm) and follows it, twice (inertial
/// fractions ε and ε/2) for the extrapolation; `None` if stopped.
pub fn run(
    r: &RecoverySection,
    model: &MembraneModel,
    rest: &[DVec3],
    start: &[DVec3],
    mu0: f64,
    mut stop: impl FnMut() -> bool,
) -> Result<Option<Extrapolated>, RunError> {
    let radius = 0.5 * hemodpd_membrane::stretch::diameters(rest).0;
    let opts = options(r, mu0, radius, start.len());
    let go = |o: &RecoveryOptions, stop: &mut dyn FnMut() -> bool| {
        recovery::recover(model, start, o, stop).map_err(|e| RunError::Output(format!("recovery: {e}")))
    };
    let coarse = go(&opts, &mut stop)?;
    if coarse.samples.len() < r.samples as usize + 1 {
        return Ok(None);
    }
    let half = RecoveryOptions {
        inertia: 0.5 * opts.inertia,
        ..opts
    };
    let fine = go(&half, &mut stop)?;
    if fine.samples.len() < r.samples as usize + 1 {
        return Ok(None);
    }
    let samples = recovery::extrapolate(&coarse, &fine)
        .ok_or_else(|| RunError::Output("recovery: the two runs' samples differ".into()))?;
    Ok(Some(Extrapolated {
        samples,
        coarse,
        fine,
        options: opts,
    }))
}

/// Writes `recovery.csv` (time s, D_A and D_T µm, L/W, area and volume deviations, then L/W of
/// the two runs behind the extrapolation).
pub fn write_csv(path: &Path, rec: &Extrapolated) -> Result<(), RunError> {
    let mut csv = String::from(
        "# recovery after release, extrapolated to massless vertices: time since release (s), axial and transverse diameters about the centroid (um), L/W, (A-A0)/A0, (V-V0)/V0; L/W of the runs at inertia_fraction and at half of it\ntime_s,axial_diameter_um,transverse_diameter_um,length_over_width,area_deviation,volume_deviation,length_over_width_coarse,length_over_width_fine\n",
    );
    for ((s, c), f) in rec.samples.iter().zip(&rec.coarse.samples).zip(&rec.fine.samples) {
        csv += &format!(
            "{:.6e},{:.6},{:.6},{:.6},{:.3e},{:.3e},{:.6},{:.6}\n",
            s.time,
            s.axial_diameter,
            s.transverse_diameter,
            s.length_over_width(),
            s.area_deviation,
            s.volume_deviation,
            c.length_over_width(),
            f.length_over_width()
        );
    }
    std::fs::write(path, csv).map_err(|source| RunError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// The Kelvin–Voigt fit of a series of samples.
fn fit_of(samples: &[RecoverySample]) -> Option<crate::capillary::HochmuthFit> {
    let t: Vec<f64> = samples.iter().map(|s| s.time).collect();
    let l: Vec<f64> = samples.iter().map(|s| s.length_over_width()).collect();
    fit_hochmuth(&t, &l)
}

/// The results block: the Kelvin–Voigt fit, Hochmuth's cells and how it was integrated.
pub fn results(r: &RecoverySection, rec: &Extrapolated, release_force_pn: f64) -> serde_json::Value {
    let opts = &rec.options;
    let fit = fit_of(&rec.samples);
    let (fit_coarse, fit_fine) = (fit_of(&rec.coarse.samples), fit_of(&rec.fine.samples));
    let reference = hochmuth_reference();
    let mean = reference["mean_t_c_s"].as_f64().unwrap_or(f64::NAN);
    let (amax, vmax) = rec.samples.iter().fold((0.0f64, 0.0f64), |(a, v), s| {
        (a.max(s.area_deviation.abs()), v.max(s.volume_deviation.abs()))
    });
    let eta = r.membrane_viscosity_pa_s_m;
    // η_m/μ0, s (μ0 pN/µm = 1e-6 N/m); the form's Kelvin–Voigt time for a deformation without
    // rotation: Fedosov's form acts as 7/13 η_m there (docs/model.md §7b), the central one as η_m
    let tkv = eta / (opts.shear_modulus * 1e-6);
    let v = link_friction(r);
    let acting = if v.eta() > 0.0 {
        v.rotation_free_eta() / v.eta()
    } else {
        1.0
    };
    json!({
        "released_from_force_pn": release_force_pn,
        "duration_s": r.duration_s,
        "membrane_viscosity_pa_s_m": eta,
        "membrane_viscosity_form": r.membrane_viscosity_form,
        "kelvin_voigt_time_s": tkv,
        "kelvin_voigt_time_of_the_form_s": acting * tkv,
        "medium_viscosity_pa_s": r.medium_viscosity_pa_s,
        "vertex_drag_pn_s_per_um": opts.drag,
        "t_c_s": fit.map(|f| f.t_c),
        "lambda_0": fit.map(|f| f.lambda_0),
        "lambda_inf": fit.map(|f| f.lambda_inf),
        "fit_rms": fit.map(|f| f.rms),
        "fit": "Hochmuth's Kelvin-Voigt form ((λ²−λ∞²)(λ0²+λ∞²))/((λ²+λ∞²)(λ0²−λ∞²)) = exp(−t/t_c), λ = L/W = D_A/D_T, λ0 the first sample, t_c and λ∞ by least squares",
        "t_c_over_hochmuth_mean": fit.map(|f| f.t_c / mean),
        "hochmuth1979": reference,
        "max_abs_area_deviation": amax,
        "max_abs_volume_deviation": vmax,
        "time_series": "recovery.csv",
        "integration": {
            "scheme": "no fluid, no noise: velocity Verlet with the membrane forces, the Shardlow sweep of the link friction, the exact decay of each vertex's velocity by the medium's drag; the vertex mass is fictitious, and the samples are extrapolated to a massless membrane from runs at inertia_fraction and at half of it (2·fine − coarse)",
            "inertia_fraction": r.inertia_fraction,
            "t_c_s_coarse": fit_coarse.map(|f| f.t_c),
            "t_c_s_fine": fit_fine.map(|f| f.t_c),
            "steps": rec.coarse.steps + rec.fine.steps,
            "time_step_s": [rec.coarse.time_step, rec.fine.time_step],
            "vertex_mass_pn_s2_per_um": [rec.coarse.vertex_mass, rec.fine.vertex_mass],
        },
    })
}
