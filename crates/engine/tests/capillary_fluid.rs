//! The capillary fluid ([`PairParams::capillary`]: a = 25, γ = 120, s = 1/4, ρ = 3) at rest: its
//! time step keeps the kinetic temperature at the thermostat's (the viscosity is measured in
//! viscosity.rs).

use glam::DVec3;
use hemodpd_engine::params::{CAPILLARY_FLUID_DENSITY, CAPILLARY_FLUID_TIMESTEP};
use hemodpd_engine::{init, observe, ForceField, PairParams, SimConfig, Simulation};

/// Mean kinetic kBT of an 8 × 8 × 8 periodic box of the capillary fluid at rest over `nsample`
/// steps after `neq`, and its block-averaged standard error; an error where the integration
/// blows up (γΔt too large for the explicit dissipative force).
fn try_mean_temperature(dt: f64, neq: u64, nsample: u64, seed: u64) -> Result<(f64, f64), hemodpd_engine::EngineError> {
    let config = SimConfig::new(DVec3::splat(8.0), dt, seed);
    let field = ForceField::single(PairParams::capillary());
    let spec = init::FluidSpec {
        density: CAPILLARY_FLUID_DENSITY,
        ..init::FluidSpec::standard()
    };
    let p = init::fluid(&config, &field, &spec, seed + 1).unwrap();
    let mut sim = Simulation::new(config, field, p).unwrap();
    sim.run(neq)?;
    let mut t = Vec::with_capacity(nsample as usize);
    for _ in 0..nsample {
        sim.step()?;
        t.push(observe::temperature(sim.particles(), sim.field()));
    }
    Ok(observe::block_average(&t, 10).unwrap())
}

fn mean_temperature(dt: f64, neq: u64, nsample: u64, seed: u64) -> (f64, f64) {
    try_mean_temperature(dt, neq, nsample, seed).unwrap()
}

/// At [`CAPILLARY_FLUID_TIMESTEP`] the box keeps kBT within 1.5 % of 1 (the criterion the
/// step was chosen by; the mean of 3000 steps has an SE ≈ 0.001).
#[test]
fn capillary_fluid_temperature_at_its_timestep() {
    let (t, se) = mean_temperature(CAPILLARY_FLUID_TIMESTEP, 500, 3000, 7);
    eprintln!("capillary fluid, dt = {CAPILLARY_FLUID_TIMESTEP}: kBT = {t:.4} ± {se:.4}");
    assert!((t - 1.0).abs() < 0.015, "kBT = {t} ± {se}");
}

/// The largest time step the membrane of the capillary scenario tolerates at the mapping of
/// this fluid (≈ 0.003 model units); the fluid's step must not exceed it, as it is the
/// scenario's default `model.timestep`.
const MEMBRANE_MAX_TIMESTEP: f64 = 0.003;

/// The scan behind [`CAPILLARY_FLUID_TIMESTEP`]: kBT at Δt = 0.01, 0.005, 0.004, 0.0025, 0.002
/// (8 × 8 × 8, 1000 steps of equilibration, mean of the next 5000; a step that blows up is
/// reported as unstable). The candidates are 0.005, 0.004, 0.0025, 0.002; the chosen step is
/// the largest of them within 1.5 % of 1 (and within 0.5 % where one is) that is also at most
/// [`MEMBRANE_MAX_TIMESTEP`]: the fluid's step is the capillary scenario's default, and the
/// membrane there needs Δt ≤ ~0.003 at the mapping of this fluid. With γ = 120 the explicit
/// friction is near its limit at 0.005 (γΔt = 0.6, kBT 9 % high) and 0.004 (kBT +0.2 %).
#[test]
#[ignore]
fn capillary_fluid_timestep_scan() {
    let mut chosen = None;
    // a smaller candidate within 0.5 % is preferred over a larger one only within 1.5 %
    let mut results = Vec::new();
    for dt in [0.01, 0.005, 0.004, 0.0025, 0.002] {
        results.push((dt, try_mean_temperature(dt, 1000, 5000, 3)));
    }
    let any_tight = results
        .iter()
        .any(|(dt, r)| *dt <= MEMBRANE_MAX_TIMESTEP && r.as_ref().is_ok_and(|(t, _)| (t - 1.0).abs() < 0.005));
    for (dt, r) in results {
        let (t, se) = match r {
            Ok(r) => r,
            Err(e) => {
                eprintln!("SUMMARY capillary fluid dt = {dt}: unstable ({e})");
                continue;
            }
        };
        let ok = (t - 1.0).abs() < 0.015;
        let tight = (t - 1.0).abs() < 0.005;
        eprintln!(
            "SUMMARY capillary fluid dt = {dt}: kBT = {t:.4} ± {se:.4} ({:+.2} %){}{}",
            100.0 * (t - 1.0),
            if ok { "" } else { "  > 1.5 %" },
            if dt > MEMBRANE_MAX_TIMESTEP {
                "  (above the membrane's bound)"
            } else {
                ""
            }
        );
        if dt <= MEMBRANE_MAX_TIMESTEP && chosen.is_none() && (tight || (ok && !any_tight)) {
            chosen = Some(dt);
        }
    }
    eprintln!("SUMMARY chosen dt = {chosen:?}");
    assert_eq!(chosen, Some(CAPILLARY_FLUID_TIMESTEP));
}
