//! Device time of one kernel (the GPU profiler's result, `GpuContext::kernel_times`): plain
//! data, in every build, so that callers print it without conditional code.

/// Device seconds and dispatches of one kernel, summed since the last reset.
#[derive(Debug, Clone, PartialEq)]
pub struct KernelTime {
    /// The kernel's entry point (and tile shape for the chunked kernel).
    pub kernel: String,
    /// Dispatches timed.
    pub dispatches: u64,
    /// Device seconds between their start and end timestamps, summed.
    pub seconds: f64,
}
