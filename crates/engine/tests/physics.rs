//! Physical checks of the engine against numbers: momentum conservation, the Groot–Warren
//! standard fluid's temperature and pressure, Newton's third law in the pair loop.

use crate::common::standard;
use glam::DVec3;
use hemodpd_engine::{observe, ForceField, ForceScheme, PairParams, Particles, SimConfig, Simulation};

/// Two particles (mid-box and across the periodic boundary), nonzero relative velocity: the
/// total pair force (conservative + dissipative + random) on one is exactly minus that on the
/// other, in both loop schemes, and both schemes agree.
#[test]
fn newton_third_law_in_the_pair_loop() {
    for (xa, xb) in [
        (DVec3::new(2.0, 2.1, 2.2), DVec3::new(2.5, 1.8, 2.4)),
        (DVec3::new(0.1, 2.1, 3.95), DVec3::new(3.8, 2.3, 0.2)),
    ] {
        let mut forces = Vec::new();
        for scheme in [ForceScheme::HalfShell, ForceScheme::Gather] {
            let mut config = SimConfig::new(DVec3::splat(4.0), 0.01, 5);
            config.scheme = scheme;
            let mut p = Particles::default();
            p.push(xa, DVec3::new(0.7, -0.2, 0.1), 0, 10);
            p.push(xb, DVec3::new(-0.4, 0.3, 0.5), 0, 3);
            let sim = Simulation::new(config, ForceField::single(PairParams::groot_warren()), p).unwrap();
            let f = &sim.particles().force;
            assert!(f[0].length() > 1.0);
            assert_eq!(f[0], -f[1], "{scheme:?}: {} vs {}", f[0], f[1]);
            forces.push(f[0]);
        }
        assert!((forces[0] - forces[1]).length() <= 1e-13 * forces[0].length());
    }
}

/// Total momentum with no body force over 10^4 steps, 192 particles (L = 4, ρ = 3).
/// Each pair force is applied exactly antisymmetrically (half shell), so the only source of
/// drift is rounding in the per-particle updates v += ½Δt f: ~ε|Δv| ≈ 1e-16 × 0.1 per particle
/// and step, a random walk over 192 × 2 × 10^4 updates gives |ΔP| ~ 1e-14 — we allow 1e-11
/// in total (5e-14 per particle), orders of magnitude below any physical effect (a single
/// particle's thermal momentum is 1).
#[test]
fn momentum_is_conserved() {
    for scheme in [ForceScheme::HalfShell, ForceScheme::Gather] {
        let mut sim = standard(4.0, 0.01, 11, scheme);
        let p0 = observe::momentum(sim.particles(), sim.field());
        assert!(p0.length() < 1e-12);
        sim.run(10_000).unwrap();
        let p1 = observe::momentum(sim.particles(), sim.field());
        let dp = (p1 - p0).length();
        eprintln!("{scheme:?}: |ΔP| after 10^4 steps = {dp:e}");
        assert!(dp < 1e-11, "{scheme:?}: |ΔP| = {dp:e}");
    }
}

/// Standard fluid (ρ = 3, a = 25, γ = 4.5, kBT = 1, rc = 1, Δt = 0.01), L = 8 (1536 particles),
/// 500 steps equilibration + 6000 steps; T sampled every step, p every 5th step.
/// * ⟨kBT⟩ within 1% of 1 (SPEC §7). The integrator's own bias at Δt = 0.01, λ = 0.5 is
///   +0.58 ± 0.11 % (150 time units, docs/engine.md); the block SE of this run is ≈ 0.002, so the
///   margin to 1% is ≈ 2 SE (measured 1.0081 ± 0.0021). A tighter test needs ~5× the run.
/// * ⟨p⟩ = 23.7 (Groot–Warren Fig. 4: α = 0.092 at ρ = 3; digitised to ±0.0005 in α ⇒ ±0.11 in
///   p; LAMMPS gives 23.70–23.73 for this fluid). Block SE of our mean ≈ 0.011. Tolerance 0.35
///   (1.5%): digitisation (0.11) + 5 SE (0.06) + Δt bias (+0.02, table) + finite size (≲ 0.1),
///   with room to spare so that a changed seed does not fail it.
#[test]
fn standard_fluid_temperature_and_pressure() {
    let mut sim = standard(8.0, 0.01, 2024, ForceScheme::HalfShell);
    sim.run(500).unwrap();
    let (mut ts, mut ps) = (Vec::new(), Vec::new());
    for k in 0..6000 {
        if k % 5 == 0 {
            let w = sim.step_with_virial().unwrap();
            ps.push(observe::pressure(sim.particles(), sim.field(), sim.domain(), &w));
        } else {
            sim.step().unwrap();
        }
        ts.push(observe::temperature(sim.particles(), sim.field()));
    }
    let (t, set) = observe::block_error(&ts).unwrap();
    let (p, sep) = observe::block_error(&ps).unwrap();
    eprintln!("standard fluid L=8: kBT = {t:.5} ± {set:.5}, p = {p:.4} ± {sep:.4}");
    assert!((t - 1.0).abs() < 0.01, "T = {t}");
    assert!(set < 0.003, "T SE {set}");
    assert!((p - 23.7).abs() < 0.35, "p = {p} ± {sep}");
    assert!(sep < 0.1, "p SE {sep}");
}
