//! Observables shared by every scenario.

use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

use crate::{EngineError, ForceField, Particles, PeriodicBox, Real};

/// Σ ½ m v² over the mobile particles.
pub fn kinetic_energy(p: &Particles, field: &ForceField) -> Real {
    let types = field.types();
    p.vel
        .iter()
        .zip(&p.ptype)
        .filter(|(_, &t)| !types[t as usize].frozen)
        .map(|(v, &t)| 0.5 * types[t as usize].mass * v.length_squared())
        .sum()
}

/// Degrees of freedom of the kinetic temperature: 3 per mobile particle, minus 3 for the
/// conserved total momentum when nothing breaks translation invariance (no frozen types and
/// no body force). With walls or body forces momentum is not conserved and all 3N count.
pub fn degrees_of_freedom(p: &Particles, field: &ForceField) -> Real {
    let types = field.types();
    let mobile = p.ptype.iter().filter(|&&t| !types[t as usize].frozen).count();
    let conserved = types.iter().all(|t| !t.frozen && t.body_force == DVec3::ZERO);
    let dof = 3.0 * mobile as Real - if conserved { 3.0 } else { 0.0 };
    dof.max(1.0)
}

/// Kinetic temperature kBT = 2 E_kin / dof (see [`degrees_of_freedom`]). Measures the
/// velocities as they are: with a body-force-driven flow this includes the flow's kinetic
/// energy; use [`peculiar_temperature`] to remove a velocity profile.
pub fn temperature(p: &Particles, field: &ForceField) -> Real {
    2.0 * kinetic_energy(p, field) / degrees_of_freedom(p, field)
}

/// Kinetic temperature of the velocities relative to `mean_vel(position)` (e.g. a binned
/// flow profile); dof = 3 × mobile particles.
pub fn peculiar_temperature(p: &Particles, field: &ForceField, mean_vel: impl Fn(DVec3) -> DVec3) -> Real {
    let types = field.types();
    let mut e = 0.0;
    let mut n = 0usize;
    for ((x, v), &t) in p.pos.iter().zip(&p.vel).zip(&p.ptype) {
        let ty = &types[t as usize];
        if !ty.frozen {
            e += ty.mass * (*v - mean_vel(*x)).length_squared();
            n += 1;
        }
    }
    e / (3.0 * n.max(1) as Real)
}

/// Total momentum Σ m v of all particles (frozen ones normally have v = 0).
pub fn momentum(p: &Particles, field: &ForceField) -> DVec3 {
    let types = field.types();
    p.vel
        .iter()
        .zip(&p.ptype)
        .fold(DVec3::ZERO, |s, (v, &t)| s + *v * types[t as usize].mass)
}

/// Pressure tensor P = (Σ m v ⊗ v + W)/V with W the pair virial Σ r_ij ⊗ f_ij returned by
/// [`crate::Simulation::step_with_virial`] (conservative + dissipative + random). Frozen
/// particles are skipped in the kinetic part.
pub fn pressure_tensor(p: &Particles, field: &ForceField, domain: &PeriodicBox, virial: &DMat3) -> DMat3 {
    let types = field.types();
    let mut k = DMat3::ZERO;
    for (v, &t) in p.vel.iter().zip(&p.ptype) {
        let ty = &types[t as usize];
        if !ty.frozen {
            let mv = *v * ty.mass;
            k += DMat3::from_cols(mv * v.x, mv * v.y, mv * v.z);
        }
    }
    (k + *virial) * (1.0 / domain.volume())
}

/// The streaming velocity of Lees–Edwards shear: u(x) = (γ̇ y + c) x̂ with c the mass-weighted
/// mean of v_x − γ̇ y over the mobile particles. Σ m (v_x − γ̇ y) is an invariant of the
/// dynamics (a crossing changes v_x by ∓U = ∓γ̇ Ly and y by ∓Ly; pair forces conserve
/// momentum) while Σ m v_y = 0, so c stays at its initial value.
pub fn shear_streaming_offset(p: &Particles, field: &ForceField, shear_rate: Real) -> Real {
    let types = field.types();
    let (mut s, mut m) = (0.0, 0.0);
    for ((x, v), &t) in p.pos.iter().zip(&p.vel).zip(&p.ptype) {
        let ty = &types[t as usize];
        if !ty.frozen {
            s += ty.mass * (v.x - shear_rate * x.y);
            m += ty.mass;
        }
    }
    if m > 0.0 {
        s / m
    } else {
        0.0
    }
}

/// Pressure tensor with the kinetic part taken from the velocities relative to
/// `mean_vel(position)` (for a flow such as shear: P = (Σ m v' ⊗ v' + W)/V, v' = v − u(x)).
pub fn peculiar_pressure_tensor(
    p: &Particles,
    field: &ForceField,
    domain: &PeriodicBox,
    virial: &DMat3,
    mean_vel: impl Fn(DVec3) -> DVec3,
) -> DMat3 {
    let types = field.types();
    let mut k = DMat3::ZERO;
    for ((x, v), &t) in p.pos.iter().zip(&p.vel).zip(&p.ptype) {
        let ty = &types[t as usize];
        if !ty.frozen {
            let w = *v - mean_vel(*x);
            let mw = w * ty.mass;
            k += DMat3::from_cols(mw * w.x, mw * w.y, mw * w.z);
        }
    }
    (k + *virial) * (1.0 / domain.volume())
}

/// Scalar pressure p = tr(P)/3.
pub fn pressure(p: &Particles, field: &ForceField, domain: &PeriodicBox, virial: &DMat3) -> Real {
    let t = pressure_tensor(p, field, domain, virial);
    (t.x_axis.x + t.y_axis.y + t.z_axis.z) / 3.0
}

/// Time-averaged binned profiles of number density and mean velocity along one axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Profile {
    axis: usize,
    length: Real,
    cross_area: Real,
    /// Only particles of these types are counted (empty = all mobile types).
    types: Vec<u16>,
    count: Vec<Real>,
    vel_sum: Vec<DVec3>,
    samples: u64,
}

impl Profile {
    /// `nbins` bins along `axis` (0 = x, 1 = y, 2 = z) of `domain`, counting particles of
    /// `types` (empty: every non-frozen type).
    pub fn new(domain: &PeriodicBox, axis: usize, nbins: usize, types: Vec<u16>) -> Result<Self, EngineError> {
        if axis > 2 || nbins == 0 {
            return Err(EngineError::invalid(
                "profile",
                format!("axis {axis} must be 0..=2 and nbins {nbins} > 0"),
            ));
        }
        let l = domain.lengths();
        Ok(Self {
            axis,
            length: l[axis],
            cross_area: domain.volume() / l[axis],
            types,
            count: vec![0.0; nbins],
            vel_sum: vec![DVec3::ZERO; nbins],
            samples: 0,
        })
    }

    /// Adds one snapshot.
    pub fn sample(&mut self, p: &Particles, field: &ForceField) {
        let nb = self.count.len();
        let scale = nb as Real / self.length;
        let ftypes = field.types();
        for ((x, v), &t) in p.pos.iter().zip(&p.vel).zip(&p.ptype) {
            let take = if self.types.is_empty() {
                !ftypes[t as usize].frozen
            } else {
                self.types.contains(&t)
            };
            if take {
                let b = ((x[self.axis] * scale) as usize).min(nb - 1);
                self.count[b] += 1.0;
                self.vel_sum[b] += *v;
            }
        }
        self.samples += 1;
    }

    /// Number of snapshots.
    pub fn samples(&self) -> u64 {
        self.samples
    }

    /// Bin centres.
    pub fn centres(&self) -> Vec<Real> {
        let w = self.length / self.count.len() as Real;
        (0..self.count.len()).map(|b| (b as Real + 0.5) * w).collect()
    }

    /// Time-averaged number density per bin.
    pub fn density(&self) -> Vec<Real> {
        let vol = self.cross_area * self.length / self.count.len() as Real;
        let s = self.samples.max(1) as Real;
        self.count.iter().map(|c| c / (s * vol)).collect()
    }

    /// Time-averaged mean velocity per bin (particle-weighted); zero in empty bins.
    pub fn velocity(&self) -> Vec<DVec3> {
        self.count
            .iter()
            .zip(&self.vel_sum)
            .map(|(c, v)| if *c > 0.0 { *v / *c } else { DVec3::ZERO })
            .collect()
    }

    /// Clears the accumulators.
    pub fn reset(&mut self) {
        self.count.iter_mut().for_each(|c| *c = 0.0);
        self.vel_sum.iter_mut().for_each(|v| *v = DVec3::ZERO);
        self.samples = 0;
    }
}

/// Mean and standard error of a correlated time series by block averaging: the series is cut
/// into `nblocks` equal blocks (the remainder at the end is dropped); SE = std(block means)/√nb.
/// Blocks must be longer than the correlation time for the estimate to be honest; check that
/// the SE does not grow further with fewer, longer blocks (see [`block_error_scan`]).
pub fn block_average(data: &[Real], nblocks: usize) -> Result<(Real, Real), EngineError> {
    if nblocks < 2 || data.len() < nblocks {
        return Err(EngineError::invalid(
            "block average",
            format!(
                "need ≥ 2 blocks and ≥ 1 sample per block: {} samples, {nblocks} blocks",
                data.len()
            ),
        ));
    }
    let m = data.len() / nblocks;
    let means: Vec<Real> = (0..nblocks)
        .map(|b| data[b * m..(b + 1) * m].iter().sum::<Real>() / m as Real)
        .collect();
    let mean = means.iter().sum::<Real>() / nblocks as Real;
    let var = means.iter().map(|x| (x - mean).powi(2)).sum::<Real>() / (nblocks - 1) as Real;
    Ok((mean, (var / nblocks as Real).sqrt()))
}

/// Flyvbjerg–Petersen style scan: the standard error for block counts n, n/2, n/4, … ≥ 4
/// (starting at one sample per block). Returns (samples per block, SE) pairs; the plateau is the
/// honest error. [`block_error`] picks the largest SE with at least 8 blocks.
pub fn block_error_scan(data: &[Real]) -> Vec<(usize, Real)> {
    let mut out = Vec::new();
    let mut nb = data.len();
    while nb >= 4 {
        if let Ok((_, se)) = block_average(data, nb) {
            out.push((data.len() / nb, se));
        }
        nb /= 2;
    }
    out
}

/// Mean and a conservative standard error: the largest block SE with ≥ 8 blocks.
pub fn block_error(data: &[Real]) -> Result<(Real, Real), EngineError> {
    if data.len() < 8 {
        return Err(EngineError::invalid("block error", "need ≥ 8 samples"));
    }
    let mean = data.iter().sum::<Real>() / data.len() as Real;
    let se = block_error_scan(data)
        .into_iter()
        .filter(|(m, _)| data.len() / m >= 8)
        .map(|(_, se)| se)
        .fold(0.0, Real::max);
    Ok((mean, se))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn block_average_of_white_noise() {
        // Deterministic ±1 sequence from a hash: SE of the mean of 4096 unit-variance samples is
        // 1/64; block estimates with 64 blocks scatter by ~1/√(2·63) ≈ 9% around that.
        let data: Vec<Real> = (0..4096u64)
            .map(|i| if crate::rng::mix64(i) & 1 == 0 { 1.0 } else { -1.0 })
            .collect();
        let (m, se) = block_average(&data, 64).unwrap();
        assert!(m.abs() < 5.0 / 64.0);
        assert!((se * 64.0 - 1.0).abs() < 0.35, "se {se}");
        let (_, se2) = block_error(&data).unwrap();
        assert!(se2 >= se * 0.5 && se2 < 2.0 / 64.0);
        assert!(block_average(&data, 1).is_err());
    }
}
