//! `kind = "poiseuille-tube"`: body-force-driven (or flow-controlled) flow in a tube, measured
//! against the parabola; η(r) from the axial momentum balance.

use super::measure::{
    fit_parabola, fluid_mass, mean_temperature, stress_mean_se, viscosity_profile, Measurement, ViscosityProfile,
    J0_FIRST_ZERO,
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

fn hundred() -> u64 {
    100
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

/// Validates a `kind = "poiseuille-tube"` scenario.
pub fn validate(s: &TubeScenario, file: &str) -> Result<(), ScenarioError> {
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
                -100.0,
                100.0,
                "a body force between −100 and 100 (model units; the flow scales as g/η: 0.05–0.2 for the standard fluid, ≈ 1 for the dense, ≈ 10–40 for the viscous)",
            )?;
            // no drive, no flow: the viscosity from the profile's curvature would be 0/0
            if g == 0.0 && mean.is_none() {
                return Err(c.fail(
                    "tube.body_force",
                    g,
                    "a non-zero body force between −100 and 100 (zero drives no flow: the viscosity and the parabola fit would be meaningless), or tube.mean_velocity for a flow held at a mean velocity",
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

super::wall_kind!(
    TubeScenario,
    "poiseuille-tube",
    run_tube,
    [
        ("viscosity", "/viscosity/value", false),
        ("viscosity SE", "/viscosity/standard_error", false),
        ("slip", "/parabola/slip_fraction", false),
        ("max |rho/rho0-1|", "/near_wall/max_density_deviation", false),
    ]
);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::channel::measure::{ProfileSums, BLOCKS};

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
