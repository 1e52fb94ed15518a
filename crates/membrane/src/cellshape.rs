//! Shape measures of a cell in a tube (docs/capillary.md), from its vertex positions.
//!
//! The tube axis is a coordinate axis (`axis`, the flow along +axis); ρ is the distance of a
//! vertex from the line through the cell's centroid parallel to it, y its coordinate along it
//! relative to the centroid.
//!
//! * axial length: max y − min y;
//! * maximum radial extent: max ρ, and the width 2·max ρ;
//! * deformation index DI = axial length / width (Tomaiuolo et al. 2009 define DI as the cell's
//!   length over its width in the capillary image, which is this for an axisymmetric cell);
//! * silhouette width: the width of the cell's image seen from the side, as through a
//!   microscope: the extent of the vertices across the axis along a direction u ⊥ axis,
//!   averaged over [`SILHOUETTE_VIEWS`] viewing directions evenly spaced about the axis (the
//!   experiments see each cell from one side, at a random angle about the tube); never more
//!   than 2·max ρ, equal to it for an axisymmetric cell. The silhouette DI = axial length /
//!   silhouette width;
//! * cross-section roundness: √(λmin/λmax) of the vertices' 2×2 covariance across the axis:
//!   1 for a cell that is round seen along the tube (a face-on disc, an axisymmetric parachute
//!   or bullet), ≈ thickness/diameter for an edge-on disc, in between for a folded or slipper
//!   cell;
//! * symmetry-axis tilt: the angle (degrees, 0–90) between the cell's own symmetry axis (below)
//!   and the tube axis: ≈ 0 for a face-on disc or an axisymmetric parachute, ≈ 90 for an edge-on
//!   disc, in between for a tilted cup (a slipper);
//! * parachute concavity depth: the mean y of the rear vertices near the axis (ρ < 0.3 max ρ,
//!   y < 0) minus the rearmost y. At rest (biconcave, axis along the tube) it is the dimple,
//!   ≈ 0.85 µm for the healthy cell; a parachute deepens it;
//! * distance from the resting shape: the RMS over vertices of the distance of (ρ', |y'|) from
//!   the resting Evans–Fung profile, where y' and ρ' are measured in the cell's own frame: along
//!   and about its symmetry axis, the eigenvector of the smallest eigenvalue of the vertices'
//!   gyration tensor (the thin direction of a discocyte or a parachute). So it is blind to the
//!   cell's rotation (a tilt by Brownian rotation is not a change of shape) and to
//!   tank-treading of the membrane; at rest it is the thermal roughness.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::shape::EvansFung;

/// The resting profile as a polyline (ρ, y ≥ 0), in the caller's length unit.
#[derive(Clone, Debug)]
pub struct RestProfile {
    points: Vec<(f64, f64)>,
}

impl RestProfile {
    /// The profile of `shape` (lengths in its unit), `n` segments.
    pub fn new(shape: &EvansFung, n: usize) -> Self {
        let n = n.max(8);
        // denser near the rim, where the profile turns: ρ = R sin(φ)
        let points = (0..=n)
            .map(|k| {
                let phi = std::f64::consts::FRAC_PI_2 * k as f64 / n as f64;
                let rho = shape.r * phi.sin();
                (rho, shape.half_thickness(rho).max(0.0))
            })
            .collect();
        RestProfile { points }
    }

    /// Distance of the point (ρ, y), y ≥ 0, from the profile.
    pub fn distance(&self, rho: f64, y: f64) -> f64 {
        let mut best = f64::INFINITY;
        for w in self.points.windows(2) {
            let (a, b) = (w[0], w[1]);
            let (dx, dy) = (b.0 - a.0, b.1 - a.1);
            let l2 = dx * dx + dy * dy;
            let t = if l2 > 0.0 {
                (((rho - a.0) * dx + (y - a.1) * dy) / l2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let (px, py) = (a.0 + t * dx - rho, a.1 + t * dy - y);
            best = best.min(px * px + py * py);
        }
        best.sqrt()
    }
}

/// Shape measures of one configuration (lengths in the positions' unit).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ShapeMetrics {
    /// Centroid of the vertices.
    pub centroid: [f64; 3],
    /// Extent along the tube axis.
    pub axial_length: f64,
    /// Largest distance of a vertex from the axis through the centroid.
    pub max_radius: f64,
    /// axial length / (2 max radius).
    pub deformation_index: f64,
    /// Parachute concavity depth (see the module docs).
    pub concavity_depth: f64,
    /// RMS distance from the resting profile.
    pub distance_from_rest: f64,
    /// Width of the side view, averaged over the viewing directions about the axis.
    #[serde(default)]
    pub silhouette_width: f64,
    /// axial length / silhouette width.
    #[serde(default)]
    pub silhouette_deformation_index: f64,
    /// Angle between the cell's own symmetry axis and the tube axis, degrees (0–90).
    #[serde(default)]
    pub symmetry_axis_tilt_deg: f64,
    /// √(λmin/λmax) of the covariance across the axis (1: round seen along the tube).
    #[serde(default)]
    pub cross_section_roundness: f64,
}

/// √(λmin/λmax) of the 2×2 covariance of `x` about `c` in the plane across `axis`.
pub fn cross_section_roundness(x: &[DVec3], c: DVec3, axis: usize) -> f64 {
    let (a1, a2) = ((axis + 1) % 3, (axis + 2) % 3);
    let (mut s11, mut s22, mut s12) = (0.0, 0.0, 0.0);
    for p in x {
        let (u, v) = (p[a1] - c[a1], p[a2] - c[a2]);
        s11 += u * u;
        s22 += v * v;
        s12 += u * v;
    }
    let mean = 0.5 * (s11 + s22);
    let dev = (0.25 * (s11 - s22).powi(2) + s12 * s12).sqrt();
    let (lo, hi) = (mean - dev, mean + dev);
    if hi > 0.0 {
        (lo.max(0.0) / hi).sqrt()
    } else {
        f64::NAN
    }
}

/// Viewing directions about the tube axis over which the silhouette width is averaged (every
/// 5°; the extent along u and −u is the same, so 36 cover the half-turn).
pub const SILHOUETTE_VIEWS: usize = 36;

/// The side view's width of `x` across `axis`, averaged over [`SILHOUETTE_VIEWS`] directions.
pub fn silhouette_width(x: &[DVec3], axis: usize) -> f64 {
    let (a1, a2) = ((axis + 1) % 3, (axis + 2) % 3);
    let mut sum = 0.0;
    for k in 0..SILHOUETTE_VIEWS {
        let phi = std::f64::consts::PI * k as f64 / SILHOUETTE_VIEWS as f64;
        let (c, s) = (phi.cos(), phi.sin());
        let (lo, hi) = x.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
            let u = c * p[a1] + s * p[a2];
            (lo.min(u), hi.max(u))
        });
        sum += (hi - lo).max(0.0);
    }
    sum / SILHOUETTE_VIEWS as f64
}

/// Unit eigenvector of the smallest eigenvalue of the symmetric matrix `m` (cyclic Jacobi).
pub fn smallest_eigenvector(m: [[f64; 3]; 3]) -> DVec3 {
    let mut a = m;
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..50 {
        let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
        if off < 1e-15 * (a[0][0].abs() + a[1][1].abs() + a[2][2].abs()).max(1e-300) {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q] == 0.0 {
                continue;
            }
            let theta = 0.5 * (a[q][q] - a[p][p]) / a[p][q];
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            for k in 0..3 {
                let (akp, akq) = (a[k][p], a[k][q]);
                a[k][p] = c * akp - s * akq;
                a[k][q] = s * akp + c * akq;
            }
            for k in 0..3 {
                let (apk, aqk) = (a[p][k], a[q][k]);
                a[p][k] = c * apk - s * aqk;
                a[q][k] = s * apk + c * aqk;
            }
            for k in 0..3 {
                let (vkp, vkq) = (v[k][p], v[k][q]);
                v[k][p] = c * vkp - s * vkq;
                v[k][q] = s * vkp + c * vkq;
            }
        }
    }
    let j = (0..3).min_by(|&i, &k| a[i][i].total_cmp(&a[k][k])).unwrap_or(0);
    DVec3::new(v[0][j], v[1][j], v[2][j]).normalize()
}

/// The symmetry axis of a cell: the thin direction of its vertices' gyration tensor.
pub fn symmetry_axis(x: &[DVec3], c: DVec3) -> DVec3 {
    let mut g = [[0.0; 3]; 3];
    for p in x {
        let d = *p - c;
        for i in 0..3 {
            for j in 0..3 {
                g[i][j] += d[i] * d[j];
            }
        }
    }
    smallest_eigenvector(g)
}

/// The measures of the (unwrapped) vertex positions `x`, tube axis `axis` (0, 1, 2).
pub fn metrics(x: &[DVec3], axis: usize, rest: &RestProfile) -> ShapeMetrics {
    let n = x.len().max(1) as f64;
    let c = x.iter().fold(DVec3::ZERO, |a, p| a + *p) / n;
    let own = symmetry_axis(x, c);
    let split = |p: DVec3| {
        let d = p - c;
        let y = d[axis];
        let mut perp = d;
        perp[axis] = 0.0;
        (perp.length(), y)
    };
    let (mut ymin, mut ymax, mut rmax) = (f64::INFINITY, f64::NEG_INFINITY, 0.0f64);
    let mut sq = 0.0;
    for p in x {
        let (rho, y) = split(*p);
        ymin = ymin.min(y);
        ymax = ymax.max(y);
        rmax = rmax.max(rho);
        let dv = *p - c;
        let y_own = dv.dot(own);
        let rho_own = (dv - own * y_own).length();
        let d = rest.distance(rho_own, y_own.abs());
        sq += d * d;
    }
    let (mut rear_sum, mut rear_n) = (0.0, 0usize);
    for p in x {
        let (rho, y) = split(*p);
        if rho < 0.3 * rmax && y < 0.0 {
            rear_sum += y;
            rear_n += 1;
        }
    }
    let concavity = if rear_n > 0 {
        rear_sum / rear_n as f64 - ymin
    } else {
        0.0
    };
    let length = ymax - ymin;
    let width = silhouette_width(x, axis);
    ShapeMetrics {
        centroid: c.to_array(),
        axial_length: length,
        max_radius: rmax,
        deformation_index: if rmax > 0.0 { length / (2.0 * rmax) } else { f64::NAN },
        concavity_depth: concavity,
        distance_from_rest: (sq / n).sqrt(),
        silhouette_width: width,
        silhouette_deformation_index: if width > 0.0 { length / width } else { f64::NAN },
        symmetry_axis_tilt_deg: own[axis].abs().min(1.0).acos().to_degrees(),
        cross_section_roundness: cross_section_roundness(x, c, axis),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points on the resting shape (symmetry axis along z) measure: length = the thickness at
    /// the thickest ring, width = 2R, distance 0, concavity = max half-thickness − centre one.
    #[test]
    fn resting_shape_measures() {
        let s = EvansFung::healthy_um();
        let rest = RestProfile::new(&s, 400);
        let mut x = Vec::new();
        for i in 0..=60 {
            let rho = s.r * (i as f64 / 60.0).powf(0.5);
            for k in 0..24 {
                let phi = k as f64 * std::f64::consts::TAU / 24.0;
                let h = s.half_thickness(rho).max(0.0);
                for sign in [1.0, -1.0] {
                    x.push(DVec3::new(rho * phi.cos(), rho * phi.sin(), sign * h) + DVec3::new(3.0, -2.0, 40.0));
                }
            }
        }
        let m = metrics(&x, 2, &rest);
        let (tmin, tmax) = s.thickness_min_max();
        assert!((m.axial_length - tmax).abs() < 0.02, "{m:?} vs {tmax}");
        assert!((m.max_radius - s.r).abs() < 1e-9);
        assert!(m.distance_from_rest < 2e-3, "{m:?}");
        // the rear near the axis (ρ < 0.3 R) averages over the dimple's floor, which rises
        // towards the rim: between 0.75 and 1 of the full dimple depth (0.88 µm)
        let dimple = 0.5 * (tmax - tmin);
        let ratio = m.concavity_depth / dimple;
        assert!((0.75..1.0).contains(&ratio), "{} vs {dimple}", m.concavity_depth);
        // a cell stretched 20 % along the axis is 0.2·|y| RMS away from rest
        let y: Vec<DVec3> = x
            .iter()
            .map(|p| DVec3::new(p.x, p.y, 40.0 + 1.2 * (p.z - 40.0)))
            .collect();
        let m2 = metrics(&y, 2, &rest);
        assert!(m2.distance_from_rest > 0.05 && m2.deformation_index > m.deformation_index);
        // the same resting cell tilted by 20° is still at distance 0 from rest
        let rot = glam::DQuat::from_axis_angle(DVec3::new(1.0, 1.0, 0.0).normalize(), 20f64.to_radians());
        let c = DVec3::new(3.0, -2.0, 40.0);
        let tilted: Vec<DVec3> = x.iter().map(|p| c + rot * (*p - c)).collect();
        let m3 = metrics(&tilted, 2, &rest);
        assert!(m3.distance_from_rest < 2e-3, "{m3:?}");
        assert!((m3.symmetry_axis_tilt_deg - 20.0).abs() < 0.01, "{m3:?}");
        // the face-on disc is seen 2R wide from every side (the rings' polygon, 24 points,
        // loses at most 1 − cos(7.5°) of it), and tilts by 0°
        assert!(m.symmetry_axis_tilt_deg < 0.01, "{m:?}");
        assert!((m.cross_section_roundness - 1.0).abs() < 1e-9, "{m:?}");
        assert!((m.silhouette_width / (2.0 * s.r) - 1.0).abs() < 0.01, "{m:?}");
        assert!((m.silhouette_deformation_index - m.deformation_index).abs() < 0.01 * m.deformation_index);
    }

    /// An edge-on ellipse-like cell: the silhouette width is the mean over the views of the
    /// caliper width of an ellipse with semi-axes a, b across the axis, which is below the
    /// 2·max ρ of `deformation_index`; checked against the ellipse's exact mean caliper
    /// width, (1/π)∫ 2√(a² cos²φ + b² sin²φ) dφ, by quadrature.
    #[test]
    fn silhouette_of_a_flat_cell_seen_from_the_side() {
        let (a, b) = (3.9, 1.2);
        let mut x = Vec::new();
        for k in 0..720 {
            let t = std::f64::consts::TAU * k as f64 / 720.0;
            for z in [-2.0, 0.0, 2.0] {
                x.push(DVec3::new(a * t.cos(), b * t.sin(), z));
            }
        }
        let w = silhouette_width(&x, 2);
        let m = 20_000;
        let exact = (0..m)
            .map(|k| {
                let phi = std::f64::consts::PI * (k as f64 + 0.5) / m as f64;
                2.0 * (a * a * phi.cos().powi(2) + b * b * phi.sin().powi(2)).sqrt()
            })
            .sum::<f64>()
            / m as f64;
        assert!((w / exact - 1.0).abs() < 2e-3, "{w} vs {exact}");
        // a uniform ring of points on the ellipse: covariance ∝ a², b², roundness b/a
        let c = x.iter().fold(DVec3::ZERO, |s, p| s + *p) / x.len() as f64;
        assert!((cross_section_roundness(&x, c, 2) - b / a).abs() < 1e-6);
        assert!(w < 2.0 * a * 0.8);
        // rotating the cell about the axis changes nothing beyond the 5° sampling of the views
        let rot = glam::DQuat::from_rotation_z(0.3);
        let w2 = silhouette_width(&x.iter().map(|p| rot * *p).collect::<Vec<_>>(), 2);
        assert!((w2 / w - 1.0).abs() < 5e-3, "{w2} vs {w}");
    }
}
