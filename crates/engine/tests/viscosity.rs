//! Shear viscosity of the standard DPD fluid by reverse (periodic) Poiseuille flow
//! (Backer et al., J. Chem. Phys. 122:154503, 2005): body force +g along x for z < Lz/2 and −g
//! for z ≥ Lz/2, applied through the [`Extension`] seam. In steady state each half carries a
//! parabola v_x = (ρg/2η) z'(h − z') + c (h = Lz/2, z' measured from the half's start, sign
//! flipped in the second half); a least-squares fit of A = ρg/2η in each half gives η.

mod common;

use glam::DVec3;
use hemodpd_engine::{init, observe, EngineError, Extension, ForceField, PairParams, SimConfig, Simulation, StateMut};

struct ReversePoiseuille {
    g: f64,
    half: f64,
}

impl Extension for ReversePoiseuille {
    fn add_forces(&mut self, s: &mut StateMut<'_>) -> Result<(), EngineError> {
        for (f, x) in s.force.iter_mut().zip(s.pos.iter()) {
            f.x += if x.z < self.half { self.g } else { -self.g };
        }
        Ok(())
    }
}

/// Least-squares fit of y = A·q(z) + c; returns A.
fn fit_parabola(z: &[f64], y: &[f64], q: impl Fn(f64) -> f64) -> f64 {
    let n = z.len() as f64;
    let qs: Vec<f64> = z.iter().map(|&z| q(z)).collect();
    let (sq, sy) = (qs.iter().sum::<f64>(), y.iter().sum::<f64>());
    let sqq = qs.iter().map(|q| q * q).sum::<f64>();
    let sqy = qs.iter().zip(y).map(|(q, y)| q * y).sum::<f64>();
    (n * sqy - sq * sy) / (n * sqq - sq * sq)
}

/// Viscosities from one reverse-Poiseuille run.
pub struct ReversePoiseuilleResult {
    /// η of each half, fitted over the whole half (including the bins at the kinks).
    pub whole: [f64; 2],
    /// η of each half, fitted over the bins at least rc = 1 from the kinks, where DPD's
    /// non-local stress leaves the parabola exact.
    pub interior: [f64; 2],
    /// Peculiar kBT against the measured profile (viscous heating check).
    pub peculiar_kbt: f64,
}

/// Runs the reverse-Poiseuille measurement.
/// The fluid starts from the steady profile of η0 = 0.9 so that only the (small) mismatch has
/// to relax (slowest mode τ = ρ Lz²/(4π² η) ≈ 8.4 for Lz = 10).
pub fn reverse_poiseuille(
    lxy: f64,
    lz: f64,
    g: f64,
    neq: u64,
    nsample: u64,
    every: u64,
    seed: u64,
) -> ReversePoiseuilleResult {
    let config = SimConfig::new(DVec3::new(lxy, lxy, lz), 0.01, seed);
    let field = ForceField::single(PairParams::groot_warren());
    let mut p = init::fluid(&config, &field, &init::FluidSpec::standard(), seed + 1).unwrap();
    let h = 0.5 * lz;
    let rho = p.len() as f64 / (lxy * lxy * lz);
    let eta0 = 0.9;
    let a0 = rho * g / (2.0 * eta0);
    for (x, v) in p.pos.iter().zip(p.vel.iter_mut()) {
        v.x += if x.z < h {
            a0 * x.z * (h - x.z) - a0 * h * h / 6.0
        } else {
            -(a0 * (x.z - h) * (lz - x.z) - a0 * h * h / 6.0)
        };
    }
    let ext = ReversePoiseuille { g, half: h };
    let mut sim = Simulation::with_extension(config, field, p, ext).unwrap();
    sim.run(neq).unwrap();
    let nbins = (lz * 2.0).round() as usize;
    let mut prof = observe::Profile::new(sim.domain(), 2, nbins, vec![]).unwrap();
    let mut temps = Vec::new();
    for k in 0..nsample {
        sim.step().unwrap();
        if k % every == 0 {
            prof.sample(sim.particles(), sim.field());
        }
    }
    let z = prof.centres();
    let vx: Vec<f64> = prof.velocity().iter().map(|v| v.x).collect();
    let nb2 = nbins / 2;
    let a1 = fit_parabola(&z[..nb2], &vx[..nb2], |z| z * (h - z));
    let a2 = -fit_parabola(&z[nb2..], &vx[nb2..], |z| (z - h) * (lz - z));
    // interior: bins whose centre is at least rc from both kinks of its half
    let inner = |lo: f64| -> (Vec<f64>, Vec<f64>) {
        z.iter()
            .zip(&vx)
            .filter(|(&z, _)| z - lo >= 1.0 && lo + h - z >= 1.0)
            .map(|(&z, &v)| (z, v))
            .unzip()
    };
    let (z1, v1) = inner(0.0);
    let (z2, v2) = inner(h);
    let a1i = fit_parabola(&z1, &v1, |z| z * (h - z));
    let a2i = -fit_parabola(&z2, &v2, |z| (z - h) * (lz - z));
    // Peculiar temperature against the measured profile (viscous heating check).
    let bw = lz / nbins as f64;
    let vprof = prof.velocity();
    temps.push(observe::peculiar_temperature(sim.particles(), sim.field(), |x| {
        vprof[((x.z / bw) as usize).min(nbins - 1)]
    }));
    let eta = |a: f64| rho * g / (2.0 * a);
    ReversePoiseuilleResult {
        whole: [eta(a1), eta(a2)],
        interior: [eta(a1i), eta(a2i)],
        peculiar_kbt: temps[0],
    }
}

/// Quick version (750 particles, 7000 steps, g = 0.2, ≈ 2 s). Reference values: our long run
/// (docs/engine.md) gives η = 0.846 ± 0.002 (g = 0.1, 6×6×16, 8 halves); published
/// measurements of this fluid are η ≈ 0.85–1.0; kinetic theory (no correlations) gives 0.957
/// (reference/dpd_viscosity_kinetic_theory.csv). The quick run's own scatter is ≈ 0.04 per
/// half (long-run seed-to-seed scatter 0.01 scaled by √(steps ratio × volume ratio)).
/// Accepted: each half in [0.74, 1.00] and the mean of the halves in [0.76, 1.00], i.e. the
/// published band widened downward by 2–2.5× the quick run's scatter; a broken dissipative or
/// random force (wrong σ, γ, or weight) moves η by far more.
#[test]
fn viscosity_reverse_poiseuille_quick() {
    let r = reverse_poiseuille(5.0, 10.0, 0.2, 2500, 4500, 5, 11);
    let ([e1, e2], t) = (r.whole, r.peculiar_kbt);
    let eta = 0.5 * (e1 + e2);
    eprintln!("quick reverse Poiseuille: η = {e1:.4}, {e2:.4} (mean {eta:.4}), kBT_pec = {t:.4}");
    for e in [e1, e2] {
        assert!((0.74..=1.00).contains(&e), "η = {e}");
    }
    assert!((0.76..=1.00).contains(&eta), "η = {eta}");
}

/// Long version for the docs: `cargo test --release -p hemodpd-engine --test viscosity -- --ignored --nocapture`.
#[test]
#[ignore]
fn viscosity_reverse_poiseuille_long() {
    for (lxy, lz, g) in [(6.0, 16.0, 0.1), (6.0, 16.0, 0.05)] {
        let (mut whole, mut interior) = (Vec::new(), Vec::new());
        for seed in [1u64, 2, 3, 4] {
            let r = reverse_poiseuille(lxy, lz, g, 6000, 30000, 5, seed);
            eprintln!(
                "L = {lxy}x{lxy}x{lz}, g = {g}, seed {seed}: η = {:.4} {:.4} (interior {:.4} {:.4}), kBT_pec = {:.4}",
                r.whole[0], r.whole[1], r.interior[0], r.interior[1], r.peculiar_kbt
            );
            whole.extend(r.whole);
            interior.extend(r.interior);
        }
        for (name, etas) in [("whole halves", &whole), ("interior", &interior)] {
            let m = etas.iter().sum::<f64>() / etas.len() as f64;
            let sd = (etas.iter().map(|e| (e - m).powi(2)).sum::<f64>() / (etas.len() - 1) as f64).sqrt();
            eprintln!(
                "L = {lxy}x{lxy}x{lz}, g = {g}, {name}: η = {m:.4} ± {:.4} (SE over {} halves)",
                sd / (etas.len() as f64).sqrt(),
                etas.len()
            );
        }
    }
}
