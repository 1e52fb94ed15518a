//! [`SharedSlice`]: one mutable slice written by several threads at once, each thread at places
//! that the caller guarantees no other thread touches meanwhile. The cell sort places particles
//! through it ([`write`](SharedSlice::write)) and the half-shell slab tasks take their force
//! windows from it ([`window`](SharedSlice::window)); each use states at its call why the places
//! are disjoint. Every access is bounds-checked. Also [`prefetch`], the cache hint that the cell
//! build and the gather of the forces back to storage order use on the slices they read through a
//! permutation.

use std::marker::PhantomData;

/// A mutable slice shared between threads for disjoint writes.
pub(crate) struct SharedSlice<'a, T> {
    ptr: *mut T,
    len: usize,
    _slice: PhantomData<&'a mut [T]>,
}

// SAFETY: a `SharedSlice` is only a pointer to a slice borrowed mutably for its lifetime, so
// sharing it moves `T`s between threads (hence `T: Send`). Concurrent accesses are sound because
// their callers touch disjoint places (see `write` and `window`).
#[allow(unsafe_code)]
unsafe impl<T: Send> Sync for SharedSlice<'_, T> {}

impl<'a, T> SharedSlice<'a, T> {
    pub(crate) fn new(v: &'a mut [T]) -> Self {
        Self {
            ptr: v.as_mut_ptr(),
            len: v.len(),
            _slice: PhantomData,
        }
    }

    /// Writes `v` at `k` (dropping the old value); panics if `k` is out of range.
    ///
    /// # Safety
    /// No other thread reads or writes index `k`, and no window containing `k` is alive, while
    /// this call runs.
    #[allow(unsafe_code)]
    #[inline(always)]
    pub(crate) unsafe fn write(&self, k: usize, v: T) {
        assert!(k < self.len, "index {k} out of range 0..{}", self.len);
        // SAFETY: in bounds (checked); exclusive by the caller's guarantee.
        unsafe { *self.ptr.add(k) = v }
    }

    /// Entries `lo..hi`; panics unless `lo ≤ hi ≤ len`.
    ///
    /// # Safety
    /// No other window overlapping `lo..hi` may be alive, and no other thread may write into
    /// `lo..hi`, while the returned one is.
    #[allow(unsafe_code, clippy::mut_from_ref)]
    #[inline]
    pub(crate) unsafe fn window(&self, lo: usize, hi: usize) -> &mut [T] {
        assert!(
            lo <= hi && hi <= self.len,
            "window {lo}..{hi} out of range 0..{}",
            self.len
        );
        // SAFETY: in bounds (checked); exclusive by the caller's guarantee.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(lo), hi - lo) }
    }
}

/// Asks the CPU to bring the cache line of `slice[i]` into L1 (a hint: no effect on results,
/// and none at all off x86-64 or when `i` is out of range).
#[inline(always)]
pub(crate) fn prefetch<T>(slice: &[T], i: usize) {
    #[cfg(target_arch = "x86_64")]
    if i < slice.len() {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        // SAFETY: SSE is part of x86-64, and a prefetch neither reads into the program nor
        // faults; the address is inside the slice anyway.
        #[allow(unsafe_code)]
        unsafe {
            _mm_prefetch::<_MM_HINT_T0>(slice.as_ptr().add(i).cast())
        };
    }
}

#[cfg(test)]
#[allow(unsafe_code)]
mod tests {
    use super::SharedSlice;
    use rayon::prelude::*;

    #[test]
    fn disjoint_writes_and_windows_from_several_threads_land_where_asked() {
        let mut v = vec![0u32; 1000];
        {
            let s = SharedSlice::new(&mut v);
            // Each k is written by exactly one task.
            (0..1000usize)
                .into_par_iter()
                .for_each(|k| unsafe { s.write(999 - k, k as u32) });
        }
        assert!(v.iter().enumerate().all(|(i, &x)| x as usize == 999 - i));
        {
            let s = SharedSlice::new(&mut v);
            // Windows of 100 that tile the slice, one per task.
            (0..10usize).into_par_iter().for_each(|w| {
                let win = unsafe { s.window(100 * w, 100 * w + 100) };
                win.fill(w as u32);
            });
            assert!(unsafe { s.window(1000, 1000) }.is_empty());
        }
        assert!(v.iter().enumerate().all(|(i, &x)| x as usize == i / 100));
    }

    #[test]
    #[should_panic(expected = "index 5 out of range 0..5")]
    fn a_write_out_of_range_panics() {
        let mut v = [0u8; 5];
        let s = SharedSlice::new(&mut v);
        unsafe { s.write(5, 1) };
    }

    #[test]
    #[should_panic(expected = "window 3..6 out of range 0..5")]
    fn a_window_out_of_range_panics() {
        let mut v = [0u8; 5];
        let s = SharedSlice::new(&mut v);
        let _ = unsafe { s.window(3, 6) };
    }

    #[test]
    #[should_panic(expected = "window 4..3 out of range")]
    fn a_reversed_window_panics() {
        let mut v = [0u8; 5];
        let s = SharedSlice::new(&mut v);
        let _ = unsafe { s.window(4, 3) };
    }
}
