//! The stretching solver's preconditioner P ≈ ∇²E, a symmetric positive-definite 3N × 3N
//! matrix: P = P₀ + U C Uᵀ, where P₀ is the sparse Gauss–Newton Hessian of the local terms
//! (links, triangles, dihedrals; see `forces/hessian.rs`) plus ε I, and U C Uᵀ the two
//! dense rank-one terms of the global area and volume constraints, (k_a/A0) ∇A ∇Aᵀ and
//! (k_v/V0) ∇V ∇Vᵀ. P₀ = L Lᵀ is factorised by faer's sparse Cholesky (AMD fill-reducing
//! order, sequential, so the factor does not depend on the thread count); P⁻¹ follows from the
//! Sherman–Morrison–Woodbury formula with the 2 × 2 capacitance matrix C⁻¹ + Uᵀ P₀⁻¹ U.
//! The solver applies P⁻¹ as its initial inverse Hessian; one factorisation serves a whole
//! force of the protocol.

use crate::block_matrix::BlockMatrix;
use crate::forces::{ForceError, MembraneModel, TermSet};
use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::cholesky::llt::factor::LltRegularization;
use faer::sparse::linalg::cholesky::{factorize_symbolic_cholesky, LltRef, SymbolicCholesky, SymmetricOrdering};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use glam::DVec3;

/// Why the preconditioner could not be built or factorised.
#[derive(Debug, thiserror::Error)]
pub enum PreconditionError {
    #[error(transparent)]
    Force(#[from] ForceError),
    #[error("the sparse Cholesky factorisation failed: {0}")]
    Factor(String),
}

/// P, factorised (see the module doc); [`apply`](Self::apply) gives P⁻¹ v.
pub struct Preconditioner {
    blocks: BlockMatrix,
    /// The lower triangle of P in compressed sparse columns (fixed pattern).
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    values: Vec<f64>,
    /// For each stored value: its block and the entry (row-major r·3 + c) in the block.
    source: Vec<(u32, u8)>,
    diagonal: Vec<usize>,
    symbolic: SymbolicCholesky<usize>,
    factor: Vec<f64>,
    factored: bool,
    rhs: Vec<f64>,
    scratch: MemBuffer,
    /// The global area and volume terms c_k u_k u_kᵀ (k = area, volume): u_k, P₀⁻¹ u_k, and the
    /// inverse of the 2 × 2 capacitance matrix diag(1/c_k) + Uᵀ P₀⁻¹ U.
    constraint: [Vec<DVec3>; 2],
    constraint_solved: [Vec<DVec3>; 2],
    capacitance_inv: [[f64; 2]; 2],
}

impl Preconditioner {
    /// The pattern and the symbolic factorisation (ordering) for `model`'s mesh.
    pub fn new(model: &MembraneModel) -> Result<Self, PreconditionError> {
        let blocks = BlockMatrix::new(model.n_vertices(), model.hessian_pairs());
        let n = blocks.n();
        let (mut col_ptr, mut row_idx, mut source, mut diagonal) = (vec![0], Vec::new(), Vec::new(), Vec::new());
        for j in 0..n {
            for c in 0..3 {
                for k in blocks.start[j]..blocks.start[j + 1] {
                    let i = blocks.rows[k] as usize;
                    for r in 0..3 {
                        if i == j && r < c {
                            continue;
                        }
                        if i == j && r == c {
                            diagonal.push(row_idx.len());
                        }
                        row_idx.push(3 * i + r);
                        source.push((k as u32, (3 * r + c) as u8));
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        let symbolic = {
            let pattern = SymbolicSparseColMatRef::new_checked(3 * n, 3 * n, &col_ptr, None, &row_idx);
            factorize_symbolic_cholesky(pattern, Side::Lower, SymmetricOrdering::Amd, Default::default())
                .map_err(|e| PreconditionError::Factor(format!("{e:?}")))?
        };
        let scratch = MemBuffer::new(StackReq::any_of(&[
            symbolic.factorize_numeric_llt_scratch::<f64>(Par::Seq, Default::default()),
            symbolic.solve_in_place_scratch::<f64>(1, Par::Seq),
        ]));
        Ok(Self {
            values: vec![0.0; row_idx.len()],
            factor: vec![0.0; symbolic.len_val()],
            blocks,
            col_ptr,
            row_idx,
            source,
            diagonal,
            symbolic,
            factored: false,
            rhs: vec![0.0; 3 * n],
            scratch,
            constraint: [vec![DVec3::ZERO; n], vec![DVec3::ZERO; n]],
            constraint_solved: [vec![DVec3::ZERO; n], vec![DVec3::ZERO; n]],
            capacitance_inv: [[0.0; 2]; 2],
        })
    }

    /// Assembles P at `x` and factorises it. On error the preconditioner is left unusable
    /// until the next successful update ([`apply`](Self::apply) then returns false).
    pub fn update(&mut self, model: &MembraneModel, x: &[DVec3]) -> Result<(), PreconditionError> {
        self.factored = false;
        self.blocks.clear();
        model.add_gauss_newton(x, TermSet::ALL, &mut self.blocks)?;
        for (v, &(k, e)) in self.values.iter_mut().zip(&self.source) {
            let m = &self.blocks.blocks[k as usize];
            *v = m.col((e % 3) as usize)[(e / 3) as usize];
        }
        // ε I, far below every physical stiffness, makes the rigid translations invertible
        let mean = self.diagonal.iter().map(|&d| self.values[d]).sum::<f64>() / self.diagonal.len() as f64;
        if !(mean > 0.0 && mean.is_finite()) {
            return Err(PreconditionError::Factor(format!("mean diagonal {mean}")));
        }
        for &d in &self.diagonal {
            self.values[d] += 1e-10 * mean;
        }
        let n = self.rhs.len();
        let a = SparseColMatRef::new(
            SymbolicSparseColMatRef::new_checked(n, n, &self.col_ptr, None, &self.row_idx),
            &self.values,
        );
        self.symbolic
            .factorize_numeric_llt::<f64>(
                &mut self.factor,
                a,
                Side::Lower,
                LltRegularization::default(),
                Par::Seq,
                MemStack::new(&mut self.scratch),
                Default::default(),
            )
            .map_err(|e| PreconditionError::Factor(format!("{e:?}")))?;
        self.factored = true;
        let [ua, uv] = &mut self.constraint;
        let (ca, cv) = model.constraint_gradients(x, ua, uv);
        let mut inverse_c = [0.0; 2];
        for (k, c) in [ca, cv].into_iter().enumerate() {
            let mut z = std::mem::take(&mut self.constraint_solved[k]);
            if c > 0.0 {
                z.copy_from_slice(&self.constraint[k]);
                self.solve(&mut z);
                inverse_c[k] = 1.0 / c;
            } else {
                // a switched-off constraint: u = 0 and a unit row in the capacitance matrix
                self.constraint[k].iter_mut().for_each(|u| *u = DVec3::ZERO);
                z.iter_mut().for_each(|u| *u = DVec3::ZERO);
                inverse_c[k] = 1.0;
            }
            self.constraint_solved[k] = z;
        }
        let m = |a: usize, b: usize| dot(&self.constraint[a], &self.constraint_solved[b]);
        let c = [[inverse_c[0] + m(0, 0), m(0, 1)], [m(1, 0), inverse_c[1] + m(1, 1)]];
        let det = c[0][0] * c[1][1] - c[0][1] * c[1][0];
        if !(det > 0.0 && det.is_finite()) {
            self.factored = false;
            return Err(PreconditionError::Factor(format!("capacitance matrix {c:?}")));
        }
        self.capacitance_inv = [[c[1][1] / det, -c[0][1] / det], [-c[1][0] / det, c[0][0] / det]];
        Ok(())
    }

    /// v ← P₀⁻¹ v (the sparse part only).
    fn solve(&mut self, v: &mut [DVec3]) {
        for (r, p) in self.rhs.chunks_exact_mut(3).zip(v.iter()) {
            r.copy_from_slice(&p.to_array());
        }
        let n = self.rhs.len();
        LltRef::<usize, f64>::new(&self.symbolic, &self.factor).solve_in_place_with_conj(
            Conj::No,
            MatMut::from_column_major_slice_mut(&mut self.rhs, n, 1),
            Par::Seq,
            MemStack::new(&mut self.scratch),
        );
        for (p, r) in v.iter_mut().zip(self.rhs.chunks_exact(3)) {
            *p = DVec3::new(r[0], r[1], r[2]);
        }
    }

    /// True after a successful [`update`](Self::update).
    pub fn is_factored(&self) -> bool {
        self.factored
    }

    /// v ← P⁻¹ v with its mean (a rigid translation, which P resolves only through ε) removed;
    /// false (v unchanged) if there is no factor.
    pub fn apply(&mut self, v: &mut [DVec3]) -> bool {
        if !self.factored {
            return false;
        }
        self.solve(v);
        // Woodbury: v −= P₀⁻¹U C⁻¹ Uᵀ v
        let a = [dot(&self.constraint[0], v), dot(&self.constraint[1], v)];
        let ci = &self.capacitance_inv;
        let b = [ci[0][0] * a[0] + ci[0][1] * a[1], ci[1][0] * a[0] + ci[1][1] * a[1]];
        let mut mean = DVec3::ZERO;
        for ((p, za), zv) in v
            .iter_mut()
            .zip(&self.constraint_solved[0])
            .zip(&self.constraint_solved[1])
        {
            *p -= *za * b[0] + *zv * b[1];
            mean += *p;
        }
        mean /= v.len() as f64;
        v.iter_mut().for_each(|p| *p -= mean);
        true
    }
}

fn dot(a: &[DVec3], b: &[DVec3]) -> f64 {
    a.iter().zip(b).map(|(p, q)| p.dot(*q)).sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::forces::tests::icosphere;
    use crate::forces::{MembraneConstants, ReferenceState};
    use crate::params::ModelParams;

    /// The N = 500 constants (µm, pN) on a 162-vertex icosphere with links ≈ L0, stress-free.
    fn icosphere_model() -> (MembraneConstants, crate::mesh::Mesh, MembraneModel) {
        let params = ModelParams::coarse_grained(500, 300.0).unwrap();
        let c = MembraneConstants::from_params(&params, 1e-6, 1e-18, 2e-3, 1e3);
        let mesh = icosphere(2, 2.0 * c.l0 / 0.55);
        let model = MembraneModel::new(
            &mesh.topology().unwrap(),
            &mesh.vertices,
            &c,
            ReferenceState::StressFree,
        )
        .unwrap();
        (c, mesh, model)
    }

    /// Solves m z = b by Gaussian elimination with partial pivoting (m is consumed).
    fn dense_solve(mut m: Vec<Vec<f64>>, mut b: Vec<f64>) -> Vec<f64> {
        let n = b.len();
        for k in 0..n {
            let p = (k..n).max_by(|&i, &j| m[i][k].abs().total_cmp(&m[j][k].abs())).unwrap();
            m.swap(k, p);
            b.swap(k, p);
            for i in k + 1..n {
                let f = m[i][k] / m[k][k];
                if f != 0.0 {
                    for j in k..n {
                        m[i][j] -= f * m[k][j];
                    }
                    b[i] -= f * b[k];
                }
            }
        }
        let mut z = vec![0.0; n];
        for k in (0..n).rev() {
            let s: f64 = (k + 1..n).map(|j| m[k][j] * z[j]).sum();
            z[k] = (b[k] - s) / m[k][k];
        }
        z
    }

    /// `apply` gives P⁻¹ v (mean removed) for P assembled densely from the same pieces: the
    /// Gauss–Newton blocks, ε I, and the two rank-one constraint terms. This checks the CSC
    /// conversion, the sparse factorisation and the Woodbury correction against plain
    /// elimination. Removing the mean is exact here: P maps translations to ε × translations
    /// and everything else to zero-mean vectors, so for a zero-mean v the two solutions agree.
    #[test]
    fn apply_is_the_dense_inverse() {
        let (c, mesh, model) = icosphere_model();
        // a stretched, rough shape: links under tension and compression, folded dihedrals
        let x: Vec<DVec3> = mesh
            .vertices
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let wobble = DVec3::new((i as f64 * 1.7).sin(), (i as f64 * 2.3).cos(), (i as f64 * 0.9).sin());
                DVec3::new(1.3 * p.x, p.y, 0.8 * p.z) + 0.05 * c.l0 * wobble
            })
            .collect();
        let mut pc = Preconditioner::new(&model).unwrap();
        pc.update(&model, &x).unwrap();
        let n = x.len();
        // the values handed to the factorisation (the lower triangle, with ε), mirrored
        let mut m = vec![vec![0.0; 3 * n]; 3 * n];
        for col in 0..3 * n {
            for s in pc.col_ptr[col]..pc.col_ptr[col + 1] {
                let r = pc.row_idx[s];
                m[r][col] = pc.values[s];
                m[col][r] = pc.values[s];
            }
        }
        // ... which are the Gauss–Newton blocks plus ε I
        let blocks = pc.blocks.to_dense();
        for r in 0..3 * n {
            for s in 0..3 * n {
                let eps = m[r][s] - blocks[r][s];
                assert!(if r == s {
                    eps > 0.0 && eps < 1e-9 * m[r][r]
                } else {
                    eps == 0.0
                });
            }
        }
        let (ka, kv) = (model.k_area() / model.area0(), model.k_volume() / model.volume0());
        let (mut ua, mut uv) = (vec![DVec3::ZERO; n], vec![DVec3::ZERO; n]);
        model.constraint_gradients(&x, &mut ua, &mut uv);
        let flat = |v: &[DVec3]| -> Vec<f64> { v.iter().flat_map(|a| a.to_array()).collect() };
        let (fa, fv) = (flat(&ua), flat(&uv));
        for r in 0..3 * n {
            for s in 0..3 * n {
                m[r][s] += ka * fa[r] * fa[s] + kv * fv[r] * fv[s];
            }
        }
        for k in 0..3 {
            let mut v: Vec<DVec3> = (0..n)
                .map(|i| {
                    DVec3::new(
                        ((i + k) as f64).sin(),
                        ((i * 3 + k) as f64).cos(),
                        ((i * 7) as f64 + k as f64).sin(),
                    )
                })
                .collect();
            let mean = v.iter().copied().sum::<DVec3>() / n as f64;
            v.iter_mut().for_each(|a| *a -= mean);
            // (the elimination's round-off along the translations, amplified by 1/ε, removed)
            let mut expected = dense_solve(m.clone(), flat(&v));
            for a in 0..3 {
                let mean = expected.iter().skip(a).step_by(3).sum::<f64>() / n as f64;
                expected.iter_mut().skip(a).step_by(3).for_each(|z| *z -= mean);
            }
            assert!(pc.apply(&mut v));
            let got = flat(&v);
            let norm = expected.iter().map(|a| a * a).sum::<f64>().sqrt();
            let err = got
                .iter()
                .zip(&expected)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!(err < 1e-8 * norm, "|P⁻¹v − dense| = {err:.2e} of {norm:.2e}");
        }
    }

    /// A shape where P cannot be built (a link stretched past its maximum extension) is an
    /// error, and the preconditioner then refuses to apply until a good update.
    #[test]
    fn a_failed_update_leaves_no_factor() {
        let (_, mesh, model) = icosphere_model();
        let mut pc = Preconditioner::new(&model).unwrap();
        pc.update(&model, &mesh.vertices).unwrap();
        assert!(pc.is_factored());
        let mut torn = mesh.vertices.clone();
        torn[0] *= 5.0;
        assert!(matches!(
            pc.update(&model, &torn),
            Err(PreconditionError::Force(ForceError::LinkOverstretched { .. }))
        ));
        assert!(!pc.is_factored());
        let mut v = vec![DVec3::X; torn.len()];
        assert!(!pc.apply(&mut v));
        assert!(v.iter().all(|&a| a == DVec3::X));
        pc.update(&model, &mesh.vertices).unwrap();
        assert!(pc.apply(&mut v));
    }
}
