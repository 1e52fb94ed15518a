//! The periodic orthorhombic box `[0, Lx) × [0, Ly) × [0, Lz)`, optionally with Lees–Edwards
//! (sliding-brick) boundaries in y for simple shear u = γ̇ y x̂.
//!
//! With Lees–Edwards, the periodic image of the box one period up (y + Ly) is shifted by the
//! offset δ(t) = (U t) mod Lx in x and moves with the shear velocity U = γ̇ Ly in x. So:
//! * a particle that leaves through y = Ly re-enters at y − Ly with x − δ and v_x − U (and
//!   the mirror image downward): [`PeriodicBox::wrap_sheared`] returns how many periods it
//!   crossed so the caller shifts the velocity;
//! * the separation of two particles is taken to the nearest image, with the x shift of the
//!   image's y period: [`PeriodicBox::min_image_sheared`] returns the image index k, and the
//!   velocity of that image is v + k U x̂ (every velocity used in a pair force must get it).
//!
//! Without shear (U = 0) everything reduces to ordinary periodic boundaries, bit for bit.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::{EngineError, Real};

/// A periodic orthorhombic box with its lower corner at the origin.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PeriodicBox {
    lengths: DVec3,
    /// Lees–Edwards shear velocity U = γ̇ Ly (velocity units; 0 = ordinary periodic box).
    #[serde(default)]
    shear_velocity: Real,
    /// Lees–Edwards offset δ ∈ [0, Lx) of the image one period up in y (length units).
    #[serde(default)]
    offset: Real,
}

impl PeriodicBox {
    /// A box of edge lengths `lengths` (model units, each finite and > 0).
    pub fn new(lengths: DVec3) -> Result<Self, EngineError> {
        if !(lengths.is_finite() && lengths.min_element() > 0.0) {
            return Err(EngineError::invalid(
                "box lengths",
                format!("must be finite and positive, got {lengths}"),
            ));
        }
        Ok(Self {
            lengths,
            shear_velocity: 0.0,
            offset: 0.0,
        })
    }

    /// The same box with Lees–Edwards boundaries in y for the shear rate `shear_rate` (1/time;
    /// flow along x, gradient along y; 0 turns them off), at time 0 (offset 0).
    pub fn with_shear_rate(mut self, shear_rate: Real) -> Result<Self, EngineError> {
        if !shear_rate.is_finite() {
            return Err(EngineError::invalid(
                "shear rate",
                format!("must be finite, got {shear_rate}"),
            ));
        }
        self.shear_velocity = shear_rate * self.lengths.y;
        self.offset = 0.0;
        Ok(self)
    }

    /// The same box at time `t`: offset δ = (U t) mod Lx. Computed from t, never accumulated,
    /// so a restarted run gets the same offset bit for bit.
    pub fn at_time(mut self, t: Real) -> Self {
        if self.shear_velocity != 0.0 {
            self.offset = wrap1(self.shear_velocity * t, self.lengths.x);
        }
        self
    }

    /// Edge lengths.
    #[inline]
    pub fn lengths(&self) -> DVec3 {
        self.lengths
    }

    /// Volume.
    #[inline]
    pub fn volume(&self) -> Real {
        self.lengths.x * self.lengths.y * self.lengths.z
    }

    /// Whether the box has Lees–Edwards boundaries (a non-zero shear velocity).
    #[inline]
    pub fn is_sheared(&self) -> bool {
        self.shear_velocity != 0.0
    }

    /// Lees–Edwards shear velocity U = γ̇ Ly: the x velocity of the image one period up.
    #[inline]
    pub fn shear_velocity(&self) -> Real {
        self.shear_velocity
    }

    /// Shear rate γ̇ = U/Ly.
    #[inline]
    pub fn shear_rate(&self) -> Real {
        self.shear_velocity / self.lengths.y
    }

    /// Lees–Edwards offset δ ∈ [0, Lx): the x shift of the image one period up.
    #[inline]
    pub fn offset(&self) -> Real {
        self.offset
    }

    /// Maps `p` into `[0, L)` along every axis. With Lees–Edwards the x shift of the y periods
    /// crossed is applied too; use [`PeriodicBox::wrap_sheared`] when the velocity must follow.
    #[inline]
    pub fn wrap(&self, p: DVec3) -> DVec3 {
        self.wrap_sheared(p).0
    }

    /// Maps `p` into the box and returns the number k of y periods it was moved down by
    /// (k = 1: it left through y = Ly). Its velocity must change by −k U x̂. Without shear k
    /// is still counted but the position is as in an ordinary periodic box.
    #[inline(always)]
    pub fn wrap_sheared(&self, p: DVec3) -> (DVec3, i32) {
        let l = self.lengths;
        let y = wrap1(p.y, l.y);
        let mut x = p.x;
        let mut k = 0;
        if y != p.y {
            k = round((p.y - y) / l.y) as i32;
            if self.shear_velocity != 0.0 {
                x -= k as Real * self.offset;
            }
        }
        (DVec3::new(wrap1(x, l.x), y, wrap1(p.z, l.z)), k)
    }

    /// Minimum-image separation `a − b` (with the Lees–Edwards shift of b's image).
    #[inline]
    pub fn min_image(&self, a: DVec3, b: DVec3) -> DVec3 {
        self.min_image_sheared(a, b).0
    }

    /// Minimum-image separation `a − b` and the y image index k of b's image that is nearest
    /// to a (k = 1: the image one period up). That image moves with v_b + k U x̂, so the
    /// relative velocity to use with this separation is `(v_a − v_b) − k U x̂`.
    #[inline]
    pub fn min_image_sheared(&self, a: DVec3, b: DVec3) -> (DVec3, i32) {
        let mut d = a - b;
        let l = self.lengths;
        let ky = round(d.y / l.y);
        d.y -= l.y * ky;
        d.x -= ky * self.offset;
        d.x -= l.x * round(d.x / l.x);
        d.z -= l.z * round(d.z / l.z);
        (d, ky as i32)
    }
}

/// `v.round()` (half away from zero), bit for bit, without the library call that `round` is on
/// baseline x86-64 (no SSE4.1): a truncating conversion and a correction by the exact remainder.
#[inline(always)]
pub(crate) fn round(v: Real) -> Real {
    // 2^52: from here on every f64 is an integer; NaN and ±∞ fail the test and pass through
    if v.is_nan() || v.abs() >= 4_503_599_627_370_496.0 {
        return v;
    }
    let t = (v as i64) as Real; // toward zero, exact
    let frac = v - t; // exact: |frac| < 1 and t has v's sign
    if frac >= 0.5 {
        t + 1.0
    } else if frac <= -0.5 {
        t - 1.0
    } else if t == 0.0 {
        0.0_f64.copysign(v) // keeps −0.0 as `round` does
    } else {
        t
    }
}

/// Wraps one coordinate into `[0, l)`. Exact (no rounding) for the common case of a particle that
/// left the box by less than one box length.
#[inline(always)]
pub(crate) fn wrap1(x: Real, l: Real) -> Real {
    let mut y = x;
    if y >= l {
        y -= l;
    } else if y < 0.0 {
        y += l;
    }
    if !(y >= 0.0 && y < l) {
        // Far outside (or rounding put it exactly on l): general, still deterministic.
        y = x.rem_euclid(l);
        if y >= l {
            y = 0.0;
        }
    }
    y
}

#[cfg(test)]
mod tests {
    /// The fast `round` equals `f64::round` bit for bit: halves, near-halves, signs, zeros,
    /// integers, huge values, ±∞ and NaN, and a million random values over many magnitudes.
    #[test]
    fn fast_round_is_round() {
        let mut special = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.5,
            -1.5,
            2.5,
            0.49999999999999994,
            -0.49999999999999994,
            0.5000000000000001,
            1e-300,
            -1e-300,
            4503599627370495.5,
            4503599627370496.0,
            9.3e18,
            -9.3e18,
            1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MAX,
            f64::MIN,
        ];
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        for _ in 0..1_000_000 {
            x = crate::rng::mix64(x);
            let mag = 10f64.powi((x % 40) as i32 - 20);
            let u = (x >> 11) as f64 / (1u64 << 53) as f64;
            special.push((2.0 * u - 1.0) * mag);
        }
        for v in special {
            assert_eq!(super::round(v).to_bits(), v.round().to_bits(), "{v:e}");
        }
        assert!(super::round(f64::NAN).is_nan());
    }

    use super::*;

    #[test]
    fn wrap_stays_in_box() {
        let b = PeriodicBox::new(DVec3::new(3.0, 4.0, 5.0)).unwrap();
        for p in [
            DVec3::new(-1e-17, 4.0, 5.0 + 1e-12),
            DVec3::new(-30.5, 17.0, 1e6),
            DVec3::new(2.999_999_999_999_999_6, -4.0, 0.0),
        ] {
            let w = b.wrap(p);
            assert!(w.x >= 0.0 && w.x < 3.0, "{w}");
            assert!(w.y >= 0.0 && w.y < 4.0, "{w}");
            assert!(w.z >= 0.0 && w.z < 5.0, "{w}");
        }
        assert!(PeriodicBox::new(DVec3::new(1.0, 0.0, 1.0)).is_err());
        assert!(PeriodicBox::new(DVec3::new(1.0, Real::NAN, 1.0)).is_err());
    }

    #[test]
    fn min_image_is_shortest() {
        let b = PeriodicBox::new(DVec3::splat(10.0)).unwrap();
        let d = b.min_image(DVec3::new(0.5, 9.5, 5.0), DVec3::new(9.5, 0.5, 5.0));
        assert!((d - DVec3::new(1.0, -1.0, 0.0)).length() < 1e-12);
    }

    #[test]
    fn lees_edwards_wrap_shifts_x_and_reports_the_period() {
        let b = PeriodicBox::new(DVec3::new(10.0, 8.0, 6.0))
            .unwrap()
            .with_shear_rate(0.5)
            .unwrap()
            .at_time(3.0); // U = 4, δ = 12 mod 10 = 2
        assert_eq!(b.shear_velocity(), 4.0);
        assert!((b.offset() - 2.0).abs() < 1e-12);
        // leaving through the top: y − Ly, x − δ, one period down
        let (w, k) = b.wrap_sheared(DVec3::new(1.0, 8.5, 3.0));
        assert_eq!(k, 1);
        assert!((w - DVec3::new(9.0, 0.5, 3.0)).length() < 1e-12, "{w}");
        // leaving through the bottom: y + Ly, x + δ
        let (w, k) = b.wrap_sheared(DVec3::new(9.0, -0.5, 3.0));
        assert_eq!(k, -1);
        assert!((w - DVec3::new(1.0, 7.5, 3.0)).length() < 1e-12, "{w}");
        // unsheared boxes report the period but do not shift x
        let p = PeriodicBox::new(DVec3::new(10.0, 8.0, 6.0)).unwrap();
        let (w, k) = p.wrap_sheared(DVec3::new(1.0, 8.5, 3.0));
        assert_eq!((w, k), (DVec3::new(1.0, 0.5, 3.0), 1));
    }

    #[test]
    fn lees_edwards_min_image_uses_the_shifted_image() {
        let b = PeriodicBox::new(DVec3::new(10.0, 8.0, 6.0))
            .unwrap()
            .with_shear_rate(0.5)
            .unwrap()
            .at_time(3.0); // δ = 2
                           // a near the bottom, b near the top: b's image one period down is at (x_b − δ, y_b − Ly)
        let a = DVec3::new(5.0, 0.2, 1.0);
        let c = DVec3::new(7.1, 7.9, 1.0);
        let (d, k) = b.min_image_sheared(a, c);
        assert_eq!(k, -1);
        assert!((d - DVec3::new(5.0 - (7.1 - 2.0), 0.3, 0.0)).length() < 1e-12, "{d}");
        // antisymmetric, with the opposite image index
        let (e, k2) = b.min_image_sheared(c, a);
        assert_eq!(k2, 1);
        assert!((d + e).length() < 1e-12);
        // the offset wraps in x too
        let c = DVec3::new(1.5, 7.9, 1.0); // image at x = −0.5 ≡ 9.5
        let (d, _) = b.min_image_sheared(DVec3::new(9.8, 0.2, 1.0), c);
        assert!((d - DVec3::new(0.3, 0.3, 0.0)).length() < 1e-12, "{d}");
    }
}
