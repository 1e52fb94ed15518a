//! Shape recovery after release (Hochmuth, Worthy & Evans 1979): a stretched cell let go in a
//! still medium relaxes at a rate set by its membrane viscosity (docs/model.md §7c).
//!
//! No fluid is simulated. The dissipation is the membrane viscosity's link friction
//! ([`crate::viscosity`]) plus a weak drag of each vertex on the still medium; a real cell's
//! medium adds a share of about η_o R/η_m ≈ 1 % to the membrane's, which the drag stands for (it
//! also damps the motions the central form of the friction leaves free: rigid rotation and
//! out-of-plane relative motion). No thermal noise: the recovery is deterministic, like the
//! static stretching it follows.
//!
//! The motion is overdamped; the vertices' mass is fictitious, chosen so that their inertial
//! time m/Γ (Γ the largest friction coefficient) is a small fraction `inertia` of the
//! relaxation scale Γ/μ0. The step is h = m/(4Γ), so a link's friction acts at its full value
//! (Γh/μ_link = ½, [`crate::respa`]); each step is velocity Verlet with the membrane forces,
//! then the Shardlow sweep of the link friction, then the exact decay of each vertex's velocity
//! by the drag. Units are the caller's (the stretching scenario: µm, pN, s).

use crate::forces::{ForceError, MembraneModel};
use crate::mesh::{area_of, volume_of};
use crate::stretch::diameters;
use crate::viscosity::{shardlow_sweep, MembraneViscosity};
use glam::DVec3;

/// The default inertial fraction m/Γ ÷ Γ/μ0. The shapes converge linearly as it shrinks (the
/// central form leaves some motions free, and they ring): at 5e-4 a single run's recovery time is
/// ≈ 4 % long at N = 500, so [`extrapolate`] combines it with a run at half of it
/// (`recovery::tests::the_fictitious_mass_converges_linearly`).
pub const DEFAULT_INERTIA: f64 = 5e-4;

/// How the cell recovers.
#[derive(Clone, Copy, Debug)]
pub struct RecoveryOptions {
    /// The membrane viscosity's link friction (force·time/length).
    pub viscosity: MembraneViscosity,
    /// Friction of each vertex against the still medium (force·time/length), ≥ 0.
    pub drag: f64,
    /// The membrane's shear modulus μ0 (force/length): the relaxation scale is Γ/μ0.
    pub shear_modulus: f64,
    /// How long the cell is watched after release (time).
    pub duration: f64,
    /// Samples of the shape, evenly spaced over `duration` (the release itself is sample 0).
    pub samples: usize,
    /// The vertices' inertial time as a fraction of Γ/μ0 ([`DEFAULT_INERTIA`]).
    pub inertia: f64,
}

/// The shape at one time after release.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct RecoverySample {
    /// Time since release.
    pub time: f64,
    /// Extent along the stretch axis (x), about the centroid.
    pub axial_diameter: f64,
    /// Twice the largest distance from the stretch axis through the centroid.
    pub transverse_diameter: f64,
    /// (A − A0)/A0 and (V − V0)/V0.
    pub area_deviation: f64,
    pub volume_deviation: f64,
}

impl RecoverySample {
    /// Hochmuth's λ = L/W: the axial over the transverse diameter.
    pub fn length_over_width(&self) -> f64 {
        self.axial_diameter / self.transverse_diameter
    }
}

/// A recovery: the samples and how it was integrated.
#[derive(Clone, Debug)]
pub struct Recovery {
    pub samples: Vec<RecoverySample>,
    /// Steps taken, and their size (time).
    pub steps: u64,
    pub time_step: f64,
    /// The fictitious vertex mass (force·time²/length).
    pub vertex_mass: f64,
    /// The final shape.
    pub positions: Vec<DVec3>,
}

/// Errors of the recovery.
#[derive(Debug, thiserror::Error)]
pub enum RecoveryError {
    #[error(
        "no dissipation: the membrane viscosity and the medium's drag are both zero, so a released cell never settles"
    )]
    NoDissipation,
    #[error("bad recovery options: {0}")]
    Options(String),
    #[error("at t = {time:.4e} after release: {source}")]
    Force { time: f64, source: ForceError },
    #[error("the recovery became unstable at t = {time:.4e} (kinetic energy {kinetic:.3e}): the membrane is stiffer than the step resolves; lower the inertial fraction")]
    Unstable { time: f64, kinetic: f64 },
}

/// The shape's diameters about its centroid (the stretch axis is x).
fn sample(model: &MembraneModel, x: &[DVec3], time: f64) -> RecoverySample {
    let c = x.iter().copied().sum::<DVec3>() / x.len().max(1) as f64;
    let centred: Vec<DVec3> = x.iter().map(|p| *p - c).collect();
    let (da, dt) = diameters(&centred);
    RecoverySample {
        time,
        axial_diameter: da,
        transverse_diameter: dt,
        area_deviation: area_of(x, model.triangles()) / model.area0() - 1.0,
        volume_deviation: volume_of(x, model.triangles()) / model.volume0() - 1.0,
    }
}

/// Releases the cell held at `start` (at rest) and follows its shape for `opts.duration`.
/// `stop` is polled between samples; when it returns true the recovery ends early with the
/// samples so far (the caller decides whether that is an interruption). Deterministic.
pub fn recover(
    model: &MembraneModel,
    start: &[DVec3],
    opts: &RecoveryOptions,
    mut stop: impl FnMut() -> bool,
) -> Result<Recovery, RecoveryError> {
    let v = &opts.viscosity;
    if !(v.is_valid() && opts.drag.is_finite() && opts.drag >= 0.0) {
        return Err(RecoveryError::Options(format!(
            "frictions must be finite and ≥ 0 (γ_T {}, γ_C {}, drag {})",
            v.gamma_t, v.gamma_c, opts.drag
        )));
    }
    if !(opts.shear_modulus > 0.0 && opts.duration > 0.0 && opts.samples >= 1 && opts.inertia > 0.0) {
        return Err(RecoveryError::Options(format!(
            "shear modulus {}, duration {}, samples {} and inertia {} must be positive",
            opts.shear_modulus, opts.duration, opts.samples, opts.inertia
        )));
    }
    let gamma = (v.gamma_t + v.gamma_c).max(opts.drag);
    if gamma <= 0.0 {
        return Err(RecoveryError::NoDissipation);
    }
    // m/Γ = inertia · Γ/μ0; h = m/(4Γ): ½ of a link's reduced mass over its friction
    let mass = opts.inertia * gamma * gamma / opts.shear_modulus;
    let dt_max = 0.25 * mass / gamma;
    let per_sample = (opts.duration / opts.samples as f64 / dt_max).ceil().max(1.0) as u64;
    let h = opts.duration / opts.samples as f64 / per_sample as f64;
    let n = start.len();
    let masses = vec![mass; n];
    let mut x = start.to_vec();
    let mut vel = vec![DVec3::ZERO; n];
    let mut f = vec![DVec3::ZERO; n];
    let force_at = |x: &[DVec3], f: &mut [DVec3], time: f64| -> Result<(), RecoveryError> {
        f.iter_mut().for_each(|fi| *fi = DVec3::ZERO);
        model
            .add_forces(x, f)
            .map(|_| ())
            .map_err(|source| RecoveryError::Force { time, source })
    };
    force_at(&x, &mut f, 0.0)?;
    // the largest kinetic energy the release can produce is the elastic energy it frees
    let e0 = model
        .energy(start)
        .map_err(|source| RecoveryError::Force { time: 0.0, source })?
        .total();
    let drag_decay = (-opts.drag * h / mass).exp();
    let mut samples = vec![sample(model, &x, 0.0)];
    let mut step = 0u64;
    for s in 1..=opts.samples {
        if stop() {
            break;
        }
        for _ in 0..per_sample {
            step += 1;
            let time = step as f64 * h;
            for i in 0..n {
                vel[i] += f[i] * (0.5 * h / mass);
                x[i] += vel[i] * h;
            }
            force_at(&x, &mut f, time)?;
            for i in 0..n {
                vel[i] += f[i] * (0.5 * h / mass);
            }
            // no noise: kBT = 0 (the seed and counter are then unused)
            shardlow_sweep(model.links(), &x, &mut vel, &masses, v, 0.0, h, 0, step);
            if drag_decay < 1.0 {
                vel.iter_mut().for_each(|u| *u *= drag_decay);
            }
        }
        let kinetic = 0.5 * mass * vel.iter().map(|u| u.length_squared()).sum::<f64>();
        let time = s as f64 * per_sample as f64 * h;
        if !kinetic.is_finite() || kinetic > 10.0 * e0.abs().max(1e-300) {
            return Err(RecoveryError::Unstable { time, kinetic });
        }
        samples.push(sample(model, &x, time));
    }
    Ok(Recovery {
        samples,
        steps: step,
        time_step: h,
        vertex_mass: mass,
        positions: x,
    })
}

/// Richardson's extrapolation to a massless membrane of two recoveries with the same samples,
/// `coarse` at an inertial fraction ε and `fine` at ε/2: each sample's diameters and deviations
/// as 2·fine − coarse (the error is linear in ε). `None` if the samples differ in number or time.
pub fn extrapolate(coarse: &Recovery, fine: &Recovery) -> Option<Vec<RecoverySample>> {
    if coarse.samples.len() != fine.samples.len() {
        return None;
    }
    coarse
        .samples
        .iter()
        .zip(&fine.samples)
        .map(|(c, f)| {
            ((c.time - f.time).abs() <= 1e-12 * c.time.abs().max(1e-300)).then_some(RecoverySample {
                time: f.time,
                axial_diameter: 2.0 * f.axial_diameter - c.axial_diameter,
                transverse_diameter: 2.0 * f.transverse_diameter - c.transverse_diameter,
                area_deviation: 2.0 * f.area_deviation - c.area_deviation,
                volume_deviation: 2.0 * f.volume_deviation - c.volume_deviation,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests;
