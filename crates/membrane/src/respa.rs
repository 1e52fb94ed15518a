//! Membrane sub-stepping: the inner (fast) steps of a two-level r-RESPA scheme
//! (Tuckerman, Berne & Martyna 1992; docs/model.md §7b).
//!
//! The fluid step Δt cannot carry a physiological membrane viscosity: a Shardlow sweep once per
//! Δt acts as a link friction of at most ≈ 2μ/Δt (μ the reduced mass of a link;
//! [`crate::viscosity`]). Splitting the vertex forces into slow ones (the pair forces from the
//! fluid and walls, applied as two half-kicks of ½Δt per fluid step) and fast ones (the membrane's
//! elastic forces, the wall repulsion, the membrane viscosity) and integrating the fast ones with
//! k inner steps of h = Δt/k raises that cap to ≈ 2μ/h = k·2μ/Δt. One inner step is velocity
//! Verlet with the fast forces followed by the sweep with step h, the same structure as one step
//! of the unsplit scheme, so the effective friction of the overdamped motion is
//! γ_eff = μ / (h (a/(1 − a) + ½)), a = exp(−γh/μ).
//!
//! [`inner_steps`] is that inner loop, written once for the cell ([`crate::coupling::Cell`]) and
//! its tests. Units are the caller's (the cell: model units).

use glam::DVec3;

use crate::viscosity::{shardlow_sweep, MembraneViscosity};

/// The membrane viscosity as the inner steps apply it: the links, the friction, the fluid's
/// thermal energy and the noise keys.
#[derive(Clone, Copy, Debug)]
pub struct InnerSweep<'a> {
    /// The links (vertex index pairs) in sweep order.
    pub links: &'a [[u32; 2]],
    /// The friction coefficients (mass/time).
    pub viscosity: &'a MembraneViscosity,
    /// Thermal energy kBT of the noise (energy).
    pub kbt: f64,
    /// Seed of the noise.
    pub seed: u64,
    /// Noise counter of the first inner step; inner step j uses `first_key + j` (the caller
    /// keeps the counters of different fluid steps apart, e.g. step·k + j).
    pub first_key: u64,
}

impl InnerSweep<'_> {
    /// The Shardlow sweep of inner step `j` with step `h` (noise counter `first_key + j`).
    fn apply(&self, x: &[DVec3], v: &mut [DVec3], mass: &[f64], h: f64, j: u32) {
        shardlow_sweep(
            self.links,
            x,
            v,
            mass,
            self.viscosity,
            self.kbt,
            h,
            self.seed,
            self.first_key.wrapping_add(j as u64),
        );
    }
}

/// Runs `k` inner steps of size `h` (time) on the positions `x` (length), velocities `v`
/// (length/time) and masses `mass`: each is v += ½h f/m; x += h v; f = fast(x); v += ½h f/m;
/// then the Shardlow sweep of `sweep` (if any) with step h. `f` holds the fast forces at `x` on
/// entry and at the final `x` on return (so the next call starts with no extra evaluation);
/// `fast` overwrites its force slice with the fast forces at the given positions, or fails
/// (the error is returned at once, the state then being that of the failed inner step).
///
/// Invariants: when `fast` conserves momentum (Σf = 0, as the membrane's forces do) and the
/// sweep does (it does, link by link), Σ m v is unchanged to round-off. Deterministic: the
/// loops are sequential and the noise is counter-based.
#[allow(clippy::too_many_arguments)]
pub fn inner_steps<E>(
    x: &mut [DVec3],
    v: &mut [DVec3],
    f: &mut [DVec3],
    mass: &[f64],
    k: u32,
    h: f64,
    sweep: Option<InnerSweep<'_>>,
    mut fast: impl FnMut(&[DVec3], &mut [DVec3]) -> Result<(), E>,
) -> Result<(), E> {
    let n = x.len();
    assert!(v.len() == n && f.len() == n && mass.len() == n);
    for j in 0..k {
        for i in 0..n {
            v[i] += f[i] * (0.5 * h / mass[i]);
            x[i] += v[i] * h;
        }
        fast(x, f)?;
        for i in 0..n {
            v[i] += f[i] * (0.5 * h / mass[i]);
        }
        if let Some(s) = sweep {
            s.apply(x, v, mass, h, j);
        }
    }
    Ok(())
}

/// The inner loop when only the drift and the viscosity are sub-stepped
/// ([`crate::coupling::SubstepForces::Outer`]: the membrane's elastic forces act with the slow
/// ones, as half-kicks of ½Δt): `k` times x += ½h v; the sweep of `sweep` (if any) with step
/// h; x += ½h v. Under a constant force F kicked in once per Δt, the slow motion of a link moves
/// at F/γ_eff with γ_eff = (2μ/h) tanh(γh/2μ) = μ/(h(a/(1 − a) + ½)), the friction of
/// [`inner_steps`] at the same k (`outer_mode_feels_the_inner_friction`). Momentum is conserved
/// by each sweep; deterministic as [`inner_steps`].
pub fn inner_sweeps(x: &mut [DVec3], v: &mut [DVec3], mass: &[f64], k: u32, h: f64, sweep: Option<InnerSweep<'_>>) {
    let n = x.len();
    assert!(v.len() == n && mass.len() == n);
    for j in 0..k {
        for i in 0..n {
            x[i] += v[i] * (0.5 * h);
        }
        if let Some(s) = sweep {
            s.apply(x, v, mass, h, j);
        }
        for i in 0..n {
            x[i] += v[i] * (0.5 * h);
        }
    }
}
