//! Engines that own their tensors: [`ResidentBackend`], the layer-by-layer interface a whole
//! network runs on without leaving the device.
//!
//! [`ConvBackend`] takes and returns host slices, which is what tests and single layers want,
//! but a network run that way on a GPU copies every activation and weight across the bus twice
//! per layer. A resident backend instead hands out tensors of its own ([`Self::Tensor`]: host
//! vectors for the CPU engine, device buffers for the GPU engine), uploaded once
//! ([`ResidentBackend::upload`]) and read back once ([`ResidentBackend::download`] or, for
//! labels only, [`ResidentBackend::argmax_rows`]); in between, convolutions and the
//! element-wise steps of the network (attention gate, weighted row gather, bias) run on them
//! where they live. Code above the engines is then written once, generic over the backend, as
//! burn's backends do it.
//!
//! Tensors are flat `f32` buffers with a capacity: an operation reads and writes the leading
//! `rows x channels` values its shapes name, so a workspace can keep one tensor per role and
//! only grow it ([`ResidentBackend::reserve`]). Every operation checks lengths and returns
//! [`SparseError::TensorTooShort`] instead of reading past the end.

use crate::backend::{BnRelu, ConvBackend, CpuEngine};
use crate::chunked::ChunkedConv;
use crate::elementwise::{self, check_len, GatherTable};
use crate::error::{Result, SparseError};

/// A [`ConvBackend`] whose tensors live where it computes: upload once, run layers and
/// element-wise steps in place, read back once.
///
/// Results match the host path ([`ConvBackend::forward_into`] and the functions of
/// [`crate::elementwise`]) to 1e-4 of the largest magnitude; the CPU engine's are identical
/// bits. A tensor belongs to the engine (device) that made it.
pub trait ResidentBackend: ConvBackend {
    /// A flat `f32` buffer owned by the engine.
    type Tensor;
    /// A [`GatherTable`] prepared for the engine.
    type Gather;

    /// A tensor holding `data`.
    ///
    /// # Errors
    /// Buffers over the device's limits, a lost device.
    fn upload(&self, data: &[f32]) -> Result<Self::Tensor, Self::Error>;

    /// The first `len` values of `t` on the host.
    ///
    /// # Errors
    /// [`SparseError::TensorTooShort`], read-back failures.
    fn download(&self, t: &Self::Tensor, len: usize) -> Result<Vec<f32>, Self::Error>;

    /// Values `t` holds (its capacity).
    fn tensor_len(&self, t: &Self::Tensor) -> usize;

    /// Grows `t` to hold at least `len` values; after growing, its contents are unspecified
    /// (every operation of the network writes its output before reading it).
    ///
    /// # Errors
    /// Buffers over the device's limits, a lost device.
    fn reserve(&self, t: &mut Self::Tensor, len: usize) -> Result<(), Self::Error>;

    /// `table` prepared for [`Self::gather_add`].
    ///
    /// # Errors
    /// Buffers over the device's limits, a lost device.
    fn gather_table(&self, table: &GatherTable) -> Result<Self::Gather, Self::Error>;

    /// `y = conv(bn_relu(x), w)` (with `accumulate`, `y += ...`) on the engine's tensors, as
    /// [`ConvBackend::forward_into`]; `bn` holds the folded scale then shift.
    ///
    /// # Shapes
    /// `x`: `[n_in, c_in]`; `bn`: `[2, c_in]`; `w`: `[K^3, c_in, c_out]`; `y`:
    /// `[n_out, c_out]` (leading values of each tensor).
    ///
    /// # Errors
    /// Short tensors, device errors.
    #[allow(clippy::too_many_arguments)]
    fn conv(
        &self,
        layer: &Self::Layer,
        x: &Self::Tensor,
        c_in: usize,
        bn: Option<&Self::Tensor>,
        w: &Self::Tensor,
        c_out: usize,
        y: &mut Self::Tensor,
        accumulate: bool,
    ) -> Result<(), Self::Error>;

    /// The attention gate in place: `g[r, ..c] *= sigmoid(g[r, c])`.
    ///
    /// # Shapes
    /// `g`: `[rows, c + 1]`.
    ///
    /// # Errors
    /// Short tensors, device errors.
    fn gate(&self, g: &mut Self::Tensor, rows: usize, c: usize) -> Result<(), Self::Error>;

    /// `dst[u, ..c] += sum_q w[u, q] src[row[u, q], ..c]` (see [`elementwise::gather_add`]).
    ///
    /// # Shapes
    /// `src`: `[source rows, stride]`; `dst`: `[table rows, c]`.
    ///
    /// # Errors
    /// Short tensors, `c > stride`, device errors.
    fn gather_add(
        &self,
        table: &Self::Gather,
        src: &Self::Tensor,
        stride: usize,
        c: usize,
        dst: &mut Self::Tensor,
    ) -> Result<(), Self::Error>;

    /// `y[r, ..c] += bias` for `rows` rows.
    ///
    /// # Shapes
    /// `y`: `[rows, c]`; `bias`: `[c]`.
    ///
    /// # Errors
    /// Short tensors, device errors.
    fn add_bias(&self, y: &mut Self::Tensor, rows: usize, bias: &Self::Tensor, c: usize) -> Result<(), Self::Error>;

    /// The index of the largest of each row's `k` scores (the first on ties), on the host:
    /// the labels of a segmentation with one small read-back instead of the scores.
    ///
    /// # Shapes
    /// `scores`: `[rows, k]`; result `[rows]`.
    ///
    /// # Errors
    /// Short tensors, read-back failures.
    fn argmax_rows(&self, scores: &Self::Tensor, rows: usize, k: usize) -> Result<Vec<u32>, Self::Error>;
}

/// The leading `rows x channels` values of a host tensor.
fn lead<'a>(what: &'static str, t: &'a [f32], rows: usize, channels: usize) -> Result<&'a [f32]> {
    Ok(&t[..check_len(what, t.len(), rows, channels)?])
}

/// The leading `rows x channels` values of a host tensor, writable.
fn lead_mut<'a>(what: &'static str, t: &'a mut [f32], rows: usize, channels: usize) -> Result<&'a mut [f32]> {
    let n = check_len(what, t.len(), rows, channels)?;
    Ok(&mut t[..n])
}

/// The CPU engine's tensors are host vectors: upload and download are copies, and every
/// operation is the host path itself (the same bits as [`ConvBackend::forward_into`] and
/// [`crate::elementwise`]).
impl ResidentBackend for CpuEngine {
    type Tensor = Vec<f32>;
    type Gather = GatherTable;

    fn upload(&self, data: &[f32]) -> Result<Vec<f32>> {
        Ok(data.to_vec())
    }

    fn download(&self, t: &Vec<f32>, len: usize) -> Result<Vec<f32>> {
        Ok(lead("download", t, len, 1)?.to_vec())
    }

    fn tensor_len(&self, t: &Vec<f32>) -> usize {
        t.len()
    }

    fn reserve(&self, t: &mut Vec<f32>, len: usize) -> Result<()> {
        // Only grows: a workspace of similar inputs then never allocates or clears again.
        if t.len() < len {
            t.resize(len, 0.0);
        }
        Ok(())
    }

    fn gather_table(&self, table: &GatherTable) -> Result<GatherTable> {
        Ok(table.clone())
    }

    fn conv(
        &self,
        layer: &ChunkedConv,
        x: &Vec<f32>,
        c_in: usize,
        bn: Option<&Vec<f32>>,
        w: &Vec<f32>,
        c_out: usize,
        y: &mut Vec<f32>,
        accumulate: bool,
    ) -> Result<()> {
        let kv = layer.forward_plan().kernel_volume();
        let x = lead("x", x, layer.n_in(), c_in)?;
        let w = lead("weights", w, kv * c_in, c_out)?;
        let bn = match bn {
            Some(t) => {
                let t = lead("batch norm", t, 2, c_in)?;
                Some(BnRelu { scale: &t[..c_in], shift: &t[c_in..] })
            }
            None => None,
        };
        let y = lead_mut("y", y, layer.n_out(), c_out)?;
        self.forward_into(layer, x, c_in, bn, w, c_out, y, accumulate)
    }

    fn gate(&self, g: &mut Vec<f32>, rows: usize, c: usize) -> Result<()> {
        elementwise::gate(lead_mut("gate", g, rows, c + 1)?, c);
        Ok(())
    }

    fn gather_add(
        &self,
        table: &GatherTable,
        src: &Vec<f32>,
        stride: usize,
        c: usize,
        dst: &mut Vec<f32>,
    ) -> Result<()> {
        elementwise::gather_add(table, src, stride, c, dst)
    }

    fn add_bias(&self, y: &mut Vec<f32>, rows: usize, bias: &Vec<f32>, c: usize) -> Result<()> {
        let bias = lead("bias", bias, 1, c)?;
        elementwise::add_bias(lead_mut("y", y, rows, c)?, bias);
        Ok(())
    }

    fn argmax_rows(&self, scores: &Vec<f32>, rows: usize, k: usize) -> Result<Vec<u32>> {
        if k == 0 && rows > 0 {
            return Err(SparseError::InvalidArgument("argmax over rows of no scores".into()));
        }
        Ok(elementwise::argmax_rows(lead("scores", scores, rows, k)?, k))
    }
}
