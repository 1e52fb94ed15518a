//! Bringing a resting cell into a tube narrower than it is.
//!
//! Before any fluid exists, the membrane alone is pressed into the tube: a confining wall of
//! radius R around the axis (the line through `centre` along z) adds ½ k (ρ − R)² to the energy
//! of every vertex outside it (ρ: the vertex's distance from the axis). R shrinks from the
//! cell's widest vertex to the target in stages, and at each stage the shape is relaxed to
//! static equilibrium by L-BFGS on the membrane's full energy, global area and volume terms
//! included, so the cell keeps its area and volume while it folds into the tube. The result is
//! a shape the cell can take in the tube at rest; placed in an equilibrated fluid, the fluid
//! inside it becomes cytosol at the fluid's own density and no particle starts on the wrong
//! side of the membrane.
//!
//! The final stage is repeated with the wall moved inwards by the overshoot until every vertex
//! lies within the target radius (a penalty wall lets vertices in by ≈ force/k).
//!
//! A cell pressed into a tube much narrower than it folds, and energy minimisation alone lets
//! two sheets of the membrane pass through each other (the 4.5 and 4.7 µm tubes did, with
//! 70–130 pairs of crossing triangles at N = 2000; the fluid cut by such a shape has regions
//! inside the cell twice or not at all, and fluid seemed to leak through the membrane there).
//! So the energy has a third term, [`SelfContact`]: vertices more than two links apart repel
//! within a link's length, [`CONTACT_STIFFNESS`] times as stiffly as the wall. The result is checked with [`crate::mesh::self_intersections`] and
//! refused if the membrane still passes through itself.

use crate::forces::{ForceError, MembraneModel};
use crate::lbfgs::Lbfgs;
use crate::mesh::{area_of, self_intersections, volume_of};
use crate::precondition::Preconditioner;
use glam::DVec3;

/// Options of [`confine`] (lengths, energies and forces in the model's units).
#[derive(Clone, Debug)]
pub struct ConfineOptions {
    /// A point (x, y) of the tube's axis; the axis runs along z.
    pub centre: [f64; 2],
    /// Target radius: at the end every vertex is within it of the axis.
    pub radius: f64,
    /// Largest shrink of the confining radius per stage.
    pub radius_step: f64,
    /// Stiffness k of the confining wall, energy per length².
    pub stiffness: f64,
    /// A stage is relaxed when the largest net force on a vertex is below this.
    pub tolerance: f64,
    /// Iteration cap per stage. A stage that reaches it hands its shape on: the shape is a
    /// start for a run, not a result, and the residual left is reported.
    pub max_iterations: usize,
}

/// The confined shape and how it was reached.
#[derive(Clone, Debug)]
pub struct Confinement {
    /// Vertex positions in the tube.
    pub positions: Vec<DVec3>,
    /// Largest distance of a vertex from the axis at the start and at the end.
    pub widest_start: f64,
    pub widest: f64,
    /// Extent of the cell along the axis at the end.
    pub axial_length: f64,
    /// Stages (radii) relaxed, and L-BFGS iterations over all of them.
    pub stages: usize,
    pub iterations: usize,
    /// Largest net force on a vertex at the end (0 when the cell fitted from the start).
    pub residual: f64,
    /// (A − A0)/A0 and (V − V0)/V0 at the end.
    pub area_deviation: f64,
    pub volume_deviation: f64,
    /// Closest approach of two vertices more than two links apart, over the contact range
    /// ([`SelfContact`]; ≥ 1 when no pair is in contact).
    pub closest_contact: f64,
}

/// Errors of [`confine`].
#[derive(Debug, thiserror::Error)]
pub enum ConfineError {
    #[error("confinement: {what} = {value} must be positive and finite")]
    BadOption { what: &'static str, value: f64 },
    #[error("confinement could not bring every vertex within radius {radius:.4} (widest {widest:.4} after the last correction)")]
    Outside { radius: f64, widest: f64 },
    #[error("confinement at radius {radius:.4}: {source}")]
    Force { radius: f64, source: ForceError },
    #[error("confinement into radius {radius:.4}: the folded membrane passes through itself ({pairs} pairs of triangles cross)")]
    SelfIntersecting { radius: f64, pairs: usize },
}

/// Stiffness of the self-contact over the confining wall's. The N = 2000 cell pressed face-on
/// into the 4.5 µm tube still passed through itself at 10 (80 pairs of triangles crossing; the
/// contact lets pairs in by ≈ force/k, and the folded cell's stretched triangles are crossed
/// with their vertices at 0.75–0.9 of the range) and did not at 30; 100 leaves a margin.
pub const CONTACT_STIFFNESS: f64 = 100.0;

/// Contact between distant parts of one membrane: vertices more than two links apart on the
/// mesh repel with the energy ½ k (range − r)² when closer than `range`. With `range` the mean
/// rest link length a sheet cannot pass through another unnoticed: an edge crossing a triangle
/// brings one of its vertices within the triangle's circumradius (≈ 0.58 of a link) of the
/// triangle's vertices, and two crossing edges bring their ends within ≈ 0.71 of a link. Pairs
/// within two links are excluded: their distance is set by the in-plane elasticity (≈ 1.7
/// links for a second neighbour at rest), and the second ring of a flat mesh would otherwise
/// repel at rest.
#[derive(Clone, Debug)]
pub struct SelfContact {
    range: f64,
    /// For each vertex, the vertices within two links of it (itself included), sorted.
    near: Vec<Vec<u32>>,
}

impl SelfContact {
    /// The contact of a mesh of `n` vertices with the given links, repelling within `range`.
    pub fn new(n: usize, links: &[[u32; 2]], range: f64) -> Self {
        let mut first = vec![Vec::new(); n];
        for l in links {
            first[l[0] as usize].push(l[1]);
            first[l[1] as usize].push(l[0]);
        }
        let near = (0..n)
            .map(|i| {
                let mut v = vec![i as u32];
                for &j in &first[i] {
                    v.push(j);
                    v.extend_from_slice(&first[j as usize]);
                }
                v.sort_unstable();
                v.dedup();
                v
            })
            .collect();
        Self { range, near }
    }

    /// The contact of `model`'s mesh within its mean rest link length.
    pub fn of(model: &MembraneModel) -> Self {
        let l0 = model.link_rest_lengths();
        let mean = l0.iter().sum::<f64>() / l0.len().max(1) as f64;
        Self::new(model.n_vertices(), model.links(), mean)
    }

    /// Contact range (length).
    pub fn range(&self) -> f64 {
        self.range
    }

    /// Calls `pair(i, j, d)` with d = x_j − x_i for each pair i < j of vertices more than two
    /// links apart and closer than the range (a cell list of cells of the range).
    fn for_each_pair(&self, x: &[DVec3], mut pair: impl FnMut(usize, usize, DVec3)) {
        let h = self.range;
        let lo = x.iter().fold(DVec3::splat(f64::MAX), |a, p| a.min(*p));
        let hi = x.iter().fold(DVec3::splat(f64::MIN), |a, p| a.max(*p));
        let n = ((hi - lo) / h).floor().as_ivec3() + 1;
        let cell = |p: DVec3| (((p - lo) / h).floor().as_ivec3()).min(n - 1);
        let index = |c: glam::IVec3| ((c.z * n.y + c.y) * n.x + c.x) as usize;
        let mut start = vec![0u32; (n.x * n.y * n.z) as usize + 1];
        for p in x {
            start[index(cell(*p)) + 1] += 1;
        }
        for c in 1..start.len() {
            start[c] += start[c - 1];
        }
        let mut fill = start.clone();
        let mut items = vec![0u32; x.len()];
        for (i, p) in x.iter().enumerate() {
            let c = index(cell(*p));
            items[fill[c] as usize] = i as u32;
            fill[c] += 1;
        }
        for (i, p) in x.iter().enumerate() {
            let c = cell(*p);
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let m = c + glam::IVec3::new(dx, dy, dz);
                        if m.cmplt(glam::IVec3::ZERO).any() || m.cmpge(n).any() {
                            continue;
                        }
                        let k = index(m);
                        for &j in &items[start[k] as usize..start[k + 1] as usize] {
                            let j = j as usize;
                            if j <= i {
                                continue;
                            }
                            let d = x[j] - *p;
                            if d.length_squared() < h * h && self.near[i].binary_search(&(j as u32)).is_err() {
                                pair(i, j, d);
                            }
                        }
                    }
                }
            }
        }
    }

    /// The contact energy at `x` with stiffness `k` (energy per length²); its forces (the
    /// negative gradient) are added to `f`.
    pub fn add_forces(&self, x: &[DVec3], k: f64, f: &mut [DVec3]) -> f64 {
        let mut energy = 0.0;
        self.for_each_pair(x, |i, j, d| {
            let r = d.length();
            let overlap = self.range - r;
            energy += 0.5 * k * overlap * overlap;
            if r > 0.0 {
                let push = d * (k * overlap / r);
                f[j] += push;
                f[i] -= push;
            }
        });
        energy
    }

    /// The closest approach of a pair in contact over the range (1 when none is in contact).
    pub fn closest(&self, x: &[DVec3]) -> f64 {
        let mut closest = self.range;
        self.for_each_pair(x, |_, _, d| closest = closest.min(d.length()));
        closest / self.range
    }
}

/// Distance of `x` from the axis through `c` along z, and the unit vector away from it.
fn radial(x: DVec3, c: [f64; 2]) -> (f64, DVec3) {
    let d = DVec3::new(x.x - c[0], x.y - c[1], 0.0);
    let r = d.length();
    (r, if r > 0.0 { d / r } else { DVec3::ZERO })
}

/// The largest distance of a vertex from the axis.
pub fn widest(x: &[DVec3], centre: [f64; 2]) -> f64 {
    x.iter().map(|p| radial(*p, centre).0).fold(0.0, f64::max)
}

/// Presses the cell `start` (a valid shape of `model`) into the tube of `opts` (see the module
/// docs). A cell that already fits is returned as it is (zero stages).
pub fn confine(model: &MembraneModel, start: &[DVec3], opts: &ConfineOptions) -> Result<Confinement, ConfineError> {
    for (what, value) in [
        ("radius", opts.radius),
        ("radius_step", opts.radius_step),
        ("stiffness", opts.stiffness),
        ("tolerance", opts.tolerance),
    ] {
        if !(value > 0.0 && value.is_finite()) {
            return Err(ConfineError::BadOption { what, value });
        }
    }
    let c = opts.centre;
    let widest_start = widest(start, c);
    let mut x = start.to_vec();
    let mut solver = Lbfgs::new(x.len(), 10, 1e-3 * opts.radius);
    solver.precondition = Preconditioner::new(model).ok();
    let mut ws = model.workspace();
    let contact = SelfContact::of(model);
    let (mut stages, mut iterations, mut residual) = (0, 0, 0.0);
    let mut relax = |x: &mut Vec<DVec3>, wall: f64, solver: &mut Lbfgs| -> Result<f64, ConfineError> {
        let k = opts.stiffness;
        let objective = |x: &[DVec3], g: &mut [DVec3]| -> Result<f64, ForceError> {
            g.iter_mut().for_each(|gi| *gi = DVec3::ZERO);
            let e = model.add_forces_parallel(x, g, &mut ws)?;
            let mut penalty = contact.add_forces(x, CONTACT_STIFFNESS * k, g);
            for (xi, gi) in x.iter().zip(g.iter_mut()) {
                let (r, out) = radial(*xi, c);
                if r > wall {
                    let d = r - wall;
                    penalty += 0.5 * k * d * d;
                    *gi -= out * (k * d);
                }
            }
            // gradient = −(membrane force + wall force)
            g.iter_mut().for_each(|gi| *gi = -*gi);
            Ok(e.total() + penalty)
        };
        if let Some(p) = solver.precondition.as_mut() {
            // P from the start shape of the stage; without it the stage runs unpreconditioned
            let _ = p.update(model, x);
        }
        let never = || false;
        let (its, residual) = solver
            .minimize(x, objective, opts.tolerance, opts.max_iterations, &never)
            .map_err(|source| ConfineError::Force { radius: wall, source })?
            .unwrap_or((0, f64::INFINITY));
        iterations += its;
        stages += 1;
        Ok(residual)
    };
    if widest_start > opts.radius {
        let n = ((widest_start - opts.radius) / opts.radius_step).ceil().max(1.0) as usize;
        for s in 1..=n {
            let wall = widest_start + (opts.radius - widest_start) * s as f64 / n as f64;
            residual = relax(&mut x, wall, &mut solver)?;
        }
        // the penalty lets vertices in by ≈ force/k: move the wall in by the overshoot, and by
        // a hair more (1e-4 of the radius), or an overshoot that shrinks by a fraction per
        // correction can still be 1e-5 out after the last one (a 7.6 µm tube failed so)
        let mut wall = opts.radius;
        for _ in 0..8 {
            let over = widest(&x, c) - opts.radius;
            if over <= 0.0 {
                break;
            }
            wall -= over + 1e-4 * opts.radius;
            residual = relax(&mut x, wall, &mut solver)?;
        }
        let w = widest(&x, c);
        if w > opts.radius {
            return Err(ConfineError::Outside {
                radius: opts.radius,
                widest: w,
            });
        }
    }
    let (lo, hi) = x
        .iter()
        .fold((f64::MAX, f64::MIN), |(lo, hi), p| (lo.min(p.z), hi.max(p.z)));
    let (a, v) = (area_of(&x, model.triangles()), volume_of(&x, model.triangles()));
    let pairs = self_intersections(&x, model.triangles());
    if pairs > 0 {
        return Err(ConfineError::SelfIntersecting {
            radius: opts.radius,
            pairs,
        });
    }
    Ok(Confinement {
        closest_contact: contact.closest(&x),
        widest: widest(&x, c),
        widest_start,
        axial_length: hi - lo,
        stages,
        iterations,
        residual,
        area_deviation: a / model.area0() - 1.0,
        volume_deviation: v / model.volume0() - 1.0,
        positions: x,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::forces::{MembraneConstants, ReferenceState};
    use crate::meshgen::{generate, MeshGenOptions};
    use crate::params::ModelParams;
    use crate::shape::EvansFung;

    /// The N = 500 cell (µm, pN), stress-free, centred at the origin, symmetry axis y.
    fn cell() -> (MembraneModel, Vec<DVec3>) {
        let p = ModelParams::coarse_grained(500, 300.0).unwrap();
        let c = MembraneConstants::from_params_um_pn(&p);
        let (mesh, _) = generate(&EvansFung::healthy_um(), &c, &MeshGenOptions::new(500, 1)).unwrap();
        let model = MembraneModel::new(
            &mesh.topology().unwrap(),
            &mesh.vertices,
            &c,
            ReferenceState::StressFree,
        )
        .unwrap();
        (model, mesh.vertices)
    }

    fn options(radius: f64) -> ConfineOptions {
        ConfineOptions {
            centre: [0.0, 0.0],
            radius,
            radius_step: 0.2,
            stiffness: 50.0,
            tolerance: 1e-2,
            max_iterations: 500,
        }
    }

    /// Edge-on (the tube's axis z lies in the cell's plane) and face-on (the axis is the cell's
    /// symmetry axis) into a 4.7 µm tube with 0.35 µm to spare: every vertex within 2.0 µm of
    /// the axis, area and volume within 1 % (the global constraints hold them), and the cell
    /// longer than it is wide, as in the narrow tubes of Hochmuth 1970.
    #[test]
    fn a_cell_folds_into_a_narrow_tube() {
        let (model, rest) = cell();
        let face_on: Vec<DVec3> = rest.iter().map(|v| DVec3::new(v.x, -v.z, v.y)).collect();
        for (name, start) in [("edge-on", rest.clone()), ("face-on", face_on)] {
            let c = confine(&model, &start, &options(2.0)).unwrap();
            assert!(c.widest_start > 3.8, "{name}: {}", c.widest_start);
            assert!(c.widest <= 2.0, "{name}: widest {}", c.widest);
            assert!(c.area_deviation.abs() < 0.01, "{name}: {c:?}");
            assert!(c.volume_deviation.abs() < 0.01, "{name}: {c:?}");
            assert!(c.axial_length > 4.0, "{name}: {}", c.axial_length);
            // no link near its WLC limit: the shape is a sound start for a run
            let longest = model
                .links()
                .iter()
                .zip(model.link_lmax())
                .map(|(l, lmax)| (c.positions[l[0] as usize] - c.positions[l[1] as usize]).length() / lmax)
                .fold(0.0, f64::max);
            assert!(longest < 0.9, "{name}: a link at {longest} of Lmax");
            // `confine` refuses a shape that passes through itself; and no two sheets closer
            // than a third of a link
            assert_eq!(self_intersections(&c.positions, model.triangles()), 0, "{name}");
            assert!(c.closest_contact > 0.3, "{name}: closest contact {}", c.closest_contact);
            eprintln!(
                "{name}: stages {} iterations {} residual {:.2e} widest {:.3} length {:.3} dA {:.2e} dV {:.2e} closest contact {:.3}",
                c.stages, c.iterations, c.residual, c.widest, c.axial_length, c.area_deviation, c.volume_deviation, c.closest_contact
            );
        }
    }

    /// The contact forces are the negative gradient of the contact energy (central
    /// differences, on the N = 500 cell flattened until its two faces touch), pairs within two
    /// links never interact, and the resting cell has no pair in contact.
    #[test]
    fn self_contact_forces_are_the_energy_gradient() {
        let (model, rest) = cell();
        let contact = SelfContact::of(&model);
        let mut f = vec![DVec3::ZERO; rest.len()];
        assert_eq!(contact.add_forces(&rest, 1.0, &mut f), 0.0);
        assert_eq!(contact.closest(&rest), 1.0);
        // symmetry axis y: squash to 5 % of the thickness, faces ≈ 0.05–0.13 µm apart
        let flat: Vec<DVec3> = rest.iter().map(|v| DVec3::new(v.x, 0.05 * v.y, v.z)).collect();
        let k = 3.0;
        let e0 = contact.add_forces(&flat, k, &mut f);
        assert!(e0 > 0.0 && contact.closest(&flat) < 0.5, "{e0}");
        let energy = |x: &[DVec3]| contact.add_forces(x, k, &mut vec![DVec3::ZERO; x.len()]);
        let h = 1e-6;
        let mut worst: f64 = 0.0;
        let mut checked = 0;
        for i in (0..flat.len()).step_by(7) {
            if f[i].length() == 0.0 {
                continue;
            }
            for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
                let (mut p, mut m) = (flat.clone(), flat.clone());
                p[i] += axis * h;
                m[i] -= axis * h;
                let numeric = -(energy(&p) - energy(&m)) / (2.0 * h);
                worst = worst.max((numeric - f[i].dot(axis)).abs() / f[i].length());
            }
            checked += 1;
        }
        assert!(checked > 20, "{checked} vertices in contact checked");
        assert!(worst < 1e-6, "relative gradient error {worst:e}");
        // the excluded pairs: a link and a second neighbour brought to the same point feel nothing
        let (a, b) = (model.links()[0][0] as usize, model.links()[0][1] as usize);
        let mut touching = rest.clone();
        touching[b] = touching[a];
        let mut g = vec![DVec3::ZERO; rest.len()];
        assert_eq!(contact.add_forces(&touching, 1.0, &mut g), 0.0);
    }

    /// A cell that fits is left as it is; bad options are refused.
    #[test]
    fn a_cell_that_fits_is_untouched_and_bad_options_fail() {
        let (model, rest) = cell();
        let c = confine(&model, &rest, &options(5.0)).unwrap();
        assert_eq!((c.stages, c.iterations), (0, 0));
        assert_eq!(c.positions, rest);
        let mut bad = options(2.0);
        bad.stiffness = 0.0;
        assert!(matches!(
            confine(&model, &rest, &bad),
            Err(ConfineError::BadOption { what: "stiffness", .. })
        ));
    }
}
