//! The AVX2 build of the pair loops' distance test, used when the CPU reports AVX2 at run time
//! (`pairs::Run::simd`); other CPUs run the portable loop in [`crate::pairs`]. Both test the same
//! candidates with the same IEEE operations (no fused multiply–add, no reordering) and append
//! the hits in the same order, so the forces agree bit for bit.
#![allow(unsafe_code)]

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

/// `assert!` for the preconditions checked on every cell or particle: on in debug builds and in
/// this crate's unit tests (which run these loops on small systems), off in optimised builds,
/// including the integration tests' (they run the same loops for millions of steps).
macro_rules! hot_assert {
    ($($arg:tt)*) => {
        if cfg!(any(debug_assertions, test)) {
            assert!($($arg)*);
        }
    };
}

use crate::Real;

/// For each 4-bit lane mask, the indices of its set lanes packed to the front (increasing).
#[cfg(target_arch = "x86_64")]
const PACK: [[i32; 4]; 16] = {
    let mut t = [[0i32; 4]; 16];
    let mut m = 0;
    while m < 16 {
        let mut n = 0;
        let mut k = 0;
        while k < 4 {
            if m & (1 << k) != 0 {
                t[m][n] = k;
                n += 1;
            }
            k += 1;
        }
        m += 1;
    }
    t
};

/// For each 4-bit lane mask, the 32-bit lane indices that move its set f64 lanes to the front
/// (`_mm256_permutevar8x32_epi32` on the f64 vector viewed as 8 × 32 bits).
#[cfg(target_arch = "x86_64")]
const PACK64: [[i32; 8]; 16] = {
    let mut t = [[0i32; 8]; 16];
    let mut m = 0;
    while m < 16 {
        let mut k = 0;
        while k < 4 {
            t[m][2 * k] = 2 * PACK[m][k];
            t[m][2 * k + 1] = 2 * PACK[m][k] + 1;
            k += 1;
        }
        m += 1;
    }
    t
};

/// The candidates that passed the distance test, as structure of arrays: sorted index j,
/// separation and r². Each array has room for a chunk past the last hit.
#[derive(Default)]
pub(crate) struct HitArrays {
    pub j: Vec<u32>,
    pub dx: Vec<Real>,
    pub dy: Vec<Real>,
    pub dz: Vec<Real>,
    pub r2: Vec<Real>,
}

impl HitArrays {
    /// Makes every array at least `m` long.
    #[inline]
    pub fn reserve(&mut self, m: usize) {
        if self.j.len() < m {
            self.j.resize(m, 0);
            for a in [&mut self.dx, &mut self.dy, &mut self.dz, &mut self.r2] {
                a.resize(m, 0.0);
            }
        }
    }
}

/// Raw pointers to the arrays of [`HitArrays`], for the unchecked stores of a scan.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(crate) struct HitPtrs {
    j: *mut u32,
    dx: *mut Real,
    dy: *mut Real,
    dz: *mut Real,
    r2: *mut Real,
}

#[cfg(target_arch = "x86_64")]
impl HitArrays {
    fn ptrs(&mut self) -> HitPtrs {
        HitPtrs {
            j: self.j.as_mut_ptr(),
            dx: self.dx.as_mut_ptr(),
            dy: self.dy.as_mut_ptr(),
            dz: self.dz.as_mut_ptr(),
            r2: self.r2.as_mut_ptr(),
        }
    }
}

/// r² = (dx² + dy²) + dz², as the scalar loop and `DVec3::dot` evaluate it.
///
/// # Safety
/// As [`scan_avx512`] (AVX-512 F enabled in the caller).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn r2_512(dx: __m512d, dy: __m512d, dz: __m512d) -> __m512d {
    _mm512_add_pd(
        _mm512_add_pd(_mm512_mul_pd(dx, dx), _mm512_mul_pd(dy, dy)),
        _mm512_mul_pd(dz, dz),
    )
}

/// Stores the lanes of `mask` (sorted index `js`, separation and r² `v`), packed to the front,
/// at hit `n` of `o`, and returns the new hit count.
///
/// # Safety
/// As [`scan_avx512`]; `o`'s arrays must have room for 8 entries from n.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn append_512(o: HitPtrs, n: usize, mask: u8, js: __m256i, v: [__m512d; 4]) -> usize {
    // SAFETY: the caller guarantees the room.
    unsafe {
        _mm256_storeu_si256(o.j.add(n).cast(), _mm256_maskz_compress_epi32(mask, js));
        _mm512_storeu_pd(o.dx.add(n), _mm512_maskz_compress_pd(mask, v[0]));
        _mm512_storeu_pd(o.dy.add(n), _mm512_maskz_compress_pd(mask, v[1]));
        _mm512_storeu_pd(o.dz.add(n), _mm512_maskz_compress_pd(mask, v[2]));
        _mm512_storeu_pd(o.r2.add(n), _mm512_maskz_compress_pd(mask, v[3]));
    }
    n + mask.count_ones() as usize
}

/// Panics unless a scan of `a..e` in chunks of `L` lanes can read and write without bounds
/// checks: the inputs padded to `e + L − 1`, the hit arrays `n + (e − a) + L` long.
#[inline(always)]
#[cfg(target_arch = "x86_64")]
fn check_room<const L: usize>(
    [px, py, pz]: [&[Real]; 3],
    cutoff: Cutoff<'_>,
    out: &HitArrays,
    a: usize,
    e: usize,
    n: usize,
) {
    let end = e + L - 1;
    assert!(
        px.len() >= end && py.len() >= end && pz.len() >= end,
        "positions not padded"
    );
    if let Cutoff::PerType { ptype, .. } = cutoff {
        assert!(ptype.len() >= end, "types not padded");
    }
    let room = n + (e - a) + L;
    let lens = [out.j.len(), out.dx.len(), out.dy.len(), out.dz.len(), out.r2.len()];
    assert!(lens.iter().all(|&l| l >= room), "hit arrays too short");
}

/// Cutoffs of the distance test: one for every candidate, or one per candidate type.
#[derive(Clone, Copy)]
#[cfg(target_arch = "x86_64")]
pub(crate) enum Cutoff<'a> {
    /// Every pair has this squared cutoff.
    One(Real),
    /// Squared cutoff per type of j (`table[ptype[j]]`), `ptype` padded like the positions.
    PerType { ptype: &'a [u16], table: &'a [Real] },
}

/// Appends to `out` at `n` the candidates j ∈ [a, e) (with their separation and r²) with 0 < r² < cutoff², where the
/// separation is `p − x_j` (`POST = false`) or `(p − x_j) − sh` (`POST = true`), and returns the
/// new count. `px, py, pz` must hold at least `e + 3` entries and `out` room for `n + (e − a) + 4`
/// hits.
///
/// # Safety
/// Only to be called from a function compiled with AVX2 enabled
/// (`#[target_feature(enable = "avx2")]`) on a CPU that has it. It is `inline(always)` so that it
/// is compiled into that caller, which a `#[target_feature]` function cannot be.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn scan_avx2<const POST: bool>(
    [px, py, pz]: [&[Real]; 3],
    cutoff: Cutoff<'_>,
    a: usize,
    e: usize,
    p: [Real; 3],
    sh: [Real; 3],
    out: &mut HitArrays,
    mut n: usize,
) -> usize {
    let (qx, qy, qz) = (_mm256_set1_pd(p[0]), _mm256_set1_pd(p[1]), _mm256_set1_pd(p[2]));
    let (sx, sy, sz) = (_mm256_set1_pd(sh[0]), _mm256_set1_pd(sh[1]), _mm256_set1_pd(sh[2]));
    let zero = _mm256_setzero_pd();
    let rc2_one = match cutoff {
        Cutoff::One(c) => _mm256_set1_pd(c),
        Cutoff::PerType { .. } => zero,
    };
    if a >= e {
        return n;
    }
    // Every chunk below reads 4 entries from j < e and writes 4 from the running count, which
    // stays below n + (e − a): check both ends once, then use unchecked pointers.
    check_room::<4>([px, py, pz], cutoff, out, a, e, n);
    let (px, py, pz) = (px.as_ptr(), py.as_ptr(), pz.as_ptr());
    let o = out.ptrs();
    let mut j = a;
    while j < e {
        // SAFETY: j + 3 < e + 3 ≤ the padded lengths asserted above; the stores are at
        // n .. n + 4 ≤ room, also asserted; `mask` < 16 indexes the 16-row tables.
        unsafe {
            let x = _mm256_loadu_pd(px.add(j));
            let y = _mm256_loadu_pd(py.add(j));
            let z = _mm256_loadu_pd(pz.add(j));
            let (dx, dy, dz) = if POST {
                (
                    _mm256_sub_pd(_mm256_sub_pd(qx, x), sx),
                    _mm256_sub_pd(_mm256_sub_pd(qy, y), sy),
                    _mm256_sub_pd(_mm256_sub_pd(qz, z), sz),
                )
            } else {
                (_mm256_sub_pd(qx, x), _mm256_sub_pd(qy, y), _mm256_sub_pd(qz, z))
            };
            // (dx² + dy²) + dz², as the scalar loop and `DVec3::dot` evaluate it
            let r2 = _mm256_add_pd(
                _mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy)),
                _mm256_mul_pd(dz, dz),
            );
            let rc2 = match cutoff {
                Cutoff::One(_) => rc2_one,
                Cutoff::PerType { ptype, table } => {
                    let t = ptype.as_ptr().add(j);
                    _mm256_set_pd(
                        table[*t.add(3) as usize],
                        table[*t.add(2) as usize],
                        table[*t.add(1) as usize],
                        table[*t as usize],
                    )
                }
            };
            let hit = _mm256_and_pd(
                _mm256_cmp_pd::<_CMP_LT_OQ>(r2, rc2),
                _mm256_cmp_pd::<_CMP_GT_OQ>(r2, zero),
            );
            let mut mask = _mm256_movemask_pd(hit) as usize;
            let valid = e - j;
            if valid < 4 {
                mask &= (1 << valid) - 1;
            }
            // Compress the hits to the front of each vector and store them at n (the lanes past
            // the hits are overwritten by the next chunk or ignored).
            let lanes = _mm_loadu_si128(PACK.as_ptr().add(mask).cast());
            _mm_storeu_si128(o.j.add(n).cast(), _mm_add_epi32(_mm_set1_epi32(j as i32), lanes));
            let perm = _mm256_loadu_si256(PACK64.as_ptr().add(mask).cast());
            let pack = |v: __m256d| _mm256_castsi256_pd(_mm256_permutevar8x32_epi32(_mm256_castpd_si256(v), perm));
            _mm256_storeu_pd(o.dx.add(n), pack(dx));
            _mm256_storeu_pd(o.dy.add(n), pack(dy));
            _mm256_storeu_pd(o.dz.add(n), pack(dz));
            _mm256_storeu_pd(o.r2.add(n), pack(r2));
            n += mask.count_ones() as usize;
        }
        j += 4;
    }
    n
}

/// The AVX-512 (F + VL) build of [`scan_avx2`]: 8 candidates per chunk, the hits compressed in
/// registers. Same arguments, same results bit for bit; `px, py, pz` (and `ptype`) must
/// hold at least `e + 7` entries and `out` room for `n + (e − a) + 8` hits.
///
/// # Safety
/// Only to be called from a function compiled with AVX-512F and AVX-512VL enabled on a CPU that
/// has them (see [`scan_avx2`]).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn scan_avx512<const POST: bool>(
    [px, py, pz]: [&[Real]; 3],
    cutoff: Cutoff<'_>,
    a: usize,
    e: usize,
    p: [Real; 3],
    sh: [Real; 3],
    out: &mut HitArrays,
    mut n: usize,
) -> usize {
    if a >= e {
        return n;
    }
    check_room::<8>([px, py, pz], cutoff, out, a, e, n);
    let (qx, qy, qz) = (_mm512_set1_pd(p[0]), _mm512_set1_pd(p[1]), _mm512_set1_pd(p[2]));
    let (sx, sy, sz) = (_mm512_set1_pd(sh[0]), _mm512_set1_pd(sh[1]), _mm512_set1_pd(sh[2]));
    let zero = _mm512_setzero_pd();
    let rc2_one = match cutoff {
        Cutoff::One(c) => _mm512_set1_pd(c),
        Cutoff::PerType { .. } => zero,
    };
    let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    let (px, py, pz) = (px.as_ptr(), py.as_ptr(), pz.as_ptr());
    let o = out.ptrs();
    let mut j = a;
    while j < e {
        // SAFETY: j + 7 < e + 7 ≤ the padded lengths asserted above; the stores are at
        // n .. n + 8 ≤ room, also asserted.
        unsafe {
            let x = _mm512_loadu_pd(px.add(j));
            let y = _mm512_loadu_pd(py.add(j));
            let z = _mm512_loadu_pd(pz.add(j));
            let (dx, dy, dz) = if POST {
                (
                    _mm512_sub_pd(_mm512_sub_pd(qx, x), sx),
                    _mm512_sub_pd(_mm512_sub_pd(qy, y), sy),
                    _mm512_sub_pd(_mm512_sub_pd(qz, z), sz),
                )
            } else {
                (_mm512_sub_pd(qx, x), _mm512_sub_pd(qy, y), _mm512_sub_pd(qz, z))
            };
            let r2 = r2_512(dx, dy, dz);
            let rc2 = match cutoff {
                Cutoff::One(_) => rc2_one,
                Cutoff::PerType { ptype, table } => {
                    let t = ptype.as_ptr().add(j);
                    _mm512_set_pd(
                        table[*t.add(7) as usize],
                        table[*t.add(6) as usize],
                        table[*t.add(5) as usize],
                        table[*t.add(4) as usize],
                        table[*t.add(3) as usize],
                        table[*t.add(2) as usize],
                        table[*t.add(1) as usize],
                        table[*t as usize],
                    )
                }
            };
            let valid = e - j;
            let tail: u8 = if valid < 8 { (1u8 << valid) - 1 } else { 0xFF };
            let mask =
                _mm512_mask_cmp_pd_mask::<_CMP_LT_OQ>(tail, r2, rc2) & _mm512_cmp_pd_mask::<_CMP_GT_OQ>(r2, zero);
            let js = _mm256_add_epi32(_mm256_set1_epi32(j as i32), lane);
            n = append_512(o, n, mask, js, [dx, dy, dz, r2]);
        }
        j += 8;
    }
    n
}

/// Bits of a tagged hit index ([`scan_cell_avx512`]) that hold the sorted index; the bits above
/// hold the number of the candidate range it came from.
#[cfg(target_arch = "x86_64")]
pub(crate) const TAG_SHIFT: u32 = 28;

/// The distance prefilter of a whole cell's particles against the sorted candidates `a..e`, 16
/// at a time in single precision (AVX-512 F): each chunk of candidates is loaded once and tested
/// against every query point `qs[k]`. Query k's candidates with r² < `rc2` (in single precision)
/// are appended to `out` at `ns[k]` (and `ns[k]` advanced) as tagged indices
/// `j | tag << TAG_SHIFT`, in order. `rc2` must exceed the double-precision cutoff² by more than
/// the rounding error of single precision, so that every hit of the double-precision test is
/// among them; the force stage tests them again in double precision ([`Geometry::hits`]) and
/// drops the rest. With `own = Some(i0)` query k is the sorted particle i0 + k and only
/// candidates j > i0 + k count (the cell's own later particles).
///
/// # Safety
/// As [`scan_avx512`], and the caller guarantees (checked here only in debug builds and unit tests, because
/// this runs for every range of every cell; the caller checks them once per slab and cell) that
/// the positions hold `e + 15` entries, `e + 16 < 2^TAG_SHIFT`, `tag < 16`, `ns` has an entry
/// per query, and each query's hit region has room for `(e − a) + 16` more entries in `out`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn scan_cell_avx512(
    [px, py, pz]: [&[f32]; 3],
    rc2: f32,
    (a, e): (usize, usize),
    own: Option<usize>,
    tag: u32,
    qs: &[[f32; 3]],
    out: &mut [u32],
    ns: &mut [usize],
) {
    if a >= e {
        return;
    }
    let end = e + 15;
    hot_assert!(
        px.len() >= end && py.len() >= end && pz.len() >= end,
        "positions not padded"
    );
    hot_assert!(e + 16 < 1 << TAG_SHIFT && tag < 16, "index or tag too large");
    hot_assert!(ns.len() >= qs.len(), "one hit count per query");
    hot_assert!(
        ns[..qs.len()].iter().all(|&n| n + (e - a) + 16 <= out.len()),
        "hit arrays too short"
    );
    let rc2v = _mm512_set1_ps(rc2);
    let lane = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    let (px, py, pz) = (px.as_ptr(), py.as_ptr(), pz.as_ptr());
    let o = out.as_mut_ptr();
    let nq = qs.len();
    let (qp, np) = (qs.as_ptr(), ns.as_mut_ptr());
    let tagv = _mm512_set1_epi32((tag << TAG_SHIFT) as i32);
    let mut j = a;
    while j < e {
        // SAFETY: j + 15 < e + 15 ≤ the padded lengths; each query's stores are at
        // ns[k] .. ns[k] + 16, which stays within the room asserted above (ns[k] grows by at
        // most e − a over the scan); k < nq ≤ ns.len().
        unsafe {
            let x = _mm512_loadu_ps(px.add(j));
            let y = _mm512_loadu_ps(py.add(j));
            let z = _mm512_loadu_ps(pz.add(j));
            let valid = e - j;
            let tail: u16 = if valid < 16 { (1u16 << valid) - 1 } else { 0xFFFF };
            let js = _mm512_add_epi32(_mm512_set1_epi32(j as i32), lane);
            let tagged = _mm512_or_si512(js, tagv);
            for k in 0..nq {
                let q = &*qp.add(k);
                let dx = _mm512_sub_ps(_mm512_set1_ps(q[0]), x);
                let dy = _mm512_sub_ps(_mm512_set1_ps(q[1]), y);
                let dz = _mm512_sub_ps(_mm512_set1_ps(q[2]), z);
                let r2 = _mm512_add_ps(
                    _mm512_add_ps(_mm512_mul_ps(dx, dx), _mm512_mul_ps(dy, dy)),
                    _mm512_mul_ps(dz, dz),
                );
                let mut mask = _mm512_mask_cmp_ps_mask::<_CMP_LT_OQ>(tail, r2, rc2v);
                if let Some(i0) = own {
                    mask &= _mm512_cmpgt_epi32_mask(js, _mm512_set1_epi32((i0 + k) as i32));
                }
                let n = *np.add(k);
                _mm512_storeu_si512(o.add(n).cast(), _mm512_maskz_compress_epi32(mask, tagged));
                *np.add(k) = n + mask.count_ones() as usize;
            }
        }
        j += 16;
    }
}

/// What turns the tagged candidates of [`scan_cell_avx512`] into separations and hits
/// ([`separations_avx512`], [`linear_forces_avx512`]): the sorted positions, the query point, the
/// ranges' shifts by tag and the double-precision cutoff², in vector registers.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub(crate) struct Geometry {
    p: [*const Real; 3],
    n: __m256i,
    rc2: __m512d,
    q: [__m512d; 3],
    sh: [(__m512d, __m512d); 3],
}

#[cfg(target_arch = "x86_64")]
impl Geometry {
    /// # Safety
    /// As [`scan_avx512`], and the caller guarantees that `rec` is shorter than `i32::MAX / 8`
    /// (checked here only in debug builds and unit tests).
    #[inline(always)]
    pub(crate) unsafe fn new(rec: &[crate::cells::Record], q: [Real; 3], sh: &[[Real; 16]; 3], rc2: Real) -> Self {
        let np = rec.len();
        // Checked once per cell by the caller (this runs for every particle).
        hot_assert!(np < (i32::MAX / 8) as usize, "too many particles");
        let r = rec.as_ptr().cast::<Real>();
        // SAFETY: each table holds 16 entries.
        let load16 = |t: &[Real; 16]| unsafe { (_mm512_loadu_pd(t.as_ptr()), _mm512_loadu_pd(t.as_ptr().add(8))) };
        Self {
            // SAFETY: a record holds 8 reals, so offsets 0..3 stay inside the first one (and a
            // null-length list is never gathered from: every lane is checked against np).
            p: unsafe { [r, r.add(1), r.add(2)] },
            n: _mm256_set1_epi32(np as i32),
            rc2: _mm512_set1_pd(rc2),
            q: [_mm512_set1_pd(q[0]), _mm512_set1_pd(q[1]), _mm512_set1_pd(q[2])],
            sh: [load16(&sh[0]), load16(&sh[1]), load16(&sh[2])],
        }
    }

    /// The plain indices of 8 tagged candidates `t` (lanes of `tail`), their dx, dy, dz, r²,
    /// and the lanes that pass the double-precision test 0 < r² < rc².
    ///
    /// # Safety
    /// As [`scan_avx512`]; panics if an index of a lane in `tail` is out of range.
    #[inline(always)]
    pub(crate) unsafe fn hits(&self, t: __m256i, tail: u8) -> (__m256i, [__m512d; 4], u8) {
        let j = _mm256_and_si256(t, _mm256_set1_epi32(((1u32 << TAG_SHIFT) - 1) as i32));
        assert!(
            _mm256_mask_cmpge_epu32_mask(tail, j, self.n) == 0,
            "hit index out of range"
        );
        let zero = _mm512_setzero_pd();
        let mut x = [zero; 3];
        // Each record is 8 reals: component c of record j is real 8j + c.
        let j8 = _mm256_slli_epi32::<3>(j);
        for (c, x) in x.iter_mut().enumerate() {
            // SAFETY: only lanes in `tail` are read, and their indices were checked above.
            *x = unsafe { _mm512_mask_i32gather_pd::<8>(zero, tail, j8, self.p[c]) };
        }
        let (d, pass) = self.separations(t, tail, x);
        (j, d, pass)
    }

    /// The dx, dy, dz, r² of 8 tagged candidates `t` (lanes of `tail`) at positions `x`, and the
    /// lanes that pass the double-precision test 0 < r² < rc²: `dx = (q − sh[tag]) − x`
    /// component by component, r² as [`r2_512`].
    ///
    /// # Safety
    /// As [`scan_avx512`] (AVX-512 F enabled in the caller).
    #[inline(always)]
    pub(crate) unsafe fn separations(&self, t: __m256i, tail: u8, x: [__m512d; 3]) -> ([__m512d; 4], u8) {
        // SAFETY: as this function's.
        unsafe { self.separations_from(self.q, t, tail, x) }
    }

    /// [`Geometry::separations`] with a query point per lane (`q`) instead of the one of
    /// [`Geometry::new`].
    ///
    /// # Safety
    /// As [`scan_avx512`] (AVX-512 F enabled in the caller).
    #[inline(always)]
    pub(crate) unsafe fn separations_from(
        &self,
        q: [__m512d; 3],
        t: __m256i,
        tail: u8,
        x: [__m512d; 3],
    ) -> ([__m512d; 4], u8) {
        let tag = _mm512_cvtepu32_epi64(_mm256_srli_epi32::<{ TAG_SHIFT as i32 }>(t));
        let zero = _mm512_setzero_pd();
        let mut d = [zero; 3];
        for c in 0..3 {
            let (lo, hi) = self.sh[c];
            d[c] = _mm512_sub_pd(_mm512_sub_pd(q[c], _mm512_permutex2var_pd(lo, tag, hi)), x[c]);
        }
        let r2 = r2_512(d[0], d[1], d[2]);
        let pass =
            _mm512_mask_cmp_pd_mask::<_CMP_LT_OQ>(tail, r2, self.rc2) & _mm512_cmp_pd_mask::<_CMP_GT_OQ>(r2, zero);
        ([d[0], d[1], d[2], r2], pass)
    }
}

/// Replaces the tagged candidates `h.j[lo..hi]` of [`scan_cell_avx512`] by the hits among them
/// (0 < r² < rc² in double precision), packed from `lo` in order, with plain sorted indices and
/// their separations and r²: `dx = (q − sh[tag]) − x_j` component by component (`sh[c][tag]`
/// is the shift of the range with that tag), r² as [`r2_512`] — the operations, and so the
/// values, of [`scan_avx512`] with `p = q − sh`. Returns the end of the hits.
///
/// # Safety
/// As [`scan_avx512`]. Panics unless `h`'s arrays hold `hi + 7` entries and every untagged index
/// is below the positions' length.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn separations_avx512(
    h: &mut HitArrays,
    (lo, hi): (usize, usize),
    rec: &[crate::cells::Record],
    q: [Real; 3],
    sh: &[[Real; 16]; 3],
    rc2: Real,
) -> usize {
    if lo >= hi {
        return lo;
    }
    let len =
        h.j.len()
            .min(h.dx.len())
            .min(h.dy.len())
            .min(h.dz.len())
            .min(h.r2.len());
    assert!(len >= hi + 7, "hit arrays too short");
    let g = Geometry::new(rec, q, sh, rc2);
    let o = h.ptrs();
    let (mut k, mut n) = (lo, lo);
    while k < hi {
        // SAFETY: n ≤ k, k + 7 < hi + 7 ≤ the asserted lengths; the stores at n .. n + 8 only
        // overwrite candidates already read; `Geometry::hits` checks the indices.
        unsafe {
            let valid = hi - k;
            let tail: u8 = if valid < 8 { (1u8 << valid) - 1 } else { 0xFF };
            let (j, [dx, dy, dz, r2], pass) = g.hits(_mm256_loadu_si256(o.j.add(k).cast()), tail);
            n = append_512(o, n, pass, j, [dx, dy, dz, r2]);
        }
        k += 8;
    }
    n
}

/// The constants of [`crate::kernel::DpdLinear`]'s force in vector registers, for
/// [`linear_lanes`].
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
struct LinearConsts {
    key: __m512i,
    inv_rc: __m512d,
    a: __m512d,
    gamma: __m512d,
    sigma_dt: __m512d,
    noisy: bool,
}

#[cfg(target_arch = "x86_64")]
impl LinearConsts {
    /// # Safety
    /// As [`scan_avx512`] (AVX-512 F enabled in the caller).
    #[inline(always)]
    unsafe fn new(key: u64, p: crate::kernel::LinearParams) -> Self {
        Self {
            key: _mm512_set1_epi64(key as i64),
            inv_rc: _mm512_set1_pd(p.inv_rc),
            a: _mm512_set1_pd(p.a),
            gamma: _mm512_set1_pd(p.gamma),
            sigma_dt: _mm512_set1_pd(p.sigma_dt),
            noisy: p.noisy,
        }
    }
}

/// The pair forces of 8 lanes: separations `d` (dx, dy, dz, r²), velocity differences `dv`
/// (vi − vj), the ids of i and j (as u64 lanes); lanes outside `pass` get +0.0. Each lane runs
/// the operations of `DpdLinear::force` and `rng::pair_xi` in their order (no fused
/// multiply–add), so every force equals the scalar one bit for bit.
///
/// # Safety
/// As [`scan_avx512`] (AVX-512 F and DQ enabled in the caller).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn linear_lanes(
    c: &LinearConsts,
    [dx, dy, dz, r2]: [__m512d; 4],
    pass: u8,
    [dvx, dvy, dvz]: [__m512d; 3],
    idi: __m512i,
    idj: __m512i,
) -> [__m512d; 3] {
    use crate::rng::{GOLDEN, MIX, SQRT3, XI_SCALE};
    let (zero, one) = (_mm512_setzero_pd(), _mm512_set1_pd(1.0));
    let xi = if c.noisy {
        let lo32 = _mm512_min_epu64(idi, idj);
        let hi32 = _mm512_max_epu64(idi, idj);
        let pos = _mm512_or_si512(_mm512_slli_epi64::<32>(lo32), hi32);
        let mut z = _mm512_add_epi64(c.key, _mm512_mullo_epi64(pos, _mm512_set1_epi64(GOLDEN as i64)));
        z = _mm512_mullo_epi64(
            _mm512_xor_si512(z, _mm512_srli_epi64::<30>(z)),
            _mm512_set1_epi64(MIX[0] as i64),
        );
        z = _mm512_mullo_epi64(
            _mm512_xor_si512(z, _mm512_srli_epi64::<27>(z)),
            _mm512_set1_epi64(MIX[1] as i64),
        );
        z = _mm512_xor_si512(z, _mm512_srli_epi64::<31>(z));
        let u = _mm512_cvtepu64_pd(_mm512_srli_epi64::<11>(z));
        _mm512_sub_pd(_mm512_mul_pd(u, _mm512_set1_pd(XI_SCALE)), _mm512_set1_pd(SQRT3))
    } else {
        zero
    };
    let r = _mm512_sqrt_pd(r2);
    let inv_r = _mm512_div_pd(one, r);
    let w = _mm512_sub_pd(one, _mm512_mul_pd(r, c.inv_rc));
    let dot = _mm512_add_pd(
        _mm512_add_pd(_mm512_mul_pd(dx, dvx), _mm512_mul_pd(dy, dvy)),
        _mm512_mul_pd(dz, dvz),
    );
    let edv = _mm512_mul_pd(dot, inv_r);
    let inner = _mm512_add_pd(
        _mm512_sub_pd(c.a, _mm512_mul_pd(_mm512_mul_pd(c.gamma, w), edv)),
        _mm512_mul_pd(c.sigma_dt, xi),
    );
    let s = _mm512_mul_pd(_mm512_mul_pd(w, inner), inv_r);
    // The prefilter's candidates that are not hits get a force of exactly +0.0, which changes
    // no sum: i's sum starts at +0.0 and so is never −0.0, and j gets −0.0.
    [
        _mm512_maskz_mov_pd(pass, _mm512_mul_pd(dx, s)),
        _mm512_maskz_mov_pd(pass, _mm512_mul_pd(dy, s)),
        _mm512_maskz_mov_pd(pass, _mm512_mul_pd(dz, s)),
    ]
}

/// The records of 8 partners, transposed into x, y, z, vx, vy, vz, id: lane l reads record
/// `index(l)`, clamped to the last record. `j` holds the same indices, checked for the lanes of
/// `tail` (the others, past the last hit, have their forces masked off).
///
/// The callers read the indices with volatile loads: plain loads of memory just loaded as the
/// vector `j` were turned by LLVM into extractions from `j` (two instructions per lane, which
/// were hot in the profile), where a scalar load is one (docs/performance.md, "Changes
/// tried").
///
/// # Safety
/// As [`scan_avx512`] (AVX-512 F enabled in the caller); `rec` is not empty and shorter than
/// `i32::MAX`. Panics unless the lanes of `tail` hold indices below `rec.len()`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn partner_records(
    rec: &[crate::cells::Record],
    j: __m256i,
    tail: u8,
    index: impl Fn(usize) -> usize,
) -> [__m512d; 7] {
    let n = _mm256_set1_epi32(rec.len() as i32);
    assert!(_mm256_mask_cmpge_epu32_mask(tail, j, n) == 0, "hit index out of range");
    let (rp, last) = (rec.as_ptr(), rec.len() - 1);
    let mut r = [_mm512_setzero_pd(); 8];
    for (l, r) in r.iter_mut().enumerate() {
        // SAFETY: the index is clamped to the last record; records are 64-byte aligned.
        *r = unsafe { _mm512_load_pd(rp.add(index(l).min(last)).cast()) };
    }
    // SAFETY: as this function's.
    unsafe { transpose8(r) }
}

/// The forces of [`crate::kernel::DpdLinear`] for the tagged hits `h.j[lo..hi]` of
/// [`scan_cell_avx512`] on a particle with velocity `vi` and id `idi`, 8 pairs at a time (AVX-512
/// F, VL and DQ), written to `out[c][k − lo]` (c = x, y, z). The 8 partners' records
/// ([`crate::cells::Record`]) are loaded whole and transposed into positions, velocities and ids,
/// instead of 7 gathers; the separations are those of [`Geometry::separations`], as in
/// [`Geometry::hits`], and the forces those of [`linear_lanes`]. Lanes past the last hit load the
/// last record; their forces are masked off.
///
/// # Safety
/// Only to be called from a function compiled with AVX-512 F, VL and DQ enabled on a CPU that
/// has them. The caller guarantees (checked here only in debug builds and unit tests, because this runs for
/// every particle) that `h.j` holds `hi + 7` entries, each of `out` `hi − lo + 7`, and `rec` is
/// not empty and shorter than `i32::MAX`. Panics unless every untagged index is below
/// `rec.len()`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn linear_forces_avx512(
    h: &HitArrays,
    (lo, hi): (usize, usize),
    rec: &[crate::cells::Record],
    vi: glam::DVec3,
    idi: u32,
    key: u64,
    p: crate::kernel::LinearParams,
    g: Geometry,
    mut out: [&mut [Real]; 3],
) {
    if lo >= hi {
        return;
    }
    // Checked once per cell by the caller (this runs for every particle).
    hot_assert!(
        h.j.len() >= hi + 7 && out.iter().all(|o| o.len() >= hi - lo + 7),
        "force arrays too short"
    );
    hot_assert!(!rec.is_empty() && rec.len() < i32::MAX as usize, "no records");
    // SAFETY: as this function's.
    let c = unsafe { LinearConsts::new(key, p) };
    let (vix, viy, viz) = (_mm512_set1_pd(vi.x), _mm512_set1_pd(vi.y), _mm512_set1_pd(vi.z));
    let idv64 = _mm512_set1_epi64(idi as i64);
    let low = (1u32 << TAG_SHIFT) - 1;
    let mut k = lo;
    while k < hi {
        // SAFETY: k + 7 < hi + 7 ≤ the asserted length of `h.j`; the records' loads are checked
        // by `partner_records`.
        unsafe {
            let valid = hi - k;
            let tail: u8 = if valid < 8 { (1u8 << valid) - 1 } else { 0xFF };
            let tv = _mm256_loadu_si256(h.j.as_ptr().add(k).cast());
            let j = _mm256_and_si256(tv, _mm256_set1_epi32(low as i32));
            let tagged = h.j.as_ptr().add(k);
            let [xj, yj, zj, vjx, vjy, vjz, idj] =
                partner_records(rec, j, tail, |l| (tagged.add(l).read_volatile() & low) as usize);
            let (d, pass) = g.separations(tv, tail, [xj, yj, zj]);
            let dv = [
                _mm512_sub_pd(vix, vjx),
                _mm512_sub_pd(viy, vjy),
                _mm512_sub_pd(viz, vjz),
            ];
            let f = linear_lanes(&c, d, pass, dv, idv64, _mm512_castpd_si512(idj));
            let o = k - lo;
            for (out, f) in out.iter_mut().zip(f) {
                _mm512_storeu_pd(out.as_mut_ptr().add(o), f);
            }
        }
        k += 8;
    }
}

/// Bits of a cell stream's hit ([`stream_cell_hits_avx512`]) that hold the query's place in its
/// cell (the slot, below 8), between the sorted index (below 2^SLOT_SHIFT) and the range's tag.
#[cfg(target_arch = "x86_64")]
pub(crate) const SLOT_SHIFT: u32 = 25;

/// Concatenates the hits of a cell's `nc ≤ 8` queries ([`scan_cell_avx512`]: query k's are
/// `hits[k · stride .. ns[k]]`) into `out` from 0, in query order, each with its slot k in the
/// bits from [`SLOT_SHIFT`]; returns their number. Writes up to 15 entries past the end.
///
/// # Safety
/// As [`scan_avx512`] (AVX-512 F enabled in the caller). The caller guarantees that every
/// query's region ends 16 entries before the next region's start (`ns[k] + 16 ≤ (k + 1) ·
/// stride`; the region bounds are checked only in debug builds and unit tests), `hits` holds `nc · stride`
/// entries, `out` holds their total + 16, and the sorted indices are below 2^SLOT_SHIFT (not
/// checked here: the slot would overwrite their high bits).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn stream_cell_hits_avx512(hits: &[u32], ns: &[usize], stride: usize, out: &mut [u32]) -> usize {
    let nc = ns.len();
    hot_assert!(
        nc <= 8 && hits.len() >= nc * stride,
        "cell too large, or hits too short"
    );
    let (src, dst) = (hits.as_ptr(), out.as_mut_ptr());
    let mut len = 0;
    for (k, &end) in ns.iter().enumerate() {
        let slot = _mm512_set1_epi32(((k as u32) << SLOT_SHIFT) as i32);
        let mut a = k * stride;
        hot_assert!(end + 16 <= (k + 1) * stride && len + (end - a) + 16 <= out.len());
        while a < end {
            // SAFETY: a + 15 < end + 16 ≤ this region's end (the caller's guarantee); the store
            // ends at most 15 entries past the stream's new end, inside `out`.
            unsafe {
                let t = _mm512_loadu_si512(src.add(a).cast());
                _mm512_storeu_si512(dst.add(len).cast(), _mm512_or_si512(t, slot));
            }
            let m = (end - a).min(16);
            len += m;
            a += m;
        }
    }
    len
}

/// The forces of [`crate::kernel::DpdLinear`] for a cell's stream of hits `stream[..len]`
/// ([`stream_cell_hits_avx512`]), 8 pairs at a time whatever query they belong to: each lane
/// takes its query's position, velocity and id from the cell's records (sorted particles s0 ..
/// s0 + nc, nc ≤ 8) by its slot, and then runs the operations of [`linear_forces_avx512`] (so the
/// same bits per pair). Written to `out[c][k]` (c = x, y, z). `g` gives the ranges' shifts and
/// the cutoff; its own query point is not used.
///
/// # Safety
/// As [`linear_forces_avx512`], with `stream` and each of `out` holding `len + 7` entries and
/// s0 + nc ≤ `rec.len()` (checked only in debug builds and unit tests); panics unless every sorted index in the
/// stream is below `rec.len()`.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub(crate) unsafe fn linear_forces_cell_avx512(
    (stream, len): (&[u32], usize),
    rec: &[crate::cells::Record],
    (s0, nc): (usize, usize),
    key: u64,
    p: crate::kernel::LinearParams,
    g: Geometry,
    mut out: [&mut [Real]; 3],
) {
    if len == 0 {
        return;
    }
    hot_assert!(stream.len() >= len + 7 && out.iter().all(|o| o.len() >= len + 7));
    hot_assert!((1..=8).contains(&nc) && s0 + nc <= rec.len() && rec.len() < i32::MAX as usize);
    // SAFETY: as this function's.
    let (c, [qx, qy, qz, vix, viy, viz, idi]) = unsafe {
        let own = _mm256_add_epi32(_mm256_set1_epi32(s0 as i32), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
        let tail = (1u16 << nc).wrapping_sub(1) as u8;
        (LinearConsts::new(key, p), partner_records(rec, own, tail, |l| s0 + l))
    };
    let idi = _mm512_castpd_si512(idi);
    let low = (1u32 << SLOT_SHIFT) - 1;
    let (lowv, slots) = (_mm256_set1_epi32(low as i32), _mm256_set1_epi32(7));
    let mut k = 0;
    while k < len {
        // SAFETY: k + 7 < len + 7 ≤ the stream's and the outputs' lengths; the records' loads
        // are checked by `partner_records`; the slots are below 8.
        unsafe {
            let valid = len - k;
            let tail: u8 = if valid < 8 { (1u8 << valid) - 1 } else { 0xFF };
            let tv = _mm256_loadu_si256(stream.as_ptr().add(k).cast());
            let j = _mm256_and_si256(tv, lowv);
            let slot = _mm512_cvtepu32_epi64(_mm256_and_si256(_mm256_srli_epi32::<{ SLOT_SHIFT as i32 }>(tv), slots));
            let own = |v: __m512d| _mm512_permutexvar_pd(slot, v);
            let tagged = stream.as_ptr().add(k);
            let [xj, yj, zj, vjx, vjy, vjz, idj] =
                partner_records(rec, j, tail, |l| (tagged.add(l).read_volatile() & low) as usize);
            let (d, pass) = g.separations_from([own(qx), own(qy), own(qz)], tv, tail, [xj, yj, zj]);
            let dv = [
                _mm512_sub_pd(own(vix), vjx),
                _mm512_sub_pd(own(viy), vjy),
                _mm512_sub_pd(own(viz), vjz),
            ];
            let idl = _mm512_permutexvar_epi64(slot, idi);
            let f = linear_lanes(&c, d, pass, dv, idl, _mm512_castpd_si512(idj));
            for (out, f) in out.iter_mut().zip(f) {
                _mm512_storeu_pd(out.as_mut_ptr().add(k), f);
            }
        }
        k += 8;
    }
}

/// Transposes 8 rows of 8 f64 into the first 7 columns.
///
/// # Safety
/// As [`scan_avx512`] (AVX-512 F enabled in the caller).
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn transpose8(r: [__m512d; 8]) -> [__m512d; 7] {
    // Pairs of rows interleaved: t[2m] holds columns 0, 2, 4, 6 of rows 2m, 2m + 1; t[2m + 1]
    // columns 1, 3, 5, 7.
    let t = [
        _mm512_unpacklo_pd(r[0], r[1]),
        _mm512_unpackhi_pd(r[0], r[1]),
        _mm512_unpacklo_pd(r[2], r[3]),
        _mm512_unpackhi_pd(r[2], r[3]),
        _mm512_unpacklo_pd(r[4], r[5]),
        _mm512_unpackhi_pd(r[4], r[5]),
        _mm512_unpacklo_pd(r[6], r[7]),
        _mm512_unpackhi_pd(r[6], r[7]),
    ];
    const EVEN: i32 = 0b10_00_10_00;
    const ODD: i32 = 0b11_01_11_01;
    // Rows 0–3 (u[..4]) and 4–7 (u[4..]): columns (0, 4), (2, 6), (1, 5), (3, 7).
    let u = [
        _mm512_shuffle_f64x2::<EVEN>(t[0], t[2]),
        _mm512_shuffle_f64x2::<ODD>(t[0], t[2]),
        _mm512_shuffle_f64x2::<EVEN>(t[1], t[3]),
        _mm512_shuffle_f64x2::<ODD>(t[1], t[3]),
        _mm512_shuffle_f64x2::<EVEN>(t[4], t[6]),
        _mm512_shuffle_f64x2::<ODD>(t[4], t[6]),
        _mm512_shuffle_f64x2::<EVEN>(t[5], t[7]),
        _mm512_shuffle_f64x2::<ODD>(t[5], t[7]),
    ];
    [
        _mm512_shuffle_f64x2::<EVEN>(u[0], u[4]),
        _mm512_shuffle_f64x2::<EVEN>(u[2], u[6]),
        _mm512_shuffle_f64x2::<EVEN>(u[1], u[5]),
        _mm512_shuffle_f64x2::<EVEN>(u[3], u[7]),
        _mm512_shuffle_f64x2::<ODD>(u[0], u[4]),
        _mm512_shuffle_f64x2::<ODD>(u[2], u[6]),
        _mm512_shuffle_f64x2::<ODD>(u[1], u[5]),
    ]
}
