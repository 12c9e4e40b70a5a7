//! The element-wise steps of a network between its convolutions, on host buffers: the
//! attention gate, the weighted row gather (trilinear interpolation across levels), the bias
//! of a linear head and the per-row argmax. They are the CPU engine's implementations of the
//! element-wise half of [`ResidentBackend`](crate::ResidentBackend); the GPU engine has the
//! same operations as WGSL kernels.
//!
//! Rows are processed in parallel blocks, but every output value is computed by one thread in
//! a fixed order: the same bits for any number of rayon threads.

use rayon::prelude::*;

use crate::error::{Result, SparseError};

/// Rows per parallel task.
const ROWS_PER_TASK: usize = 256;

/// Per-row weighted sums of source rows: output row `u` receives
/// `sum_q weights[u, q] * src[rows[u, q]]` (entries of weight zero are skipped, so their rows
/// are never read). The network's trilinear interpolation from a coarse level to a fine one is
/// such a table, built once per input.
///
/// # Shapes
/// `rows`, `weights`: `[n, per_row]`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct GatherTable {
    rows: Vec<u32>,
    weights: Vec<f32>,
    per_row: usize,
    /// Largest source row referenced (`None` for an empty table), checked against every
    /// source at the call instead of per entry.
    max_row: Option<u32>,
}

impl GatherTable {
    /// A table of `per_row` `(row, weight)` entries per output row.
    ///
    /// # Shapes
    /// `rows`, `weights`: `[n, per_row]`.
    ///
    /// # Errors
    /// [`SparseError::InvalidArgument`] when the lengths differ, are not a multiple of
    /// `per_row`, or `per_row` is zero.
    pub fn new(rows: Vec<u32>, weights: Vec<f32>, per_row: usize) -> Result<Self> {
        if per_row == 0 || rows.len() != weights.len() || !rows.len().is_multiple_of(per_row) {
            return Err(SparseError::InvalidArgument(format!(
                "gather table of {} rows and {} weights with {per_row} entries per row",
                rows.len(),
                weights.len()
            )));
        }
        let max_row = rows.iter().copied().max();
        Ok(Self { rows, weights, per_row, max_row })
    }

    /// Source rows, `[n, per_row]`.
    pub fn rows(&self) -> &[u32] {
        &self.rows
    }

    /// Weights, `[n, per_row]`.
    pub fn weights(&self) -> &[f32] {
        &self.weights
    }

    /// Entries per output row.
    pub fn per_row(&self) -> usize {
        self.per_row
    }

    /// Output rows.
    pub fn len(&self) -> usize {
        self.rows.len() / self.per_row.max(1)
    }

    /// Whether the table has no output rows.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// Source rows a source must have (largest referenced row + 1).
    pub fn source_rows(&self) -> usize {
        self.max_row.map_or(0, |r| r as usize + 1)
    }
}

/// Checks that a buffer of `len` values holds `rows x channels`.
///
/// # Errors
/// [`SparseError::TensorTooShort`].
pub fn check_len(what: &'static str, len: usize, rows: usize, channels: usize) -> Result<usize> {
    match rows.checked_mul(channels) {
        Some(need) if need <= len => Ok(need),
        _ => Err(SparseError::TensorTooShort { what, len, rows, channels }),
    }
}

/// The attention gate: `g[r, ..c] *= sigmoid(g[r, c])` for every row of `c + 1` values.
///
/// # Shapes
/// `g`: `[rows, c + 1]`.
pub fn gate(g: &mut [f32], c: usize) {
    g.par_chunks_mut((c + 1) * ROWS_PER_TASK).for_each(|blk| {
        for row in blk.chunks_exact_mut(c + 1) {
            let s = 1.0 / (1.0 + (-row[c]).exp());
            for v in &mut row[..c] {
                *v *= s;
            }
        }
    });
}

/// `dst[u, ..c] += sum_q w[u, q] src[row[u, q], ..c]` with source rows of `stride` values,
/// entries in table order (weight-zero entries skipped).
///
/// # Shapes
/// `src`: `[table.source_rows(), stride]` (at least); `dst`: `[table.len(), c]`.
///
/// # Errors
/// [`SparseError::TensorTooShort`] for short buffers, [`SparseError::InvalidArgument`] when
/// `c > stride`.
pub fn gather_add(table: &GatherTable, src: &[f32], stride: usize, c: usize, dst: &mut [f32]) -> Result<()> {
    if c > stride {
        return Err(SparseError::InvalidArgument(format!("gathering {c} channels from rows of {stride}")));
    }
    check_len("gather source", src.len(), table.source_rows(), stride)?;
    let n = check_len("gather destination", dst.len(), table.len(), c)?;
    if c == 0 {
        return Ok(());
    }
    let q = table.per_row;
    dst[..n].par_chunks_mut(c * ROWS_PER_TASK).enumerate().for_each(|(blk, dd)| {
        for (r, drow) in dd.chunks_exact_mut(c).enumerate() {
            let u = blk * ROWS_PER_TASK + r;
            for e in u * q..(u + 1) * q {
                let w = table.weights[e];
                if w == 0.0 {
                    continue;
                }
                let s = table.rows[e] as usize * stride;
                for (dv, &gv) in drow.iter_mut().zip(&src[s..s + c]) {
                    *dv += w * gv;
                }
            }
        }
    });
    Ok(())
}

/// `y[r, ..] += bias` for every row.
///
/// # Shapes
/// `y`: `[rows, c]` with `c = bias.len()`.
pub fn add_bias(y: &mut [f32], bias: &[f32]) {
    let c = bias.len();
    if c == 0 {
        return;
    }
    y.par_chunks_mut(c * ROWS_PER_TASK).for_each(|blk| {
        for row in blk.chunks_exact_mut(c) {
            row.iter_mut().zip(bias).for_each(|(v, b)| *v += b);
        }
    });
}

/// The index of the largest of every row of `k` scores (the first on ties; a NaN never wins
/// over the values before it).
///
/// # Shapes
/// `scores`: `[rows, k]`; result `[rows]`.
pub fn argmax_rows(scores: &[f32], k: usize) -> Vec<u32> {
    scores
        .chunks_exact(k.max(1))
        .map(|row| {
            let mut best = 0;
            for (c, &s) in row.iter().enumerate() {
                if s > row[best] {
                    best = c;
                }
            }
            best as u32
        })
        .collect()
}
