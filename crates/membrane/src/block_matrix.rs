//! A symmetric 3N × 3N matrix stored as 3 × 3 blocks on a fixed sparsity pattern of vertex
//! pairs: what the Gauss–Newton Hessian of the membrane terms (`forces/hessian.rs`) is
//! assembled into and what the stretching preconditioner (`precondition.rs`) factorises.

use glam::{DMat3, DVec3};

/// a bᵀ.
#[inline]
pub(crate) fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// A symmetric matrix of 3 × 3 blocks on a fixed pattern of vertex pairs; only the blocks
/// (i, j) with i ≥ j are stored, block (i, j) holding rows 3i..3i+3 and columns 3j..3j+3.
pub(crate) struct BlockMatrix {
    /// For column block j, its row blocks are `rows[start[j]..start[j + 1]]`, ascending, the
    /// first being j itself.
    pub(crate) start: Vec<usize>,
    pub(crate) rows: Vec<u32>,
    pub(crate) blocks: Vec<DMat3>,
}

impl BlockMatrix {
    /// The pattern: every diagonal block and the blocks of `pairs` (either order, repeats allowed).
    pub(crate) fn new(n: usize, pairs: impl Iterator<Item = (u32, u32)>) -> Self {
        let mut lists: Vec<Vec<u32>> = (0..n as u32).map(|j| vec![j]).collect();
        for (a, b) in pairs {
            let (i, j) = if a >= b { (a, b) } else { (b, a) };
            lists[j as usize].push(i);
        }
        let mut start = Vec::with_capacity(n + 1);
        let mut rows = Vec::new();
        start.push(0);
        for mut l in lists {
            l.sort_unstable();
            l.dedup();
            rows.extend(l);
            start.push(rows.len());
        }
        let blocks = vec![DMat3::ZERO; rows.len()];
        Self { start, rows, blocks }
    }

    pub(crate) fn n(&self) -> usize {
        self.start.len() - 1
    }

    pub(crate) fn clear(&mut self) {
        self.blocks.iter_mut().for_each(|b| *b = DMat3::ZERO);
    }

    /// Index of block (i, j), i ≥ j; the pair must be in the pattern.
    #[inline]
    fn find(&self, i: usize, j: usize) -> usize {
        let (s, e) = (self.start[j], self.start[j + 1]);
        match self.rows[s..e].binary_search(&(i as u32)) {
            Ok(k) => s + k,
            Err(_) => panic!("block ({i}, {j}) is not in the pattern"),
        }
    }

    /// H_ij += m (and so H_ji += mᵀ). A diagonal m must be symmetric.
    #[inline]
    pub(crate) fn add(&mut self, i: usize, j: usize, m: DMat3) {
        if i >= j {
            let k = self.find(i, j);
            self.blocks[k] += m;
        } else {
            let k = self.find(j, i);
            self.blocks[k] += m.transpose();
        }
    }

    /// The dense 3N × 3N matrix (both triangles), for tests.
    #[cfg(test)]
    pub(crate) fn to_dense(&self) -> Vec<Vec<f64>> {
        let n = self.n();
        let mut m = vec![vec![0.0; 3 * n]; 3 * n];
        for j in 0..n {
            for k in self.start[j]..self.start[j + 1] {
                let i = self.rows[k] as usize;
                for r in 0..3 {
                    for c in 0..3 {
                        let v = self.blocks[k].col(c)[r];
                        m[3 * i + r][3 * j + c] = v;
                        m[3 * j + c][3 * i + r] = v;
                    }
                }
            }
        }
        m
    }

    /// H += c Σ_ab g_a g_bᵀ over the vertices `idx` (distinct) with gradients `g`.
    #[inline]
    pub(crate) fn add_outer(&mut self, idx: &[usize], g: &[DVec3], c: f64) {
        for (a, &ia) in idx.iter().enumerate() {
            for (b, &ib) in idx.iter().enumerate() {
                if ia >= ib {
                    let k = self.find(ia, ib);
                    self.blocks[k] += outer(g[a] * c, g[b]);
                }
            }
        }
    }
}
