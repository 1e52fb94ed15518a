//! Pair kernels: small `Copy` values with one `force` method, compiled into the generic pair
//! loops of [`crate::pairs`] (one monomorphised loop per kernel type; no dynamic dispatch per
//! pair). A kernel value holds the parameters of one type pair, already combined with Δt.
//!
//! To add a kernel: write a `Copy` struct, implement [`PairKernel`], build a table of it with
//! [`KernelTable::from_fn`] and pass it to the loops (see `docs/engine.md`).

use glam::DVec3;

use crate::{PairParams, Real};

/// A pair force law.
pub trait PairKernel: Copy + Send + Sync + 'static {
    /// Squared cutoff; pairs with r² ≥ this (or r² = 0) are skipped. 0 disables the pair.
    fn cutoff2(&self) -> Real;
    /// Force on particle i from j. `dr = x_i − x_j` (0 < |dr|² = `r2` < cutoff²),
    /// `dv = v_i − v_j` (the predicted velocities), `xi` the pair's symmetric random number.
    /// Must be odd in (dr, dv) for fixed `xi` so that Newton's third law holds exactly.
    fn force(&self, dr: DVec3, r2: Real, dv: DVec3, xi: Real) -> DVec3;
    /// Whether the random force is on (σ ≠ 0 and the pair enabled). For a pair that is not
    /// (zero temperature, a repulsion-only pair) the loops pass ξ = 0 and compute no hash.
    fn noisy(&self) -> bool;
    /// The parameters of the linear kernel when this is one ([`DpdLinear`]), so that the pair
    /// loops may evaluate its forces several pairs at a time with the same operations.
    #[inline(always)]
    fn linear(&self) -> Option<LinearParams> {
        None
    }
}

/// What [`DpdLinear::force`] needs besides the pair: 1/rc, a, γ, σ/√Δt, and whether the random
/// force is on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinearParams {
    pub inv_rc: Real,
    pub a: Real,
    pub gamma: Real,
    pub sigma_dt: Real,
    pub noisy: bool,
}

/// Groot–Warren DPD with w^R = 1 − r/rc (s = 1): the specialised common case (no `powf`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DpdLinear {
    rc2: Real,
    inv_rc: Real,
    a: Real,
    gamma: Real,
    /// σ/√Δt.
    sigma_dt: Real,
}

impl DpdLinear {
    /// From pair parameters and the time step. `enabled = false` gives a non-interacting pair.
    pub fn new(p: &PairParams, dt: Real, enabled: bool) -> Self {
        let on = enabled && p.rc > 0.0;
        Self {
            rc2: if on { p.rc * p.rc } else { 0.0 },
            inv_rc: if on { 1.0 / p.rc } else { 0.0 },
            a: p.a,
            gamma: p.gamma,
            sigma_dt: p.sigma() / dt.sqrt(),
        }
    }
}

impl PairKernel for DpdLinear {
    #[inline(always)]
    fn cutoff2(&self) -> Real {
        self.rc2
    }

    #[inline(always)]
    fn noisy(&self) -> bool {
        self.rc2 > 0.0 && self.sigma_dt != 0.0
    }

    #[inline(always)]
    fn force(&self, dr: DVec3, r2: Real, dv: DVec3, xi: Real) -> DVec3 {
        let r = r2.sqrt();
        let inv_r = 1.0 / r;
        let w = 1.0 - r * self.inv_rc;
        let edv = dr.dot(dv) * inv_r;
        // a w − γ w² (e·v) + σ w ξ/√Δt, times e = dr/r
        let mag = w * (self.a - self.gamma * w * edv + self.sigma_dt * xi);
        dr * (mag * inv_r)
    }

    #[inline(always)]
    fn linear(&self) -> Option<LinearParams> {
        Some(LinearParams {
            inv_rc: self.inv_rc,
            a: self.a,
            gamma: self.gamma,
            sigma_dt: self.sigma_dt,
            noisy: self.noisy(),
        })
    }
}

/// Groot–Warren DPD with a general exponent: w^R = (1 − r/rc)^s, w^D = (w^R)²; the conservative
/// weight stays linear.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DpdGeneral {
    rc2: Real,
    inv_rc: Real,
    a: Real,
    gamma: Real,
    sigma_dt: Real,
    s: Real,
}

impl DpdGeneral {
    /// From pair parameters and the time step.
    pub fn new(p: &PairParams, dt: Real, enabled: bool) -> Self {
        let l = DpdLinear::new(p, dt, enabled);
        Self {
            rc2: l.rc2,
            inv_rc: l.inv_rc,
            a: l.a,
            gamma: l.gamma,
            sigma_dt: l.sigma_dt,
            s: p.s,
        }
    }
}

impl PairKernel for DpdGeneral {
    #[inline(always)]
    fn cutoff2(&self) -> Real {
        self.rc2
    }

    #[inline(always)]
    fn noisy(&self) -> bool {
        self.rc2 > 0.0 && self.sigma_dt != 0.0
    }

    #[inline(always)]
    fn force(&self, dr: DVec3, r2: Real, dv: DVec3, xi: Real) -> DVec3 {
        let r = r2.sqrt();
        let inv_r = 1.0 / r;
        let w = 1.0 - r * self.inv_rc;
        let wr = w.powf(self.s);
        let edv = dr.dot(dv) * inv_r;
        let mag = self.a * w - self.gamma * wr * wr * edv + self.sigma_dt * wr * xi;
        dr * (mag * inv_r)
    }
}

/// Groot–Warren DPD with s = ¼ (the capillary and shear fluid, [`crate::PairParams::capillary`]):
/// w^R = (1 − r/rc)^¼ = √√w and w^D = √w, two square roots instead of a `powf`. Agrees with
/// [`DpdGeneral`] at s = ¼ to round-off (not bit for bit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DpdQuarter(DpdLinear);

impl DpdQuarter {
    /// From pair parameters (their s is taken to be ¼) and the time step.
    pub fn new(p: &PairParams, dt: Real, enabled: bool) -> Self {
        Self(DpdLinear::new(p, dt, enabled))
    }
}

impl PairKernel for DpdQuarter {
    #[inline(always)]
    fn cutoff2(&self) -> Real {
        self.0.rc2
    }

    #[inline(always)]
    fn noisy(&self) -> bool {
        self.0.noisy()
    }

    #[inline(always)]
    fn force(&self, dr: DVec3, r2: Real, dv: DVec3, xi: Real) -> DVec3 {
        let r = r2.sqrt();
        let inv_r = 1.0 / r;
        let k = &self.0;
        // ≥ 0: r² < rc² can still round to r = rc
        let w = (1.0 - r * k.inv_rc).max(0.0);
        let wd = w.sqrt();
        let wr = wd.sqrt();
        let edv = dr.dot(dv) * inv_r;
        let mag = k.a * w - k.gamma * wd * edv + k.sigma_dt * wr * xi;
        dr * (mag * inv_r)
    }
}

/// Groot–Warren DPD with s = ⅛ (the dense fluid, [`crate::PairParams::dense`]):
/// w^R = (1 − r/rc)^⅛ = √√√w and w^D = √√w, three square roots instead of a `powf` (which took
/// 48 % of the dense fluid's step when profiled). Agrees with [`DpdGeneral`] at s = ⅛ to
/// round-off (not bit for bit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DpdEighth(DpdLinear);

impl DpdEighth {
    /// From pair parameters (their s is taken to be ⅛) and the time step.
    pub fn new(p: &PairParams, dt: Real, enabled: bool) -> Self {
        Self(DpdLinear::new(p, dt, enabled))
    }
}

impl PairKernel for DpdEighth {
    #[inline(always)]
    fn cutoff2(&self) -> Real {
        self.0.rc2
    }

    #[inline(always)]
    fn noisy(&self) -> bool {
        self.0.noisy()
    }

    #[inline(always)]
    fn force(&self, dr: DVec3, r2: Real, dv: DVec3, xi: Real) -> DVec3 {
        let r = r2.sqrt();
        let inv_r = 1.0 / r;
        let k = &self.0;
        // ≥ 0: r² < rc² can still round to r = rc
        let w = (1.0 - r * k.inv_rc).max(0.0);
        let wd = w.sqrt().sqrt();
        let wr = wd.sqrt();
        let edv = dr.dot(dv) * inv_r;
        let mag = k.a * w - k.gamma * wd * edv + k.sigma_dt * wr * xi;
        dr * (mag * inv_r)
    }
}

/// Per-type-pair table of kernel values, row-major `ntypes × ntypes`.
#[derive(Debug, Clone)]
pub struct KernelTable<K> {
    nt: usize,
    k: Vec<K>,
    /// `k[..].cutoff2()`, same layout.
    rc2: Vec<Real>,
    /// Per row: the squared cutoff when it is the same for every type of j (the common case: a
    /// fluid particle meets every type at rc), so the distance test needs no type lookup.
    uniform: Vec<Option<Real>>,
}

impl<K: PairKernel> KernelTable<K> {
    /// Builds the table from `f(i, j)`.
    pub fn from_fn(nt: usize, mut f: impl FnMut(usize, usize) -> K) -> Self {
        let mut k = Vec::with_capacity(nt * nt);
        for i in 0..nt {
            for j in 0..nt {
                k.push(f(i, j));
            }
        }
        let rc2: Vec<Real> = k.iter().map(|k| k.cutoff2()).collect();
        let uniform = rc2
            .chunks(nt)
            .map(|row| row.iter().all(|&c| c == row[0]).then_some(row[0]))
            .collect();
        Self { nt, k, rc2, uniform }
    }

    /// Number of types.
    #[inline(always)]
    pub fn ntypes(&self) -> usize {
        self.nt
    }

    /// Kernel of the pair (i, j).
    #[inline(always)]
    pub fn get(&self, i: usize, j: usize) -> K {
        self.k[i * self.nt + j]
    }

    /// Squared cutoffs of row i.
    #[inline(always)]
    pub fn cutoff2_row(&self, i: usize) -> &[Real] {
        &self.rc2[i * self.nt..(i + 1) * self.nt]
    }

    /// The squared cutoff of row i if it does not depend on the type of j.
    #[inline(always)]
    pub fn uniform_cutoff2(&self, i: usize) -> Option<Real> {
        self.uniform[i]
    }

    /// Row i (kernels of (i, 0..nt)).
    #[inline(always)]
    pub fn row(&self, i: usize) -> &[K] {
        &self.k[i * self.nt..(i + 1) * self.nt]
    }
}

/// The kernel tables an engine can run, chosen once per simulation (outside the loop).
#[derive(Debug, Clone)]
pub enum DpdTable {
    /// Every pair has s = 1.
    Linear(KernelTable<DpdLinear>),
    /// Every interacting pair has s = ¼.
    Quarter(KernelTable<DpdQuarter>),
    /// Every interacting pair has s = ⅛.
    Eighth(KernelTable<DpdEighth>),
    /// Any other mix of exponents.
    General(KernelTable<DpdGeneral>),
}

impl DpdTable {
    /// Builds the table for a force field and time step; frozen–frozen pairs are disabled.
    pub fn new(field: &crate::ForceField, dt: Real) -> Self {
        let nt = field.ntypes();
        let types = field.types();
        let enabled = |i: usize, j: usize| !(types[i].frozen && types[j].frozen);
        // only pairs that interact count: a disabled pair never reaches the kernel
        let all_s = |s: Real| {
            (0..nt).all(|i| (0..nt).all(|j| !(enabled(i, j) && field.pair(i, j).rc > 0.0) || field.pair(i, j).s == s))
        };
        if all_s(1.0) {
            DpdTable::Linear(KernelTable::from_fn(nt, |i, j| {
                DpdLinear::new(field.pair(i, j), dt, enabled(i, j))
            }))
        } else if all_s(0.25) {
            DpdTable::Quarter(KernelTable::from_fn(nt, |i, j| {
                DpdQuarter::new(field.pair(i, j), dt, enabled(i, j))
            }))
        } else if all_s(0.125) {
            DpdTable::Eighth(KernelTable::from_fn(nt, |i, j| {
                DpdEighth::new(field.pair(i, j), dt, enabled(i, j))
            }))
        } else {
            DpdTable::General(KernelTable::from_fn(nt, |i, j| {
                DpdGeneral::new(field.pair(i, j), dt, enabled(i, j))
            }))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params(a: Real, gamma: Real, s: Real) -> PairParams {
        PairParams {
            a,
            gamma,
            kbt: 1.0,
            rc: 1.3,
            s,
        }
    }

    /// F^C = −dU/dr with U = a rc/2 (1 − r/rc)², by central differences, to 1e-6 relative
    /// (SPEC §7). The difference quotient of a quadratic is exact up to round-off
    /// (~ε U/h ≈ 1e-10 relative for h = 1e-5).
    #[test]
    fn conservative_force_is_minus_gradient() {
        let p = params(25.0, 0.0, 1.0);
        let u = |r: Real| 0.5 * p.a * p.rc * (1.0 - r / p.rc).powi(2);
        let lin = DpdLinear::new(&p, 0.01, true);
        let gen = DpdGeneral::new(&params(25.0, 0.0, 0.5), 0.01, true);
        let quarter = DpdQuarter::new(&params(25.0, 0.0, 0.25), 0.01, true);
        let eighth = DpdEighth::new(&params(25.0, 0.0, 0.125), 0.01, true);
        let dir = DVec3::new(0.3, -0.5, 0.8).normalize();
        for &r in &[0.05, 0.3, 0.7, 1.0, 1.25, 1.29] {
            let h = 1e-5;
            let fd = -(u(r + h) - u(r - h)) / (2.0 * h);
            let dr = dir * r;
            for f in [
                lin.force(dr, dr.length_squared(), DVec3::ZERO, 0.0),
                gen.force(dr, dr.length_squared(), DVec3::ZERO, 0.0),
                quarter.force(dr, dr.length_squared(), DVec3::ZERO, 0.0),
                eighth.force(dr, dr.length_squared(), DVec3::ZERO, 0.0),
            ] {
                // force along +e (repulsive) with magnitude −dU/dr
                let along = f.dot(dir);
                assert!((along - fd).abs() <= 1e-6 * fd.abs(), "r {r}: {along} vs {fd}");
                assert!((f - dir * along).length() <= 1e-12 * fd.abs());
            }
        }
    }

    /// Newton's third law per pair: swapping i and j (dr → −dr, dv → −dv, same ξ) gives exactly
    /// the opposite force, including the dissipative and random parts.
    #[test]
    fn newton_third_law_exact() {
        for s in [1.0, 0.5, 0.25] {
            let p = params(25.0, 4.5, s);
            let lin = DpdLinear::new(&p, 0.01, true);
            let gen = DpdGeneral::new(&p, 0.01, true);
            let dr = DVec3::new(0.31, -0.47, 0.22);
            let dv = DVec3::new(1.3, 0.2, -0.9);
            for xi in [-1.7, 0.0, 0.93] {
                let fij = gen.force(dr, dr.length_squared(), dv, xi);
                let fji = gen.force(-dr, dr.length_squared(), -dv, xi);
                assert_eq!(fij, -fji);
                assert!(fij.length() > 0.0);
                let fij = lin.force(dr, dr.length_squared(), dv, xi);
                let fji = lin.force(-dr, dr.length_squared(), -dv, xi);
                assert_eq!(fij, -fji);
                let q = DpdQuarter::new(&p, 0.01, true);
                assert_eq!(
                    q.force(dr, dr.length_squared(), dv, xi),
                    -q.force(-dr, dr.length_squared(), -dv, xi)
                );
                let e = DpdEighth::new(&p, 0.01, true);
                assert_eq!(
                    e.force(dr, dr.length_squared(), dv, xi),
                    -e.force(-dr, dr.length_squared(), -dv, xi)
                );
            }
        }
    }

    /// The s = ¼ specialisation agrees with the general kernel at s = ¼ to round-off (√√w against
    /// powf(w, ¼)), in all three parts, over the whole range of r; and the table picks it when
    /// every interacting pair has s = ¼ (a disabled pair's s does not matter).
    #[test]
    fn quarter_matches_general() {
        let p = params(25.0, 120.0, 0.25);
        let q = DpdQuarter::new(&p, 0.0025, true);
        let gen = DpdGeneral::new(&p, 0.0025, true);
        let dir = DVec3::new(0.31, -0.47, 0.22).normalize();
        let dv = DVec3::new(1.3, 0.2, -0.9);
        for &r in &[0.01, 0.2, 0.5, 0.9, 1.2, 1.2999] {
            let dr = dir * r;
            for xi in [-1.7, 0.0, 0.93] {
                let a = q.force(dr, dr.length_squared(), dv, xi);
                let b = gen.force(dr, dr.length_squared(), dv, xi);
                assert!((a - b).length() <= 1e-12 * b.length().max(1e-12), "r {r}: {a} vs {b}");
            }
        }
        let mut field = crate::ForceField::new(
            vec![crate::TypeSpec::new("fluid"), crate::TypeSpec::frozen("wall")],
            crate::PairParams::capillary(),
        )
        .unwrap();
        field.set_pair(1, 1, crate::PairParams::none()).unwrap();
        assert!(matches!(DpdTable::new(&field, 0.0025), DpdTable::Quarter(_)));
        field.set_pair(0, 1, params(25.0, 4.5, 1.0)).unwrap();
        assert!(matches!(DpdTable::new(&field, 0.0025), DpdTable::General(_)));
    }

    /// The s = ⅛ specialisation agrees with the general kernel at s = ⅛ to round-off (√√√w
    /// against powf(w, ⅛)) in all three parts over the whole range of r, and the table picks it
    /// for the dense fluid with a frozen wall type.
    #[test]
    fn eighth_matches_general() {
        let p = params(100.0, 41.0, 0.125);
        let e = DpdEighth::new(&p, 0.003, true);
        let gen = DpdGeneral::new(&p, 0.003, true);
        let dir = DVec3::new(0.31, -0.47, 0.22).normalize();
        let dv = DVec3::new(1.3, 0.2, -0.9);
        for &r in &[0.01, 0.2, 0.5, 0.9, 1.2, 1.2999] {
            let dr = dir * r;
            for xi in [-1.7, 0.0, 0.93] {
                let a = e.force(dr, dr.length_squared(), dv, xi);
                let b = gen.force(dr, dr.length_squared(), dv, xi);
                assert!((a - b).length() <= 1e-12 * b.length().max(1e-12), "r {r}: {a} vs {b}");
            }
        }
        let mut field = crate::ForceField::new(
            vec![crate::TypeSpec::new("fluid"), crate::TypeSpec::frozen("wall")],
            crate::PairParams::dense(),
        )
        .unwrap();
        field.set_pair(1, 1, crate::PairParams::none()).unwrap();
        assert!(matches!(DpdTable::new(&field, 0.003), DpdTable::Eighth(_)));
    }

    /// The s = 1 specialisation agrees with the general kernel at s = 1 (to round-off, since
    /// the two evaluate the same expression in a different order).
    #[test]
    fn linear_matches_general() {
        let p = params(25.0, 4.5, 1.0);
        let lin = DpdLinear::new(&p, 0.01, true);
        let gen = DpdGeneral::new(&p, 0.01, true);
        let dr = DVec3::new(0.31, -0.47, 0.22);
        let dv = DVec3::new(1.3, 0.2, -0.9);
        let a = lin.force(dr, dr.length_squared(), dv, 0.4);
        let b = gen.force(dr, dr.length_squared(), dv, 0.4);
        assert!((a - b).length() < 1e-12 * a.length());
        // Dissipative part alone opposes the approach velocity along e.
        let d = DpdLinear::new(&params(0.0, 4.5, 1.0), 0.01, true).force(dr, dr.length_squared(), dv, 0.0);
        assert!(d.dot(dr) * dv.dot(dr) < 0.0);
    }
}
