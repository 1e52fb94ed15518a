//! The paper's mesh procedure: distribute N points uniformly over the Evans–Fung shape,
//! triangulate them, then relax them by the model's in-plane free energy while holding them
//! on the shape and flipping every link to the shorter diagonal of its two triangles, until
//! nothing moves and nothing flips.
//!
//! * Points: a golden-angle spiral that is uniform in the *cell's* area (the latitude of point
//!   i is where the cumulative area reaches (i + ½)/N), jittered by a seeded RNG.
//! * Triangulation: the convex hull of the points' pre-images on the unit sphere (a spherical
//!   Delaunay triangulation); the sphere → cell map is one-to-one and orientation-preserving.
//! * Relaxation: FIRE (damped inertial descent) on the in-plane energy Σ V_WLC + Σ C/A with the
//!   paper's uniform L0, forces projected onto the surface's tangent plane, positions projected
//!   back on the shape after each step; a flip pass every `flip_interval` steps.

use crate::forces::{MembraneConstants, MembraneModel};
use crate::mesh::{Mesh, MeshError};
use crate::shape::EvansFung;
use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::collections::HashSet;

/// Options of the mesh generator. Lengths in the unit of the shape's radius.
#[derive(Clone, Debug)]
pub struct MeshGenOptions {
    /// Number of vertices (≥ 4; the model needs ≥ 100).
    pub n: usize,
    /// Seed of the point jitter: the mesh is a deterministic function of (n, seed, options).
    pub seed: u64,
    /// Stop when the largest tangential force is below this fraction of the mean link tension.
    pub force_tolerance: f64,
    /// Upper bound on FIRE steps.
    pub max_steps: usize,
    /// A flip pass every this many steps.
    pub flip_interval: usize,
}

impl MeshGenOptions {
    pub fn new(n: usize, seed: u64) -> Self {
        Self {
            n,
            seed,
            force_tolerance: 1e-4,
            max_steps: 200_000,
            flip_interval: 100,
        }
    }
}

/// What the relaxation did.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RelaxReport {
    pub steps: usize,
    pub flips: usize,
    /// Largest tangential force over the mean link tension at the end.
    pub residual: f64,
    pub converged: bool,
}

/// Errors of mesh generation.
#[derive(Debug, thiserror::Error)]
pub enum MeshGenError {
    #[error("cannot mesh the cell with n = {0} vertices: at least 4 are needed (the model needs 100)")]
    TooFew(usize),
    #[error("convex hull failed: {0}")]
    Hull(String),
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error("relaxation: {0}")]
    Force(#[from] crate::forces::ForceError),
}

/// Cumulative area of the upper half of the shape as a function of the polar angle t of the
/// sphere parametrisation (ρ = R sin t). Returns (t_k, A_k) on a fine grid.
fn cumulative_half_area(shape: &EvansFung, samples: usize) -> (Vec<f64>, Vec<f64>) {
    let h = std::f64::consts::FRAC_PI_2 / samples as f64;
    let dens = |t: f64| {
        let (st, ct) = t.sin_cos();
        let s = st * st;
        let rho = shape.r * st;
        let drho = shape.r * ct;
        let dy = shape.r * (-st * shape.poly(s) + ct * (shape.c1 + 2.0 * shape.c2 * s) * 2.0 * st * ct);
        2.0 * std::f64::consts::PI * rho * (drho * drho + dy * dy).sqrt()
    };
    let mut ts = vec![0.0];
    let mut acc = vec![0.0];
    for k in 0..samples {
        let (a, b) = (k as f64 * h, (k + 1) as f64 * h);
        let seg = (b - a) / 6.0 * (dens(a) + 4.0 * dens(0.5 * (a + b)) + dens(b));
        ts.push(b);
        acc.push(acc[k] + seg);
    }
    (ts, acc)
}

/// N points spread uniformly (in area) over the cell, returned as their pre-images on the unit
/// sphere. Deterministic for a seed.
pub fn spiral_points_on_sphere(shape: &EvansFung, n: usize, seed: u64) -> Vec<DVec3> {
    let (ts, acc) = cumulative_half_area(shape, 20_000);
    let half = *acc.last().unwrap();
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let jitter = 0.15; // fraction of the spacing
    (0..n)
        .map(|i| {
            // fraction of the total area from the +y pole
            let q = (i as f64 + 0.5 + jitter * (rng.random::<f64>() - 0.5)) / n as f64;
            let (target, upper) = if q <= 0.5 {
                (q * 2.0 * half, true)
            } else {
                ((1.0 - q) * 2.0 * half, false)
            };
            let k = acc.partition_point(|&a| a < target).clamp(1, acc.len() - 1);
            let w = (target - acc[k - 1]) / (acc[k] - acc[k - 1]).max(f64::MIN_POSITIVE);
            let t = ts[k - 1] + w * (ts[k] - ts[k - 1]);
            let phi = i as f64 * golden + jitter * (rng.random::<f64>() - 0.5) * golden;
            let (st, ct) = t.sin_cos();
            let uy = if upper { ct } else { -ct };
            DVec3::new(st * phi.cos(), uy, st * phi.sin())
        })
        .collect()
}

/// Convex hull of points on (or near) the unit sphere, as outward-oriented triangles.
/// Incremental; O(N × faces), a second or two for 24k points.
pub fn convex_hull(points: &[DVec3]) -> Result<Vec<[u32; 3]>, MeshGenError> {
    let n = points.len();
    if n < 4 {
        return Err(MeshGenError::TooFew(n));
    }
    // Initial tetrahedron from well-separated points.
    let p0 = 0usize;
    let p1 = (0..n)
        .max_by(|&a, &b| {
            cmp(
                points[a].distance_squared(points[p0]),
                points[b].distance_squared(points[p0]),
            )
        })
        .unwrap();
    let line = (points[p1] - points[p0]).normalize();
    let dist_line = |i: usize| {
        let d = points[i] - points[p0];
        (d - line * d.dot(line)).length_squared()
    };
    let p2 = (0..n).max_by(|&a, &b| cmp(dist_line(a), dist_line(b))).unwrap();
    let nrm = (points[p1] - points[p0]).cross(points[p2] - points[p0]).normalize();
    let p3 = (0..n)
        .max_by(|&a, &b| {
            cmp(
                (points[a] - points[p0]).dot(nrm).abs(),
                (points[b] - points[p0]).dot(nrm).abs(),
            )
        })
        .unwrap();
    if (points[p3] - points[p0]).dot(nrm).abs() < 1e-12 {
        return Err(MeshGenError::Hull("all points are coplanar".into()));
    }
    let centre = (points[p0] + points[p1] + points[p2] + points[p3]) / 4.0;
    struct Face {
        v: [u32; 3],
        n: DVec3,
        a: DVec3,
    }
    let make = |v: [u32; 3]| -> Face {
        let (a, b, c) = (points[v[0] as usize], points[v[1] as usize], points[v[2] as usize]);
        Face {
            v,
            n: (b - a).cross(c - a),
            a,
        }
    };
    let mut faces: Vec<Face> = Vec::with_capacity(2 * n);
    for tri in [[p0, p1, p2], [p0, p1, p3], [p0, p2, p3], [p1, p2, p3]] {
        let mut v = tri.map(|i| i as u32);
        let f = make(v);
        if f.n.dot(f.a - centre) < 0.0 {
            v.swap(1, 2);
        }
        faces.push(make(v));
    }
    let mut edges: HashSet<(u32, u32)> = HashSet::new();
    let mut visible = Vec::new();
    for i in 0..n {
        if [p0, p1, p2, p3].contains(&i) {
            continue;
        }
        let p = points[i];
        visible.clear();
        edges.clear();
        for (k, f) in faces.iter().enumerate() {
            if f.n.dot(p - f.a) > 1e-14 * f.n.length() {
                visible.push(k);
                for e in 0..3 {
                    edges.insert((f.v[e], f.v[(e + 1) % 3]));
                }
            }
        }
        if visible.is_empty() {
            return Err(MeshGenError::Hull(format!(
                "point {i} lies inside the hull (duplicate point?)"
            )));
        }
        let horizon: Vec<(u32, u32)> = visible
            .iter()
            .flat_map(|&k| (0..3).map(move |e| (k, e)))
            .map(|(k, e)| (faces[k].v[e], faces[k].v[(e + 1) % 3]))
            .filter(|&(a, b)| !edges.contains(&(b, a)))
            .collect();
        let mut vi = 0;
        let mut idx = 0;
        faces.retain(|_| {
            let keep = !(vi < visible.len() && visible[vi] == idx);
            if !keep {
                vi += 1;
            }
            idx += 1;
            keep
        });
        for (a, b) in horizon {
            faces.push(make([a, b, i as u32]));
        }
    }
    Ok(faces.into_iter().map(|f| f.v).collect())
}

fn cmp(a: f64, b: f64) -> std::cmp::Ordering {
    a.partial_cmp(&b).unwrap_or(std::cmp::Ordering::Equal)
}

/// Spreads points evenly over the shape by a short-ranged soft repulsion,
/// U = Σ (d/r)⁶ over pairs closer than r_c = 2.5 d, d the hexagonal spacing of N points on
/// the area, with the points held on the surface (the paper's "uniformly distributed" step).
pub fn spread_points(shape: &EvansFung, points: &mut [DVec3], iterations: usize) {
    let n = points.len();
    let (area, _) = shape.area_and_volume();
    let spacing = (2.0 * area / (3f64.sqrt() * n as f64)).sqrt();
    let rc = 2.5 * spacing;
    let mut force = vec![DVec3::ZERO; n];
    let mut grid: std::collections::HashMap<[i32; 3], Vec<u32>> = std::collections::HashMap::new();
    let key = |p: DVec3| {
        [
            (p.x / rc).floor() as i32,
            (p.y / rc).floor() as i32,
            (p.z / rc).floor() as i32,
        ]
    };
    for _ in 0..iterations {
        grid.values_mut().for_each(Vec::clear);
        for (i, p) in points.iter().enumerate() {
            grid.entry(key(*p)).or_default().push(i as u32);
        }
        force.iter_mut().for_each(|f| *f = DVec3::ZERO);
        for (i, p) in points.iter().enumerate() {
            let k = key(*p);
            let mut f = DVec3::ZERO;
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        let Some(cell) = grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) else {
                            continue;
                        };
                        for &j in cell {
                            if j as usize == i {
                                continue;
                            }
                            let d = *p - points[j as usize];
                            let r = d.length();
                            if r < rc && r > 0.0 {
                                // U = (spacing/r)^6, shifted to vanish at r_c
                                let q = spacing / r;
                                f += d * (6.0 * q.powi(6) / (r * r));
                            }
                        }
                    }
                }
            }
            force[i] = f;
        }
        for (p, f) in points.iter_mut().zip(&force) {
            let nrm = shape.normal(*p);
            let ft = *f - nrm * f.dot(nrm);
            // a step of at most 5 % of the spacing
            let step = ft * (0.01 * spacing * spacing);
            let len = step.length();
            let step = if len > 0.05 * spacing {
                step * (0.05 * spacing / len)
            } else {
                step
            };
            *p = shape.project(*p + step);
        }
    }
}

/// The unrelaxed mesh: spiral points on the cell spread evenly by repulsion, triangulated
/// through the sphere (convex hull of their pre-images).
pub fn initial_mesh(shape: &EvansFung, n: usize, seed: u64) -> Result<Mesh, MeshGenError> {
    if n < 4 {
        return Err(MeshGenError::TooFew(n));
    }
    let sphere = spiral_points_on_sphere(shape, n, seed);
    let mut verts: Vec<DVec3> = sphere.iter().map(|&u| shape.from_sphere(u)).collect();
    if n >= 20 {
        spread_points(shape, &mut verts, 300);
    }
    let sphere: Vec<DVec3> = verts.iter().map(|&p| shape.to_sphere(p)).collect();
    let tris = convex_hull(&sphere)?;
    let verts = sphere.iter().map(|&u| shape.from_sphere(u)).collect();
    let mut mesh = Mesh::new(verts, tris)?;
    // the sphere's Delaunay triangulation is not the cell's: make it Delaunay on the cell
    for _ in 0..100 {
        if flip_pass_with(&mut mesh, shape, FlipRule::Delaunay)? == 0 {
            break;
        }
    }
    Ok(mesh)
}

/// One pass of link flips: every link whose opposite vertices are closer than its own ends is
/// replaced by that shorter diagonal (unless it already exists, a vertex would leave valences
/// 5–7, or the new triangles would fold). Returns the number of flips.
pub fn flip_pass(mesh: &mut Mesh, shape: &EvansFung) -> Result<usize, MeshError> {
    flip_pass_with(mesh, shape, FlipRule::ShorterDiagonal)
}

/// Which links a flip pass flips.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlipRule {
    /// The paper's rule: the shorter diagonal, keeping valences within 5–7.
    ShorterDiagonal,
    /// Delaunay in 3D: flip when the two angles opposite the link add up to more than 180°
    /// (used once on the raw triangulation, keeping valences ≥ 4).
    Delaunay,
}

/// One pass of link flips under `rule`. Returns the number of flips.
pub fn flip_pass_with(mesh: &mut Mesh, shape: &EvansFung, rule: FlipRule) -> Result<usize, MeshError> {
    let topo = mesh.topology()?;
    let mut link_set: HashSet<(u32, u32)> = topo.links.iter().map(|l| (l[0], l[1])).collect();
    let mut valence = topo.valences();
    let mut touched = vec![false; mesh.triangles.len()];
    let x = &mesh.vertices;
    let mut flips = 0;
    for (dih, lt) in topo.dihedrals.iter().zip(&topo.link_triangles) {
        let [a, b, c, d] = *dih;
        let (t1, t2) = (lt[0] as usize, lt[1] as usize);
        if touched[t1] || touched[t2] {
            continue;
        }
        let (xa, xb, xc, xd) = (x[a as usize], x[b as usize], x[c as usize], x[d as usize]);
        let key = (a.min(d), a.max(d));
        let (va, vb, vc, vd) = (
            valence[a as usize],
            valence[b as usize],
            valence[c as usize],
            valence[d as usize],
        );
        let wanted = match rule {
            FlipRule::ShorterDiagonal => {
                xa.distance_squared(xd) < xb.distance_squared(xc) * (1.0 - 1e-10)
                    && vb > 5
                    && vc > 5
                    && va < 7
                    && vd < 7
            }
            FlipRule::Delaunay => {
                (xb - xa).angle_between(xc - xa) + (xb - xd).angle_between(xc - xd) > std::f64::consts::PI + 1e-9
                    && vb > 4
                    && vc > 4
            }
        };
        if !wanted || link_set.contains(&key) {
            continue;
        }
        // new triangles (a, b, d) and (a, d, c) must face outward
        let n1 = (xb - xa).cross(xd - xa);
        let n2 = (xd - xa).cross(xc - xa);
        let mid = shape.normal((xa + xd) * 0.5);
        if n1.dot(mid) <= 0.0 || n2.dot(mid) <= 0.0 {
            continue;
        }
        mesh.triangles[t1] = [a, b, d];
        mesh.triangles[t2] = [a, d, c];
        touched[t1] = true;
        touched[t2] = true;
        link_set.remove(&(b.min(c), b.max(c)));
        link_set.insert(key);
        valence[b as usize] -= 1;
        valence[c as usize] -= 1;
        valence[a as usize] += 1;
        valence[d as usize] += 1;
        flips += 1;
    }
    Ok(flips)
}

/// Relaxes `mesh` on `shape` by the in-plane energy of `constants` (bending, area and volume
/// terms are not used: the points are held on the shape), with flip passes, until the largest
/// tangential force is below `opts.force_tolerance` × mean link tension and a flip pass flips nothing.
pub fn relax(
    mesh: &mut Mesh,
    shape: &EvansFung,
    constants: &MembraneConstants,
    opts: &MeshGenOptions,
) -> Result<RelaxReport, MeshGenError> {
    let in_plane = MembraneConstants {
        k_bend: 0.0,
        k_area: 0.0,
        k_volume: 0.0,
        ..*constants
    };
    let n = mesh.vertices.len();
    let mut topo = mesh.topology()?;
    let (a0, v0) = (mesh.area(), mesh.volume());
    let mut model = MembraneModel::uniform(&topo, &in_plane, a0, v0)?;
    let mut f = vec![DVec3::ZERO; n];
    let mut v = vec![DVec3::ZERO; n];
    // FIRE parameters (Bitzek et al. 2006), time in units where the mass is 1.
    let force_scale = link_tension_scale(constants);
    let dt_max = (0.05 * constants.l0 / force_scale).sqrt();
    let (n_min, f_inc, f_dec, alpha0, f_alpha) = (5, 1.1, 0.5, 0.1, 0.99);
    let mut dt = 0.1 * dt_max;
    let mut alpha = alpha0;
    let mut n_pos = 0usize;
    let mut flips_total = 0;
    let mut residual = f64::INFINITY;
    let mut steps = 0;
    let mut converged = false;
    let tangential = |x: &[DVec3], f: &mut [DVec3]| {
        for (fi, xi) in f.iter_mut().zip(x) {
            let nrm = shape.normal(*xi);
            *fi -= nrm * fi.dot(nrm);
        }
    };
    while steps < opts.max_steps {
        f.iter_mut().for_each(|fi| *fi = DVec3::ZERO);
        model.add_forces(&mesh.vertices, &mut f)?;
        tangential(&mesh.vertices, &mut f);
        residual = f.iter().map(|fi| fi.length()).fold(0.0, f64::max) / force_scale;
        if residual < opts.force_tolerance || (steps > 0 && steps % opts.flip_interval == 0) {
            let flipped = flip_pass(mesh, shape)?;
            flips_total += flipped;
            if flipped > 0 {
                topo = mesh.topology()?;
                model = MembraneModel::uniform(&topo, &in_plane, a0, v0)?;
                v.iter_mut().for_each(|vi| *vi = DVec3::ZERO);
                alpha = alpha0;
                n_pos = 0;
                steps += 1;
                continue;
            } else if residual < opts.force_tolerance {
                converged = true;
                break;
            }
        }
        // FIRE velocity mixing
        let p: f64 = f.iter().zip(&v).map(|(a, b)| a.dot(*b)).sum();
        if p > 0.0 {
            let vn = v.iter().map(|x| x.length_squared()).sum::<f64>().sqrt();
            let fnorm = f.iter().map(|x| x.length_squared()).sum::<f64>().sqrt().max(1e-300);
            for (vi, fi) in v.iter_mut().zip(&f) {
                *vi = *vi * (1.0 - alpha) + *fi * (alpha * vn / fnorm);
            }
            n_pos += 1;
            if n_pos > n_min {
                dt = (dt * f_inc).min(dt_max);
                alpha *= f_alpha;
            }
        } else {
            n_pos = 0;
            dt *= f_dec;
            alpha = alpha0;
            v.iter_mut().for_each(|vi| *vi = DVec3::ZERO);
        }
        for ((xi, vi), fi) in mesh.vertices.iter_mut().zip(v.iter_mut()).zip(&f) {
            *vi += *fi * dt;
            // never let one step move a vertex more than a tenth of a link
            let step = *vi * dt;
            let max_step = 0.1 * constants.l0;
            let step = if step.length() > max_step {
                step * (max_step / step.length())
            } else {
                step
            };
            let moved = shape.project(*xi + step);
            let nrm = shape.normal(moved);
            *vi -= nrm * vi.dot(nrm);
            *xi = moved;
        }
        steps += 1;
    }
    Ok(RelaxReport {
        steps,
        flips: flips_total,
        residual,
        converged,
    })
}

/// Typical link tension of the model: the WLC force at L0, kBT/p · (1/(4(1−x0)²) − 1/4 + x0).
fn link_tension_scale(c: &MembraneConstants) -> f64 {
    let x0 = 1.0 / c.lmax_over_l0;
    c.kbt / c.persistence_length * (0.25 / (1.0 - x0).powi(2) - 0.25 + x0)
}

/// Generates the relaxed mesh: spiral points, hull, relaxation with flips.
pub fn generate(
    shape: &EvansFung,
    constants: &MembraneConstants,
    opts: &MeshGenOptions,
) -> Result<(Mesh, RelaxReport), MeshGenError> {
    let mut mesh = initial_mesh(shape, opts.n, opts.seed)?;
    let report = relax(&mut mesh, shape, constants, opts)?;
    Ok((mesh, report))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hull_of_spiral_points_is_a_closed_sphere() {
        let shape = EvansFung::healthy_um();
        for n in [4usize, 5, 12, 100, 500, 2000] {
            let m = initial_mesh(&shape, n, 7).unwrap();
            let topo = m.topology().unwrap();
            assert_eq!(topo.links.len(), 3 * n - 6);
            assert_eq!(m.triangles.len(), 2 * n - 4);
            assert!(m.volume() > 0.0);
        }
    }

    #[test]
    fn spiral_is_deterministic_for_a_seed() {
        let shape = EvansFung::healthy_um();
        let a = spiral_points_on_sphere(&shape, 300, 1);
        let b = spiral_points_on_sphere(&shape, 300, 1);
        let c = spiral_points_on_sphere(&shape, 300, 2);
        assert_eq!(a, b);
        assert_ne!(a, c);
    }

    /// The relaxed N = 500 mesh: converged, no flips pending, good triangles. Flat triangles cut
    /// the curved surface, so area and volume fall 1–2 % short of the smooth shape's 134.1 µm² and
    /// 94.09 µm³; an independently relaxed N = 500 mesh (shared/reference/membrane_golden: A0 =
    /// 132.777 µm², V0 = 92.437 µm³) falls short by the same amount, so we require agreement with
    /// it to 0.2 % (a few times the seed-to-seed spread).
    #[test]
    fn relaxed_mesh_quality() {
        let shape = EvansFung::healthy_um();
        let p = crate::params::ModelParams::coarse_grained(500, 300.0).unwrap();
        let c = MembraneConstants::from_params_um_pn(&p);
        let (mut mesh, report) = generate(&shape, &c, &MeshGenOptions::new(500, 1)).unwrap();
        assert!(report.converged, "{report:?}");
        assert_eq!(flip_pass(&mut mesh, &shape).unwrap(), 0);
        let q = mesh.quality().unwrap();
        assert!(q.link_rel_sd < 0.08, "{q:?}");
        assert!(q.min_angle_deg > 35.0 && q.max_angle_deg < 100.0, "{q:?}");
        assert!(q.valence_histogram.iter().all(|(v, _)| (4..=8).contains(v)), "{q:?}");
        assert!(
            (q.area / 132.777 - 1.0).abs() < 2e-3 && (q.volume / 92.437 - 1.0).abs() < 2e-3,
            "{q:?}"
        );
        // every vertex is on the shape
        for v in &mesh.vertices {
            assert!((shape.project(*v) - *v).length() < 1e-9);
        }
    }
}
