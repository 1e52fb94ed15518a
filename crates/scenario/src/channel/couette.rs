//! `kind = "couette"`: plane Couette flow between plates moving at ±U, measured against the
//! line; η from the wall stress.

use super::measure::{
    block_mean, fit_line, fluid_mass, jackknife_se, mean_temperature, stress_mean_se, viscosity_profile, Measurement,
};
use super::run::{run_plan, wall_results, write_csv};
use super::{validate_wall_common, Channel, Plan, WallOutput, WallRunSection, WallsSection};
use crate::context::{RunContext, RunError};
use crate::file::{Check, FluidSection, ScenarioError};
use glam::DVec3;
use hemodpd_engine::walls::{WallShape, Walls};
use hemodpd_engine::Simulation;
use hemodpd_io::checkpoint::Checkpoint;
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::path::PathBuf;

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

/// Validates a `kind = "couette"` scenario.
pub fn validate(s: &CouetteScenario, file: &str) -> Result<(), ScenarioError> {
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

super::wall_kind!(
    CouetteScenario,
    "couette",
    run_couette,
    [
        ("viscosity", "/viscosity/value", false),
        ("viscosity SE", "/viscosity/standard_error", false),
        ("slip lower", "/line/slip_fraction_lower", false),
        ("slip upper", "/line/slip_fraction_upper", false),
    ]
);
