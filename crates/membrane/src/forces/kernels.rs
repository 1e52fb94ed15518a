//! Pure per-element kernels: the WLC link, the triangle area gradient and the signed dihedral
//! angle with its exact gradient. No allocation, no state; shared by the model loops and tests.

// `!(x < y)` is deliberate throughout: it is also true for NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

use glam::DVec3;

/// g(x) = (3x² − 2x³)/(1 − x): the WLC energy is `w · Lmax · g(L/Lmax)` with `w = kBT/(4p)`.
#[inline(always)]
pub fn wlc_g(x: f64) -> f64 {
    x * x * (3.0 - 2.0 * x) / (1.0 - x)
}

/// g'(x) = (6x − 9x² + 4x³)/(1 − x)²; the link tension is `dV/dL = w · g'(x)`
/// (= kBT/p · [1/(4(1−x)²) − 1/4 + x], the Marko–Siggia force).
#[inline(always)]
pub fn wlc_dg(x: f64) -> f64 {
    let om = 1.0 - x;
    x * (6.0 - 9.0 * x + 4.0 * x * x) / (om * om)
}

/// g''(x) = 2/(1 − x)³ + 4 (from g'(x) = 1/(1 − x)² − 1 + 4x); the link stiffness is `w · g''(x) / Lmax`.
#[inline(always)]
pub fn wlc_ddg(x: f64) -> f64 {
    let om = 1.0 - x;
    2.0 / (om * om * om) + 4.0
}

/// Energy and tension dV/dL of one WLC link of length `l`, maximum extension `lmax` and
/// prefactor `w = kBT/(4p)`. Returns `None` if `l/lmax ≥ 1` (or is not finite).
#[inline(always)]
pub fn wlc(l: f64, lmax: f64, w: f64) -> Option<(f64, f64)> {
    let x = l / lmax;
    // `!(x < 1)` also catches NaN.
    if !(x < 1.0) {
        return None;
    }
    Some((w * lmax * wlc_g(x), w * wlc_dg(x)))
}

/// Gradient of the area of triangle (a, b, c) with respect to a, b, c, given the unit normal
/// `nh` of `(b − a) × (c − a)`: ∂A/∂a = ½ n̂ × (c − b), ∂A/∂b = ½ n̂ × (a − c), ∂A/∂c = ½ n̂ × (b − a).
#[inline(always)]
pub fn area_gradient(nh: DVec3, a: DVec3, b: DVec3, c: DVec3) -> [DVec3; 3] {
    [0.5 * nh.cross(c - b), 0.5 * nh.cross(a - c), 0.5 * nh.cross(b - a)]
}

/// Signed dihedral angle of the pair of triangles (a, b, c) and (d, c, b), which share the link
/// b–c and are both outward-oriented: θ is the angle between their outward normals
/// N1 = (b − a) × (c − a) and N2 = (c − d) × (b − d), positive for a convex fold (sign of
/// (N1 × N2)·(c − b)).
///
/// Returns `(cos θ, sin θ, ∂θ/∂[a, b, c, d])` (no trigonometric call: cos θ = N1·N2/(|N1||N2|),
/// sin θ = (N1 × N2)·ê/(|N1||N2|), exact for every angle), or `None` if either triangle or the
/// link is degenerate. The gradient: ∂θ/∂a = −|e|/|N1|² N1, ∂θ/∂d = −|e|/|N2|² N2, and, with
/// the projections t_a = (a − b)·e/|e|², t_d = (d − b)·e/|e|² of the wings on e = c − b,
/// ∂θ/∂b = −(1 − t_a) ∂θ/∂a − (1 − t_d) ∂θ/∂d, ∂θ/∂c = −t_a ∂θ/∂a − t_d ∂θ/∂d.
#[inline(always)]
pub fn dihedral(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> Option<(f64, f64, [DVec3; 4])> {
    let e = c - b;
    let n1 = (b - a).cross(c - a);
    let n2 = (c - d).cross(b - d);
    let e2 = e.length_squared();
    let n1s = n1.length_squared();
    let n2s = n2.length_squared();
    if !(e2 > 0.0 && n1s > 0.0 && n2s > 0.0) {
        return None;
    }
    let el = e2.sqrt();
    let inv_e2 = 1.0 / e2;
    let inv_n = 1.0 / (n1s * n2s).sqrt();
    let cos_t = n1.dot(n2) * inv_n;
    let sin_t = n1.cross(n2).dot(e) * (inv_n / el);
    let ga = n1 * (-el / n1s);
    let gd = n2 * (-el / n2s);
    let ta = (a - b).dot(e) * inv_e2;
    let td = (d - b).dot(e) * inv_e2;
    let gb = ga * (ta - 1.0) + gd * (td - 1.0);
    let gc = ga * (-ta) + gd * (-td);
    Some((cos_t, sin_t, [ga, gb, gc, gd]))
}

/// cos θ and sin θ of the signed dihedral angle (same convention as [`dihedral`]).
#[inline(always)]
pub fn dihedral_cos_sin(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> Option<(f64, f64)> {
    let e = c - b;
    let n1 = (b - a).cross(c - a);
    let n2 = (c - d).cross(b - d);
    let e2 = e.length_squared();
    let n1s = n1.length_squared();
    let n2s = n2.length_squared();
    if !(e2 > 0.0 && n1s > 0.0 && n2s > 0.0) {
        return None;
    }
    let inv_n = 1.0 / (n1s * n2s).sqrt();
    Some((n1.dot(n2) * inv_n, n1.cross(n2).dot(e) * (inv_n / e2.sqrt())))
}

/// The signed dihedral angle θ ∈ (−π, π] (same convention as [`dihedral`]).
#[inline(always)]
pub fn dihedral_angle(a: DVec3, b: DVec3, c: DVec3, d: DVec3) -> Option<f64> {
    dihedral_cos_sin(a, b, c, d).map(|(cos_t, sin_t)| sin_t.atan2(cos_t))
}

/// ∂A/∂L_a of a triangle with sides (a, b, c) and area `area` (Heron): a(b² + c² − a²)/(8A).
#[inline(always)]
pub fn heron_dadl(a: f64, b: f64, c: f64, area: f64) -> f64 {
    a * (b * b + c * c - a * a) / (8.0 * area)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wlc_derivatives_match_finite_differences() {
        for &x in &[0.05, 0.3, 1.0 / 3.17, 0.6, 0.9] {
            let h = 1e-5;
            let fd = (wlc_g(x + h) - wlc_g(x - h)) / (2.0 * h);
            assert!((fd / wlc_dg(x) - 1.0).abs() < 1e-7, "g' at {x}");
            let fd2 = (wlc_dg(x + h) - wlc_dg(x - h)) / (2.0 * h);
            assert!(
                (fd2 / wlc_ddg(x) - 1.0).abs() < 1e-7,
                "g'' at {x}: {fd2} vs {}",
                wlc_ddg(x)
            );
            // Marko–Siggia form of the tension
            let ms = 4.0 * (0.25 / (1.0 - x).powi(2) - 0.25 + x);
            assert!((ms / wlc_dg(x) - 1.0).abs() < 1e-14);
        }
        assert!(wlc(1.0, 1.0, 1.0).is_none());
        assert!(wlc(f64::NAN, 1.0, 1.0).is_none());
    }

    /// Convex fold → θ > 0; flat → 0; concave → θ < 0; a right-angle fold gives ±π/2.
    #[test]
    fn dihedral_sign_convention() {
        let b = DVec3::ZERO;
        let c = DVec3::X;
        let fold = |h: f64| {
            let a = DVec3::new(0.5, 1.0, -h);
            let d = DVec3::new(0.5, -1.0, -h);
            dihedral_angle(a, b, c, d).unwrap()
        };
        assert!(fold(0.0).abs() < 1e-15);
        assert!(fold(0.3) > 0.0);
        assert!(fold(-0.3) < 0.0);
        // h = 1: each face tilted by 45°, normals 90° apart
        assert!((fold(1.0) - std::f64::consts::FRAC_PI_2).abs() < 1e-14);
    }
}
