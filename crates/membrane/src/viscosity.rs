//! Membrane viscosity: Fedosov's dissipative and random forces on the membrane links, integrated
//! by a Shardlow sweep with the exact Ornstein–Uhlenbeck solution per link (docs/model.md,
//! "Membrane viscosity").
//!
//! Per link (i, j) with relative velocity v = vᵢ − vⱼ and unit vector ê = (xᵢ − xⱼ)/|xᵢ − xⱼ|,
//! the dissipative force on i is
//!
//! F^D = −γ_T v − γ_C (v·ê) ê,
//!
//! with the random force of the fluctuation–dissipation theorem (covariance 2 kBT (γ_T 1 + γ_C êê)
//! per unit time; Fedosov's symmetric-traceless construction has exactly this covariance when
//! 3γ_C ≥ γ_T). The 2D membrane viscosity is η_m = √3 γ_T + √3 γ_C / 4 (force·time/length, the
//! same unit as γ), and γ_C = γ_T/3 by default, as Fedosov takes it.
//!
//! A physiological η_m is very stiff in model units (γ_T of thousands for vertex masses ~1 and
//! Δt ~ 0.0025: γΔt/m ≫ 1), so an explicit force would blow up. With ê held fixed over the step,
//! the pair's relative velocity obeys a linear Ornstein–Uhlenbeck equation whose solution is
//! exact: its component along ê decays at the rate (γ_T + γ_C)(1/mᵢ + 1/mⱼ), the perpendicular
//! components at γ_T(1/mᵢ + 1/mⱼ), and the noise restores the Maxwell distribution of variance
//! kBT/μ per component (μ the reduced mass). The pair's centre-of-mass velocity does not change,
//! so momentum is conserved link by link. Links are updated one after another in their fixed
//! order (Shardlow's splitting), which is unconditionally stable. The random numbers are
//! counter-based on (seed, step, link index), so the sweep does not depend on the thread count
//! and needs no state in a checkpoint.

use glam::DVec3;
use hemodpd_engine::rng::{mix64, step_key};
use serde::{Deserialize, Serialize};

/// Mixed into the seed of the membrane-viscosity noise (a stream apart from the pair noise and
/// the Maxwell reflections).
const VISCOSITY_SALT: u64 = 0x7669_7363_6f75_735f;

const GOLDEN: u64 = 0x9E37_79B9_7F4A_7C15;

/// The friction coefficients of the membrane viscosity (force·time/length = mass/time, in the
/// units of the caller; both ≥ 0 and finite).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MembraneViscosity {
    /// γ_T: friction of the whole relative velocity of a link's two vertices.
    pub gamma_t: f64,
    /// γ_C: extra friction of its component along the link.
    pub gamma_c: f64,
}

impl MembraneViscosity {
    /// Fedosov's choice γ_C = γ_T/3 for the 2D membrane viscosity `eta_m`:
    /// η_m = √3 γ_T (1 + 1/12), so γ_T = 12 η_m / (13 √3).
    pub fn from_eta(eta_m: f64) -> Self {
        let gamma_t = 12.0 * eta_m / (13.0 * 3f64.sqrt());
        MembraneViscosity {
            gamma_t,
            gamma_c: gamma_t / 3.0,
        }
    }

    /// The central form for the 2D membrane viscosity `eta_m`: γ_T = 0, γ_C = 4 η_m/√3 (the
    /// form Mirheo implements). It resists only the stretching rate of the links: a rigid
    /// rotation of the membrane, or an out-of-plane relative motion of two linked vertices
    /// (v_ij ⊥ link), is not damped; Fedosov's γ_T term damps both.
    pub fn central_from_eta(eta_m: f64) -> Self {
        MembraneViscosity {
            gamma_t: 0.0,
            gamma_c: 4.0 * eta_m / 3f64.sqrt(),
        }
    }

    /// The 2D membrane viscosity η_m = √3 γ_T + √3 γ_C / 4.
    pub fn eta(&self) -> f64 {
        3f64.sqrt() * (self.gamma_t + 0.25 * self.gamma_c)
    }

    /// The viscosity the friction acts as in a deformation without rotation (a stretched cell
    /// relaxing), on a flat triangular lattice: (√3/2) γ_T + (√3/4) γ_C; 7/13 η_m for
    /// [`Self::from_eta`], η_m for [`Self::central_from_eta`].
    pub fn rotation_free_eta(&self) -> f64 {
        3f64.sqrt() * (0.5 * self.gamma_t + 0.25 * self.gamma_c)
    }

    /// Whether both coefficients are finite and ≥ 0.
    pub fn is_valid(&self) -> bool {
        self.gamma_t.is_finite() && self.gamma_c.is_finite() && self.gamma_t >= 0.0 && self.gamma_c >= 0.0
    }
}

/// Three independent standard Gaussian numbers of link `link` under the per-step `key`
/// (Box–Muller on counter-based uniforms in (0, 1)).
#[inline]
fn link_gaussians(key: u64, link: u64) -> [f64; 3] {
    let base = key.wrapping_add(link.wrapping_mul(4).wrapping_mul(GOLDEN));
    let u = |k: u64| uniform(base, k);
    let (r1, p1) = ((-2.0 * u(1).ln()).sqrt(), std::f64::consts::TAU * u(2));
    let r2 = (-2.0 * u(3).ln()).sqrt() * (std::f64::consts::TAU * u(4)).cos();
    [r1 * p1.cos(), r1 * p1.sin(), r2]
}

/// One standard Gaussian number of link `link` under `key`: the first of [`link_gaussians`]
/// (what the central form needs, its noise acting along the link only).
#[inline]
fn link_gaussian(key: u64, link: u64) -> f64 {
    let base = key.wrapping_add(link.wrapping_mul(4).wrapping_mul(GOLDEN));
    (-2.0 * uniform(base, 1).ln()).sqrt() * (std::f64::consts::TAU * uniform(base, 2)).cos()
}

/// The counter-based uniform number `k` of a link's stream `base`, in (0, 1).
#[inline]
fn uniform(base: u64, k: u64) -> f64 {
    let h = mix64(base.wrapping_add(k.wrapping_mul(GOLDEN)));
    ((h >> 11) as f64 + 0.5) / (1u64 << 53) as f64
}

/// The exact Ornstein–Uhlenbeck factors of one link over a step: its relative velocity's
/// components along and across the link are multiplied by `a_par`, `a_perp` and get `s_par`,
/// `s_perp` times a standard Gaussian of noise. They depend on the link only through its reduced
/// mass, so a sweep computes them once per mass pair.
#[derive(Clone, Copy, Debug)]
struct Decay {
    a_par: f64,
    s_par: f64,
    a_perp: f64,
    s_perp: f64,
}

impl Decay {
    fn new(mu: f64, visc: &MembraneViscosity, kbt: f64, dt: f64) -> Self {
        let decay = |gamma: f64| {
            let x = -gamma * dt / mu;
            // a = e^x, 1 − a² = −expm1(2x) (accurate when x is small)
            (x.exp(), (kbt / mu * -(2.0 * x).exp_m1()).max(0.0).sqrt())
        };
        let (a_perp, s_perp) = decay(visc.gamma_t);
        let (a_par, s_par) = decay(visc.gamma_t + visc.gamma_c);
        Decay {
            a_par,
            s_par,
            a_perp,
            s_perp,
        }
    }

    #[inline]
    fn apply(&self, v: DVec3, e: DVec3, xi: DVec3) -> DVec3 {
        let v_par = e * v.dot(e);
        let xi_par = e * xi.dot(e);
        (v_par * self.a_par + xi_par * self.s_par) + ((v - v_par) * self.a_perp + (xi - xi_par) * self.s_perp)
    }
}

/// The exact Ornstein–Uhlenbeck update over `dt` of one link's relative velocity `v`, with unit
/// link vector `e` (or zero when the link has no direction: then only γ_T acts), reduced mass
/// `mu`, thermal energy `kbt` and the standard Gaussian vector `xi`. Returns the new relative
/// velocity: each component along and across `e` is multiplied by a = exp(−rate·dt) and gets
/// √(kBT/μ · (1 − a²)) of noise, so its stationary distribution is Maxwell of variance kBT/μ.
#[inline]
pub fn relative_velocity_update(
    v: DVec3,
    e: DVec3,
    mu: f64,
    visc: &MembraneViscosity,
    kbt: f64,
    dt: f64,
    xi: DVec3,
) -> DVec3 {
    Decay::new(mu, visc, kbt, dt).apply(v, e, xi)
}

/// One Shardlow sweep of the membrane viscosity over `links`, in their order: `x` are the
/// (unwrapped) vertex positions, `vel` the vertex velocities (updated), `mass` the vertex
/// masses. `seed` and `step` key the noise (with the link index). Returns nothing; momentum is
/// conserved to round-off by every link update.
///
/// The decay factors are computed once per reduced mass (once per sweep for equal masses). The
/// central form (γ_T = 0) changes only the component along the link, so it draws one Gaussian
/// per link instead of three (the component along ê of an isotropic Gaussian vector is one
/// standard Gaussian); without noise (kBT = 0) none is drawn.
#[allow(clippy::too_many_arguments)]
pub fn shardlow_sweep(
    links: &[[u32; 2]],
    x: &[DVec3],
    vel: &mut [DVec3],
    mass: &[f64],
    visc: &MembraneViscosity,
    kbt: f64,
    dt: f64,
    seed: u64,
    step: u64,
) {
    let key = step_key(seed ^ VISCOSITY_SALT, step);
    let central = visc.gamma_t == 0.0;
    let noisy = kbt > 0.0;
    let mut cached: Option<(f64, Decay)> = None;
    for (l, link) in links.iter().enumerate() {
        let (i, j) = (link[0] as usize, link[1] as usize);
        let (mi, mj) = (mass[i], mass[j]);
        let mu = mi * mj / (mi + mj);
        let decay = match cached {
            Some((m, d)) if m == mu => d,
            _ => {
                let d = Decay::new(mu, visc, kbt, dt);
                cached = Some((mu, d));
                d
            }
        };
        let e = (x[i] - x[j]).normalize_or_zero();
        let v = vel[i] - vel[j];
        let dv = if central {
            let xi = if noisy { link_gaussian(key, l as u64) } else { 0.0 };
            e * (v.dot(e) * (decay.a_par - 1.0) + xi * decay.s_par)
        } else {
            let xi = if noisy {
                DVec3::from_array(link_gaussians(key, l as u64))
            } else {
                DVec3::ZERO
            };
            decay.apply(v, e, xi) - v
        };
        // mᵢΔvᵢ = μΔv = −mⱼΔvⱼ: the pair's momentum is unchanged, its relative velocity
        // changes by Δv
        let p = dv * mu;
        vel[i] += p / mi;
        vel[j] -= p / mj;
    }
}

#[cfg(test)]
mod tests;
