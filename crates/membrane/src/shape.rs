//! The Evans–Fung biconcave reference shape (Eq. 7 of the paper):
//! `y = ±R √(1 − s) (c0 + c1 s + c2 s²)`, `s = (x² + z²)/R²`, large diameter in the xz plane.
//!
//! The paper prints c0 = 0.0135805, a digit transposition of 0.1035805 (= 2 × Evans–Fung's
//! a0 = 0.0518 in units of R): see `docs/model.md`. [`EvansFung::healthy_um`] uses the corrected value.

use glam::DVec3;

/// Coefficients of the biconcave shape. `r` is in the caller's length unit.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct EvansFung {
    /// Cell radius R.
    pub r: f64,
    pub c0: f64,
    pub c1: f64,
    pub c2: f64,
}

impl EvansFung {
    /// The healthy cell, R = 3.91 µm with the corrected c0 = 0.1035805 (radius in µm).
    pub const fn healthy_um() -> Self {
        Self {
            r: 3.91,
            c0: 0.1035805,
            c1: 1.001279,
            c2: -0.561381,
        }
    }

    /// Eq. (7) exactly as printed (c0 = 0.0135805): a cell 0.11 µm thick at its centre.
    pub const fn as_printed_um() -> Self {
        Self {
            r: 3.91,
            c0: 0.0135805,
            c1: 1.001279,
            c2: -0.561381,
        }
    }

    /// The same shape with R expressed in another unit (`factor` = new units per old unit).
    pub fn scaled(self, factor: f64) -> Self {
        Self {
            r: self.r * factor,
            ..self
        }
    }

    /// Polynomial factor P(s) = c0 + c1 s + c2 s².
    #[inline]
    pub fn poly(&self, s: f64) -> f64 {
        self.c0 + self.c1 * s + self.c2 * s * s
    }

    #[inline]
    fn dpoly(&self, s: f64) -> f64 {
        self.c1 + 2.0 * self.c2 * s
    }

    /// Half-thickness y(ρ) ≥ 0 of the upper surface at distance ρ from the axis (ρ ≤ R).
    pub fn half_thickness(&self, rho: f64) -> f64 {
        let s = (rho / self.r).powi(2).min(1.0);
        self.r * (1.0 - s).sqrt() * self.poly(s)
    }

    /// Maps a point `u` of the unit sphere onto the cell surface:
    /// `(R u_x, R u_y P(u_x² + u_z²), R u_z)`. Smooth, one-to-one and orientation-preserving
    /// (P > 0 on [0, 1]), so a triangulation of the sphere is one of the cell.
    #[inline]
    pub fn from_sphere(&self, u: DVec3) -> DVec3 {
        let s = u.x * u.x + u.z * u.z;
        DVec3::new(self.r * u.x, self.r * u.y * self.poly(s), self.r * u.z)
    }

    /// Inverse of [`from_sphere`](Self::from_sphere) for a point on (or near) the surface.
    #[inline]
    pub fn to_sphere(&self, p: DVec3) -> DVec3 {
        let (ux, uz) = (p.x / self.r, p.z / self.r);
        let s = ux * ux + uz * uz;
        if s >= 1.0 {
            let n = s.sqrt();
            return DVec3::new(ux / n, 0.0, uz / n);
        }
        DVec3::new(ux, (1.0 - s).sqrt().copysign(p.y), uz).normalize()
    }

    /// Implicit function g(p) = y² − R²(1 − s)P(s)², zero on the surface, and its gradient.
    #[inline]
    fn implicit(&self, p: DVec3) -> (f64, DVec3) {
        let r2 = self.r * self.r;
        let s = (p.x * p.x + p.z * p.z) / r2;
        let pp = self.poly(s);
        let h = (1.0 - s) * pp * pp;
        let dh_ds = -pp * pp + 2.0 * (1.0 - s) * pp * self.dpoly(s);
        let g = p.y * p.y - r2 * h;
        // dg/dx = -R² dh/ds · 2x/R² = -2x dh/ds
        let grad = DVec3::new(-2.0 * p.x * dh_ds, 2.0 * p.y, -2.0 * p.z * dh_ds);
        (g, grad)
    }

    /// Outward unit normal at a point on the surface.
    pub fn normal(&self, p: DVec3) -> DVec3 {
        let (_, grad) = self.implicit(p);
        grad.normalize()
    }

    /// Moves a point near the surface onto it (Newton iterations along the gradient of the
    /// implicit function; converges in a few steps from a distance small against the thickness).
    pub fn project(&self, mut p: DVec3) -> DVec3 {
        for _ in 0..50 {
            let (g, grad) = self.implicit(p);
            let g2 = grad.length_squared();
            if g2 == 0.0 {
                break;
            }
            let step = grad * (g / g2);
            p -= step;
            if step.length() < 1e-15 * self.r {
                break;
            }
        }
        p
    }

    /// Area and enclosed volume of the smooth surface by Gauss–Legendre quadrature in the
    /// polar angle of the sphere parametrisation (the integrand is smooth there).
    pub fn area_and_volume(&self) -> (f64, f64) {
        // Parametrise the upper half by t ∈ [0, π/2]: ρ = R sin t, y = R cos t P(sin² t).
        let n = 4000;
        let (mut area, mut vol) = (0.0, 0.0);
        let h = std::f64::consts::FRAC_PI_2 / n as f64;
        // composite Simpson's rule
        for i in 0..=n {
            let t = i as f64 * h;
            let w = if i == 0 || i == n {
                1.0
            } else if i % 2 == 1 {
                4.0
            } else {
                2.0
            };
            let (st, ct) = t.sin_cos();
            let s = st * st;
            let rho = self.r * st;
            let drho = self.r * ct;
            let y = self.r * ct * self.poly(s);
            let dy = self.r * (-st * self.poly(s) + ct * self.dpoly(s) * 2.0 * st * ct);
            area += w * 2.0 * std::f64::consts::PI * rho * (drho * drho + dy * dy).sqrt();
            // volume of the upper half: ∫ 2π ρ y dρ
            vol += w * 2.0 * std::f64::consts::PI * rho * y * drho;
        }
        (2.0 * area * h / 3.0, 2.0 * vol * h / 3.0)
    }

    /// Thickness at the centre (2 y(0)) and the largest thickness (2 max y).
    pub fn thickness_min_max(&self) -> (f64, f64) {
        let n = 20000;
        let hmax = (0..=n)
            .map(|i| self.half_thickness(self.r * i as f64 / n as f64))
            .fold(0.0, f64::max);
        (2.0 * self.half_thickness(0.0), 2.0 * hmax)
    }
}

/// Reduced volume v = 6√π V / A^(3/2) (1 for a sphere).
pub fn reduced_volume(area: f64, volume: f64) -> f64 {
    6.0 * std::f64::consts::PI.sqrt() * volume / area.powf(1.5)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SPEC §1 / reference README §2: corrected c0 gives A = 134.1 µm², V = 94.1 µm³,
    /// h_min = 0.81 µm, v = 0.644; the printed c0 gives 126.8 µm², 71.6 µm³, 0.11 µm.
    /// The reference figures are quoted to the digits given, so tolerances are half a last digit.
    #[test]
    fn area_volume_thickness_of_the_reference_shape() {
        let s = EvansFung::healthy_um();
        let (a, v) = s.area_and_volume();
        assert!((a - 134.1).abs() < 0.05, "A = {a}");
        assert!((v - 94.09).abs() < 0.005, "V = {v}");
        assert!((reduced_volume(a, v) - 0.644).abs() < 0.0005);
        let (hmin, hmax) = s.thickness_min_max();
        assert!((hmin - 0.810).abs() < 0.0005, "hmin {hmin}");
        assert!((hmax - 2.566).abs() < 0.0005, "hmax {hmax}");

        let p = EvansFung::as_printed_um();
        let (a, v) = p.area_and_volume();
        assert!((a - 126.8).abs() < 0.05, "A = {a}");
        assert!((v - 71.6).abs() < 0.05, "V = {v}");
        assert!((p.thickness_min_max().0 - 0.106).abs() < 0.0005);
    }

    #[test]
    fn sphere_map_round_trip_and_projection() {
        let s = EvansFung::healthy_um();
        for &u in &[
            DVec3::new(0.3, 0.5, -0.2),
            DVec3::new(-0.9, -0.1, 0.3),
            DVec3::new(0.0, 1.0, 0.0),
        ] {
            let u = u.normalize();
            let p = s.from_sphere(u);
            assert!(s.implicit(p).0.abs() < 1e-12);
            assert!((s.to_sphere(p) - u).length() < 1e-12);
            let off = p + s.normal(p) * 0.05 + DVec3::new(0.01, 0.0, 0.02);
            let q = s.project(off);
            assert!(s.implicit(q).0.abs() < 1e-12);
            assert!((q - p).length() < 0.1);
        }
    }
}
