//! Closed triangulated surfaces: vertices, outward-oriented triangles, and the derived topology
//! (links and dihedral pairs) that the forces loop over.

use glam::DVec3;
use std::collections::HashMap;

/// Errors about a mesh: its topology, or a file that should hold one.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    #[error("mesh has {0} vertices; a closed surface needs at least 4")]
    TooFewVertices(usize),
    #[error("triangle {tri} refers to vertex {vertex}, but the mesh has only {n} vertices")]
    BadIndex { tri: usize, vertex: u32, n: usize },
    #[error("triangle {0} is degenerate (repeats a vertex)")]
    Degenerate(usize),
    #[error("link {a}-{b} is shared by {count} triangles; a closed manifold surface needs exactly 2")]
    NonManifold { a: u32, b: u32, count: usize },
    #[error("link {a}-{b} is traversed in the same direction by both its triangles: orientations are inconsistent")]
    Orientation { a: u32, b: u32 },
    #[error("the surface is not a sphere: V - E + F = {0}, expected 2")]
    Genus(i64),
    #[error("vertex {0} belongs to no triangle")]
    Isolated(usize),
    #[error("{path}: {msg}")]
    File { path: String, msg: String },
}

/// A closed triangulated surface. Triangles are counter-clockwise seen from outside, so
/// `(b − a) × (c − a)` points outward and the signed volume is positive.
#[derive(Clone, Debug, PartialEq)]
pub struct Mesh {
    pub vertices: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
}

/// Links and dihedral pairs of a closed mesh, derived once from its triangles.
#[derive(Clone, Debug)]
pub struct Topology {
    /// Number of vertices.
    pub n_vertices: usize,
    /// Triangles, outward-oriented (copied from the mesh).
    pub triangles: Vec<[u32; 3]>,
    /// Each undirected link once, as `[a, b]` with `a < b`.
    pub links: Vec<[u32; 2]>,
    /// One entry per link: `[a, b, c, d]` where the two triangles sharing link `b–c` are
    /// `(a, b, c)` and `(d, c, b)`, both outward-oriented. Same order as `links`.
    pub dihedrals: Vec<[u32; 4]>,
    /// For each link, the indices of its two triangles `(a,b,c)` and `(d,c,b)`.
    pub link_triangles: Vec<[u32; 2]>,
}

impl Topology {
    /// Builds and checks the topology: every link shared by exactly two triangles with opposite
    /// orientations, every vertex used, Euler characteristic 2.
    pub fn new(n_vertices: usize, triangles: &[[u32; 3]]) -> Result<Self, MeshError> {
        if n_vertices < 4 {
            return Err(MeshError::TooFewVertices(n_vertices));
        }
        // directed edge (from, to) -> (triangle, opposite vertex)
        let mut directed: HashMap<(u32, u32), (u32, u32)> = HashMap::with_capacity(triangles.len() * 3);
        let mut used = vec![false; n_vertices];
        for (t, tri) in triangles.iter().enumerate() {
            for &v in tri {
                if v as usize >= n_vertices {
                    return Err(MeshError::BadIndex {
                        tri: t,
                        vertex: v,
                        n: n_vertices,
                    });
                }
                used[v as usize] = true;
            }
            if tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2] {
                return Err(MeshError::Degenerate(t));
            }
            for k in 0..3 {
                let (from, to, opp) = (tri[k], tri[(k + 1) % 3], tri[(k + 2) % 3]);
                if directed.insert((from, to), (t as u32, opp)).is_some() {
                    return Err(MeshError::Orientation { a: from, b: to });
                }
            }
        }
        if let Some(v) = used.iter().position(|u| !u) {
            return Err(MeshError::Isolated(v));
        }
        let mut links = Vec::with_capacity(directed.len() / 2);
        let mut dihedrals = Vec::with_capacity(directed.len() / 2);
        let mut link_triangles = Vec::with_capacity(directed.len() / 2);
        // Deterministic order: walk triangles, emit each link when seen as (lo -> hi).
        for tri in triangles {
            for k in 0..3 {
                let (b, c) = (tri[k], tri[(k + 1) % 3]);
                if b > c {
                    continue;
                }
                let (t1, a) = directed[&(b, c)];
                let Some(&(t2, d)) = directed.get(&(c, b)) else {
                    return Err(MeshError::NonManifold { a: b, b: c, count: 1 });
                };
                links.push([b, c]);
                dihedrals.push([a, b, c, d]);
                link_triangles.push([t1, t2]);
            }
        }
        // every directed edge must have its reverse
        for &(from, to) in directed.keys() {
            if !directed.contains_key(&(to, from)) {
                return Err(MeshError::NonManifold {
                    a: from.min(to),
                    b: from.max(to),
                    count: 1,
                });
            }
        }
        let euler = n_vertices as i64 - links.len() as i64 + triangles.len() as i64;
        if euler != 2 {
            return Err(MeshError::Genus(euler));
        }
        Ok(Self {
            n_vertices,
            triangles: triangles.to_vec(),
            links,
            dihedrals,
            link_triangles,
        })
    }

    /// Vertex valences (number of links at each vertex).
    pub fn valences(&self) -> Vec<u32> {
        let mut v = vec![0u32; self.n_vertices];
        for l in &self.links {
            v[l[0] as usize] += 1;
            v[l[1] as usize] += 1;
        }
        v
    }
}

/// Area of the triangle (a, b, c).
#[inline]
pub fn triangle_area(a: DVec3, b: DVec3, c: DVec3) -> f64 {
    0.5 * (b - a).cross(c - a).length()
}

impl Mesh {
    /// A mesh from vertices and triangles, with its topology checked.
    pub fn new(vertices: Vec<DVec3>, triangles: Vec<[u32; 3]>) -> Result<Self, MeshError> {
        Topology::new(vertices.len(), &triangles)?;
        Ok(Self { vertices, triangles })
    }

    /// Builds the topology (links, dihedrals). Checks the surface is a closed oriented sphere.
    pub fn topology(&self) -> Result<Topology, MeshError> {
        Topology::new(self.vertices.len(), &self.triangles)
    }

    /// Total area of the flat triangles.
    pub fn area(&self) -> f64 {
        area_of(&self.vertices, &self.triangles)
    }

    /// Enclosed volume (positive for outward orientation).
    pub fn volume(&self) -> f64 {
        volume_of(&self.vertices, &self.triangles)
    }

    /// Quality figures: link-length spread, triangle angles, valence histogram.
    pub fn quality(&self) -> Result<MeshQuality, MeshError> {
        let topo = self.topology()?;
        let lengths: Vec<f64> = topo
            .links
            .iter()
            .map(|l| (self.vertices[l[0] as usize] - self.vertices[l[1] as usize]).length())
            .collect();
        let n = lengths.len() as f64;
        let mean = lengths.iter().sum::<f64>() / n;
        let sd = (lengths.iter().map(|l| (l - mean).powi(2)).sum::<f64>() / n).sqrt();
        let (mut min_angle, mut max_angle) = (f64::MAX, 0.0f64);
        for t in &self.triangles {
            let p = t.map(|i| self.vertices[i as usize]);
            for k in 0..3 {
                let u = p[(k + 1) % 3] - p[k];
                let v = p[(k + 2) % 3] - p[k];
                let ang = u.angle_between(v).to_degrees();
                min_angle = min_angle.min(ang);
                max_angle = max_angle.max(ang);
            }
        }
        let mut hist = std::collections::BTreeMap::new();
        for v in topo.valences() {
            *hist.entry(v).or_insert(0usize) += 1;
        }
        Ok(MeshQuality {
            n_vertices: self.vertices.len(),
            n_links: topo.links.len(),
            n_triangles: self.triangles.len(),
            link_mean: mean,
            link_min: lengths.iter().cloned().fold(f64::MAX, f64::min),
            link_max: lengths.iter().cloned().fold(0.0, f64::max),
            link_rel_sd: sd / mean,
            min_angle_deg: min_angle,
            max_angle_deg: max_angle,
            valence_histogram: hist.into_iter().collect(),
            area: self.area(),
            volume: self.volume(),
        })
    }
}

/// Total area of flat triangles.
pub fn area_of(x: &[DVec3], triangles: &[[u32; 3]]) -> f64 {
    triangles
        .iter()
        .map(|t| triangle_area(x[t[0] as usize], x[t[1] as usize], x[t[2] as usize]))
        .sum()
}

/// Enclosed volume, Σ a·(b×c)/6 over outward triangles.
pub fn volume_of(x: &[DVec3], triangles: &[[u32; 3]]) -> f64 {
    triangles
        .iter()
        .map(|t| x[t[0] as usize].dot(x[t[1] as usize].cross(x[t[2] as usize])))
        .sum::<f64>()
        / 6.0
}

/// Generalised winding number of the closed, outward-oriented triangulated surface
/// (`x`, `triangles`) about the point `p`: the total solid angle the triangles subtend at `p`
/// over 4π (Van Oosterom & Strackee's formula per triangle). It is 1 inside, 0 outside, and
/// varies smoothly only within about a triangle's size of the surface, so `> 0.5` is a robust
/// inside test with no ray to pass exactly through an edge or a vertex. Cost: one pass over
/// the triangles.
pub fn winding_number(p: DVec3, x: &[DVec3], triangles: &[[u32; 3]]) -> f64 {
    let mut total = 0.0;
    for t in triangles {
        let (a, b, c) = (x[t[0] as usize] - p, x[t[1] as usize] - p, x[t[2] as usize] - p);
        let (la, lb, lc) = (a.length(), b.length(), c.length());
        let num = a.dot(b.cross(c));
        let den = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
        total += 2.0 * num.atan2(den);
    }
    total / (4.0 * std::f64::consts::PI)
}

/// Whether `p` is inside the closed, outward-oriented surface ([`winding_number`] > ½).
pub fn contains(p: DVec3, x: &[DVec3], triangles: &[[u32; 3]]) -> bool {
    winding_number(p, x, triangles) > 0.5
}

/// Whether the segment p–q passes through the interior or the boundary of the triangle a, b, c
/// (a segment lying in the triangle's plane is not counted).
fn segment_meets_triangle(p: DVec3, q: DVec3, a: DVec3, b: DVec3, c: DVec3) -> bool {
    let n = (b - a).cross(c - a);
    let (dp, dq) = ((p - a).dot(n), (q - a).dot(n));
    if dp == dq || (dp > 0.0 && dq > 0.0) || (dp < 0.0 && dq < 0.0) {
        return false;
    }
    let h = p + (q - p) * (dp / (dp - dq));
    let nn = n.length_squared();
    let w1 = (h - a).cross(c - a).dot(n) / nn;
    let w2 = (b - a).cross(h - a).dot(n) / nn;
    w1 >= 0.0 && w2 >= 0.0 && w1 + w2 <= 1.0
}

/// Number of pairs of triangles of the surface (`x`, `triangles`) that share no vertex and
/// intersect (an edge of one passes through the other): 0 for a surface that does not pass
/// through itself. A self-intersecting membrane has regions enclosed twice or not at all, where
/// the inside of the cell is undefined ([`winding_number`] 2 or 0 between its sheets). Triangles
/// sorted by their lowest z and swept, so the cost is about the number of pairs whose z ranges
/// overlap.
pub fn self_intersections(x: &[DVec3], triangles: &[[u32; 3]]) -> usize {
    let corners = |t: &[u32; 3]| t.map(|k| x[k as usize]);
    let boxes: Vec<(DVec3, DVec3)> = triangles
        .iter()
        .map(|t| {
            let [a, b, c] = corners(t);
            (a.min(b).min(c), a.max(b).max(c))
        })
        .collect();
    let mut order: Vec<usize> = (0..triangles.len()).collect();
    order.sort_by(|&i, &j| boxes[i].0.z.total_cmp(&boxes[j].0.z));
    let mut pairs = 0;
    for (k, &i) in order.iter().enumerate() {
        let (lo, hi) = boxes[i];
        for &j in &order[k + 1..] {
            let (lo_j, hi_j) = boxes[j];
            if lo_j.z > hi.z {
                break;
            }
            if lo_j.cmpgt(hi).any() || lo.cmpgt(hi_j).any() || triangles[i].iter().any(|v| triangles[j].contains(v)) {
                continue;
            }
            let (ti, tj) = (corners(&triangles[i]), corners(&triangles[j]));
            let crosses = |e: &[DVec3; 3], f: &[DVec3; 3]| {
                (0..3).any(|m| segment_meets_triangle(e[m], e[(m + 1) % 3], f[0], f[1], f[2]))
            };
            if crosses(&ti, &tj) || crosses(&tj, &ti) {
                pairs += 1;
            }
        }
    }
    pairs
}

/// Mesh quality report (lengths in the mesh's unit).
#[derive(Clone, Debug, serde::Serialize)]
pub struct MeshQuality {
    pub n_vertices: usize,
    pub n_links: usize,
    pub n_triangles: usize,
    pub link_mean: f64,
    pub link_min: f64,
    pub link_max: f64,
    /// Standard deviation of link lengths over their mean.
    pub link_rel_sd: f64,
    pub min_angle_deg: f64,
    pub max_angle_deg: f64,
    /// (valence, number of vertices with it)
    pub valence_histogram: Vec<(u32, usize)>,
    pub area: f64,
    pub volume: f64,
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Regular octahedron of circumradius 1, outward-oriented.
    pub fn octahedron() -> Mesh {
        let v = vec![DVec3::X, DVec3::NEG_X, DVec3::Y, DVec3::NEG_Y, DVec3::Z, DVec3::NEG_Z];
        let t = vec![
            [0, 2, 4],
            [2, 1, 4],
            [1, 3, 4],
            [3, 0, 4],
            [2, 0, 5],
            [1, 2, 5],
            [3, 1, 5],
            [0, 3, 5],
        ];
        Mesh::new(v, t).unwrap()
    }

    /// An embedded surface has no self-intersections; two octahedra (one vertex list) that
    /// overlap have some, and none once moved apart.
    #[test]
    fn self_intersections_of_overlapping_octahedra() {
        let m = octahedron();
        assert_eq!(self_intersections(&m.vertices, &m.triangles), 0);
        let (mut xs, mut ts) = (m.vertices.clone(), m.triangles.clone());
        xs.extend(m.vertices.iter().map(|v| *v + DVec3::new(0.5, 0.2, 0.1)));
        ts.extend(m.triangles.iter().map(|t| t.map(|k| k + 6)));
        assert!(self_intersections(&xs, &ts) > 0);
        for v in &mut xs[6..] {
            *v += DVec3::new(3.0, 0.0, 0.0);
        }
        assert_eq!(self_intersections(&xs, &ts), 0);
    }

    #[test]
    fn octahedron_topology_area_volume() {
        let m = octahedron();
        let topo = m.topology().unwrap();
        assert_eq!(topo.links.len(), 12);
        assert_eq!(topo.dihedrals.len(), 12);
        assert!(topo.valences().iter().all(|&v| v == 4));
        // area 8 * (sqrt(3)/4 * 2) = 4 sqrt(3); volume 4/3
        assert!((m.area() - 4.0 * 3f64.sqrt()).abs() < 1e-14);
        assert!((m.volume() - 4.0 / 3.0).abs() < 1e-14);
        // dihedral triangles are outward-oriented: (a,b,c) and (d,c,b) are mesh triangles
        for (dih, lt) in topo.dihedrals.iter().zip(&topo.link_triangles) {
            let t1 = m.triangles[lt[0] as usize];
            let t2 = m.triangles[lt[1] as usize];
            let rot = |t: [u32; 3], s: [u32; 3]| (0..3).any(|k| [t[k], t[(k + 1) % 3], t[(k + 2) % 3]] == s);
            assert!(rot(t1, [dih[0], dih[1], dih[2]]));
            assert!(rot(t2, [dih[3], dih[2], dih[1]]));
        }
    }

    /// The winding number is 1 inside and 0 outside, also next to the surface and on the far
    /// side of a vertex; on the biconcave Evans–Fung surface (N = 500) the inside test agrees with
    /// the analytic shape |y| < h(ρ) at every point of a grid more than 0.1 µm from the surface,
    /// the dimple included.
    #[test]
    fn winding_number_inside_and_outside() {
        let m = octahedron();
        let w = |p: DVec3| winding_number(p, &m.vertices, &m.triangles);
        assert!((w(DVec3::ZERO) - 1.0).abs() < 1e-12);
        assert!((w(DVec3::new(0.3, 0.3, 0.3)) - 1.0).abs() < 1e-12);
        assert!(w(DVec3::new(3.0, -2.0, 1.0)).abs() < 1e-12);
        assert!(w(DVec3::new(1.0001, 0.0, 0.0)).abs() < 1e-12, "beyond a vertex");
        assert!(contains(DVec3::new(0.33, 0.33, 0.33), &m.vertices, &m.triangles));
        assert!(!contains(DVec3::new(0.34, 0.34, 0.34), &m.vertices, &m.triangles));

        let shape = crate::shape::EvansFung::healthy_um();
        let mesh = crate::meshgen::initial_mesh(&shape, 500, 1).unwrap();
        let (mut inside, mut checked) = (0, 0);
        for i in 0..40 {
            for j in 0..20 {
                let (rho, y) = (
                    -4.2 + 8.4 * (i as f64 + 0.5) / 40.0,
                    -1.6 + 3.2 * (j as f64 + 0.5) / 20.0,
                );
                let p = DVec3::new(rho * 0.8, y, rho * 0.6);
                let h = if rho.abs() < shape.r {
                    shape.half_thickness(rho.abs())
                } else {
                    -1.0
                };
                if (y.abs() - h).abs() < 0.1 || (rho.abs() - shape.r).abs() < 0.1 {
                    continue;
                }
                let expected = y.abs() < h;
                assert_eq!(
                    contains(p, &mesh.vertices, &mesh.triangles),
                    expected,
                    "ρ {rho}, y {y}, h {h}"
                );
                checked += 1;
                inside += expected as usize;
            }
        }
        assert!(checked > 500 && inside > 100, "{checked} points, {inside} inside");
        // the dimple: on the axis above the centre but below the rim, outside
        let h0 = shape.half_thickness(0.0);
        assert!(contains(
            DVec3::new(0.0, 0.5 * h0, 0.0),
            &mesh.vertices,
            &mesh.triangles
        ));
        assert!(!contains(
            DVec3::new(0.0, h0 + 0.3, 0.0),
            &mesh.vertices,
            &mesh.triangles
        ));
    }

    #[test]
    fn rejects_bad_topology() {
        let m = octahedron();
        let mut t = m.triangles.clone();
        t.swap(0, 1);
        t[0] = [0, 4, 2]; // flipped orientation
        assert!(matches!(Topology::new(6, &t), Err(MeshError::Orientation { .. })));
        let t2 = &m.triangles[..7];
        assert!(Topology::new(6, t2).is_err());
        assert!(matches!(Topology::new(7, &m.triangles), Err(MeshError::Isolated(6))));
    }
}
