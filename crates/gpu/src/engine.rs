//! The GPU engine: [`ConvBackend`] on wgpu, with the chunked kernel (Algorithm 2) or the
//! rulebook baseline (Algorithm 1) on the same device geometry.
//!
//! A call of the host-slice interface ([`ConvBackend`]) copies its feature and weight buffers
//! into the context's pooled device buffers (kept between calls and only grown), records
//! every dispatch of the layer in one command buffer, submits it and reads the result back;
//! layer geometry stays on the device between calls. The same recording functions serve the
//! resident-tensor interface (crate::resident), which skips the copies. The input gradient is the forward kernel on the transposed problem (the
//! forward plan with mirrored offsets for submanifold layers, the plan over the inputs for
//! strided ones, exactly as the CPU engine does it); the weight gradient runs one thread per
//! weight over the offset's pair list.

use std::sync::Arc;

use semrecon_sparse::backend::check_forward;
use semrecon_sparse::{BnRelu, ChunkConfig, ChunkedConv, ConvAlgorithm, ConvBackend, Coord, MapKind};

use crate::context::{GpuContext, WORKGROUP};
use crate::error::{GpuError, Result};
use crate::layer::{DevicePlan, GpuLayer, LayerParts};
use crate::record::Recorder;
use crate::tile::{TileShape, CHANNEL_STEP, CHUNKED_TILES};

/// The GPU engine: an opened device and the algorithm of its convolutions.
#[derive(Debug, Clone)]
pub struct GpuEngine {
    ctx: Arc<GpuContext>,
    /// The algorithm of every convolution.
    pub algorithm: ConvAlgorithm,
    /// How outputs are cut into chunks (the same planner as the CPU engine).
    pub chunk: ChunkConfig,
    /// The chunked kernel's tile shape, an index in [`CHUNKED_TILES`]; `None` picks by the
    /// layer's size ([`TileShape::for_layer`]). For benchmarks.
    tile: Option<usize>,
    /// Ranges of (offset, channel step) pairs the chunked kernel splits every layer into;
    /// `None` picks by the layer's size ([`TileShape::splits`]). For benchmarks and tests.
    splits: Option<u32>,
}

/// Destinations per block of the chunked weight gradient (shaders/weight_grad.wgsl `RB`).
const WEIGHT_GRAD_ROWS: u32 = 32;
/// Workgroups the chunked weight gradient aims for (segments of rows times weight blocks).
const WEIGHT_GRAD_GROUPS: u32 = 512;

/// Weights `[kv, c_in, c_out]` transposed per offset to `[kv, c_out, c_in]`, offset `k` taken
/// from `source(k)`.
fn transpose(w: &[f32], kv: usize, c_in: usize, c_out: usize, source: impl Fn(usize) -> usize) -> Vec<f32> {
    let mut t = vec![0f32; w.len()];
    for k in 0..kv {
        let s = source(k);
        for ci in 0..c_in {
            for co in 0..c_out {
                t[(k * c_out + co) * c_in + ci] = w[(s * c_in + ci) * c_out + co];
            }
        }
    }
    t
}

pub(crate) fn count32(what: &'static str, n: usize) -> Result<u32> {
    u32::try_from(n).map_err(|_| GpuError::TooLarge { what, bytes: n as u64 * 4, limit: u32::MAX as u64 })
}

impl GpuEngine {
    /// Opens the GPU (see [`GpuContext::new`]) for `algorithm`.
    ///
    /// # Errors
    /// As [`GpuContext::new`].
    pub fn new(algorithm: ConvAlgorithm) -> Result<Self> {
        Ok(Self::with_context(Arc::new(GpuContext::new()?), algorithm))
    }

    /// An engine on an already opened device (engines of both algorithms can share one).
    pub fn with_context(ctx: Arc<GpuContext>, algorithm: ConvAlgorithm) -> Self {
        Self { ctx, algorithm, chunk: ChunkConfig::default(), tile: None, splits: None }
    }

    /// The device.
    pub fn context(&self) -> &Arc<GpuContext> {
        &self.ctx
    }

    /// The same device and algorithm with outputs cut into chunks of `chunk`'s shape.
    pub fn with_chunk(&self, chunk: ChunkConfig) -> Self {
        Self { chunk, ..self.clone() }
    }

    /// A layer of a neighbour table (`[n_out, kv]`, the input row of every output at every
    /// offset or `u32::MAX`, outputs in the order the work should follow: Z-order) for this
    /// engine's forward, without the host's chunk plans: what the network's GPU path imports
    /// ([`GpuError::LayerPart`] for the other algorithm and the gradients).
    ///
    /// # Errors
    /// A table that is not whole rows or names a row past `n_in`; buffers over the device's
    /// limits, a lost device.
    pub fn import_table(&self, kind: MapKind, n_in: usize, table: &[u32]) -> Result<GpuLayer> {
        GpuLayer::from_table(&self.ctx, kind, n_in, table, self.algorithm)
    }

    /// The same engine with the chunked kernel's tile shape fixed to `CHUNKED_TILES[tile]`
    /// (`None`: by the layer's width, the default), for benchmarks.
    ///
    /// # Errors
    /// [`GpuError::Device`] for an index past the table.
    pub fn with_tile(&self, tile: Option<usize>) -> Result<Self> {
        if tile.is_some_and(|t| t >= CHUNKED_TILES.len()) {
            return Err(GpuError::Device(format!("no tile shape {tile:?}: there are {}", CHUNKED_TILES.len())));
        }
        Ok(Self { tile, ..self.clone() })
    }

    /// The same engine with the chunked kernel's (offset, channel step) sequence split into
    /// `splits` ranges in every layer (`None`: by the layer's size, the default), for
    /// benchmarks and tests; more splits than steps count as one per step.
    ///
    /// # Errors
    /// [`GpuError::Device`] for zero splits.
    pub fn with_splits(&self, splits: Option<u32>) -> Result<Self> {
        if splits == Some(0) {
            return Err(GpuError::Device("zero offset splits".into()));
        }
        Ok(Self { splits, ..self.clone() })
    }

    /// The same device running `algorithm`.
    pub fn with_algorithm(&self, algorithm: ConvAlgorithm) -> Self {
        Self { algorithm, ..self.clone() }
    }

    /// A layer of a CPU geometry (kernel map and chunk plans built on the host, as the
    /// network's geometry builds them) uploaded for this engine's forward: only what this
    /// engine's algorithm reads (the other algorithm and the gradients return
    /// [`GpuError::LayerPart`] on it). Inference pays this for every new input.
    ///
    /// # Errors
    /// Buffers over the device's limits, a lost device.
    pub fn import(&self, layer: &ChunkedConv) -> Result<GpuLayer> {
        GpuLayer::from_cpu(&self.ctx, layer, LayerParts::Forward(self.algorithm))
    }

    /// The chunked kernel over `plan` into `y` (`[rows, c_out]`, with `accumulate` its
    /// contents are added to), host buffers in and out.
    #[allow(clippy::too_many_arguments)]
    fn run_chunked(
        &self,
        plan: &DevicePlan,
        kv: usize,
        x: &[f32],
        c_in: usize,
        bn: Option<BnRelu<'_>>,
        w: &[f32],
        c_out: usize,
        y: &mut [f32],
        accumulate: bool,
    ) -> Result<()> {
        self.on_host_buffers(x, bn, w, y, accumulate, |enc, xb, bnb, wb, yb| {
            self.encode_chunked(enc, plan, kv, xb, c_in, bnb, wb, c_out, yb, accumulate)
        })
    }

    /// Uploads `x`, `bn` (scale then shift), `w` and, with `accumulate`, `y` into transient
    /// device buffers, records `encode` on them and reads the output back into `y`. Without
    /// `accumulate` the output buffer is left as allocated: the chunked kernel writes every
    /// row and the rulebook encoder clears it first.
    fn on_host_buffers(
        &self,
        x: &[f32],
        bn: Option<BnRelu<'_>>,
        w: &[f32],
        y: &mut [f32],
        accumulate: bool,
        encode: impl FnOnce(&mut Recorder, &wgpu::Buffer, Option<&wgpu::Buffer>, &wgpu::Buffer, &wgpu::Buffer) -> Result<()>,
    ) -> Result<()> {
        let ctx = &*self.ctx;
        let xb = ctx.transient_upload("features", x)?;
        let wb = ctx.transient_upload("weights", w)?;
        let bnb = bn.map(|bn| ctx.transient_upload("batch norm", &[bn.scale, bn.shift].concat())).transpose()?;
        let yb =
            if accumulate { ctx.transient_upload("output", y)? } else { ctx.transient("output", y.len() as u64 * 4)? };
        let mut enc = ctx.encoder();
        encode(&mut enc, &xb, bnb.as_ref(), &wb, &yb)?;
        let out: Vec<f32> = ctx.finish_and_read(enc, &yb, y.len())?;
        y.copy_from_slice(&out);
        Ok(())
    }

    /// Records the chunked kernel over `plan` on device buffers: `y = conv(bn_relu(x), w)`
    /// (or `+=`), `bn` the folded scale then shift.
    ///
    /// # Shapes
    /// `x`: `[plan sources, c_in]`; `bn`: `[2, c_in]`; `w`: `[kv, c_in, c_out]`;
    /// `y`: `[plan destinations, c_out]`.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn encode_chunked(
        &self,
        enc: &mut Recorder,
        plan: &DevicePlan,
        kv: usize,
        x: &wgpu::Buffer,
        c_in: usize,
        bn: Option<&wgpu::Buffer>,
        w: &wgpu::Buffer,
        c_out: usize,
        y: &wgpu::Buffer,
        accumulate: bool,
    ) -> Result<()> {
        let ctx = &*self.ctx;
        // An unused binding still needs a buffer; the pooled one is never written by queue.
        let unused;
        let bnb = match bn {
            Some(b) => b,
            None => {
                unused = ctx.transient("batch norm", 4)?;
                &unused
            }
        };
        // One workgroup per tile of destinations x output channels; the shape by the layer's
        // size, and small layers split over ranges of their steps (`TileShape::splits`).
        let which = self.tile.unwrap_or_else(|| TileShape::for_layer(plan.n_dst, c_out));
        let tile = CHUNKED_TILES[which];
        let tiles = plan.n_dst.div_ceil(tile.rows);
        let channel_tiles = count32("channels", c_out.div_ceil(tile.channels as usize))?;
        let kv32 = kv as u32;
        let c_in32 = count32("channels", c_in)?;
        let steps = kv32.saturating_mul(c_in32.div_ceil(CHANNEL_STEP));
        let splits = self
            .splits
            .unwrap_or_else(|| TileShape::splits(tiles.saturating_mul(channel_tiles), kv32, c_in32))
            .clamp(1, steps.max(1));
        let slice = count32("split partial sums", plan.n_dst as usize * c_out)?;
        let partial = if splits > 1 {
            // Slices are addressed by u32 offsets in the kernel.
            let words = count32("split partial sums", splits as usize * slice as usize)?;
            Some(ctx.transient("split partial sums", u64::from(words) * 4)?)
        } else {
            None
        };
        let shape = || format!("rows {} kv {kv} {c_in}->{c_out}", plan.n_dst);
        // Splits write their own slices; only the whole layer adds to y.
        let adds = accumulate && partial.is_none();
        let flags = u32::from(bn.is_some()) | (u32::from(adds) << 1);
        let params = [
            c_in32,
            count32("channels", c_out)?,
            kv32,
            plan.n_dst,
            flags,
            0,
            plan.table_offset(),
            splits,
            channel_tiles,
            slice,
        ];
        let out = partial.as_ref().unwrap_or(y);
        let bindings = [(1, x), (2, w), (3, bnb), (4, &plan.buffer), (5, out)];
        let z = channel_tiles.saturating_mul(splits);
        ctx.dispatch_shaped(enc, &ctx.pipelines.chunked[which], &params, &bindings, tiles, z, shape);
        if let Some(partial) = &partial {
            let params = [slice, splits, u32::from(accumulate), 0];
            let bindings = [(1, partial), (3, y)];
            ctx.dispatch(enc, &ctx.pipelines.split_sum, &params, &bindings, slice.div_ceil(WORKGROUP), 1);
        }
        Ok(())
    }

    /// The rulebook kernels over the layer's pairs: per offset gather, GEMM, scatter-add;
    /// `swap` reads from output rows and writes to input rows (the input gradient, with
    /// weights `[kv, c_src, c_dst]` already transposed). Host buffers in and out.
    #[allow(clippy::too_many_arguments)]
    fn run_rulebook(
        &self,
        layer: &GpuLayer,
        swap: bool,
        x: &[f32],
        c_src: usize,
        bn: Option<BnRelu<'_>>,
        w: &[f32],
        c_dst: usize,
        y: &mut [f32],
        accumulate: bool,
    ) -> Result<()> {
        let sizes = (x.len(), y.len());
        self.on_host_buffers(x, bn, w, y, accumulate, |enc, xb, bnb, wb, yb| {
            self.encode_rulebook(enc, layer, swap, xb, c_src, bnb, wb, c_dst, yb, sizes, accumulate)
        })
    }

    /// Records the rulebook kernels on device buffers (see [`Self::run_rulebook`]); `sizes`
    /// are the values of `x` and `y` the layer reads and writes.
    ///
    /// # Shapes
    /// `x`: `[n_src, c_src]`; `bn`: `[2, c_src]`; `w`: `[kv, c_src, c_dst]`;
    /// `y`: `[n_dst, c_dst]`.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn encode_rulebook(
        &self,
        enc: &mut Recorder,
        layer: &GpuLayer,
        swap: bool,
        x: &wgpu::Buffer,
        c_src: usize,
        bn: Option<&wgpu::Buffer>,
        w: &wgpu::Buffer,
        c_dst: usize,
        y: &wgpu::Buffer,
        sizes: (usize, usize),
        accumulate: bool,
    ) -> Result<()> {
        let ctx = &*self.ctx;
        let p = &ctx.pipelines;
        let (cs, cd) = (count32("channels", c_src)?, count32("channels", c_dst)?);
        let n_pairs = count32("pairs", layer.num_pairs())?;
        let pairs = layer.pairs()?;
        let most = pairs.starts.windows(2).map(|s| s[1] - s[0]).max().unwrap_or(0) as u64;
        // Written before they are read, within each offset.
        let gathered = ctx.transient("gathered rows", most * u64::from(cs) * 4)?;
        let products = ctx.transient("products", most * u64::from(cd) * 4)?;
        if !accumulate && sizes.1 > 0 {
            // The scatter adds: the output starts at zero.
            enc.clear(y, sizes.1 as u64 * 4);
        }
        let normalised;
        let mut src = x;
        if let Some(bnb) = bn {
            // The standard algorithm's separate normalisation pass.
            normalised = ctx.transient("normalised features", sizes.0 as u64 * 4)?;
            let n = count32("features", sizes.0)?;
            let b = [(1, x), (3, bnb), (4, &normalised)];
            ctx.dispatch(enc, &p.bn_relu, &[n, cs, 0, 0, 0, 0, 0, 0], &b, n.div_ceil(WORKGROUP), 1);
            src = &normalised;
        }
        for k in 0..layer.kv {
            let (base, rows) = (pairs.starts[k], pairs.starts[k + 1] - pairs.starts[k]);
            if rows == 0 {
                continue;
            }
            let w_base = count32("weights", k * c_src * c_dst)?;
            let params = [rows, cs, cd, base, n_pairs, u32::from(swap), w_base, layer.kv as u32];
            let g = [(1, src), (2, &pairs.buffer), (4, &gathered)];
            let threads = count32("gathered rows", rows as usize * c_src)?;
            ctx.dispatch(enc, &p.gather, &params, &g, threads.div_ceil(WORKGROUP), 1);
            let m = [(1, &gathered), (3, w), (4, &products)];
            ctx.dispatch(enc, &p.gemm, &params, &m, rows.div_ceil(16), cd.div_ceil(16));
            let s = [(1, &products), (2, &pairs.buffer), (4, y)];
            let threads = count32("products", rows as usize * c_dst)?;
            ctx.dispatch(enc, &p.scatter, &params, &s, threads.div_ceil(WORKGROUP), 1);
        }
        Ok(())
    }
}

impl ConvBackend for GpuEngine {
    type Layer = GpuLayer;
    type Error = GpuError;

    fn name(&self) -> String {
        format!("gpu-{}", self.algorithm.name())
    }

    fn submanifold(&self, coords: &[Coord], kernel_size: usize) -> Result<GpuLayer> {
        GpuLayer::submanifold(&self.ctx, coords, kernel_size, &self.chunk)
    }

    fn downsample(&self, fine: &[Coord]) -> Result<(Vec<Coord>, GpuLayer)> {
        GpuLayer::downsample(&self.ctx, fine, &self.chunk)
    }

    fn upsample(&self, coarse: &[Coord], fine: &[Coord]) -> Result<GpuLayer> {
        GpuLayer::upsample(&self.ctx, coarse, fine, &self.chunk)
    }

    fn layer_rows(&self, layer: &GpuLayer) -> (usize, usize) {
        (layer.n_in, layer.n_out)
    }

    fn forward_into(
        &self,
        layer: &GpuLayer,
        x: &[f32],
        c_in: usize,
        bn: Option<BnRelu<'_>>,
        w: &[f32],
        c_out: usize,
        y: &mut [f32],
        accumulate: bool,
    ) -> Result<()> {
        check_forward(layer.kv, (layer.n_in, layer.n_out), x, c_in, bn, w, c_out, y)?;
        if y.is_empty() || layer.n_in == 0 || c_in == 0 {
            // Nothing to read: the convolution is zero.
            if !accumulate {
                y.fill(0.0);
            }
            return Ok(());
        }
        let _call = self.ctx.begin_call()?;
        match self.algorithm {
            ConvAlgorithm::Chunked => {
                self.run_chunked(layer.forward_plan()?, layer.kv, x, c_in, bn, w, c_out, y, accumulate)
            }
            ConvAlgorithm::Rulebook => self.run_rulebook(layer, false, x, c_in, bn, w, c_out, y, accumulate),
        }
    }

    fn backward_input(&self, layer: &GpuLayer, dy: &[f32], c_out: usize, w: &[f32], c_in: usize) -> Result<Vec<f32>> {
        let mut dx = vec![0f32; layer.n_in * c_in];
        // The transposed problem's shapes: dy is its input, dx its output.
        check_forward(layer.kv, (layer.n_out, layer.n_in), dy, c_out, None, w, c_in, &dx)?;
        if dx.is_empty() || layer.n_out == 0 || c_out == 0 {
            return Ok(dx);
        }
        let kv = layer.kv;
        let _call = self.ctx.begin_call()?;
        match (self.algorithm, &layer.backward) {
            (ConvAlgorithm::Rulebook, _) => {
                let wt = transpose(w, kv, c_in, c_out, |k| k);
                self.run_rulebook(layer, true, dy, c_out, None, &wt, c_in, &mut dx, false)?;
            }
            (ConvAlgorithm::Chunked, Some(plan)) => {
                let wt = transpose(w, kv, c_in, c_out, |k| k);
                self.run_chunked(plan, kv, dy, c_out, None, &wt, c_in, &mut dx, false)?;
            }
            (ConvAlgorithm::Chunked, None) => {
                if !matches!(layer.kind, MapKind::Submanifold { .. }) {
                    return Err(GpuError::Device("strided layer without an input-side plan".into()));
                }
                // Submanifold: the pairs of offset k, swapped, are those of its mirror.
                let wt = transpose(w, kv, c_in, c_out, |k| kv - 1 - k);
                self.run_chunked(layer.forward_plan()?, kv, dy, c_out, None, &wt, c_in, &mut dx, false)?;
            }
        }
        Ok(dx)
    }

    fn backward_weight(&self, layer: &GpuLayer, x: &[f32], c_in: usize, dy: &[f32], c_out: usize) -> Result<Vec<f32>> {
        let kv = layer.kv;
        let dw = vec![0f32; kv * c_in * c_out];
        check_forward(kv, (layer.n_in, layer.n_out), x, c_in, None, &dw, c_out, dy)?;
        if dw.is_empty() || layer.num_pairs() == 0 {
            return Ok(dw);
        }
        let ctx = &*self.ctx;
        let _call = ctx.begin_call()?;
        let xb = ctx.transient_upload("features", x)?;
        let dyb = ctx.transient_upload("output gradient", dy)?;
        // Every weight is written by the kernel.
        let dwb = ctx.transient("weight gradient", dw.len() as u64 * 4)?;
        let (cs, cd) = (count32("channels", c_in)?, count32("channels", c_out)?);
        let mut enc = ctx.encoder();
        match self.algorithm {
            ConvAlgorithm::Chunked => {
                // Blocks of 16 input x 64 output channels per offset, each over a segment of
                // the plan's rows; the segment count depends on the sizes alone (same bits on
                // every device) and gives a GPU some hundreds of workgroups.
                let plan = layer.forward_plan()?;
                let (c_blocks, o_blocks) = (cs.div_ceil(16), cd.div_ceil(64));
                let blocks = kv as u32 * c_blocks * o_blocks;
                let most = plan.n_dst.div_ceil(WEIGHT_GRAD_ROWS).max(1);
                let wanted = WEIGHT_GRAD_GROUPS.div_ceil(blocks).clamp(1, most);
                let segment_rows = plan.n_dst.div_ceil(wanted).next_multiple_of(WEIGHT_GRAD_ROWS).max(WEIGHT_GRAD_ROWS);
                let segments = plan.n_dst.div_ceil(segment_rows).max(1);
                let params = [cs, cd, kv as u32, plan.n_dst, 0, plan.table_offset(), c_blocks, segments, segment_rows];
                let partial;
                let out = if segments == 1 {
                    &dwb
                } else {
                    partial = ctx.transient("weight gradient parts", u64::from(segments) * dw.len() as u64 * 4)?;
                    &partial
                };
                let b = [(1, &xb), (2, &dyb), (3, &plan.buffer), (4, out)];
                let groups = count32("weight blocks", (segments * kv as u32 * c_blocks) as usize)?;
                ctx.dispatch(&mut enc, &ctx.pipelines.weight_grad_tiled, &params, &b, groups, o_blocks);
                if segments > 1 {
                    let r = [(5, out), (6, &dwb)];
                    let threads = count32("weights", dw.len())?.div_ceil(WORKGROUP);
                    ctx.dispatch(&mut enc, &ctx.pipelines.reduce_segments, &params, &r, threads, 1);
                }
            }
            ConvAlgorithm::Rulebook => {
                let n_pairs = count32("pairs", layer.num_pairs())?;
                let params = [0, cs, cd, 0, n_pairs, 0, 0, kv as u32];
                let b = [(1, &xb), (2, &layer.pairs()?.buffer), (4, &dwb), (5, &dyb)];
                let threads = count32("weights", dw.len())?.div_ceil(WORKGROUP);
                ctx.dispatch(&mut enc, &ctx.pipelines.weight_grad, &params, &b, threads, 1);
            }
        }
        ctx.finish_and_read(enc, &dwb, dw.len())
    }
}
