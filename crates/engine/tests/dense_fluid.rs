//! The dense fluid ([`PairParams::dense`]: n = 10, a = 100, γ = 41, s = 1/8) at rest: the
//! kinetic temperature at its time step and its sound speed (the viscosity is measured in
//! viscosity.rs, the wall slip in tests/capillary.rs). The scenario crate's fluid table
//! (`hemodpd_scenario::units::FluidModel::table`) ships these numbers; the ignored tests here
//! re-measure them (`cargo test --release -p hemodpd-engine --test engine -- dense_fluid:: --ignored
//! --nocapture`, ≈ 2 min on 2 cores).

use glam::DVec3;
use hemodpd_engine::params::{
    DENSE_FLUID_DENSITY, DENSE_FLUID_SOUND_SPEED, DENSE_FLUID_TIMESTEP, VISCOUS_FLUID_KBT_AT_TIMESTEP,
    VISCOUS_FLUID_TIMESTEP,
};
use hemodpd_engine::{init, observe, EngineError, ForceField, PairParams, SimConfig, Simulation};

/// A measured mean and its standard error.
type MeanSe = (f64, f64);

/// Mean kinetic kBT and virial pressure of a periodic box of side `side` of a fluid of the dense
/// fluid's family (`pair`: the dense or the viscous fluid) at number density `density` over
/// `nsample` steps after `neq` (pressure sampled every 5th step), with block-averaged standard
/// errors; an error where the integration blows up.
fn try_measure(
    pair: PairParams,
    density: f64,
    dt: f64,
    side: f64,
    neq: u64,
    nsample: u64,
    seed: u64,
) -> Result<(MeanSe, MeanSe), EngineError> {
    let config = SimConfig::new(DVec3::splat(side), dt, seed);
    let field = ForceField::single(pair);
    let spec = init::FluidSpec {
        density,
        ..init::FluidSpec::standard()
    };
    let p = init::fluid(&config, &field, &spec, seed + 1).unwrap();
    let mut sim = Simulation::new(config, field, p).unwrap();
    sim.run(neq)?;
    let (mut t, mut pr) = (Vec::new(), Vec::new());
    for k in 0..nsample {
        if k % 5 == 0 {
            let virial = sim.step_with_virial()?;
            pr.push(observe::pressure(sim.particles(), sim.field(), sim.domain(), &virial));
        } else {
            sim.step()?;
        }
        t.push(observe::temperature(sim.particles(), sim.field()));
    }
    Ok((
        observe::block_average(&t, 10).unwrap(),
        observe::block_average(&pr, 10).unwrap(),
    ))
}

/// At [`DENSE_FLUID_TIMESTEP`] a 6³ box (2160 particles) keeps kBT within 0.5 % of 1 (the
/// scan below finds +0.1 %; the mean of 3000 steps has an SE ≈ 0.001), and the equation of
/// state is stiff: p ≈ 1000 (Groot–Warren's p = ρ + 0.101·a·ρ² = 1020).
#[test]
fn dense_fluid_temperature_at_its_timestep() {
    let ((t, se), (p, pse)) = try_measure(
        PairParams::dense(),
        DENSE_FLUID_DENSITY,
        DENSE_FLUID_TIMESTEP,
        6.0,
        300,
        3000,
        7,
    )
    .unwrap();
    eprintln!("dense fluid, dt = {DENSE_FLUID_TIMESTEP}: kBT = {t:.4} ± {se:.4}, p = {p:.1} ± {pse:.1}");
    assert!((t - 1.0).abs() < 0.005, "kBT = {t} ± {se}");
    assert!((p / 1020.0 - 1.0).abs() < 0.1, "p = {p}");
}

/// The scan behind [`DENSE_FLUID_TIMESTEP`]: kBT at Δt = 0.002, 0.0025, 0.003, 0.0035, 0.004
/// (8³ box, 1000 steps of equilibration, mean of the next 4000; a step that blows up is
/// reported as such). Asserts that the chosen step keeps kBT within 0.5 % of 1 and that the
/// next candidate above 0.0035 is either unstable or more than 1 % off: the chosen step keeps a
/// margin from the friction limit.
#[test]
#[ignore]
fn dense_fluid_timestep_scan() {
    let mut at_chosen = None;
    let mut at_004 = None;
    for dt in [0.002, 0.0025, 0.003, 0.0035, 0.004] {
        match try_measure(PairParams::dense(), DENSE_FLUID_DENSITY, dt, 8.0, 1000, 4000, 3) {
            Ok(((t, se), (p, pse))) => {
                eprintln!(
                    "SUMMARY dense fluid Δt = {dt} (γΔt = {:.3}): kBT = {t:.4} ± {se:.4}, p = {p:.2} ± {pse:.2}",
                    41.0 * dt
                );
                if dt == DENSE_FLUID_TIMESTEP {
                    at_chosen = Some(t);
                }
                if dt == 0.004 {
                    at_004 = Some(t);
                }
            }
            Err(e) => eprintln!("SUMMARY dense fluid Δt = {dt} (γΔt = {:.3}): unstable ({e})", 41.0 * dt),
        }
    }
    let t = at_chosen.expect("the chosen step is stable");
    assert!((t - 1.0).abs() < 0.005, "kBT = {t} at the chosen step");
    if let Some(t4) = at_004 {
        assert!(
            (t4 - 1.0).abs() > 0.01,
            "Δt = 0.004 is stable and accurate (kBT {t4}): the step could be raised"
        );
    }
}

/// The viscous fluid's sound speed, measured as `dense_fluid_sound_speed` at its own step
/// (20 000 sampled steps per density: its virial is noisier); printed beside the dense fluid's.
#[test]
#[ignore]
fn viscous_fluid_sound_speed() {
    let mut p = Vec::new();
    for (k, n) in [9.5, 10.5].into_iter().enumerate() {
        let ((t, _), (pm, pse)) = try_measure(
            PairParams::viscous(),
            n,
            VISCOUS_FLUID_TIMESTEP,
            8.0,
            1000,
            20000,
            20 + k as u64,
        )
        .unwrap();
        eprintln!("SUMMARY viscous fluid ρ = {n}: p = {pm:.2} ± {pse:.2}, kBT {t:.4}");
        p.push((pm, pse));
    }
    let c2 = p[1].0 - p[0].0;
    let c2_se = (p[1].1.powi(2) + p[0].1.powi(2)).sqrt();
    let c = c2.sqrt();
    eprintln!(
        "SUMMARY viscous fluid sound speed c = {c:.3} ± {:.3}; dense fluid's constant {DENSE_FLUID_SOUND_SPEED}",
        0.5 * c2_se / c
    );
    assert!((c - DENSE_FLUID_SOUND_SPEED).abs() < 1.5 * c2_se / c + 0.3, "c = {c}");
}

/// The measurement behind [`DENSE_FLUID_SOUND_SPEED`]: the virial pressure at ρ = 9.5, 10 and
/// 10.5 (8³ box, 6000 sampled steps after 1000, Δt = [`DENSE_FLUID_TIMESTEP`]); c² = dp/dρ
/// (m = 1) by the central difference. Asserts the constant within 3 standard errors of the
/// difference (the pressures' SEs combined) and prints the Groot–Warren estimate beside it.
#[test]
#[ignore]
fn dense_fluid_sound_speed() {
    let mut p = Vec::new();
    for (k, n) in [9.5, 10.0, 10.5].into_iter().enumerate() {
        let ((t, _), (pm, pse)) = try_measure(
            PairParams::dense(),
            n,
            DENSE_FLUID_TIMESTEP,
            8.0,
            1000,
            6000,
            20 + k as u64,
        )
        .unwrap();
        eprintln!("SUMMARY dense fluid ρ = {n}: p = {pm:.2} ± {pse:.2}, kBT {t:.4}");
        p.push((pm, pse));
    }
    let c2 = (p[2].0 - p[0].0) / 1.0;
    let c2_se = (p[2].1.powi(2) + p[0].1.powi(2)).sqrt();
    let c = c2.sqrt();
    let c_se = 0.5 * c2_se / c;
    let eos = hemodpd_engine::params::sound_speed(&PairParams::dense(), DENSE_FLUID_DENSITY, 1.0);
    eprintln!(
        "SUMMARY dense fluid sound speed c = {c:.3} ± {c_se:.3} (c² = {c2:.1} ± {c2_se:.1}); Groot–Warren EOS {eos:.3}; constant {DENSE_FLUID_SOUND_SPEED}"
    );
    assert!(
        (c - DENSE_FLUID_SOUND_SPEED).abs() < 3.0 * c_se + 0.01,
        "c = {c} ± {c_se}"
    );
}

/// The viscous fluid ([`PairParams::viscous`]: the dense fluid with γ = 410) at its step
/// Δt = 0.0003 (γΔt = 0.123, the dense fluid's): a 6³ box keeps kBT within 0.5 % of 1 and of the
/// table's value, and its virial pressure is the dense fluid's at the same step (the
/// conservative force is the same, and the thermostat samples the same canonical ensemble at any
/// γ; at its own Δt = 0.003 the dense fluid reads ≈ 3 % higher, a step error): within 3 combined
/// SE plus 0.5 % (the viscous fluid's virial carries its large dissipative and random pair
/// forces: SE ≈ 7 against ≈ 2). Measured: 987.2 ± 7.4 against 1007.9 ± 2.4.
#[test]
fn viscous_fluid_temperature_and_pressure() {
    // both fluids at the viscous fluid's step, the same box and seed
    let at_step = |pair| try_measure(pair, DENSE_FLUID_DENSITY, VISCOUS_FLUID_TIMESTEP, 6.0, 300, 3000, 7).unwrap();
    let ((t, se), (p, pse)) = at_step(PairParams::viscous());
    let (_, (pd, pdse)) = at_step(PairParams::dense());
    eprintln!(
        "viscous fluid, dt = {VISCOUS_FLUID_TIMESTEP}: kBT = {t:.4} ± {se:.4}, p = {p:.1} ± {pse:.1}; dense fluid p = {pd:.1} ± {pdse:.1}"
    );
    assert!((t - 1.0).abs() < 0.005, "kBT = {t} ± {se}");
    assert!(
        (t - VISCOUS_FLUID_KBT_AT_TIMESTEP).abs() < 0.003,
        "kBT = {t} ± {se} vs the table's {VISCOUS_FLUID_KBT_AT_TIMESTEP}"
    );
    assert!(
        (p - pd).abs() < 3.0 * (pse * pse + pdse * pdse).sqrt() + 0.005 * pd,
        "p = {p} ± {pse}, dense {pd} ± {pdse}"
    );
}

/// The scan behind [`VISCOUS_FLUID_TIMESTEP`]: kBT at γΔt = 0.082, 0.103, 0.123, 0.144, 0.164
/// (Δt = 0.0002 … 0.0004; 8³ box, 1000 steps of equilibration, mean of the next 4000), as
/// `dense_fluid_timestep_scan` for the dense fluid: the explicit friction's error depends on
/// γΔt at a given density and weight, so the dense fluid's limit should carry over. Asserts
/// the chosen step within 0.5 % of 1 and the table's kBT within 0.3 %.
#[test]
#[ignore]
fn viscous_fluid_timestep_scan() {
    let mut at_chosen = None;
    for dt in [0.0002, 0.00025, 0.0003, 0.00035, 0.0004] {
        let gdt = PairParams::viscous().gamma * dt;
        match try_measure(PairParams::viscous(), DENSE_FLUID_DENSITY, dt, 8.0, 1000, 4000, 3) {
            Ok(((t, se), (p, pse))) => {
                eprintln!(
                    "SUMMARY viscous fluid Δt = {dt} (γΔt = {gdt:.3}): kBT = {t:.4} ± {se:.4}, p = {p:.2} ± {pse:.2}"
                );
                if dt == VISCOUS_FLUID_TIMESTEP {
                    at_chosen = Some(t);
                }
            }
            Err(e) => eprintln!("SUMMARY viscous fluid Δt = {dt} (γΔt = {gdt:.3}): unstable ({e})"),
        }
    }
    let t = at_chosen.expect("the chosen step is stable");
    assert!((t - 1.0).abs() < 0.005, "kBT = {t} at the chosen step");
    assert!(
        (t - VISCOUS_FLUID_KBT_AT_TIMESTEP).abs() < 0.003,
        "kBT = {t}, table {VISCOUS_FLUID_KBT_AT_TIMESTEP}"
    );
}
