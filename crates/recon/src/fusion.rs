//! Projective TSDF fusion of one RGB-D frame into a [`TsdfMap`].
//!
//! Two steps. Chunk selection back-projects a sub-sampled set of depth pixels, walks each
//! pixel's ray through the truncation band `depth ± band(depth)` and collects the chunks it
//! crosses; only those chunks are visited, so the cost follows the observed surface, not the
//! camera frustum. Integration then updates every voxel of the selected chunks: the voxel
//! centre is projected into the depth image (nearest pixel), its signed distance is the depth
//! minus the voxel's depth along the optical axis, truncated to ±band(depth), and folded into
//! the voxel's running weighted mean with a depth-dependent weight. Colour, which needs far
//! fewer observations than the distance, is blended from every
//! [`crate::TsdfConfig::color_every`]-th frame only (and from every frame while a voxel has
//! fewer than 16 colour observations): blending the whole band every frame was a fifth of
//! fusion's time (docs/fusion.md).
//!
//! The band follows the sensor noise ([`crate::TsdfConfig::band`]): narrow for near surfaces,
//! the full truncation distance far away. Distances are stored in units of the full
//! truncation whatever the band, so observations with different bands average correctly;
//! a narrow band means fewer chunks selected and fewer voxels updated, which is where fusion
//! and meshing spend their time.
//!
//! Chunks are updated in parallel with rayon, one task per chunk; every voxel's update
//! depends only on its own state and the frame, so results are bit-identical for any thread
//! count. Chunks newly allocated for a frame that end up holding no voxel within the
//! truncation band are freed again, so the map only keeps chunks near observed surfaces.
//!
//! Both steps have SIMD kernels chosen once at run time: AVX-512F or AVX2 intrinsics where
//! the CPU has them (submodules `avx512`, `avx2`), the `wide::f32x8` kernel and a scalar band
//! walk otherwise; `SEMRECON_FUSION_SIMD=avx2|portable` forces a lower level. The baseline
//! build targets SSE2, where `wide` runs as pairs of SSE operations with lane-by-lane
//! gathers. Every kernel performs the same float operations in the same order (no fused
//! multiply-add), so all give the same bits, tested against the scalar `Voxel::fuse`.
//!
//! Invalid depth (0, negative, NaN, infinite, outside the configured range) is skipped.

use std::sync::OnceLock;

use glam::{Affine3A, Vec3A};
use rayon::prelude::*;
use semrecon_data::{Frame, Intrinsics};
use wide::{f32x8, i16x8, i32x8, u16x8};

use crate::error::{ReconError, Result};
use crate::map::{
    blend_color, key_order, BandModel, Chunk, ChunkKey, SignSummary, TsdfMap, CHUNK_SIDE, COLOR_WARMUP, NOISE_OFFSET,
    TSDF_SCALE, WEIGHT_SCALE,
};
use crate::TsdfConfig;

/// Weight of one depth observation: `1 / z²` (z in metres) capped at 4.
///
/// Structured-light and time-of-flight depth noise grows roughly with the square of depth,
/// so a near observation deserves more trust; the cap keeps a very close observation from
/// freezing a voxel.
#[inline]
pub fn depth_weight(depth: f32) -> f32 {
    (1.0 / (depth * depth)).min(4.0)
}

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;

/// Which integration kernel runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kernel {
    /// `wide::f32x8` (whatever the build's target features make of it).
    Portable,
    /// AVX2 intrinsics with hardware gathers, chosen at run time.
    #[cfg(target_arch = "x86_64")]
    Avx2,
    /// AVX-512 intrinsics, two voxel rows per register (and 16 pixels' band walks at once).
    #[cfg(target_arch = "x86_64")]
    Avx512,
}

/// The kernel for this machine, chosen once: the widest the CPU has, unless
/// `SEMRECON_FUSION_SIMD=avx2|portable` forces a lower one (all give the same bits).
fn kernel() -> Kernel {
    static KERNEL: OnceLock<Kernel> = OnceLock::new();
    *KERNEL.get_or_init(|| {
        #[cfg(target_arch = "x86_64")]
        {
            let forced = std::env::var("SEMRECON_FUSION_SIMD").unwrap_or_default();
            let avx2 = is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma");
            if forced != "portable" && forced != "avx2" && avx2 && is_x86_feature_detected!("avx512f") {
                return Kernel::Avx512;
            }
            if forced != "portable" && avx2 {
                return Kernel::Avx2;
            }
        }
        Kernel::Portable
    })
}

/// Integrates one chunk with `kernel`; `fixed`: the band is the full truncation everywhere.
fn integrate_chunk_with(kernel: Kernel, chunk: &mut Chunk, view: &FrameView, fixed: bool) -> ChunkOutcome {
    match (kernel, fixed) {
        (Kernel::Portable, false) => integrate_chunk::<true>(chunk, view),
        (Kernel::Portable, true) => integrate_chunk::<false>(chunk, view),
        // SAFETY: `Kernel::Avx2` is only chosen where the CPU has AVX2 and FMA, and
        // `integrate_chunks_with` only for frames below 2^24 pixels.
        #[cfg(target_arch = "x86_64")]
        (Kernel::Avx2, false) => unsafe { avx2::integrate_chunk::<true>(chunk, view) },
        #[cfg(target_arch = "x86_64")]
        (Kernel::Avx2, true) => unsafe { avx2::integrate_chunk::<false>(chunk, view) },
        // SAFETY: `Kernel::Avx512` is only chosen where the CPU has AVX-512F, and
        // `integrate_chunks_with` only for frames below 2^24 pixels.
        #[cfg(target_arch = "x86_64")]
        (Kernel::Avx512, false) => unsafe { avx512::integrate_chunk::<true>(chunk, view) },
        #[cfg(target_arch = "x86_64")]
        (Kernel::Avx512, true) => unsafe { avx512::integrate_chunk::<false>(chunk, view) },
    }
}

/// What one integration did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct IntegrationStats {
    /// Chunks visited (the selection).
    pub visited_chunks: usize,
    /// Chunks allocated for this frame and kept.
    pub new_chunks: usize,
    /// Chunks allocated for this frame and freed again (no voxel in the truncation band).
    pub freed_chunks: usize,
    /// Chunks with at least one updated voxel.
    pub updated_chunks: usize,
    /// Chunks with at least one voxel updated from within the truncation band.
    pub band_chunks: usize,
    /// Voxel updates.
    pub updated_voxels: usize,
}

impl std::ops::AddAssign for IntegrationStats {
    /// Sums the counts of several integrations (one frame fused in several passes).
    fn add_assign(&mut self, s: Self) {
        self.visited_chunks += s.visited_chunks;
        self.new_chunks += s.new_chunks;
        self.freed_chunks += s.freed_chunks;
        self.updated_chunks += s.updated_chunks;
        self.band_chunks += s.band_chunks;
        self.updated_voxels += s.updated_voxels;
    }
}

/// Everything a per-chunk integration task reads, precomputed once per frame.
struct FrameView<'a> {
    depth: &'a [f32],
    color: &'a [[u8; 3]],
    k: Intrinsics,
    /// Rotation columns and translation of `camera_from_world`.
    rot: [Vec3A; 3],
    trans: Vec3A,
    voxel_size: f32,
    /// The widest band, the unit of the stored distances (metres).
    truncation: f32,
    band: BandModel,
    min_depth: f32,
    max_depth: f32,
    weight_cap: u16,
    /// Whether this is a colour frame ([`TsdfConfig::color_every`]): every voxel near the
    /// surface takes the frame's colour; otherwise only those with fewer than
    /// [`COLOR_WARMUP`] colour observations.
    color_all: bool,
    /// Colour is blended only where `-color_band <= sdf < color_band` (truncation units;
    /// [`TsdfConfig::color_band_voxels`]).
    color_band: f32,
    /// Observations from the surface up to this many bands behind a voxel are clamped to one
    /// band behind ([`TsdfConfig::behind_band`]); beyond, skipped.
    behind: f32,
    /// Factor on each observation's weight: 1 for a frame, n where one frame stands for n
    /// similar ones (loop closure re-fusing a subsample). Multiplying by 1 is exact, so the
    /// default changes no bit.
    obs_weight: f32,
}

impl<'a> FrameView<'a> {
    /// The view of `frame` seen from `world_from_camera`, fused into a map of `config`, each
    /// observation weighing `obs_weight` frames.
    fn new(frame: &'a Frame, world_from_camera: Affine3A, config: &TsdfConfig, obs_weight: f32) -> Self {
        let camera_from_world = world_from_camera.inverse();
        Self {
            depth: &frame.depth,
            color: &frame.color,
            k: frame.intrinsics,
            rot: [camera_from_world.matrix3.x_axis, camera_from_world.matrix3.y_axis, camera_from_world.matrix3.z_axis],
            trans: camera_from_world.translation,
            voxel_size: config.voxel_size,
            truncation: config.truncation(),
            band: config.band_model(),
            min_depth: config.min_depth,
            max_depth: config.max_depth,
            weight_cap: (config.max_weight * WEIGHT_SCALE).round().clamp(1.0, u16::MAX as f32) as u16,
            color_all: config.is_color_frame(frame.index),
            color_band: config.color_band(),
            behind: config.behind_band,
            obs_weight,
        }
    }
}

/// Per-chunk outcome of an integration task.
#[derive(Clone, Copy, Default)]
struct ChunkOutcome {
    updated: u32,
    near: bool,
}

impl TsdfMap {
    /// Chunks within the truncation band of `frame`'s valid depth pixels, seen from
    /// `world_from_camera`; sorted (z, y, x) and without duplicates.
    pub fn select_chunks(&self, frame: &Frame, world_from_camera: Affine3A) -> Result<Vec<ChunkKey>> {
        check_frame(frame, &world_from_camera)?;
        let view = SelectionView::new(&self.config, frame, world_from_camera);
        let kernel = kernel();
        let rows: Vec<usize> = (0..view.height).step_by(view.stride).collect();
        let blocks: Vec<Vec<ChunkKey>> = rows
            .par_chunks(16)
            .map(|rows| {
                let mut out = Candidates::new(view.max_steps);
                for &v in rows {
                    select_row_with(kernel, &view, v, &mut out);
                }
                out.keys
            })
            .collect();
        Ok(sorted_unique(blocks))
    }

    /// Fuses `frame` seen from `world_from_camera`: chunk selection, then integration.
    pub fn integrate(&mut self, frame: &Frame, world_from_camera: Affine3A) -> Result<IntegrationStats> {
        let keys = self.select_chunks(frame, world_from_camera)?;
        self.integrate_chunks(frame, world_from_camera, &keys)
    }

    /// Fuses `frame` into the given chunks only (allocating those that are missing). `keys`
    /// may come from [`TsdfMap::select_chunks`] or from [`TsdfMap::chunks_touched_by`] when
    /// re-integrating; duplicates are ignored.
    pub fn integrate_chunks(
        &mut self,
        frame: &Frame,
        world_from_camera: Affine3A,
        keys: &[ChunkKey],
    ) -> Result<IntegrationStats> {
        let id = frame_id(frame.index);
        self.integrate_chunks_with(kernel(), frame, world_from_camera, keys, 1.0, (id, id))
    }

    /// [`TsdfMap::integrate_chunks`] with each observation weighing `weight` times its usual
    /// weight (still capped by [`TsdfConfig::max_weight`]) and standing for the frames
    /// `frames` (recorded in the chunks it changes, [`crate::Chunk::frames`]): one frame, or
    /// an average of several, standing for `weight` similar ones, as when far surfaces are
    /// fused from groups of frames or loop closure re-fuses runs of stored frames. `weight` 1
    /// and `frames` the frame's own index give the same bits as
    /// [`TsdfMap::integrate_chunks`].
    ///
    /// # Errors
    /// [`ReconError::InvalidConfig`] when `weight` is not finite and positive or `frames` is
    /// empty; what [`TsdfMap::integrate_chunks`] returns.
    pub fn integrate_chunks_weighted(
        &mut self,
        frame: &Frame,
        world_from_camera: Affine3A,
        keys: &[ChunkKey],
        weight: f32,
        frames: std::ops::RangeInclusive<usize>,
    ) -> Result<IntegrationStats> {
        if !(weight.is_finite() && weight > 0.0) {
            return Err(ReconError::InvalidConfig(format!("observation weight {weight} must be finite and positive")));
        }
        if frames.is_empty() {
            return Err(ReconError::InvalidConfig(format!(
                "the frames an observation stands for, {frames:?}, are none"
            )));
        }
        let span = (frame_id(*frames.start()), frame_id(*frames.end()));
        self.integrate_chunks_with(kernel(), frame, world_from_camera, keys, weight, span)
    }

    /// The integration with the given kernel (tests compare the kernels): the observation
    /// weighs `obs_weight` and stands for the frames `span` (inclusive).
    fn integrate_chunks_with(
        &mut self,
        kernel: Kernel,
        frame: &Frame,
        world_from_camera: Affine3A,
        keys: &[ChunkKey],
        obs_weight: f32,
        span: (u32, u32),
    ) -> Result<IntegrationStats> {
        check_frame(frame, &world_from_camera)?;
        // The intrinsics kernels form pixel indices in f32, exact below 2^24 pixels only, and
        // gather without bounds checks: larger images take the portable kernel.
        let kernel = if frame.intrinsics.pixel_count() >= 1 << 24 { Kernel::Portable } else { kernel };
        let mut stats = IntegrationStats::default();
        // The camera came back to spilled chunks: read them (and their neighbours, which
        // meshing will read) back before anything touches them.
        self.restore_spilled(keys)?;
        let old_len = self.chunks.len();
        let unsorted = self.allocate_all(keys);
        // Chunks allocated above are the new ones.
        let slots = sorted_unique_slots(&unsorted, self.chunks.len());
        stats.visited_chunks = slots.len();
        if slots.is_empty() {
            return Ok(stats);
        }
        let view = FrameView::new(frame, world_from_camera, &self.config, obs_weight);
        let mut targets = select_mut(&mut self.chunks, &slots);
        // A fixed band (clamped to exactly 1 truncation) skips the band arithmetic.
        let fixed = view.band.min_relative >= 1.0;
        let revision = self.next_revision;
        self.next_revision += 1;
        // The per-chunk bookkeeping happens in the tasks too: done afterwards in one loop it
        // would chase every chunk's record and frame list again, on one thread.
        // `targets` and `outcomes` are in slab order, like the sorted `slots`.
        let outcomes: Vec<ChunkOutcome> = targets
            .par_iter_mut()
            .zip(&slots)
            .map(|(chunk, &slot)| {
                let is_new = slot as usize >= old_len;
                let out = integrate_chunk_with(kernel, chunk, &view, fixed);
                chunk.touched = chunk.touched.max(span.1);
                // A new chunk without a voxel in the band is freed below: no bookkeeping.
                let kept = !is_new || out.near;
                if out.updated > 0 && kept {
                    chunk.dirty = true;
                    chunk.revision = revision;
                    chunk.frames.push_span(span.0, span.1);
                }
                out
            })
            .collect();
        drop(targets);
        let mut to_free = Vec::new();
        for (&slot, out) in slots.iter().zip(&outcomes) {
            let is_new = slot as usize >= old_len;
            if is_new && !out.near {
                to_free.push(slot);
                continue;
            }
            stats.new_chunks += is_new as usize;
            stats.band_chunks += out.near as usize;
            if out.updated > 0 {
                stats.updated_chunks += 1;
                stats.updated_voxels += out.updated as usize;
            }
        }
        stats.freed_chunks = to_free.len();
        self.free(to_free);
        Ok(stats)
    }
}

/// A frame index as chunks record it (saturating: a stream past 2^32 frames records its
/// last frames as one).
fn frame_id(index: usize) -> u32 {
    index.min(u32::MAX as usize) as u32
}

/// `slots` (positions in a slab of `len` chunks, any order, repeats allowed) sorted and
/// without repeats, through a bitset over the slab: a bit per chunk is a few kilobytes to
/// clear, less than sorting thousands of slots.
fn sorted_unique_slots(slots: &[u32], len: usize) -> Vec<u32> {
    let mut words = vec![0u64; len.div_ceil(64)];
    for &s in slots {
        words[s as usize / 64] |= 1 << (s % 64);
    }
    let mut sorted = Vec::with_capacity(slots.len());
    for (w, &word) in words.iter().enumerate() {
        let mut word = word;
        while word != 0 {
            sorted.push((w * 64) as u32 + word.trailing_zeros());
            word &= word - 1;
        }
    }
    sorted
}

/// `&mut` to the chunks at the sorted, unique positions `slots`, in that order: the slab is
/// split at each of them, so the cost follows the selection, not the map.
fn select_mut<'a>(chunks: &'a mut [Chunk], slots: &[u32]) -> Vec<&'a mut Chunk> {
    let mut targets = Vec::with_capacity(slots.len());
    let mut rest = chunks;
    let mut start = 0;
    for &slot in slots {
        let Some((chunk, tail)) =
            std::mem::take(&mut rest).get_mut(slot as usize - start..).and_then(<[Chunk]>::split_first_mut)
        else {
            break;
        };
        targets.push(chunk);
        rest = tail;
        start = slot as usize + 1;
    }
    debug_assert_eq!(targets.len(), slots.len(), "slots sorted, unique and in the slab");
    targets
}

/// Everything chunk selection reads, precomputed once per frame.
///
/// Coordinates are in chunk units shifted so that chunk k spans [k, k + 1): voxel centres
/// sit at multiples of the voxel size, so a chunk spans voxels [8k - 0.5, 8k + 7.5).
/// [`SELECTION_OFFSET`] keeps coordinates positive so that truncation is floor (one
/// instruction, where `floor` is a library call without SSE4.1).
struct SelectionView<'a> {
    depth: &'a [f32],
    k: Intrinsics,
    width: usize,
    height: usize,
    stride: usize,
    /// `world_from_camera`'s rotation in chunk units.
    rot: glam::Mat3A,
    /// The camera centre in shifted chunk units.
    origin: Vec3A,
    trunc: f32,
    inv_voxel: f32,
    band: BandModel,
    min_depth: f32,
    max_depth: f32,
    /// Most band samples per pixel, minus one.
    max_steps: usize,
    /// `1 / max(n, 1)` for `n` in `0..=max_steps`.
    inv_steps: Vec<f32>,
}

/// 2^14 chunks (655 m at 5 mm voxels) either side of the origin, at 1/64 voxel precision;
/// points beyond are not selected.
const SELECTION_OFFSET: f32 = (1 << 14) as f32;

impl<'a> SelectionView<'a> {
    fn new(c: &TsdfConfig, frame: &'a Frame, world_from_camera: Affine3A) -> Self {
        let k = frame.intrinsics;
        let trunc = c.truncation();
        let inv_chunk = 1.0 / c.chunk_size();
        // Samples along the band no further apart than two voxels, so that the walk cannot
        // step over a chunk (8 voxels) except at a corner clipped by less than a voxel.
        let max_steps = (trunc / c.voxel_size).ceil().max(1.0) as usize;
        Self {
            depth: &frame.depth,
            k,
            width: k.width as usize,
            height: k.height as usize,
            stride: c.selection_stride,
            rot: world_from_camera.matrix3 * inv_chunk,
            origin: (world_from_camera.translation + Vec3A::splat(0.5 * c.voxel_size)) * inv_chunk
                + Vec3A::splat(SELECTION_OFFSET),
            trunc,
            inv_voxel: 1.0 / c.voxel_size,
            band: c.band_model(),
            min_depth: c.min_depth,
            max_depth: c.max_depth,
            max_steps,
            // `1 / steps` by table: a division and a `ceil` (a library call without SSE4.1)
            // per pixel cost as much as the band itself.
            inv_steps: (0..=max_steps).map(|n| 1.0 / n.max(1) as f32).collect(),
        }
    }

    /// The band walk of pixel `(u, v)` with valid depth `d`: the first sample, the step
    /// between samples (shifted chunk units) and the number of steps.
    #[inline(always)]
    fn band_walk(&self, row_ray: Vec3A, u: usize, d: f32) -> (Vec3A, Vec3A, usize) {
        // This pixel's band, the one integration applies to its voxels.
        let mu = self.band.relative(d) * self.trunc;
        let x = mu * self.inv_voxel;
        let whole = x as usize;
        let steps = (whole + ((whole as f32) < x) as usize).clamp(1, self.max_steps);
        let ray = self.rot.x_axis * ((u as f32 - self.k.cx) / self.k.fx) + row_ray;
        let p_near = self.origin + ray * (d - mu);
        let step = ray * (2.0 * mu * self.inv_steps[steps]);
        (p_near, step, steps)
    }

    /// Ray (camera z = 1) in chunk units without its x part, for image row `v`.
    #[inline(always)]
    fn row_ray(&self, v: usize) -> Vec3A {
        self.rot.y_axis * ((v as f32 - self.k.cy) / self.k.fy) + self.rot.z_axis
    }
}

/// Chunk keys collected by one task, most repeats filtered out on the way.
///
/// Neighbouring pixels cross the same chunks: `last_*[s]` hold the key sample `s` of the
/// previous pixel saw (as x, y and z planes, which the AVX2 walk loads as vectors), and a
/// small direct-mapped table of recent keys catches most of the other repeats, so that the
/// merge sees few duplicates (it removes the rest).
struct Candidates {
    last_x: Vec<i32>,
    last_y: Vec<i32>,
    last_z: Vec<i32>,
    recent: Box<[ChunkKey; Self::RECENT]>,
    keys: Vec<ChunkKey>,
}

impl Candidates {
    const RECENT: usize = 512;

    fn new(max_steps: usize) -> Self {
        // Rounded up to whole 8-lane groups for the AVX2 walk.
        let n = (max_steps + 1).div_ceil(8) * 8;
        Self {
            last_x: vec![i32::MAX; n],
            last_y: vec![i32::MAX; n],
            last_z: vec![i32::MAX; n],
            recent: Box::new([ChunkKey::MAX; Self::RECENT]),
            keys: Vec::new(),
        }
    }

    #[inline(always)]
    fn push(&mut self, key: ChunkKey) {
        let h = (key.x as u32).wrapping_mul(0x9e37_79b1)
            ^ (key.y as u32).wrapping_mul(0x85eb_ca77)
            ^ (key.z as u32).wrapping_mul(0xc2b2_ae3d);
        let slot = &mut self.recent[(h >> 23) as usize % Self::RECENT];
        if *slot != key {
            *slot = key;
            self.keys.push(key);
        }
    }
}

/// Selects the chunks of image row `v` with `kernel`.
fn select_row_with(kernel: Kernel, view: &SelectionView, v: usize, out: &mut Candidates) {
    match kernel {
        Kernel::Portable => select_row(view, v, out),
        // SAFETY: `Kernel::Avx2` is only chosen where the CPU has AVX2 and FMA.
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx2 => unsafe { avx2::select_row(view, v, out) },
        // SAFETY: `Kernel::Avx512` is only chosen where the CPU has AVX-512F.
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx512 => unsafe { avx512::select_row(view, v, out) },
    }
}

/// Walks the band of every sampled valid pixel of image row `v` and collects the chunks
/// its samples fall into.
fn select_row(view: &SelectionView, v: usize, out: &mut Candidates) {
    let offset = ChunkKey::splat(SELECTION_OFFSET as i32);
    let row_ray = view.row_ray(v);
    let depth = &view.depth[v * view.width..(v + 1) * view.width];
    for u in (0..view.width).step_by(view.stride) {
        let d = depth[u];
        if !(d >= view.min_depth && d <= view.max_depth) {
            continue;
        }
        let (p_near, step, steps) = view.band_walk(row_ray, u, d);
        for s in 0..=steps {
            let p = p_near + step * s as f32;
            if p.cmplt(Vec3A::ZERO).any() || p.cmpge(Vec3A::splat(2.0 * SELECTION_OFFSET)).any() {
                continue;
            }
            let key = p.as_ivec3() - offset;
            if key != ChunkKey::new(out.last_x[s], out.last_y[s], out.last_z[s]) {
                (out.last_x[s], out.last_y[s], out.last_z[s]) = (key.x, key.y, key.z);
                out.push(key);
            }
        }
    }
}

/// The keys of all blocks, sorted (z, y, x) without duplicates: through a bitset over their
/// bounding box when that is small (one bit per chunk, read back in order), by sorting
/// otherwise.
fn sorted_unique(blocks: Vec<Vec<ChunkKey>>) -> Vec<ChunkKey> {
    const MAX_BITS: usize = 1 << 24;
    let mut lo = ChunkKey::MAX;
    let mut hi = ChunkKey::MIN;
    for key in blocks.iter().flatten() {
        lo = lo.min(*key);
        hi = hi.max(*key);
    }
    if lo.cmpgt(hi).any() {
        return Vec::new();
    }
    let size = (hi - lo).as_i64vec3() + 1;
    let bits = size.x.saturating_mul(size.y).saturating_mul(size.z);
    if bits > MAX_BITS as i64 {
        let mut keys: Vec<ChunkKey> = blocks.into_iter().flatten().collect();
        keys.sort_unstable_by_key(|k| key_order(*k));
        keys.dedup();
        return keys;
    }
    let (nx, ny) = (size.x as usize, size.y as usize);
    let mut words = vec![0u64; (bits as usize).div_ceil(64)];
    let mut count = 0;
    for key in blocks.iter().flatten() {
        let l = (*key - lo).as_uvec3();
        let i = (l.z as usize * ny + l.y as usize) * nx + l.x as usize;
        let bit = 1u64 << (i % 64);
        count += (words[i / 64] & bit == 0) as usize;
        words[i / 64] |= bit;
    }
    let mut keys = Vec::with_capacity(count);
    for (w, &word) in words.iter().enumerate() {
        let mut word = word;
        while word != 0 {
            let i = w * 64 + word.trailing_zeros() as usize;
            word &= word - 1;
            let (x, rest) = (i % nx, i / nx);
            keys.push(lo + ChunkKey::new(x as i32, (rest % ny) as i32, (rest / ny) as i32));
        }
    }
    keys
}

/// Rejects frames whose buffers do not match their camera and non-finite poses; depth values
/// themselves are never an error.
fn check_frame(frame: &Frame, world_from_camera: &Affine3A) -> Result<()> {
    let n = frame.intrinsics.pixel_count();
    let bad = |message: String| Err(ReconError::InvalidFrame { index: frame.index, message });
    if frame.depth.len() != n {
        return bad(format!("depth has {} pixels, the camera {n}", frame.depth.len()));
    }
    if !frame.color.is_empty() && frame.color.len() != n {
        return bad(format!("colour has {} pixels, the camera {n}", frame.color.len()));
    }
    if !world_from_camera.is_finite() {
        return bad("world_from_camera is not finite".into());
    }
    Ok(())
}

impl FrameView<'_> {
    /// The camera-frame centre of chunk `key`'s first voxel and the camera-frame steps of one
    /// voxel along the map's x, y and z: every kernel walks a chunk's centres from these.
    fn chunk_axes(&self, key: ChunkKey) -> [Vec3A; 4] {
        let origin = (key * CHUNK_SIDE as i32).as_vec3() * self.voxel_size;
        let base = self.rot[0] * origin.x + self.rot[1] * origin.y + self.rot[2] * origin.z + self.trans;
        [base, self.rot[0] * self.voxel_size, self.rot[1] * self.voxel_size, self.rot[2] * self.voxel_size]
    }
}

/// Updates every voxel of one chunk from the frame.
///
/// One row of 8 voxels (along x) per step, as 8-lane SIMD (`wide::f32x8`: AVX where the
/// build enables it, two SSE registers otherwise): project the 8 centres, gather their 8
/// depths, compute all 8 updates and keep those of valid observations with a blend instead
/// of branches. Colours, needed only inside the truncation band, follow per voxel. The
/// arithmetic is that of `Voxel::fuse` lane for lane (same operations, same rounding), so
/// results do not depend on how rows are split into registers.
///
/// `DEPTH_BAND` false: the band is the full truncation for every depth (the band model
/// clamps to exactly 1 then, so both forms give the same bits).
fn integrate_chunk<const DEPTH_BAND: bool>(chunk: &mut Chunk, f: &FrameView) -> ChunkOutcome {
    const N: usize = CHUNK_SIDE;
    let [base, dx, dy, dz] = f.chunk_axes(chunk.key);
    let splat = f32x8::splat;
    let steps = f32x8::new([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]);
    let (step_x, step_y, step_z) = (steps * splat(dx.x), steps * splat(dx.y), steps * splat(dx.z));
    let (fx, fy, cx, cy) = (splat(f.k.fx), splat(f.k.fy), splat(f.k.cx), splat(f.k.cy));
    let (wf, hf) = (splat(f.k.width as f32 - 0.5), splat(f.k.height as f32 - 0.5));
    let width = splat(f.k.width as f32);
    let (min_d, max_d) = (splat(f.min_depth), splat(f.max_depth));
    let inv_trunc = splat(1.0 / f.truncation);
    let (band_c, band_q, band_min) = (splat(f.band.constant), splat(f.band.quadratic), splat(f.band.min_relative));
    let noise_offset = splat(NOISE_OFFSET);
    let (zero, half, one) = (f32x8::ZERO, f32x8::HALF, f32x8::ONE);
    let cap = splat(f.weight_cap as f32);
    let color_band = splat(f.color_band);
    let behind = splat(f.behind);
    let has_color = !f.color.is_empty();
    let block = &mut *chunk.voxels;
    let (tsdf_rows, _) = block.tsdf.as_chunks_mut::<N>();
    let (weight_rows, _) = block.weight.as_chunks_mut::<N>();
    let (color_rows, _) = block.color.as_chunks_mut::<N>();
    let mut updated = 0u32;
    let mut near_any = false;
    let mut signs = SignSummary::default();
    for r in 0..N * N {
        let (y, z) = ((r % N) as f32, (r / N) as f32);
        let row = base + dy * y + dz * z;
        let pz = splat(row.z) + step_z;
        let inv_z = one / pz;
        let u = fx * (splat(row.x) + step_x) * inv_z + cx;
        let v = fy * (splat(row.y) + step_y) * inv_z + cy;
        let inside = pz.simd_gt(zero) & u.simd_ge(-half) & u.simd_lt(wf) & v.simd_ge(-half) & v.simd_lt(hf);
        // Pixel index in f32 (exact below 2^24 pixels); off-image voxels read pixel 0 and
        // stay masked by `inside`.
        let pix_f = (v + half).fast_trunc_int().round_float() * width + (u + half).fast_trunc_int().round_float();
        let pix = inside.select(pix_f, zero).fast_trunc_int().to_array();
        // `from_fn`, not `map`: `map` stays an out-of-line call here, a fifth of the kernel.
        let d = f32x8::new(std::array::from_fn(|l| f.depth[pix[l] as usize]));
        // Signed distance and this observation's band, in truncation units.
        let sdf = (d - pz) * inv_trunc;
        let mu = if DEPTH_BAND {
            let e = d - noise_offset;
            (band_c + band_q * (e * e)).fast_max(band_min).fast_min(one)
        } else {
            one
        };
        let tsdf_row = &mut tsdf_rows[r];
        let weight_row = &mut weight_rows[r];
        let t_old = i32x8::from_i16x8(i16x8::new(*tsdf_row)).round_float();
        let w_old_q = i32x8::from_u16x8(u16x8::new(*weight_row)).round_float();
        let valid = inside & d.simd_ge(min_d) & d.simd_le(max_d) & sdf.simd_ge(-mu * behind);
        let valid_bits = valid.to_bitmask();
        let (t_now, w_now) = if valid_bits != 0 {
            let obs = sdf.fast_min(mu).fast_max(-mu);
            let w_obs = valid.select((one / (d * d)).fast_min(splat(4.0)) * splat(f.obs_weight), zero);
            let w_old = w_old_q * splat(1.0 / WEIGHT_SCALE);
            let w_sum = w_old + w_obs;
            let inv = one / w_sum.fast_max(splat(1e-30));
            let a = w_old * inv;
            let b = w_obs * inv;
            let t = t_old * a + obs * (b * splat(TSDF_SCALE));
            let t_new = valid.select(t.round(), t_old);
            let w_q = (w_sum * splat(WEIGHT_SCALE)).round().fast_max(one).fast_min(cap);
            let w_new = valid.select(w_q, w_old_q);
            // Values are integral and in range: the conversions are exact.
            *tsdf_row = i16x8::from_i32x8_truncate(t_new.fast_trunc_int()).to_array();
            *weight_row = i16x8::from_i32x8_truncate(w_new.fast_trunc_int()).to_array().map(|w| w as u16);
            updated += valid_bits.count_ones();
            let near = valid & sdf.simd_lt(mu);
            if near.any() {
                near_any = true;
                let colored = near & sdf.simd_lt(color_band) & sdf.simd_ge(-color_band);
                if has_color {
                    let mut bits = colored.to_bitmask();
                    while bits != 0 {
                        let x = bits.trailing_zeros() as usize;
                        // Off colour frames only voxels still warming up take a colour.
                        if f.color_all || color_rows[r][x][3] < COLOR_WARMUP {
                            blend_color(&mut color_rows[r][x], f.color[pix[x] as usize]);
                        }
                        bits &= bits - 1;
                    }
                }
            }
            (t_new, w_new)
        } else {
            (t_old, w_old_q)
        };
        let observed = w_now.simd_gt(zero);
        signs.add_row(r, (observed & t_now.simd_lt(zero)).to_bitmask(), (observed & t_now.simd_ge(zero)).to_bitmask());
    }
    chunk.signs = signs.bits();
    ChunkOutcome { updated, near: near_any }
}

#[cfg(test)]
mod tests;
