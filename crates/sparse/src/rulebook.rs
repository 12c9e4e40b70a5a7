//! The rulebook baseline, the paper's Algorithm 1 (as in SparseConvNet and MinkowskiEngine's
//! CPU path): for every kernel offset, gather its input rows into a dense buffer, multiply by
//! that offset's weights, scatter-add the products into the output rows. Each of the three
//! steps runs in parallel over row blocks with the same micro-GEMM as the chunked kernel, so
//! the comparison between the two measures the memory traffic of the algorithm, not the
//! arithmetic. The centre offset of a submanifold map is a plain GEMM with no gather.
//!
//! Deterministic: offsets are applied in index order and every output element is written by
//! one task per offset.

use rayon::prelude::*;

use crate::error::Result;
use crate::gemm::{gemm_rows, gemm_tn_rows};
use crate::kernel_map::{check_weights, transpose_weights, KernelMap};
use crate::scatter::DisjointRows;
use crate::tensor::check_rows;

/// Rows per parallel task.
const BLOCK: usize = 256;

fn iota(n: usize) -> Vec<u32> {
    (0..n as u32).collect()
}

/// `dst[dst_rows] += src[src_rows] . w_k` for every offset, Algorithm 1 style.
#[allow(clippy::too_many_arguments)]
fn apply(map: &KernelMap, swap: bool, src: &[f32], c_src: usize, w: &[f32], c_dst: usize, dst: &mut [f32]) {
    let kv = map.kernel_volume();
    let ident = iota(BLOCK);
    let most = (0..kv).map(|k| map.pairs(k).0.len()).max().unwrap_or(0);
    let mut gathered_buf = vec![0f32; most * c_src];
    let mut products_buf = vec![0f32; most * c_dst];
    for k in 0..kv {
        let (ins, outs) = map.pairs(k);
        let (from, to) = if swap { (outs, ins) } else { (ins, outs) };
        let wk = &w[k * c_src * c_dst..(k + 1) * c_src * c_dst];
        if map.centre() == Some(k) {
            // Identity pairs: one dense GEMM straight from the source rows.
            let rows = DisjointRows::new(dst);
            (0..from.len().div_ceil(BLOCK)).into_par_iter().for_each(|b| {
                let r0 = b * BLOCK;
                let m = BLOCK.min(from.len() - r0);
                // SAFETY: blocks cover disjoint row ranges.
                let out = unsafe { rows.slice(r0 * c_dst, m * c_dst) };
                let a = &src[r0 * c_src..(r0 + m) * c_src];
                gemm_rows(a, c_src, &ident[..m], wk, c_src, c_dst, out, c_dst, &ident[..m], true);
            });
            continue;
        }
        let p = from.len();
        let gathered = &mut gathered_buf[..p * c_src];
        let products = &mut products_buf[..p * c_dst];
        gathered.par_chunks_mut(BLOCK * c_src.max(1)).enumerate().for_each(|(b, g)| {
            for (j, &r) in from[b * BLOCK..].iter().take(BLOCK).enumerate() {
                if c_src > 0 {
                    g[j * c_src..(j + 1) * c_src].copy_from_slice(&src[r as usize * c_src..(r as usize + 1) * c_src]);
                }
            }
        });
        let gathered_ro: &[f32] = gathered;
        products.par_chunks_mut(BLOCK * c_dst.max(1)).enumerate().for_each(|(b, z)| {
            let m = BLOCK.min(p - b * BLOCK);
            let a = &gathered_ro[b * BLOCK * c_src..(b * BLOCK + m) * c_src];
            gemm_rows(a, c_src, &ident[..m], wk, c_src, c_dst, z, c_dst, &ident[..m], false);
        });
        let products: &[f32] = products;
        let rows = DisjointRows::new(dst);
        (0..p.div_ceil(BLOCK)).into_par_iter().for_each(|b| {
            for (j, &r) in to[b * BLOCK..].iter().take(BLOCK).enumerate() {
                let z = &products[(b * BLOCK + j) * c_dst..(b * BLOCK + j + 1) * c_dst];
                // SAFETY: within one offset every destination row appears once.
                let out = unsafe { rows.slice(r as usize * c_dst, c_dst) };
                for (o, &v) in out.iter_mut().zip(z) {
                    *o += v;
                }
            }
        });
    }
}

/// Forward pass.
///
/// # Shapes
/// `x`: `[map.n_in(), c_in]`; `w`: `[K^3, c_in, c_out]`; result `[map.n_out(), c_out]`.
///
/// # Errors
/// [`crate::SparseError::FeatureShape`] / [`crate::SparseError::WeightShape`] on mismatched buffers.
pub fn forward(map: &KernelMap, x: &[f32], c_in: usize, w: &[f32], c_out: usize) -> Result<Vec<f32>> {
    let mut y = vec![0f32; map.n_out() * c_out];
    forward_into(map, x, c_in, w, c_out, &mut y)?;
    Ok(y)
}

/// [`forward`] into a caller's buffer (overwritten).
///
/// # Shapes
/// `y`: `[map.n_out(), c_out]`.
///
/// # Errors
/// As [`forward`], and for a `y` of the wrong size.
pub fn forward_into(map: &KernelMap, x: &[f32], c_in: usize, w: &[f32], c_out: usize, y: &mut [f32]) -> Result<()> {
    check_rows("x", x, map.n_in(), c_in)?;
    check_weights(w, map.kernel_volume(), c_in, c_out)?;
    check_rows("y", y, map.n_out(), c_out)?;
    y.fill(0.0);
    apply(map, false, x, c_in, w, c_out, y);
    Ok(())
}

/// Input gradient.
///
/// # Shapes
/// `dy`: `[map.n_out(), c_out]`; `w`: `[K^3, c_in, c_out]`; result `[map.n_in(), c_in]`.
///
/// # Errors
/// As [`forward`].
pub fn backward_input(map: &KernelMap, dy: &[f32], c_out: usize, w: &[f32], c_in: usize) -> Result<Vec<f32>> {
    let mut dx = vec![0f32; map.n_in() * c_in];
    backward_input_into(map, dy, c_out, w, c_in, &mut dx)?;
    Ok(dx)
}

/// [`backward_input`] into a caller's buffer (overwritten).
///
/// # Shapes
/// `dx`: `[map.n_in(), c_in]`.
///
/// # Errors
/// As [`forward`], and for a `dx` of the wrong size.
pub fn backward_input_into(
    map: &KernelMap,
    dy: &[f32],
    c_out: usize,
    w: &[f32],
    c_in: usize,
    dx: &mut [f32],
) -> Result<()> {
    check_rows("dy", dy, map.n_out(), c_out)?;
    let kv = map.kernel_volume();
    check_weights(w, kv, c_in, c_out)?;
    check_rows("dx", dx, map.n_in(), c_in)?;
    let wt = transpose_weights(w, kv, c_in, c_out, |k| k);
    dx.fill(0.0);
    apply(map, true, dy, c_out, &wt, c_in, dx);
    Ok(())
}

/// Weight gradient; offsets in parallel, each one gather + GEMM.
///
/// # Shapes
/// `x`: `[map.n_in(), c_in]`; `dy`: `[map.n_out(), c_out]`; result `[K^3, c_in, c_out]`.
///
/// # Errors
/// As [`forward`].
pub fn backward_weight(map: &KernelMap, x: &[f32], c_in: usize, dy: &[f32], c_out: usize) -> Result<Vec<f32>> {
    check_rows("x", x, map.n_in(), c_in)?;
    check_rows("dy", dy, map.n_out(), c_out)?;
    let kv = map.kernel_volume();
    let mut dw = vec![0f32; kv * c_in * c_out];
    if c_in * c_out == 0 {
        return Ok(dw);
    }
    dw.par_chunks_mut(c_in * c_out).enumerate().for_each(|(k, dwk)| {
        let (ins, outs) = map.pairs(k);
        let p = ins.len();
        let ident = iota(p);
        if map.centre() == Some(k) {
            gemm_tn_rows(x, c_in, &ident, c_in, dy, c_out, &ident, c_out, dwk);
            return;
        }
        let mut a = vec![0f32; p * c_in];
        let mut b = vec![0f32; p * c_out];
        for (j, (&i, &o)) in ins.iter().zip(outs).enumerate() {
            a[j * c_in..(j + 1) * c_in].copy_from_slice(&x[i as usize * c_in..(i as usize + 1) * c_in]);
            b[j * c_out..(j + 1) * c_out].copy_from_slice(&dy[o as usize * c_out..(o as usize + 1) * c_out]);
        }
        gemm_tn_rows(&a, c_in, &ident, c_in, &b, c_out, &ident, c_out, dwk);
    });
    Ok(dw)
}
