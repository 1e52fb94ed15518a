//! A positive semi-definite approximation of the Hessian of the membrane energy, for the
//! stretching solver's preconditioner ([`crate::precondition`]).
//!
//! Each term E = φ(s(x)) of one scalar s (a link length, a triangle area, a dihedral angle)
//! has the Hessian φ''(s) ∇s ∇sᵀ + φ'(s) ∇²s. The Gauss–Newton part φ'' ∇s ∇sᵀ is kept where
//! φ'' > 0; of the second part only a link's tension term (T/L)(I − ê êᵀ), T > 0, is kept (it
//! is what makes a stretched network stiff against sideways motion). The global area and
//! volume terms are rank one and dense, and are left to the quasi-Newton memory.

use super::{kernels, ForceError, MembraneModel};
use crate::precondition::BlockMatrix;
use glam::{DMat3, DVec3};

impl MembraneModel {
    /// Every pair of vertices the approximate Hessian couples: the links and the two wing
    /// vertices of each dihedral.
    pub(crate) fn hessian_pairs(&self) -> impl Iterator<Item = (u32, u32)> + '_ {
        self.links
            .iter()
            .map(|l| (l[0], l[1]))
            .chain(self.dihedrals.iter().map(|d| (d[0], d[3])))
    }

    /// Adds the Gauss–Newton Hessian blocks at `x` to `h` (whose pattern comes from
    /// [`hessian_pairs`](Self::hessian_pairs)).
    pub(crate) fn add_gauss_newton(&self, x: &[DVec3], h: &mut BlockMatrix) -> Result<(), ForceError> {
        for (i, l) in self.links.iter().enumerate() {
            let (ia, ib) = (l[0] as usize, l[1] as usize);
            let d = x[ib] - x[ia];
            let len = d.length();
            let lmax = self.link_lmax[i];
            let Some((_, t)) = kernels::wlc(len, lmax, self.link_w[i]) else {
                return Err(self.overstretched(i, len));
            };
            let stiffness = self.link_w[i] * kernels::wlc_ddg(len / lmax) / lmax;
            let sideways = ((t - self.link_tau[i]) / len).max(0.0);
            let e = d / len;
            let k = DMat3::from_diagonal(DVec3::splat(sideways)) + outer(e, e) * (stiffness - sideways);
            h.add(ia, ia, k);
            h.add(ib, ib, k);
            h.add(ib, ia, -k);
        }
        for (t, tri) in self.triangles.iter().enumerate() {
            let idx = tri.map(|v| v as usize);
            let [a, b, c] = idx.map(|v| x[v]);
            let n = (b - a).cross(c - a);
            let nl = n.length();
            let area = 0.5 * nl;
            if !(area > self.tri_amin[t]) {
                return Err(ForceError::DegenerateTriangle {
                    triangle: t,
                    vertices: *tri,
                    area,
                });
            }
            // d²(C/A)/dA² = 2C/A³
            let g = kernels::area_gradient(n / nl, a, b, c);
            h.add_outer(&idx, &g, 2.0 * self.tri_c[t] / (area * area * area));
        }
        if self.k_bend != 0.0 {
            for (k, d) in self.dihedrals.iter().enumerate() {
                let idx = d.map(|v| v as usize);
                let [a, b, c, dd] = idx.map(|v| x[v]);
                let (cos_t, sin_t, g) =
                    kernels::dihedral(a, b, c, dd).ok_or(ForceError::DegenerateDihedral { pair: k, vertices: *d })?;
                // d²/dθ² k [1 − cos(θ − θ0)] = k cos(θ − θ0)
                let curvature = self.k_bend * (cos_t * self.cos_theta0 + sin_t * self.sin_theta0);
                if curvature > 0.0 {
                    h.add_outer(&idx, &g, curvature);
                }
            }
        }
        Ok(())
    }
}

impl MembraneModel {
    /// The global constraints' curvatures d²E_A/dA² = k_a/A0 and d²E_V/dV² = k_v/V0, and the
    /// gradients ∂A/∂x and ∂V/∂x at `x` (written to `ga`, `gv`): the two rank-one terms the
    /// preconditioner adds by the Sherman–Morrison–Woodbury formula.
    pub(crate) fn constraint_gradients(&self, x: &[DVec3], ga: &mut [DVec3], gv: &mut [DVec3]) -> (f64, f64) {
        ga.iter_mut().chain(gv.iter_mut()).for_each(|g| *g = DVec3::ZERO);
        let origin = x[0];
        for tri in &self.triangles {
            let idx = tri.map(|v| v as usize);
            let [a, b, c] = idx.map(|v| x[v] - origin);
            let n = (b - a).cross(c - a);
            let nl = n.length();
            if nl > 0.0 {
                let g = kernels::area_gradient(n / nl, a, b, c);
                for k in 0..3 {
                    ga[idx[k]] += g[k];
                }
            }
            gv[idx[0]] += b.cross(c) / 6.0;
            gv[idx[1]] += c.cross(a) / 6.0;
            gv[idx[2]] += a.cross(b) / 6.0;
        }
        (self.k_area / self.area0, self.k_volume / self.volume0)
    }
}

/// a bᵀ.
#[inline]
pub(crate) fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}
