//! CPU time of the whole process, for benchmarks on a machine that may be shared: the CPU
//! time of all threads is the fair measure of work, where wall time also counts the waits
//! for cores that other programs hold.
#![allow(dead_code)]

use std::time::Instant;

/// CPU time of all threads of this process in nanoseconds (Linux schedstat; 0 elsewhere).
/// On dedicated cores the wall time of a parallel stage approaches CPU time / threads.
pub fn cpu_ns() -> u64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return 0;
    };
    tasks
        .filter_map(|t| t.ok())
        .filter_map(|t| std::fs::read_to_string(t.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next().and_then(|v| v.parse::<u64>().ok()))
        .sum()
}

/// The result of `f`, with the wall and CPU milliseconds it took.
pub fn timed<T>(f: impl FnOnce() -> T) -> (T, f64, f64) {
    let c = cpu_ns();
    let t = Instant::now();
    let out = f();
    (out, t.elapsed().as_secs_f64() * 1e3, cpu_ns().saturating_sub(c) as f64 * 1e-6)
}
