//! The AVX2 build of the pair loops' distance test, used when the CPU reports AVX2 at run time
//! (`pairs::Run::simd`); other CPUs run the portable loop in [`crate::pairs`]. Both test the same
//! candidates with the same IEEE operations (no fused multiply–add, no reordering) and append
//! the hits in the same order, so the forces agree bit for bit.
#![allow(unsafe_code)]

#[cfg(target_arch = "x86_64")]
use std::arch::x86_64::*;

use crate::Real;

/// For each 4-bit lane mask, the indices of its set lanes packed to the front (increasing).
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
    pub fn reserve(&mut self, m: usize) {
        if self.j.len() < m {
            self.j.resize(m, 0);
            for a in [&mut self.dx, &mut self.dy, &mut self.dz, &mut self.r2] {
                a.resize(m, 0.0);
            }
        }
    }
}

/// Panics unless a scan of `a..e` in chunks of `L` lanes can read and write without bounds
/// checks: the inputs padded to `e + L − 1`, the hit arrays `n + (e − a) + L` long.
#[inline(always)]
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
    let (oj, ox, oy, oz, or) = (
        out.j.as_mut_ptr(),
        out.dx.as_mut_ptr(),
        out.dy.as_mut_ptr(),
        out.dz.as_mut_ptr(),
        out.r2.as_mut_ptr(),
    );
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
            _mm_storeu_si128(oj.add(n).cast(), _mm_add_epi32(_mm_set1_epi32(j as i32), lanes));
            let perm = _mm256_loadu_si256(PACK64.as_ptr().add(mask).cast());
            let pack = |v: __m256d| _mm256_castsi256_pd(_mm256_permutevar8x32_epi32(_mm256_castpd_si256(v), perm));
            _mm256_storeu_pd(ox.add(n), pack(dx));
            _mm256_storeu_pd(oy.add(n), pack(dy));
            _mm256_storeu_pd(oz.add(n), pack(dz));
            _mm256_storeu_pd(or.add(n), pack(r2));
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
    let (oj, ox, oy, oz, or) = (
        out.j.as_mut_ptr(),
        out.dx.as_mut_ptr(),
        out.dy.as_mut_ptr(),
        out.dz.as_mut_ptr(),
        out.r2.as_mut_ptr(),
    );
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
            // (dx² + dy²) + dz², as the scalar loop and `DVec3::dot` evaluate it
            let r2 = _mm512_add_pd(
                _mm512_add_pd(_mm512_mul_pd(dx, dx), _mm512_mul_pd(dy, dy)),
                _mm512_mul_pd(dz, dz),
            );
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
            _mm256_storeu_si256(oj.add(n).cast(), _mm256_maskz_compress_epi32(mask, js));
            _mm512_storeu_pd(ox.add(n), _mm512_maskz_compress_pd(mask, dx));
            _mm512_storeu_pd(oy.add(n), _mm512_maskz_compress_pd(mask, dy));
            _mm512_storeu_pd(oz.add(n), _mm512_maskz_compress_pd(mask, dz));
            _mm512_storeu_pd(or.add(n), _mm512_maskz_compress_pd(mask, r2));
            n += mask.count_ones() as usize;
        }
        j += 8;
    }
    n
}
