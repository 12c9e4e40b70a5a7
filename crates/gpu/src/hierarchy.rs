//! A voxel hierarchy built on the device: what a U-Net (the network's levels) needs of its
//! input's coordinates, without the host building and uploading it per input.
//!
//! Per level: the voxels, the 3x3x3 submanifold layer (hash table and look-ups,
//! shaders/map.wgsl), the pointwise layer, and the strided layer to the next level with its
//! transpose (shaders/hierarchy.wgsl): parents `floor(u / 2)` go into a hash table whose slots
//! keep the lowest fine row of each parent, a prefix sum over "first child" flags numbers the
//! coarse voxels in order of first appearance (the CPU's order, `KernelMap::downsample`), and
//! every fine row writes its entry of both strided tables. Then, on request, the trilinear
//! interpolation tables between levels (the network's cross-scale fusion), as
//! `crates/net` geometry.rs builds them on the host.
//!
//! Why: on an H100 the host's geometry and its upload took 45 of the network's 61-68 ms per
//! room (docs/gpu.md). Here the host uploads the coordinates only, and waits once per level
//! for the coarse voxel count (buffers are sized exactly; the forward needs the counts anyway).
//! The scratch buffers (hash tables, ranks, statuses) are the context's pooled ones, kept
//! between calls: buffer creation was a good part of the fixed cost of a small input.
//! Every table is the same as the host's, bit for bit (integer work, fixed orders), except the
//! interpolation weights, whose division rounds on the device (within an ulp or two).
//!
//! The layers are the chunked kernel's forward only (the network's inference path); the
//! rulebook kernels and the gradients return [`GpuError::LayerPart`] on them.

use semrecon_sparse::key::pack_key;
use semrecon_sparse::{Coord, MapKind, SparseError};

use crate::context::{GpuContext, WORKGROUP};
use crate::engine::{count32, GpuEngine};
use crate::error::{GpuError, Result};
use crate::host_level::HostLevel;
use crate::layer::{DevicePlan, GpuLayer, EMPTY};
use crate::record::Recorder;
use crate::resident::GpuGather;

/// Rows per block of the device prefix sum (shaders/hierarchy.wgsl `SCAN`).
const SCAN: u32 = 256;

/// One level of a [`DeviceHierarchy`].
#[derive(Debug)]
pub struct DeviceLevel {
    rows: usize,
    neighbour_pairs: usize,
    /// `[rows]` as `vec4<i32>`.
    coords: wgpu::Buffer,
    /// `[rows]`: the row of every voxel's parent at the next level (absent at the coarsest).
    parent: Option<wgpu::Buffer>,
    /// The 3x3x3 submanifold layer of the level's voxels.
    pub subm: GpuLayer,
    /// The pointwise (1x1x1) layer: linear layers on the rows.
    pub point: GpuLayer,
    /// The strided layer to the next level and its transpose back (absent at the coarsest).
    pub down: Option<(GpuLayer, GpuLayer)>,
}

impl DeviceLevel {
    /// Voxels of the level.
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// (voxel, neighbour) pairs of the submanifold layer, the voxel itself included.
    pub fn neighbour_pairs(&self) -> usize {
        self.neighbour_pairs
    }
}

/// The levels of one input, on the device of the engine that built them
/// ([`GpuEngine::build_hierarchy`]).
#[derive(Debug)]
pub struct DeviceHierarchy {
    /// Level 0 is the input's voxels, in the order given; each next level their parents.
    pub levels: Vec<DeviceLevel>,
}

impl GpuEngine {
    /// Builds `levels` levels of `coords` (distinct voxels, in range; Z-order makes the
    /// chunked kernel fastest and is kept at every level) on the device.
    ///
    /// # Errors
    /// Zero levels, out-of-range or duplicate coordinates ([`GpuError::Sparse`] naming the
    /// row), buffers over the device's limits, a lost device.
    pub fn build_hierarchy(&self, coords: &[Coord], levels: usize) -> Result<DeviceHierarchy> {
        if levels == 0 {
            return Err(SparseError::InvalidArgument("a hierarchy of no levels".into()).into());
        }
        for (row, &c) in coords.iter().enumerate() {
            pack_key(c, row)?;
        }
        let ctx = &**self.context();
        let _call = ctx.begin_call()?;
        let mut rows = coords.len();
        let mut coords_buf = ctx.upload("coordinates", coords)?;
        let mut out = Vec::with_capacity(levels);
        let mut enc = ctx.encoder();
        for level in 0..levels {
            let n = count32("voxels", rows)?;
            let entries = count32("neighbour table", rows.checked_mul(28).ok_or(SparseError::TooManyRows(rows))?)?;
            let capacity = count32("hash slots", (2 * rows).next_power_of_two().max(64))?;
            let slots = ctx.transient("hierarchy hash slots", u64::from(capacity) * 4)?;
            fill(ctx, &mut enc, &slots, capacity, EMPTY);
            // [destination rows | table]: the chunked kernel's plan layout.
            let subm_plan = ctx.zeroed("submanifold plan", u64::from(entries) * 4)?;
            let map_status = ctx.transient("hierarchy map status", 12)?;
            fill(ctx, &mut enc, &map_status, 3, 0);
            let p = &ctx.pipelines;
            let b = [(1, &coords_buf), (2, &slots), (3, &map_status)];
            ctx.dispatch(&mut enc, &p.map_insert, &[n, capacity - 1, 3, 27, 0], &b, n.div_ceil(WORKGROUP), 1);
            let b = [(1, &coords_buf), (2, &slots), (3, &map_status), (4, &subm_plan)];
            let groups = count32("neighbour table", rows * 27)?.div_ceil(WORKGROUP);
            ctx.dispatch(&mut enc, &p.map_lookup, &[n, capacity - 1, 3, 27, 1], &b, groups, 1);
            let point_plan = ctx.zeroed("pointwise plan", u64::from(n) * 8)?;
            row_numbers(ctx, &mut enc, &point_plan, 2 * n, n);
            let coarser = (level + 1 < levels).then(|| Parents::count(ctx, &mut enc, &coords_buf, n)).transpose()?;

            // One wait per level: the statuses, the pair count and the coarse voxel count.
            let report = ctx.transient("hierarchy report", 20)?;
            enc.copy(&map_status, 0, &report, 0, 12);
            if let Some(parents) = &coarser {
                enc.copy(&parents.status, 0, &report, 12, 8);
            }
            let r = ctx.finish_and_read_status(std::mem::replace(&mut enc, ctx.encoder()), &report, 5)?;
            if r[0] != 0 {
                let row = r[0] as usize - 1;
                return Err(SparseError::InvalidArgument(format!(
                    "duplicate coordinate {:?} at row {row} (build a SparseTensor to merge duplicates)",
                    coords.get(row).copied().unwrap_or_default()
                ))
                .into());
            }
            // The parents' words were copied only with a coarser level.
            if r[1] != 0 || (coarser.is_some() && r[4] != 0) {
                return Err(GpuError::Device("the voxel hash table overflowed".into()));
            }
            let sub = MapKind::Submanifold { kernel_size: 3 };
            let subm = GpuLayer::of_device_plan(sub, rows, r[2] as usize, DevicePlan { buffer: subm_plan, n_dst: n });
            let point_kind = MapKind::Submanifold { kernel_size: 1 };
            let point = GpuLayer::of_device_plan(point_kind, rows, rows, DevicePlan { buffer: point_plan, n_dst: n });
            let (next, parent, down) = match coarser {
                Some(parents) => {
                    let (coarse, parent, down, up) = parents.emit(ctx, &mut enc, &coords_buf, n, r[3])?;
                    let down_layer = GpuLayer::of_device_plan(MapKind::Down, rows, rows, down);
                    let up_layer = GpuLayer::of_device_plan(MapKind::Up, r[3] as usize, rows, up);
                    (Some((coarse, r[3] as usize)), Some(parent), Some((down_layer, up_layer)))
                }
                None => (None, None, None),
            };
            let this =
                DeviceLevel { rows, neighbour_pairs: r[2] as usize, coords: coords_buf, parent, subm, point, down };
            out.push(this);
            match next {
                Some((c, m)) => {
                    coords_buf = c;
                    rows = m;
                }
                None => break,
            }
        }
        Ok(DeviceHierarchy { levels: out })
    }

    /// The trilinear interpolation from level `j` of `h` to level `t < j` (the network's
    /// cross-scale fusion, as `crates/net` geometry.rs builds it on the host): 8 `(row,
    /// weight)` per row of level `t`, recorded on the device without waiting; the corners
    /// are looked up in level `j`'s submanifold table.
    ///
    /// # Errors
    /// `t >= j` or `j` past the levels; a lost device.
    pub fn interpolation(&self, h: &DeviceHierarchy, t: usize, j: usize) -> Result<GpuGather> {
        if t >= j || j >= h.levels.len() {
            return Err(SparseError::InvalidArgument(format!(
                "interpolation from level {j} to level {t} of a hierarchy of {}",
                h.levels.len()
            ))
            .into());
        }
        let ctx = &**self.context();
        let _call = ctx.begin_resident_call()?;
        let fine = &h.levels[t];
        let n = count32("voxels", fine.rows)?;
        let coarse = &h.levels[j];
        let coarse_rows = count32("voxels", coarse.rows)?;
        let plan = coarse.subm.forward_plan()?;
        let first = fine.parent.as_ref().ok_or(GpuError::LayerPart("the parents of a level with no coarser one"))?;
        let parents = h.levels[t + 1..j]
            .iter()
            .map(|level| level.parent.as_ref().ok_or(GpuError::LayerPart("parents")))
            .collect::<Result<Vec<_>>>()?;
        // Written whole (the copy below) before it is read.
        let ancestors = ctx.transient("hierarchy ancestors", u64::from(n) * 4)?;
        let gather = ctx.zeroed("interpolation table", u64::from(n) * 64)?;
        let p = &ctx.pipelines.hierarchy;
        ctx.record(|enc| {
            // Ancestors: the parents, then their parents, up to level j.
            enc.copy(first, 0, &ancestors, 0, u64::from(n) * 4);
            for parent in parents {
                let b = [(7, parent), (10, &ancestors)];
                ctx.dispatch(enc, &p.ancestor, &[n, 0, 0, 0], &b, n.div_ceil(WORKGROUP), 1);
            }
            let params = [n, (j - t) as u32, coarse_rows, 0];
            let b = [(1, &fine.coords), (10, &ancestors), (11, &plan.buffer), (12, &gather)];
            ctx.dispatch(enc, &p.interp, &params, &b, n.div_ceil(WORKGROUP), 1);
            Ok(())
        })?;
        Ok(GpuGather::on_device(gather, fine.rows, 8, coarse.rows))
    }

    /// Level `i` of `h` read back (coordinates, tables, parents): for checks against the
    /// host's geometry.
    ///
    /// # Errors
    /// `i` past the levels; a lost device.
    pub fn download_level(&self, h: &DeviceHierarchy, i: usize) -> Result<HostLevel> {
        let level = h.levels.get(i).ok_or_else(|| {
            GpuError::from(SparseError::InvalidArgument(format!("no level {i} in {}", h.levels.len())))
        })?;
        let ctx = &**self.context();
        let _call = ctx.begin_call()?;
        let n = level.rows;
        let coords: Vec<Coord> = ctx.finish_and_read(ctx.encoder(), &level.coords, n)?;
        let plan: Vec<u32> = ctx.finish_and_read(ctx.encoder(), &level.subm.forward_plan()?.buffer, n * 28)?;
        let down = match &level.down {
            Some((d, u)) => {
                let nc = d.n_out;
                let dp: Vec<u32> = ctx.finish_and_read(ctx.encoder(), &d.forward_plan()?.buffer, nc * 9)?;
                let up: Vec<u32> = ctx.finish_and_read(ctx.encoder(), &u.forward_plan()?.buffer, n * 9)?;
                Some((dp[nc..].to_vec(), up[n..].to_vec()))
            }
            None => None,
        };
        let parent = level.parent.as_ref().map(|p| ctx.finish_and_read(ctx.encoder(), p, n)).transpose()?;
        Ok(HostLevel { coords, subm: plan[n..].to_vec(), down, parent })
    }

    /// An interpolation table read back: `(rows, weights)`, `[rows, 8]` each.
    ///
    /// # Errors
    /// A lost device.
    pub fn download_gather(&self, g: &GpuGather) -> Result<(Vec<u32>, Vec<f32>)> {
        let ctx = &**self.context();
        let _call = ctx.begin_call()?;
        let len = g.len() * g.per_row();
        let words: Vec<u32> = ctx.finish_and_read(ctx.encoder(), g.buffer(), 2 * len)?;
        Ok((words[..len].to_vec(), words[len..].iter().map(|&w| f32::from_bits(w)).collect()))
    }
}

/// The parents of a level being numbered (until the coarse count is read back).
struct Parents {
    slots: wgpu::Buffer,
    slot_of: wgpu::Buffer,
    rank: wgpu::Buffer,
    /// `[coarse voxels, overflow]`.
    status: wgpu::Buffer,
}

impl Parents {
    /// Records the parents' hash table, the first-child flags and their prefix sum.
    fn count(ctx: &GpuContext, enc: &mut Recorder, coords: &wgpu::Buffer, n: u32) -> Result<Self> {
        let capacity = count32("hash slots", (2 * n as usize).next_power_of_two().max(64))?;
        let slots = ctx.transient("hierarchy parent slots", u64::from(capacity) * 4)?;
        fill(ctx, enc, &slots, capacity, EMPTY);
        // Written for every row (insert, first_child) and block (scan_blocks) before read.
        let slot_of = ctx.transient("hierarchy parent slot of rows", u64::from(n) * 4)?;
        let rank = ctx.transient("hierarchy parent ranks", u64::from(n) * 4)?;
        let blocks = n.div_ceil(SCAN);
        let block_sums = ctx.transient("hierarchy prefix sum blocks", u64::from(blocks) * 4)?;
        let status = ctx.transient("hierarchy parent status", 8)?;
        fill(ctx, enc, &status, 2, 0);
        let p = &ctx.pipelines.hierarchy;
        let params = [n, capacity - 1, blocks, 0];
        let groups = n.div_ceil(WORKGROUP);
        ctx.dispatch(enc, &p.insert, &params, &[(1, coords), (2, &slots), (3, &slot_of), (6, &status)], groups, 1);
        ctx.dispatch(enc, &p.first_child, &params, &[(2, &slots), (3, &slot_of), (4, &rank)], groups, 1);
        ctx.dispatch(enc, &p.scan_blocks, &params, &[(4, &rank), (5, &block_sums)], blocks, 1);
        ctx.dispatch(enc, &p.scan_totals, &params, &[(5, &block_sums), (6, &status)], 1, 1);
        ctx.dispatch(enc, &p.scan_add, &params, &[(4, &rank), (5, &block_sums)], blocks, 1);
        Ok(Self { slots, slot_of, rank, status })
    }

    /// Records the coarse voxels, the parent rows and the strided layer's plans (down:
    /// `[coarse | coarse x 8]`, up: `[fine | fine x 8]`), now that there are `nc` parents.
    fn emit(
        &self,
        ctx: &GpuContext,
        enc: &mut Recorder,
        coords: &wgpu::Buffer,
        n: u32,
        nc: u32,
    ) -> Result<(wgpu::Buffer, wgpu::Buffer, DevicePlan, DevicePlan)> {
        let coarse = ctx.zeroed("coordinates", u64::from(nc) * 16)?;
        let parent = ctx.zeroed("parents", u64::from(n) * 4)?;
        let down_words = count32("strided plan", nc as usize * 9)?;
        let up_words = count32("strided plan", n as usize * 9)?;
        let down = ctx.zeroed("strided plan", u64::from(down_words) * 4)?;
        let up = ctx.zeroed("strided plan", u64::from(up_words) * 4)?;
        fill(ctx, enc, &down, down_words, EMPTY);
        fill(ctx, enc, &up, up_words, EMPTY);
        row_numbers(ctx, enc, &down, nc, nc);
        row_numbers(ctx, enc, &up, n, n);
        let b = [
            (1, coords),
            (2, &self.slots),
            (3, &self.slot_of),
            (4, &self.rank),
            (7, &parent),
            (8, &coarse),
            (9, &down),
            (10, &up),
        ];
        ctx.dispatch(enc, &ctx.pipelines.hierarchy.emit, &[n, nc, 0, 0], &b, n.div_ceil(WORKGROUP), 1);
        Ok((coarse, parent, DevicePlan { buffer: down, n_dst: nc }, DevicePlan { buffer: up, n_dst: n }))
    }
}

/// Records `buffer[i] = value` for `i < n`.
fn fill(ctx: &GpuContext, enc: &mut Recorder, buffer: &wgpu::Buffer, n: u32, value: u32) {
    ctx.dispatch(enc, &ctx.pipelines.hierarchy.fill, &[n, 0, 0, value], &[(9, buffer)], n.div_ceil(WORKGROUP), 1);
}

/// Records `buffer[i] = i % modulus` for `i < n` (plans' destination rows).
fn row_numbers(ctx: &GpuContext, enc: &mut Recorder, buffer: &wgpu::Buffer, n: u32, modulus: u32) {
    let params = [n, 0, 0, modulus.max(1)];
    ctx.dispatch(enc, &ctx.pipelines.hierarchy.rows, &params, &[(9, buffer)], n.div_ceil(WORKGROUP), 1);
}
