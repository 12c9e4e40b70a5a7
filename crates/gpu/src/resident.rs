//! The GPU engine's tensors: [`ResidentBackend`] on device buffers. A network uploads its
//! weights once ([`GpuTensor`]s kept by the caller across calls), its input once per forward,
//! and reads back only the logits (or the labels: an argmax kernel); convolutions and the
//! element-wise steps between them (attention gate, weighted row gather, bias) run on the
//! device buffers where they are. Operations are recorded into the queued work without waiting
//! (`GpuContext::record`); the read-back submits the queue and waits once.
//!
//! Tensors are only ever created fresh (upload, growth), never rewritten through the queue,
//! so the queued work that reads them cannot see a later write land early.

use semrecon_sparse::elementwise::check_len;
use semrecon_sparse::{ConvAlgorithm, ConvBackend, GatherTable, ResidentBackend, SparseError};

use crate::context::{Transfer, WORKGROUP};
use crate::engine::{count32, GpuEngine};
use crate::error::{GpuError, Result};
use crate::layer::GpuLayer;
use crate::record::Recorder;

/// A flat `f32` buffer on the device of the [`GpuEngine`] that made it.
#[derive(Debug)]
pub struct GpuTensor {
    pub(crate) buffer: wgpu::Buffer,
    /// Values the buffer holds.
    pub(crate) len: usize,
}

/// A [`GatherTable`] on the device: `[rows | weight bits]` in one buffer.
#[derive(Debug)]
pub struct GpuGather {
    buffer: wgpu::Buffer,
    rows: usize,
    per_row: usize,
    source_rows: usize,
}

impl GpuGather {
    /// A table already on the device (`[rows | weight bits]`, `rows x per_row` each).
    pub(crate) fn on_device(buffer: wgpu::Buffer, rows: usize, per_row: usize, source_rows: usize) -> Self {
        Self { buffer, rows, per_row, source_rows }
    }

    /// Rows of the table.
    pub fn len(&self) -> usize {
        self.rows
    }

    /// Whether the table has no rows.
    pub fn is_empty(&self) -> bool {
        self.rows == 0
    }

    /// Entries per row.
    pub fn per_row(&self) -> usize {
        self.per_row
    }

    pub(crate) fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }
}

impl GpuEngine {
    /// Records one element-wise kernel over `threads` threads into `enc`.
    fn elementwise(
        &self,
        enc: &mut Recorder,
        pipeline: &wgpu::ComputePipeline,
        params: [u32; 4],
        bindings: &[(u32, &wgpu::Buffer)],
        threads: usize,
    ) -> Result<()> {
        let groups = count32("threads", threads)?.div_ceil(WORKGROUP);
        self.context().dispatch(enc, pipeline, &params, bindings, groups, 1);
        Ok(())
    }
}

impl ResidentBackend for GpuEngine {
    type Tensor = GpuTensor;
    type Gather = GpuGather;

    fn upload(&self, data: &[f32]) -> Result<GpuTensor> {
        let buffer = self.context().upload_counted("tensor", data, Transfer::Tensor)?;
        Ok(GpuTensor { buffer, len: data.len() })
    }

    fn download(&self, t: &GpuTensor, len: usize) -> Result<Vec<f32>> {
        check_len("download", t.len, len, 1).map_err(GpuError::from)?;
        let ctx = self.context();
        let _call = ctx.begin_resident_call()?;
        ctx.finish_and_read(ctx.encoder(), &t.buffer, len)
    }

    fn tensor_len(&self, t: &GpuTensor) -> usize {
        t.len
    }

    fn reserve(&self, t: &mut GpuTensor, len: usize) -> Result<()> {
        if t.len < len {
            // A new buffer (queued work keeps the old one alive until it has run).
            t.buffer = self.context().zeroed("tensor", len as u64 * 4)?;
            t.len = len;
        }
        Ok(())
    }

    fn gather_table(&self, table: &GatherTable) -> Result<GpuGather> {
        let mut words = Vec::with_capacity(table.rows().len() * 2);
        words.extend_from_slice(table.rows());
        words.extend(table.weights().iter().map(|w| w.to_bits()));
        Ok(GpuGather {
            buffer: self.context().upload("gather table", &words)?,
            rows: table.len(),
            per_row: table.per_row(),
            source_rows: table.source_rows(),
        })
    }

    fn conv(
        &self,
        layer: &GpuLayer,
        x: &GpuTensor,
        c_in: usize,
        bn: Option<&GpuTensor>,
        w: &GpuTensor,
        c_out: usize,
        y: &mut GpuTensor,
        accumulate: bool,
    ) -> Result<()> {
        let (n_in, n_out) = self.layer_rows(layer);
        let x_len = check_len("x", x.len, n_in, c_in)?;
        check_len("weights", w.len, layer.kv * c_in, c_out)?;
        if let Some(bn) = bn {
            check_len("batch norm", bn.len, 2, c_in)?;
        }
        let y_len = check_len("y", y.len, n_out, c_out)?;
        if y_len == 0 {
            return Ok(());
        }
        let ctx = self.context();
        let _call = ctx.begin_resident_call()?;
        let bnb = bn.map(|t| &t.buffer);
        ctx.record(|enc| match self.algorithm {
            // Nothing to read: the convolution is zero.
            _ if x_len == 0 => {
                if !accumulate {
                    enc.clear(&y.buffer, y_len as u64 * 4);
                }
                Ok(())
            }
            ConvAlgorithm::Chunked => self.encode_chunked(
                enc,
                layer.forward_plan()?,
                layer.kv,
                &x.buffer,
                c_in,
                bnb,
                &w.buffer,
                c_out,
                &y.buffer,
                accumulate,
            ),
            ConvAlgorithm::Rulebook => self.encode_rulebook(
                enc,
                layer,
                false,
                &x.buffer,
                c_in,
                bnb,
                &w.buffer,
                c_out,
                &y.buffer,
                (x_len, y_len),
                accumulate,
            ),
        })
    }

    fn gate(&self, g: &mut GpuTensor, rows: usize, c: usize) -> Result<()> {
        check_len("gate", g.len, rows, c + 1)?;
        if rows * c == 0 {
            return Ok(());
        }
        let ctx = self.context();
        let _call = ctx.begin_resident_call()?;
        let params = [count32("rows", rows)?, count32("channels", c)?, 0, 0];
        ctx.record(|enc| self.elementwise(enc, &ctx.pipelines.gate, params, &[(3, &g.buffer)], rows * c))
    }

    fn gather_add(
        &self,
        table: &GpuGather,
        src: &GpuTensor,
        stride: usize,
        c: usize,
        dst: &mut GpuTensor,
    ) -> Result<()> {
        if c > stride {
            return Err(SparseError::InvalidArgument(format!("gathering {c} channels from rows of {stride}")).into());
        }
        check_len("gather source", src.len, table.source_rows, stride)?;
        let n = check_len("gather destination", dst.len, table.rows, c)?;
        if n == 0 {
            return Ok(());
        }
        let ctx = self.context();
        let _call = ctx.begin_resident_call()?;
        let params =
            [count32("rows", table.rows)?, count32("channels", c)?, count32("stride", stride)?, table.per_row as u32];
        let bindings = [(1, &src.buffer), (2, &table.buffer), (3, &dst.buffer)];
        ctx.record(|enc| self.elementwise(enc, &ctx.pipelines.gather_add, params, &bindings, n))
    }

    fn add_bias(&self, y: &mut GpuTensor, rows: usize, bias: &GpuTensor, c: usize) -> Result<()> {
        check_len("bias", bias.len, 1, c)?;
        let n = check_len("y", y.len, rows, c)?;
        if n == 0 {
            return Ok(());
        }
        let ctx = self.context();
        let _call = ctx.begin_resident_call()?;
        let params = [count32("rows", rows)?, count32("channels", c)?, 0, 0];
        let bindings = [(1, &bias.buffer), (3, &y.buffer)];
        ctx.record(|enc| self.elementwise(enc, &ctx.pipelines.add_bias, params, &bindings, n))
    }

    fn argmax_rows(&self, scores: &GpuTensor, rows: usize, k: usize) -> Result<Vec<u32>> {
        if k == 0 && rows > 0 {
            return Err(SparseError::InvalidArgument("argmax over rows of no scores".into()).into());
        }
        check_len("scores", scores.len, rows, k)?;
        if rows == 0 {
            return Ok(Vec::new());
        }
        let ctx = self.context();
        let _call = ctx.begin_resident_call()?;
        // Pooled, and written only by the kernel below.
        let labels = ctx.transient("labels", rows as u64 * 4)?;
        let params = [count32("rows", rows)?, count32("scores", k)?, 0, 0];
        let bindings = [(1, &scores.buffer), (4, &labels)];
        ctx.record(|enc| self.elementwise(enc, &ctx.pipelines.argmax, params, &bindings, rows))?;
        ctx.finish_and_read(ctx.encoder(), &labels, rows)
    }
}
