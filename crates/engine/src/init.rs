//! Initial fluid configurations, reproducible from a seed (xoshiro256++).

use glam::DVec3;
use rand_xoshiro::rand_core::{RngCore, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use serde::{Deserialize, Serialize};

use crate::{EngineError, ForceField, Particles, PeriodicBox, Real, SimConfig};

/// Where the particles go.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Placement {
    /// Uniformly random positions (DPD's soft repulsion copes with overlaps).
    Random,
    /// A simple-cubic-like lattice with at least N sites (N sites chosen at random if more),
    /// each displaced uniformly by up to ±`jitter` × the lattice spacing along each axis.
    JitteredLattice {
        /// Fraction of the spacing (0 = perfect lattice). Typical 0.1.
        jitter: Real,
    },
}

/// A fluid of one type at density ρ.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FluidSpec {
    /// Number density ρ (particles per volume); N = round(ρ V).
    pub density: Real,
    /// Type of the particles.
    pub ptype: u16,
    /// Temperature of the Maxwell–Boltzmann velocities (energy units).
    pub kbt: Real,
    /// Placement.
    pub placement: Placement,
    /// First global id (ids are `first_id..first_id + N`).
    pub first_id: u32,
}

impl FluidSpec {
    /// ρ = 3, type 0, kBT = 1, jittered lattice (jitter 0.1), ids from 0.
    pub fn standard() -> Self {
        Self {
            density: 3.0,
            ptype: 0,
            kbt: 1.0,
            placement: Placement::JitteredLattice { jitter: 0.1 },
            first_id: 0,
        }
    }
}

/// Uniform in [0, 1) from the top 53 bits.
#[inline]
fn uniform(rng: &mut Xoshiro256PlusPlus) -> Real {
    (rng.next_u64() >> 11) as Real * (1.0 / 9_007_199_254_740_992.0)
}

/// Standard normal pair by Box–Muller.
fn normal_pair(rng: &mut Xoshiro256PlusPlus) -> (Real, Real) {
    let u1 = 1.0 - uniform(rng); // (0, 1]
    let u2 = uniform(rng);
    let r = (-2.0 * u1.ln()).sqrt();
    let t = std::f64::consts::TAU * u2;
    (r * t.cos(), r * t.sin())
}

/// A fluid filling the box of `config`: N = round(ρV) particles of `spec.ptype`,
/// Maxwell–Boltzmann velocities at `spec.kbt` (mass from the force field) with zero total
/// momentum, zero forces. Deterministic in `seed`.
pub fn fluid(config: &SimConfig, field: &ForceField, spec: &FluidSpec, seed: u64) -> Result<Particles, EngineError> {
    let domain = PeriodicBox::new(config.box_lengths)?;
    if !(spec.density.is_finite() && spec.density > 0.0) {
        return Err(EngineError::invalid(
            "density",
            format!("must be finite and > 0, got {}", spec.density),
        ));
    }
    if !(spec.kbt.is_finite() && spec.kbt >= 0.0) {
        return Err(EngineError::invalid(
            "kBT",
            format!("must be finite and ≥ 0, got {}", spec.kbt),
        ));
    }
    let t = spec.ptype as usize;
    let Some(ty) = field.types().get(t) else {
        return Err(EngineError::invalid(
            "type",
            format!("{t} out of range for {} types", field.ntypes()),
        ));
    };
    let nf = (spec.density * domain.volume()).round();
    if nf < 1.0 || nf > (u32::MAX - spec.first_id) as Real || nf > 1e9 {
        return Err(EngineError::invalid(
            "density",
            format!("gives {nf} particles in volume {}", domain.volume()),
        ));
    }
    let n = nf as usize;
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let l = domain.lengths();
    let mut pos = Vec::with_capacity(n);
    match spec.placement {
        Placement::Random => {
            for _ in 0..n {
                let p = DVec3::new(uniform(&mut rng), uniform(&mut rng), uniform(&mut rng)) * l;
                pos.push(domain.wrap(p));
            }
        }
        Placement::JitteredLattice { jitter } => {
            if !(jitter.is_finite() && (0.0..=0.5).contains(&jitter)) {
                return Err(EngineError::invalid(
                    "jitter",
                    format!("must be in [0, 0.5], got {jitter}"),
                ));
            }
            let a = (domain.volume() / nf).cbrt();
            let m = [
                ((l.x / a).ceil() as usize).max(1),
                ((l.y / a).ceil() as usize).max(1),
                ((l.z / a).ceil() as usize).max(1),
            ];
            let spacing = DVec3::new(l.x / m[0] as Real, l.y / m[1] as Real, l.z / m[2] as Real);
            let mut sites: Vec<[usize; 3]> = Vec::with_capacity(m[0] * m[1] * m[2]);
            for z in 0..m[2] {
                for y in 0..m[1] {
                    for x in 0..m[0] {
                        sites.push([x, y, z]);
                    }
                }
            }
            // Partial Fisher–Yates: the first n entries are a uniform random subset.
            for k in 0..n.min(sites.len()) {
                let r = k + (rng.next_u64() % (sites.len() - k) as u64) as usize;
                sites.swap(k, r);
            }
            for s in sites.iter().take(n) {
                let base = DVec3::new(s[0] as Real + 0.5, s[1] as Real + 0.5, s[2] as Real + 0.5);
                let j = DVec3::new(
                    2.0 * uniform(&mut rng) - 1.0,
                    2.0 * uniform(&mut rng) - 1.0,
                    2.0 * uniform(&mut rng) - 1.0,
                ) * jitter;
                pos.push(domain.wrap((base + j) * spacing));
            }
        }
    }
    let sd = (spec.kbt / ty.mass).sqrt();
    let mut vel = Vec::with_capacity(n);
    for _ in 0..n {
        let (a, b) = normal_pair(&mut rng);
        let (c, _) = normal_pair(&mut rng);
        vel.push(DVec3::new(a, b, c) * sd);
    }
    if !ty.frozen && n > 1 {
        let mean = vel.iter().fold(DVec3::ZERO, |s, v| s + *v) / n as Real;
        for v in vel.iter_mut() {
            *v -= mean;
        }
    } else if ty.frozen {
        vel.iter_mut().for_each(|v| *v = DVec3::ZERO);
    }
    let mut p = Particles::with_capacity(n);
    for (k, (x, v)) in pos.into_iter().zip(vel).enumerate() {
        p.push(x, v, spec.ptype, spec.first_id + k as u32);
    }
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::PairParams;

    #[test]
    fn fluid_is_reproducible_and_momentum_free() {
        let cfg = SimConfig::new(DVec3::new(4.0, 5.0, 6.0), 0.01, 1);
        let field = ForceField::single(PairParams::groot_warren());
        for placement in [Placement::Random, Placement::JitteredLattice { jitter: 0.2 }] {
            let spec = FluidSpec {
                placement,
                ..FluidSpec::standard()
            };
            let a = fluid(&cfg, &field, &spec, 9).unwrap();
            let b = fluid(&cfg, &field, &spec, 9).unwrap();
            let c = fluid(&cfg, &field, &spec, 10).unwrap();
            assert_eq!(a, b);
            assert_ne!(a.pos, c.pos);
            assert_eq!(a.len(), 360);
            let p = a.vel.iter().fold(DVec3::ZERO, |s, v| s + *v);
            assert!(p.length() < 1e-12, "{p}");
            // kinetic temperature of 360 MB particles: relative SE √(2/(3N)) ≈ 4%; allow 5 SE.
            let t = a.vel.iter().map(|v| v.length_squared()).sum::<Real>() / (3.0 * 359.0);
            assert!((t - 1.0).abs() < 0.2, "T = {t}");
            assert!(a.pos.iter().all(|x| x.x >= 0.0 && x.x < 4.0 && x.z < 6.0));
        }
    }

    #[test]
    fn bad_density_is_an_error() {
        let cfg = SimConfig::new(DVec3::splat(4.0), 0.01, 1);
        let field = ForceField::single(PairParams::groot_warren());
        for d in [0.0, -1.0, Real::NAN] {
            let spec = FluidSpec {
                density: d,
                ..FluidSpec::standard()
            };
            let e = fluid(&cfg, &field, &spec, 1).unwrap_err();
            assert!(e.to_string().contains("density"), "{e}");
        }
    }
}
