//! Asking for memory ahead of use. The map is far larger than the caches, and several of
//! its readers (the ray-cast's march, the semantic cells' chunk reads) follow chains of
//! dependent reads: asked for early, a chunk's voxels arrive while other work goes on.

/// Asks for the cache lines at `count` offsets `stride` bytes apart from the start of `data`
/// (those inside it; `usize::MAX` for all): a hint, with no effect on results (none off
/// x86-64).
#[inline(always)]
pub fn prefetch<T>(data: &[T], stride: usize, count: usize) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let bytes = std::mem::size_of_val(data);
        let start = data.as_ptr().cast::<i8>();
        for offset in (0..bytes).step_by(stride.max(1)).take(count) {
            // SAFETY: a prefetch never faults, and the address lies inside `data`.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(start.add(offset)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (data, stride, count);
}
