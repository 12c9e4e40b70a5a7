//! Device set-up and the plumbing every kernel shares: one Vulkan adapter and device, the
//! compiled pipelines, buffer creation checked against the device's limits, dispatch and
//! read-back.
//!
//! wgpu reports device errors through callbacks (its default handler panics). The context
//! installs its own handlers, which record validation errors and device loss, and every
//! engine call checks them after waiting for the queue, so a lost device or a bad dispatch
//! becomes a [`GpuError`] instead of a panic or a silently wrong result.
//!
//! Operations on resident tensors do not wait: they record into one queued encoder (and one
//! compute pass, crate::record) that goes to the device every few dozen operations or before
//! the next read-back, so a network forward costs a handful of submissions, not one per layer.
//! Data is written into a buffer through the queue only while nothing queued uses it (fresh
//! buffers, or pooled ones after [`GpuContext::flush`]), because queue writes land before the
//! commands of the submission they precede. Every transfer is counted ([`TransferCounts`]).

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{mpsc, Arc, Mutex, MutexGuard};
use std::time::Instant;

use crate::error::{GpuError, Result};
use crate::kernel_time::KernelTime;
use crate::profile::Profiler;
use crate::record::{ParamArena, Recorder};
use crate::tile::CHUNKED_TILES;
use crate::transfers::TransferCounts;

/// Threads per workgroup of the one-dimensional kernels (and of the chunked kernel).
pub(crate) const WORKGROUP: u32 = 64;
/// Largest workgroup count of one grid dimension (the WebGPU minimum every device offers).
const MAX_GROUPS: u32 = 65_535;
/// Workgroup memory the chunked kernel uses at most, in bytes (within WebGPU's 16 KiB minimum).
const WORKGROUP_BYTES: u32 = {
    let mut most = 0;
    let mut i = 0;
    while i < CHUNKED_TILES.len() {
        let b = CHUNKED_TILES[i].workgroup_bytes();
        if b > most {
            most = b;
        }
        i += 1;
    }
    most
};
/// Read-back buffers up to this size are kept between calls (one per power of two): a call's
/// status words and labels, not the logits of a large room.
const STAGING_POOLED: u64 = 8 << 20;
/// Operations queued before they are submitted without waiting for a read-back: few
/// submissions per forward, without holding an unbounded backlog. The environment variable
/// `SEMRECON_GPU_SUBMIT_EVERY` sets another count (a tuning knob: on lavapipe 256 took a
/// third off the host's CPU per call, but the device then starts later; a GPU decides).
const MAX_PENDING: usize = 32;

/// Operations queued before a submission: `SEMRECON_GPU_SUBMIT_EVERY` when it is a positive
/// count, else [`MAX_PENDING`].
fn submit_every() -> usize {
    std::env::var("SEMRECON_GPU_SUBMIT_EVERY")
        .ok()
        .and_then(|v| v.trim().parse::<usize>().ok())
        .filter(|&n| n > 0)
        .unwrap_or(MAX_PENDING)
}

/// Which counter a transfer goes to.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Transfer {
    /// Features and weights.
    Tensor,
    /// Plans, pair lists, tables, coordinates.
    Geometry,
}

/// The compute pipelines of the engine, compiled once per context.
pub(crate) struct Pipelines {
    pub map_insert: wgpu::ComputePipeline,
    pub map_lookup: wgpu::ComputePipeline,
    /// The chunked kernel, one per tile shape of `CHUNKED_TILES`.
    pub chunked: [wgpu::ComputePipeline; CHUNKED_TILES.len()],
    pub gather: wgpu::ComputePipeline,
    pub gemm: wgpu::ComputePipeline,
    pub scatter: wgpu::ComputePipeline,
    pub bn_relu: wgpu::ComputePipeline,
    pub weight_grad: wgpu::ComputePipeline,
    /// The chunked algorithm's weight gradient (shaders/weight_grad.wgsl).
    pub weight_grad_tiled: wgpu::ComputePipeline,
    /// Sums its segments' partial weight gradients.
    pub reduce_segments: wgpu::ComputePipeline,
    pub gate: wgpu::ComputePipeline,
    pub gather_add: wgpu::ComputePipeline,
    pub add_bias: wgpu::ComputePipeline,
    pub argmax: wgpu::ComputePipeline,
    /// Adds the chunked kernel's partial sums of split offsets.
    pub split_sum: wgpu::ComputePipeline,
    /// The device voxel hierarchy's kernels (shaders/hierarchy.wgsl).
    pub hierarchy: HierarchyPipelines,
    /// Every pipeline's name (for the profiler) and bind group layout.
    names: HashMap<wgpu::ComputePipeline, (&'static str, wgpu::BindGroupLayout)>,
}

/// The entry points of shaders/hierarchy.wgsl.
pub(crate) struct HierarchyPipelines {
    pub insert: wgpu::ComputePipeline,
    pub first_child: wgpu::ComputePipeline,
    pub scan_blocks: wgpu::ComputePipeline,
    pub scan_totals: wgpu::ComputePipeline,
    pub scan_add: wgpu::ComputePipeline,
    pub emit: wgpu::ComputePipeline,
    pub fill: wgpu::ComputePipeline,
    pub rows: wgpu::ComputePipeline,
    pub ancestor: wgpu::ComputePipeline,
    pub interp: wgpu::ComputePipeline,
}

/// An opened GPU: device, queue, pipelines and the error state of the device.
pub struct GpuContext {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    pub(crate) pipelines: Pipelines,
    info: wgpu::AdapterInfo,
    limits: wgpu::Limits,
    /// A cap below the device's buffer limit ([`Self::set_buffer_limit`]).
    buffer_cap: Option<u64>,
    errors: Arc<Mutex<Vec<String>>>,
    lost: Arc<Mutex<Option<String>>>,
    /// Per-call buffers (features, weights, outputs, scratch) by role, kept between calls and
    /// only grown, so repeated calls (every layer of the network, every call of a benchmark)
    /// allocate nothing on the device. Layer geometry is never pooled.
    pool: Mutex<HashMap<&'static str, wgpu::Buffer>>,
    /// Read-back buffers not in use, at most one per power of two (see [`STAGING_POOLED`]).
    staging: Mutex<Vec<wgpu::Buffer>>,
    /// Held for a whole engine call: pooled buffers are then never shared by two calls.
    call: Mutex<()>,
    /// Recorded work of resident-tensor operations not yet submitted.
    pending: Mutex<Option<Recorder>>,
    /// Operations queued before a submission ([`submit_every`]).
    submit_every: usize,
    /// The parameters of recorded dispatches (and the submissions so far: see
    /// [`Self::submit`]).
    params: Mutex<ParamArena>,
    /// Recorders alive: while one is, recorded parameters may still be unsubmitted.
    live: Arc<AtomicUsize>,
    /// Host-device transfers so far.
    transfers: Mutex<TransferCounts>,
    /// Dispatches recorded so far, and the host's nanoseconds recording them (parameters,
    /// bind group, pass): the per-dispatch overhead a network of many small layers pays.
    recorded: (AtomicU64, AtomicU64),
    /// Device time per kernel (`SEMRECON_GPU_PROFILE=1`), absent otherwise.
    profiler: Option<Mutex<Profiler>>,
}

impl std::fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuContext").field("adapter", &self.adapter_name()).finish_non_exhaustive()
    }
}

/// Checks one adapter limit against what the engine needs.
fn need(info: &wgpu::AdapterInfo, what: &'static str, has: u64, needs: u64) -> Result<()> {
    if has < needs {
        return Err(GpuError::MissingCapability { adapter: info.name.clone(), what, has, needs });
    }
    Ok(())
}

impl GpuContext {
    /// Opens the first Vulkan adapter (`WGPU_ADAPTER_NAME` and `WGPU_BACKEND` pick another)
    /// with the best limits it offers, and compiles the kernels.
    ///
    /// # Errors
    /// [`GpuError::NoAdapter`] without a Vulkan driver, [`GpuError::MissingCapability`] when a
    /// limit the kernels need is missing, [`GpuError::RequestDevice`] / [`GpuError::Device`]
    /// when the device cannot be opened or a kernel does not compile on it.
    pub fn new() -> Result<Self> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        desc.backends = wgpu::Backends::VULKAN;
        let instance = wgpu::Instance::new(desc);
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            apply_limit_buckets: false,
        }))
        .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let info = adapter.get_info();
        let limits = adapter.limits();
        need(&info, "compute invocations per workgroup", limits.max_compute_invocations_per_workgroup.into(), 256)?;
        need(
            &info,
            "workgroup storage bytes",
            limits.max_compute_workgroup_storage_size.into(),
            WORKGROUP_BYTES.into(),
        )?;
        // The hierarchy's emit kernel binds eight (the WebGPU minimum).
        need(&info, "storage buffers per shader stage", limits.max_storage_buffers_per_shader_stage.into(), 8)?;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("semrecon-gpu"),
            required_features: if Profiler::wanted() {
                adapter.features() & wgpu::Features::TIMESTAMP_QUERY
            } else {
                wgpu::Features::empty()
            },
            required_limits: limits.clone(),
            experimental_features: wgpu::ExperimentalFeatures::disabled(),
            memory_hints: wgpu::MemoryHints::Performance,
            trace: wgpu::Trace::Off,
        }))
        .map_err(|e| GpuError::RequestDevice(e.to_string()))?;

        let errors = Arc::new(Mutex::new(Vec::new()));
        let lost = Arc::new(Mutex::new(None));
        {
            let errors = Arc::clone(&errors);
            device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
                if let Ok(mut v) = errors.lock() {
                    v.push(e.to_string());
                }
            }));
            let lost = Arc::clone(&lost);
            device.set_device_lost_callback(move |reason, message| {
                if let Ok(mut l) = lost.lock() {
                    *l = Some(format!("{reason:?}: {message}"));
                }
            });
        }
        let pipelines = Pipelines::new(&device);
        let params = ParamArena::new(&device, limits.min_uniform_buffer_offset_alignment);
        let profiler = Profiler::new(&device, &queue).map(Mutex::new);
        let context = Self {
            device,
            queue,
            pipelines,
            info,
            limits,
            buffer_cap: None,
            errors,
            lost,
            pool: Mutex::new(HashMap::new()),
            staging: Mutex::new(Vec::new()),
            call: Mutex::new(()),
            pending: Mutex::new(None),
            submit_every: submit_every(),
            params: Mutex::new(params),
            live: Arc::new(AtomicUsize::new(0)),
            transfers: Mutex::new(TransferCounts::default()),
            recorded: (AtomicU64::new(0), AtomicU64::new(0)),
            profiler,
        };
        context.check()?;
        Ok(context)
    }

    /// The adapter's name and driver, e.g. `llvmpipe (LLVM 15.0.6, 256 bits) (Mesa 22.3.6)`.
    pub fn adapter_name(&self) -> String {
        let i = &self.info;
        if i.driver_info.is_empty() {
            i.name.clone()
        } else {
            format!("{} ({})", i.name, i.driver_info)
        }
    }

    /// Whether the adapter is a CPU software rasteriser (lavapipe, SwiftShader): correct,
    /// but its timings say nothing about a real GPU.
    pub fn is_software(&self) -> bool {
        self.info.device_type == wgpu::DeviceType::Cpu
    }

    /// [`GpuError::DeviceLost`] once the device is gone.
    pub(crate) fn check_lost(&self) -> Result<()> {
        match self.lost.lock() {
            Ok(l) => match &*l {
                Some(reason) => Err(GpuError::DeviceLost(reason.clone())),
                None => Ok(()),
            },
            Err(_) => Err(GpuError::DeviceLost("device state poisoned".into())),
        }
    }

    /// The errors recorded since the last check, as one error (device loss first).
    pub(crate) fn check(&self) -> Result<()> {
        self.check_lost()?;
        let mut errors = self.errors.lock().map_err(|_| GpuError::Device("error log poisoned".into()))?;
        if errors.is_empty() {
            return Ok(());
        }
        let message = errors.join("; ");
        errors.clear();
        Err(GpuError::Device(message))
    }

    /// Bytes a storage buffer may hold on this device.
    pub fn max_buffer_bytes(&self) -> u64 {
        let device = self.limits.max_storage_buffer_binding_size.min(self.limits.max_buffer_size);
        self.buffer_cap.map_or(device, |c| c.min(device))
    }

    /// Treats buffers over `bytes` as over the device's limit (to leave memory to others, and
    /// to test the limit without filling a real device).
    pub fn set_buffer_limit(&mut self, bytes: u64) {
        self.buffer_cap = Some(bytes);
    }

    /// Destroys the device: every later call fails with [`GpuError::DeviceLost`] (what a
    /// driver reset or a removed GPU looks like to the engine).
    pub fn destroy(&self) {
        self.device.destroy();
    }

    fn check_size(&self, what: &'static str, bytes: u64) -> Result<()> {
        let limit = self.max_buffer_bytes();
        if bytes > limit {
            return Err(GpuError::TooLarge { what, bytes, limit });
        }
        Ok(())
    }

    /// A new storage buffer holding layer geometry `data` (at least one word: empty bindings
    /// are invalid).
    pub(crate) fn upload<T: bytemuck::Pod>(&self, what: &'static str, data: &[T]) -> Result<wgpu::Buffer> {
        self.upload_counted(what, data, Transfer::Geometry)
    }

    /// A new storage buffer holding `data`, counted as `kind`.
    ///
    /// Written through the queue, not mapped at creation: wgpu's mapped-at-creation path
    /// panics on a lost device, the queue write reports an error. The buffer is new, so no
    /// queued command can see the write land early.
    pub(crate) fn upload_counted<T: bytemuck::Pod>(
        &self,
        what: &'static str,
        data: &[T],
        kind: Transfer,
    ) -> Result<wgpu::Buffer> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let buffer = self.zeroed(what, bytes.len() as u64)?;
        if !bytes.is_empty() {
            self.queue.write_buffer(&buffer, 0, bytes);
            self.count(kind, bytes.len());
        }
        Ok(buffer)
    }

    /// Adds one transfer of `bytes` to the counters.
    fn count(&self, kind: Transfer, bytes: usize) {
        let mut t = self.transfers.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let bytes = bytes as u64;
        match kind {
            Transfer::Tensor => {
                t.tensor_uploads += 1;
                t.tensor_bytes += bytes;
            }
            Transfer::Geometry => {
                t.geometry_uploads += 1;
                t.geometry_bytes += bytes;
            }
        }
    }

    /// The host-device transfers since the context was opened (take two snapshots and
    /// [`TransferCounts::since`] for one call's).
    pub fn transfers(&self) -> TransferCounts {
        *self.transfers.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Dispatches recorded since the context was opened, and the host's seconds spent
    /// recording them (kernel parameters, bind groups, passes; not the device's work).
    pub fn dispatches(&self) -> (u64, f64) {
        (self.recorded.0.load(Ordering::Relaxed), self.recorded.1.load(Ordering::Relaxed) as f64 * 1e-9)
    }

    /// Whether kernels are being timed on the device (`SEMRECON_GPU_PROFILE=1` and an adapter
    /// with timestamp queries).
    pub fn profiling(&self) -> bool {
        self.profiler.is_some()
    }

    /// Device seconds per kernel since the last call (longest first), from the dispatches
    /// whose work has been read back; empty when not [`profiling`](Self::profiling).
    pub fn kernel_times(&self) -> Vec<KernelTime> {
        self.profiler
            .as_ref()
            .map_or_else(Vec::new, |p| p.lock().unwrap_or_else(std::sync::PoisonError::into_inner).take())
    }

    /// Exclusive use of the pooled buffers for one call of the host-slice interface, with the
    /// queued resident work submitted first (the call then writes into pooled buffers that no
    /// queued command may see).
    pub(crate) fn begin_call(&self) -> Result<MutexGuard<'_, ()>> {
        let guard = self.begin_resident_call()?;
        self.flush()?;
        Ok(guard)
    }

    /// Exclusive use of the pooled buffers while one resident operation is recorded.
    pub(crate) fn begin_resident_call(&self) -> Result<MutexGuard<'_, ()>> {
        self.check_lost()?;
        // A panic while holding the lock left no buffer in a state a later call relies on.
        Ok(self.call.lock().unwrap_or_else(std::sync::PoisonError::into_inner))
    }

    /// The queued work.
    fn pending(&self) -> MutexGuard<'_, Option<Recorder>> {
        self.pending.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// The parameter pages.
    fn arena(&self) -> MutexGuard<'_, ParamArena> {
        self.params.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Records one resident operation with `op` into the queued work, which is submitted once
    /// it holds enough operations. Should `op` fail, what it recorded stays queued with the
    /// rest (the earlier operations' work must not be lost).
    pub(crate) fn record<T>(&self, op: impl FnOnce(&mut Recorder) -> Result<T>) -> Result<T> {
        let mut pending = self.pending();
        let recorder = pending.get_or_insert_with(|| Recorder::new(&self.device, &self.live));
        let out = op(recorder);
        recorder.ops += 1;
        if recorder.ops >= self.submit_every {
            let full = pending.take();
            drop(pending);
            self.submit(full);
            self.check()?;
        }
        out
    }

    /// Submits the queued work without waiting for it.
    ///
    /// # Errors
    /// A lost device, validation errors recorded so far.
    pub fn flush(&self) -> Result<()> {
        let queued = self.pending().take();
        if let Some(recorder) = queued {
            self.submit([recorder]);
        }
        self.check()
    }

    /// Submits `recorders`' work, in order, after the parameters recorded so far; returns the
    /// number of this submission. Under the parameters' lock: no page is recycled between a
    /// recorder's end and its submission.
    fn submit(&self, recorders: impl IntoIterator<Item = Recorder>) -> u64 {
        let mut arena = self.arena();
        arena.write(&self.queue);
        let work: Vec<wgpu::CommandBuffer> = recorders.into_iter().map(Recorder::finish).collect();
        self.queue.submit(work);
        arena.submissions += 1;
        arena.submissions
    }

    /// Lets the parameter pages be reused once the device has finished submission `waited`,
    /// when it is the last one and no recorder is alive (nothing recorded can read them).
    fn recycle_params(&self, waited: u64) {
        let mut arena = self.arena();
        if arena.submissions == waited && self.live.load(Ordering::Acquire) == 0 {
            arena.recycle();
        }
    }

    /// The pooled storage buffer of `role` with room for `bytes` (contents undefined), grown
    /// to the next power of two when too small. Callers hold [`Self::begin_call`]'s guard.
    pub(crate) fn transient(&self, role: &'static str, bytes: u64) -> Result<wgpu::Buffer> {
        self.check_lost()?;
        self.check_size(role, bytes)?;
        let mut pool = self.pool.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(b) = pool.get(role) {
            if b.size() >= bytes.max(4) {
                return Ok(b.clone());
            }
        }
        let limit = self.max_buffer_bytes();
        let size = bytes.max(4).next_power_of_two().min(limit).max(bytes.max(4).next_multiple_of(4));
        let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST;
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(role),
            size,
            usage,
            mapped_at_creation: false,
        });
        pool.insert(role, buffer.clone());
        Ok(buffer)
    }

    /// The pooled buffer of `role` holding `data`.
    pub(crate) fn transient_upload<T: bytemuck::Pod>(&self, role: &'static str, data: &[T]) -> Result<wgpu::Buffer> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        let buffer = self.transient(role, bytes.len() as u64)?;
        if !bytes.is_empty() {
            self.queue.write_buffer(&buffer, 0, bytes);
            self.count(Transfer::Tensor, bytes.len());
        }
        Ok(buffer)
    }

    /// A zero-filled storage buffer of `bytes` (at least 4).
    pub(crate) fn zeroed(&self, what: &'static str, bytes: u64) -> Result<wgpu::Buffer> {
        self.check_lost()?;
        self.check_size(what, bytes)?;
        let usage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC | wgpu::BufferUsages::COPY_DST;
        // New buffers are zero-initialised by wgpu.
        Ok(self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(what),
            size: bytes.max(4).next_multiple_of(4),
            usage,
            mapped_at_creation: false,
        }))
    }

    /// Records one dispatch of `pipeline` with the kernel parameters `params` (`u32` words,
    /// binding 0) and `bindings` (binding number, buffer) over a grid of `groups` workgroups
    /// (folded into x and y past the per-dimension limit) times `z` in the third dimension.
    pub(crate) fn dispatch(
        &self,
        rec: &mut Recorder,
        pipeline: &wgpu::ComputePipeline,
        params: &[u32],
        bindings: &[(u32, &wgpu::Buffer)],
        groups: u32,
        z: u32,
    ) {
        self.dispatch_shaped(rec, pipeline, params, bindings, groups, z, String::new);
    }

    /// [`Self::dispatch`] with the problem's shape for the profiler (`shape` is only called
    /// when profiling): its times are then kept per kernel and shape.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn dispatch_shaped(
        &self,
        rec: &mut Recorder,
        pipeline: &wgpu::ComputePipeline,
        params: &[u32],
        bindings: &[(u32, &wgpu::Buffer)],
        groups: u32,
        z: u32,
        shape: impl FnOnce() -> String,
    ) {
        if groups == 0 || z == 0 {
            return;
        }
        let start = Instant::now();
        let slot = self.arena().push(&self.device, &self.queue, params);
        let (name, layout) = self.pipelines.info(pipeline);
        let mut entries = Vec::with_capacity(bindings.len() + 1);
        entries.push(wgpu::BindGroupEntry {
            binding: 0,
            resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                buffer: &slot.buffer,
                offset: slot.offset,
                size: Some(slot.size),
            }),
        });
        entries.extend(
            bindings
                .iter()
                .map(|&(binding, buffer)| wgpu::BindGroupEntry { binding, resource: buffer.as_entire_binding() }),
        );
        let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &layout,
            entries: &entries,
        });
        let (x, y) = grid(groups);
        let timed = self.profiler.as_ref().and_then(|p| {
            let shape = shape();
            let label = if shape.is_empty() { name.to_string() } else { format!("{name} {shape}") };
            p.lock().unwrap_or_else(std::sync::PoisonError::into_inner).next(label)
        });
        match &timed {
            // Timestamps are written at a pass's start and end: a timed dispatch has its own.
            Some((query_set, i)) => {
                let mut pass = rec.timed_pass(wgpu::ComputePassTimestampWrites {
                    query_set,
                    beginning_of_pass_write_index: Some(*i),
                    end_of_pass_write_index: Some(i + 1),
                });
                pass.set_pipeline(pipeline);
                pass.set_bind_group(0, &group, &[]);
                pass.dispatch_workgroups(x, y, z);
            }
            None => {
                let pass = rec.pass();
                pass.set_pipeline(pipeline);
                pass.set_bind_group(0, &group, &[]);
                pass.dispatch_workgroups(x, y, z);
            }
        }
        self.recorded.0.fetch_add(1, Ordering::Relaxed);
        self.recorded.1.fetch_add(start.elapsed().as_nanos() as u64, Ordering::Relaxed);
    }

    /// A new recorder, for work submitted by a read-back ([`Self::finish_and_read`]), after
    /// the queued work.
    pub(crate) fn encoder(&self) -> Recorder {
        Recorder::new(&self.device, &self.live)
    }

    /// Submits the queued work and `encoder` after appending a copy of the first `count`
    /// values of `buffer` to a staging buffer, waits, and returns them.
    pub(crate) fn finish_and_read<T: bytemuck::Pod>(
        &self,
        encoder: Recorder,
        buffer: &wgpu::Buffer,
        count: usize,
    ) -> Result<Vec<T>> {
        self.submit_and_read(encoder, buffer, count, false)
    }

    /// As [`Self::finish_and_read`], for a few status words the host needs before it can go
    /// on (counted as a status read, not a read-back of data).
    pub(crate) fn finish_and_read_status(
        &self,
        encoder: Recorder,
        buffer: &wgpu::Buffer,
        count: usize,
    ) -> Result<Vec<u32>> {
        self.submit_and_read(encoder, buffer, count, true)
    }

    /// A read-back buffer of at least `bytes`, unmapped and used by nothing.
    fn staging_buffer(&self, bytes: u64) -> wgpu::Buffer {
        let mut size = bytes.max(4).next_multiple_of(4);
        if size <= STAGING_POOLED {
            size = size.next_power_of_two().max(256);
            let mut pool = self.staging.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
            if let Some(i) = pool.iter().position(|b| b.size() == size) {
                return pool.swap_remove(i);
            }
        }
        self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("read-back"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// Keeps a read-back buffer, unmapped again, for the next read-back of its size.
    fn keep_staging(&self, buffer: wgpu::Buffer) {
        if buffer.size() <= STAGING_POOLED {
            let mut pool = self.staging.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
            if !pool.iter().any(|b| b.size() == buffer.size()) {
                pool.push(buffer);
            }
        }
    }

    fn submit_and_read<T: bytemuck::Pod>(
        &self,
        mut encoder: Recorder,
        buffer: &wgpu::Buffer,
        count: usize,
        status: bool,
    ) -> Result<Vec<T>> {
        let bytes = (count * std::mem::size_of::<T>()) as u64;
        let staging = self.staging_buffer(bytes);
        if bytes > 0 {
            encoder.copy(buffer, 0, &staging, 0, bytes.next_multiple_of(4));
        }
        // The kernels timed so far, resolved behind everything they timed.
        let timed = match &self.profiler {
            Some(p) => {
                let mut p = p.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
                let size = p.staging_bytes();
                (size > 0).then(|| {
                    let ticks = self.device.create_buffer(&wgpu::BufferDescriptor {
                        label: Some("timestamps read-back"),
                        size,
                        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                        mapped_at_creation: false,
                    });
                    let kernels = p.resolve(encoder.encoder(), &ticks);
                    (ticks, kernels)
                })
            }
            None => None,
        };
        let queued = self.pending().take();
        let submission = self.submit(queued.into_iter().chain([encoder]));
        let mut t = self.transfers.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if status {
            t.status_reads += 1;
        } else {
            t.readbacks += 1;
            t.readback_bytes += bytes;
        }
        drop(t);
        let (tx, rx) = mpsc::channel();
        staging.slice(..).map_async(wgpu::MapMode::Read, move |r| {
            // The receiver waits below; a failed send only means it gave up.
            let _ = tx.send(r);
        });
        let timed = timed.map(|(ticks, kernels)| {
            let (ttx, trx) = mpsc::channel();
            ticks.slice(..).map_async(wgpu::MapMode::Read, move |r| {
                let _ = ttx.send(r);
            });
            (ticks, kernels, trx)
        });
        self.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| GpuError::Readback(e.to_string()))?;
        self.check()?;
        self.recycle_params(submission);
        match rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(GpuError::Readback(e.to_string())),
            Err(_) => return Err(GpuError::Readback("the mapping callback never ran".into())),
        }
        let view = staging.slice(..).get_mapped_range().map_err(|e| GpuError::Readback(e.to_string()))?;
        let out: Vec<T> = bytemuck::pod_collect_to_vec(&view[..bytes as usize]);
        drop(view);
        staging.unmap();
        self.keep_staging(staging);
        if let (Some((ticks, kernels, trx)), Some(p)) = (timed, &self.profiler) {
            if let Ok(Ok(())) = trx.recv() {
                let view = ticks.slice(..).get_mapped_range().map_err(|e| GpuError::Readback(e.to_string()))?;
                let values: Vec<u64> = bytemuck::pod_collect_to_vec(&view);
                drop(view);
                p.lock().unwrap_or_else(std::sync::PoisonError::into_inner).add(kernels, &values);
            }
        }
        Ok(out)
    }
}

/// `groups` workgroups as an `(x, y)` grid within the per-dimension limit; kernels recover the
/// flat index as `x + y * num_workgroups.x` and skip the tail.
pub(crate) fn grid(groups: u32) -> (u32, u32) {
    let x = groups.min(MAX_GROUPS);
    (x, groups.div_ceil(x.max(1)))
}

impl Pipelines {
    fn new(device: &wgpu::Device) -> Self {
        let module = |label: &str, source: &str| {
            device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(label),
                source: wgpu::ShaderSource::Wgsl(source.into()),
            })
        };
        let hash = include_str!("shaders/hash.wgsl");
        let map = module("map", &[include_str!("shaders/map.wgsl"), hash].concat());
        let hierarchy = module("hierarchy", &[include_str!("shaders/hierarchy.wgsl"), hash].concat());
        // WGSL has no includes: the shared helper goes after each kernel that calls it.
        let workgroup_any = include_str!("shaders/workgroup_any.wgsl");
        let chunked_source = [include_str!("shaders/chunked.wgsl"), workgroup_any].concat();
        let chunked_tiles = CHUNKED_TILES.map(|t| {
            let source = chunked_source
                .replace("const TR: u32 = 64u;", &format!("const TR: u32 = {}u;", t.rows))
                .replace("const TO: u32 = 64u;", &format!("const TO: u32 = {}u;", t.channels))
                .replace("const RQ: u32 = 1u;", &format!("const RQ: u32 = {}u;", t.row_quads))
                .replace("const CQ: u32 = 1u;", &format!("const CQ: u32 = {}u;", t.channel_quads));
            module("chunked", &source)
        });
        let rulebook = module("rulebook", include_str!("shaders/rulebook.wgsl"));
        let weight_grad = module("weight_grad", &[include_str!("shaders/weight_grad.wgsl"), workgroup_any].concat());
        let elementwise = module("elementwise", include_str!("shaders/elementwise.wgsl"));
        let pipeline = |m: &wgpu::ShaderModule, entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: None,
                module: m,
                entry_point: Some(entry),
                compilation_options: wgpu::PipelineCompilationOptions::default(),
                cache: None,
            })
        };
        let mut pipelines = Self {
            map_insert: pipeline(&map, "insert"),
            map_lookup: pipeline(&map, "lookup"),
            chunked: chunked_tiles.each_ref().map(|m| pipeline(m, "forward")),
            gather: pipeline(&rulebook, "gather"),
            gemm: pipeline(&rulebook, "gemm"),
            scatter: pipeline(&rulebook, "scatter"),
            bn_relu: pipeline(&rulebook, "bn_relu"),
            weight_grad: pipeline(&rulebook, "weight_grad"),
            weight_grad_tiled: pipeline(&weight_grad, "weight_grad"),
            reduce_segments: pipeline(&weight_grad, "reduce_segments"),
            gate: pipeline(&elementwise, "gate"),
            gather_add: pipeline(&elementwise, "gather_add"),
            add_bias: pipeline(&elementwise, "add_bias"),
            argmax: pipeline(&elementwise, "argmax"),
            split_sum: pipeline(&elementwise, "split_sum"),
            hierarchy: HierarchyPipelines {
                insert: pipeline(&hierarchy, "insert"),
                first_child: pipeline(&hierarchy, "first_child"),
                scan_blocks: pipeline(&hierarchy, "scan_blocks"),
                scan_totals: pipeline(&hierarchy, "scan_totals"),
                scan_add: pipeline(&hierarchy, "scan_add"),
                emit: pipeline(&hierarchy, "emit"),
                fill: pipeline(&hierarchy, "fill"),
                rows: pipeline(&hierarchy, "rows"),
                ancestor: pipeline(&hierarchy, "ancestor"),
                interp: pipeline(&hierarchy, "interp"),
            },
            names: HashMap::new(),
        };
        let h = &pipelines.hierarchy;
        let mut names: Vec<(&wgpu::ComputePipeline, &'static str)> = vec![
            (&pipelines.map_insert, "map insert"),
            (&pipelines.map_lookup, "map lookup"),
            (&pipelines.gather, "rulebook gather"),
            (&pipelines.gemm, "rulebook gemm"),
            (&pipelines.scatter, "rulebook scatter"),
            (&pipelines.bn_relu, "bn relu"),
            (&pipelines.weight_grad, "rulebook weight gradient"),
            (&pipelines.weight_grad_tiled, "chunked weight gradient"),
            (&pipelines.reduce_segments, "weight gradient reduce"),
            (&pipelines.gate, "gate"),
            (&pipelines.gather_add, "gather add"),
            (&pipelines.add_bias, "add bias"),
            (&pipelines.argmax, "argmax"),
            (&pipelines.split_sum, "split sum"),
            (&h.insert, "hierarchy insert"),
            (&h.first_child, "hierarchy first child"),
            (&h.scan_blocks, "hierarchy scan blocks"),
            (&h.scan_totals, "hierarchy scan totals"),
            (&h.scan_add, "hierarchy scan add"),
            (&h.emit, "hierarchy emit"),
            (&h.fill, "hierarchy fill"),
            (&h.rows, "hierarchy rows"),
            (&h.ancestor, "hierarchy ancestor"),
            (&h.interp, "hierarchy interpolation"),
        ];
        const TILE_NAMES: [&str; CHUNKED_TILES.len()] =
            ["chunked 64x64", "chunked 128x32", "chunked 128x64", "chunked 64x128"];
        for (p, name) in pipelines.chunked.iter().zip(TILE_NAMES) {
            names.push((p, name));
        }
        // wgpu hashes and compares pipelines by identity: the interior state is not the key.
        #[allow(clippy::mutable_key_type)]
        let names = names.into_iter().map(|(p, n)| (p.clone(), (n, p.get_bind_group_layout(0)))).collect();
        pipelines.names = names;
        pipelines
    }

    /// `pipeline`'s name and bind group layout (the layout asked of wgpu once, not per
    /// dispatch).
    fn info(&self, pipeline: &wgpu::ComputePipeline) -> (&'static str, wgpu::BindGroupLayout) {
        match self.names.get(pipeline) {
            Some((name, layout)) => (name, layout.clone()),
            None => ("unnamed", pipeline.get_bind_group_layout(0)),
        }
    }
}
