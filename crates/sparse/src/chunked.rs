//! The chunk-based kernel, the paper's Algorithm 2 adapted to CPU caches.
//!
//! Surfaces are continuous, so outputs that are close in space share most of their inputs.
//! The output voxels are sorted along the Z-order curve and cut into aligned cubic chunks of
//! side `C` (runs of equal Morton prefix); a chunk whose *input region* (the distinct input
//! rows its outputs read) exceeds the cache budget is split into its eight `C/2` sub-cubes,
//! and again into `C/4` ([`ChunkConfig::levels`] levels in all), so chunks are large where the
//! surface is sparse and small where it is dense. A kernel pass then handles one chunk per
//! rayon task: copy the region's rows once into a contiguous buffer, run one micro-GEMM per
//! offset from it (rows addressed through the chunk-local pair lists), and write each output
//! row exactly once. No atomics, no scatter into shared memory, and the result does not depend
//! on the thread count.
//!
//! The [`ChunkPlan`] is plain index arrays (CSR over chunks, then over offsets) built once per
//! kernel map: a GPU backend can upload it as it is, one thread block per chunk.
//!
//! Backward: the input gradient is the forward pass of the transposed map. For submanifold
//! maps that map is the same map with offsets mirrored, so the forward plan is reused with
//! mirrored transposed weights; strided maps get a second plan chunked over the input set.
//! The weight gradient walks the forward plan: per chunk and offset a micro-GEMM `X^T dY`
//! into per-group partial sums; groups are runs of chunks balanced by pair count (a function
//! of the plan alone, not of the thread count) and are reduced in index order, so the result
//! is deterministic too.
//!
//! Row order: any. When the output rows of a chunk are one contiguous run (tensors in Z-order,
//! as [`crate::voxelize()`] and [`crate::SparseTensor::sorted_morton`] make them) the chunk
//! is computed in place in the output; otherwise through a chunk buffer and one copy.

use std::sync::{Mutex, OnceLock};

use rayon::prelude::*;

use crate::block_index::NeighbourFinder;
use crate::error::{Result, SparseError};
use crate::gemm::{gemm_rows, gemm_tn_rows};
use crate::kernel_map::{check_weights, transpose_weights, KernelMap, MapKind};
use crate::key::{pack_key, Coord};
use crate::morton::morton_unchecked;
use crate::scatter::DisjointRows;
use crate::tensor::check_rows;

/// How outputs are cut into chunks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChunkConfig {
    /// Side of the top-level cubic chunks in voxels of the output grid (a power of two).
    pub chunk_side: u32,
    /// Splitting levels: chunks of side `C`, `C/2`, ..., `C / 2^(levels - 1)`.
    pub levels: u32,
    /// Largest input region (rows) a chunk may read before it is split; the cache budget in
    /// rows (bytes = rows x channels x 4).
    pub max_region_rows: usize,
}

impl Default for ChunkConfig {
    /// Side 8, three levels (8, 4, 2), 256 region rows (64 KiB at 64 channels). Measured on
    /// the benchmark room (35k voxels at 2 cm, 64 channels, `conv_bench --sweep`): forward and
    /// input gradient are flat (within 5 %) from side 4 to 32 because every chunk's working
    /// set stays in L2 at these sizes; the weight gradient wants L1-sized regions and is 10-50 % slower with chunks of
    /// side 16-32 and no splitting, or side 4 (halo 2.2x). Side 8 also leaves ~500 chunks for
    /// load balance.
    fn default() -> Self {
        Self { chunk_side: 8, levels: 3, max_region_rows: 256 }
    }
}

/// Chunks of a kernel map's outputs with their input regions and chunk-local pairs.
///
/// Layout (all plain arrays, indices are `u32`):
/// - chunk `c` owns destination rows `dst_rows[dst_start[c]..dst_start[c + 1]]` (Z-order);
/// - its input region is `src_rows[src_start[c]..src_start[c + 1]]`; for maps with an
///   identity centre offset the first region rows are the chunk's own destination rows;
/// - pairs of chunk `c`, offset `k` are `pair_src[q]`, `pair_dst[q]` for `q` in
///   `pair_start[c * K + k]..pair_start[c * K + k + 1]`, as indices into the chunk's region
///   and destination lists.
#[derive(Debug, Clone, PartialEq)]
pub struct ChunkPlan {
    kernel_volume: usize,
    centre: Option<usize>,
    n_src: usize,
    n_dst: usize,
    dst_start: Vec<u32>,
    dst_rows: Vec<u32>,
    src_start: Vec<u32>,
    src_rows: Vec<u32>,
    pair_start: Vec<u32>,
    pair_src: Vec<u32>,
    pair_dst: Vec<u32>,
    iota: Vec<u32>,
}

/// Borrowed index arrays of a [`ChunkPlan`] (see its documentation for the layout).
#[derive(Debug, Clone, Copy)]
pub struct ChunkPlanArrays<'a> {
    /// CSR start of every chunk in `dst_rows`, `[chunks + 1]`.
    pub dst_start: &'a [u32],
    /// Destination rows grouped by chunk, `[n_dst]`.
    pub dst_rows: &'a [u32],
    /// CSR start of every chunk in `src_rows`, `[chunks + 1]`.
    pub src_start: &'a [u32],
    /// Input-region rows grouped by chunk.
    pub src_rows: &'a [u32],
    /// CSR start of every (chunk, offset) in `pair_src` / `pair_dst`, `[chunks * K + 1]`.
    pub pair_start: &'a [u32],
    /// Chunk-local region index of every pair.
    pub pair_src: &'a [u32],
    /// Chunk-local destination index of every pair.
    pub pair_dst: &'a [u32],
}

const NONE: u32 = u32::MAX;

/// Runs of equal `code >> shift` in `keyed[lo..hi]`, appended as `(start, end, level)`.
fn runs(keyed: &[(u64, u32)], lo: usize, hi: usize, shift: u32, level: u32, out: &mut Vec<(usize, usize, u32)>) {
    let mut s = lo;
    while s < hi {
        let p = keyed[s].0 >> shift;
        let mut e = s + 1;
        while e < hi && keyed[e].0 >> shift == p {
            e += 1;
        }
        out.push((s, e, level));
        s = e;
    }
}

/// One chunk's region and local pairs, before concatenation.
struct ChunkParts {
    src: Vec<u32>,
    pair_src: Vec<u32>,
    pair_dst: Vec<u32>,
    counts: Vec<u32>,
    rows: usize,
}

/// Per-thread scratch for plan building: a generation mark and a local index per source row
/// (so that no clearing is needed between chunks).
struct Marks {
    mark: Vec<u32>,
    local: Vec<u32>,
    generation: u32,
}

thread_local! {
    /// Planning scratch of this thread, grown to the largest source set seen: a fresh pair of
    /// `n_src` arrays per rayon job costs more (zeroing, page faults) than planning itself.
    static MARKS: std::cell::RefCell<Marks> = const {
        std::cell::RefCell::new(Marks { mark: Vec::new(), local: Vec::new(), generation: 0 })
    };
}

/// Runs `f` with this thread's [`Marks`], sized for `n_src` rows.
fn with_marks<R>(n_src: usize, f: impl FnOnce(&mut Marks) -> R) -> R {
    MARKS.with(|m| {
        let mut m = m.borrow_mut();
        if m.mark.len() < n_src {
            // New entries are 0, a generation never handed out after a wrap-around reset.
            m.mark.resize(n_src, 0);
            m.local.resize(n_src, 0);
        }
        f(&mut m)
    })
}

impl Marks {
    fn next(&mut self) -> u32 {
        self.generation = self.generation.wrapping_add(1);
        if self.generation == 0 {
            self.mark.fill(0);
            self.generation = 1;
        }
        self.generation
    }

    /// Distinct source rows read by the destinations whose table rows are `tab`.
    fn region_size(&mut self, tab: &[u32]) -> usize {
        let g = self.next();
        let mut count = 0;
        for &s in tab {
            if s != NONE && self.mark[s as usize] != g {
                self.mark[s as usize] = g;
                count += 1;
            }
        }
        count
    }

    /// The region (identity-centre rows first, then first appearance) and local pairs of the
    /// destinations whose table rows (`kv` entries each) are `tab`.
    ///
    /// Two passes over the rows: the first builds the region and counts pairs per offset, the
    /// second writes every pair straight to its slot, so pairs of an offset come out in
    /// destination order with no per-offset rescans.
    fn chunk_parts(&mut self, tab: &[u32], kv: usize, centre: Option<usize>) -> ChunkParts {
        let g = self.next();
        let m = tab.len() / kv.max(1);
        let mut src = Vec::with_capacity(m * 2);
        let (mark, local) = (&mut self.mark, &mut self.local);
        if let Some(c) = centre {
            for row in tab.chunks_exact(kv) {
                let s = row[c];
                if mark[s as usize] != g {
                    mark[s as usize] = g;
                    local[s as usize] = src.len() as u32;
                    src.push(s);
                }
            }
        }
        let mut counts = vec![0u32; kv];
        for row in tab.chunks_exact(kv) {
            for (count, &s) in counts.iter_mut().zip(row) {
                if s != NONE {
                    *count += 1;
                    if mark[s as usize] != g {
                        mark[s as usize] = g;
                        local[s as usize] = src.len() as u32;
                        src.push(s);
                    }
                }
            }
        }
        let mut next: Vec<usize> = Vec::with_capacity(kv);
        let mut total = 0;
        for &count in &counts {
            next.push(total);
            total += count as usize;
        }
        let mut pair_src = vec![0u32; total];
        let mut pair_dst = vec![0u32; total];
        for (j, row) in tab.chunks_exact(kv).enumerate() {
            for (slot, &s) in next.iter_mut().zip(row) {
                if s != NONE {
                    pair_src[*slot] = local[s as usize];
                    pair_dst[*slot] = j as u32;
                    *slot += 1;
                }
            }
        }
        ChunkParts { src, pair_src, pair_dst, counts, rows: m }
    }
}

impl ChunkPlan {
    /// Chunks the outputs of `map` (whose coordinates are `dst_coords`). The coordinates only
    /// shape the chunks: wrong ones cost speed, never correctness, since every output row still
    /// lands in exactly one chunk with all of its pairs.
    ///
    /// # Errors
    /// [`SparseError::CoordCount`] when `dst_coords` does not match `map.n_out()`,
    /// [`SparseError::InvalidArgument`] for a chunk side that is not a power of two in
    /// `1..=2^20`, zero levels or budget, range errors on coordinates.
    pub fn new(map: &KernelMap, dst_coords: &[Coord], config: &ChunkConfig) -> Result<Self> {
        if dst_coords.len() != map.n_out() {
            return Err(SparseError::CoordCount { what: "dst_coords", got: dst_coords.len(), expected: map.n_out() });
        }
        let side = config.chunk_side;
        if !side.is_power_of_two() || side > 1 << 20 || config.levels == 0 || config.max_region_rows == 0 {
            return Err(SparseError::InvalidArgument(format!("bad chunk configuration {config:?}")));
        }
        let kv = map.kernel_volume();
        // Neighbour table: the source row of every (destination, offset), or NONE.
        let mut nbr = vec![NONE; map.n_out() * kv];
        for k in 0..kv {
            let (ins, outs) = map.pairs(k);
            for (&i, &o) in ins.iter().zip(outs) {
                nbr[o as usize * kv + k] = i;
            }
        }
        Self::from_rows(
            |d, row| row.copy_from_slice(&nbr[d * kv..(d + 1) * kv]),
            kv,
            map.centre(),
            map.n_in(),
            dst_coords,
            config,
        )
    }

    /// [`Self::new`] from a whole `[n_dst, kv]` neighbour table (the source row of every
    /// destination and offset, or `u32::MAX`), for engines that build the table elsewhere
    /// (the GPU engine builds it with a hash table on the device). `centre` names an identity
    /// offset (source row = destination row) whose rows the regions list first.
    ///
    /// # Errors
    /// [`SparseError::InvalidArgument`] for a table of the wrong size or with a source row
    /// out of range, and the errors of [`Self::new`].
    pub fn from_table(
        table: &[u32],
        kv: usize,
        centre: Option<usize>,
        n_src: usize,
        dst_coords: &[Coord],
        config: &ChunkConfig,
    ) -> Result<Self> {
        if kv == 0 || table.len() != dst_coords.len() * kv || centre.is_some_and(|c| c >= kv) {
            return Err(SparseError::InvalidArgument(format!(
                "neighbour table of {} entries for {} destinations of {kv} offsets (centre {centre:?})",
                table.len(),
                dst_coords.len()
            )));
        }
        if let Some(bad) = table.iter().find(|&&s| s != NONE && s as usize >= n_src) {
            return Err(SparseError::InvalidArgument(format!("neighbour table names source row {bad} of {n_src}")));
        }
        if let Some(c) = centre {
            if table.chunks_exact(kv).enumerate().any(|(d, row)| row[c] as usize != d) {
                return Err(SparseError::InvalidArgument("centre offset of the table is not the identity".into()));
            }
        }
        Self::from_rows(
            |d, row| row.copy_from_slice(&table[d * kv..(d + 1) * kv]),
            kv,
            centre,
            n_src,
            dst_coords,
            config,
        )
    }

    /// [`Self::new`] from the rows of the map's `[n_dst, kv]` neighbour table (source row of
    /// every destination and offset, or `u32::MAX`): `fill(d, row)` writes row `d`. Rows are
    /// asked for chunk by chunk, so the whole table never needs to exist.
    pub(crate) fn from_rows(
        fill: impl Fn(usize, &mut [u32]) + Sync,
        kv: usize,
        centre: Option<usize>,
        n_src: usize,
        dst_coords: &[Coord],
        config: &ChunkConfig,
    ) -> Result<Self> {
        let side = config.chunk_side;
        if !side.is_power_of_two() || side > 1 << 20 || config.levels == 0 || config.max_region_rows == 0 {
            return Err(SparseError::InvalidArgument(format!("bad chunk configuration {config:?}")));
        }
        let n_dst = dst_coords.len();
        for (row, &c) in dst_coords.iter().enumerate() {
            pack_key(c, row)?;
        }
        let mut keyed: Vec<(u64, u32)> =
            dst_coords.par_iter().enumerate().map(|(r, &c)| (morton_unchecked(c), r as u32)).collect();
        if !keyed.windows(2).all(|w| w[0] <= w[1]) {
            keyed.par_sort_unstable();
        }

        // Adaptive splitting over runs of equal Morton prefix, top-level cubes in parallel.
        let top_shift = 3 * side.trailing_zeros();
        let mut top = Vec::new();
        runs(&keyed, 0, n_dst, top_shift, 0, &mut top);
        // Per top-level cube: its table rows once, then the adaptive splitting and every
        // final chunk's region and local pairs from them (sub-chunks are sub-ranges).
        let nested: Vec<Vec<((usize, usize), ChunkParts)>> = top
            .par_iter()
            .map(|&(lo, hi, _)| {
                let mut tab = vec![NONE; (hi - lo) * kv];
                for (row, &(_, d)) in tab.chunks_exact_mut(kv.max(1)).zip(&keyed[lo..hi]) {
                    fill(d as usize, row);
                }
                let rows = |a: usize, b: usize| &tab[(a - lo) * kv..(b - lo) * kv];
                with_marks(n_src, |marks| {
                    let mut out = Vec::new();
                    let mut stack = vec![(lo, hi, 0u32)];
                    while let Some((a, b, level)) = stack.pop() {
                        let last = level + 1 >= config.levels || top_shift < 3 * (level + 1);
                        if last || marks.region_size(rows(a, b)) <= config.max_region_rows {
                            out.push(((a, b), marks.chunk_parts(rows(a, b), kv, centre)));
                        } else {
                            let mut sub = Vec::new();
                            runs(&keyed, a, b, top_shift - 3 * (level + 1), level + 1, &mut sub);
                            stack.extend(sub.into_iter().rev());
                        }
                    }
                    out
                })
            })
            .collect();
        let (chunks, parts): (Vec<(usize, usize)>, Vec<ChunkParts>) = nested.into_iter().flatten().unzip();
        let num_pairs: usize = parts.iter().map(|p| p.pair_src.len()).sum();
        let total_src: usize = parts.iter().map(|p| p.src.len()).sum();
        let mut plan = Self {
            kernel_volume: kv,
            centre,
            n_src,
            n_dst,
            dst_start: Vec::with_capacity(chunks.len() + 1),
            dst_rows: keyed.iter().map(|&(_, d)| d).collect(),
            src_start: Vec::with_capacity(chunks.len() + 1),
            src_rows: Vec::with_capacity(total_src),
            pair_start: Vec::with_capacity(chunks.len() * kv + 1),
            pair_src: Vec::with_capacity(num_pairs),
            pair_dst: Vec::with_capacity(num_pairs),
            iota: Vec::new(),
        };
        let too_many = |n: usize| u32::try_from(n).map_err(|_| SparseError::TooManyRows(n));
        plan.dst_start.push(0);
        plan.src_start.push(0);
        plan.pair_start.push(0);
        let mut max_rows = 0;
        for (&(_, hi), part) in chunks.iter().zip(&parts) {
            // Chunks are consecutive runs of the sorted list, so `dst_rows` is already grouped.
            plan.dst_start.push(hi as u32);
            plan.src_rows.extend_from_slice(&part.src);
            plan.src_start.push(too_many(plan.src_rows.len())?);
            let mut q = 0;
            for &count in &part.counts {
                q += count as usize;
                plan.pair_start.push(too_many(plan.pair_src.len() + q)?);
            }
            plan.pair_src.extend_from_slice(&part.pair_src);
            plan.pair_dst.extend_from_slice(&part.pair_dst);
            max_rows = max_rows.max(part.src.len()).max(part.rows);
        }
        plan.iota = (0..max_rows as u32).collect();
        Ok(plan)
    }

    /// The plan of the identity map of `n` rows: chunks of [`IDENTITY_ROWS`] consecutive rows.
    pub(crate) fn identity(n: usize) -> Self {
        let chunks = n.div_ceil(IDENTITY_ROWS);
        let bounds: Vec<u32> = (0..=chunks).map(|c| (c * IDENTITY_ROWS).min(n) as u32).collect();
        let pair_local: Vec<u32> = (0..n).map(|r| (r % IDENTITY_ROWS) as u32).collect();
        Self {
            kernel_volume: 1,
            centre: Some(0),
            n_src: n,
            n_dst: n,
            dst_start: bounds.clone(),
            dst_rows: (0..n as u32).collect(),
            src_start: bounds.clone(),
            src_rows: (0..n as u32).collect(),
            pair_start: bounds,
            pair_src: pair_local.clone(),
            pair_dst: pair_local,
            iota: (0..IDENTITY_ROWS.min(n) as u32).collect(),
        }
    }

    /// The plan's plain index arrays (layout in the type's documentation), for backends that
    /// upload them as they are.
    pub fn arrays(&self) -> ChunkPlanArrays<'_> {
        ChunkPlanArrays {
            dst_start: &self.dst_start,
            dst_rows: &self.dst_rows,
            src_start: &self.src_start,
            src_rows: &self.src_rows,
            pair_start: &self.pair_start,
            pair_src: &self.pair_src,
            pair_dst: &self.pair_dst,
        }
    }

    /// The identity offset whose pairs are `(j, j)` for every chunk-local row `j` (the first
    /// region rows are the chunk's own rows), if the map has one.
    pub fn centre(&self) -> Option<usize> {
        self.centre
    }

    /// Pairs over all chunks and offsets (those of the kernel map).
    pub fn num_pairs(&self) -> usize {
        self.pair_src.len()
    }

    /// The `[n_dst, K]` neighbour table of the planned map (source row of every destination
    /// and offset, or `u32::MAX`), rebuilt from the chunk-local pairs.
    pub fn neighbour_table(&self) -> Vec<u32> {
        self.table()
    }

    /// The `[n_dst, kv]` neighbour table the plan was made from.
    pub(crate) fn table(&self) -> Vec<u32> {
        let kv = self.kernel_volume;
        let mut table = vec![NONE; self.n_dst * kv];
        for c in 0..self.num_chunks() {
            let (srcs, dsts) = (self.chunk_src(c), self.chunk_dst(c));
            for k in 0..kv {
                let (ps, pd) = self.chunk_pairs(c, k);
                for (&s, &d) in ps.iter().zip(pd) {
                    table[dsts[d as usize] as usize * kv + k] = srcs[s as usize];
                }
            }
        }
        table
    }

    /// Number of chunks.
    pub fn num_chunks(&self) -> usize {
        self.dst_start.len() - 1
    }

    /// Offsets of the kernel map.
    pub fn kernel_volume(&self) -> usize {
        self.kernel_volume
    }

    /// Destination rows of chunk `c` (Z-order).
    pub fn chunk_dst(&self, c: usize) -> &[u32] {
        &self.dst_rows[self.dst_start[c] as usize..self.dst_start[c + 1] as usize]
    }

    /// Input region (source rows) of chunk `c`.
    pub fn chunk_src(&self, c: usize) -> &[u32] {
        &self.src_rows[self.src_start[c] as usize..self.src_start[c + 1] as usize]
    }

    /// Chunk-local `(region index, destination index)` pairs of chunk `c`, offset `k`.
    pub fn chunk_pairs(&self, c: usize, k: usize) -> (&[u32], &[u32]) {
        let q = c * self.kernel_volume + k;
        let r = self.pair_start[q] as usize..self.pair_start[q + 1] as usize;
        (&self.pair_src[r.clone()], &self.pair_dst[r])
    }

    /// Mean region rows per destination row (1.0 would be a perfect halo-free tiling).
    pub fn halo_ratio(&self) -> f64 {
        if self.dst_rows.is_empty() {
            1.0
        } else {
            self.src_rows.len() as f64 / self.dst_rows.len() as f64
        }
    }

    /// `dst[d] = sum over offsets of src[s] . w_k` for every chunk. `w`: `[kv, c_src, c_dst]`.
    ///
    /// With `pre = Some((scale, shift))` the sources are read as `max(0, src * scale + shift)`
    /// per channel (a batch norm and ReLU folded into the gather, computed exactly as a
    /// separate pass would); with `accumulate` the result is added to `dst` instead of
    /// overwriting it.
    #[allow(clippy::too_many_arguments)]
    fn apply(
        &self,
        src: &[f32],
        c_src: usize,
        w: &[f32],
        c_dst: usize,
        dst: &mut [f32],
        pre: Option<(&[f32], &[f32])>,
        accumulate: bool,
    ) {
        let kv = self.kernel_volume;
        let rows = DisjointRows::new(dst);
        (0..self.num_chunks()).into_par_iter().for_each_init(
            || (Vec::new(), Vec::new()),
            |(xbuf, ybuf): &mut (Vec<f32>, Vec<f32>), c| {
                let srcs = self.chunk_src(c);
                let dsts = self.chunk_dst(c);
                let m = dsts.len();
                xbuf.clear();
                match pre {
                    None => {
                        for &s in srcs {
                            xbuf.extend_from_slice(&src[s as usize * c_src..(s as usize + 1) * c_src]);
                        }
                    }
                    Some((scale, shift)) => {
                        for &s in srcs {
                            let row = &src[s as usize * c_src..(s as usize + 1) * c_src];
                            xbuf.extend(row.iter().zip(scale).zip(shift).map(|((x, s), b)| (x * s + b).max(0.0)));
                        }
                    }
                }
                // Z-ordered tensors (as `voxelize` makes them) give chunks whose rows are one
                // contiguous run: compute straight into the output, no copy-out.
                let contiguous = dsts.windows(2).all(|p| p[1] == p[0] + 1);
                let y: &mut [f32] = if contiguous && m > 0 {
                    // SAFETY: every destination row belongs to exactly one chunk.
                    unsafe { rows.slice(dsts[0] as usize * c_dst, m * c_dst) }
                } else {
                    ybuf.clear();
                    if accumulate {
                        for &d in dsts {
                            // SAFETY: every destination row belongs to exactly one chunk.
                            ybuf.extend_from_slice(unsafe { rows.slice(d as usize * c_dst, c_dst) });
                        }
                    } else {
                        ybuf.resize(m * c_dst, 0.0);
                    }
                    ybuf
                };
                let wk = |k: usize| &w[k * c_src * c_dst..(k + 1) * c_src * c_dst];
                match self.centre {
                    Some(ct) => {
                        // The region starts with the chunk's own rows: a dense GEMM, no
                        // indirection, storing (so `y` needs no clearing).
                        let id = &self.iota[..m];
                        gemm_rows(xbuf, c_src, id, wk(ct), c_src, c_dst, y, c_dst, id, accumulate);
                    }
                    None if accumulate => {}
                    None => y.fill(0.0),
                }
                for k in 0..kv {
                    if Some(k) == self.centre {
                        continue;
                    }
                    let (ps, pd) = self.chunk_pairs(c, k);
                    gemm_rows(xbuf, c_src, ps, wk(k), c_src, c_dst, y, c_dst, pd, true);
                }
                if !contiguous {
                    for (j, &d) in dsts.iter().enumerate() {
                        // SAFETY: every destination row belongs to exactly one chunk.
                        let out = unsafe { rows.slice(d as usize * c_dst, c_dst) };
                        out.copy_from_slice(&ybuf[j * c_dst..(j + 1) * c_dst]);
                    }
                }
            },
        );
    }

    /// `dW_k = sum over pairs of src[s]^T dst[d]`, `[kv, c_src, c_dst]`, deterministic.
    /// `partials` is scratch (reused between calls to spare the page faults of a fresh
    /// multi-megabyte buffer).
    fn weight_grad(
        &self,
        src: &[f32],
        c_src: usize,
        dst: &[f32],
        c_dst: usize,
        dw: &mut [f32],
        partials: &mut Vec<f32>,
    ) {
        let kv = self.kernel_volume;
        let size = kv * c_src * c_dst;
        let n = self.num_chunks();
        let groups = n.min(WEIGHT_GROUPS);
        dw.fill(0.0);
        if size == 0 || groups == 0 {
            return;
        }
        partials.resize(groups * size, 0.0);
        // Group boundaries balance the pair counts (the work), from the plan alone, so that
        // they do not depend on the thread count.
        let total = *self.pair_start.last().unwrap_or(&0) as usize;
        let mut bounds = vec![0usize; groups + 1];
        let mut c = 0;
        for (g, b) in bounds.iter_mut().enumerate().skip(1) {
            let target = total * g / groups;
            while c < n && (self.pair_start[c * kv] as usize) < target {
                c += 1;
            }
            *b = c;
        }
        bounds[groups] = n;
        partials.par_chunks_mut(size).enumerate().for_each(|(g, acc)| {
            acc.fill(0.0);
            let (mut xbuf, mut ybuf) = (Vec::new(), Vec::new());
            for c in bounds[g]..bounds[g + 1] {
                let srcs = self.chunk_src(c);
                let dsts = self.chunk_dst(c);
                xbuf.clear();
                for &s in srcs {
                    xbuf.extend_from_slice(&src[s as usize * c_src..(s as usize + 1) * c_src]);
                }
                let y: &[f32] = if dsts.windows(2).all(|p| p[1] == p[0] + 1) && !dsts.is_empty() {
                    let d0 = dsts[0] as usize;
                    &dst[d0 * c_dst..(d0 + dsts.len()) * c_dst]
                } else {
                    ybuf.clear();
                    for &d in dsts {
                        ybuf.extend_from_slice(&dst[d as usize * c_dst..(d as usize + 1) * c_dst]);
                    }
                    &ybuf
                };
                for k in 0..kv {
                    let acck = &mut acc[k * c_src * c_dst..(k + 1) * c_src * c_dst];
                    if Some(k) == self.centre {
                        let id = &self.iota[..dsts.len()];
                        gemm_tn_rows(&xbuf, c_src, id, c_src, y, c_dst, id, c_dst, acck);
                    } else {
                        let (ps, pd) = self.chunk_pairs(c, k);
                        gemm_tn_rows(&xbuf, c_src, ps, c_src, y, c_dst, pd, c_dst, acck);
                    }
                }
            }
        });
        // Every element sums the groups in index order, whichever thread does the slice.
        let partials: &[f32] = partials;
        dw.par_chunks_mut(4096).enumerate().for_each(|(i, d)| {
            for p in partials.chunks(size) {
                for (d, &v) in d.iter_mut().zip(&p[i * 4096..]) {
                    *d += v;
                }
            }
        });
    }
}

/// Rows per chunk of an identity (pointwise) plan: 64 KiB of 64-channel rows.
const IDENTITY_ROWS: usize = 256;

/// Fixed number of partial weight-gradient sums (independent of the thread count).
const WEIGHT_GROUPS: usize = 16;

/// A convolution layer geometry ready for the chunked kernels: the kernel map and its chunk
/// plans. Build it once per level (or per strided transition) and call it for every layer.
///
/// The chunked kernels only read the plans. A layer made by [`Self::submanifold`] therefore
/// builds its kernel map (the pair lists, which the rulebook kernels and exports read) on the
/// first call of [`Self::map`], from the plan, and a pure chunked forward never pays for it.
#[derive(Debug)]
pub struct ChunkedConv {
    map: OnceLock<KernelMap>,
    kind: MapKind,
    n_in: usize,
    n_out: usize,
    forward: ChunkPlan,
    backward: Option<ChunkPlan>,
    /// Scratch of the weight gradient's partial sums, kept between calls.
    workspace: Mutex<Vec<f32>>,
}

impl Clone for ChunkedConv {
    fn clone(&self) -> Self {
        Self {
            map: self.map.clone(),
            kind: self.kind,
            n_in: self.n_in,
            n_out: self.n_out,
            forward: self.forward.clone(),
            backward: self.backward.clone(),
            workspace: Mutex::new(Vec::new()),
        }
    }
}

impl ChunkedConv {
    /// Plans `map` whose input and output voxels are `in_coords` and `out_coords`.
    ///
    /// # Errors
    /// Coordinate counts not matching the map, bad configuration, range errors.
    pub fn new(map: KernelMap, in_coords: &[Coord], out_coords: &[Coord], config: &ChunkConfig) -> Result<Self> {
        if in_coords.len() != map.n_in() {
            return Err(SparseError::CoordCount { what: "in_coords", got: in_coords.len(), expected: map.n_in() });
        }
        let forward = ChunkPlan::new(&map, out_coords, config)?;
        let backward = match map.kind() {
            MapKind::Submanifold { .. } => None,
            _ => Some(ChunkPlan::new(&map.transposed(), in_coords, config)?),
        };
        Ok(Self::from_parts(map, forward, backward))
    }

    /// The submanifold layer of `coords` with an odd `kernel_size` (3 in the network): its
    /// kernel map and chunk plan from one neighbour table, the same map and plan as
    /// `ChunkedConv::new(KernelMap::submanifold(coords, kernel_size)?, coords, coords, config)`
    /// with half the work.
    ///
    /// # Errors
    /// As [`KernelMap::submanifold`] and [`ChunkPlan::new`].
    pub fn submanifold(coords: &[Coord], kernel_size: usize, config: &ChunkConfig) -> Result<Self> {
        let index = KernelMap::submanifold_index(coords, kernel_size)?;
        let kv = kernel_size.pow(3);
        let n = coords.len();
        let forward = if kernel_size == 1 {
            ChunkPlan::from_rows(|d, row| row[0] = d as u32, 1, Some(0), n, coords, config)?
        } else {
            let finder = NeighbourFinder::new(&index, coords, kernel_size);
            ChunkPlan::from_rows(|d, row| finder.fill(d, row), kv, Some(kv / 2), n, coords, config)?
        };
        let layer = Self {
            map: OnceLock::new(),
            kind: MapKind::Submanifold { kernel_size },
            n_in: n,
            n_out: n,
            forward,
            backward: None,
            workspace: Mutex::new(Vec::new()),
        };
        Ok(layer)
    }

    /// The `[n_out, K]` neighbour table of the layer's map: entry `(u, k)` is the input row
    /// paired with output `u` at offset `k`, or `u32::MAX` (for submanifold maps, the row of
    /// `coords[u] + offset(k)` in the offset numbering of [`crate::kernel_map`]).
    pub fn neighbour_table(&self) -> Vec<u32> {
        self.forward.table()
    }

    /// The pointwise (1x1x1) layer of `n` rows: a linear map applied to every row (the
    /// identity kernel map, chunks of consecutive rows). Needs no coordinates, so it costs
    /// nothing to build; the caller vouches that the rows are distinct voxels.
    ///
    /// # Errors
    /// [`SparseError::TooManyRows`] beyond the `u32` row range.
    pub fn pointwise(n: usize) -> Result<Self> {
        let (map, forward) = (KernelMap::identity(n)?, ChunkPlan::identity(n));
        Ok(Self::from_parts(map, forward, None))
    }

    fn from_parts(map: KernelMap, forward: ChunkPlan, backward: Option<ChunkPlan>) -> Self {
        Self {
            kind: map.kind(),
            n_in: map.n_in(),
            n_out: map.n_out(),
            map: OnceLock::from(map),
            forward,
            backward,
            workspace: Mutex::new(Vec::new()),
        }
    }

    /// The transposed layer of a strided one: the `Up` convolution from this `Down` layer's
    /// outputs back to its inputs (or the reverse), sharing both chunk plans with no new
    /// planning. `None` for submanifold layers, whose transpose is themselves.
    pub fn transposed(&self) -> Option<Self> {
        let backward = self.backward.clone()?;
        Some(Self::from_parts(self.map().transposed(), backward, Some(self.forward.clone())))
    }

    /// The kernel map (built from the plan on the first call for layers made by
    /// [`Self::submanifold`]).
    pub fn map(&self) -> &KernelMap {
        self.map.get_or_init(|| {
            KernelMap::from_table(self.kind, self.n_in, &self.forward.table(), self.forward.kernel_volume)
        })
    }

    /// What the layer connects (without building the kernel map, unlike `map().kind()`).
    pub fn kind(&self) -> MapKind {
        self.kind
    }

    /// Number of (input, output) pairs over all offsets.
    pub fn num_pairs(&self) -> usize {
        self.forward.num_pairs()
    }

    /// Rows of the input set.
    pub fn n_in(&self) -> usize {
        self.n_in
    }

    /// Rows of the output set.
    pub fn n_out(&self) -> usize {
        self.n_out
    }

    /// The plan over the outputs (forward pass and weight gradient).
    pub fn forward_plan(&self) -> &ChunkPlan {
        &self.forward
    }

    /// The plan over the inputs (input gradient); `None` for submanifold maps, which reuse
    /// the forward plan with mirrored offsets.
    pub fn backward_plan(&self) -> Option<&ChunkPlan> {
        self.backward.as_ref()
    }

    /// Forward pass.
    ///
    /// # Shapes
    /// `x`: `[n_in, c_in]`; `w`: `[K^3, c_in, c_out]`; result `[n_out, c_out]`.
    ///
    /// # Errors
    /// [`SparseError::FeatureShape`] / [`SparseError::WeightShape`] on mismatched buffers.
    pub fn forward(&self, x: &[f32], c_in: usize, w: &[f32], c_out: usize) -> Result<Vec<f32>> {
        let mut y = vec![0f32; self.n_out * c_out];
        self.forward_into(x, c_in, w, c_out, &mut y)?;
        Ok(y)
    }

    /// [`Self::forward`] into a caller's buffer (overwritten; no clearing needed), so that a
    /// training loop does not pay for a fresh allocation and its page faults every pass.
    ///
    /// # Shapes
    /// `y`: `[n_out, c_out]`.
    ///
    /// # Errors
    /// As [`Self::forward`], and for a `y` of the wrong size.
    pub fn forward_into(&self, x: &[f32], c_in: usize, w: &[f32], c_out: usize, y: &mut [f32]) -> Result<()> {
        check_rows("x", x, self.n_in, c_in)?;
        check_weights(w, self.forward.kernel_volume, c_in, c_out)?;
        check_rows("y", y, self.n_out, c_out)?;
        self.forward.apply(x, c_in, w, c_out, y, None, false);
        Ok(())
    }

    /// [`Self::forward_into`] with a batch norm and ReLU folded into the read of `x` and,
    /// with `accumulate`, the result added to `y` (a residual connection) instead of
    /// overwriting it: `y (+)= conv(max(0, x * scale + shift), w)`, with per-channel
    /// `scale`, `shift`. Saves the separate passes over the activations; the normalised
    /// values are bit for bit those of a separate pass, and without `accumulate` the output
    /// is that of [`Self::forward_into`] on them.
    ///
    /// # Shapes
    /// `x`: `[n_in, c_in]`; `scale`, `shift`: `[c_in]`; `w`: `[K^3, c_in, c_out]`;
    /// `y`: `[n_out, c_out]`.
    ///
    /// # Errors
    /// As [`Self::forward_into`], and for `scale` / `shift` not of length `c_in`.
    #[allow(clippy::too_many_arguments)]
    pub fn forward_bn_relu_into(
        &self,
        x: &[f32],
        c_in: usize,
        scale: &[f32],
        shift: &[f32],
        w: &[f32],
        c_out: usize,
        y: &mut [f32],
        accumulate: bool,
    ) -> Result<()> {
        check_rows("x", x, self.n_in, c_in)?;
        check_weights(w, self.forward.kernel_volume, c_in, c_out)?;
        check_rows("y", y, self.n_out, c_out)?;
        check_rows("scale", scale, 1, c_in)?;
        check_rows("shift", shift, 1, c_in)?;
        self.forward.apply(x, c_in, w, c_out, y, Some((scale, shift)), accumulate);
        Ok(())
    }

    /// Input gradient.
    ///
    /// # Shapes
    /// `dy`: `[n_out, c_out]`; `w`: `[K^3, c_in, c_out]`; result `[n_in, c_in]`.
    ///
    /// # Errors
    /// As [`Self::forward`].
    pub fn backward_input(&self, dy: &[f32], c_out: usize, w: &[f32], c_in: usize) -> Result<Vec<f32>> {
        let mut dx = vec![0f32; self.n_in * c_in];
        self.backward_input_into(dy, c_out, w, c_in, &mut dx)?;
        Ok(dx)
    }

    /// [`Self::backward_input`] into a caller's buffer (overwritten).
    ///
    /// # Shapes
    /// `dx`: `[n_in, c_in]`.
    ///
    /// # Errors
    /// As [`Self::forward`], and for a `dx` of the wrong size.
    pub fn backward_input_into(&self, dy: &[f32], c_out: usize, w: &[f32], c_in: usize, dx: &mut [f32]) -> Result<()> {
        check_rows("dy", dy, self.n_out, c_out)?;
        let kv = self.forward.kernel_volume;
        check_weights(w, kv, c_in, c_out)?;
        check_rows("dx", dx, self.n_in, c_in)?;
        match &self.backward {
            Some(plan) => {
                let wt = transpose_weights(w, kv, c_in, c_out, |k| k);
                plan.apply(dy, c_out, &wt, c_in, dx, None, false);
            }
            None => {
                let wt = transpose_weights(w, kv, c_in, c_out, |k| kv - 1 - k);
                self.forward.apply(dy, c_out, &wt, c_in, dx, None, false);
            }
        }
        Ok(())
    }

    /// Weight gradient.
    ///
    /// # Shapes
    /// `x`: `[n_in, c_in]`; `dy`: `[n_out, c_out]`; result `[K^3, c_in, c_out]`.
    ///
    /// # Errors
    /// As [`Self::forward`].
    pub fn backward_weight(&self, x: &[f32], c_in: usize, dy: &[f32], c_out: usize) -> Result<Vec<f32>> {
        let mut dw = vec![0f32; self.forward.kernel_volume * c_in * c_out];
        self.backward_weight_into(x, c_in, dy, c_out, &mut dw)?;
        Ok(dw)
    }

    /// [`Self::backward_weight`] into a caller's buffer (overwritten).
    ///
    /// # Shapes
    /// `dw`: `[K^3, c_in, c_out]`.
    ///
    /// # Errors
    /// As [`Self::forward`], and for a `dw` of the wrong size.
    pub fn backward_weight_into(&self, x: &[f32], c_in: usize, dy: &[f32], c_out: usize, dw: &mut [f32]) -> Result<()> {
        check_rows("x", x, self.n_in, c_in)?;
        check_rows("dy", dy, self.n_out, c_out)?;
        check_weights(dw, self.forward.kernel_volume, c_in, c_out)?;
        // A concurrent call on the same layer gets a scratch buffer of its own.
        match self.workspace.try_lock() {
            Ok(mut scratch) => self.forward.weight_grad(x, c_in, dy, c_out, dw, &mut scratch),
            Err(_) => self.forward.weight_grad(x, c_in, dy, c_out, dw, &mut Vec::new()),
        }
        Ok(())
    }
}
