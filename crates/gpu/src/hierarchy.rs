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
//! room (docs/gpu.md). Here the host uploads the coordinates only and waits once: the coarser
//! levels' voxel counts stay on the device until the end, buffers are sized by the input's
//! count (no level has more voxels), and each kernel's parameters are written on the device
//! from the counts (shaders/derive.wgsl). Every table is the same as the host's, bit for bit
//! (integer work, fixed orders), except the interpolation weights, whose division rounds on
//! the device (within an ulp or two).
//!
//! The layers are the chunked kernel's forward only (the network's inference path); the
//! rulebook kernels and the gradients return [`GpuError::LayerPart`] on them.

use semrecon_sparse::key::pack_key;
use semrecon_sparse::{Coord, MapKind, SparseError};

use crate::context::{DerivedWord, GpuContext, WORKGROUP};
use crate::engine::{count32, GpuEngine};
use crate::error::{GpuError, Result};
use crate::host_level::HostLevel;
use crate::layer::{DevicePlan, GpuLayer, EMPTY};
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
        // Every level has at most the input's voxels: buffers are sized by that bound, and the
        // kernels read their level's true count from `counts` (derived parameters).
        let bound = count32("voxels", coords.len())?;
        let bound_entries = |per: u32| count32("hierarchy tables", bound as usize * per as usize);
        let capacity = count32("hash slots", (2 * bound as usize).next_power_of_two().max(64))?;
        let mut initial = vec![0u32; levels];
        initial[0] = bound;
        let counts = ctx.upload("voxel counts", &initial)?;
        // Report: counts [levels] | map status [levels, 3] | parents' overflow [levels].
        let report = ctx.zeroed("hierarchy report", 5 * levels as u64 * 4)?;
        let mut coords_buf = ctx.upload("coordinates", coords)?;
        let mut enc = ctx.encoder();
        let p = &ctx.pipelines;
        let mut built: Vec<Built> = Vec::with_capacity(levels);
        for level in 0..levels {
            let count = |mul: u32, add: u32| DerivedWord::Count { index: level as u32, mul, add };
            let slots = ctx.zeroed("hash slots", u64::from(capacity) * 4)?;
            fill(ctx, &mut enc, &slots, capacity, EMPTY);
            // [destination rows | table]: the chunked kernel's plan layout.
            let subm_plan = ctx.zeroed("submanifold plan", u64::from(bound_entries(28)?) * 4)?;
            let map_status = ctx.zeroed("map status", 12)?;
            let mask = DerivedWord::Const(capacity - 1);
            let (three, kv) = (DerivedWord::Const(3), DerivedWord::Const(27));
            let insert = ctx.derived_params(&mut enc, &counts, &[count(1, 0), mask, three, kv, DerivedWord::Const(0)]);
            let b = [(0, &insert), (1, &coords_buf), (2, &slots), (3, &map_status)];
            ctx.dispatch(&mut enc, &p.map_insert, &b, bound.div_ceil(WORKGROUP), 1);
            let lookup = ctx.derived_params(&mut enc, &counts, &[count(1, 0), mask, three, kv, DerivedWord::Const(1)]);
            let b = [(0, &lookup), (1, &coords_buf), (2, &slots), (3, &map_status), (4, &subm_plan)];
            ctx.dispatch(&mut enc, &p.map_lookup, &b, bound_entries(27)?.div_ceil(WORKGROUP), 1);
            let point_plan = ctx.zeroed("pointwise plan", u64::from(bound) * 8)?;
            let zero = DerivedWord::Const(0);
            let rows = ctx.derived_params(&mut enc, &counts, &[count(2, 0), zero, zero, count(1, 0)]);
            ctx.dispatch(
                &mut enc,
                &p.hierarchy.rows,
                &[(0, &rows), (9, &point_plan)],
                (2 * bound).div_ceil(WORKGROUP),
                1,
            );
            enc.copy_buffer_to_buffer(&map_status, 0, &report, (levels as u64 + 3 * level as u64) * 4, 12);
            if level + 1 < levels {
                let next = Parents::record(ctx, &mut enc, &counts, level, &coords_buf, bound, capacity)?;
                enc.copy_buffer_to_buffer(&next.status, 4, &report, (4 * levels + level) as u64 * 4, 4);
                let coarse = next.coarse;
                built.push((coords_buf, subm_plan, point_plan, Some((next.parent, next.down, next.up))));
                coords_buf = coarse;
            } else {
                built.push((coords_buf, subm_plan, point_plan, None));
                break;
            }
        }
        enc.copy_buffer_to_buffer(&counts, 0, &report, 0, levels as u64 * 4);
        // The one wait: every level's count, statuses and pair count.
        let r = ctx.finish_and_read_status(enc, &report, 5 * levels)?;
        if r[levels] != 0 {
            let row = r[levels] as usize - 1;
            return Err(SparseError::InvalidArgument(format!(
                "duplicate coordinate {:?} at row {row} (build a SparseTensor to merge duplicates)",
                coords.get(row).copied().unwrap_or_default()
            ))
            .into());
        }
        if (0..levels).any(|l| r[levels + 3 * l + 1] != 0 || r[4 * levels + l] != 0) {
            return Err(GpuError::Device("the voxel hash table overflowed".into()));
        }
        let mut out = Vec::with_capacity(levels);
        for (level, (coords, subm_plan, point_plan, strided)) in built.into_iter().enumerate() {
            let n = r[level];
            let rows = n as usize;
            let pairs = r[levels + 3 * level + 2] as usize;
            let sub = MapKind::Submanifold { kernel_size: 3 };
            let subm = GpuLayer::of_device_plan(sub, rows, pairs, DevicePlan { buffer: subm_plan, n_dst: n });
            let point_kind = MapKind::Submanifold { kernel_size: 1 };
            let point = GpuLayer::of_device_plan(point_kind, rows, rows, DevicePlan { buffer: point_plan, n_dst: n });
            let (parent, down) = match strided {
                Some((parent, down, up)) => {
                    let m = r[level + 1];
                    let down_layer =
                        GpuLayer::of_device_plan(MapKind::Down, rows, rows, DevicePlan { buffer: down, n_dst: m });
                    let up_layer =
                        GpuLayer::of_device_plan(MapKind::Up, m as usize, rows, DevicePlan { buffer: up, n_dst: n });
                    (Some(parent), Some((down_layer, up_layer)))
                }
                None => (None, None),
            };
            out.push(DeviceLevel { rows, neighbour_pairs: pairs, coords, parent, subm, point, down });
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
        let mut enc = ctx.encoder();
        // Ancestors: the parents, then their parents, up to level j.
        let ancestors = ctx.zeroed("ancestors", u64::from(n) * 4)?;
        let first = fine.parent.as_ref().ok_or(GpuError::LayerPart("the parents of a level with no coarser one"))?;
        enc.copy_buffer_to_buffer(first, 0, &ancestors, 0, u64::from(n) * 4);
        let p = &ctx.pipelines.hierarchy;
        for level in &h.levels[t + 1..j] {
            let parent = level.parent.as_ref().ok_or(GpuError::LayerPart("parents"))?;
            let params = ctx.params(&[n, 0, 0, 0]);
            ctx.dispatch(
                &mut enc,
                &p.ancestor,
                &[(0, &params), (7, parent), (10, &ancestors)],
                n.div_ceil(WORKGROUP),
                1,
            );
        }
        let coarse = &h.levels[j];
        let gather = ctx.zeroed("interpolation table", u64::from(n) * 64)?;
        let plan = coarse.subm.forward_plan()?;
        let params = ctx.params(&[n, (j - t) as u32, count32("voxels", coarse.rows)?, 0]);
        let b = [(0, &params), (1, &fine.coords), (10, &ancestors), (11, &plan.buffer), (12, &gather)];
        ctx.dispatch(&mut enc, &p.interp, &b, n.div_ceil(WORKGROUP), 1);
        ctx.enqueue(enc)?;
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

/// One level's buffers while the hierarchy is recorded: coordinates, submanifold plan,
/// pointwise plan, and (below the coarsest) parents, down plan and up plan.
type Built = (wgpu::Buffer, wgpu::Buffer, wgpu::Buffer, Option<(wgpu::Buffer, wgpu::Buffer, wgpu::Buffer)>);

/// The parents of one level, recorded on the device: numbered, the coarse voxels, the parent
/// rows and the strided layer's plans (down: `[coarse | coarse x 8]`, up: `[fine | fine x 8]`),
/// all sized by the input's voxel count and filled up to the device's counts.
struct Parents {
    coarse: wgpu::Buffer,
    parent: wgpu::Buffer,
    down: wgpu::Buffer,
    up: wgpu::Buffer,
    /// `[coarse voxels, overflow]`.
    status: wgpu::Buffer,
}

impl Parents {
    /// Records the parents of level `level` (its count in `counts[level]`, at most `bound`):
    /// the hash table of parents, the first-child flags and their prefix sum (the coarse
    /// count goes to `counts[level + 1]`), then the coarse voxels and both strided plans.
    fn record(
        ctx: &GpuContext,
        enc: &mut wgpu::CommandEncoder,
        counts: &wgpu::Buffer,
        level: usize,
        coords: &wgpu::Buffer,
        bound: u32,
        capacity: u32,
    ) -> Result<Self> {
        let slots = ctx.zeroed("parent slots", u64::from(capacity) * 4)?;
        fill(ctx, enc, &slots, capacity, EMPTY);
        let slot_of = ctx.zeroed("parent slot of rows", u64::from(bound) * 4)?;
        let rank = ctx.zeroed("parent ranks", u64::from(bound) * 4)?;
        let blocks = bound.div_ceil(SCAN);
        let block_sums = ctx.zeroed("prefix sum blocks", u64::from(blocks) * 4)?;
        let status = ctx.zeroed("parent status", 8)?;
        let p = &ctx.pipelines.hierarchy;
        let fine = |mul: u32, add: u32| DerivedWord::Count { index: level as u32, mul, add };
        let coarse_count = |mul: u32, add: u32| DerivedWord::Count { index: level as u32 + 1, mul, add };
        let zero = DerivedWord::Const(0);
        // Blocks past the level's rows scan zeros: harmless.
        let params = ctx.derived_params(
            enc,
            counts,
            &[fine(1, 0), DerivedWord::Const(capacity - 1), DerivedWord::Const(blocks), zero],
        );
        let groups = bound.div_ceil(WORKGROUP);
        ctx.dispatch(enc, &p.insert, &[(0, &params), (1, coords), (2, &slots), (3, &slot_of), (6, &status)], groups, 1);
        ctx.dispatch(enc, &p.first_child, &[(0, &params), (2, &slots), (3, &slot_of), (4, &rank)], groups, 1);
        ctx.dispatch(enc, &p.scan_blocks, &[(0, &params), (4, &rank), (5, &block_sums)], blocks, 1);
        ctx.dispatch(enc, &p.scan_totals, &[(0, &params), (5, &block_sums), (6, &status)], 1, 1);
        ctx.dispatch(enc, &p.scan_add, &[(0, &params), (4, &rank), (5, &block_sums)], blocks, 1);
        enc.copy_buffer_to_buffer(&status, 0, counts, (level as u64 + 1) * 4, 4);

        let coarse = ctx.zeroed("coordinates", u64::from(bound) * 16)?;
        let parent = ctx.zeroed("parents", u64::from(bound) * 4)?;
        let plan_words = count32("strided plan", bound as usize * 9)?;
        let down = ctx.zeroed("strided plan", u64::from(plan_words) * 4)?;
        let up = ctx.zeroed("strided plan", u64::from(plan_words) * 4)?;
        fill(ctx, enc, &down, plan_words, EMPTY);
        fill(ctx, enc, &up, plan_words, EMPTY);
        let down_rows = ctx.derived_params(enc, counts, &[coarse_count(1, 0), zero, zero, coarse_count(1, 0)]);
        ctx.dispatch(enc, &p.rows, &[(0, &down_rows), (9, &down)], groups, 1);
        let up_rows = ctx.derived_params(enc, counts, &[fine(1, 0), zero, zero, fine(1, 0)]);
        ctx.dispatch(enc, &p.rows, &[(0, &up_rows), (9, &up)], groups, 1);
        let emit = ctx.derived_params(enc, counts, &[fine(1, 0), coarse_count(1, 0), zero, zero]);
        let b = [
            (0, &emit),
            (1, coords),
            (2, &slots),
            (3, &slot_of),
            (4, &rank),
            (7, &parent),
            (8, &coarse),
            (9, &down),
            (10, &up),
        ];
        ctx.dispatch(enc, &p.emit, &b, groups, 1);
        Ok(Self { coarse, parent, down, up, status })
    }
}

/// Records `buffer[i] = value` for `i < n`.
fn fill(ctx: &GpuContext, enc: &mut wgpu::CommandEncoder, buffer: &wgpu::Buffer, n: u32, value: u32) {
    let params = ctx.params(&[n, 0, 0, value]);
    ctx.dispatch(enc, &ctx.pipelines.hierarchy.fill, &[(0, &params), (9, buffer)], n.div_ceil(WORKGROUP), 1);
}
