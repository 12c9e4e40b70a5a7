//! Layer geometry on the device: the kernel map and chunk plans of one layer, uploaded once
//! and reused by every call (the network runs every layer of a level on one geometry).
//!
//! Submanifold maps are built on the device: the voxels go into a hash table (one
//! compare-exchange per voxel) and one look-up per (voxel, offset) writes the `[n, K^3]`
//! neighbour table. The table comes back to the host, where `semrecon_sparse::ChunkPlan`
//! cuts the outputs into adaptive chunks (sides C, C/2, C/4) and the per-offset pair lists of
//! the rulebook kernels are read off it; both go back up as plain index arrays. Strided maps
//! (down and transposed) are built on the host by `semrecon_sparse::KernelMap`, which they
//! share with the CPU engine. Planning on the device is left for later (docs/gpu.md).

use rayon::prelude::*;
use semrecon_sparse::chunked::ChunkPlan;
use semrecon_sparse::key::pack_key;
use semrecon_sparse::{ChunkConfig, ChunkedConv, ConvAlgorithm, Coord, KernelMap, MapKind, SparseError};

use crate::context::{GpuContext, WORKGROUP};
use crate::error::{GpuError, Result};

/// Marks a missing neighbour in tables.
pub(crate) const EMPTY: u32 = u32::MAX;

/// A chunk plan on the device, as the chunked kernel reads it: the destinations in plan
/// order (`[n_dst]`, from word 0) and then their source rows at every offset (`[n_dst, kv]`,
/// or EMPTY; from word [`Self::table_offset`]), in one buffer.
#[derive(Debug)]
pub(crate) struct DevicePlan {
    pub buffer: wgpu::Buffer,
    /// Destinations (rows of the plan's order).
    pub n_dst: u32,
}

impl DevicePlan {
    /// The word where the neighbour table starts (after the destination rows).
    pub(crate) fn table_offset(&self) -> u32 {
        self.n_dst
    }

    /// Uploads `plan`'s destinations and its neighbour table in plan order (chunks in
    /// parallel: on the host this is the per-call cost of a new geometry).
    fn upload(ctx: &GpuContext, plan: &ChunkPlan) -> Result<Self> {
        let a = plan.arrays();
        let kv = plan.kernel_volume();
        let n_dst = a.dst_rows.len();
        let mut table = vec![EMPTY; n_dst * kv];
        // Each chunk owns the table rows of its destinations: disjoint slices.
        let mut parts = Vec::with_capacity(plan.num_chunks());
        let mut rest = table.as_mut_slice();
        for c in 0..plan.num_chunks() {
            let rows = (a.dst_start[c + 1] - a.dst_start[c]) as usize;
            let (part, tail) = rest.split_at_mut(rows * kv);
            parts.push((c, part));
            rest = tail;
        }
        parts.into_par_iter().for_each(|(c, part)| {
            let s0 = a.src_start[c] as usize;
            for k in 0..kv {
                let (ps, pd) = plan.chunk_pairs(c, k);
                for (&s, &d) in ps.iter().zip(pd) {
                    part[d as usize * kv + k] = a.src_rows[s0 + s as usize];
                }
            }
        });
        Self::from_parts(ctx, a.dst_rows.iter().copied(), &table)
    }

    /// The plan of a neighbour table taken as it is: destinations in row order (the table's
    /// rows are Z-ordered by whoever built them), no chunks.
    fn upload_table(ctx: &GpuContext, table: &[u32], n_dst: usize) -> Result<Self> {
        let n = u32::try_from(n_dst).map_err(|_| SparseError::TooManyRows(n_dst))?;
        Self::from_parts(ctx, 0..n, table)
    }

    /// One buffer of the destination rows then the table.
    fn from_parts(ctx: &GpuContext, dst_rows: impl ExactSizeIterator<Item = u32>, table: &[u32]) -> Result<Self> {
        let n_dst = dst_rows.len();
        let mut words = Vec::with_capacity(n_dst + table.len());
        words.extend(dst_rows);
        words.extend_from_slice(table);
        word_offset(words.len())?;
        let n_dst = u32::try_from(n_dst).map_err(|_| SparseError::TooManyRows(n_dst))?;
        Ok(Self { buffer: ctx.upload("chunk plan", &words)?, n_dst })
    }
}

/// The rulebook kernels' per-offset pair lists on the device.
#[derive(Debug)]
pub(crate) struct DevicePairs {
    /// `[in rows | out rows | offset starts]`.
    pub buffer: wgpu::Buffer,
    /// Host copy of the offset starts, `[kv + 1]`.
    pub starts: Vec<u32>,
}

/// A word index as `u32`, or a size error.
fn word_offset(n: usize) -> Result<u32> {
    u32::try_from(n).map_err(|_| GpuError::TooLarge {
        what: "index arrays",
        bytes: n as u64 * 4,
        limit: u32::MAX as u64,
    })
}

/// A layer prepared on the device for the [`GpuEngine`](crate::GpuEngine).
///
/// A layer made by the engine (`submanifold`, `downsample`, `upsample`) holds what every
/// pass of both algorithms needs; one imported for inference
/// ([`GpuEngine::import`](crate::GpuEngine::import)) holds only what its algorithm's forward
/// reads, and the other passes return [`GpuError::LayerPart`].
#[derive(Debug)]
pub struct GpuLayer {
    pub(crate) kind: MapKind,
    pub(crate) kv: usize,
    pub(crate) n_in: usize,
    pub(crate) n_out: usize,
    n_pairs: usize,
    /// The plan over the outputs (chunked kernels).
    forward: Option<DevicePlan>,
    /// The plan over the inputs (input gradient of strided maps; submanifold maps reuse the
    /// forward plan with mirrored offsets).
    pub(crate) backward: Option<DevicePlan>,
    /// The rulebook kernels' pairs (and the weight gradient's).
    pairs: Option<DevicePairs>,
}

/// What [`GpuLayer::from_cpu`] uploads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum LayerParts {
    /// Everything: both algorithms, every pass.
    All,
    /// The forward of one algorithm.
    Forward(ConvAlgorithm),
}

impl GpuLayer {
    /// What the layer connects.
    pub fn kind(&self) -> MapKind {
        self.kind
    }

    /// Number of (input, output) pairs.
    pub fn num_pairs(&self) -> usize {
        self.n_pairs
    }

    /// The plan over the outputs.
    pub(crate) fn forward_plan(&self) -> Result<&DevicePlan> {
        self.forward.as_ref().ok_or(GpuError::LayerPart("the chunked kernels' plan"))
    }

    /// The pair lists.
    pub(crate) fn pairs(&self) -> Result<&DevicePairs> {
        self.pairs.as_ref().ok_or(GpuError::LayerPart("the rulebook kernels' pair lists"))
    }

    /// The layer of a CPU geometry: its plans and pairs uploaded as they are (`parts` says
    /// which).
    ///
    /// # Errors
    /// Buffers over the device's limits, device errors.
    pub(crate) fn from_cpu(ctx: &GpuContext, layer: &ChunkedConv, parts: LayerParts) -> Result<Self> {
        let plan = layer.forward_plan();
        let kv = plan.kernel_volume();
        let (chunked, rulebook, all) = match parts {
            LayerParts::All => (true, true, true),
            LayerParts::Forward(ConvAlgorithm::Chunked) => (true, false, false),
            LayerParts::Forward(ConvAlgorithm::Rulebook) => (false, true, false),
        };
        let forward = chunked.then(|| DevicePlan::upload(ctx, plan)).transpose()?;
        let backward = if all { layer.backward_plan().map(|p| DevicePlan::upload(ctx, p)).transpose()? } else { None };
        let pairs = rulebook.then(|| upload_pairs(ctx, &plan.neighbour_table(), kv)).transpose()?;
        Ok(Self {
            kind: layer.kind(),
            kv,
            n_in: layer.n_in(),
            n_out: layer.n_out(),
            n_pairs: plan.num_pairs(),
            forward,
            backward,
            pairs,
        })
    }

    /// The layer of a `[n_out, kv]` neighbour table (entry `(u, k)`: the input row of output
    /// `u` at offset `k`, or EMPTY), for `algorithm`'s forward only, as
    /// [`LayerParts::Forward`]: the chunked kernel reads the table itself, the rulebook kernels
    /// its pair lists.
    ///
    /// # Errors
    /// A table that is not `n_out` rows of `kv` entries or names a row past `n_in`; buffers
    /// over the device's limits.
    pub(crate) fn from_table(
        ctx: &GpuContext,
        kind: MapKind,
        n_in: usize,
        table: &[u32],
        algorithm: ConvAlgorithm,
    ) -> Result<Self> {
        let kv = kernel_volume(kind);
        if !table.len().is_multiple_of(kv) {
            return Err(SparseError::InvalidArgument(format!(
                "a neighbour table of {} entries is not whole rows of {kv}",
                table.len()
            ))
            .into());
        }
        let n_out = table.len() / kv;
        let (bad, n_pairs) = table
            .par_iter()
            .map(|&r| (usize::from(r != EMPTY && r as usize >= n_in), usize::from(r != EMPTY)))
            .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
        if bad > 0 {
            return Err(SparseError::InvalidArgument(format!(
                "{bad} neighbour table entries name rows past the {n_in} input rows"
            ))
            .into());
        }
        let (forward, pairs) = match algorithm {
            ConvAlgorithm::Chunked => (Some(DevicePlan::upload_table(ctx, table, n_out)?), None),
            ConvAlgorithm::Rulebook => (None, Some(upload_pairs(ctx, table, kv)?)),
        };
        Ok(Self { kind, kv, n_in, n_out, n_pairs, forward, backward: None, pairs })
    }

    /// The layer of a plan built on the device ([`crate::DeviceHierarchy`]): the chunked
    /// forward only (the rulebook kernels and the gradients return [`GpuError::LayerPart`]).
    pub(crate) fn of_device_plan(kind: MapKind, n_in: usize, n_pairs: usize, plan: DevicePlan) -> Self {
        let kv = kernel_volume(kind);
        let n_out = plan.n_dst as usize;
        Self { kind, kv, n_in, n_out, n_pairs, forward: Some(plan), backward: None, pairs: None }
    }

    /// A submanifold layer with its neighbour table built on the device.
    pub(crate) fn submanifold(
        ctx: &GpuContext,
        coords: &[Coord],
        kernel_size: usize,
        chunk: &ChunkConfig,
    ) -> Result<Self> {
        if kernel_size.is_multiple_of(2) || kernel_size > 9 {
            return Err(SparseError::KernelSize(kernel_size).into());
        }
        let kv = kernel_size.pow(3);
        let n = coords.len();
        let table = neighbour_table(ctx, coords, kernel_size)?;
        let plan = ChunkPlan::from_table(&table, kv, Some(kv / 2), n, coords, chunk)?;
        let forward = DevicePlan::upload(ctx, &plan)?;
        let pairs = upload_pairs(ctx, &table, kv)?;
        Ok(Self {
            kind: MapKind::Submanifold { kernel_size },
            kv,
            n_in: n,
            n_out: n,
            n_pairs: plan.num_pairs(),
            forward: Some(forward),
            backward: None,
            pairs: Some(pairs),
        })
    }

    /// The strided layer from `fine` to its coarse set.
    pub(crate) fn downsample(ctx: &GpuContext, fine: &[Coord], chunk: &ChunkConfig) -> Result<(Vec<Coord>, Self)> {
        let (coarse, map) = KernelMap::downsample(fine)?;
        let layer = ChunkedConv::new(map, fine, &coarse, chunk)?;
        Ok((coarse, Self::from_cpu(ctx, &layer, LayerParts::All)?))
    }

    /// The transposed layer from `coarse` to `fine`.
    pub(crate) fn upsample(ctx: &GpuContext, coarse: &[Coord], fine: &[Coord], chunk: &ChunkConfig) -> Result<Self> {
        let layer = ChunkedConv::new(KernelMap::upsample(coarse, fine)?, coarse, fine, chunk)?;
        Self::from_cpu(ctx, &layer, LayerParts::All)
    }
}

/// Offsets of a layer of `kind`: `K^3` for submanifold maps, 8 for strided ones.
fn kernel_volume(kind: MapKind) -> usize {
    match kind {
        MapKind::Submanifold { kernel_size } => kernel_size.pow(3),
        MapKind::Down | MapKind::Up => 8,
    }
}

/// The per-offset pair lists of an `[n_out, kv]` neighbour table (sorted by output row within
/// an offset, as `KernelMap` keeps them), uploaded as `[in | out | starts]`.
fn upload_pairs(ctx: &GpuContext, table: &[u32], kv: usize) -> Result<DevicePairs> {
    let n_out = table.len().checked_div(kv).unwrap_or(0);
    let mut per: Vec<(Vec<u32>, Vec<u32>)> = vec![(Vec::new(), Vec::new()); kv];
    for u in 0..n_out {
        for (k, p) in per.iter_mut().enumerate() {
            let s = table[u * kv + k];
            if s != EMPTY {
                p.0.push(s);
                p.1.push(u as u32);
            }
        }
    }
    let total: usize = per.iter().map(|p| p.0.len()).sum();
    let mut words = Vec::with_capacity(2 * total + kv + 1);
    let mut starts = Vec::with_capacity(kv + 1);
    starts.push(0u32);
    for p in &per {
        words.extend_from_slice(&p.0);
        starts.push(word_offset(words.len())?);
    }
    for p in &per {
        words.extend_from_slice(&p.1);
    }
    words.extend_from_slice(&starts);
    word_offset(words.len())?;
    Ok(DevicePairs { buffer: ctx.upload("pair lists", &words)?, starts })
}

/// The `[n, K^3]` submanifold neighbour table of `coords`, built on the device.
fn neighbour_table(ctx: &GpuContext, coords: &[Coord], kernel_size: usize) -> Result<Vec<u32>> {
    let n = coords.len();
    let kv = kernel_size.pow(3);
    for (row, &c) in coords.iter().enumerate() {
        pack_key(c, row)?;
    }
    if n == 0 {
        return Ok(Vec::new());
    }
    let entries = n.checked_mul(kv).filter(|&e| e < u32::MAX as usize).ok_or(SparseError::TooManyRows(n))?;
    // Load factor at most one half: short probe sequences.
    let capacity = (2 * n).next_power_of_two().max(64);
    let cap32 = u32::try_from(capacity).map_err(|_| SparseError::TooManyRows(n))?;
    let coords_buf = ctx.upload("coordinates", coords)?;
    let slots = ctx.upload("hash slots", &vec![EMPTY; capacity])?;
    let status = ctx.zeroed("map status", 12)?;
    let table = ctx.zeroed("neighbour table", entries as u64 * 4)?;
    let params = [n as u32, cap32 - 1, kernel_size as u32, kv as u32, 0];
    // The pooled buffers are not touched, but recording is one caller at a time.
    let _call = ctx.begin_call()?;
    let mut enc = ctx.encoder();
    let p = &ctx.pipelines;
    let b = [(1, &coords_buf), (2, &slots), (3, &status)];
    ctx.dispatch(&mut enc, &p.map_insert, &params, &b, (n as u32).div_ceil(WORKGROUP), 1);
    let b = [(1, &coords_buf), (2, &slots), (3, &status), (4, &table)];
    ctx.dispatch(&mut enc, &p.map_lookup, &params, &b, (entries as u32).div_ceil(WORKGROUP), 1);
    let status: Vec<u32> = ctx.finish_and_read(enc, &status, 2)?;
    if status[0] != 0 {
        let row = status[0] as usize - 1;
        return Err(SparseError::InvalidArgument(format!(
            "duplicate coordinate {:?} at row {row} (build a SparseTensor to merge duplicates)",
            coords[row]
        ))
        .into());
    }
    if status[1] != 0 {
        return Err(GpuError::Device("the voxel hash table overflowed".into()));
    }
    ctx.finish_and_read(ctx.encoder(), &table, entries)
}
