//! The pair-force loops, generic over the kernel (one compiled loop per kernel type), over
//! whether the virial is accumulated (`V`, so normal steps pay nothing) and over whether there is
//! a single particle type (`ONE`, which skips the type lookup).
//!
//! Both schemes produce results that do not depend on the number of threads: the work is split
//! into a fixed, thread-count-independent set of tasks (z-slabs or z-layers of cells), each task
//! adds in a fixed order, and partial virials are summed in task order.
//!
//! With Lees–Edwards boundaries ([`ShearImages`]) the pairs across the y boundary are left out
//! of both schemes and computed by a separate pass ([`shear_cross`]) in which each particle of
//! the first and last rows of cells sums its own cross-boundary pairs (so each such pair is
//! computed twice, once from each side). Its neighbour cells are the row across the boundary,
//! shifted in x by the offset δ, which is not a multiple of the cell size: four cells per row
//! cover the cutoff. The separation uses the image's shift `(k δ + m Lx, k Ly, n Lz)` and the
//! velocity difference the image's velocity `v_j + k U x̂`; both are formed so that the two
//! sides get exactly opposite values, and the force is odd in them, so Newton's third law holds
//! bit for bit here too.

use glam::{DMat3, DVec3};
use rayon::prelude::*;

use crate::cells::CellList;
use crate::kernel::{KernelTable, PairKernel};
use crate::rng::pair_xi;
use crate::{ForceScheme, Real};

/// What the pair loop needs of Lees–Edwards boundaries (see [`crate::PeriodicBox`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShearImages {
    /// Offset δ ∈ [0, Lx) of the image one period up in y.
    pub offset: Real,
    /// Shear velocity U: the x velocity of the image one period up.
    pub velocity: Real,
}

/// Whether the neighbour offset `dy` from row `y` of `ny` crosses the y boundary.
#[inline(always)]
fn crosses_y(y: usize, dy: i32, ny: usize) -> bool {
    (y == 0 && dy < 0) || (y + 1 == ny && dy > 0)
}

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
/// and returns the pair virial Σ_pairs r_ij ⊗ f_ij (zero unless `virial`). `shear` gives the
/// Lees–Edwards images of a sheared box (None: ordinary periodic boundaries).
pub fn compute<K: PairKernel>(
    scheme: ForceScheme,
    cl: &CellList,
    table: &KernelTable<K>,
    key: u64,
    sf: &mut Vec<DVec3>,
    virial: bool,
    shear: Option<ShearImages>,
) -> DMat3 {
    sf.clear();
    sf.resize(cl.pos.len(), DVec3::ZERO);
    let one = table.ntypes() == 1;
    let le = shear.is_some();
    let w = match (scheme, virial, one) {
        (ForceScheme::HalfShell, false, false) => half_shell::<K, false, false>(cl, table, key, sf, le),
        (ForceScheme::HalfShell, false, true) => half_shell::<K, false, true>(cl, table, key, sf, le),
        (ForceScheme::HalfShell, true, false) => half_shell::<K, true, false>(cl, table, key, sf, le),
        (ForceScheme::HalfShell, true, true) => half_shell::<K, true, true>(cl, table, key, sf, le),
        (ForceScheme::Gather, false, false) => gather::<K, false, false>(cl, table, key, sf, le),
        (ForceScheme::Gather, false, true) => gather::<K, false, true>(cl, table, key, sf, le),
        (ForceScheme::Gather, true, false) => gather::<K, true, false>(cl, table, key, sf, le),
        (ForceScheme::Gather, true, true) => gather::<K, true, true>(cl, table, key, sf, le),
    };
    match shear {
        None => w,
        Some(sh) => {
            w + match (virial, one) {
                (false, false) => shear_cross::<K, false, false>(cl, table, key, sf, sh),
                (false, true) => shear_cross::<K, false, true>(cl, table, key, sf, sh),
                (true, false) => shear_cross::<K, true, false>(cl, table, key, sf, sh),
                (true, true) => shear_cross::<K, true, true>(cl, table, key, sf, sh),
            }
        }
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
    le: bool,
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
            .map(|(s, mut w)| (s, slab::<K, V, ONE>(cl, table, key, layers(s), &mut w, le)))
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
            .map(|(s, mut w)| (s, slab::<K, V, ONE>(cl, table, key, layers(s), &mut w, le)))
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
    le: bool,
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
                    if le && crosses_y(y, d[1], ny) {
                        continue; // Lees–Edwards: done by `shear_cross`
                    }
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
    le: bool,
) -> DMat3 {
    per_layer(cl, sf, |z, off, w| {
        gather_layer::<K, V, ONE>(cl, table, key, z, off, w, le)
    })
}

/// Runs `task(z, offset, forces)` for every z-layer of cells in parallel, each on its own
/// contiguous part of the sorted force array (starting at sorted index `offset`), and sums the
/// returned virials in layer order (the same sum for any thread count).
fn per_layer(cl: &CellList, sf: &mut [DVec3], task: impl Fn(usize, usize, &mut [DVec3]) -> DMat3 + Sync) -> DMat3 {
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
    let out: Vec<DMat3> = tasks.into_par_iter().map(|(z, off, w)| task(z, off, w)).collect();
    out.iter().fold(DMat3::ZERO, |acc, m| acc + *m)
}

fn gather_layer<K: PairKernel, const V: bool, const ONE: bool>(
    cl: &CellList,
    table: &KernelTable<K>,
    key: u64,
    z: usize,
    off: usize,
    out: &mut [DVec3],
    le: bool,
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
                    if le && crosses_y(y, dy, ny) {
                        continue; // Lees–Edwards: done by `shear_cross`
                    }
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

// ------------------------------------------------------------------------------ Lees–Edwards

/// The pairs across the Lees–Edwards boundary (see the module docs), added to `sf`; tasks are
/// z-layers, each writing only the particles of its own first and last rows of cells.
fn shear_cross<K: PairKernel, const V: bool, const ONE: bool>(
    cl: &CellList,
    table: &KernelTable<K>,
    key: u64,
    sf: &mut [DVec3],
    sh: ShearImages,
) -> DMat3 {
    per_layer(cl, sf, |z, off, w| {
        shear_cross_layer::<K, V, ONE>(cl, table, key, z, off, w, sh)
    })
}

fn shear_cross_layer<K: PairKernel, const V: bool, const ONE: bool>(
    cl: &CellList,
    table: &KernelTable<K>,
    key: u64,
    z: usize,
    off: usize,
    out: &mut [DVec3],
    sh: ShearImages,
) -> DMat3 {
    let g = &cl.grid;
    let [nx, ny, nzc] = g.n;
    let l = g.lengths();
    let mut vir = DMat3::ZERO;
    // (sorted range, position shift, velocity shift)
    let mut nb = [(0usize, 0usize, DVec3::ZERO, DVec3::ZERO); 12];
    let mut hits = Hits::default();
    // Row 0 sees the last row one period down (k = −1); the last row sees row 0 one period up.
    for (y, yj, k) in [(0usize, ny - 1, -1.0f64), (ny - 1, 0usize, 1.0f64)] {
        let vsh = DVec3::new(k * sh.velocity, 0.0, 0.0);
        for x in 0..nx {
            let (s0, s1) = cl.range(g.index(x, y, z));
            if s0 == s1 {
                continue;
            }
            // The image of x_j is x_j + k δ: cells from floor(x − k δ/sx) − 1 to + 2 cover the
            // cutoff (cell size ≥ cutoff).
            let q0 = (x as Real - k * sh.offset / g.size.x).floor() as i64;
            let mut nnb = 0;
            let mut m = 0;
            for dz in -1i64..=1 {
                let mut zj = z as i64 + dz;
                let mut sz = 0.0;
                if zj < 0 {
                    zj += nzc as i64;
                    sz = -l.z;
                } else if zj >= nzc as i64 {
                    zj -= nzc as i64;
                    sz = l.z;
                }
                for q in q0 - 1..=q0 + 2 {
                    let wraps = q.div_euclid(nx as i64);
                    let xj = q.rem_euclid(nx as i64) as usize;
                    let (a, e) = cl.range(g.index(xj, yj, zj as usize));
                    if a == e {
                        continue;
                    }
                    let shift = DVec3::new(k * sh.offset + wraps as Real * l.x, k * l.y, sz);
                    nb[nnb] = (a, e, shift, vsh);
                    nnb += 1;
                    m += e - a;
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
                let mut fi = DVec3::ZERO;
                for &(a, e, shift, vshift) in &nb[..nnb] {
                    hits.n = 0;
                    hits.scan::<K, ONE>(row, cl, a, e, |pj| (pi - pj) - shift);
                    for &h in &hits.h[..hits.n] {
                        let j = h.j as usize;
                        let kern = if ONE { row[0] } else { row[cl.ptype[j] as usize] };
                        let xi = pair_xi(key, idi, cl.id[j]);
                        let f = kern.force(h.dr, h.r2, (vi - cl.vel[j]) - vshift, xi);
                        fi += f;
                        if V {
                            vir += outer(h.dr, f * 0.5);
                        }
                    }
                }
                out[i - off] += fi;
            }
        }
    }
    vir
}
