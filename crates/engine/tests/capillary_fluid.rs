//! The capillary fluid ([`PairParams::capillary`]: a = 25, γ = 40, s = 1/4, ρ = 3) at rest: its
//! time step keeps the kinetic temperature at the thermostat's (the viscosity is measured in
//! viscosity.rs).

use glam::DVec3;
use hemodpd_engine::params::{CAPILLARY_FLUID_DENSITY, CAPILLARY_FLUID_TIMESTEP};
use hemodpd_engine::{init, observe, ForceField, PairParams, SimConfig, Simulation};

/// Mean kinetic kBT of an 8 × 8 × 8 periodic box of the capillary fluid at rest over `nsample`
/// steps after `neq`, and its block-averaged standard error.
fn mean_temperature(dt: f64, neq: u64, nsample: u64, seed: u64) -> (f64, f64) {
    let config = SimConfig::new(DVec3::splat(8.0), dt, seed);
    let field = ForceField::single(PairParams::capillary());
    let spec = init::FluidSpec {
        density: CAPILLARY_FLUID_DENSITY,
        ..init::FluidSpec::standard()
    };
    let p = init::fluid(&config, &field, &spec, seed + 1).unwrap();
    let mut sim = Simulation::new(config, field, p).unwrap();
    sim.run(neq).unwrap();
    let mut t = Vec::with_capacity(nsample as usize);
    for _ in 0..nsample {
        sim.step().unwrap();
        t.push(observe::temperature(sim.particles(), sim.field()));
    }
    observe::block_average(&t, 10).unwrap()
}

/// At [`CAPILLARY_FLUID_TIMESTEP`] the box keeps kBT within 1.5 % of 1 (the criterion the
/// step was chosen by; the mean of 3000 steps has an SE ≈ 0.001).
#[test]
fn capillary_fluid_temperature_at_its_timestep() {
    let (t, se) = mean_temperature(CAPILLARY_FLUID_TIMESTEP, 500, 3000, 7);
    eprintln!("capillary fluid, dt = {CAPILLARY_FLUID_TIMESTEP}: kBT = {t:.4} ± {se:.4}");
    assert!((t - 1.0).abs() < 0.015, "kBT = {t} ± {se}");
}

/// The scan behind [`CAPILLARY_FLUID_TIMESTEP`]: kBT at Δt = 0.01, 0.005, 0.004, 0.0025
/// (8 × 8 × 8, 1000 steps of equilibration, mean of the next 5000). The chosen step is the
/// largest of 0.005, 0.004, 0.0025 within 1.5 % of 1.
#[test]
#[ignore]
fn capillary_fluid_timestep_scan() {
    let mut chosen = None;
    for dt in [0.01, 0.005, 0.004, 0.0025] {
        let (t, se) = mean_temperature(dt, 1000, 5000, 3);
        let ok = (t - 1.0).abs() < 0.015;
        eprintln!(
            "SUMMARY capillary fluid dt = {dt}: kBT = {t:.4} ± {se:.4} ({:+.2} %){}",
            100.0 * (t - 1.0),
            if ok { "" } else { "  > 1.5 %" }
        );
        if ok && dt <= 0.005 && chosen.is_none() {
            chosen = Some(dt);
        }
    }
    eprintln!("SUMMARY chosen dt = {chosen:?}");
    assert_eq!(chosen, Some(CAPILLARY_FLUID_TIMESTEP));
}
