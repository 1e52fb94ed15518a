//! A rayon-parallel force evaluation for large meshes, bit-identical for every thread count.
//!
//! Each link, triangle and link pair writes its contributions to its own slot of a
//! [`ForceWorkspace`] (parallel over fixed-size chunks). Each vertex then gathers its
//! contributions in a fixed order (parallel over vertices). Energies are summed per chunk and
//! the chunk sums are added in chunk order. No write conflicts, no atomics, no dependence on
//! the number of threads. The result equals the serial [`MembraneModel::add_forces`] to
//! round-off (the summation order differs), not bit for bit.

use super::{kernels, EnergyTerms, ForceError, MembraneModel};
use glam::DVec3;
use rayon::prelude::*;

/// Elements per parallel task (fixed, so that the energy sums do not depend on the thread count).
const CHUNK: usize = 1024;

/// Scratch space and vertex incidence lists for [`MembraneModel::add_forces_parallel`].
/// Build once per model with [`MembraneModel::workspace`]; reuse for every call.
#[derive(Clone, Debug)]
pub struct ForceWorkspace {
    n_vertices: usize,
    link_f: Vec<DVec3>,
    tri_f: Vec<[DVec3; 3]>,
    dih_f: Vec<[DVec3; 4]>,
    /// CSR incidence per vertex: link refs `2i + end`, triangle refs `3t + slot`,
    /// link-pair refs `4k + slot`, each list ascending.
    link_off: Vec<u32>,
    link_refs: Vec<u32>,
    tri_off: Vec<u32>,
    tri_refs: Vec<u32>,
    dih_off: Vec<u32>,
    dih_refs: Vec<u32>,
}

/// CSR lists from (vertex, ref) pairs generated in ascending ref order.
fn csr<const K: usize>(n: usize, elems: &[[u32; K]]) -> (Vec<u32>, Vec<u32>) {
    let mut count = vec![0u32; n + 1];
    for e in elems {
        for &v in e {
            count[v as usize + 1] += 1;
        }
    }
    for i in 0..n {
        count[i + 1] += count[i];
    }
    let off = count.clone();
    let mut next = count;
    let mut refs = vec![0u32; elems.len() * K];
    for (i, e) in elems.iter().enumerate() {
        for (slot, &v) in e.iter().enumerate() {
            let p = &mut next[v as usize];
            refs[*p as usize] = (i * K + slot) as u32;
            *p += 1;
        }
    }
    (off, refs)
}

impl ForceWorkspace {
    fn new(model: &MembraneModel) -> Self {
        let n = model.n_vertices;
        let (link_off, link_refs) = csr(n, &model.links);
        let (tri_off, tri_refs) = csr(n, &model.triangles);
        let (dih_off, dih_refs) = csr(n, &model.dihedrals);
        Self {
            n_vertices: n,
            link_f: vec![DVec3::ZERO; model.links.len()],
            tri_f: vec![[DVec3::ZERO; 3]; model.triangles.len()],
            dih_f: vec![[DVec3::ZERO; 4]; model.dihedrals.len()],
            link_off,
            link_refs,
            tri_off,
            tri_refs,
            dih_off,
            dih_refs,
        }
    }
}

/// First error in chunk order, else the chunk values in order.
fn ordered<T>(v: Vec<Result<T, ForceError>>) -> Result<Vec<T>, ForceError> {
    v.into_iter().collect()
}

impl MembraneModel {
    /// Scratch space for [`add_forces_parallel`](Self::add_forces_parallel).
    pub fn workspace(&self) -> ForceWorkspace {
        ForceWorkspace::new(self)
    }

    /// As [`add_forces`](Self::add_forces) (every term), parallel with rayon. The result is
    /// bit-identical for any number of threads and equals `add_forces` to round-off. Worth it
    /// from a few thousand vertices; `ws` must come from this model's
    /// [`workspace`](Self::workspace).
    pub fn add_forces_parallel(
        &self,
        x: &[DVec3],
        f: &mut [DVec3],
        ws: &mut ForceWorkspace,
    ) -> Result<EnergyTerms, ForceError> {
        super::check_positions(x, self.n_vertices, "positions")?;
        if f.len() != self.n_vertices {
            return Err(ForceError::WrongLength {
                what: "force buffer",
                expected: self.n_vertices,
                got: f.len(),
            });
        }
        if ws.n_vertices != self.n_vertices
            || ws.link_f.len() != self.links.len()
            || ws.tri_f.len() != self.triangles.len()
        {
            return Err(ForceError::WrongLength {
                what: "workspace",
                expected: self.n_vertices,
                got: ws.n_vertices,
            });
        }
        let mut e = EnergyTerms::default();

        // Global area and volume (about vertex 0), chunk sums in order.
        let origin = x[0];
        let parts = ordered(
            self.triangles
                .par_chunks(CHUNK)
                .enumerate()
                .map(|(ci, tris)| {
                    let (mut a_sum, mut v_sum) = (0.0, 0.0);
                    for j in 0..tris.len() {
                        let (at, v6) = self.triangle_area_vol6(ci * CHUNK + j, x, origin)?;
                        a_sum += at;
                        v_sum += v6;
                    }
                    Ok((a_sum, v_sum))
                })
                .collect(),
        )?;
        let (area, vol6) = parts.iter().fold((0.0, 0.0), |(a, v), p| (a + p.0, v + p.1));
        let volume = vol6 / 6.0;
        e.area = 0.5 * self.k_area * (area - self.area0).powi(2) / self.area0;
        e.volume = 0.5 * self.k_volume * (volume - self.volume0).powi(2) / self.volume0;
        let da = self.k_area * (area - self.area0) / self.area0;
        let vcoef = -self.k_volume * (volume - self.volume0) / self.volume0 / 6.0;

        // Links: force on the first end (the second gets the opposite).
        let wlc = ordered(
            ws.link_f
                .par_chunks_mut(CHUNK)
                .enumerate()
                .map(|(ci, out)| {
                    let mut s = 0.0;
                    for (j, o) in out.iter_mut().enumerate() {
                        let i = ci * CHUNK + j;
                        let l = self.links[i];
                        let d = x[l[1] as usize] - x[l[0] as usize];
                        let len = d.length();
                        let (v, t) = kernels::wlc(len, self.link_lmax[i], self.link_w[i])
                            .ok_or_else(|| self.overstretched(i, len))?;
                        let tau = self.link_tau[i];
                        s += v - tau * (len - self.link_l0[i]);
                        *o = d * ((t - tau) / len);
                    }
                    Ok(s)
                })
                .collect(),
        )?;
        e.wlc = wlc.iter().sum();

        // Triangles: C/A, area and volume.
        let ca = ws
            .tri_f
            .par_chunks_mut(CHUNK)
            .enumerate()
            .map(|(ci, out)| {
                let mut s = 0.0;
                for (j, o) in out.iter_mut().enumerate() {
                    let t = ci * CHUNK + j;
                    let tri = self.triangles[t];
                    let [a, b, c] = tri.map(|v| x[v as usize]);
                    let n = (b - a).cross(c - a);
                    let nl = n.length();
                    let at = 0.5 * nl;
                    let cat = self.tri_c[t] / at;
                    s += cat;
                    let coef = cat / at - da;
                    let g = kernels::area_gradient(n / nl, a, b, c);
                    let (ra, rb, rc) = (a - origin, b - origin, c - origin);
                    *o = [
                        g[0] * coef + rb.cross(rc) * vcoef,
                        g[1] * coef + rc.cross(ra) * vcoef,
                        g[2] * coef + ra.cross(rb) * vcoef,
                    ];
                }
                s
            })
            .collect::<Vec<f64>>();
        e.c_over_a = ca.iter().sum();

        // Link pairs: bending.
        let bend = ordered(
            ws.dih_f
                .par_chunks_mut(CHUNK)
                .enumerate()
                .map(|(ci, out)| {
                    let mut s = 0.0;
                    for (j, o) in out.iter_mut().enumerate() {
                        let k = ci * CHUNK + j;
                        let d = self.dihedrals[k];
                        let [a, b, c, dd] = d.map(|v| x[v as usize]);
                        let (cos_t, sin_t, g) = kernels::dihedral(a, b, c, dd)
                            .ok_or(ForceError::DegenerateDihedral { pair: k, vertices: d })?;
                        s += self.k_bend * (1.0 - cos_t * self.cos_theta0 - sin_t * self.sin_theta0);
                        let m = -self.k_bend * (sin_t * self.cos_theta0 - cos_t * self.sin_theta0);
                        *o = g.map(|gi| gi * m);
                    }
                    Ok(s)
                })
                .collect(),
        )?;
        e.bending = bend.iter().sum();

        // Gather per vertex, in a fixed order.
        let ws = &*ws;
        f.par_iter_mut().enumerate().for_each(|(v, fv)| {
            let mut acc = DVec3::ZERO;
            for &r in &ws.link_refs[ws.link_off[v] as usize..ws.link_off[v + 1] as usize] {
                let lf = ws.link_f[(r / 2) as usize];
                if r % 2 == 0 {
                    acc += lf;
                } else {
                    acc -= lf;
                }
            }
            for &r in &ws.tri_refs[ws.tri_off[v] as usize..ws.tri_off[v + 1] as usize] {
                acc += ws.tri_f[(r / 3) as usize][(r % 3) as usize];
            }
            for &r in &ws.dih_refs[ws.dih_off[v] as usize..ws.dih_off[v + 1] as usize] {
                acc += ws.dih_f[(r / 4) as usize][(r % 4) as usize];
            }
            *fv += acc;
        });
        Ok(e)
    }
}
