//! Device time per kernel, from timestamp queries: where a network forward's milliseconds go
//! on a real GPU, which host timers cannot say (the host only sees the final wait). Opt-in,
//! with the environment variable `SEMRECON_GPU_PROFILE=1` on an adapter that offers
//! timestamp queries: each dispatch (one compute pass) then writes a timestamp at its start
//! and end; the pairs are resolved with the next read-back and summed per kernel
//! ([`crate::GpuContext::kernel_times`]). Off, it costs nothing.

use std::collections::BTreeMap;

use crate::kernel_time::KernelTime;

/// Dispatches timed between two read-backs at most (the rest go untimed): two queries each,
/// within wgpu's 4096 per query set.
const CAPACITY: u32 = 2048;

/// The query set and the dispatches timed since the last resolve.
pub(crate) struct Profiler {
    query_set: wgpu::QuerySet,
    resolve: wgpu::Buffer,
    /// Nanoseconds per timestamp tick.
    period: f64,
    /// The kernel of each timed dispatch, in query order (pair `i`: queries `2i`, `2i + 1`).
    pending: Vec<String>,
    totals: BTreeMap<String, (u64, f64)>,
}

impl Profiler {
    /// A profiler when the environment asks for one and the device can (it was opened with
    /// [`wgpu::Features::TIMESTAMP_QUERY`]).
    pub(crate) fn new(device: &wgpu::Device, queue: &wgpu::Queue) -> Option<Self> {
        if !device.features().contains(wgpu::Features::TIMESTAMP_QUERY) {
            return None;
        }
        let query_set = device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("kernel timestamps"),
            ty: wgpu::QueryType::Timestamp,
            count: 2 * CAPACITY,
        });
        let resolve = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("kernel timestamps"),
            size: u64::from(2 * CAPACITY) * 8,
            usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        Some(Self {
            query_set,
            resolve,
            period: f64::from(queue.get_timestamp_period()),
            pending: Vec::new(),
            totals: BTreeMap::new(),
        })
    }

    /// Whether `SEMRECON_GPU_PROFILE` asks for profiling.
    pub(crate) fn wanted() -> bool {
        std::env::var("SEMRECON_GPU_PROFILE").is_ok_and(|v| v != "0" && !v.is_empty())
    }

    /// The timestamp writes of the next dispatch of `kernel` (none once the set is full).
    pub(crate) fn next(&mut self, kernel: String) -> Option<(wgpu::QuerySet, u32)> {
        let i = u32::try_from(self.pending.len()).ok().filter(|&i| i < CAPACITY)?;
        self.pending.push(kernel);
        Some((self.query_set.clone(), 2 * i))
    }

    /// Records the resolve of the pending timestamps into `staging` (a mappable buffer of
    /// [`Self::staging_bytes`]); returns the kernels it holds, in order.
    pub(crate) fn resolve(&mut self, encoder: &mut wgpu::CommandEncoder, staging: &wgpu::Buffer) -> Vec<String> {
        let n = self.pending.len() as u32;
        if n > 0 {
            encoder.resolve_query_set(&self.query_set, 0..2 * n, &self.resolve, 0);
            encoder.copy_buffer_to_buffer(&self.resolve, 0, staging, 0, u64::from(2 * n) * 8);
        }
        std::mem::take(&mut self.pending)
    }

    /// Bytes a staging buffer needs for the pending timestamps (0: nothing to resolve).
    pub(crate) fn staging_bytes(&self) -> u64 {
        self.pending.len() as u64 * 16
    }

    /// Adds resolved timestamps (`[2 n]` ticks) of `kernels` to the totals.
    pub(crate) fn add(&mut self, kernels: Vec<String>, ticks: &[u64]) {
        for (k, pair) in kernels.into_iter().zip(ticks.chunks_exact(2)) {
            let e = self.totals.entry(k).or_insert((0, 0.0));
            e.0 += 1;
            e.1 += pair[1].saturating_sub(pair[0]) as f64 * self.period * 1e-9;
        }
    }

    /// The totals, longest first, and a reset.
    pub(crate) fn take(&mut self) -> Vec<KernelTime> {
        let mut out: Vec<KernelTime> = std::mem::take(&mut self.totals)
            .into_iter()
            .map(|(k, (d, s))| KernelTime { kernel: k, dispatches: d, seconds: s })
            .collect();
        out.sort_by(|a, b| b.seconds.total_cmp(&a.seconds));
        out
    }
}
