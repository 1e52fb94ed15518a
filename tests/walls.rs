//! Walls: reflection keeps every fluid particle out, the adaptive control flattens the near-wall
//! density, Poiseuille flow in a tube and plane Couette flow against their analytic profiles.
//! Each test prints its numbers (`cargo test --release --test walls -- --nocapture`).

use glam::DVec3;
use hemodpd_engine::walls::WallForceProfile;
use hemodpd_engine::walls::{self, AdaptRecord, Reflection, WallConfig, WallSetup, WallShape, Walls, WallsState};
use hemodpd_engine::{EngineError, Extension, PairParams, PeriodicBox, SimConfig, Simulation, StateMut};

/// Reverse-Poiseuille viscosity of the standard fluid measured by this engine (engine
/// against engine; `scripts/validate_viscosity.sh` keeps it honest).
const ETA_PERIODIC: f64 = hemodpd_engine::params::STANDARD_FLUID_VISCOSITY;

fn tube(radius: f64, length: f64, seed: u64, reflection: Reflection) -> Simulation<Walls> {
    let side = 2.0 * (radius + 1.0) + 0.5;
    let config = SimConfig::new(DVec3::new(side, side, length), 0.01, seed);
    let shape = WallShape::Cylinder {
        axis: 2,
        centre: [0.5 * side; 2],
        radius,
    };
    let (field, p) = walls::build(&config, &WallSetup::standard(shape), seed).unwrap();
    let cfg = WallConfig {
        reflection,
        bins: 5,
        gain: 3.0,
        update_every: 500,
        ..WallConfig::default()
    };
    Simulation::with_extension(config, field, p, Walls::new(shape, cfg).unwrap()).unwrap()
}

fn plates(gap: f64, width: f64, u: f64, seed: u64) -> Simulation<Walls> {
    let config = SimConfig::new(DVec3::new(width, width, gap + 2.0), 0.01, seed);
    let shape = WallShape::Plates {
        axis: 2,
        lower: 1.0,
        upper: 1.0 + gap,
        period: gap + 2.0,
        lower_velocity: DVec3::new(-u, 0.0, 0.0),
        upper_velocity: DVec3::new(u, 0.0, 0.0),
    };
    let (field, p) = walls::build(&config, &WallSetup::standard(shape), seed).unwrap();
    let cfg = WallConfig {
        bins: 5,
        gain: 3.0,
        update_every: 500,
        ..WallConfig::default()
    };
    Simulation::with_extension(config, field, p, Walls::new(shape, cfg).unwrap()).unwrap()
}

fn print_history(h: &[AdaptRecord]) {
    for r in h {
        let rel: Vec<String> = r.relative_density.iter().map(|x| format!("{x:.3}")).collect();
        let f: Vec<String> = r.forces.iter().map(|x| format!("{x:.2}")).collect();
        println!(
            "  iter {:2} step {:6} max|ρ/ρ0−1| {:.4}  ρ/ρ0 [{}]  F [{}]",
            r.iteration,
            r.step,
            r.max_deviation,
            rel.join(" "),
            f.join(" ")
        );
    }
}

/// Max |ρ_k/ρ0 − 1| of the measured near-wall profile.
fn max_dev(w: &Walls) -> f64 {
    w.relative_density().iter().map(|r| (r - 1.0).abs()).fold(0.0, f64::max)
}

/// Adapts the near-wall force for `updates` periods (with the flow on) and returns the history.
fn adapt(sim: &mut Simulation<Walls>, updates: u64) -> Vec<AdaptRecord> {
    let m = sim.extension().config().update_every;
    sim.extension_mut().set_adapt(true);
    sim.run(updates * m).unwrap();
    sim.extension_mut().set_adapt(false);
    sim.extension().history().to_vec()
}

/// Result of a tube Poiseuille run of the `poiseuille-tube` scenario.
#[derive(Debug)]
struct Tube {
    /// The plateau of η(r) from the momentum balance, its standard error, and the width of
    /// the wall layer outside the plateau.
    eta: f64,
    eta_se: f64,
    wall_layer: f64,
    /// Slip velocity over centre velocity, from the whole-profile parabola.
    slip: f64,
    centre: f64,
    density_dev: f64,
    reflections: u64,
    /// (r, v_z, parabola, ρ/ρ0, analytic no-slip parabola for η = ETA_PERIODIC) per radial bin.
    profile: Vec<[f64; 5]>,
    /// (r, η, standard error) at the bin edges.
    eta_profile: Vec<[f64; 3]>,
    /// Measured centre velocity over that of the analytic no-slip parabola for ETA_PERIODIC.
    centre_over_reference: f64,
    /// Wall shear stress from the forces on the wall (and its SE) and n̄gR/2.
    wall_stress: (f64, f64, f64),
    /// Peculiar kBT (mean over the fluid) and its radial, azimuthal and axial components.
    kbt: [f64; 4],
}

/// Steps of flow development before sampling: the flow (on during the 5000 steps of
/// adaptation, when adaptive) must reach steady state, within e⁻⁵ ≈ 0.7 % of it after five
/// viscous times τ_v = nR²/(η j0²) (15 τ at R = 5, 40 τ at R = 8); at least 3000.
fn flow_steps(radius: f64, adaptive: bool) -> u64 {
    let tau_v = 3.0 * radius * radius / (ETA_PERIODIC * 2.405f64.powi(2));
    let needed = (5.0 * tau_v / 0.01) as u64;
    let adapting = if adaptive { 5000 } else { 0 };
    needed.saturating_sub(adapting).max(if adaptive { 3000 } else { 8000 })
}

/// Runs the shipped scenario `file` (in `scenarios/`) with the `--set` overrides `sets` in a
/// temporary directory and returns its results.
fn run_scenario(file: &str, sets: &[String]) -> serde_json::Value {
    let dir = tempfile::tempdir().unwrap();
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scenarios")
        .join(file);
    let s = hemodpd_scenario::load(&path, sets).unwrap();
    hemodpd_scenario::run(&s, &hemodpd_scenario::RunContext::new(dir.path(), 0, false)).unwrap()
}

/// Runs the shipped tube scenario with R = `radius`, body force `g`, length `length`, and
/// `steps` sampled steps; adaptive runs start from a zero force profile, the others get as
/// many steps of flow development as the adaptive ones spend adapting.
fn poiseuille(radius: f64, length: f64, g: f64, adaptive: bool, steps: u64, seed: u64) -> Tube {
    let sets: Vec<String> = vec![
        format!("tube.radius={radius}"),
        format!("tube.length={length}"),
        format!("tube.body_force={g}"),
        format!("seed={seed}"),
        format!("walls.adaptive={adaptive}"),
        format!("tube.reference_viscosity={ETA_PERIODIC}"),
        format!("run.flow_steps={}", flow_steps(radius, adaptive)),
        format!("run.steps={steps}"),
        "run.measure_overhead=false".into(),
    ];
    let r = run_scenario("poiseuille-tube.toml", &sets);
    let f = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
    let col = |v: &serde_json::Value| -> Vec<f64> { v.as_array().unwrap().iter().map(f).collect() };
    let pr = &r["profile"];
    let (rr, v, fit, rho) = (
        col(&pr["r"]),
        col(&pr["v_z"]),
        col(&pr["parabola"]),
        col(&pr["density"]),
    );
    let rho0 = f(&r["near_wall"]["target_density"]);
    let reference = col(&r["reference_parabola"]["profile"]);
    let vp = &r["viscosity_profile"];
    let (er, eta, ese) = (col(&vp["edge"]), col(&vp["eta"]), col(&vp["standard_error"]));
    let ws = &r["wall_shear_stress"];
    let t = &r["temperature"];
    let visc = &r["viscosity"];
    let tube = Tube {
        eta: f(&visc["value"]),
        eta_se: f(&visc["standard_error"]),
        wall_layer: radius - f(&visc["plateau_to"]),
        slip: f(&r["parabola"]["slip_fraction"]),
        centre: f(&r["parabola"]["centre_velocity"]),
        density_dev: f(&r["near_wall"]["max_density_deviation"]),
        reflections: r["reflections"].as_u64().unwrap(),
        profile: (0..rr.len())
            .map(|k| [rr[k], v[k], fit[k], rho[k] / rho0, reference[k]])
            .collect(),
        eta_profile: (0..er.len()).map(|k| [er[k], eta[k], ese[k]]).collect(),
        centre_over_reference: f(&r["reference_parabola"]["centre_velocity_measured_over_reference"]),
        wall_stress: (f(&ws["measured"]), f(&ws["standard_error"]), f(&ws["expected"])),
        kbt: [f(&t["mean"]), f(&t["radial"]), f(&t["azimuthal"]), f(&t["axial"])],
    };
    println!(
        "tube R = {radius}, L = {length}, g = {g}, adaptive = {adaptive}, seed {seed}: η plateau = {:.4} ± {:.4} (wall layer {:.2} rc, χ²/dof {:.2}), whole-profile η {:.4}, centre {:.4} ({:.4} × the no-slip parabola for η = {ETA_PERIODIC}), slip {:.4}, near-wall max |ρ/ρ0−1| = {:.4}, wall stress {:.5} ± {:.5} vs n̄gR/2 = {:.5}, kBT {:.4} (r {:.4}, θ {:.4}, z {:.4}), reflections {}",
        tube.eta,
        tube.eta_se,
        tube.wall_layer,
        f(&visc["chi2_per_dof"]),
        f(&r["parabola"]["viscosity_whole_profile"]),
        tube.centre,
        tube.centre_over_reference,
        tube.slip,
        tube.density_dev,
        tube.wall_stress.0,
        tube.wall_stress.1,
        tube.wall_stress.2,
        tube.kbt[0],
        tube.kbt[1],
        tube.kbt[2],
        tube.kbt[3],
        tube.reflections
    );
    for (k, e) in tube.eta_profile.iter().enumerate() {
        let b = &tube.profile[k];
        println!(
            "  r {:.3}  v {:.4}  ρ/ρ0 {:.4} | edge {:.3}  η {:.4} ± {:.4}",
            b[0], b[1], b[3], e[0], e[1], e[2]
        );
    }
    tube
}

/// Mean and standard error of the mean.
fn mean_se(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    let sd = (x.iter().map(|e| (e - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    (m, sd / n.sqrt())
}

/// Longer tube runs for docs/walls.md (`scripts/validate_walls.sh`): the plateau of η(r)
/// against the tube radius over 4 seeds each, at the same wall shear rate. Each mean must agree with the periodic
/// (reverse-Poiseuille) viscosity within 3 %, the wall stress with n̄gR/2 within 1 %.
#[test]
#[ignore]
fn tube_viscosity_vs_radius() {
    // the same wall shear rate n̄gR/(2η) ≈ 0.9 in every tube: g = 0.5/R
    for (radius, g) in [(5.0, 0.1), (6.0, 0.5 / 6.0), (8.0, 0.0625)] {
        let runs: Vec<Tube> = (1..=4)
            .map(|seed| poiseuille(radius, 12.0, g, true, 20000, seed))
            .collect();
        let (m, se) = mean_se(&runs.iter().map(|t| t.eta).collect::<Vec<_>>());
        let (layer, _) = mean_se(&runs.iter().map(|t| t.wall_layer).collect::<Vec<_>>());
        let (stress, _) = mean_se(
            &runs
                .iter()
                .map(|t| t.wall_stress.0 / t.wall_stress.2)
                .collect::<Vec<_>>(),
        );
        println!(
            "SUMMARY R = {radius}, g = {g}: η plateau = {m:.4} ± {se:.4} ({:+.1}% against {ETA_PERIODIC}), wall layer {layer:.2} rc, wall stress / n̄gR/2 = {stress:.4}",
            100.0 * (m / ETA_PERIODIC - 1.0)
        );
        assert!((m / ETA_PERIODIC - 1.0).abs() < 0.03, "R = {radius}: η = {m} ± {se}");
        assert!((stress - 1.0).abs() < 0.01, "R = {radius}: wall stress ratio {stress}");
    }
}

/// Result of a run of the shipped Couette scenario, shrunk with the given sizes.
#[derive(Debug)]
struct Couette {
    eta: f64,
    eta_se: f64,
    slip: (f64, f64),
    shear_rate: f64,
    /// (z, v_x, line) per bin.
    profile: Vec<[f64; 3]>,
    kbt: f64,
}

/// Runs `scenarios/couette.toml` (its own `couette_results`) with gap, width, wall speed,
/// sampled steps and seed.
fn couette(gap: f64, width: f64, u: f64, steps: u64, seed: u64) -> Couette {
    let sets: Vec<String> = vec![
        format!("plates.gap={gap}"),
        format!("plates.width=[{width}, {width}]"),
        format!("plates.wall_speed={u}"),
        format!("seed={seed}"),
        format!("run.steps={steps}"),
        "run.measure_overhead=false".into(),
    ];
    let r = run_scenario("couette.toml", &sets);
    let f = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
    let col = |v: &serde_json::Value| -> Vec<f64> { v.as_array().unwrap().iter().map(f).collect() };
    let (z, v, line) = (
        col(&r["profile"]["z"]),
        col(&r["profile"]["v_x"]),
        col(&r["profile"]["line"]),
    );
    let c = Couette {
        eta: f(&r["viscosity"]["value"]),
        eta_se: f(&r["viscosity"]["standard_error"]),
        slip: (
            f(&r["line"]["slip_fraction_lower"]),
            f(&r["line"]["slip_fraction_upper"]),
        ),
        shear_rate: f(&r["line"]["shear_rate"]),
        profile: (0..z.len()).map(|k| [z[k], v[k], line[k]]).collect(),
        kbt: f(&r["temperature"]["mean"]),
    };
    println!(
        "couette gap {gap}, ±{u}, seed {seed}: η plateau {:.4} ± {:.4} ({} edges), whole-line η {:.4}, shear rate {:.4} (no slip {:.4}), slip {:.4} {:.4}, kBT {:.4}",
        c.eta,
        c.eta_se,
        r["viscosity"]["plateau_edges"],
        f(&r["viscosity_whole_line"]["value"]),
        c.shear_rate,
        2.0 * u / gap,
        c.slip.0,
        c.slip.1,
        c.kbt
    );
    let vp = &r["viscosity_profile"];
    for ((z, e), se) in col(&vp["edge"])
        .iter()
        .zip(col(&vp["eta"]))
        .zip(col(&vp["standard_error"]))
    {
        println!("  z {z:.3}  η {e:.4} ± {se:.4}");
    }
    c
}

/// Reflection keeps every fluid particle out of the wall (bounce-back and specular), with many
/// reflections per run; a particle that would still be inside after reflection is a typed
/// error naming the step and the particle.
#[test]
fn no_fluid_particle_ever_inside_a_wall() {
    for refl in [Reflection::BounceBack, Reflection::Specular] {
        let mut sim = tube(4.0, 6.0, 5, refl);
        sim.set_body_force(0, DVec3::new(0.0, 0.0, 0.1)).unwrap();
        for _ in 0..10 {
            sim.run(100).unwrap();
            let shape = *sim.extension().shape();
            let p = sim.particles();
            let worst = (0..p.len())
                .filter(|&i| p.ptype[i] == walls::FLUID_TYPE)
                .map(|i| shape.signed_distance(p.pos[i]))
                .fold(f64::MIN, f64::max);
            assert!(worst <= 0.0, "{refl:?}: fluid particle at signed distance {worst}");
        }
        // ~1.8 hits per step expected from kinetic theory (ρ√(kT/2πm) × area 151)
        let n = sim.extension().reflections();
        println!("{refl:?}: {n} reflections in 1000 steps");
        assert!(n > 1000, "{n}");
    }
    // A particle 3.5 deep in a wall whose fluid is only 2.5 wide: its mirror point is in the
    // wall on the other side → error.
    let domain = PeriodicBox::new(DVec3::new(4.0, 4.0, 10.0)).unwrap();
    let shape = WallShape::Plates {
        axis: 2,
        lower: 0.5,
        upper: 3.0,
        period: 10.0,
        lower_velocity: DVec3::ZERO,
        upper_velocity: DVec3::ZERO,
    };
    let field = walls::wall_field(PairParams::groot_warren()).unwrap();
    let mut w = Walls::new(shape, WallConfig::default()).unwrap();
    let mut pos = vec![DVec3::new(1.0, 1.0, 2.0), DVec3::new(1.0, 1.0, 6.5)];
    let mut vel = vec![DVec3::ZERO, DVec3::Z];
    let mut force = vec![DVec3::ZERO; 2];
    let mut s = StateMut {
        pos: &mut pos,
        vel: &mut vel,
        force: &mut force,
        ptype: &[0, 0],
        id: &[10, 11],
        domain: &domain,
        field: &field,
        dt: 0.01,
        step: 42,
    };
    let e = w.after_position_update(&mut s).unwrap_err();
    println!("{e}");
    assert!(matches!(e, EngineError::Extension { step: 42, .. }));
    assert!(e.to_string().contains("id 11"), "{e}");
}

/// Adaptive control where it matters: wall particles with the dissipative and random forces
/// but no conservative force (a_wf = 0). Without a wall force the fluid piles up against the
/// surface; the half-space formula removes most of it; adaptation from it brings every bin of
/// the near-wall layer within ±3% of ρ0. The converged profile is saved and reused.
#[test]
fn adaptive_control_flattens_near_wall_density() {
    adaptive_a0();
}

/// The a_wf = 0 adaptation experiment; returns the near-wall profiles (label, (h, ρ/ρ0)).
fn adaptive_a0() -> Vec<(String, Vec<(f64, f64)>)> {
    let mut profiles = Vec::new();
    let (gap, width) = (6.0, 10.0);
    let make = |profile: Option<&WallForceProfile>, gain: f64| {
        let config = SimConfig::new(DVec3::new(width, width, gap + 2.0), 0.01, 11);
        let shape = WallShape::Plates {
            axis: 2,
            lower: 1.0,
            upper: 1.0 + gap,
            period: gap + 2.0,
            lower_velocity: DVec3::ZERO,
            upper_velocity: DVec3::ZERO,
        };
        let (mut field, p) = walls::build(&config, &WallSetup::standard(shape), 11).unwrap();
        field
            .set_pair(
                0,
                1,
                PairParams {
                    a: 0.0,
                    ..PairParams::groot_warren()
                },
            )
            .unwrap();
        let mut w = Walls::new(
            shape,
            WallConfig {
                bins: 5,
                gain,
                update_every: 500,
                adapt: false,
                ..WallConfig::default()
            },
        )
        .unwrap();
        if let Some(p) = profile {
            w = w.with_profile(p).unwrap();
        }
        Simulation::with_extension(config, field, p, w).unwrap()
    };
    let mut measure = |sim: &mut Simulation<Walls>, label: &str| {
        sim.run(500).unwrap();
        sim.extension_mut().reset_measurements();
        sim.run(4000).unwrap();
        let rel = sim.extension().relative_density();
        let d = max_dev(sim.extension());
        println!(
            "{label}: max |ρ/ρ0−1| = {d:.4}, ρ/ρ0 = {:?}",
            rel.iter().map(|x| (x * 1000.0).round() / 1000.0).collect::<Vec<_>>()
        );
        let h = sim.extension().bin_centres();
        profiles.push((label.to_string(), h.into_iter().zip(rel).collect::<Vec<_>>()));
        d
    };
    let mut none = make(None, 0.0);
    let d_none = measure(&mut none, "a_wf = 0, no wall force");
    let guess = WallForceProfile::half_space(PairParams::groot_warren(), 3.0, 5);
    let mut half = make(Some(&guess), 0.0);
    let d_half = measure(&mut half, "a_wf = 0, half-space force");
    let mut ad = make(Some(&guess), 3.0);
    let hist = adapt(&mut ad, 14);
    println!("adaptation from the half-space force (gradient law, α = 3, M = 500):");
    print_history(&hist);
    let d_ad = measure(&mut ad, "a_wf = 0, adapted");
    assert!(
        d_none > 0.10,
        "without a wall force the near-wall density should be far off: {d_none}"
    );
    assert!(d_ad < 0.03, "after adaptation: {d_ad}");
    assert!(d_ad < d_half && d_ad < d_none / 3.0);
    // save and reuse: a new run started from the saved profile is flat at once
    let saved = ad.extension().profile(PairParams::groot_warren(), 3.0);
    let text = saved.to_csv();
    let back = WallForceProfile::from_csv(&text).unwrap();
    assert!(back.matches(&PairParams::groot_warren(), 3.0, 5));
    let mut again = make(Some(&back), 0.0);
    let d_again = measure(&mut again, "a_wf = 0, reused profile");
    // 3% target + ~0.5% for the statistical error of a 4000-step measurement (≈ 0.3–0.6% per bin)
    assert!(d_again < 0.035, "reused profile: {d_again}");
    profiles
}

/// PNG figures for docs/walls.md (`scripts/validate_walls.sh`, which sets
/// `HEMODPD_FIGURES_DIR=docs/figures`; without it they go to a temporary directory). The runs
/// behind the figures are longer than the suite's and assert the same physics.
#[test]
#[ignore]
fn wall_figures() {
    use hemodpd_io::plot::{line_chart, Series};
    let tmp = tempfile::tempdir().unwrap();
    let dir = std::env::var_os("HEMODPD_FIGURES_DIR").map_or(tmp.path().to_path_buf(), std::path::PathBuf::from);
    let plain = poiseuille(5.0, 12.0, 0.1, false, 20000, 1);
    let adapted = poiseuille(5.0, 12.0, 0.1, true, 20000, 1);
    assert!(adapted.density_dev <= 0.03 && plain.density_dev <= 0.05);
    assert!((adapted.eta / ETA_PERIODIC - 1.0).abs() < 0.03, "{adapted:?}");
    let mut series = Vec::new();
    for (t, name) in [(&plain, "no adaptive force"), (&adapted, "adaptive force")] {
        series.push(Series::points(
            format!("v_z, {name}"),
            t.profile.iter().map(|p| (p[0], p[1])).collect(),
        ));
        series.push(Series::line(
            format!("parabola, {name} (slip {:.1}%)", 100.0 * t.slip),
            t.profile.iter().map(|p| (p[0], p[2])).collect(),
        ));
    }
    series.push(Series::line(
        format!("no-slip parabola for η = {ETA_PERIODIC} (reverse Poiseuille)"),
        adapted.profile.iter().map(|p| (p[0], p[4])).collect(),
    ));
    line_chart(
        dir.join("walls_tube_velocity.png"),
        "Poiseuille flow in a tube, R = 5 rc, g = 0.1",
        "r (rc)",
        "axial velocity",
        &series,
    )
    .unwrap();
    let mut series = Vec::new();
    for (t, name) in [(&plain, "no adaptive force"), (&adapted, "adaptive force")] {
        // η(r) where it is measured to better than 10 % (near the axis dv/dr → 0)
        series.push(Series::line_with_points(
            format!(
                "η(r), {name}: plateau {:.3} ± {:.3}, wall layer {:.2} rc",
                t.eta, t.eta_se, t.wall_layer
            ),
            t.eta_profile
                .iter()
                .filter(|e| e[2] < 0.1 * e[1])
                .map(|e| (e[0], e[1]))
                .collect(),
        ));
    }
    series.push(Series::line(
        format!("periodic (reverse Poiseuille) {ETA_PERIODIC}"),
        vec![(0.0, ETA_PERIODIC), (5.0, ETA_PERIODIC)],
    ));
    line_chart(
        dir.join("walls_tube_viscosity_profile.png"),
        "η(r) = σ_rz/(dv/dr), σ_rz from the axial momentum balance; R = 5 rc, g = 0.1",
        "r (rc)",
        "η",
        &series,
    )
    .unwrap();
    let mut series = Vec::new();
    for (t, name) in [(&plain, "no adaptive force"), (&adapted, "adaptive force")] {
        series.push(Series::line_with_points(
            name,
            t.profile.iter().map(|p| (p[0], p[3])).collect(),
        ));
    }
    line_chart(
        dir.join("walls_tube_density.png"),
        "Tube density across the radius (standard frozen wall)",
        "r (rc)",
        "ρ/ρ0",
        &series,
    )
    .unwrap();
    let profiles = adaptive_a0();
    let series: Vec<Series> = profiles
        .into_iter()
        .map(|(l, p)| Series::line_with_points(l, p))
        .collect();
    line_chart(
        dir.join("walls_near_wall_density.png"),
        "Near-wall density, wall without conservative force (a_wf = 0)",
        "h, distance from the wall (rc)",
        "ρ/ρ0",
        &series,
    )
    .unwrap();
    let c = couette(8.0, 8.0, 2.0, 40000, 3);
    assert!((c.eta / ETA_PERIODIC - 1.0).abs() < 0.03, "{c:?}");
    let series = vec![
        Series::points("v_x", c.profile.iter().map(|p| (p[0], p[1])).collect()),
        Series::line(
            format!(
                "line (η plateau {:.3} ± {:.3}, slip {:.1}%, {:.1}%)",
                c.eta,
                c.eta_se,
                100.0 * c.slip.0,
                100.0 * c.slip.1
            ),
            c.profile.iter().map(|p| (p[0], p[2])).collect(),
        ),
        Series::line(
            "no slip (line through the wall velocities)",
            vec![(1.0, -2.0), (9.0, 2.0)],
        ),
    ];
    line_chart(
        dir.join("walls_couette.png"),
        "Plane Couette flow, plates at z = 1 and 9 moving at ∓2",
        "z (rc)",
        "v_x",
        &series,
    )
    .unwrap();
}

/// Standard frozen-particle wall (a_wf = 25), body force g = 0.1.
/// - Slip ≤ 3 % of the centre velocity with (R = 5) and without (R = 4) adaptation; the
///   near-wall density within ±3 % after adaptation (5 % without: the frozen layer already
///   supplies most of the missing repulsion).
/// - The plateau of η(r) (momentum balance, no chosen window) agrees with the periodic
///   reverse-Poiseuille viscosity within 3 % (the issue's bound). Its standard error in this
///   run must be below 1 % so that 3 % is three of them.
/// - The wall shear stress from the forces on the wall particles equals n̄gR/2 (the exact
///   momentum balance) within 3 standard errors of its 10-block average and within 1 %.
/// - The fluid is warmer than kBT by viscous heating, ≈ 0.05 γ̇_w² (docs/walls.md), and by
///   no more than 0.01 beyond that.
/// - The centre velocity lies within TUBE_CENTRE_BAND × that of the no-slip parabola for the
///   periodic viscosity (docs/walls.md: the wall layer and the residual slip make the tube
///   faster; 1.06–1.09 over 4 seeds, measured 1.085 here).
#[test]
fn tube_poiseuille_profile_slip_and_density() {
    let plain = poiseuille(4.0, 8.0, 0.1, false, 8000, 1);
    let adapted = poiseuille(5.0, 12.0, 0.1, true, 20000, 1);
    for t in [&plain, &adapted] {
        assert!(t.slip.abs() <= 0.03, "{t:?}");
        assert!(t.reflections > 0);
        let (tau, se, expected) = t.wall_stress;
        assert!(
            (tau - expected).abs() < 3.0 * se && (tau / expected - 1.0).abs() < 0.01,
            "wall stress {tau} ± {se} vs n̄gR/2 = {expected}"
        );
        // viscous heating: T − kBT ≈ 0.05 γ̇_w² (docs/walls.md), γ̇_w = n̄gR/(2η) the wall
        // shear rate; at most 0.01 above that
        let shear_w = 2.0 * expected / ETA_PERIODIC;
        assert!(
            t.kbt[0] - 1.0 < 0.01 + 0.05 * shear_w * shear_w,
            "peculiar kBT {:?}, γ̇_w {shear_w}",
            t.kbt
        );
        assert!(t.kbt[0] > 1.0);
    }
    assert!(
        TUBE_CENTRE_BAND.contains(&adapted.centre_over_reference),
        "centre {} × the no-slip parabola",
        adapted.centre_over_reference
    );
    // the target holds after adaptation; without it the frozen wall alone is 1.7–2.7% off
    assert!(adapted.density_dev <= 0.03, "{adapted:?}");
    assert!(plain.density_dev <= 0.05, "{plain:?}");
    assert!(adapted.eta_se < 0.01 * ETA_PERIODIC, "{adapted:?}");
    assert!((adapted.eta / ETA_PERIODIC - 1.0).abs() < 0.03, "{adapted:?}");
}

/// The shipped tube's drive keeps the fluid within 1 % of its kBT (docs/walls.md,
/// "Temperature"): the excess is viscous heating, ≈ 0.05 γ̇_w² over the fluid at rest, and the
/// shipped body force is chosen for it. R = 5 as shipped, L = 12, 6000 sampled steps: the
/// time-averaged peculiar kBT is known to ±0.001, measured 1.0067 (1.005 of it is the
/// Δt = 0.01 offset of the periodic fluid). The same run at g = 0.1 is 1.043, at rest 1.005.
#[test]
fn tube_fluid_within_one_percent_of_kbt_at_the_shipped_drive() {
    let sets: Vec<String> = ["tube.length=12", "run.steps=6000", "run.measure_overhead=false"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let r = run_scenario("poiseuille-tube.toml", &sets);
    let t = &r["temperature"];
    println!("shipped drive g = {}: peculiar kBT {t}", r["body_force"]);
    let mean = t["mean"].as_f64().unwrap();
    assert!((mean - 1.0).abs() < 0.01, "mean {mean}");
    // each component (a third of the samples each, and the flow heats the axial one first)
    for c in ["radial", "azimuthal", "axial"] {
        let v = t[c].as_f64().unwrap();
        assert!((v - 1.0).abs() < 0.015, "{c}: {v}");
    }
}

/// Band of the tube's centre velocity over that of the no-slip parabola for the periodic
/// viscosity (R = 5, g = 0.1, adaptive); see the test above and docs/walls.md.
const TUBE_CENTRE_BAND: std::ops::Range<f64> = 1.0..1.10;

/// The flow controller holds the tube's mean velocity: R = 4, L = 8, target 0.6, starting from
/// the Poiseuille estimate for η = 0.842. After the 8000 steps of adaptation and development
/// (8 viscous times τ_v = nR²/(η j0²) ≈ 10), a critically damped loop is within 0.3% of the
/// target; the mean over 6000 sampled steps must be within 2% (the window means scatter by
/// about 1.5%). The mean force is the one that gives this velocity: within 15% of the
/// Poiseuille estimate, since the near-wall layer makes the tube 7–13% faster than Poiseuille's
/// law (docs/walls.md).
#[test]
fn tube_flow_controller_holds_the_mean_velocity() {
    let sets: Vec<String> = vec![
        "tube.radius=4".into(),
        "tube.length=8".into(),
        "tube.mean_velocity=0.6".into(),
        format!("tube.reference_viscosity={ETA_PERIODIC}"),
        "run.steps=6000".into(),
        "run.measure_overhead=false".into(),
    ];
    let r = run_scenario("poiseuille-tube.toml", &sets);
    let c = &r["flow_control"];
    let f = |v: &serde_json::Value| v.as_f64().unwrap();
    let (u, force) = (f(&c["measured_mean_velocity"]), f(&c["body_force_mean"]));
    let poiseuille = 8.0 * ETA_PERIODIC * 0.6 / (3.0 * 16.0);
    println!(
        "flow control: mean velocity {u:.4} (target 0.6), mean force {force:.5} (Poiseuille {poiseuille:.5}), {} updates",
        c["updates"]
    );
    assert!((u / 0.6 - 1.0).abs() < 0.02, "{c}");
    assert!((force / poiseuille - 1.0).abs() < 0.15, "{c}");
    assert_eq!(c["tube_body_force_not_used"], 0.02);
    assert_eq!(f(&r["body_force"]), force);
}

/// Plane Couette flow between plates moving at ±2, run through the scenario's own
/// `couette_results`: a linear profile (shear rate within 5 % of the no-slip 2U/gap), no slip
/// at either wall (≤ 3 % of the wall speed difference), and the plateau of η(z) = σ/(dv/dz)
/// with σ the wall shear stress agrees with the periodic viscosity within 3 %, its standard
/// error below 1 %.
#[test]
fn couette_linear_profile_no_slip_and_viscosity() {
    let c = couette(8.0, 8.0, 2.0, 40000, 2);
    assert!(c.slip.0.abs() <= 0.03 && c.slip.1.abs() <= 0.03, "{c:?}");
    assert!((c.shear_rate / 0.5 - 1.0).abs() < 0.05, "{c:?}");
    assert!(c.eta_se < 0.012 * ETA_PERIODIC, "{c:?}");
    assert!((c.eta / ETA_PERIODIC - 1.0).abs() < 0.03, "{c:?}");
}

/// Walls (reflection, moving wall particles, adaptive updates) give the same trajectory with 1
/// and 2 threads, bit for bit.
#[test]
fn walls_are_deterministic_across_thread_counts() {
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let mut sim = plates(4.0, 5.0, 1.0, 9);
                sim.set_body_force(0, DVec3::new(0.0, 0.05, 0.0)).unwrap();
                let mut cfg = sim.extension().config().clone();
                cfg.update_every = 50;
                let shape = *sim.extension().shape();
                let (state, _) = sim.into_parts();
                let mut sim = Simulation::with_extension(
                    state.config,
                    state.field,
                    state.particles,
                    Walls::new(shape, cfg).unwrap(),
                )
                .unwrap();
                sim.run(300).unwrap();
                let p = sim.particles();
                let bits: Vec<u64> = p
                    .pos
                    .iter()
                    .chain(&p.vel)
                    .flat_map(|v| [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()])
                    .collect();
                (bits, sim.extension().forces().to_vec(), sim.extension().reflections())
            })
    };
    let (a, b) = (run(1), run(2));
    assert!(a.2 > 0);
    assert_eq!(a.1, b.1);
    assert_eq!(a.2, b.2);
    assert!(a.0 == b.0, "trajectories differ between 1 and 2 threads");
}

/// A walled run stopped in the middle of an adaptation period, with its simulation and wall
/// state passed through serde (as a checkpoint stores them), continues bit for bit.
#[test]
fn walls_restart_is_bit_identical() {
    let fresh = || {
        let mut sim = plates(4.0, 5.0, 1.0, 5);
        sim.set_body_force(0, DVec3::new(0.0, 0.05, 0.0)).unwrap();
        let mut cfg = sim.extension().config().clone();
        cfg.update_every = 40;
        let shape = *sim.extension().shape();
        let (state, _) = sim.into_parts();
        Simulation::with_extension(
            state.config,
            state.field,
            state.particles,
            Walls::new(shape, cfg).unwrap(),
        )
        .unwrap()
    };
    let fingerprint = |sim: &Simulation<Walls>| {
        let p = sim.particles();
        let bits: Vec<u64> = p
            .pos
            .iter()
            .chain(&p.vel)
            .chain(&p.force)
            .flat_map(|v| [v.x.to_bits(), v.y.to_bits(), v.z.to_bits()])
            .collect();
        (bits, sim.extension().state())
    };
    let mut whole = fresh();
    whole.run(250).unwrap();
    let mut first = fresh();
    first.run(130).unwrap(); // 3 updates done, 10 steps into the 4th period
    let (state, ext) = first.into_parts();
    let saved = serde_json::to_string(&ext.state()).unwrap();
    let shape = *ext.shape();
    let cfg = ext.config().clone();
    let domain = PeriodicBox::new(state.config.box_lengths).unwrap();
    let restored = Walls::new(shape, cfg)
        .unwrap()
        .with_state(serde_json::from_str::<WallsState>(&saved).unwrap(), &domain)
        .unwrap();
    // the measured profile is there before any step
    assert!(!ext.relative_density().is_empty());
    assert_eq!(restored.relative_density(), ext.relative_density());
    let mut second = Simulation::from_state(state, restored).unwrap();
    second.run(120).unwrap();
    let (a, b) = (fingerprint(&whole), fingerprint(&second));
    assert_eq!(a.1.history.len(), 6);
    assert!(a.1.reflections > 0);
    assert_eq!(a.1, b.1, "wall state differs after the restart");
    assert!(a.0 == b.0, "trajectory differs after the restart");
    // a state for other walls is refused
    let mut wrong = ext_state_with_bins(&a.1, 3);
    assert!(Walls::new(shape, WallConfig::default())
        .unwrap()
        .with_state(wrong.clone(), &domain)
        .is_err());
    wrong.forces[0] = f64::NAN;
    assert!(Walls::new(
        shape,
        WallConfig {
            bins: 3,
            ..WallConfig::default()
        }
    )
    .unwrap()
    .with_state(wrong, &domain)
    .is_err());
}

fn ext_state_with_bins(s: &WallsState, bins: usize) -> WallsState {
    WallsState {
        forces: vec![0.0; bins],
        period_counts: vec![0; bins],
        total_counts: vec![0; bins],
        ..s.clone()
    }
}

/// Both scenario files load and run end to end (shrunk with --set overrides): the summary
/// holds the fitted profile, slip, near-wall density, reflections, the η(r) profile and the
/// overhead; the converged force profile goes to the run directory and the cache, never next
/// to the scenario, and is reused from a previous run's file or from the cache.
#[test]
fn wall_scenarios_run() {
    let dir = tempfile::tempdir().unwrap();
    // a private cache for this test binary (no other test here reads the cache)
    std::env::set_var("HEMODPD_CACHE", dir.path().join("cache"));
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let tube_sets: Vec<String> = [
        "tube.radius=3",
        "tube.length=4",
        "tube.body_force=0.1",
        "walls.adapt_iterations=2",
        "walls.update_every=100",
        "run.flow_steps=100",
        "run.steps=300",
        "run.profile_bins=6",
        "run.measure_overhead=true",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let s = hemodpd_scenario::load(&root.join("poiseuille-tube.toml"), &tube_sets).unwrap();
    assert_eq!(s.kind(), "poiseuille-tube");
    let ctx = hemodpd_scenario::RunContext::new(dir.path().join("tube"), 1, false);
    let r = hemodpd_scenario::run(&s, &ctx).unwrap();
    assert_eq!(r["viscosity_profile"]["eta"].as_array().unwrap().len(), 5);
    assert!(r["viscosity"]["value"].is_f64() || r["viscosity"]["note"].is_string());
    assert!(r["parabola"]["slip_fraction"].as_f64().unwrap().is_finite());
    assert!(r["reflections"].as_u64().unwrap() > 0);
    assert!(r["overhead"]["ratio"].as_f64().unwrap() > 0.0);
    assert!(r["wall_shear_stress"]["measured"].as_f64().unwrap() > 0.0);
    assert_eq!(r["adaptation"]["iterations"].as_array().unwrap().len(), 2);
    let first = dir.path().join("tube/wall_force.csv");
    assert!(first.exists() && dir.path().join("tube/velocity_profile.csv").exists());
    assert!(dir.path().join("tube/viscosity_profile.csv").exists());
    let cached: Vec<_> = std::fs::read_dir(dir.path().join("cache")).unwrap().collect();
    assert_eq!(cached.len(), 1, "one cached profile: {cached:?}");
    // a later run starts from the first run's file, or from the cache
    for (set, expect) in [
        (
            format!("walls.force_file={:?}", first.to_str().unwrap()),
            first.display().to_string(),
        ),
        ("walls.initial=\"cached\"".to_string(), "wall-force-".to_string()),
    ] {
        let mut sets = tube_sets.clone();
        sets.push(set);
        let s = hemodpd_scenario::load(&root.join("poiseuille-tube.toml"), &sets).unwrap();
        let again = hemodpd_scenario::run(
            &s,
            &hemodpd_scenario::RunContext::new(dir.path().join("tube2"), 1, false),
        )
        .unwrap();
        let source = again["wall_force_source"].as_str().unwrap();
        assert!(source.starts_with("file") && source.contains(&expect), "{source}");
    }
    // bins no particle visited are reported as empty (null), not as v = 0, and the fits skip them
    let mut sets = tube_sets.clone();
    sets.extend(["run.profile_bins=400".to_string(), "run.steps=20".to_string()]);
    let s = hemodpd_scenario::load(&root.join("poiseuille-tube.toml"), &sets).unwrap();
    let r = hemodpd_scenario::run(
        &s,
        &hemodpd_scenario::RunContext::new(dir.path().join("tube3"), 1, false),
    )
    .unwrap();
    let v = r["profile"]["v_z"].as_array().unwrap();
    let density = r["profile"]["density"].as_array().unwrap();
    let empty: Vec<usize> = (0..v.len()).filter(|&k| density[k] == 0.0).collect();
    assert!(
        !empty.is_empty(),
        "the innermost of 400 bins over 4 samples should be empty"
    );
    assert!(
        empty.iter().all(|&k| v[k].is_null()),
        "{:?}",
        empty.iter().map(|&k| &v[k]).collect::<Vec<_>>()
    );
    assert!(v
        .iter()
        .filter(|x| !x.is_null())
        .all(|x| x.as_f64().unwrap().is_finite()));
    assert!(r["parabola"]["centre_velocity"].as_f64().unwrap().is_finite());
    // nothing was written next to the scenario files
    let mut names: Vec<String> = std::fs::read_dir(&root)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    // (scenarios/fits/ holds the shipped fit files)
    assert!(names.iter().all(|n| n.ends_with(".toml") || n == "fits"), "{names:?}");

    let sets: Vec<String> = [
        "plates.gap=4",
        "plates.width=[4, 4]",
        "walls.adapt_iterations=1",
        "walls.update_every=100",
        "run.flow_steps=100",
        "run.steps=300",
        "run.measure_overhead=false",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let s = hemodpd_scenario::load(&root.join("couette.toml"), &sets).unwrap();
    let r = hemodpd_scenario::run(
        &s,
        &hemodpd_scenario::RunContext::new(dir.path().join("couette"), 1, false),
    )
    .unwrap();
    assert!(r["line"]["shear_rate"].as_f64().unwrap() > 0.0);
    assert!(r["viscosity_whole_line"]["value"].as_f64().unwrap().is_finite());
    assert!(r["temperature"]["mean"].as_f64().unwrap() > 0.5);
    // a bad value is named
    let e = hemodpd_scenario::load(&root.join("couette.toml"), &["walls.reflection=sticky".into()]).unwrap_err();
    assert!(e.to_string().contains("walls.reflection"), "{e}");
}
