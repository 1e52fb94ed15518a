//! Bad input and numerical instability are typed errors, never panics or NaNs.

use crate::common::standard;
use glam::DVec3;
use hemodpd_engine::{
    init, EngineError, Extension, ForceField, ForceScheme, PairParams, Particles, SimConfig, Simulation, StateMut,
    TypeSpec,
};

/// Δt = 5 in the standard fluid: the first step moves particles by ~|v|Δt ≈ 8 ≫ one cell.
#[test]
fn huge_time_step_is_reported() {
    let mut config = SimConfig::new(DVec3::splat(6.0), 0.01, 1);
    let field = ForceField::single(PairParams::groot_warren());
    let p = init::fluid(&config, &field, &init::FluidSpec::standard(), 1).unwrap();
    config.dt = 5.0;
    let mut sim = Simulation::new(config, field, p).unwrap();
    let err = sim.run(10).unwrap_err();
    let msg = err.to_string();
    assert!(
        matches!(
            err,
            EngineError::TooFast { step: 0, .. } | EngineError::NonFinite { step: 0, .. }
        ),
        "{msg}"
    );
    assert!(msg.contains("step 0") && msg.contains("particle id"), "{msg}");
    assert!(msg.contains("time step"), "{msg}");
}

/// Two particles 10^-3 apart with a = 10^7: F ≈ 10^7, the kick ½Δt F/m ≈ 5·10^4 moves them
/// ~500 ≫ cell in one step. The error names the step, the particle id and its type.
#[test]
fn overlapping_particles_are_reported() {
    let config = SimConfig::new(DVec3::splat(4.0), 0.01, 1);
    let mut pp = PairParams::groot_warren();
    pp.a = 1e7;
    let field = ForceField::single(pp);
    let mut p = Particles::default();
    p.push(DVec3::splat(2.0), DVec3::ZERO, 0, 41);
    p.push(DVec3::new(2.001, 2.0, 2.0), DVec3::ZERO, 0, 42);
    let mut sim = Simulation::new(config, field, p).unwrap();
    let err = sim.step().unwrap_err();
    let msg = err.to_string();
    match &err {
        EngineError::TooFast { step, id, ptype, .. } => {
            assert_eq!(*step, 0);
            assert!(*id == 41 || *id == 42);
            assert_eq!(*ptype, 0);
        }
        e => panic!("wrong error {e}"),
    }
    assert!(msg.contains("particle id 41"), "{msg}");
    assert!(msg.contains("overlapping"), "{msg}");
}

/// A NaN produced by an extension's force is caught after the step, with the quantity named.
#[test]
fn non_finite_force_is_reported() {
    struct Poison;
    impl Extension for Poison {
        fn add_forces(&mut self, s: &mut StateMut<'_>) -> Result<(), EngineError> {
            if s.step == 3 {
                s.force[7].y = f64::NAN;
            }
            Ok(())
        }
    }
    let sim = standard(4.0, 0.01, 1, ForceScheme::HalfShell);
    let (state, ()) = sim.into_parts();
    let mut sim = Simulation::from_state(state, Poison).unwrap();
    let err = sim.run(10).unwrap_err();
    let msg = err.to_string();
    assert!(
        matches!(
            err,
            EngineError::NonFinite {
                step: 3,
                index: 7,
                quantity: "force",
                ..
            }
        ),
        "{msg}"
    );
    assert!(msg.contains("NaN"), "{msg}");
}

/// A plain fluid (`()` adds no forces) does its second half-kick in the pass that returns the
/// forces to storage order; a velocity that overflows there is caught just the same. Two
/// particles, out of range at the start (no force for the first kick), close to within the
/// cutoff in one step; with a = 10^308 and m = 10^-10 the second kick ½Δt F/m overflows. Also
/// with the storage sorted every step, where that pass writes the storage in cell order
/// (`SimConfig::sort_every = 1`): the error names one of the two particles.
#[test]
fn overflow_in_the_second_kick_of_a_plain_fluid_is_reported() {
    for sort_every in [0, 1] {
        let mut config = SimConfig::new(DVec3::splat(4.0), 0.01, 1);
        config.sort_every = sort_every;
        let mut pp = PairParams::groot_warren();
        pp.a = 1e308;
        let mut light = TypeSpec::new("light");
        light.mass = 1e-10;
        let field = ForceField::new(vec![light], pp).unwrap();
        let mut p = Particles::default();
        p.push(DVec3::new(1.0, 2.0, 2.0), DVec3::new(10.0, 0.0, 0.0), 0, 1);
        p.push(DVec3::new(2.05, 2.0, 2.0), DVec3::new(-10.0, 0.0, 0.0), 0, 2);
        let mut sim = Simulation::new(config, field, p).unwrap();
        assert!(!().adds_forces());
        let err = sim.step().unwrap_err();
        let msg = err.to_string();
        assert!(
            matches!(
                err,
                EngineError::NonFinite {
                    step: 0,
                    quantity: "velocity",
                    id: 1 | 2,
                    ..
                }
            ),
            "sort_every {sort_every}: {msg}"
        );
    }
}

#[test]
fn bad_input_is_rejected() {
    let field = ForceField::single(PairParams::groot_warren());
    let mut p = Particles::default();
    p.push(DVec3::ONE, DVec3::ZERO, 0, 0);
    let cases: Vec<(SimConfig, ForceField, Particles, &str)> = vec![
        // box smaller than 3 rc
        (
            SimConfig::new(DVec3::new(4.0, 2.5, 4.0), 0.01, 1),
            field.clone(),
            p.clone(),
            "3 cutoffs",
        ),
        (
            SimConfig::new(DVec3::new(4.0, -1.0, 4.0), 0.01, 1),
            field.clone(),
            p.clone(),
            "box",
        ),
        (
            SimConfig::new(DVec3::splat(4.0), 0.0, 1),
            field.clone(),
            p.clone(),
            "time step",
        ),
        (
            SimConfig::new(DVec3::splat(4.0), f64::NAN, 1),
            field.clone(),
            p.clone(),
            "time step",
        ),
        (
            SimConfig {
                lambda: 1.5,
                ..SimConfig::new(DVec3::splat(4.0), 0.01, 1)
            },
            field.clone(),
            p.clone(),
            "lambda",
        ),
        (
            SimConfig::new(DVec3::splat(4.0), 0.01, 1),
            field.clone(),
            Particles::default(),
            "no particles",
        ),
        (
            SimConfig::new(DVec3::splat(4.0), 0.01, 1),
            field.clone(),
            {
                let mut q = p.clone();
                q.push(DVec3::ONE, DVec3::ZERO, 3, 1);
                q
            },
            "out of range",
        ),
        (
            SimConfig::new(DVec3::splat(4.0), 0.01, 1),
            field.clone(),
            {
                let mut q = p.clone();
                q.push(DVec3::ONE, DVec3::ZERO, 0, 0);
                q
            },
            "used twice",
        ),
        (
            SimConfig::new(DVec3::splat(4.0), 0.01, 1),
            field.clone(),
            {
                let mut q = p.clone();
                q.vel[0].x = f64::INFINITY;
                q
            },
            "non-finite",
        ),
        (
            SimConfig::new(DVec3::splat(4.0), 0.01, 1),
            field.clone(),
            {
                let mut q = p.clone();
                q.id.push(5);
                q
            },
            "lengths differ",
        ),
    ];
    for (config, field, particles, expect) in cases {
        let err = Simulation::new(config, field, particles).unwrap_err();
        assert!(matches!(err, EngineError::InvalidInput { .. }));
        assert!(err.to_string().contains(expect), "expected '{expect}' in '{err}'");
    }
    // Parameter validation in the force field itself.
    let mut f = ForceField::new(
        vec![TypeSpec::new("a"), TypeSpec::frozen("wall")],
        PairParams::groot_warren(),
    )
    .unwrap();
    assert!(f.set_pair(0, 2, PairParams::groot_warren()).is_err());
    let mut bad = PairParams::groot_warren();
    bad.gamma = -1.0;
    assert!(f.set_pair(0, 1, bad).is_err());
    bad = PairParams::groot_warren();
    bad.s = 0.0;
    assert!(f.set_pair(0, 1, bad).is_err());
    assert!(f.set_body_force(0, DVec3::new(f64::NAN, 0.0, 0.0)).is_err());
    assert!(ForceField::new(vec![], PairParams::groot_warren()).is_err());
    // Density ≤ 0.
    let config = SimConfig::new(DVec3::splat(4.0), 0.01, 1);
    let spec = init::FluidSpec {
        density: 0.0,
        ..init::FluidSpec::standard()
    };
    assert!(init::fluid(&config, &f, &spec, 1).is_err());
}
