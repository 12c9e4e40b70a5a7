//! Disjoint row writes from parallel tasks. Both fast kernels write output rows from many
//! rayon tasks at once, each row by exactly one task (a chunk owns its output rows; within one
//! offset of a kernel map no output row repeats). Proving that to the borrow checker would
//! need a sort and a split per pass, so this wrapper hands out row slices through a raw
//! pointer, with bounds checked and the disjointness contract stated at every use.

use std::marker::PhantomData;

/// A mutable `f32` buffer whose rows may be written by several threads, one writer per row.
pub(crate) struct DisjointRows<'a> {
    ptr: *mut f32,
    len: usize,
    _buf: PhantomData<&'a mut [f32]>,
}

// SAFETY: access goes through `row`, whose contract forbids two live slices over one element.
unsafe impl Send for DisjointRows<'_> {}
// SAFETY: as above.
unsafe impl Sync for DisjointRows<'_> {}

impl<'a> DisjointRows<'a> {
    pub(crate) fn new(buf: &'a mut [f32]) -> Self {
        Self { ptr: buf.as_mut_ptr(), len: buf.len(), _buf: PhantomData }
    }

    /// The elements `start..start + len`.
    ///
    /// # Safety
    /// No other slice over any of these elements may be alive at the same time (on any
    /// thread).
    ///
    /// # Panics
    /// When the range leaves the buffer.
    #[allow(clippy::mut_from_ref)]
    pub(crate) unsafe fn slice(&self, start: usize, len: usize) -> &mut [f32] {
        assert!(start.checked_add(len).is_some_and(|e| e <= self.len));
        // SAFETY: in bounds (asserted); exclusivity is the caller's contract.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(start), len) }
    }
}
