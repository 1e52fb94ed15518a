//! Stress-free reference shapes other than the resting cell: the oblate spheroid of the cell's
//! area and a chosen reduced volume (docs/model.md, "The stress-free reference").
//!
//! The membrane's in-plane elasticity is stress-free on its reference; the resting cell is what
//! bending, the reference and the global area and volume constraints settle on. A reference
//! closer to a sphere than the biconcave cell (reduced volume 0.93–0.97 rather than 0.64) is
//! what fits stretching, relaxation and tank-treading together in the peer studies (Amoudruz
//! et al., tRBC-UQ); [`spheroid_reference`] builds it for any mesh of the cell.

use crate::cellshape::smallest_eigenvector;
use crate::mesh::area_of;
use crate::shape::reduced_volume;
use glam::DVec3;
use std::f64::consts::PI;

/// An oblate spheroid about its local y axis: semi-axes `a` (x and z) and `c` ≤ `a` (y).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spheroid {
    pub a: f64,
    pub c: f64,
}

impl Spheroid {
    /// Surface area 2πa²(1 + (1 − e²) artanh(e)/e), e² = 1 − c²/a² (4πa² for a sphere).
    pub fn area(&self) -> f64 {
        let (a, c) = (self.a, self.c);
        let e = (1.0 - (c / a).powi(2)).max(0.0).sqrt();
        if e < 1e-8 {
            // the series of artanh(e)/e: 1 + e²/3; the area is 4πa²(1 − e²/3) to O(e⁴)
            return 4.0 * PI * a * a * (1.0 - e * e / 3.0);
        }
        2.0 * PI * a * a * (1.0 + (1.0 - e * e) * e.atanh() / e)
    }

    /// Volume 4πa²c/3.
    pub fn volume(&self) -> f64 {
        4.0 / 3.0 * PI * self.a * self.a * self.c
    }

    /// Reduced volume v = 6√π V / A^(3/2).
    pub fn reduced_volume(&self) -> f64 {
        reduced_volume(self.area(), self.volume())
    }

    /// The oblate spheroid of surface area `area` and reduced volume `v` (0 < v ≤ 1), or
    /// `None` outside that range. v grows monotonically with c/a, from 0 (a flat disc) to 1 (a
    /// sphere), so c/a is found by bisection to round-off.
    pub fn with_area_and_reduced_volume(area: f64, v: f64) -> Option<Self> {
        if !(v > 0.0 && v <= 1.0 && area > 0.0 && area.is_finite()) {
            return None;
        }
        let (mut lo, mut hi) = (0.0f64, 1.0f64);
        for _ in 0..100 {
            let mid = 0.5 * (lo + hi);
            if (Spheroid { a: 1.0, c: mid }).reduced_volume() < v {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let unit = Spheroid {
            a: 1.0,
            c: 0.5 * (lo + hi),
        };
        let k = (area / unit.area()).sqrt();
        Some(Spheroid { a: k, c: k * unit.c })
    }
}

/// The cell's centroid and its symmetry axis: the direction of the smallest principal moment of
/// the vertices' gyration tensor (the biconcave cell is thinnest along its axis).
pub fn cell_axis(x: &[DVec3]) -> (DVec3, DVec3) {
    let n = x.len().max(1) as f64;
    let centre = x.iter().copied().sum::<DVec3>() / n;
    let mut g = [[0.0; 3]; 3];
    for p in x {
        let d = (*p - centre).to_array();
        for (i, row) in g.iter_mut().enumerate() {
            for (j, e) in row.iter_mut().enumerate() {
                *e += d[i] * d[j] / n;
            }
        }
    }
    (centre, smallest_eigenvector(g))
}

/// The vertices of the cell mesh `rest` (any position and orientation) moved onto the oblate
/// spheroid of the same area and reduced volume `v`, keeping the mesh's topology: the
/// stress-free reference of a spheroidal cell. Each vertex keeps its polar parameter: at height
/// y along the cell's axis and distance ρ from it, u = (ρ/R, ±√(1 − ρ²/R²)) on the unit circle
/// (R the largest ρ: the inverse of the Evans–Fung map for a mesh on that shape), placed at
/// (a u_ρ, c u_y) on the spheroid about the same axis and centre. The result is scaled so that
/// its triangulated area equals that of `rest`. `None` if v is outside (0, 1] or the mesh is
/// degenerate.
pub fn spheroid_reference(rest: &[DVec3], triangles: &[[u32; 3]], v: f64) -> Option<Vec<DVec3>> {
    let area = area_of(rest, triangles);
    let shape = Spheroid::with_area_and_reduced_volume(area, v)?;
    let (centre, axis) = cell_axis(rest);
    let split = |p: DVec3| {
        let d = p - centre;
        let y = d.dot(axis);
        (y, d - y * axis)
    };
    let r_max = rest.iter().map(|p| split(*p).1.length()).fold(0.0, f64::max);
    if r_max.is_nan() || r_max <= 0.0 {
        return None;
    }
    let mut x: Vec<DVec3> = rest
        .iter()
        .map(|p| {
            let (y, radial) = split(*p);
            let s = (radial.length() / r_max).min(1.0);
            let uy = (1.0 - s * s).max(0.0).sqrt().copysign(y);
            let dir = radial.try_normalize().unwrap_or(DVec3::ZERO);
            centre + dir * (shape.a * s) + axis * (shape.c * uy)
        })
        .collect();
    let k = (area / area_of(&x, triangles)).sqrt();
    if !(k.is_finite() && k > 0.0) {
        return None;
    }
    for p in &mut x {
        *p = centre + (*p - centre) * k;
    }
    Some(x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shape::EvansFung;

    #[test]
    fn spheroid_area_and_reduced_volume_are_as_asked() {
        // a sphere: v = 1, a = c = √(A/4π); v is flat in c/a there (1 − v ∝ (1 − c/a)²), so
        // c/a is found only to ≈ √ε
        let s = Spheroid::with_area_and_reduced_volume(4.0 * PI, 1.0).unwrap();
        assert!((s.a - 1.0).abs() < 1e-7 && (s.c - 1.0).abs() < 1e-7, "{s:?}");
        for v in [0.3, 0.644, 0.93, 0.95, 0.97, 0.999] {
            let s = Spheroid::with_area_and_reduced_volume(134.1, v).unwrap();
            assert!((s.area() / 134.1 - 1.0).abs() < 1e-12, "v = {v}: area {}", s.area());
            assert!(
                (s.reduced_volume() - v).abs() < 1e-12,
                "v = {v}: {}",
                s.reduced_volume()
            );
            assert!(s.c < s.a);
        }
        // a flat disc's area is 2πa²: at small c/a the closed form tends to it
        let s = Spheroid { a: 1.0, c: 1e-6 };
        assert!((s.area() / (2.0 * PI) - 1.0).abs() < 1e-5);
        // out of range
        for v in [0.0, -0.1, 1.01, f64::NAN] {
            assert!(Spheroid::with_area_and_reduced_volume(1.0, v).is_none(), "{v}");
        }
    }

    /// The area of an oblate spheroid by quadrature of its surface of revolution, against the
    /// closed form.
    #[test]
    fn spheroid_area_matches_quadrature() {
        let s = Spheroid { a: 4.0, c: 1.5 };
        let n = 200_000;
        let mut sum = 0.0;
        for k in 0..n {
            let t = PI * (k as f64 + 0.5) / n as f64;
            let (rho, dr, dy) = (s.a * t.sin(), s.a * t.cos(), s.c * t.sin());
            sum += 2.0 * PI * rho * (dr * dr + dy * dy).sqrt() * PI / n as f64;
        }
        assert!((sum / s.area() - 1.0).abs() < 1e-8, "{sum} vs {}", s.area());
    }

    #[test]
    fn reference_of_a_cell_mesh_is_the_spheroid_of_its_area() {
        let mesh = crate::meshgen::initial_mesh(&EvansFung::healthy_um(), 500, 7).unwrap();
        // placed anywhere, turned about some axis
        let rot = glam::DQuat::from_axis_angle(DVec3::new(1.0, 2.0, -0.5).normalize(), 0.7);
        let shift = DVec3::new(3.0, -1.0, 12.0);
        let placed: Vec<DVec3> = mesh.vertices.iter().map(|p| rot * *p + shift).collect();
        let v = 0.95;
        let x = spheroid_reference(&placed, &mesh.triangles, v).unwrap();
        let a0 = area_of(&placed, &mesh.triangles);
        assert!((area_of(&x, &mesh.triangles) / a0 - 1.0).abs() < 1e-12);
        // every vertex on the spheroid of area a0 (to the mesh's discretisation: the polygon's
        // area is below the surface's, so the scaled mesh is slightly larger)
        let s = Spheroid::with_area_and_reduced_volume(a0, v).unwrap();
        let axis = rot * DVec3::Y;
        for p in &x {
            let d = *p - shift;
            let y = d.dot(axis);
            let rho = (d - y * axis).length();
            let on = (rho / s.a).powi(2) + (y / s.c).powi(2);
            assert!((on.sqrt() - 1.0).abs() < 0.02, "vertex off the spheroid: {on}");
        }
        // the discrete reduced volume close to v
        let vol = crate::mesh::volume_of(&x, &mesh.triangles);
        let vd = reduced_volume(a0, vol);
        assert!((vd - v).abs() < 0.01, "discrete v = {vd}");
    }

    /// The cell at rest (static equilibrium at zero force, N = 500, µm and pN) with the
    /// stress-free reference on the resting cell and on spheroids of reduced volume 0.9–0.97:
    /// its RMS distance from the Evans–Fung surface, its area and volume against A0, V0, and its
    /// thickness at the centre and at the rim, printed; asserted: A and V within 1 % of the
    /// resting cell's, and the shape still biconcave (thinner at the centre than at the rim,
    /// within 0.1 R of the Evans–Fung surface).
    #[test]
    fn spheroidal_reference_rests_biconcave() {
        use crate::forces::{MembraneConstants, MembraneModel, ReferenceState};
        use crate::meshgen::{generate, MeshGenOptions};
        use crate::params::ModelParams;
        use crate::stretch::{stretch, Preconditioning, StretchOptions};
        let shape = EvansFung::healthy_um();
        let p = ModelParams::coarse_grained(500, 300.0).unwrap();
        let c = MembraneConstants::from_params_um_pn(&p);
        let (mesh, _) = generate(&shape, &c, &MeshGenOptions::new(500, 1)).unwrap();
        let topo = mesh.topology().unwrap();
        let (a0, v0) = (mesh.area(), mesh.volume());
        let opts = StretchOptions {
            forces: vec![0.0],
            end_fraction: 0.05,
            tolerance: 1e-4,
            max_iterations: 20_000,
            preconditioning: Preconditioning::GaussNewton,
        };
        for reference in [
            ReferenceState::StressFree,
            ReferenceState::Spheroid { reduced_volume: 0.9 },
            ReferenceState::Spheroid { reduced_volume: 0.95 },
            ReferenceState::Spheroid { reduced_volume: 0.97 },
        ] {
            let model = MembraneModel::new(&topo, &mesh.vertices, &c, reference).unwrap();
            assert_eq!(model.reference(), reference);
            let eq = stretch(&model, &mesh.vertices, &opts, |_| {}).unwrap();
            let x = &eq[0].positions;
            // in the cell's own frame (a rigid motion costs nothing)
            let (centre, axis) = cell_axis(x);
            let e1 = axis.any_orthonormal_vector();
            let e2 = axis.cross(e1);
            let local: Vec<DVec3> = x
                .iter()
                .map(|p| {
                    let d = *p - centre;
                    DVec3::new(d.dot(e1), d.dot(axis), d.dot(e2))
                })
                .collect();
            let rms = (local
                .iter()
                .map(|p| (*p - shape.project(*p)).length_squared())
                .sum::<f64>()
                / local.len() as f64)
                .sqrt();
            let (a, v) = (
                crate::mesh::area_of(x, &mesh.triangles),
                crate::mesh::volume_of(x, &mesh.triangles),
            );
            // thickness: the extent along the axis of the vertices near the axis and near the rim's crest
            let thick = |lo: f64, hi: f64| {
                let ys: Vec<f64> = local
                    .iter()
                    .filter(|p| {
                        let r = (p.x * p.x + p.z * p.z).sqrt() / shape.r;
                        r >= lo && r < hi
                    })
                    .map(|p| p.y)
                    .collect();
                ys.iter().cloned().fold(f64::NEG_INFINITY, f64::max) - ys.iter().cloned().fold(f64::INFINITY, f64::min)
            };
            let (centre_t, rim_t) = (thick(0.0, 0.25), thick(0.6, 0.8));
            println!(
                "{reference:?}: RMS distance from Evans–Fung {rms:.3} µm ({:.3} R), A/A0 − 1 = {:+.2e}, V/V0 − 1 = {:+.2e}, thickness centre {centre_t:.2} µm, rim {rim_t:.2} µm, residual {:.1e} pN in {} iterations",
                rms / shape.r,
                a / a0 - 1.0,
                v / v0 - 1.0,
                eq[0].residual,
                eq[0].iterations
            );
            assert!(
                (a / a0 - 1.0).abs() < 0.01 && (v / v0 - 1.0).abs() < 0.01,
                "{reference:?}"
            );
            assert!(
                centre_t < rim_t,
                "{reference:?}: not biconcave ({centre_t} at the centre, {rim_t} at the rim)"
            );
            assert!(rms < 0.1 * shape.r, "{reference:?}: {rms} µm from the Evans–Fung shape");
        }
    }

    /// The spheroidal construction on generated meshes of several N: it succeeds (every link's
    /// C/A-to-WLC tension ratio inside the bounds), the in-plane force vanishes on the spheroid
    /// (it is the reference) and not on the resting cell, and A0, V0 are the resting cell's.
    #[test]
    fn spheroidal_reference_at_several_n() {
        use crate::forces::{MembraneConstants, MembraneModel, TermSet};
        use crate::meshgen::{generate, MeshGenOptions};
        use crate::params::ModelParams;
        let shape = EvansFung::healthy_um();
        for n in [100, 500, 1000, 2000] {
            let p = ModelParams::coarse_grained(n, 300.0).unwrap();
            let c = MembraneConstants::from_params_um_pn(&p);
            let (mesh, _) = generate(&shape, &c, &MeshGenOptions::new(n, 1)).unwrap();
            let topo = mesh.topology().unwrap();
            let model =
                MembraneModel::spheroidal(&topo, &mesh.vertices, &c, 0.95).unwrap_or_else(|e| panic!("N = {n}: {e}"));
            assert!((model.area0() / mesh.area() - 1.0).abs() < 1e-12, "N = {n}");
            assert!((model.volume0() / mesh.volume() - 1.0).abs() < 1e-12, "N = {n}");
            let reference = spheroid_reference(&mesh.vertices, &mesh.triangles, 0.95).unwrap();
            let in_plane = |x: &[DVec3]| {
                let mut f = vec![DVec3::ZERO; x.len()];
                model.add_forces_terms(x, &mut f, TermSet::IN_PLANE).unwrap();
                f.iter().map(|v| v.length()).fold(0.0, f64::max)
            };
            let x0 = c.x0();
            let f_link = c.kbt / c.persistence_length * (0.25 / (1.0 - x0).powi(2) - 0.25 + x0);
            let (on_reference, at_rest) = (in_plane(&reference), in_plane(&mesh.vertices));
            assert!(
                on_reference < 1e-10 * f_link,
                "N = {n}: {on_reference} pN on the spheroid"
            );
            assert!(at_rest > 0.01 * f_link, "N = {n}: {at_rest} pN at rest");
        }
    }
}
