//! The naive reference: sparse convolution written as plain loops over voxels and offsets with
//! `f64` accumulation, looking neighbours up in a `std` hash map straight from the coordinates.
//! It shares no code with the kernel maps or the fast kernels, which makes it the oracle of
//! the tests. Slow on purpose; use it only on small sets.

use std::collections::HashMap;

use crate::error::{Result, SparseError};
use crate::kernel_map::{check_weights, MapKind};
use crate::key::{parent, Coord};
use crate::tensor::check_rows;

/// `(offset, input row, output row)` of one connection.
type Triple = (usize, usize, usize);

/// The kernel volume and the connections of a layer, found by brute force.
fn triples(kind: MapKind, in_coords: &[Coord], out_coords: &[Coord]) -> Result<(usize, Vec<Triple>)> {
    let in_index: HashMap<Coord, usize> = in_coords.iter().enumerate().map(|(i, &c)| (c, i)).collect();
    let out_index: HashMap<Coord, usize> = out_coords.iter().enumerate().map(|(i, &c)| (c, i)).collect();
    let parity = |c: Coord| ((c[0] & 1) + 2 * (c[1] & 1) + 4 * (c[2] & 1)) as usize;
    let mut t = Vec::new();
    match kind {
        MapKind::Submanifold { kernel_size } => {
            if kernel_size.is_multiple_of(2) {
                return Err(SparseError::KernelSize(kernel_size));
            }
            let r = (kernel_size / 2) as i32;
            for (o, u) in out_coords.iter().enumerate() {
                let mut k = 0;
                for dz in -r..=r {
                    for dy in -r..=r {
                        for dx in -r..=r {
                            if let Some(&i) = in_index.get(&[u[0] + dx, u[1] + dy, u[2] + dz, u[3]]) {
                                t.push((k, i, o));
                            }
                            k += 1;
                        }
                    }
                }
            }
            Ok((kernel_size.pow(3), t))
        }
        MapKind::Down => {
            for (i, &u) in in_coords.iter().enumerate() {
                let o = *out_index.get(&parent(u)).ok_or(SparseError::MissingParent { row: i, coord: u })?;
                t.push((parity(u), i, o));
            }
            Ok((8, t))
        }
        MapKind::Up => {
            for (o, &u) in out_coords.iter().enumerate() {
                let i = *in_index.get(&parent(u)).ok_or(SparseError::MissingParent { row: o, coord: u })?;
                t.push((parity(u), i, o));
            }
            Ok((8, t))
        }
    }
}

/// Forward pass: `y[out] = sum over pairs of x[in] . W[offset]`.
///
/// # Shapes
/// `x`: `[in_coords.len(), c_in]`; `w`: `[K^3, c_in, c_out]`; result `[out_coords.len(), c_out]`.
///
/// # Errors
/// Shape mismatches, even kernel sizes, missing parents of strided layers.
pub fn forward(
    kind: MapKind,
    in_coords: &[Coord],
    out_coords: &[Coord],
    x: &[f32],
    c_in: usize,
    w: &[f32],
    c_out: usize,
) -> Result<Vec<f32>> {
    check_rows("x", x, in_coords.len(), c_in)?;
    let (kv, t) = triples(kind, in_coords, out_coords)?;
    check_weights(w, kv, c_in, c_out)?;
    let mut y = vec![0f64; out_coords.len() * c_out];
    for &(k, i, o) in &t {
        for co in 0..c_out {
            let mut s = 0f64;
            for ci in 0..c_in {
                s += f64::from(x[i * c_in + ci]) * f64::from(w[(k * c_in + ci) * c_out + co]);
            }
            y[o * c_out + co] += s;
        }
    }
    Ok(y.into_iter().map(|v| v as f32).collect())
}

/// Input gradient: `dx[in] = sum over pairs of dy[out] . W[offset]^T`.
///
/// # Shapes
/// `dy`: `[out_coords.len(), c_out]`; `w`: `[K^3, c_in, c_out]`; result `[in_coords.len(), c_in]`.
///
/// # Errors
/// As [`forward`].
pub fn backward_input(
    kind: MapKind,
    in_coords: &[Coord],
    out_coords: &[Coord],
    dy: &[f32],
    c_out: usize,
    w: &[f32],
    c_in: usize,
) -> Result<Vec<f32>> {
    check_rows("dy", dy, out_coords.len(), c_out)?;
    let (kv, t) = triples(kind, in_coords, out_coords)?;
    check_weights(w, kv, c_in, c_out)?;
    let mut dx = vec![0f64; in_coords.len() * c_in];
    for &(k, i, o) in &t {
        for ci in 0..c_in {
            let mut s = 0f64;
            for co in 0..c_out {
                s += f64::from(dy[o * c_out + co]) * f64::from(w[(k * c_in + ci) * c_out + co]);
            }
            dx[i * c_in + ci] += s;
        }
    }
    Ok(dx.into_iter().map(|v| v as f32).collect())
}

/// Weight gradient: `dW[offset] = sum over pairs of x[in]^T dy[out]`.
///
/// # Shapes
/// `x`: `[in_coords.len(), c_in]`; `dy`: `[out_coords.len(), c_out]`; result `[K^3, c_in, c_out]`.
///
/// # Errors
/// As [`forward`].
pub fn backward_weight(
    kind: MapKind,
    in_coords: &[Coord],
    out_coords: &[Coord],
    x: &[f32],
    c_in: usize,
    dy: &[f32],
    c_out: usize,
) -> Result<Vec<f32>> {
    check_rows("x", x, in_coords.len(), c_in)?;
    check_rows("dy", dy, out_coords.len(), c_out)?;
    let (kv, t) = triples(kind, in_coords, out_coords)?;
    let mut dw = vec![0f64; kv * c_in * c_out];
    for &(k, i, o) in &t {
        for ci in 0..c_in {
            for co in 0..c_out {
                dw[(k * c_in + ci) * c_out + co] += f64::from(x[i * c_in + ci]) * f64::from(dy[o * c_out + co]);
            }
        }
    }
    Ok(dw.into_iter().map(|v| v as f32).collect())
}
