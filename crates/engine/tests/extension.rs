//! The extension seam: hooks are called in order once per step, frozen types do not move,
//! body forces act.

use glam::DVec3;
use hemodpd_engine::{
    init, observe, EngineError, Extension, ForceField, PairParams, SimConfig, Simulation, StateMut, TypeSpec,
};

#[derive(Default)]
struct Recorder {
    calls: Vec<(&'static str, u64)>,
}

impl Extension for Recorder {
    fn after_position_update(&mut self, s: &mut StateMut<'_>) -> Result<(), EngineError> {
        self.calls.push(("move", s.step));
        Ok(())
    }
    fn add_forces(&mut self, s: &mut StateMut<'_>) -> Result<(), EngineError> {
        self.calls.push(("force", s.step));
        Ok(())
    }
    fn end_of_step(&mut self, s: &mut StateMut<'_>) -> Result<(), EngineError> {
        self.calls.push(("end", s.step));
        Ok(())
    }
}

#[test]
fn hooks_run_in_order() {
    let config = SimConfig::new(DVec3::splat(4.0), 0.01, 1);
    let field = ForceField::single(PairParams::groot_warren());
    let p = init::fluid(&config, &field, &init::FluidSpec::standard(), 1).unwrap();
    let mut sim = Simulation::with_extension(config, field, p, Recorder::default()).unwrap();
    sim.run(2).unwrap();
    assert_eq!(
        sim.extension().calls,
        vec![
            ("force", 0), // initial force evaluation
            ("move", 0),
            ("force", 0),
            ("end", 1),
            ("move", 1),
            ("force", 1),
            ("end", 2)
        ]
    );
}

/// A frozen "wall" type keeps its positions bit for bit while the fluid moves; a body force
/// g on the fluid accelerates it: with walls taking up momentum the fluid's mean velocity
/// still grows (checked loosely), and without walls P_x grows by exactly N g t (to 1e-9 rel).
#[test]
fn frozen_types_and_body_force() {
    let config = SimConfig::new(DVec3::splat(5.0), 0.01, 3);
    let mut field = ForceField::new(
        vec![TypeSpec::new("solvent"), TypeSpec::frozen("wall")],
        PairParams::groot_warren(),
    )
    .unwrap();
    let mut p = init::fluid(&config, &field, &init::FluidSpec::standard(), 2).unwrap();
    let n = p.len();
    for i in (0..n).step_by(10) {
        p.ptype[i] = 1;
        p.vel[i] = DVec3::ZERO;
    }
    field.set_body_force(0, DVec3::new(0.1, 0.0, 0.0)).unwrap();
    // By id: a plain fluid's storage is reordered every `sort_every` steps.
    let frozen = |p: &hemodpd_engine::Particles| {
        let mut v: Vec<(u32, [f64; 3])> = (0..n)
            .filter(|&i| p.ptype[i] == 1)
            .map(|i| (p.id[i], p.pos[i].to_array()))
            .collect();
        v.sort_by_key(|e| e.0);
        v
    };
    let frozen_before = frozen(&p);
    let mut sim = Simulation::new(config.clone(), field.clone(), p).unwrap();
    sim.run(200).unwrap();
    let q = sim.particles();
    assert_eq!(frozen_before, frozen(q));
    let vx: f64 = (0..n).filter(|&i| q.ptype[i] == 0).map(|i| q.vel[i].x).sum::<f64>() / (n - n.div_ceil(10)) as f64;
    assert!(vx > 0.0 && vx.is_finite());

    // No walls: dP/dt = N g exactly (pair forces cancel).
    let field = {
        let mut f = ForceField::single(PairParams::groot_warren());
        f.set_body_force(0, DVec3::new(0.1, 0.0, 0.0)).unwrap();
        f
    };
    let p = init::fluid(&config, &field, &init::FluidSpec::standard(), 2).unwrap();
    let n = p.len() as f64;
    let mut sim = Simulation::new(config, field, p).unwrap();
    sim.run(100).unwrap();
    let px = observe::momentum(sim.particles(), sim.field()).x;
    let expect = n * 0.1 * 100.0 * 0.01;
    assert!((px - expect).abs() < 1e-9 * expect, "{px} vs {expect}");
}

/// Moves the particles of one type itself (a rigid translation, kicked by their pair forces as
/// the engine would) and records the largest pair force they felt from the frozen type.
struct OwnIntegrator {
    ptype: u16,
    /// Largest pair force (the force less the body force).
    max_force: f64,
    /// Whether every force was exactly the body force.
    body_only: bool,
}

impl Extension for OwnIntegrator {
    fn after_position_update(&mut self, s: &mut StateMut<'_>) -> Result<(), EngineError> {
        let body = s.field.types()[self.ptype as usize].body_force;
        for i in 0..s.pos.len() {
            if s.ptype[i] == self.ptype {
                self.max_force = self.max_force.max((s.force[i] - body).length());
                self.body_only &= s.force[i] == body;
            }
        }
        Ok(())
    }
}

/// A type integrated by an extension: the engine neither moves nor kicks it (its positions and
/// velocities are unchanged bit for bit, the extension above does not move them), but its force
/// holds its body force and its pair forces, from the frozen type too (frozen–frozen pairs are
/// skipped; this type is not frozen).
#[test]
fn types_integrated_by_an_extension_are_left_to_it() {
    let config = SimConfig::new(DVec3::splat(5.0), 0.01, 3);
    let mut field = ForceField::new(
        vec![
            TypeSpec::new("solvent"),
            TypeSpec::frozen("wall"),
            TypeSpec {
                integrated_by_extension: true,
                ..TypeSpec::new("held")
            },
        ],
        PairParams::groot_warren(),
    )
    .unwrap();
    // only the wall acts on the held type: a large pair force would show if the pair were skipped
    let none = PairParams {
        a: 0.0,
        gamma: 0.0,
        kbt: 0.0,
        ..PairParams::groot_warren()
    };
    field.set_pair(0, 2, none).unwrap();
    field.set_pair(2, 2, none).unwrap();
    field.set_body_force(2, DVec3::new(5.0, 0.0, 0.0)).unwrap();
    let mut p = init::fluid(&config, &field, &init::FluidSpec::standard(), 2).unwrap();
    let n = p.len();
    for i in 0..n {
        match i % 10 {
            0 => {
                p.ptype[i] = 1;
                p.vel[i] = DVec3::ZERO;
            }
            1 => p.ptype[i] = 2,
            _ => {}
        }
    }
    let held: Vec<usize> = (0..n).filter(|i| i % 10 == 1).collect();
    let before: Vec<(DVec3, DVec3)> = held.iter().map(|&i| (p.pos[i], p.vel[i])).collect();
    let ext = OwnIntegrator {
        ptype: 2,
        max_force: 0.0,
        body_only: true,
    };
    let mut sim = Simulation::with_extension(config.clone(), field.clone(), p.clone(), ext).unwrap();
    sim.run(20).unwrap();
    let q = sim.particles();
    let after: Vec<(DVec3, DVec3)> = held.iter().map(|&i| (q.pos[i], q.vel[i])).collect();
    assert_eq!(before, after);
    // a = 25 at a typical wall neighbour distance of 0.5 rc gives forces of order 10
    assert!(sim.extension().max_force > 1.0, "{}", sim.extension().max_force);
    assert!(!sim.extension().body_only);
    // without the wall pair, the force is the body force exactly
    field.set_pair(1, 2, none).unwrap();
    let ext = OwnIntegrator {
        ptype: 2,
        max_force: 0.0,
        body_only: true,
    };
    let mut sim = Simulation::with_extension(config, field, p, ext).unwrap();
    sim.run(5).unwrap();
    assert!(sim.extension().body_only);
}
