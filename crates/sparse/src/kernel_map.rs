//! Kernel maps: for every kernel offset, the list of `(input row, output row)` pairs that the
//! convolution connects. A map is built once per level (from coordinates only) and reused by
//! every layer of that level, by the backward pass and by every kernel (reference, rulebook,
//! chunked; a GPU backend can upload the arrays as they are).
//!
//! Storage is CSR over offsets, plain index arrays: the pairs of offset `k` are
//! `in_rows[offset_start[k]..offset_start[k + 1]]` / `out_rows[...]`, sorted by output row.
//! Within one offset no input row and no output row repeats, for every map kind, so a
//! per-offset scatter never collides.
//!
//! Offset numbering. Submanifold, kernel size `K`, `r = (K - 1) / 2`: offset `(dx, dy, dz)`
//! with components in `[-r, r]` has index `((dz + r) * K + dy + r) * K + dx + r`; the input of
//! output `u` for it is `u + (dx, dy, dz)`. Offset `k` and `K^3 - 1 - k` are opposite, so the
//! pairs of the second half are the swapped pairs of the first half (only half the look-ups
//! are done) and the centre offset `(K^3 - 1) / 2` is the identity. Strided (down, K = 2,
//! stride 2): fine input `u` feeds coarse output `v = floor(u / 2)` through offset
//! `d = u - 2v` in `{0, 1}^3`, index `dx + 2 dy + 4 dz`. Transposed (up): the same pairs with
//! input and output swapped, coarse to fine.

use rayon::prelude::*;

use crate::block_index::VoxelIndex;
use crate::error::{Result, SparseError};
use crate::hash_map::VoxelHashMap;
use crate::key::{pack_key, parent, Coord};
use crate::morton::morton_unchecked;
use crate::tensor::check_row_count;

/// What a kernel map connects.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapKind {
    /// Submanifold convolution: output set = input set, `kernel_size^3` offsets.
    Submanifold {
        /// Odd kernel size.
        kernel_size: usize,
    },
    /// Strided convolution, K = 2, stride 2, fine to coarse.
    Down,
    /// Transposed convolution, K = 2, stride 2, coarse back to the fine set.
    Up,
}

/// Input/output pairs per kernel offset (see the module documentation for the layout).
#[derive(Debug, Clone, PartialEq)]
pub struct KernelMap {
    kind: MapKind,
    n_in: usize,
    n_out: usize,
    offset_start: Vec<usize>,
    in_rows: Vec<u32>,
    out_rows: Vec<u32>,
}

fn index_of(coords: &[Coord]) -> Result<VoxelHashMap> {
    check_row_count(coords.len())?;
    let mut map = VoxelHashMap::with_capacity(coords.len());
    for (row, &c) in coords.iter().enumerate() {
        if map.insert_or_get(pack_key(c, row)?, row as u32).is_some() {
            return Err(SparseError::InvalidArgument(format!(
                "duplicate coordinate {c:?} at row {row} (build a SparseTensor to merge duplicates)"
            )));
        }
    }
    Ok(map)
}

/// Checks a weight buffer against `[kernel_volume, c_in, c_out]`.
pub(crate) fn check_weights(w: &[f32], kernel_volume: usize, c_in: usize, c_out: usize) -> Result<()> {
    if kernel_volume.checked_mul(c_in).and_then(|v| v.checked_mul(c_out)) != Some(w.len()) {
        return Err(SparseError::WeightShape { len: w.len(), kernel_volume, c_in, c_out });
    }
    Ok(())
}

/// Weights `[kv, c_in, c_out]` transposed per offset to `[kv, c_out, c_in]`, with offset `k`
/// taken from `source(k)` (the mirror offset when a submanifold map is reused backwards).
pub(crate) fn transpose_weights(
    w: &[f32],
    kv: usize,
    c_in: usize,
    c_out: usize,
    source: impl Fn(usize) -> usize,
) -> Vec<f32> {
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

impl KernelMap {
    /// The submanifold map of a voxel set with an odd `kernel_size` (3 in the network).
    ///
    /// # Errors
    /// [`SparseError::KernelSize`] for an even or too large kernel, range errors and duplicate
    /// coordinates as [`SparseError::CoordOutOfRange`] / [`SparseError::InvalidArgument`].
    pub fn submanifold(coords: &[Coord], kernel_size: usize) -> Result<Self> {
        Ok(Self::submanifold_with_table(coords, kernel_size)?.0)
    }

    /// [`Self::submanifold`] and its `[n, K^3]` neighbour table (entry `(u, k)`: the input row
    /// of output `u` at offset `k`, or `u32::MAX`), which the chunk planner reads directly.
    ///
    /// The table is filled row by row from the block index (every voxel's neighbours are
    /// array reads once the blocks around its block are known), then transposed into the
    /// per-offset pair lists in row blocks, so the pairs come out sorted by output row.
    pub(crate) fn submanifold_with_table(coords: &[Coord], kernel_size: usize) -> Result<(Self, Vec<u32>)> {
        let table = Self::submanifold_table(coords, kernel_size)?;
        let map = Self::from_table(MapKind::Submanifold { kernel_size }, coords.len(), &table, kernel_size.pow(3));
        Ok((map, table))
    }

    /// The `[n, K^3]` neighbour table of [`Self::submanifold_with_table`] alone: what an
    /// engine that orders its work by rows needs (the GPU engine's tiles), without pair lists
    /// or a chunk plan.
    ///
    /// # Errors
    /// As [`Self::submanifold`].
    pub fn submanifold_table(coords: &[Coord], kernel_size: usize) -> Result<Vec<u32>> {
        let index = Self::submanifold_index(coords, kernel_size)?;
        Ok(if kernel_size == 1 {
            (0..coords.len() as u32).collect()
        } else {
            index.neighbour_table(coords, kernel_size)
        })
    }

    /// The voxel index of a submanifold layer, after the checks of [`Self::submanifold`].
    pub(crate) fn submanifold_index(coords: &[Coord], kernel_size: usize) -> Result<VoxelIndex> {
        if kernel_size.is_multiple_of(2) || kernel_size > 9 {
            return Err(SparseError::KernelSize(kernel_size));
        }
        check_row_count(coords.len())?;
        VoxelIndex::build(coords)
    }

    /// The map whose pairs are the non-empty entries of an `[n_out, kv]` table.
    pub(crate) fn from_table(kind: MapKind, n_in: usize, table: &[u32], kv: usize) -> Self {
        const ROWS: usize = 4096;
        let n_out = table.len().checked_div(kv).unwrap_or(0);
        // Per block of rows, its pairs per offset; blocks then concatenated per offset.
        let blocks: Vec<Vec<(Vec<u32>, Vec<u32>)>> = table
            .par_chunks(kv * ROWS)
            .enumerate()
            .map(|(b, t)| {
                let mut per: Vec<(Vec<u32>, Vec<u32>)> = vec![(Vec::new(), Vec::new()); kv];
                for (j, row) in t.chunks_exact(kv).enumerate() {
                    let u = (b * ROWS + j) as u32;
                    for (p, &i) in per.iter_mut().zip(row) {
                        if i != u32::MAX {
                            p.0.push(i);
                            p.1.push(u);
                        }
                    }
                }
                per
            })
            .collect();
        let mut offset_start = Vec::with_capacity(kv + 1);
        offset_start.push(0);
        for k in 0..kv {
            let count: usize = blocks.iter().map(|b| b[k].0.len()).sum();
            offset_start.push(offset_start[k] + count);
        }
        let total = offset_start[kv];
        let mut in_rows = vec![0u32; total];
        let mut out_rows = vec![0u32; total];
        // Disjoint destination ranges per offset, filled in parallel.
        let mut tasks = Vec::with_capacity(kv);
        let (mut rest_in, mut rest_out) = (&mut in_rows[..], &mut out_rows[..]);
        for k in 0..kv {
            let len = offset_start[k + 1] - offset_start[k];
            let (a, b) = std::mem::take(&mut rest_in).split_at_mut(len);
            let (c, d) = std::mem::take(&mut rest_out).split_at_mut(len);
            tasks.push((k, a, c));
            rest_in = b;
            rest_out = d;
        }
        tasks.into_par_iter().for_each(|(k, ins, outs)| {
            let mut q = 0;
            for b in &blocks {
                let (bi, bo) = &b[k];
                ins[q..q + bi.len()].copy_from_slice(bi);
                outs[q..q + bo.len()].copy_from_slice(bo);
                q += bi.len();
            }
        });
        Self { kind, n_in, n_out, offset_start, in_rows, out_rows }
    }

    /// The identity map of `n` rows (a 1x1x1 submanifold map, built without coordinates).
    ///
    /// # Errors
    /// [`SparseError::TooManyRows`] beyond the `u32` row range.
    pub fn identity(n: usize) -> Result<Self> {
        check_row_count(n)?;
        let rows: Vec<u32> = (0..n as u32).collect();
        Ok(Self {
            kind: MapKind::Submanifold { kernel_size: 1 },
            n_in: n,
            n_out: n,
            offset_start: vec![0, n],
            in_rows: rows.clone(),
            out_rows: rows,
        })
    }

    /// The coarse voxel set `{floor(u / 2)}` of `fine` (in order of first appearance, which is
    /// Z-order when `fine` is) and the strided map from `fine` to it.
    ///
    /// # Errors
    /// Range errors and duplicate coordinates.
    pub fn downsample(fine: &[Coord]) -> Result<(Vec<Coord>, Self)> {
        check_row_count(fine.len())?;
        let mut codes = Vec::with_capacity(fine.len());
        for (row, &c) in fine.iter().enumerate() {
            pack_key(c, row)?;
            codes.push(morton_unchecked(c));
        }
        let mut coarse = Vec::new();
        let mut parent_row = Vec::with_capacity(fine.len());
        if codes.windows(2).all(|w| w[0] < w[1]) {
            // Z-ordered without repeats (so no duplicates): the eight children of a coarse
            // voxel share `code >> 3` and are consecutive, so parents are runs, no hashing.
            let mut last = u64::MAX;
            for (&c, &code) in fine.iter().zip(&codes) {
                if code >> 3 != last {
                    last = code >> 3;
                    coarse.push(parent(c));
                }
                parent_row.push(coarse.len() as u32 - 1);
            }
        } else {
            index_of(fine)?;
            let mut coarse_index = VoxelHashMap::with_capacity(fine.len() / 2 + 4);
            for &c in fine {
                let p = parent(c);
                let v = coarse.len() as u32;
                match coarse_index.insert_or_get(crate::key::pack_unchecked(p), v) {
                    None => {
                        coarse.push(p);
                        parent_row.push(v);
                    }
                    Some(v) => parent_row.push(v),
                }
            }
        }
        let map = Self::strided(fine, &parent_row, coarse.len(), MapKind::Down);
        Ok((coarse, map))
    }

    /// The transposed (up) map from `coarse` back to `fine`: every fine voxel receives from
    /// its parent `floor(u / 2)`, which must be in `coarse`.
    ///
    /// # Errors
    /// [`SparseError::MissingParent`] when a fine voxel has no parent in `coarse`; range errors
    /// and duplicates.
    pub fn upsample(coarse: &[Coord], fine: &[Coord]) -> Result<Self> {
        let coarse_index = index_of(coarse)?;
        index_of(fine)?;
        let mut parent_row = Vec::with_capacity(fine.len());
        for (row, &c) in fine.iter().enumerate() {
            let p = parent(c);
            match coarse_index.get(crate::key::pack_unchecked(p)) {
                Some(v) => parent_row.push(v),
                None => return Err(SparseError::MissingParent { row, coord: c }),
            }
        }
        Ok(Self::strided(fine, &parent_row, coarse.len(), MapKind::Down).transposed())
    }

    fn strided(fine: &[Coord], parent_row: &[u32], n_coarse: usize, kind: MapKind) -> Self {
        let mut counts = [0usize; 8];
        let which: Vec<usize> = fine.iter().map(|c| ((c[0] & 1) + 2 * (c[1] & 1) + 4 * (c[2] & 1)) as usize).collect();
        for &k in &which {
            counts[k] += 1;
        }
        let mut offset_start = vec![0usize; 9];
        for k in 0..8 {
            offset_start[k + 1] = offset_start[k] + counts[k];
        }
        // Pairs grouped by offset, then sorted by coarse output row: a counting sort by parent.
        let mut per_offset: Vec<Vec<(u32, u32)>> = vec![Vec::new(); 8];
        for (row, (&k, &p)) in which.iter().zip(parent_row).enumerate() {
            per_offset[k].push((p, row as u32));
        }
        let mut in_rows = Vec::with_capacity(fine.len());
        let mut out_rows = Vec::with_capacity(fine.len());
        for list in &mut per_offset {
            list.sort_unstable();
            for &(p, row) in list.iter() {
                in_rows.push(row);
                out_rows.push(p);
            }
        }
        Self { kind, n_in: fine.len(), n_out: n_coarse, offset_start, in_rows, out_rows }
    }

    /// The same pairs with inputs and outputs swapped (the map of the input gradient); a
    /// `Down` map becomes the `Up` map of the same two sets and vice versa. Pairs are re-sorted
    /// by their new output row.
    pub fn transposed(&self) -> Self {
        let kv = self.kernel_volume();
        let mut in_rows = Vec::with_capacity(self.in_rows.len());
        let mut out_rows = Vec::with_capacity(self.in_rows.len());
        let mut offset_start = Vec::with_capacity(kv + 1);
        offset_start.push(0);
        for k in 0..kv {
            let (ins, outs) = self.pairs(k);
            let mut p: Vec<(u32, u32)> = ins.iter().zip(outs).map(|(&i, &o)| (i, o)).collect();
            p.sort_unstable();
            for (i, o) in p {
                in_rows.push(o);
                out_rows.push(i);
            }
            offset_start.push(in_rows.len());
        }
        let kind = match self.kind {
            MapKind::Down => MapKind::Up,
            MapKind::Up => MapKind::Down,
            k @ MapKind::Submanifold { .. } => k,
        };
        Self { kind, n_in: self.n_out, n_out: self.n_in, offset_start, in_rows, out_rows }
    }

    /// What the map connects.
    pub fn kind(&self) -> MapKind {
        self.kind
    }

    /// Number of kernel offsets (`K^3`, 8 for strided maps).
    pub fn kernel_volume(&self) -> usize {
        self.offset_start.len() - 1
    }

    /// Rows of the input set.
    pub fn n_in(&self) -> usize {
        self.n_in
    }

    /// Rows of the output set.
    pub fn n_out(&self) -> usize {
        self.n_out
    }

    /// Total number of pairs over all offsets.
    pub fn num_pairs(&self) -> usize {
        self.in_rows.len()
    }

    /// `(input rows, output rows)` of offset `k`, sorted by output row.
    ///
    /// # Panics
    /// When `k >= kernel_volume()` (a programming error, not a data error).
    pub fn pairs(&self, k: usize) -> (&[u32], &[u32]) {
        let r = self.offset_start[k]..self.offset_start[k + 1];
        (&self.in_rows[r.clone()], &self.out_rows[r])
    }

    /// CSR start of every offset in [`Self::in_rows`] / [`Self::out_rows`], `[kernel_volume + 1]`.
    pub fn offset_start(&self) -> &[usize] {
        &self.offset_start
    }

    /// Input row of every pair, grouped by offset.
    pub fn in_rows(&self) -> &[u32] {
        &self.in_rows
    }

    /// Output row of every pair, grouped by offset.
    pub fn out_rows(&self) -> &[u32] {
        &self.out_rows
    }

    /// The identity offset of a submanifold map (input row = output row for every row).
    pub fn centre(&self) -> Option<usize> {
        match self.kind {
            MapKind::Submanifold { .. } => Some(self.kernel_volume() / 2),
            _ => None,
        }
    }

    /// The opposite offset of `k` for submanifold maps (its pairs are `k`'s swapped).
    pub fn mirror(&self, k: usize) -> Option<usize> {
        match self.kind {
            MapKind::Submanifold { .. } => Some(self.kernel_volume() - 1 - k),
            _ => None,
        }
    }

    /// Mean number of pairs per output row (active neighbours for submanifold maps).
    pub fn mean_neighbours(&self) -> f64 {
        if self.n_out == 0 {
            0.0
        } else {
            self.num_pairs() as f64 / self.n_out as f64
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn mirror_offsets_hold_swapped_pairs() {
        let coords: Vec<Coord> = (0..40).map(|i| [i % 4, (i / 4) % 3, i / 12 - 1, 0]).collect();
        let m = KernelMap::submanifold(&coords, 3).unwrap();
        let c = m.centre().unwrap();
        assert_eq!(m.pairs(c).0, m.pairs(c).1);
        for k in 0..27 {
            let (i, o) = m.pairs(k);
            let (mi, mo) = m.pairs(26 - k);
            let mut a: Vec<_> = i.iter().zip(o).map(|(&a, &b)| (a, b)).collect();
            let mut b: Vec<_> = mi.iter().zip(mo).map(|(&a, &b)| (b, a)).collect();
            a.sort_unstable();
            b.sort_unstable();
            assert_eq!(a, b);
            assert!(o.windows(2).all(|w| w[0] < w[1]));
        }
    }

    #[test]
    fn down_then_up_returns_to_the_fine_set() {
        let fine: Vec<Coord> = vec![[-1, 0, 0, 0], [0, 0, 0, 0], [1, 1, 1, 0], [2, 0, 0, 1], [3, 3, -3, 1]];
        let (coarse, down) = KernelMap::downsample(&fine).unwrap();
        assert_eq!(coarse, vec![[-1, 0, 0, 0], [0, 0, 0, 0], [1, 0, 0, 1], [1, 1, -2, 1]]);
        assert_eq!(down.num_pairs(), 5);
        let up = KernelMap::upsample(&coarse, &fine).unwrap();
        assert_eq!(up, down.transposed());
        assert_eq!(up.kind(), MapKind::Up);
        assert!(KernelMap::upsample(&coarse[..1], &fine).is_err());
    }

    #[test]
    fn bad_kernel_sizes_and_duplicates_are_errors() {
        assert!(KernelMap::submanifold(&[], 2).is_err());
        assert!(KernelMap::submanifold(&[[0, 0, 0, 0], [0, 0, 0, 0]], 3).is_err());
        assert_eq!(KernelMap::submanifold(&[], 3).unwrap().num_pairs(), 0);
    }
}
