//! The pair-force loops, generic over the kernel (one compiled loop per kernel type), over
//! whether the virial is accumulated (`V`, so normal steps pay nothing) and over whether there is
//! a single particle type (`ONE`, which skips the type lookup).
//!
//! Both schemes produce results that do not depend on the number of threads: the work is split
//! into a fixed, thread-count-independent set of tasks (z-slabs or z-layers of cells), each task
//! adds in a fixed order, and partial virials are summed in task order.

use glam::{DMat3, DVec3};
use rayon::prelude::*;

use crate::cells::CellList;
use crate::kernel::{KernelTable, PairKernel};
use crate::rng::pair_xi;
use crate::ForceScheme;

/// The 13 forward neighbour offsets of the half shell (dz = 1: all 9; dz = 0: dy = 1, or
/// dy = 0 and dx = 1). Together with the pairs inside a cell they visit each pair once.
const HALF: [[i32; 3]; 13] = [
    [1, 0, 0],
    [-1, 1, 0],
    [0, 1, 0],
    [1, 1, 0],
    [-1, -1, 1],
    [0, -1, 1],
    [1, -1, 1],
    [-1, 0, 1],
    [0, 0, 1],
    [1, 0, 1],
    [-1, 1, 1],
    [0, 1, 1],
    [1, 1, 1],
];

#[inline(always)]
fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// A candidate pair that passed the distance test: sorted index j, separation, r².
#[derive(Clone, Copy, Default)]
struct Hit {
    dr: DVec3,
    r2: f64,
    j: u32,
}

/// The hits of one particle i.
#[derive(Default)]
struct Hits {
    h: Vec<Hit>,
    n: usize,
}

impl Hits {
    /// Makes room for `m` candidates (the branch-free append writes one slot past the last hit).
    #[inline]
    fn reserve(&mut self, m: usize) {
        if self.h.len() < m + 1 {
            self.h.resize(m + 1, Hit::default());
        }
    }

    /// Distance test of i against sorted particles `a..e`, appended without a data-dependent
    /// branch (the cutoff test is ~30% true and would mispredict a lot). `sep(j)` gives
    /// x_i − x_j for the right periodic image.
    #[inline(always)]
    fn scan<K: PairKernel, const ONE: bool>(
        &mut self,
        row: &[K],
        cl: &CellList,
        a: usize,
        e: usize,
        sep: impl Fn(DVec3) -> DVec3,
    ) {
        let mut n = self.n;
        let rc2_one = row[0].cutoff2();
        let h = &mut self.h[..];
        for (j, pj) in cl.pos[a..e].iter().enumerate() {
            let dr = sep(*pj);
            let r2 = dr.length_squared();
            let rc2 = if ONE {
                rc2_one
            } else {
                row[cl.ptype[a + j] as usize].cutoff2()
            };
            h[n] = Hit {
                dr,
                r2,
                j: (a + j) as u32,
            };
            n += ((r2 < rc2) & (r2 > 0.0)) as usize;
        }
        self.n = n;
    }
}

/// Force from the k-th hit on i.
#[inline(always)]
fn hit_force<K: PairKernel, const ONE: bool>(
    row: &[K],
    cl: &CellList,
    key: u64,
    vi: DVec3,
    idi: u32,
    h: Hit,
) -> (usize, DVec3, DVec3) {
    let j = h.j as usize;
    let kern = if ONE { row[0] } else { row[cl.ptype[j] as usize] };
    let xi = pair_xi(key, idi, cl.id[j]);
    (j, h.dr, kern.force(h.dr, h.r2, vi - cl.vel[j], xi))
}

/// Appends the neighbour cell range `(a, e, shift)` to `nb[..*len]`, merging it into the previous
/// entry when contiguous in the sorted arrays with the same shift (the cells x−1, x, x+1 of a
/// row are adjacent unless the row wraps). Visiting order is unchanged, so results are too.
#[inline(always)]
fn push_range(nb: &mut [(usize, usize, DVec3)], len: &mut usize, a: usize, e: usize, sh: DVec3) {
    if a == e {
        return;
    }
    if *len > 0 {
        let last = &mut nb[*len - 1];
        if last.1 == a && last.2 == sh {
            last.1 = e;
            return;
        }
    }
    nb[*len] = (a, e, sh);
    *len += 1;
}

/// Computes the pair forces of the cell-sorted particles into `sf` (sorted order, overwritten)
/// and returns the pair virial Σ_pairs r_ij ⊗ f_ij (zero unless `virial`).
pub fn compute<K: PairKernel>(
    scheme: ForceScheme,
    cl: &CellList,
    table: &KernelTable<K>,
    key: u64,
    sf: &mut Vec<DVec3>,
    virial: bool,
) -> DMat3 {
    sf.clear();
    sf.resize(cl.pos.len(), DVec3::ZERO);
    let one = table.ntypes() == 1;
    match (scheme, virial, one) {
        (ForceScheme::HalfShell, false, false) => half_shell::<K, false, false>(cl, table, key, sf),
        (ForceScheme::HalfShell, false, true) => half_shell::<K, false, true>(cl, table, key, sf),
        (ForceScheme::HalfShell, true, false) => half_shell::<K, true, false>(cl, table, key, sf),
        (ForceScheme::HalfShell, true, true) => half_shell::<K, true, true>(cl, table, key, sf),
        (ForceScheme::Gather, false, false) => gather::<K, false, false>(cl, table, key, sf),
        (ForceScheme::Gather, false, true) => gather::<K, false, true>(cl, table, key, sf),
        (ForceScheme::Gather, true, false) => gather::<K, true, false>(cl, table, key, sf),
        (ForceScheme::Gather, true, true) => gather::<K, true, true>(cl, table, key, sf),
    }
}

// ------------------------------------------------------------------------------- half shell

/// Up to two disjoint windows of the sorted force array that one slab task may write: its own
/// slab and the next one (the next one wraps to slab 0 for the last slab).
struct Win<'a> {
    a: &'a mut [DVec3],
    a0: usize,
    b: &'a mut [DVec3],
    b0: usize,
}

impl Win<'_> {
    #[inline(always)]
    fn add(&mut self, k: usize, f: DVec3) {
        let ka = k.wrapping_sub(self.a0);
        if ka < self.a.len() {
            self.a[ka] += f;
        } else {
            self.b[k - self.b0] += f;
        }
    }
}

/// Slabs are single z-layers of cells, except that with an odd layer count the last slab holds
/// the last two layers, so the slab count is even. Phase 1 runs the even slabs in parallel, phase
/// 2 the odd ones; a slab writes only to itself and the next slab, so no two concurrent tasks
/// share a particle, and each particle's sum has the same order whatever the thread count.
fn half_shell<K: PairKernel, const V: bool, const ONE: bool>(
    cl: &CellList,
    table: &KernelTable<K>,
    key: u64,
    sf: &mut [DVec3],
) -> DMat3 {
    let nz = cl.grid.n[2];
    let nslab = if nz % 2 == 0 { nz } else { nz - 1 };
    let n = sf.len();
    let b: Vec<usize> = (0..=nslab)
        .map(|s| if s < nslab { cl.layer_start(s) } else { n })
        .collect();
    let layers = |s: usize| (s, if s + 1 == nslab { nz } else { s + 1 });
    let mut vir = vec![DMat3::ZERO; nslab];

    // Phase 1: even slabs; slab 2k writes [b(2k), b(2k+2)), contiguous and disjoint.
    {
        let mut tasks = Vec::with_capacity(nslab / 2);
        let mut rest: &mut [DVec3] = sf;
        let mut off = 0;
        for s in (0..nslab).step_by(2) {
            let end = b[s + 2];
            let (w, r) = rest.split_at_mut(end - off);
            tasks.push((
                s,
                Win {
                    a: w,
                    a0: off,
                    b: &mut [],
                    b0: 0,
                },
            ));
            rest = r;
            off = end;
        }
        let out: Vec<(usize, DMat3)> = tasks
            .into_par_iter()
            .map(|(s, mut w)| (s, slab::<K, V, ONE>(cl, table, key, layers(s), &mut w)))
            .collect();
        for (s, m) in out {
            vir[s] = m;
        }
    }
    // Phase 2: odd slabs; slab 2k+1 writes [b(2k+1), b(2k+3)); the last one wraps to slab 0.
    {
        let (head, mut rest) = sf.split_at_mut(b[1]);
        let mut head = Some(head);
        let mut off = b[1];
        let mut tasks = Vec::with_capacity(nslab / 2);
        for s in (1..nslab).step_by(2) {
            let last = s + 1 == nslab;
            let end = if last { n } else { b[s + 2] };
            let (w, r) = rest.split_at_mut(end - off);
            let win = if last {
                Win {
                    a: w,
                    a0: off,
                    b: head.take().unwrap_or_default(),
                    b0: 0,
                }
            } else {
                Win {
                    a: w,
                    a0: off,
                    b: &mut [],
                    b0: 0,
                }
            };
            tasks.push((s, win));
            rest = r;
            off = end;
        }
        let out: Vec<(usize, DMat3)> = tasks
            .into_par_iter()
            .map(|(s, mut w)| (s, slab::<K, V, ONE>(cl, table, key, layers(s), &mut w)))
            .collect();
        for (s, m) in out {
            vir[s] = m;
        }
    }
    vir.iter().fold(DMat3::ZERO, |acc, m| acc + *m)
}

fn slab<K: PairKernel, const V: bool, const ONE: bool>(
    cl: &CellList,
    table: &KernelTable<K>,
    key: u64,
    (z0, z1): (usize, usize),
    win: &mut Win<'_>,
) -> DMat3 {
    let g = &cl.grid;
    let [nx, ny, _] = g.n;
    let mut vir = DMat3::ZERO;
    let mut nb = [(0usize, 0usize, DVec3::ZERO); 13];
    let mut hits = Hits::default();
    for z in z0..z1 {
        for y in 0..ny {
            for x in 0..nx {
                let (s0, s1) = cl.range(g.index(x, y, z));
                if s0 == s1 {
                    continue;
                }
                let mut m = s1 - s0;
                let mut nnb = 0;
                for d in HALF.iter() {
                    let (c, sh) = g.neighbour(x, y, z, *d);
                    let (a, e) = cl.range(c);
                    push_range(&mut nb, &mut nnb, a, e, sh);
                    m += e - a;
                }
                hits.reserve(m);
                for i in s0..s1 {
                    let pi = cl.pos[i];
                    let vi = cl.vel[i];
                    let idi = cl.id[i];
                    let row = if ONE {
                        table.row(0)
                    } else {
                        table.row(cl.ptype[i] as usize)
                    };
                    hits.n = 0;
                    hits.scan::<K, ONE>(row, cl, i + 1, s1, |pj| pi - pj);
                    for &(a, e, sh) in &nb[..nnb] {
                        let pis = pi - sh;
                        hits.scan::<K, ONE>(row, cl, a, e, |pj| pis - pj);
                    }
                    let mut fi = DVec3::ZERO;
                    for &h in &hits.h[..hits.n] {
                        let (j, dr, f) = hit_force::<K, ONE>(row, cl, key, vi, idi, h);
                        fi += f;
                        win.add(j, -f);
                        if V {
                            vir += outer(dr, f);
                        }
                    }
                    win.add(i, fi);
                }
            }
        }
    }
    vir
}

// ----------------------------------------------------------------------------------- gather

/// Every particle sums its own pairs over the 27 neighbour cells; tasks are z-layers, each
/// writing only its own contiguous part of the sorted force array.
fn gather<K: PairKernel, const V: bool, const ONE: bool>(
    cl: &CellList,
    table: &KernelTable<K>,
    key: u64,
    sf: &mut [DVec3],
) -> DMat3 {
    let nz = cl.grid.n[2];
    let mut tasks = Vec::with_capacity(nz);
    let mut rest: &mut [DVec3] = sf;
    let mut off = 0;
    for z in 0..nz {
        let end = cl.layer_start(z + 1);
        let (w, r) = rest.split_at_mut(end - off);
        tasks.push((z, off, w));
        rest = r;
        off = end;
    }
    let out: Vec<DMat3> = tasks
        .into_par_iter()
        .map(|(z, off, w)| gather_layer::<K, V, ONE>(cl, table, key, z, off, w))
        .collect();
    out.iter().fold(DMat3::ZERO, |acc, m| acc + *m)
}

fn gather_layer<K: PairKernel, const V: bool, const ONE: bool>(
    cl: &CellList,
    table: &KernelTable<K>,
    key: u64,
    z: usize,
    off: usize,
    out: &mut [DVec3],
) -> DMat3 {
    let g = &cl.grid;
    let [nx, ny, _] = g.n;
    let mut vir = DMat3::ZERO;
    let mut nb = [(0usize, 0usize, DVec3::ZERO); 27];
    let mut hits = Hits::default();
    for y in 0..ny {
        for x in 0..nx {
            let (s0, s1) = cl.range(g.index(x, y, z));
            if s0 == s1 {
                continue;
            }
            let mut nnb = 0;
            let mut m = 0;
            for dz in -1..=1 {
                for dy in -1..=1 {
                    for dx in -1..=1 {
                        let (c, sh) = g.neighbour(x, y, z, [dx, dy, dz]);
                        let (a, e) = cl.range(c);
                        push_range(&mut nb, &mut nnb, a, e, sh);
                        m += e - a;
                    }
                }
            }
            hits.reserve(m);
            for i in s0..s1 {
                let pi = cl.pos[i];
                let vi = cl.vel[i];
                let idi = cl.id[i];
                let row = if ONE {
                    table.row(0)
                } else {
                    table.row(cl.ptype[i] as usize)
                };
                hits.n = 0;
                for &(a, e, sh) in &nb[..nnb] {
                    if sh == DVec3::ZERO {
                        // j == i gives r² = 0 and is skipped.
                        hits.scan::<K, ONE>(row, cl, a, e, |pj| pi - pj);
                    } else {
                        // Across the boundary: dr = (x_i − x_j) − shift is exactly the negative
                        // of what j computes for i, so Newton's third law holds bit for bit.
                        hits.scan::<K, ONE>(row, cl, a, e, |pj| (pi - pj) - sh);
                    }
                }
                let mut fi = DVec3::ZERO;
                for &h in &hits.h[..hits.n] {
                    let (_, dr, f) = hit_force::<K, ONE>(row, cl, key, vi, idi, h);
                    fi += f;
                    if V {
                        vir += outer(dr, f * 0.5);
                    }
                }
                out[i - off] = fi;
            }
        }
    }
    vir
}
