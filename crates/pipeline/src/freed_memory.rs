//! Returning freed heap memory to the operating system while a large structure is taken
//! apart. glibc's allocator keeps the memory of small freed blocks (a chunk mesh's vectors
//! are a few kilobytes each) in its free lists, resident, unless it lies at the top of a
//! heap; a whole mesh then built beside them, in allocations of hundreds of megabytes that
//! those lists cannot serve, adds to the process's peak instead of replacing them.
//! `malloc_trim` gives the free lists' whole pages back. Elsewhere this does nothing.

/// Returns the allocator's free pages to the operating system (glibc on Linux; a no-op
/// elsewhere).
pub(crate) fn return_to_os() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: `malloc_trim` takes no pointer and only walks the allocator's own free lists;
    // it is safe to call from any thread at any time.
    unsafe {
        libc::malloc_trim(0);
    }
}
