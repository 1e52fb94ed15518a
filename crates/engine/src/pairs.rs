//! The pair-force loops, generic over the kernel (one compiled loop per kernel type), over
//! whether the virial is accumulated (`V`, so normal steps pay nothing) and over whether there is
//! a single particle type (`ONE`, which skips the type lookup).
//!
//! Both schemes produce results that do not depend on the number of threads: the work is split
//! into a fixed, thread-count-independent set of tasks (z-slabs or z-layers of cells), each task
//! adds in a fixed order, and partial virials are summed in task order.
//!
//! With Lees–Edwards boundaries ([`ShearImages`]) the pairs across the y boundary are left out
//! of both schemes and computed by a separate pass (`shear_cross`) in which each particle of
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
use crate::shared::SharedSlice;
use crate::simd;
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

/// The most lanes of the distance test: candidates are tested up to `LANES` at a time on the
/// structure-of-arrays positions (the sorted arrays are padded so a chunk may read past the end
/// of a range).
pub(crate) const LANES: usize = 8;
/// The bits of a tagged hit index that hold the sorted index ([`simd::scan_cell_avx512`]).
#[cfg(target_arch = "x86_64")]
const TAG_LOW: u32 = (1 << simd::TAG_SHIFT) - 1;
/// The bits of a cell stream's hit that hold the sorted index ([`simd::stream_cell_hits_avx512`]).
#[cfg(target_arch = "x86_64")]
const SLOT_LOW: u32 = (1 << simd::SLOT_SHIFT) - 1;
const _: () = assert!(crate::cells::PAD + 1 >= LANES);

/// The candidates of one particle i that passed the distance test: `h.j[..n]` (sorted indices)
/// with their separations `h.dx, h.dy, h.dz` and `h.r2`.
#[derive(Default)]
struct Hits {
    h: simd::HitArrays,
    n: usize,
}

impl Hits {
    /// Makes room for `m` candidates (an append writes up to a chunk past the last hit).
    #[inline]
    fn reserve(&mut self, m: usize) {
        self.h.reserve(m + LANES);
    }

    /// Separation and r² of hit k.
    #[inline(always)]
    fn get(&self, k: usize) -> (usize, DVec3, Real) {
        let h = &self.h;
        (h.j[k] as usize, DVec3::new(h.dx[k], h.dy[k], h.dz[k]), h.r2[k])
    }

    /// Distance test of i against sorted particles `a..e`, `LANES` candidates at a time, appended
    /// without a data-dependent branch (the cutoff test is ~30% true and would mispredict a lot).
    /// The separation is `p − x_j` (`POST = false`, `p` already shifted) or `(p − x_j) − sh`
    /// (`POST = true`), component by component, and r² = (dx² + dy²) + dz² as `DVec3::dot`.
    #[inline(always)]
    fn scan<const ONE: bool, const POST: bool>(
        &mut self,
        (rc2_row, uniform): (&[Real], Option<Real>),
        cl: &CellList,
        isa: Isa,
        a: usize,
        e: usize,
        p: DVec3,
        sh: DVec3,
    ) {
        #[cfg(target_arch = "x86_64")]
        if isa != Isa::Portable {
            let cutoff = match (ONE, uniform) {
                (true, _) => simd::Cutoff::One(rc2_row[0]),
                (false, Some(c)) => simd::Cutoff::One(c),
                (false, None) => simd::Cutoff::PerType {
                    ptype: &cl.ptype,
                    table: rc2_row,
                },
            };
            let (pos, p, sh) = ([&cl.px[..], &cl.py, &cl.pz], p.to_array(), sh.to_array());
            // SAFETY: `isa` names an instruction set the CPU reports (`Isa::detect`), and then
            // this is compiled into the `*_avx2` / `*_avx512` builds of the tasks (inline(always)
            // all the way up), which enable it.
            #[allow(unsafe_code)]
            let n = unsafe {
                if isa == Isa::Avx512 {
                    simd::scan_avx512::<POST>(pos, cutoff, a, e, p, sh, &mut self.h, self.n)
                } else {
                    simd::scan_avx2::<POST>(pos, cutoff, a, e, p, sh, &mut self.h, self.n)
                }
            };
            self.n = n;
            return;
        }
        let _ = (isa, uniform);
        let mut n = self.n;
        let h = &mut self.h;
        for j in a..e {
            let (dx, dy, dz) = if POST {
                (
                    (p.x - cl.px[j]) - sh.x,
                    (p.y - cl.py[j]) - sh.y,
                    (p.z - cl.pz[j]) - sh.z,
                )
            } else {
                (p.x - cl.px[j], p.y - cl.py[j], p.z - cl.pz[j])
            };
            let r2 = dx * dx + dy * dy + dz * dz;
            let rc2 = rc2_row[if ONE { 0 } else { cl.ptype[j] as usize }];
            (h.j[n], h.dx[n], h.dy[n], h.dz[n], h.r2[n]) = (j as u32, dx, dy, dz, r2);
            n += ((r2 < rc2) & (r2 > 0.0)) as usize;
        }
        self.n = n;
    }
}

/// Force on i from sorted particle j at separation `dr` (r² = `r2`); `dv_shift` is subtracted from the
/// velocity difference (the Lees–Edwards image velocity; zero otherwise).
#[inline(always)]
fn pair_force<K: PairKernel, const ONE: bool>(
    row: &[K],
    cl: &CellList,
    key: u64,
    vi: DVec3,
    idi: u32,
    (j, dr, r2): (usize, DVec3, Real),
    dv_shift: DVec3,
) -> DVec3 {
    let kern = if ONE { row[0] } else { row[cl.ptype[j] as usize] };
    // no hash for a pair without a random force (zero temperature, or the repulsion-only
    // plasma–cytosol pairs)
    let xi = if kern.noisy() { pair_xi(key, idi, cl.id(j)) } else { 0.0 };
    kern.force(dr, r2, (vi - cl.velocity(j)) - dv_shift, xi)
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

/// The single-precision cutoff² of the distance prefilter for the double-precision cutoff² `rc2`
/// in a box whose longest edge is `l`: above rc² by more than the rounding error of r² in single
/// precision for any pair inside the cutoff, so that the prefilter keeps every hit (positions and
/// shifted query points are below 2l in magnitude; each coordinate difference is then off by at
/// most d = ulp(2l) + ulp(rc), and r² by at most 2√3·rc·d + 3d² + a few ulp(rc²)).
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
fn prefilter_cutoff2(rc2: Real, l: Real) -> f32 {
    let ulp = |x: f32| (x.next_up() - x) as Real;
    let rc = rc2.sqrt();
    let d = ulp((2.0 * l) as f32) + ulp(rc as f32);
    let margin = 4.0 * rc * d + 3.0 * d * d + 8.0 * ulp(rc2 as f32);
    ((rc2 + margin) as f32).next_up()
}

/// Whether the pair loop reads the single-precision positions of a cell list for a force table
/// with `ntypes` particle types (the AVX-512 cell-at-a-time path: one type); the owner of the
/// list may skip filling them otherwise ([`CellList::single`]).
pub(crate) fn reads_single(ntypes: usize) -> bool {
    ntypes == 1 && Isa::detect() == Isa::Avx512
}

/// Whether the pair loop reads the double-precision structure-of-arrays positions of a cell
/// list ([`CellList::px`]) for a force table with `ntypes` particle types, in `scheme`, with or
/// without Lees–Edwards images: all but the AVX-512 one-type half shell without images, which
/// reads the positions from the records. The owner of the list may skip filling them otherwise
/// ([`CellList::soa64`]).
pub(crate) fn reads_soa64(ntypes: usize, scheme: ForceScheme, sheared: bool) -> bool {
    !(reads_single(ntypes) && scheme == ForceScheme::HalfShell && !sheared)
}

/// What every pair task needs besides the particles and kernels.
#[derive(Clone, Copy, Debug)]
struct Run {
    /// Noise key of this force evaluation ([`crate::rng::step_key`]).
    key: u64,
    /// The instruction set the tasks run with (detected at run time).
    isa: Isa,
}

/// Builds of the pair tasks: all give the same results bit for bit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Isa {
    /// Plain Rust, any CPU.
    Portable,
    /// x86-64 with AVX2 and `popcnt`: the distance test 4 candidates at a time.
    Avx2,
    /// x86-64 with AVX-512 F, VL and DQ and `popcnt`: 8 at a time; with one particle type a
    /// whole cell per chunk of 16 candidates, prefiltered in single precision and tested again
    /// in double precision, and the linear kernel 8 pairs at a time.
    Avx512,
}

impl Isa {
    /// The widest build this CPU runs. `HEMODPD_ISA=portable|avx2` caps it (for benchmarks and
    /// to cross-check the builds); a cap the CPU does not support is ignored.
    fn detect() -> Self {
        static ISA: std::sync::OnceLock<Isa> = std::sync::OnceLock::new();
        *ISA.get_or_init(|| {
            let best = Self::best();
            match std::env::var("HEMODPD_ISA").as_deref() {
                Ok("portable") => Isa::Portable,
                Ok("avx2") if best != Isa::Portable => Isa::Avx2,
                _ => best,
            }
        })
    }

    fn best() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            let popcnt = std::arch::is_x86_feature_detected!("popcnt");
            if popcnt
                && std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("avx512vl")
                && std::arch::is_x86_feature_detected!("avx512dq")
            {
                return Isa::Avx512;
            }
            if popcnt && std::arch::is_x86_feature_detected!("avx2") {
                return Isa::Avx2;
            }
        }
        Isa::Portable
    }
}

/// Defines `$name`, which runs `$body` in its AVX-512 or AVX2 build when the CPU has it, or in
/// the portable one (the results are the same bit for bit: no floating-point contraction or
/// reordering is allowed in any of them), and the two `#[target_feature]` builds it calls.
/// `$body` must be `inline(always)` so that each build compiles its own copy; `$run` names the
/// [`Run`] argument.
macro_rules! isa_builds {
    ($name:ident, $avx2:ident, $avx512:ident, $body:ident, $run:ident, ($($arg:ident: $ty:ty),*), ($($call:ident),*)) => {
        #[allow(unsafe_code)]
        fn $name<K: PairKernel, const V: bool, const ONE: bool>($($arg: $ty),*) -> DMat3 {
            // SAFETY: `run.isa` names an instruction set the CPU reports (`Isa::detect`).
            #[cfg(target_arch = "x86_64")]
            match $run.isa {
                Isa::Avx512 => return unsafe { $avx512::<K, V, ONE>($($call),*) },
                Isa::Avx2 => return unsafe { $avx2::<K, V, ONE>($($call),*) },
                Isa::Portable => {}
            }
            $body::<K, V, ONE>($($call),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,popcnt")]
        fn $avx2<K: PairKernel, const V: bool, const ONE: bool>($($arg: $ty),*) -> DMat3 {
            $body::<K, V, ONE>($($call),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx512f,avx512vl,avx512dq,popcnt")]
        fn $avx512<K: PairKernel, const V: bool, const ONE: bool>($($arg: $ty),*) -> DMat3 {
            $body::<K, V, ONE>($($call),*)
        }
    };
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
    // Not zeroed here: the half shell's first phase zeroes the windows it owns (which tile the
    // array) in parallel, and the gather scheme assigns every entry.
    sf.resize(cl.len(), DVec3::ZERO);
    let one = table.ntypes() == 1;
    assert!(
        cl.single || !reads_single(table.ntypes()),
        "the cell list has no single-precision positions"
    );
    let le = shear.is_some();
    assert!(
        cl.soa64 || !reads_soa64(table.ntypes(), scheme, le),
        "the cell list has no double-precision structure-of-arrays positions"
    );
    let run = Run {
        key,
        isa: Isa::detect(),
    };
    let w = match (scheme, virial, one) {
        (ForceScheme::HalfShell, false, false) => half_shell::<K, false, false>(cl, table, run, sf, le),
        (ForceScheme::HalfShell, false, true) => half_shell::<K, false, true>(cl, table, run, sf, le),
        (ForceScheme::HalfShell, true, false) => half_shell::<K, true, false>(cl, table, run, sf, le),
        (ForceScheme::HalfShell, true, true) => half_shell::<K, true, true>(cl, table, run, sf, le),
        (ForceScheme::Gather, false, false) => gather::<K, false, false>(cl, table, run, sf, le),
        (ForceScheme::Gather, false, true) => gather::<K, false, true>(cl, table, run, sf, le),
        (ForceScheme::Gather, true, false) => gather::<K, true, false>(cl, table, run, sf, le),
        (ForceScheme::Gather, true, true) => gather::<K, true, true>(cl, table, run, sf, le),
    };
    match shear {
        None => w,
        Some(sh) => {
            w + match (virial, one) {
                (false, false) => shear_cross::<K, false, false>(cl, table, run, sf, sh),
                (false, true) => shear_cross::<K, false, true>(cl, table, run, sf, sh),
                (true, false) => shear_cross::<K, true, false>(cl, table, run, sf, sh),
                (true, true) => shear_cross::<K, true, true>(cl, table, run, sf, sh),
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
/// the last two layers, so the slab count is even. A slab writes only to itself and the next
/// slab. The even slabs are started in parallel (their windows tile the array, and each zeroes
/// its window first); odd slab 2k + 1 runs as soon as its two even neighbours 2k and 2k + 2
/// (mod the slab count) have finished, the only slabs whose windows overlap its own. So no two
/// concurrent tasks share a particle, there is no barrier between the even and the odd slabs,
/// and each particle's sum has the same order whatever the thread count: a particle of an even
/// layer gets its own slab's forces before the odd slab below, one of an odd layer the even
/// slab below before its own.
fn half_shell<K: PairKernel, const V: bool, const ONE: bool>(
    cl: &CellList,
    table: &KernelTable<K>,
    run: Run,
    sf: &mut [DVec3],
    le: bool,
) -> DMat3 {
    let nz = cl.grid.n[2];
    let nslab = if nz.is_multiple_of(2) { nz } else { nz - 1 };
    let n = sf.len();
    let b: Vec<usize> = (0..=nslab)
        .map(|s| if s < nslab { cl.layer_start(s) } else { n })
        .collect();
    let vir: Vec<std::sync::OnceLock<DMat3>> = (0..nslab).map(|_| std::sync::OnceLock::new()).collect();
    // Even neighbours each odd slab still waits for (one when there are only two slabs).
    let wait: Vec<std::sync::atomic::AtomicUsize> = (0..nslab / 2)
        .map(|_| std::sync::atomic::AtomicUsize::new(if nslab == 2 { 1 } else { 2 }))
        .collect();
    // The sorted forces, shared by the slab tasks: their windows overlap in memory, but a task
    // runs only after every task whose window overlaps its own has finished.
    let forces = SharedSlice::new(sf);
    let (b, vir, wait, forces) = (&b, &vir, &wait, &forces);
    let layers = move |s: usize| (s, if s + 1 == nslab { nz } else { s + 1 });
    let odd = move |s: usize| {
        let last = s + 1 == nslab;
        let (lo, hi) = (b[s], if last { n } else { b[s + 2] });
        // SAFETY: this odd slab's windows, lo..hi and (for the last slab) 0..b[1], overlap
        // only the windows of the even slabs s − 1 and s + 1 (mod nslab), which have finished
        // and dropped them (the counter in `wait` reached zero after both), and no other odd
        // slab's.
        #[allow(unsafe_code)]
        let mut w = unsafe {
            Win {
                a: forces.window(lo, hi),
                a0: lo,
                b: if last { forces.window(0, b[1]) } else { &mut [] },
                b0: 0,
            }
        };
        let m = slab::<K, V, ONE>(cl, table, run, layers(s), &mut w, le);
        vir[s].set(m).expect("each slab runs once");
    };
    rayon::scope(|sc| {
        // Spawned from the top down: the spawning thread pops its own tasks last-in first-out
        // and so starts at the bottom slab, while the other threads steal from the top. That is
        // the same split as rayon's parallel iterators give the O(N) passes (the caller takes
        // the low indices, which are the low z-layers in cell order), so on 2 threads each
        // thread works on the same half of the box in every pass of a step, and its data stays
        // in its own cache. The order of the tasks changes no result.
        for e in (0..nslab).step_by(2).rev() {
            sc.spawn(move |sc| {
                let (lo, hi) = (b[e], b[e + 2]);
                {
                    // SAFETY: the even slabs' windows are disjoint, and an odd slab overlapping
                    // this one starts only after this task has released it below.
                    #[allow(unsafe_code)]
                    let a = unsafe { forces.window(lo, hi) };
                    a.fill(DVec3::ZERO);
                    let mut w = Win {
                        a,
                        a0: lo,
                        b: &mut [],
                        b0: 0,
                    };
                    let m = slab::<K, V, ONE>(cl, table, run, layers(e), &mut w, le);
                    vir[e].set(m).expect("each slab runs once");
                }
                let (up, down) = (e + 1, (e + nslab - 1) % nslab);
                for o in [Some(up), (down != up).then_some(down)].into_iter().flatten() {
                    if wait[o / 2].fetch_sub(1, std::sync::atomic::Ordering::AcqRel) == 1 {
                        sc.spawn(move |_| odd(o));
                    }
                }
            });
        }
    });
    vir.iter()
        .map(|m| *m.get().expect("every slab ran"))
        .fold(DMat3::ZERO, |acc, m| acc + m)
}

isa_builds!(slab, slab_avx2, slab_avx512, slab_body, run, (cl: &CellList, table: &KernelTable<K>, run: Run, zz: (usize, usize), win: &mut Win<'_>, le: bool), (cl, table, run, zz, win, le));

#[inline(always)]
fn slab_body<K: PairKernel, const V: bool, const ONE: bool>(
    cl: &CellList,
    table: &KernelTable<K>,
    run: Run,
    (z0, z1): (usize, usize),
    win: &mut Win<'_>,
    le: bool,
) -> DMat3 {
    let g = &cl.grid;
    let [nx, ny, nz] = g.n;
    // Index offsets of the middle cells of the half shell's 4 rows (dy, dz) = (1, 0), (−1, 1),
    // (0, 1), (1, 1), in `HALF`'s order.
    let rows = [nx, nx * ny - nx, nx * ny, nx * ny + nx];
    let mut vir = DMat3::ZERO;
    let mut nb = [(0usize, 0usize, DVec3::ZERO); 13];
    let mut scratch = SCRATCH.with(|c| c.take());
    #[cfg_attr(not(target_arch = "x86_64"), allow(unused_mut))]
    let mut hits = &mut scratch.hits;
    // The state of the cell-at-a-time path (AVX-512, one type): query points, hit counts, the
    // previous cell's hits and the cell whose forces are pending, the forces' buffer, and what
    // those forces need (the kernel row, the noise key, the linear kernel's parameters).
    #[cfg(target_arch = "x86_64")]
    let (qs, mut ns) = (&mut scratch.qs, &mut scratch.ns);
    // The cutoff² of the cell path: in double precision, and its single-precision prefilter.
    #[cfg(target_arch = "x86_64")]
    let (rc2, rc2_32) = {
        let rc2 = table.cutoff2_row(0)[0];
        (rc2, prefilter_cutoff2(rc2, g.lengths().max_element()))
    };
    // The slab-wide part of what the cell-at-a-time scans need (`simd::scan_cell_avx512`):
    // every range ends at a sorted index ≤ n, so 15 entries of padding and tagged indices
    // below 2^TAG_SHIFT for n + 16 cover them all.
    #[cfg(target_arch = "x86_64")]
    if ONE && run.isa == Isa::Avx512 {
        let n = cl.len();
        assert!(
            [&cl.px32, &cl.py32, &cl.pz32].iter().all(|p| p.len() >= n + 15),
            "positions not padded"
        );
        assert!(n + 16 < 1 << simd::TAG_SHIFT, "too many particles for tagged indices");
    }
    #[cfg(target_arch = "x86_64")]
    let (mut prev, mut prev_ns, mut pending) = (&mut scratch.prev, &mut scratch.prev_ns, None);
    // A cell of up to 8 particles has its forces evaluated as one stream of hits when the sorted
    // indices leave room for the slot bits (`simd::SLOT_SHIFT`).
    #[cfg(target_arch = "x86_64")]
    let bufs = &mut scratch.bufs;
    #[cfg(target_arch = "x86_64")]
    {
        bufs.streams = cl.len() + 16 < 1 << simd::SLOT_SHIFT;
    }
    // The shifts of this cell's ranges and the previous cell's, swapped by reference below
    // (each is 384 bytes). Only the entries of the tags in use are set.
    #[cfg(target_arch = "x86_64")]
    let mut shifts = [[[0.0; 16]; 3]; 2];
    #[cfg(target_arch = "x86_64")]
    let (mut sh, mut prev_sh) = {
        let [a, b] = &mut shifts;
        (a, b)
    };
    #[cfg(target_arch = "x86_64")]
    let kern = (
        table.row(0),
        run.key,
        if ONE { table.row(0)[0].linear() } else { None },
        rc2,
    );
    for z in z0..z1 {
        for y in 0..ny {
            for x in 0..nx {
                let (s0, s1) = cl.range(g.index(x, y, z));
                if s0 == s1 {
                    continue;
                }
                let mut m = s1 - s0;
                let mut nnb = 0;
                let (own_end, skip) = if x >= 1 && x + 1 < nx && y >= 1 && y + 1 < ny && z + 1 < nz {
                    // Inside the grid: the cell x + 1 follows this one, and the other 12
                    // neighbours are 4 rows of 3 consecutive cells, none wrapped (the same
                    // candidates in the same order as the general case below).
                    let c = g.index(x, y, z);
                    for o in rows {
                        let (a, e) = (cl.start[c + o - 1] as usize, cl.start[c + o + 2] as usize);
                        nb[nnb] = (a, e, DVec3::ZERO);
                        nnb += 1;
                        m += e - a;
                    }
                    let own_end = cl.start[c + 2] as usize;
                    m += own_end - s1;
                    (own_end, 0)
                } else {
                    for d in HALF.iter() {
                        if le && crosses_y(y, d[1], ny) {
                            continue; // Lees–Edwards: done by `shear_cross`
                        }
                        let (c, sh) = g.neighbour(x, y, z, *d);
                        let (a, e) = cl.range(c);
                        push_range(&mut nb, &mut nnb, a, e, sh);
                        m += e - a;
                    }
                    // The cell x + 1 usually follows this one in the sorted arrays with no
                    // shift: then it joins the cell's own range (same visiting order, one range
                    // less).
                    match nb.first() {
                        Some(&(a, e, sh)) if nnb > 0 && a == s1 && sh == DVec3::ZERO => (e, 1),
                        _ => (s1, 0),
                    }
                };
                #[cfg(target_arch = "x86_64")]
                if ONE && run.isa == Isa::Avx512 {
                    // The whole cell at once: each chunk of candidates is loaded once for all
                    // of the cell's particles; particle k's hits go to its own region of `hits`
                    // (k · stride onwards), in the same order as the per-particle scan below.
                    let nc = s1 - s0;
                    let stride = m + 2 * LANES;
                    hits.reserve(nc * stride);
                    qs.clear();
                    ns.clear();
                    for k in 0..nc {
                        let p = cl.position(s0 + k);
                        qs.push([p.x as f32, p.y as f32, p.z as f32]);
                        ns.push(k * stride);
                    }
                    // What the scans below need (`simd::scan_cell_avx512`'s safety section):
                    // query k's hits start at k · stride and grow by at most m, the candidates
                    // of all the ranges together, and the last store writes 16 entries past
                    // them, so they end before (k + 1) · stride = k · stride + m + 16 (checked
                    // here for the last query); every range ends at a sorted index below the
                    // slab-wide bounds checked before the loop; the tags are at most 13.
                    assert!(hits.h.j.len() >= nc * stride, "hit arrays too short");
                    let pos = [&cl.px32[..], &cl.py32, &cl.pz32];
                    // The ranges' shifts by tag (0: the own range, unshifted).
                    for c in 0..3 {
                        sh[c][0] = 0.0;
                    }
                    for (t, &(_, _, s)) in nb[skip..nnb].iter().enumerate() {
                        for c in 0..3 {
                            sh[c][t + 1] = s[c];
                        }
                    }
                    // SAFETY: as in `Hits::scan`: the CPU has AVX-512 F + VL (+ DQ) and this is
                    // compiled into the `slab_avx512` build.
                    #[allow(unsafe_code)]
                    unsafe {
                        simd::scan_cell_avx512(pos, rc2_32, (s0, own_end), Some(s0), 0, qs, &mut hits.h.j, ns);
                        // The query points shifted by the range's shift, recomputed only when
                        // the shift changes (never inside the grid, where all are zero; p − 0
                        // is p, so the points are the same either way).
                        let mut shifted = DVec3::ZERO;
                        for (t, &(a, e, s)) in nb[skip..nnb].iter().enumerate() {
                            if s != shifted {
                                for (k, q) in qs.iter_mut().enumerate() {
                                    let p = cl.position(s0 + k) - s;
                                    *q = [p.x as f32, p.y as f32, p.z as f32];
                                }
                                shifted = s;
                            }
                            simd::scan_cell_avx512(pos, rc2_32, (a, e), None, t as u32 + 1, qs, &mut hits.h.j, ns);
                        }
                    }
                    // The forces of the previous cell now, this cell's after the next scan:
                    // its hits are read well after they were stored (a load right after the
                    // compressing stores cannot be forwarded from them and stalls).
                    if let Some(p) = pending {
                        cell_forces::<K, V, ONE>(cl, kern, (prev, prev_ns, prev_sh), p, bufs, win, &mut vir);
                    }
                    std::mem::swap(&mut hits, &mut prev);
                    std::mem::swap(&mut ns, &mut prev_ns);
                    std::mem::swap(&mut sh, &mut prev_sh);
                    pending = Some((s0, s1, stride));
                    continue;
                }
                hits.reserve(m);
                for i in s0..s1 {
                    let pi = cl.position(i);
                    let ti = if ONE { 0 } else { cl.ptype[i] as usize };
                    let (row, rc2_row) = (table.row(ti), (table.cutoff2_row(ti), table.uniform_cutoff2(ti)));
                    // The cell's own later particles, then the neighbour ranges, in visiting order.
                    hits.n = 0;
                    hits.scan::<ONE, false>(rc2_row, cl, run.isa, i + 1, own_end, pi, DVec3::ZERO);
                    for &(a, e, sh) in &nb[skip..nnb] {
                        hits.scan::<ONE, false>(rc2_row, cl, run.isa, a, e, pi - sh, DVec3::ZERO);
                    }
                    hit_forces::<K, V, ONE>(cl, row, run.key, i, hits, 0..hits.n, win, &mut vir);
                }
            }
        }
    }
    #[cfg(target_arch = "x86_64")]
    if let Some(p) = pending {
        cell_forces::<K, V, ONE>(cl, kern, (prev, prev_ns, prev_sh), p, bufs, win, &mut vir);
    }
    SCRATCH.with(|c| c.replace(scratch));
    vir
}

/// The buffers of a slab task ([`slab_body`]): hits, and for the cell-at-a-time path the query
/// points, hit counts, the previous cell's hits and counts, and the forces. Kept per thread
/// between tasks, so that a warm task allocates nothing; their contents never carry over (each
/// task writes before it reads).
#[derive(Default)]
struct Scratch {
    hits: Hits,
    #[cfg(target_arch = "x86_64")]
    qs: Vec<[f32; 3]>,
    #[cfg(target_arch = "x86_64")]
    ns: Vec<usize>,
    #[cfg(target_arch = "x86_64")]
    prev: Hits,
    #[cfg(target_arch = "x86_64")]
    prev_ns: Vec<usize>,
    #[cfg(target_arch = "x86_64")]
    bufs: KernelBufs,
}

/// The 8-lane kernel's buffers: the forces of a particle's or a cell's hits (x, y, z), and a
/// cell's stream of hits ([`cell_stream_forces`]), which `streams` allows (set per slab).
#[cfg(target_arch = "x86_64")]
#[derive(Default)]
struct KernelBufs {
    f: [Vec<Real>; 3],
    stream: Vec<u32>,
    streams: bool,
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Scratch> = std::cell::RefCell::new(Scratch::default());
}

/// The forces of one cell's particles s0..s1 from their candidates (particle k's are the tagged
/// indices `hits` k · stride .. `ns[k]` of [`simd::scan_cell_avx512`], with the ranges' shifts
/// `sh`), particle by particle. With the linear kernel's parameters (`linear`) and no virial a
/// cell of up to 8 particles goes through [`cell_stream_forces`] (if `bufs.streams`); in a larger
/// one each particle's forces are evaluated 8 pairs at a time into `bufs.f`
/// ([`simd::linear_forces_avx512`], the same operations per pair; candidates beyond the cutoff
/// get +0.0), then summed in the same order. Otherwise the hits and their separations are filled
/// in ([`simd::separations_avx512`]) and run through [`hit_forces`].
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn cell_forces<K: PairKernel, const V: bool, const ONE: bool>(
    cl: &CellList,
    (row, key, linear, rc2): (&[K], u64, Option<crate::kernel::LinearParams>, Real),
    (hits, ns, sh): (&mut Hits, &[usize], &[[Real; 16]; 3]),
    (s0, s1, stride): (usize, usize, usize),
    bufs: &mut KernelBufs,
    win: &mut Win<'_>,
    vir: &mut DMat3,
) {
    let linear = linear.filter(|_| !V);
    if let (Some(lp), true) = (linear, bufs.streams && s1 - s0 <= 8) {
        cell_stream_forces(cl, (key, lp, rc2), (hits, ns, sh), (s0, s1, stride), bufs, win);
        return;
    }
    let fbuf = &mut bufs.f;
    // What `simd::linear_forces_avx512` and `simd::Geometry::new` need, once per cell: particle
    // k's hits lie in k · stride .. k · stride + stride − 16 (see the scan in `slab_body`;
    // asserted per particle below), so 7 entries past them stay inside the hit arrays and
    // inside force buffers of stride + 8; the records are few enough for 32-bit lane indices.
    if linear.is_some() && fbuf[0].len() < stride + LANES {
        for b in fbuf.iter_mut() {
            b.resize(stride + LANES, 0.0);
        }
    }
    assert!(hits.h.j.len() >= (s1 - s0) * stride, "hit arrays too short");
    assert!(
        !cl.rec.is_empty() && cl.rec.len() < (i32::MAX / 8) as usize,
        "no records, or too many"
    );
    for (k, i) in (s0..s1).enumerate() {
        let (lo, mut hi) = (k * stride, ns[k]);
        // The one bound the cell's checks above rest on (one compare per particle).
        assert!(lo <= hi && hi + 2 * LANES <= lo + stride, "hits outside their region");
        let (rec, q) = (&cl.rec[..], cl.position(i).to_array());
        if linear.is_none() {
            // SAFETY: only called from the `slab_avx512` build (AVX-512 F, VL, DQ checked at
            // run time by `Isa::best`).
            #[allow(unsafe_code)]
            let end = unsafe { simd::separations_avx512(&mut hits.h, (lo, hi), rec, q, sh, rc2) };
            hi = end;
        }
        let Some(lp) = linear else {
            hit_forces::<K, V, ONE>(cl, row, key, i, hits, lo..hi, win, vir);
            continue;
        };
        // SAFETY: only called from the `slab_avx512` build, which enables AVX-512 F, VL and DQ,
        // all three checked at run time (`Isa::best`).
        #[allow(unsafe_code)]
        unsafe {
            let g = simd::Geometry::new(rec, q, sh, rc2);
            simd::linear_forces_avx512(
                &hits.h,
                (lo, hi),
                &cl.rec,
                cl.velocity(i),
                cl.id(i),
                key,
                lp,
                g,
                fbuf.each_mut().map(|b| &mut b[..]),
            );
        }
        let f = fbuf.each_ref().map(|b| &b[..hi - lo]);
        sum_hit_forces(i, &hits.h.j[lo..hi], TAG_LOW, f, win);
    }
}

/// The forces `f` (x, y, z) of particle i's hits `tagged` (sorted index: the bits of `low`), in
/// order: each −f to its j at once, their sum to i after them.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn sum_hit_forces(i: usize, tagged: &[u32], low: u32, [fx, fy, fz]: [&[Real]; 3], win: &mut Win<'_>) {
    let mut fi = DVec3::ZERO;
    for (((&j, &fx), &fy), &fz) in tagged.iter().zip(fx).zip(fy).zip(fz) {
        let f = DVec3::new(fx, fy, fz);
        fi += f;
        win.add((j & low) as usize, -f);
    }
    win.add(i, fi);
}

/// [`cell_forces`] for a cell of up to 8 particles with the linear kernel and no virial: the
/// particles' hits are concatenated into one stream ([`simd::stream_cell_hits_avx512`]) and
/// evaluated 8 pairs at a time across particles ([`simd::linear_forces_cell_avx512`]), so a
/// cell runs ⌈hits / 8⌉ blocks instead of a partial block or two per particle. The forces are
/// then summed particle by particle as in [`cell_forces`]: each −f to its j at once, the sum to
/// i after its hits, in the same order, so the results are the same bits.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn cell_stream_forces(
    cl: &CellList,
    (key, lp, rc2): (u64, crate::kernel::LinearParams, Real),
    (hits, ns, sh): (&mut Hits, &[usize], &[[Real; 16]; 3]),
    (s0, s1, stride): (usize, usize, usize),
    bufs: &mut KernelBufs,
    win: &mut Win<'_>,
) {
    let (fbuf, stream) = (&mut bufs.f, &mut bufs.stream);
    let nc = s1 - s0;
    // The stream holds at most nc · (stride − 16) hits, and its copy writes 15 entries past
    // them; the kernel reads the stream and writes the forces' buffers up to 7 past them.
    let room = nc * stride;
    if stream.len() < room {
        stream.resize(room, 0);
    }
    if fbuf[0].len() < room + LANES {
        for b in fbuf.iter_mut() {
            b.resize(room + LANES, 0.0);
        }
    }
    assert!(ns.len() == nc && hits.h.j.len() >= room, "hit arrays too short");
    for (k, &end) in ns.iter().enumerate() {
        // The one bound the copy rests on (one compare per particle).
        assert!(
            k * stride <= end && end + 2 * LANES <= (k + 1) * stride,
            "hits outside their region"
        );
    }
    assert!(cl.rec.len() < (i32::MAX / 8) as usize, "too many records");
    // SAFETY: only called from the `slab_avx512` build (AVX-512 F, VL, DQ checked at run time by
    // `Isa::best`); the regions, the stream's and the buffers' room and the record count are
    // asserted above, and the sorted indices are below 2^SLOT_SHIFT (`bufs.streams`, set per
    // slab from the particle count).
    #[allow(unsafe_code)]
    unsafe {
        let len = simd::stream_cell_hits_avx512(&hits.h.j, ns, stride, stream);
        let g = simd::Geometry::new(&cl.rec, cl.position(s0).to_array(), sh, rc2);
        let out = fbuf.each_mut().map(|b| &mut b[..]);
        simd::linear_forces_cell_avx512((stream, len), &cl.rec, (s0, nc), key, lp, g, out);
        let mut a = 0;
        for (k, &end) in ns.iter().enumerate() {
            let e = a + (end - k * stride);
            let f = fbuf.each_ref().map(|b| &b[a..e]);
            sum_hit_forces(s0 + k, &stream[a..e], SLOT_LOW, f, win);
            a = e;
        }
    }
}

/// The forces of sorted particle i's hits `ks` (indices into `hits`, in order): each −f goes to
/// its j at once, their sum to i at the end; each pair's virial is added to `vir` (if `V`).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn hit_forces<K: PairKernel, const V: bool, const ONE: bool>(
    cl: &CellList,
    row: &[K],
    key: u64,
    i: usize,
    hits: &Hits,
    ks: std::ops::Range<usize>,
    win: &mut Win<'_>,
    vir: &mut DMat3,
) {
    let (vi, idi) = (cl.velocity(i), cl.id(i));
    let mut fi = DVec3::ZERO;
    for k in ks {
        let hit = hits.get(k);
        let f = pair_force::<K, ONE>(row, cl, key, vi, idi, hit, DVec3::ZERO);
        fi += f;
        win.add(hit.0, -f);
        if V {
            *vir += outer(hit.1, f);
        }
    }
    win.add(i, fi);
}

// ----------------------------------------------------------------------------------- gather

/// Every particle sums its own pairs over the 27 neighbour cells; tasks are z-layers, each
/// writing only its own contiguous part of the sorted force array.
fn gather<K: PairKernel, const V: bool, const ONE: bool>(
    cl: &CellList,
    table: &KernelTable<K>,
    run: Run,
    sf: &mut [DVec3],
    le: bool,
) -> DMat3 {
    per_layer(cl, sf, |z, off, w| {
        gather_layer::<K, V, ONE>(cl, table, run, z, off, w, le)
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

isa_builds!(gather_layer, gather_layer_avx2, gather_layer_avx512, gather_layer_body, run, (cl: &CellList, table: &KernelTable<K>, run: Run, z: usize, off: usize, out: &mut [DVec3], le: bool), (cl, table, run, z, off, out, le));

#[inline(always)]
fn gather_layer_body<K: PairKernel, const V: bool, const ONE: bool>(
    cl: &CellList,
    table: &KernelTable<K>,
    run: Run,
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
                let pi = cl.position(i);
                let vi = cl.velocity(i);
                let idi = cl.id(i);
                let ti = if ONE { 0 } else { cl.ptype[i] as usize };
                let (row, rc2_row) = (table.row(ti), (table.cutoff2_row(ti), table.uniform_cutoff2(ti)));
                // dr = (x_i − x_j) − shift is exactly the negative of what j computes for i
                // (j == i gives r² = 0 and is skipped), so Newton's third law holds bit for bit.
                hits.n = 0;
                for &(a, e, sh) in &nb[..nnb] {
                    hits.scan::<ONE, true>(rc2_row, cl, run.isa, a, e, pi, sh);
                }
                let mut fi = DVec3::ZERO;
                for k in 0..hits.n {
                    let hit = hits.get(k);
                    let f = pair_force::<K, ONE>(row, cl, run.key, vi, idi, hit, DVec3::ZERO);
                    fi += f;
                    if V {
                        vir += outer(hit.1, f * 0.5);
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
    run: Run,
    sf: &mut [DVec3],
    sh: ShearImages,
) -> DMat3 {
    per_layer(cl, sf, |z, off, w| {
        shear_cross_layer::<K, V, ONE>(cl, table, run, z, off, w, sh)
    })
}

isa_builds!(shear_cross_layer, shear_cross_layer_avx2, shear_cross_layer_avx512, shear_cross_layer_body, run, (cl: &CellList, table: &KernelTable<K>, run: Run, z: usize, off: usize, out: &mut [DVec3], sh: ShearImages), (cl, table, run, z, off, out, sh));

#[inline(always)]
fn shear_cross_layer_body<K: PairKernel, const V: bool, const ONE: bool>(
    cl: &CellList,
    table: &KernelTable<K>,
    run: Run,
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
                let pi = cl.position(i);
                let vi = cl.velocity(i);
                let idi = cl.id(i);
                let ti = if ONE { 0 } else { cl.ptype[i] as usize };
                let (row, rc2_row) = (table.row(ti), (table.cutoff2_row(ti), table.uniform_cutoff2(ti)));
                let mut fi = DVec3::ZERO;
                for &(a, e, shift, vshift) in &nb[..nnb] {
                    hits.n = 0;
                    hits.scan::<ONE, true>(rc2_row, cl, run.isa, a, e, pi, shift);
                    for k in 0..hits.n {
                        let hit = hits.get(k);
                        let f = pair_force::<K, ONE>(row, cl, run.key, vi, idi, hit, vshift);
                        fi += f;
                        if V {
                            vir += outer(hit.1, f * 0.5);
                        }
                    }
                }
                out[i - off] += fi;
            }
        }
    }
    vir
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cells::CellGrid;
    use crate::kernel::DpdLinear;
    use crate::{PairParams, PeriodicBox};
    use rand_xoshiro::rand_core::{RngCore, SeedableRng};

    /// 600 random particles of 2 types in a 6.3 × 5.1 × 4.7 box (cells of ≥ 1, so the x rows
    /// wrap and merge unevenly), random velocities; type pair (1, 1) has a shorter cutoff 0.8
    /// and (0, 1) no interaction at all, to exercise the per-type cutoffs.
    fn setup(kbt: Real) -> (CellList, KernelTable<DpdLinear>, KernelTable<DpdLinear>) {
        setup_in(DVec3::new(6.3, 5.1, 4.7), kbt)
    }

    fn setup_in(l: DVec3, kbt: Real) -> (CellList, KernelTable<DpdLinear>, KernelTable<DpdLinear>) {
        let domain = PeriodicBox::new(l).unwrap();
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(7);
        let mut u = || (rng.next_u64() >> 11) as Real / (1u64 << 53) as Real;
        let n = 600;
        let pos: Vec<DVec3> = (0..n).map(|_| DVec3::new(u() * l.x, u() * l.y, u() * l.z)).collect();
        let vel: Vec<DVec3> = (0..n).map(|_| DVec3::new(u(), u(), u()) - 0.5).collect();
        let ptype: Vec<u16> = (0..n).map(|i| (i % 3 == 0) as u16).collect();
        let id: Vec<u32> = (0..n as u32).collect();
        let mut cl = CellList::new(CellGrid::new(&domain, 1.0).unwrap());
        cl.build(&pos, &ptype, &id, |i| vel[i]);
        let p = PairParams {
            kbt,
            ..PairParams::groot_warren()
        };
        let short = PairParams { rc: 0.8, ..p };
        let two = KernelTable::from_fn(2, |i, j| match (i, j) {
            (0, 0) => DpdLinear::new(&p, 0.01, true),
            (1, 1) => DpdLinear::new(&short, 0.01, true),
            _ => DpdLinear::new(&p, 0.01, false),
        });
        let one = KernelTable::from_fn(1, |_, _| DpdLinear::new(&p, 0.01, true));
        (cl, one, two)
    }

    fn all_schemes(cl: &CellList, t: &KernelTable<DpdLinear>, run: Run) -> Vec<(Vec<DVec3>, DMat3)> {
        if t.ntypes() == 1 {
            let mut cl = cl.clone();
            cl.ptype.fill(0);
            schemes::<true>(&cl, t, run)
        } else {
            schemes::<false>(cl, t, run)
        }
    }

    fn schemes<const ONE: bool>(cl: &CellList, t: &KernelTable<DpdLinear>, run: Run) -> Vec<(Vec<DVec3>, DMat3)> {
        let n = cl.len();
        let sh = ShearImages {
            offset: 2.345,
            velocity: 0.7,
        };
        let mut out = Vec::new();
        for le in [false, true] {
            let mut f = vec![DVec3::ZERO; n];
            let mut w = half_shell::<DpdLinear, true, ONE>(cl, t, run, &mut f, le);
            if le {
                w += shear_cross::<DpdLinear, true, ONE>(cl, t, run, &mut f, sh);
            }
            out.push((f, w));
            let mut f = vec![DVec3::ZERO; n];
            let w = gather::<DpdLinear, true, ONE>(cl, t, run, &mut f, le);
            out.push((f, w));
            // without the virial (the path of most steps)
            let mut f = vec![DVec3::ZERO; n];
            let mut w = half_shell::<DpdLinear, false, ONE>(cl, t, run, &mut f, le);
            if le {
                w += shear_cross::<DpdLinear, false, ONE>(cl, t, run, &mut f, sh);
            }
            out.push((f, w));
        }
        out
    }

    /// The AVX2 and AVX-512 distance tests and the portable one give the same forces and virials
    /// bit for bit, for one and two types, at kBT = 1 and 0 (no noise), both schemes and the
    /// Lees–Edwards pass. With one type the AVX-512 build scans a cell at a time and evaluates
    /// the linear kernel 8 pairs at a time: as one stream of hits for the cells of up to 8
    /// particles, particle by particle for the larger ones (the setup has both kinds). A build
    /// the test machine's CPU cannot run is not compared, and the test says so.
    #[test]
    fn simd_and_portable_loops_agree_bit_for_bit() {
        let (cl, one, two) = setup(1.0);
        let (_, cold, _) = setup(0.0);
        let sizes: Vec<usize> = (0..cl.grid.ncells()).map(|c| cl.range(c).1 - cl.range(c).0).collect();
        assert!(sizes.iter().any(|&m| m > 8) && sizes.iter().filter(|&&m| (1..=8).contains(&m)).count() > 50);
        let portable = Run {
            key: 42,
            isa: Isa::Portable,
        };
        for t in [&one, &two, &cold] {
            let a = all_schemes(&cl, t, portable);
            assert!(a.iter().all(|(f, _)| f.iter().any(|x| *x != DVec3::ZERO)));
            let best = Isa::best();
            for isa in [Isa::Avx2, Isa::Avx512] {
                let on_cpu = match isa {
                    Isa::Avx512 => best == Isa::Avx512,
                    _ => best != Isa::Portable,
                };
                if on_cpu {
                    let b = all_schemes(&cl, t, Run { isa, ..portable });
                    assert!(a == b, "{isa:?} and portable pair loops differ");
                } else {
                    eprintln!("this CPU has no {isa:?}: that build was not compared");
                }
            }
        }
    }

    /// At zero temperature no pair is noisy, so no random force enters: the forces do not depend
    /// on the noise key, while at kBT = 1 they do (the same 600 particles).
    #[test]
    fn zero_temperature_skips_the_noise() {
        let (cl, cold, _) = setup(0.0);
        assert!(!cold.row(0)[0].noisy());
        let (_, hot, _) = setup(1.0);
        assert!(hot.row(0)[0].noisy());
        let run = |key| Run {
            key,
            isa: Isa::Portable,
        };
        assert!(all_schemes(&cl, &cold, run(9)) == all_schemes(&cl, &cold, run(10)));
        assert!(all_schemes(&cl, &hot, run(9)) != all_schemes(&cl, &hot, run(10)));
    }
    /// Both schemes find every pair: their forces equal a brute-force sum over all pairs with the
    /// minimum image, for one and two types (a shorter cutoff and a non-interacting pair), in a
    /// box whose cells are larger than the cutoff and in one whose cells are exactly the cutoff
    /// (particles at a cell face are at zero distance from the next cell).
    #[test]
    fn every_scheme_equals_the_brute_force_sum() {
        for l in [DVec3::new(6.3, 5.1, 4.7), DVec3::new(5.0, 4.0, 3.0)] {
            let (cl, one, two) = setup_in(l, 1.0);
            let run = Run {
                key: 5,
                isa: Isa::best(),
            };
            for t in [&one, &two] {
                let ty = |i: usize| if t.ntypes() == 1 { 0 } else { cl.ptype[i] as usize };
                let n = cl.len();
                let mut pairs = 0;
                let brute: Vec<DVec3> = (0..n)
                    .map(|i| {
                        let mut f = DVec3::ZERO;
                        for j in (0..n).filter(|&j| j != i) {
                            let mut dr = cl.position(i) - cl.position(j);
                            dr -= l * (dr / l).round();
                            let (r2, k) = (dr.length_squared(), t.get(ty(i), ty(j)));
                            if r2 < k.cutoff2() {
                                pairs += 1;
                                f += k.force(
                                    dr,
                                    r2,
                                    cl.velocity(i) - cl.velocity(j),
                                    pair_xi(run.key, cl.id(i), cl.id(j)),
                                );
                            }
                        }
                        f
                    })
                    .collect();
                assert!(pairs > 2000, "{pairs} pairs");
                for (k, (f, _)) in all_schemes(&cl, t, run).iter().enumerate().filter(|(k, _)| *k < 3) {
                    for i in 0..n {
                        let err = (f[i] - brute[i]).length();
                        assert!(
                            err < 1e-9 * (1.0 + brute[i].length()),
                            "box {l}, {} types, scheme {k}: particle {i}: {} vs {}",
                            t.ntypes(),
                            f[i],
                            brute[i]
                        );
                    }
                }
            }
        }
    }

    /// The AVX-512 one-type half shell reads the positions from the records only: a list built
    /// without the double-precision structure of arrays gives the same forces and virial bit
    /// for bit. Where the CPU lacks AVX-512 every path reads that structure of arrays, and the
    /// pair loop refuses a list without it.
    #[test]
    fn the_one_type_half_shell_needs_no_double_precision_arrays() {
        let (cl, one, _) = setup(1.0);
        let n = cl.len();
        let sorted = |f: &dyn Fn(usize) -> DVec3| (0..n).map(f).collect::<Vec<_>>();
        let (pos, vel) = (sorted(&|k| cl.position(k)), sorted(&|k| cl.velocity(k)));
        let id: Vec<u32> = (0..n).map(|k| cl.id(k)).collect();
        let mut lean = CellList::new(cl.grid);
        lean.soa64 = false;
        lean.build(&pos, &vec![0; n], &id, |i| vel[i]);
        assert!(lean.px.is_empty() && lean.len() == n);
        let mut full = CellList::new(cl.grid);
        full.build(&pos, &vec![0; n], &id, |i| vel[i]);
        let forces = |c: &CellList, virial: bool| {
            let mut sf = Vec::new();
            let w = compute(ForceScheme::HalfShell, c, &one, 42, &mut sf, virial, None);
            (sf, w)
        };
        for virial in [false, true] {
            if reads_soa64(1, ForceScheme::HalfShell, false) {
                let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| forces(&lean, virial)));
                assert!(r.is_err(), "the pair loop read a list without its arrays");
            } else {
                let (a, b) = (forces(&full, virial), forces(&lean, virial));
                assert!(a.0.iter().any(|f| *f != DVec3::ZERO));
                assert!(a == b, "virial {virial}: the lean list gives other forces");
            }
        }
    }

    /// The single-precision prefilter of the AVX-512 cell path lets through candidates just
    /// beyond the cutoff; the force stage drops them. 300 random particles, each with a partner
    /// at r = rc (1 ± 1e-9) in a random direction (so many pairs lie within the prefilter's
    /// rounding of the cutoff, on both sides): the forces equal the portable loop's bit for bit,
    /// with and without the virial, and at least 100 pairs beyond the cutoff were prefilter
    /// candidates.
    #[test]
    fn prefilter_candidates_beyond_the_cutoff_are_dropped() {
        let l = DVec3::new(7.0, 6.0, 5.0);
        let domain = PeriodicBox::new(l).unwrap();
        let mut rng = rand_xoshiro::Xoshiro256PlusPlus::seed_from_u64(11);
        let mut u = || (rng.next_u64() >> 11) as Real / (1u64 << 53) as Real;
        let mut pos = Vec::new();
        for k in 0..300 {
            let p = DVec3::new(u() * l.x, u() * l.y, u() * l.z);
            let dir = DVec3::new(u() - 0.5, u() - 0.5, u() - 0.5).normalize();
            let r = 1.0 + if k % 2 == 0 { 1e-9 } else { -1e-9 };
            pos.push(p);
            pos.push(domain.wrap(p + dir * r));
        }
        let n = pos.len();
        let vel: Vec<DVec3> = (0..n).map(|_| DVec3::new(u(), u(), u()) - 0.5).collect();
        let id: Vec<u32> = (0..n as u32).collect();
        let mut cl = CellList::new(CellGrid::new(&domain, 1.0).unwrap());
        cl.build(&pos, &vec![0; n], &id, |i| vel[i]);
        let p = PairParams::groot_warren();
        let one = KernelTable::from_fn(1, |_, _| DpdLinear::new(&p, 0.01, true));

        let portable = Run {
            key: 3,
            isa: Isa::Portable,
        };
        let a = all_schemes(&cl, &one, portable);
        if Isa::best() == Isa::Avx512 {
            let b = all_schemes(
                &cl,
                &one,
                Run {
                    isa: Isa::Avx512,
                    ..portable
                },
            );
            assert!(a == b, "AVX-512 and portable pair loops differ");
        } else {
            eprintln!("this CPU has no AVX-512: the prefilter was not exercised");
        }

        // In single precision, pairs beyond the cutoff that pass the prefilter, and hits it
        // would miss.
        let rc2_32 = prefilter_cutoff2(1.0, l.max_element());
        let (mut beyond, mut missed) = (0, 0);
        for i in 0..n {
            for j in 0..i {
                let mut d = cl.position(i) - cl.position(j);
                d -= l * (d / l).round();
                let d32 = [d.x as f32, d.y as f32, d.z as f32];
                let r2_32 = d32[0] * d32[0] + d32[1] * d32[1] + d32[2] * d32[2];
                let r2 = d.length_squared();
                beyond += (r2 >= 1.0 && r2_32 < rc2_32) as usize;
                missed += (r2 < 1.0 && r2_32 >= rc2_32) as usize;
            }
        }
        assert_eq!(missed, 0, "hits the prefilter would miss");
        assert!(beyond >= 100, "{beyond} prefilter candidates beyond the cutoff");
    }
}
