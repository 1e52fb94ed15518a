//! A positive semi-definite approximation of the Hessian of the membrane energy, for the
//! stretching solver's preconditioner ([`crate::precondition`]).
//!
//! Each term E = φ(s(x)) of one scalar s (a link length, a triangle area, a dihedral angle)
//! has the Hessian φ''(s) ∇s ∇sᵀ + φ'(s) ∇²s. The Gauss–Newton part φ'' ∇s ∇sᵀ is kept where
//! φ'' > 0; of the second part only a link's tension term (T/L)(I − ê êᵀ), T > 0, is kept (it
//! is what makes a stretched network stiff against sideways motion). The global area and
//! volume terms are rank one and dense, and are left to the quasi-Newton memory.

use super::{kernels, ForceError, MembraneModel, TermSet};
use crate::block_matrix::{outer, BlockMatrix};
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

    /// Adds the Gauss–Newton Hessian blocks of the local `terms` (WLC, C/A, bending) at `x` to
    /// `h` (whose pattern comes from [`hessian_pairs`](Self::hessian_pairs)).
    pub(crate) fn add_gauss_newton(&self, x: &[DVec3], terms: TermSet, h: &mut BlockMatrix) -> Result<(), ForceError> {
        for (i, l) in self.links.iter().enumerate().filter(|_| terms.wlc) {
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
        for (t, tri) in self.triangles.iter().enumerate().filter(|_| terms.c_over_a) {
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
        if terms.bending && self.k_bend != 0.0 {
            for k in 0..self.dihedrals.len() {
                let (idx, cos_t, sin_t, g) = self.dihedral_at(k, x)?;
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

#[cfg(test)]
mod tests {
    use super::super::tests::icosphere;
    use super::*;
    use crate::forces::{MembraneConstants, ReferenceState};
    use crate::params::ModelParams;

    fn constants() -> MembraneConstants {
        MembraneConstants::from_params(
            &ModelParams::coarse_grained(500, 300.0).unwrap(),
            1e-6,
            1e-18,
            1e-3,
            1e3,
        )
    }

    /// Deterministic deviates in [−1, 1).
    fn noise(i: usize, k: u64) -> f64 {
        let mut z = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ k.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 29)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 32;
        (z >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }

    fn jitter(x: &[DVec3], amplitude: f64, k: u64) -> Vec<DVec3> {
        x.iter()
            .enumerate()
            .map(|(i, p)| *p + amplitude * DVec3::new(noise(i, k), noise(i, k + 1), noise(i, k + 2)))
            .collect()
    }

    /// For the WLC links alone (uniform reference: every link under tension), the Gauss–Newton
    /// matrix keeps every term of the Hessian, so it must equal the finite-difference Hessian
    /// −∂f/∂x of the analytic forces (central differences, h = 1e-6 L0: error ~1e-9 relative).
    #[test]
    fn link_blocks_are_the_exact_hessian() {
        let c = constants();
        let mesh = icosphere(1, c.l0 / 0.55);
        let topo = mesh.topology().unwrap();
        let rest = jitter(&mesh.vertices, 0.03 * c.l0, 1);
        let model = MembraneModel::new(&topo, &rest, &c, ReferenceState::Uniform).unwrap();
        let x = jitter(&rest, 0.05 * c.l0, 7);
        let wlc = TermSet {
            wlc: true,
            ..TermSet::NONE
        };
        let mut h = BlockMatrix::new(x.len(), model.hessian_pairs());
        model.add_gauss_newton(&x, wlc, &mut h).unwrap();
        let p = h.to_dense();
        let step = 1e-6 * c.l0;
        let mut worst: f64 = 0.0;
        let scale = p.iter().flatten().fold(0.0f64, |a, v| a.max(v.abs()));
        for col in 0..3 * x.len() {
            let f_at = |sign: f64| {
                let mut y = x.clone();
                y[col / 3][col % 3] += sign * step;
                let mut f = vec![DVec3::ZERO; y.len()];
                model.add_forces_terms(&y, &mut f, wlc).unwrap();
                f
            };
            let (fp, fm) = (f_at(1.0), f_at(-1.0));
            for row in 0..3 * x.len() {
                let fd = -(fp[row / 3][row % 3] - fm[row / 3][row % 3]) / (2.0 * step);
                worst = worst.max((fd - p[row][col]).abs() / scale);
            }
        }
        assert!(worst < 1e-7, "largest difference {worst:.1e} of the largest entry");
    }

    /// For C/A and bending, vᵀ P v must equal Σ φ''(s) (∇s·v)² over the triangles (s = area,
    /// φ'' = 2C/A³) and the dihedrals (s = θ, φ'' = max(k cos(θ − θ0), 0)), with each ∇s·v
    /// taken by central differences of the area and the angle alone: this checks the assembly
    /// (indices, blocks, symmetry) independently of the gradient kernels.
    #[test]
    fn area_and_bending_blocks_match_directional_second_derivatives() {
        let c = constants();
        let mesh = icosphere(2, 2.0 * c.l0 / 0.55);
        let topo = mesh.topology().unwrap();
        let model = MembraneModel::new(&topo, &mesh.vertices, &c, ReferenceState::StressFree).unwrap();
        // rough enough that some dihedrals have cos(θ − θ0) well below 1
        let x = jitter(&mesh.vertices, 0.12 * c.l0, 3);
        for (terms, label) in [
            (
                TermSet {
                    c_over_a: true,
                    ..TermSet::NONE
                },
                "C/A",
            ),
            (
                TermSet {
                    bending: true,
                    ..TermSet::NONE
                },
                "bending",
            ),
        ] {
            let mut h = BlockMatrix::new(x.len(), model.hessian_pairs());
            model.add_gauss_newton(&x, terms, &mut h).unwrap();
            let p = h.to_dense();
            for k in 0..3u64 {
                let v = jitter(&vec![DVec3::ZERO; x.len()], 1.0, 100 + 3 * k);
                let flat: Vec<f64> = v.iter().flat_map(|a| a.to_array()).collect();
                let vpv: f64 = (0..flat.len())
                    .map(|r| flat[r] * (0..flat.len()).map(|c| p[r][c] * flat[c]).sum::<f64>())
                    .sum();
                let step = 1e-6 * c.l0;
                let along = |s: f64| -> Vec<DVec3> { x.iter().zip(&v).map(|(a, b)| *a + *b * s).collect() };
                let (xp, xm) = (along(step), along(-step));
                let mut expected = 0.0;
                if terms.c_over_a {
                    for (t, tri) in model.triangles.iter().enumerate() {
                        let area = |y: &[DVec3]| {
                            let [a, b, c] = tri.map(|i| y[i as usize]);
                            0.5 * (b - a).cross(c - a).length()
                        };
                        let ds = (area(&xp) - area(&xm)) / (2.0 * step);
                        expected += 2.0 * model.tri_c[t] / area(&x).powi(3) * ds * ds;
                    }
                } else {
                    for d in &model.dihedrals {
                        let angle = |y: &[DVec3]| {
                            let [a, b, c, e] = d.map(|i| y[i as usize]);
                            kernels::dihedral_angle(a, b, c, e).unwrap()
                        };
                        let ds = (angle(&xp) - angle(&xm)) / (2.0 * step);
                        let curvature = (model.k_bend * (angle(&x) - model.theta0).cos()).max(0.0);
                        expected += curvature * ds * ds;
                    }
                }
                assert!(
                    ((vpv - expected) / expected).abs() < 1e-7,
                    "{label}: vᵀPv = {vpv:.10e}, expected {expected:.10e}"
                );
            }
        }
    }

    /// ∂A/∂x and ∂V/∂x of `constraint_gradients` against central differences of
    /// `area_volume`, and the curvatures k_a/A0, k_v/V0.
    #[test]
    fn constraint_gradients_match_finite_differences() {
        let c = constants();
        let mesh = icosphere(2, 2.0 * c.l0 / 0.55);
        let topo = mesh.topology().unwrap();
        let model = MembraneModel::new(&topo, &mesh.vertices, &c, ReferenceState::StressFree).unwrap();
        let x = jitter(&mesh.vertices, 0.1 * c.l0, 11);
        let n = x.len();
        let (mut ga, mut gv) = (vec![DVec3::ZERO; n], vec![DVec3::ZERO; n]);
        let (ca, cv) = model.constraint_gradients(&x, &mut ga, &mut gv);
        assert_eq!((ca, cv), (model.k_area / model.area0, model.k_volume / model.volume0));
        let step = 1e-6 * c.l0;
        let (mut worst_a, mut worst_v) = (0.0f64, 0.0f64);
        let (sa, sv) = (
            ga.iter().fold(0.0f64, |m, g| m.max(g.abs().max_element())),
            gv.iter().fold(0.0f64, |m, g| m.max(g.abs().max_element())),
        );
        for i in 0..n {
            for k in 0..3 {
                let at = |s: f64| {
                    let mut y = x.clone();
                    y[i][k] += s;
                    model.area_volume(&y).unwrap()
                };
                let ((ap, vp), (am, vm)) = (at(step), at(-step));
                worst_a = worst_a.max(((ap - am) / (2.0 * step) - ga[i][k]).abs() / sa);
                worst_v = worst_v.max(((vp - vm) / (2.0 * step) - gv[i][k]).abs() / sv);
            }
        }
        assert!(
            worst_a < 1e-7 && worst_v < 1e-7,
            "∂A/∂x off by {worst_a:.1e}, ∂V/∂x by {worst_v:.1e}"
        );
    }
}
