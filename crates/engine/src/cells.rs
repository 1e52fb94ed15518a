//! Cell lists: a counting sort of the particles into cells of edge ≥ the largest cutoff, and a
//! cell-ordered copy of what the pair loop reads (position, predicted velocity, type, id).
//!
//! Cells are numbered `c = x + nx (y + ny z)`, so a z-layer of cells is a contiguous range of the
//! sorted arrays; within a cell particles keep their storage order (the sort is stable), which
//! makes the pair order, and so the floating-point sums, a function of the positions only.

use glam::DVec3;
use rayon::prelude::*;

use crate::shared::SharedSlice;
use crate::{EngineError, PeriodicBox, Real};

/// Entries past the last particle in the padded sorted arrays (≥ the pair loop's lanes − 1).
pub const PAD: usize = 16;

/// Smallest chunk of particles a rayon task gets in the O(N) passes.
pub(crate) const MIN_LEN: usize = 4096;

/// Most blocks the counting sort splits the particles into. Each block keeps a count per cell,
/// and there are about N/3 cells at the standard density, so every block adds per-cell work of
/// the order of the sort's own per-particle work.
pub const SORT_BLOCKS_MAX: usize = 4;

/// Fewest particles per block of the counting sort.
const SORT_BLOCK_MIN: usize = 8192;

/// Cells per chunk of the sort's parallel prefix sum.
const CELL_CHUNK: usize = 4096;

/// Sorted indices per task of the sorted copy.
const COPY_CHUNK: usize = 2048;

/// How many sorted indices ahead the sorted copy, and the gather of the forces back to storage
/// order, prefetch their sources: enough to cover a miss to memory at 192,000 particles, where
/// the arrays outgrow the caches (docs/performance.md, "Changes tried").
pub(crate) const AHEAD: usize = 16;

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

/// One sorted particle's position (x, y, z), velocity (x, y, z) and id (the bits of the f64 at
/// index 6 are the id as u64), in one 64-byte aligned cache line: the vectorised force kernel
/// loads 8 partners' records and transposes them instead of gathering each quantity.
#[derive(Debug, Clone, Copy, Default)]
#[repr(C, align(64))]
pub(crate) struct Record(pub [Real; 8]);

impl Record {
    #[inline(always)]
    fn new(x: DVec3, v: DVec3, id: u32) -> Self {
        Self([x.x, x.y, x.z, v.x, v.y, v.z, f64::from_bits(id as u64), 0.0])
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
    /// Per sorted particle: position, velocity used by the dissipative force (the predicted
    /// velocity) and id ([`CellList::position`], [`CellList::velocity`], [`CellList::id`]).
    pub(crate) rec: Vec<Record>,
    /// Sorted positions as structure of arrays, for the vectorised distance test; each is
    /// padded with [`PAD`] zeros past the last particle so a chunk of lanes may read past a range.
    /// Empty after a build in which the owner skipped them (when the pair loop reads the
    /// positions only from the records: the AVX-512 one-type half shell without Lees–Edwards
    /// images).
    pub px: Vec<Real>,
    /// See [`CellList::px`].
    pub py: Vec<Real>,
    /// See [`CellList::px`].
    pub pz: Vec<Real>,
    /// Whether [`CellList::build`] fills [`CellList::px32`] etc. (true unless the owner knows
    /// that the pair loop will not read them).
    pub(crate) single: bool,
    /// Whether [`CellList::build`] fills [`CellList::px`], `py`, `pz` (true unless the owner
    /// knows that the pair loop reads the positions only from the records: the AVX-512
    /// one-type half shell without Lees–Edwards images, [`crate::pairs::reads_soa64`]). Always
    /// filled when [`CellList::single`] is not set.
    pub(crate) soa64: bool,
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
    cell: Vec<u32>,
    inv: Vec<u32>,
    /// Per block of the sort, its particle count per cell, then its running insertion point.
    hist: Vec<u32>,
    /// Per block, its histogram's sum per chunk of [`CELL_CHUNK`] cells.
    chunk_sum: Vec<u32>,
    /// Per chunk of cells, the sorted index where it starts.
    chunk_base: Vec<u32>,
    /// Per (cell, block), cell-major, where the block's particles of the cell start.
    off: Vec<u32>,
}

impl CellList {
    /// An empty list on `grid`.
    pub fn new(grid: CellGrid) -> Self {
        Self {
            grid,
            start: vec![0; grid.ncells() + 1],
            perm: Vec::new(),
            px: Vec::new(),
            py: Vec::new(),
            pz: Vec::new(),
            single: true,
            soa64: true,
            px32: Vec::new(),
            py32: Vec::new(),
            pz32: Vec::new(),
            rec: Vec::new(),
            ptype: Vec::new(),
            cell: Vec::new(),
            inv: Vec::new(),
            hist: Vec::new(),
            chunk_sum: Vec::new(),
            chunk_base: Vec::new(),
            off: Vec::new(),
        }
    }

    /// Sorts the particles into cells. `vel_of(i)` gives the velocity the dissipative force
    /// should see for storage index i. Positions must be inside the box.
    ///
    /// The sort is a stable counting sort run in parallel: the particles are split into up to
    /// [`SORT_BLOCKS_MAX`] blocks in storage order, each block counts its particles per cell, an
    /// exclusive prefix sum over (cell, block) gives every block its own insertion points, and
    /// each block places its particles. The result is the one order of a stable sort, so it is
    /// the same for any number of blocks or threads.
    pub fn build(&mut self, pos: &[DVec3], ptype: &[u16], id: &[u32], vel_of: impl Fn(usize) -> DVec3 + Sync) {
        self.build_prefetching(pos, ptype, id, vel_of, |_| {});
    }

    /// [`Self::build`], calling `prefetch(i)` a fixed distance (`AHEAD` places) before the sorted
    /// copy reads storage index i, so that the caller can prefetch what `vel_of(i)` will read (the
    /// position is prefetched here). Hints only: the result is that of `build`.
    pub fn build_prefetching(
        &mut self,
        pos: &[DVec3],
        ptype: &[u16],
        id: &[u32],
        vel_of: impl Fn(usize) -> DVec3 + Sync,
        prefetch: impl Fn(usize) + Sync,
    ) {
        let n = pos.len();
        assert!(ptype.len() == n && id.len() == n, "one type and id per position");
        assert!(n < u32::MAX as usize, "too many particles");
        let nc = self.grid.ncells();
        let grid = self.grid;
        if n == 0 {
            self.start.clear();
            self.start.resize(nc + 1, 0);
            for v in [&mut self.cell, &mut self.inv, &mut self.perm] {
                v.clear();
            }
            self.rec.clear();
            for a in [&mut self.px, &mut self.py, &mut self.pz] {
                a.clear();
                a.resize(PAD, 0.0);
            }
            for a in [&mut self.px32, &mut self.py32, &mut self.pz32] {
                a.clear();
                a.resize(if self.single { PAD } else { 0 }, 0.0);
            }
            self.ptype.clear();
            self.ptype.resize(PAD, 0);
            return;
        }
        let blocks = (n / SORT_BLOCK_MIN).clamp(1, rayon::current_num_threads().clamp(1, SORT_BLOCKS_MAX));
        // Block length, and the number of blocks that length really gives (≥ 1).
        let bl = n.div_ceil(blocks);
        let blocks = n.div_ceil(bl);
        let nq = nc.div_ceil(CELL_CHUNK);
        self.cell.resize(n, 0);
        self.inv.resize(n, 0);
        self.perm.resize(n, 0);
        self.hist.resize(blocks * nc, 0);
        self.chunk_sum.resize(blocks * nq, 0);
        // 1. Each block: its particles' cells, its histogram and the histogram's sum per chunk
        //    of cells.
        self.cell
            .par_chunks_mut(bl)
            .zip(pos.par_chunks(bl))
            .zip(self.hist.par_chunks_mut(nc))
            .zip(self.chunk_sum.par_chunks_mut(nq))
            .for_each(|(((cell, pos), hist), sums)| {
                hist.fill(0);
                for (c, p) in cell.iter_mut().zip(pos) {
                    let k = grid.cell_of(*p);
                    *c = k as u32;
                    hist[k] += 1;
                }
                for (s, h) in sums.iter_mut().zip(hist.chunks(CELL_CHUNK)) {
                    *s = h.iter().sum();
                }
            });
        // 2. Where each chunk of cells starts (sequential over the few chunks).
        self.chunk_base.clear();
        let mut run = 0u32;
        for q in 0..nq {
            self.chunk_base.push(run);
            run += (0..blocks).map(|b| self.chunk_sum[b * nq + q]).sum::<u32>();
        }
        // 3. Per cell: where it starts, and where each block's particles of it start.
        self.start.resize(nc + 1, 0);
        self.start[nc] = n as u32;
        self.off.resize(nc * blocks, 0);
        {
            let (hist, base) = (&self.hist, &self.chunk_base);
            self.start[..nc]
                .par_chunks_mut(CELL_CHUNK)
                .zip(self.off.par_chunks_mut(CELL_CHUNK * blocks))
                .enumerate()
                .for_each(|(q, (start, off))| {
                    let c0 = q * CELL_CHUNK;
                    let mut run = base[q];
                    for (dc, (s, o)) in start.iter_mut().zip(off.chunks_mut(blocks)).enumerate() {
                        *s = run;
                        for (b, o) in o.iter_mut().enumerate() {
                            *o = run;
                            run += hist[b * nc + c0 + dc];
                        }
                    }
                });
        }
        // 4. Each block places its particles, in storage order, at its own insertion points.
        {
            let off = &self.off;
            let perm = SharedSlice::new(&mut self.perm);
            self.inv
                .par_chunks_mut(bl)
                .zip(self.cell.par_chunks(bl))
                .zip(self.hist.par_chunks_mut(nc))
                .enumerate()
                .for_each(|(b, ((inv, cell), fill))| {
                    for (c, f) in fill.iter_mut().enumerate() {
                        *f = off[c * blocks + b];
                    }
                    let i0 = b * bl;
                    for (di, (v, &c)) in inv.iter_mut().zip(cell).enumerate() {
                        let k = fill[c as usize];
                        fill[c as usize] = k + 1;
                        *v = k;
                        // SAFETY: the insertion points of (cell, block) pairs are disjoint
                        // intervals that tile 0..n (step 3), and each block advances only its
                        // own, so every sorted index is written by exactly one block, once.
                        #[allow(unsafe_code)]
                        unsafe {
                            perm.write(k as usize, (i0 + di) as u32)
                        };
                    }
                });
        }
        // 5. The sorted copies (a parallel gather): the records and types, then from the records
        //    the positions as structure of arrays, in double and/or single precision as wanted.
        let (single, soa64) = (self.single, self.soa64 || !self.single);
        self.rec.resize(n, Record::default());
        self.ptype.resize(n + PAD, 0);
        self.ptype[n..].fill(0);
        for (a, on) in [(&mut self.px, soa64), (&mut self.py, soa64), (&mut self.pz, soa64)] {
            a.resize(if on { n + PAD } else { 0 }, 0.0);
            a.iter_mut().skip(n).for_each(|x| *x = 0.0);
        }
        for a in [&mut self.px32, &mut self.py32, &mut self.pz32] {
            a.resize(if single { n + PAD } else { 0 }, 0.0);
            a.iter_mut().skip(n).for_each(|x| *x = 0.0);
        }
        let perm = &self.perm;
        let gather = |k0: usize, rec: &mut [Record], t: &mut [u16]| {
            for (dk, (r, t)) in rec.iter_mut().zip(t.iter_mut()).enumerate() {
                if let Some(&a) = perm.get(k0 + dk + AHEAD) {
                    let a = a as usize;
                    crate::shared::prefetch(pos, a);
                    prefetch(a);
                }
                let i = perm[k0 + dk] as usize;
                *r = Record::new(pos[i], vel_of(i), id[i]);
                *t = ptype[i];
            }
        };
        let soa = |rec: &[Record], p64: Option<[&mut [Real]; 3]>, p32: Option<[&mut [f32]; 3]>| {
            if let Some(p) = p64 {
                for (c, p) in p.into_iter().enumerate() {
                    for (x, r) in p.iter_mut().zip(rec) {
                        *x = r.0[c];
                    }
                }
            }
            if let Some(p) = p32 {
                for (c, p) in p.into_iter().enumerate() {
                    for (x, r) in p.iter_mut().zip(rec) {
                        *x = r.0[c] as f32;
                    }
                }
            }
        };
        let chunks = self
            .rec
            .par_chunks_mut(COPY_CHUNK)
            .zip(self.ptype[..n].par_chunks_mut(COPY_CHUNK))
            .enumerate();
        fn first<T: Send>(a: &mut [T], n: usize) -> rayon::slice::ChunksMut<'_, T> {
            a[..n].par_chunks_mut(COPY_CHUNK)
        }
        let (n64, n32) = (if soa64 { n } else { 0 }, if single { n } else { 0 });
        let [x64, y64, z64] = [&mut self.px, &mut self.py, &mut self.pz];
        let [x32, y32, z32] = [&mut self.px32, &mut self.py32, &mut self.pz32];
        match (soa64, single) {
            (true, true) => chunks
                .zip(first(x64, n64).zip(first(y64, n64)).zip(first(z64, n64)))
                .zip(first(x32, n32).zip(first(y32, n32)).zip(first(z32, n32)))
                .for_each(|(((q, (r, t)), ((x, y), z)), ((lx, ly), lz))| {
                    gather(q * COPY_CHUNK, r, t);
                    soa(r, Some([x, y, z]), Some([lx, ly, lz]));
                }),
            (true, false) => chunks
                .zip(first(x64, n64).zip(first(y64, n64)).zip(first(z64, n64)))
                .for_each(|((q, (r, t)), ((x, y), z))| {
                    gather(q * COPY_CHUNK, r, t);
                    soa(r, Some([x, y, z]), None);
                }),
            (false, _) => chunks
                .zip(first(x32, n32).zip(first(y32, n32)).zip(first(z32, n32)))
                .for_each(|((q, (r, t)), ((lx, ly), lz))| {
                    gather(q * COPY_CHUNK, r, t);
                    soa(r, None, Some([lx, ly, lz]));
                }),
        }
    }

    /// The number of particles in the list.
    #[inline]
    pub fn len(&self) -> usize {
        self.rec.len()
    }

    /// Whether the list holds no particles.
    #[inline]
    pub fn is_empty(&self) -> bool {
        self.rec.is_empty()
    }

    /// Position of sorted particle k.
    #[inline(always)]
    pub fn position(&self, k: usize) -> DVec3 {
        let r = &self.rec[k].0;
        DVec3::new(r[0], r[1], r[2])
    }

    /// Velocity of sorted particle k for the dissipative force (the `vel_of` of the build).
    #[inline(always)]
    pub fn velocity(&self, k: usize) -> DVec3 {
        let r = &self.rec[k].0;
        DVec3::new(r[3], r[4], r[5])
    }

    /// Id of sorted particle k.
    #[inline(always)]
    pub fn id(&self, k: usize) -> u32 {
        self.rec[k].0[6].to_bits() as u32
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
                assert_eq!(g.cell_of(cl.position(k)), c);
                if k > a {
                    assert!(cl.perm[k] > cl.perm[k - 1]);
                }
            }
        }
        let mut p = cl.perm.clone();
        p.sort();
        assert_eq!(p, id);
    }

    #[test]
    fn an_empty_box_has_empty_cells() {
        let b = PeriodicBox::new(DVec3::splat(3.0)).unwrap();
        let mut cl = CellList::new(CellGrid::new(&b, 1.0).unwrap());
        let one = [DVec3::splat(1.5)];
        cl.build(&one, &[0], &[0], |_| DVec3::ZERO);
        cl.build(&[], &[], &[], |_| DVec3::ZERO);
        assert!(cl.start.iter().all(|&s| s == 0) && cl.perm.is_empty() && cl.is_empty());
    }

    /// The parallel counting sort gives the one stable order for any number of blocks: against a
    /// sequential stable sort by cell, with 1 to 4 threads (so 1 to 4 blocks) and a thread count
    /// that does not divide the particles evenly, on storage that is partly in cell order.
    #[test]
    fn parallel_sort_equals_the_sequential_stable_sort() {
        use rand_xoshiro::rand_core::{RngCore, SeedableRng};
        let b = PeriodicBox::new(DVec3::new(23.0, 17.0, 29.0)).unwrap();
        let g = CellGrid::new(&b, 1.0).unwrap();
        let n = 4 * SORT_BLOCK_MIN + 777;
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(5);
        let mut u = || (rng.next_u64() >> 11) as Real / (1u64 << 53) as Real;
        let mut pos: Vec<DVec3> = (0..n).map(|_| DVec3::new(u() * 23.0, u() * 17.0, u() * 29.0)).collect();
        // The first half in cell order, as after a storage sort; the rest random.
        pos[..n / 2].sort_by_key(|p| g.cell_of(*p));
        let ty: Vec<u16> = (0..n).map(|i| (i % 3) as u16).collect();
        let id: Vec<u32> = (0..n as u32).rev().collect();
        let vel: Vec<DVec3> = (0..n).map(|i| DVec3::splat(i as Real)).collect();
        let mut want: Vec<u32> = (0..n as u32).collect();
        want.sort_by_key(|&i| g.cell_of(pos[i as usize])); // stable
        for threads in 1..=4 {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let mut cl = CellList::new(g);
            // Twice, so that the second build reuses (and must reset) the first one's buffers.
            for _ in 0..2 {
                pool.install(|| cl.build(&pos, &ty, &id, |i| vel[i]));
            }
            assert_eq!(cl.perm, want, "{threads} threads");
            for (k, &i) in cl.perm.iter().enumerate() {
                let i = i as usize;
                assert_eq!(cl.inverse()[i] as usize, k);
                assert_eq!(
                    (cl.position(k), cl.velocity(k), cl.ptype[k], cl.id(k)),
                    (pos[i], vel[i], ty[i], id[i])
                );
                assert_eq!((cl.px[k], cl.py[k], cl.pz[k]), (pos[i].x, pos[i].y, pos[i].z));
                assert_eq!(
                    (cl.px32[k], cl.py32[k], cl.pz32[k]),
                    (pos[i].x as f32, pos[i].y as f32, pos[i].z as f32)
                );
            }
            for c in 0..g.ncells() {
                let (a, e) = cl.range(c);
                assert!((a..e).all(|k| g.cell_of(cl.position(k)) == c));
            }
            assert_eq!(cl.start[g.ncells()] as usize, n);
            assert!(cl.ptype[n..].iter().all(|&t| t == 0) && cl.px[n..].iter().all(|&x| x == 0.0));
        }
    }
}
