//! Cell lists: a counting sort of the particles into cells of edge ≥ the largest cutoff, and a
//! cell-ordered copy of what the pair loop reads (position, predicted velocity, type, id).
//!
//! Cells are numbered `c = x + nx (y + ny z)`, so a z-layer of cells is a contiguous range of the
//! sorted arrays; within a cell particles keep their storage order (the sort is stable), which
//! makes the pair order, and so the floating-point sums, a function of the positions only.

use glam::DVec3;
use rayon::prelude::*;

use crate::{EngineError, PeriodicBox, Real};

/// Entries past the last particle in the padded sorted arrays (≥ the pair loop's lanes − 1).
pub const PAD: usize = 16;

/// Smallest chunk of particles a rayon task gets in the O(N) passes.
pub(crate) const MIN_LEN: usize = 4096;

/// The grid of cells.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellGrid {
    /// Cells per axis (each ≥ 3).
    pub n: [usize; 3],
    /// Cell edge lengths (≥ cutoff).
    pub size: DVec3,
    inv_size: DVec3,
    lengths: DVec3,
}

impl CellGrid {
    /// The finest grid with cells no smaller than `cutoff`; needs ≥ 3 cells per axis.
    pub fn new(domain: &PeriodicBox, cutoff: Real) -> Result<Self, EngineError> {
        if !(cutoff.is_finite() && cutoff > 0.0) {
            return Err(EngineError::invalid("cutoff", format!("must be > 0, got {cutoff}")));
        }
        let l = domain.lengths();
        let mut n = [0usize; 3];
        for a in 0..3 {
            let c = (l[a] / cutoff).floor();
            if c < 3.0 {
                return Err(EngineError::invalid(
                    "box",
                    format!(
                        "edge {a} is {} but must be at least 3 cutoffs ({}) for the cell list",
                        l[a],
                        3.0 * cutoff
                    ),
                ));
            }
            if c > 1e6 {
                return Err(EngineError::invalid("box", "more than 10^6 cells along an axis"));
            }
            n[a] = c as usize;
        }
        if n[0].saturating_mul(n[1]).saturating_mul(n[2]) > (u32::MAX as usize) / 2 {
            return Err(EngineError::invalid("box", "too many cells"));
        }
        let size = DVec3::new(l.x / n[0] as Real, l.y / n[1] as Real, l.z / n[2] as Real);
        Ok(Self {
            n,
            size,
            inv_size: DVec3::ONE / size,
            lengths: l,
        })
    }

    /// The box edge lengths the grid divides.
    #[inline]
    pub fn lengths(&self) -> DVec3 {
        self.lengths
    }

    /// Total number of cells.
    #[inline]
    pub fn ncells(&self) -> usize {
        self.n[0] * self.n[1] * self.n[2]
    }

    /// Cell index of a position inside the box.
    #[inline(always)]
    pub fn cell_of(&self, p: DVec3) -> usize {
        let cx = ((p.x * self.inv_size.x) as usize).min(self.n[0] - 1);
        let cy = ((p.y * self.inv_size.y) as usize).min(self.n[1] - 1);
        let cz = ((p.z * self.inv_size.z) as usize).min(self.n[2] - 1);
        cx + self.n[0] * (cy + self.n[1] * cz)
    }

    /// Index of cell (x, y, z).
    #[inline(always)]
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        x + self.n[0] * (y + self.n[1] * z)
    }

    /// Neighbour of cell (x, y, z) at offset (dx, dy, dz) ∈ {−1, 0, 1}³ with the periodic shift
    /// to subtract from particle i's position: `dr = (x_i − shift) − x_j`.
    #[inline(always)]
    pub fn neighbour(&self, x: usize, y: usize, z: usize, d: [i32; 3]) -> (usize, DVec3) {
        let mut c = [0usize; 3];
        let mut shift = DVec3::ZERO;
        let p = [x as i64, y as i64, z as i64];
        for a in 0..3 {
            let mut q = p[a] + d[a] as i64;
            let n = self.n[a] as i64;
            if q < 0 {
                q += n;
                shift[a] = -self.lengths[a];
            } else if q >= n {
                q -= n;
                shift[a] = self.lengths[a];
            }
            c[a] = q as usize;
        }
        // Wrapping upward (q ≥ n) means j's image next to i is x_j + L, so
        // dr = x_i − (x_j + L) = (x_i − L) − x_j: the shift to subtract from x_i is +L.
        (self.index(c[0], c[1], c[2]), shift)
    }
}

/// A cell list with the cell-sorted copy of the particle data the pair loop reads.
#[derive(Debug, Clone)]
pub struct CellList {
    /// The grid.
    pub grid: CellGrid,
    /// `start[c]..start[c + 1]` are the sorted indices of cell c (length ncells + 1).
    pub start: Vec<u32>,
    /// Sorted index → storage index.
    pub perm: Vec<u32>,
    /// Sorted positions.
    pub pos: Vec<DVec3>,
    /// Sorted velocities used by the dissipative force (the predicted velocities).
    pub vel: Vec<DVec3>,
    /// Sorted positions as structure of arrays, for the vectorised distance test; each is
    /// padded with [`PAD`] zeros past the last particle so a chunk of lanes may read past a range.
    pub px: Vec<Real>,
    /// See [`CellList::px`].
    pub py: Vec<Real>,
    /// See [`CellList::px`].
    pub pz: Vec<Real>,
    /// Whether [`CellList::build`] fills [`CellList::px32`] etc. (true unless the owner knows
    /// that the pair loop will not read them).
    pub(crate) single: bool,
    /// Sorted positions in single precision (padded like [`CellList::px`]), for the
    /// vectorised prefilter of the distance test, whose hits are then tested again in double
    /// precision. Filled only when [`CellList::single`] is set.
    pub(crate) px32: Vec<f32>,
    /// See [`CellList::px32`].
    pub(crate) py32: Vec<f32>,
    /// See [`CellList::px32`].
    pub(crate) pz32: Vec<f32>,
    /// Sorted types (padded like [`CellList::px`], with type 0).
    pub ptype: Vec<u16>,
    /// Sorted ids.
    pub id: Vec<u32>,
    cell: Vec<u32>,
    inv: Vec<u32>,
}

impl CellList {
    /// An empty list on `grid`.
    pub fn new(grid: CellGrid) -> Self {
        Self {
            grid,
            start: vec![0; grid.ncells() + 1],
            perm: Vec::new(),
            pos: Vec::new(),
            px: Vec::new(),
            py: Vec::new(),
            pz: Vec::new(),
            single: true,
            px32: Vec::new(),
            py32: Vec::new(),
            pz32: Vec::new(),
            vel: Vec::new(),
            ptype: Vec::new(),
            id: Vec::new(),
            cell: Vec::new(),
            inv: Vec::new(),
        }
    }

    /// Sorts the particles into cells. `vel_of(i)` gives the velocity the dissipative force
    /// should see for storage index i. Positions must be inside the box. The per-particle
    /// passes run in parallel (rayon); the counting sort itself is sequential, so the order is
    /// the same for any thread count.
    pub fn build(&mut self, pos: &[DVec3], ptype: &[u16], id: &[u32], vel_of: impl Fn(usize) -> DVec3 + Sync) {
        let n = pos.len();
        let nc = self.grid.ncells();
        let grid = self.grid;
        self.cell.resize(n, 0);
        self.cell
            .par_iter_mut()
            .zip(pos.par_iter())
            .with_min_len(MIN_LEN)
            .for_each(|(c, p)| *c = grid.cell_of(*p) as u32);
        self.start.clear();
        self.start.resize(nc + 1, 0);
        for &c in &self.cell {
            self.start[c as usize + 1] += 1;
        }
        for c in 0..nc {
            self.start[c + 1] += self.start[c];
        }
        // Stable counting sort; `fill` is the running insertion point of each cell.
        self.perm.resize(n, 0);
        self.inv.resize(n, 0);
        let mut fill: Vec<u32> = self.start[..nc].to_vec();
        for (i, &c) in self.cell.iter().enumerate() {
            let k = fill[c as usize];
            self.perm[k as usize] = i as u32;
            self.inv[i] = k;
            fill[c as usize] = k + 1;
        }
        self.pos.resize(n, DVec3::ZERO);
        self.vel.resize(n, DVec3::ZERO);
        self.id.resize(n, 0);
        for a in [&mut self.px, &mut self.py, &mut self.pz] {
            a.resize(n + PAD, 0.0);
            a[n..].fill(0.0);
        }
        self.ptype.resize(n + PAD, 0);
        self.ptype[n..].fill(0);
        let perm = &self.perm;
        self.pos
            .par_iter_mut()
            .zip(self.px[..n].par_iter_mut())
            .zip(self.py[..n].par_iter_mut())
            .zip(self.pz[..n].par_iter_mut())
            .zip(self.vel.par_iter_mut())
            .zip(self.ptype[..n].par_iter_mut())
            .zip(self.id.par_iter_mut())
            .zip(perm.par_iter())
            .with_min_len(MIN_LEN)
            .for_each(|(((((((x, px), py), pz), v), t), d), &i)| {
                let i = i as usize;
                let p = pos[i];
                *x = p;
                (*px, *py, *pz) = (p.x, p.y, p.z);
                *v = vel_of(i);
                *t = ptype[i];
                *d = id[i];
            });
        if self.single {
            for (lo, hi) in [
                (&mut self.px32, &self.px),
                (&mut self.py32, &self.py),
                (&mut self.pz32, &self.pz),
            ] {
                lo.resize(n + PAD, 0.0);
                lo[n..].fill(0.0);
                lo[..n]
                    .par_chunks_mut(MIN_LEN)
                    .zip(hi[..n].par_chunks(MIN_LEN))
                    .for_each(|(lo, hi)| {
                        for (l, &h) in lo.iter_mut().zip(hi) {
                            *l = h as f32;
                        }
                    });
            }
        }
    }

    /// Storage index → sorted index (inverse of `perm`).
    #[inline]
    pub fn inverse(&self) -> &[u32] {
        &self.inv
    }

    /// Sorted range of cell c.
    #[inline(always)]
    pub fn range(&self, c: usize) -> (usize, usize) {
        (self.start[c] as usize, self.start[c + 1] as usize)
    }

    /// Sorted index where z-layer `z` starts (`z = nz` gives the particle count).
    #[inline]
    pub fn layer_start(&self, z: usize) -> usize {
        self.start[z * self.grid.n[0] * self.grid.n[1]] as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_checks_box() {
        let b = PeriodicBox::new(DVec3::new(3.0, 5.5, 2.9)).unwrap();
        assert!(CellGrid::new(&b, 1.0).is_err());
        let b = PeriodicBox::new(DVec3::new(3.0, 5.5, 4.0)).unwrap();
        let g = CellGrid::new(&b, 1.0).unwrap();
        assert_eq!(g.n, [3, 5, 4]);
        assert!(g.size.y >= 1.0);
    }

    #[test]
    fn neighbour_shift_gives_short_separation() {
        let b = PeriodicBox::new(DVec3::splat(4.0)).unwrap();
        let g = CellGrid::new(&b, 1.0).unwrap();
        // i in cell (3, 0, 0) near x = 4, j in cell (0, 0, 0) near x = 0: offset +1 in x wraps.
        let (c, s) = g.neighbour(3, 0, 0, [1, 0, 0]);
        assert_eq!(c, g.index(0, 0, 0));
        let xi = DVec3::new(3.9, 0.5, 0.5);
        let xj = DVec3::new(0.1, 0.5, 0.5);
        let dr = (xi - s) - xj;
        assert!((dr - DVec3::new(-0.2, 0.0, 0.0)).length() < 1e-12, "{dr}");
    }

    #[test]
    fn sort_is_stable_and_complete() {
        let b = PeriodicBox::new(DVec3::splat(3.0)).unwrap();
        let g = CellGrid::new(&b, 1.0).unwrap();
        let pos: Vec<DVec3> = (0..100)
            .map(|i| {
                let t = i as Real * 0.37;
                b.wrap(DVec3::new(t, 2.0 * t, 3.0 * t))
            })
            .collect();
        let ty = vec![0u16; 100];
        let id: Vec<u32> = (0..100).collect();
        let mut cl = CellList::new(g);
        cl.build(&pos, &ty, &id, |_| DVec3::ZERO);
        assert_eq!(cl.start[g.ncells()], 100);
        for c in 0..g.ncells() {
            let (a, e) = cl.range(c);
            for k in a..e {
                assert_eq!(g.cell_of(cl.pos[k]), c);
                if k > a {
                    assert!(cl.perm[k] > cl.perm[k - 1]);
                }
            }
        }
        let mut p = cl.perm.clone();
        p.sort();
        assert_eq!(p, id);
    }
}
