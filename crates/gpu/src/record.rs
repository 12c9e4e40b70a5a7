//! Recording work for the device cheaply: one command encoder for a batch of work, one compute
//! pass over consecutive dispatches, and the kernels' parameters in shared pages of one uniform
//! buffer instead of a new buffer per dispatch.
//!
//! Why: a network forward is about 140 small dispatches and the device hierarchy about 70 more.
//! Per dispatch the engine used to create a uniform buffer, copy its few words through a
//! staging buffer of their own, open a compute pass, and (per operation) a command encoder
//! whose command buffer wgpu submits behind a barrier buffer of its own. On a small input that
//! host work is most of a call (docs/gpu.md, "the fixed cost per call").
//!
//! Merging passes changes no result: wgpu tracks buffer usage per dispatch inside a compute
//! pass and inserts the same barriers between two dispatches of a pass as between two passes
//! (a storage buffer written by one dispatch and read or written by the next).
//!
//! Parameters are written once per submission: a dispatch appends its words to the host copy
//! of the current page and binds its slot (at the device's uniform offset alignment); before
//! every submission the words appended since the last one go up with one queue write, which
//! lands before the submitted commands run. A slot is written once and read only by commands
//! recorded after it was taken; pages are reused only once nothing recorded can still read
//! them ([`ParamArena::recycle`]).

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

/// Bytes of one parameter page (some hundreds of dispatches).
const PAGE_BYTES: u64 = 64 * 1024;
/// Full pages kept for reuse at most; more are left to wgpu to free once unused.
const KEPT_PAGES: usize = 16;

/// Counts the recorders alive: the parameter pages may be reused only when none is.
struct Live(Arc<AtomicUsize>);

impl Live {
    fn new(count: &Arc<AtomicUsize>) -> Self {
        count.fetch_add(1, Ordering::AcqRel);
        Self(Arc::clone(count))
    }
}

impl Drop for Live {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

/// Commands being recorded: an encoder and, while dispatches follow one another, the compute
/// pass they go into (ended before any copy or clear, which the encoder records outside
/// passes).
pub(crate) struct Recorder {
    // Declared before the encoder: a pass still open when the recorder is dropped ends first.
    pass: Option<wgpu::ComputePass<'static>>,
    encoder: wgpu::CommandEncoder,
    /// Operations recorded (queued work is submitted once there are enough of them).
    pub(crate) ops: usize,
    _live: Live,
}

impl Recorder {
    /// A new recorder on `device`, counted in `live`.
    pub(crate) fn new(device: &wgpu::Device, live: &Arc<AtomicUsize>) -> Self {
        Self {
            pass: None,
            encoder: device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: None }),
            ops: 0,
            _live: Live::new(live),
        }
    }

    /// The open compute pass, opened when there is none.
    pub(crate) fn pass(&mut self) -> &mut wgpu::ComputePass<'static> {
        let encoder = &mut self.encoder;
        self.pass.get_or_insert_with(|| {
            encoder
                .begin_compute_pass(&wgpu::ComputePassDescriptor { label: None, timestamp_writes: None })
                .forget_lifetime()
        })
    }

    /// A pass of its own, its start and end timed (the profiler's dispatches).
    pub(crate) fn timed_pass(
        &mut self,
        timestamp_writes: wgpu::ComputePassTimestampWrites<'_>,
    ) -> wgpu::ComputePass<'_> {
        self.pass = None;
        self.encoder
            .begin_compute_pass(&wgpu::ComputePassDescriptor { label: None, timestamp_writes: Some(timestamp_writes) })
    }

    /// The encoder, for commands outside compute passes (the open pass ends first).
    pub(crate) fn encoder(&mut self) -> &mut wgpu::CommandEncoder {
        self.pass = None;
        &mut self.encoder
    }

    /// Records a copy of `bytes` from `src` at `src_offset` to `dst` at `dst_offset`.
    pub(crate) fn copy(
        &mut self,
        src: &wgpu::Buffer,
        src_offset: u64,
        dst: &wgpu::Buffer,
        dst_offset: u64,
        bytes: u64,
    ) {
        self.encoder().copy_buffer_to_buffer(src, src_offset, dst, dst_offset, bytes);
    }

    /// Records zeroing the first `bytes` of `buffer`.
    pub(crate) fn clear(&mut self, buffer: &wgpu::Buffer, bytes: u64) {
        self.encoder().clear_buffer(buffer, 0, Some(bytes));
    }

    /// The recorded commands.
    pub(crate) fn finish(self) -> wgpu::CommandBuffer {
        let Self { pass, encoder, .. } = self;
        drop(pass);
        encoder.finish()
    }
}

/// One dispatch's parameters: where they are bound.
pub(crate) struct ParamSlot {
    pub buffer: wgpu::Buffer,
    pub offset: u64,
    pub size: wgpu::BufferSize,
}

/// The pages of kernel parameters and the words not yet written to the current one.
pub(crate) struct ParamArena {
    /// Slot offsets are multiples of this (the device's uniform offset alignment).
    align: u64,
    current: wgpu::Buffer,
    /// Bytes of the current page taken by slots.
    cursor: u64,
    /// Bytes of the current page already written to the device.
    written: u64,
    /// The current page's bytes from `written` to `cursor`, to be written.
    staged: Vec<u8>,
    /// Full pages whose slots recorded work may still read.
    retired: Vec<wgpu::Buffer>,
    /// Pages nothing recorded reads any more.
    free: Vec<wgpu::Buffer>,
    /// Submissions to the queue so far (the context counts them here, under the same lock).
    pub submissions: u64,
}

impl ParamArena {
    /// An empty arena on `device`, whose uniform bindings start at multiples of `align`.
    pub(crate) fn new(device: &wgpu::Device, align: u32) -> Self {
        Self {
            align: u64::from(align.max(16)),
            current: page(device),
            cursor: 0,
            written: 0,
            staged: Vec::new(),
            retired: Vec::new(),
            free: Vec::new(),
            submissions: 0,
        }
    }

    /// A slot holding `words` (padded to 16 bytes, the size of the kernels' uniform structs).
    pub(crate) fn push(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, words: &[u32]) -> ParamSlot {
        let padded = words.len().next_multiple_of(4).max(4);
        let size = padded as u64 * 4;
        let mut offset = self.cursor.next_multiple_of(self.align);
        if offset + size > PAGE_BYTES {
            self.next_page(device, queue);
            offset = 0;
        }
        // The gap left by the alignment is never read: zeros keep the staged bytes contiguous.
        self.staged.resize((offset - self.written) as usize, 0);
        self.staged.extend(words.iter().flat_map(|w| w.to_le_bytes()));
        self.staged.resize((offset + size - self.written) as usize, 0);
        self.cursor = offset + size;
        ParamSlot {
            buffer: self.current.clone(),
            offset,
            size: wgpu::BufferSize::new(size).unwrap_or(wgpu::BufferSize::MIN),
        }
    }

    /// Writes the words staged since the last write (before a submission: the write lands
    /// before the submitted commands run).
    pub(crate) fn write(&mut self, queue: &wgpu::Queue) {
        if !self.staged.is_empty() {
            queue.write_buffer(&self.current, self.written, &self.staged);
            self.written += self.staged.len() as u64;
            self.staged.clear();
        }
    }

    /// Makes every page free for reuse: callers know that all work recorded so far has been
    /// submitted and has finished on the device.
    pub(crate) fn recycle(&mut self) {
        debug_assert!(self.staged.is_empty(), "staged parameters are written before a submission");
        self.free.append(&mut self.retired);
        self.free.truncate(KEPT_PAGES);
        self.cursor = 0;
        self.written = 0;
    }

    /// Writes the current page's staged words and moves on to a fresh page.
    fn next_page(&mut self, device: &wgpu::Device, queue: &wgpu::Queue) {
        self.write(queue);
        let fresh = self.free.pop().unwrap_or_else(|| page(device));
        let full = std::mem::replace(&mut self.current, fresh);
        if self.retired.len() < KEPT_PAGES {
            self.retired.push(full);
        }
        self.cursor = 0;
        self.written = 0;
    }
}

/// A new page of parameters.
fn page(device: &wgpu::Device) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("kernel parameters"),
        size: PAGE_BYTES,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}
