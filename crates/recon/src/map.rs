//! The voxel-hashed TSDF map: a truncated signed-distance field stored only near observed
//! surfaces, in 8x8x8-voxel chunks found through a hash map keyed by integer chunk
//! coordinates. Dense grids would need gigabytes for a room at 5 mm; chunks near surfaces
//! need megabytes, and a chunk is the unit of parallel fusion, meshing and re-integration.
//!
//! Grid convention: voxel `v` (integer, world frame) has its centre at `v * voxel_size`;
//! chunk `k` holds voxels `8k .. 8k + 7` on every axis; inside a chunk voxel `(x, y, z)`
//! is stored at `x + 8 y + 64 z`.
//!
//! Each voxel is 8 bytes (see [`Voxel`]): the signed distance in steps of 1/2047 of the
//! truncation distance in an `i16`, the weight in steps of 1/16 in a `u16`, an sRGB colour
//! and its observation count, so a chunk's voxels are exactly 4 KiB. The steps are as coarse
//! as accuracy allows (issue 20): a step of the distance is 0.024 mm at 5 mm voxels and a
//! truncation of 10 voxels, far under sensor noise, and the finer steps before (1/32767,
//! 1/256) only stored noise, which packed chunks (submodule `compressed`) paid for in bits:
//! packed chunks are a sixth smaller, mesh accuracy on rendered scans 1.37 -> 1.38 mm
//! (docs/benchmarks_log.md, "A compact voxel and denser packing").
//!
//! Chunks fusion has left alone can be packed in memory (exactly but for distances far from
//! the surface, [`TsdfConfig::packed_far_step_voxels`]) or spilled to a file (submodules
//! `compressed`, `storage`, `memory`, `spill`); spilling changes no voxel of packing.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use glam::{IVec3, Vec3};
use rayon::prelude::*;

use crate::error::Result;

mod compressed;
mod config;
mod memory;
mod rice;
mod spill;
mod storage;
mod subset;

pub use compressed::PackError;
pub use config::TsdfConfig;
pub(crate) use config::{depth_noise, BandModel, COLOR_WARMUP, NOISE_OFFSET};
pub use memory::{Compaction, MapMemory};
pub use spill::{SpillError, SpillFile};
use storage::VoxelStore;

/// Voxels along one side of a chunk.
pub const CHUNK_SIDE: usize = 8;
/// Voxels in one chunk.
pub const CHUNK_VOXELS: usize = CHUNK_SIDE * CHUNK_SIDE * CHUNK_SIDE;

/// Integer coordinates of a chunk (chunk `k` covers voxels `8k .. 8k + 7` per axis).
pub type ChunkKey = IVec3;

/// Fixed-point scale of [`Voxel`] weights: a stored weight of 16 is a weight of 1. One
/// observation weighs at least 1/25 (5 m, the farthest fused depth), above half a step, so
/// every observation still counts (a far one a little more than its weight); the cap of 64
/// is 1024 steps.
pub const WEIGHT_SCALE: f32 = 16.0;
/// Scale of the quantised truncated signed distance: 2047 is +1 truncation (12 bits with the
/// sign, stored in an `i16`).
pub const TSDF_SCALE: f32 = 2047.0;

/// One voxel's state, 8 bytes (a value: chunks store the fields in separate arrays).
///
/// A weight of 0 means never observed: such voxels carry no distance and are masked by
/// meshing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(C)]
pub struct Voxel {
    /// Truncated signed distance in units of the truncation distance, times [`TSDF_SCALE`].
    pub(crate) tsdf: i16,
    /// Fusion weight times [`WEIGHT_SCALE`].
    pub(crate) weight: u16,
    /// Weighted mean sRGB colour of the observations.
    pub(crate) color: [u8; 3],
    /// Number of colour observations, saturating at 255 (colour has its own count because
    /// free-space observations update the distance but not the colour).
    pub(crate) color_count: u8,
}

impl Voxel {
    /// Signed distance in units of the truncation distance, in -1..=1 (positive in front of
    /// the surface, toward the camera).
    #[inline]
    pub fn tsdf(&self) -> f32 {
        self.tsdf as f32 * (1.0 / TSDF_SCALE)
    }

    /// Fusion weight (0 when never observed).
    #[inline]
    pub fn weight(&self) -> f32 {
        self.weight as f32 * (1.0 / WEIGHT_SCALE)
    }

    /// Weighted mean colour of the observations.
    #[inline]
    pub fn color(&self) -> [u8; 3] {
        self.color
    }

    /// Whether any observation reached this voxel.
    #[inline]
    pub fn is_observed(&self) -> bool {
        self.weight > 0
    }

    /// Folds one observation into the running weighted mean.
    ///
    /// `tsdf` is in -1..=1, `weight` > 0, `weight_cap` is the cap in stored units; the colour
    /// is only updated when `color` is given (observations far in front of the surface see
    /// free space, not the surface's colour).
    /// Fusion itself runs a vectorised copy of this arithmetic; this scalar form is its
    /// specification, used by tests.
    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) fn fuse(&mut self, tsdf: f32, weight: f32, color: Option<[u8; 3]>, weight_cap: u16) {
        let w_old = self.weight as f32 * (1.0 / WEIGHT_SCALE);
        let w_sum = w_old + weight;
        let inv = 1.0 / w_sum;
        let a = w_old * inv;
        let b = weight * inv;
        let t = self.tsdf as f32 * a + tsdf * (b * TSDF_SCALE);
        self.tsdf = round_half_away(t) as i16;
        if let Some(color) = color {
            let mut c = [self.color[0], self.color[1], self.color[2], self.color_count];
            blend_color(&mut c, color);
            self.color = [c[0], c[1], c[2]];
            self.color_count = c[3];
        }
        // At least one unit so that an observed voxel never reads as unobserved.
        let w_new = round_half_away(w_sum * WEIGHT_SCALE).max(1.0);
        self.weight = w_new.min(weight_cap as f32) as u16;
    }
}

/// Rounds half away from zero exactly as `wide`'s SIMD `round` does (`trunc(|x| + 0.5)`
/// with the sign restored; the largest float below 0.5 rounds to 0), so that the scalar and
/// the SIMD fusion agree bit for bit. Inputs here are below 2^23 in magnitude.
#[inline]
pub(crate) fn round_half_away(x: f32) -> f32 {
    let a = x.abs();
    let r = if a == 0.5f32.next_down() { 0.0 } else { (a + 0.5).trunc() };
    r.copysign(x)
}

/// Which signs a chunk's observed voxels have, in the whole chunk and on its three lower
/// faces (local x = 0, y = 0, z = 0): meshing reads a neighbour only through the lower face
/// that touches the chunk being meshed, so these bits let it skip chunks whose cells cannot
/// hold a surface without gathering any voxel.
///
/// Bits: 0 negative / 1 non-negative anywhere; 2/3 on the x = 0 face; 4/5 on y = 0; 6/7 on
/// z = 0.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct SignSummary {
    neg: u32,
    pos: u32,
    bits: u8,
}

impl SignSummary {
    /// Adds row `r` (`y = r % 8`, `z = r / 8`) with per-x bit masks of negative and
    /// non-negative observed voxels.
    #[inline]
    pub(crate) fn add_row(&mut self, r: usize, neg: u32, pos: u32) {
        self.neg |= neg;
        self.pos |= pos;
        let pair = |n: bool, p: bool| n as u8 | (p as u8) << 1;
        self.bits |= pair(neg & 1 != 0, pos & 1 != 0) << 2;
        if r.is_multiple_of(CHUNK_SIDE) {
            self.bits |= pair(neg != 0, pos != 0) << 4;
        }
        if r / CHUNK_SIDE == 0 {
            self.bits |= pair(neg != 0, pos != 0) << 6;
        }
    }

    /// The summary byte.
    pub(crate) fn bits(&self) -> u8 {
        self.bits | (self.neg != 0) as u8 | ((self.pos != 0) as u8) << 1
    }
}

/// Folds colour observation `obs` into `c = [r, g, b, count]`: a plain running mean over the
/// first 255 observations, then an exponential one.
/// Fixed point with reciprocals from a table: no division and no float conversion.
#[inline(always)]
pub(crate) fn blend_color(c: &mut [u8; 4], obs: [u8; 3]) {
    let n = c[3] as u32;
    let recip = RECIPROCALS[c[3] as usize];
    for k in 0..3 {
        c[k] = (((c[k] as u32 * n + obs[k] as u32) * recip + (1 << 15)) >> 16) as u8;
    }
    c[3] = c[3].saturating_add(1);
}

/// `RECIPROCALS[n] = round(2^16 / (n + 1))`: the running mean's divisor in 16-bit fixed point.
pub(crate) const RECIPROCALS: [u32; 256] = {
    let mut t = [0u32; 256];
    let mut n = 0;
    while n < 256 {
        t[n] = ((1u32 << 16) + (n as u32).div_ceil(2)) / (n as u32 + 1);
        n += 1;
    }
    t
};

/// Contiguous runs of frame indices, compact because a scan touches a chunk in runs.
///
/// At most [`FrameRuns::MAX_RUNS`] runs are kept: a long scan that comes back to a place
/// again and again would otherwise add a run per visit, and map memory would grow with the
/// frame count instead of with the surface. Beyond the cap the two runs with the smallest
/// gap between them merge, so the runs become a superset of the frames (re-integrating a
/// frame that did not touch the chunk only adds its observations).
///
/// The runs live inline (65 bytes), not on the heap: fusion records a frame in every chunk
/// it changes, and a heap list cost a cache miss per chunk and frame, on the critical path
/// of every integration task.
#[derive(Debug, Clone, Default)]
pub struct FrameRuns {
    /// `runs[..len]` are the runs; entries beyond are unused.
    runs: [(u32, u32); Self::MAX_RUNS],
    len: u8,
}

impl PartialEq for FrameRuns {
    fn eq(&self, other: &Self) -> bool {
        self.runs() == other.runs()
    }
}

impl Eq for FrameRuns {}

impl FrameRuns {
    /// Most runs kept per chunk (8 bytes each).
    pub const MAX_RUNS: usize = 8;

    /// Records `frame` (inclusive runs; repeated or consecutive indices extend the last run).
    #[inline]
    pub fn push(&mut self, frame: u32) {
        self.push_span(frame, frame);
    }

    /// Records the frames `first..=last` (one observation standing for several frames, as
    /// when an average of consecutive frames is fused): runs the span overlaps or touches at
    /// the end of the list merge with it.
    #[inline]
    pub fn push_span(&mut self, first: u32, last: u32) {
        let (mut first, mut last) = (first.min(last), first.max(last));
        let mut n = self.len as usize;
        if let Some(end) = self.runs[..n].last_mut() {
            if first >= end.0 && first <= end.1.saturating_add(1) {
                end.1 = end.1.max(last);
                return;
            }
        }
        // A span reaching back over the last runs (rare: recording is in capture order)
        // absorbs them, so the runs stay disjoint.
        while n > 0 && first <= self.runs[n - 1].1.saturating_add(1) && last.saturating_add(1) >= self.runs[n - 1].0 {
            first = first.min(self.runs[n - 1].0);
            last = last.max(self.runs[n - 1].1);
            n -= 1;
        }
        if n == Self::MAX_RUNS {
            // Merge the closest neighbours (first such pair on ties: deterministic).
            let runs = &mut self.runs;
            let gap = |i: usize| runs[i + 1].0.abs_diff(runs[i].1);
            let i = (0..n - 1).min_by_key(|&i| gap(i)).unwrap_or(0);
            let (a, b) = (runs[i], runs[i + 1]);
            runs[i] = (a.0.min(b.0), a.1.max(b.1));
            runs.copy_within(i + 2..n, i + 1);
            n -= 1;
        }
        self.runs[n] = (first, last);
        self.len = (n + 1) as u8;
    }

    /// Whether `frame` was recorded (or lies in a gap merged away, see the type).
    pub fn contains(&self, frame: u32) -> bool {
        self.runs().iter().any(|&(a, b)| (a..=b).contains(&frame))
    }

    /// The runs as inclusive `(first, last)` pairs in recording order.
    pub fn runs(&self) -> &[(u32, u32)] {
        &self.runs[..self.len as usize]
    }

    /// Every recorded frame index, in recording order (a superset once runs merged).
    pub fn frames(&self) -> impl Iterator<Item = u32> + '_ {
        self.runs().iter().flat_map(|&(a, b)| a..=b)
    }
}

/// The voxels of one chunk, field by field (4096 bytes).
///
/// # Shapes
/// Every array is indexed by local `(x, y, z)` at `x + 8 y + 64 z`; `color[i]` is
/// `[r, g, b, colour observation count]`.
#[derive(Debug, Clone, PartialEq, Eq)]
#[repr(C, align(64))]
pub(crate) struct VoxelBlock {
    pub(crate) tsdf: [i16; CHUNK_VOXELS],
    pub(crate) weight: [u16; CHUNK_VOXELS],
    pub(crate) color: [[u8; 4]; CHUNK_VOXELS],
}

impl VoxelBlock {
    /// The sign summary stored in [`Chunk`]`::signs` (fusion computes it on the fly).
    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) fn signs(&self) -> u8 {
        let mut signs = SignSummary::default();
        for r in 0..CHUNK_SIDE * CHUNK_SIDE {
            let (mut neg, mut pos) = (0u32, 0u32);
            for x in 0..CHUNK_SIDE {
                let i = r * CHUNK_SIDE + x;
                let observed = (self.weight[i] != 0) as u32;
                neg |= (observed & (self.tsdf[i] < 0) as u32) << x;
                pos |= (observed & (self.tsdf[i] >= 0) as u32) << x;
            }
            signs.add_row(r, neg, pos);
        }
        signs.bits()
    }

    pub(crate) fn empty() -> Box<Self> {
        Box::new(Self { tsdf: [0; CHUNK_VOXELS], weight: [0; CHUNK_VOXELS], color: [[0; 4]; CHUNK_VOXELS] })
    }

    #[inline]
    pub(crate) fn get(&self, i: usize) -> Voxel {
        let c = self.color[i];
        Voxel { tsdf: self.tsdf[i], weight: self.weight[i], color: [c[0], c[1], c[2]], color_count: c[3] }
    }

    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) fn set(&mut self, i: usize, v: Voxel) {
        self.tsdf[i] = v.tsdf;
        self.weight[i] = v.weight;
        self.color[i] = [v.color[0], v.color[1], v.color[2], v.color_count];
    }
}

/// One allocated chunk.
#[derive(Debug, Clone)]
pub struct Chunk {
    pub(crate) key: ChunkKey,
    /// The voxels, a plain block or packed when cold (reads see the same bits either way).
    pub(crate) voxels: VoxelStore,
    pub(crate) dirty: bool,
    pub(crate) revision: u64,
    pub(crate) frames: FrameRuns,
    /// Signs of the observed voxels, see [`SignSummary`]; meshing skips a chunk whose cells
    /// cannot see both signs.
    pub(crate) signs: u8,
    /// The latest frame whose fusion selected the chunk, changed or not: compaction packs
    /// only chunks that fusion has left alone for a while, since fusion unpacks every chunk
    /// it selects (frame runs record only the frames that changed a voxel).
    pub(crate) touched: u32,
}

impl Chunk {
    fn new(key: ChunkKey) -> Self {
        Self {
            key,
            voxels: VoxelStore::Hot(VoxelBlock::empty()),
            dirty: false,
            revision: 0,
            signs: 0,
            frames: FrameRuns::default(),
            touched: 0,
        }
    }

    /// The chunk's coordinates.
    pub fn key(&self) -> ChunkKey {
        self.key
    }

    /// Voxel `i` (local `(x, y, z)` at `i = x + 8 y + 64 z`); panics when `i >= 512`.
    #[inline]
    pub fn voxel(&self, i: usize) -> Voxel {
        self.voxels.get(i)
    }

    /// The 512 voxels in local index order (`x + 8 y + 64 z`).
    pub fn voxels(&self) -> impl ExactSizeIterator<Item = Voxel> + '_ {
        (0..CHUNK_VOXELS).map(|i| self.voxels.get(i))
    }

    /// The stored distances of the 512 voxels in local index order, in units of the
    /// truncation distance times [`TSDF_SCALE`] (the quantised form of [`Voxel::tsdf`]): for
    /// readers that scan whole chunks (the semantic map's surface cells), where a [`Voxel`]
    /// per voxel costs three gathers.
    pub fn stored_tsdf(&self) -> &[i16; CHUNK_VOXELS] {
        &self.voxels.tsdf
    }

    /// The stored weights of the 512 voxels in local index order, times [`WEIGHT_SCALE`]
    /// (0: never observed; see [`Chunk::stored_tsdf`]).
    pub fn stored_weights(&self) -> &[u16; CHUNK_VOXELS] {
        &self.voxels.weight
    }

    /// The stored colours of the 512 voxels in local index order, `[r, g, b, colour
    /// observation count]` (see [`Chunk::stored_tsdf`]).
    pub fn stored_colors(&self) -> &[[u8; 4]; CHUNK_VOXELS] {
        &self.voxels.color
    }

    /// Which signs the observed voxels (weight not 0) have, in the whole chunk and on its
    /// three lower faces: bit 0 a negative distance anywhere, bit 1 a non-negative one; bits
    /// 2/3 the same on the face x = 0, 4/5 on y = 0, 6/7 on z = 0. A reader of zero
    /// crossings skips a chunk whose own bits and whose upper neighbours' lower-face bits do
    /// not add up to both signs.
    pub fn sign_bits(&self) -> u8 {
        self.signs
    }

    /// Whether fusion changed the chunk since the last [`TsdfMap::take_dirty`].
    pub fn is_dirty(&self) -> bool {
        self.dirty
    }

    /// A map-wide increasing stamp of the last change (consumers such as the mesher compare
    /// it with the stamp they last saw, so several consumers need no shared dirty flag).
    pub fn revision(&self) -> u64 {
        self.revision
    }

    /// The frames whose integration changed this chunk (for re-integration after loop
    /// closure).
    pub fn frames(&self) -> &FrameRuns {
        &self.frames
    }
}

/// FxHash-style hasher for chunk keys: a multiply-rotate per `i32` and a final avalanche.
///
/// Keys are three small integers, not attacker-controlled, so SipHash's DoS resistance buys
/// nothing and costs about 20 ns per lookup; this costs about 2. The final mix spreads
/// entropy to the low bits, which hashbrown uses to pick buckets.
#[derive(Debug, Default, Clone, Copy)]
pub struct ChunkHasher(u64);

const HASH_MUL: u64 = 0x51_7c_c1_b7_27_22_0a_95;

impl Hasher for ChunkHasher {
    #[inline]
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(5) ^ b as u64).wrapping_mul(HASH_MUL);
        }
    }

    #[inline]
    fn write_i32(&mut self, i: i32) {
        self.0 = (self.0.rotate_left(5) ^ i as u32 as u64).wrapping_mul(HASH_MUL);
    }

    #[inline]
    fn write_u64(&mut self, i: u64) {
        self.0 = (self.0.rotate_left(5) ^ i).wrapping_mul(HASH_MUL);
    }

    #[inline]
    fn finish(&self) -> u64 {
        let h = self.0;
        (h ^ (h >> 31)).wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ (h >> 29)
    }
}

/// Builds [`ChunkHasher`]s.
pub type ChunkHashBuilder = BuildHasherDefault<ChunkHasher>;

/// The sparse TSDF volume.
#[derive(Debug, Clone)]
pub struct TsdfMap {
    pub(crate) config: TsdfConfig,
    /// Chunk key -> position in `chunks`.
    pub(crate) index: HashMap<ChunkKey, u32, ChunkHashBuilder>,
    /// Chunk storage in allocation order (a slab, so that fusion can hand out `&mut` to
    /// disjoint chunks through `par_iter_mut`).
    pub(crate) chunks: Vec<Chunk>,
    pub(crate) next_revision: u64,
    /// Spill file, budget and what happened to them.
    pub(crate) memory: memory::MemoryState,
}

impl TsdfMap {
    /// An empty map; fails on an invalid configuration.
    pub fn new(config: TsdfConfig) -> Result<Self> {
        config.validate()?;
        Ok(Self {
            config,
            index: HashMap::default(),
            chunks: Vec::new(),
            next_revision: 1,
            memory: memory::MemoryState::default(),
        })
    }

    /// The configuration.
    pub fn config(&self) -> &TsdfConfig {
        &self.config
    }

    /// Number of allocated chunks.
    pub fn chunk_count(&self) -> usize {
        self.chunks.len()
    }

    /// Bytes one allocated chunk costs: the 4 KiB voxel block, the chunk record (its frame
    /// runs included: they are inline) and its hash entry.
    pub const fn bytes_per_chunk() -> usize {
        std::mem::size_of::<VoxelBlock>() + std::mem::size_of::<Chunk>() + std::mem::size_of::<(ChunkKey, u32)>() + 1
    }

    /// Approximate heap bytes held by the map in memory (hot voxel blocks, packed cold
    /// chunks and unpacked copies of them, chunk records with their frame runs, hash table;
    /// not the spill file): [`MapMemory::in_memory`] of [`TsdfMap::memory`].
    pub fn memory_bytes(&self) -> usize {
        self.memory().in_memory()
    }

    /// The chunk at `key`, if allocated.
    pub fn chunk(&self, key: ChunkKey) -> Option<&Chunk> {
        self.index.get(&key).map(|&i| &self.chunks[i as usize])
    }

    /// Every allocated chunk (in allocation order; sort keys where order matters).
    pub fn chunks(&self) -> impl ExactSizeIterator<Item = &Chunk> {
        self.chunks.iter()
    }

    /// Keys of every allocated chunk, sorted (z, then y, then x).
    pub fn sorted_keys(&self) -> Vec<ChunkKey> {
        let mut keys: Vec<ChunkKey> = self.chunks.iter().map(|c| c.key).collect();
        keys.sort_unstable_by_key(|k| key_order(*k));
        keys
    }

    /// The voxel at global voxel coordinates `v`, if its chunk is allocated.
    pub fn voxel(&self, v: IVec3) -> Option<Voxel> {
        let (key, local) = split_voxel(v);
        self.chunk(key).map(|c| c.voxels.get(local))
    }

    /// Centre of voxel `v` in the world frame, metres.
    pub fn voxel_center(&self, v: IVec3) -> Vec3 {
        v.as_vec3() * self.config.voxel_size
    }

    /// The voxel whose cell contains world point `p_world` (nearest voxel centre).
    pub fn voxel_at(&self, p_world: Vec3) -> IVec3 {
        (p_world / self.config.voxel_size).round().as_ivec3()
    }

    /// The chunk containing world point `p_world`.
    pub fn chunk_at(&self, p_world: Vec3) -> ChunkKey {
        split_voxel(self.voxel_at(p_world)).0
    }

    /// Keys of the chunks changed since the last call (sorted), clearing their dirty flags.
    pub fn take_dirty(&mut self) -> Vec<ChunkKey> {
        let mut keys: Vec<ChunkKey> = self
            .chunks
            .iter_mut()
            .filter(|c| c.dirty)
            .map(|c| {
                c.dirty = false;
                c.key
            })
            .collect();
        keys.sort_unstable_by_key(|k| key_order(*k));
        keys
    }

    /// Keys of the chunks that frame `frame` changed (sorted).
    pub fn chunks_touched_by(&self, frame: u32) -> Vec<ChunkKey> {
        let mut keys: Vec<ChunkKey> = self.chunks.iter().filter(|c| c.frames.contains(frame)).map(|c| c.key).collect();
        keys.sort_unstable_by_key(|k| key_order(*k));
        keys
    }

    /// Clears the chunks at `keys` (distances, weights, colours and frame runs) and marks
    /// them changed, so that the frames that made them can be fused again at corrected poses
    /// (loop closure); keys without a chunk are ignored. Consumers see a new revision.
    pub fn reset_chunks(&mut self, keys: &[ChunkKey]) {
        let revision = self.next_revision;
        self.next_revision += 1;
        for key in keys {
            if let Some(&slot) = self.index.get(key) {
                let c = &mut self.chunks[slot as usize];
                // A fresh block: a cold chunk is not unpacked only to be cleared.
                c.voxels = VoxelStore::Hot(VoxelBlock::empty());
                c.frames = FrameRuns::default();
                c.signs = 0;
                c.dirty = true;
                c.revision = revision;
            }
        }
    }

    /// Frees those chunks of `keys` without an observed voxel (left empty by a
    /// re-integration whose frames now see that space elsewhere); returns how many.
    pub fn free_unobserved(&mut self, keys: &[ChunkKey]) -> usize {
        let slots: Vec<u32> = keys
            .iter()
            .filter_map(|k| self.index.get(k).copied())
            .filter(|&s| self.chunks[s as usize].voxels.weight.iter().all(|&w| w == 0))
            .collect::<std::collections::BTreeSet<u32>>()
            .into_iter()
            .collect();
        let n = slots.len();
        self.free(slots);
        n
    }

    /// Allocates the chunk at `key` when absent; returns its slab position and whether it is
    /// new ([`TsdfMap::allocate_all`] for one key, which is what tests build maps with).
    #[cfg(test)]
    pub(crate) fn allocate(&mut self, key: ChunkKey) -> (u32, bool) {
        let before = self.chunks.len() as u32;
        let slot = self.allocate_all(&[key])[0];
        (slot, slot >= before)
    }

    /// Slab positions of `keys` (in `keys` order, repeats allowed), allocating the missing
    /// chunks; positions from `chunk_count()` before the call on are the new chunks.
    ///
    /// Present chunks are looked up in parallel (a probe costs a cache miss or two) and new
    /// blocks are made in parallel (a new 4 KiB block costs a page fault); positions are
    /// handed out serially in order of first appearance, so they never depend on threads.
    pub(crate) fn allocate_all(&mut self, keys: &[ChunkKey]) -> Vec<u32> {
        const BATCH: usize = 512;
        let found: Vec<Option<u32>> =
            keys.par_iter().with_min_len(BATCH).map(|key| self.index.get(key).copied()).collect();
        let mut fresh = Vec::new();
        let mut next = self.chunks.len() as u32;
        let slots = keys
            .iter()
            .zip(found)
            .map(|(&key, slot)| {
                slot.unwrap_or_else(|| {
                    *self.index.entry(key).or_insert_with(|| {
                        fresh.push(key);
                        next += 1;
                        next - 1
                    })
                })
            })
            .collect();
        let mut new_chunks = Vec::new();
        fresh.par_iter().with_min_len(BATCH / 16).map(|&key| Chunk::new(key)).collect_into_vec(&mut new_chunks);
        self.chunks.append(&mut new_chunks);
        slots
    }

    /// Frees the chunks at the given slab positions (any order, no duplicates).
    pub(crate) fn free(&mut self, mut slots: Vec<u32>) {
        // Highest first, so that swap_remove never moves a chunk that is still to be freed.
        slots.sort_unstable_by(|a, b| b.cmp(a));
        for s in slots {
            let removed = self.chunks.swap_remove(s as usize);
            self.index.remove(&removed.key);
            if let Some(moved) = self.chunks.get(s as usize) {
                self.index.insert(moved.key, s);
            }
        }
    }
}

/// Splits global voxel coordinates into the chunk key and the index inside the chunk.
#[inline]
pub fn split_voxel(v: IVec3) -> (ChunkKey, usize) {
    let side = CHUNK_SIDE as i32;
    let key = IVec3::new(v.x.div_euclid(side), v.y.div_euclid(side), v.z.div_euclid(side));
    let l = v - key * side;
    (key, (l.x + side * (l.y + side * l.z)) as usize)
}

/// Sort key ordering chunks by z, then y, then x (the mesh assembly order).
#[inline]
pub(crate) fn key_order(k: ChunkKey) -> (i32, i32, i32) {
    (k.z, k.y, k.x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn voxel_is_eight_bytes_and_chunk_four_kib() {
        assert_eq!(std::mem::size_of::<Voxel>(), 8);
        assert_eq!(std::mem::size_of::<VoxelBlock>(), 4096);
        // The record grew by 8 bytes with hot/cold storage (a tag beside the block pointer).
        assert!(TsdfMap::bytes_per_chunk() < 4096 + 136, "{}", TsdfMap::bytes_per_chunk());
    }

    #[test]
    fn split_voxel_handles_negative_coordinates() {
        assert_eq!(split_voxel(IVec3::new(-1, 0, 9)), (IVec3::new(-1, 0, 1), 7 + 64));
        assert_eq!(split_voxel(IVec3::new(-8, -9, 7)), (IVec3::new(-1, -2, 0), 7 * 8 + 7 * 64));
    }

    #[test]
    fn fuse_is_a_weighted_mean_with_cap() {
        let mut v = Voxel::default();
        v.fuse(0.5, 1.0, Some([100, 0, 0]), 2000);
        v.fuse(-0.5, 3.0, Some([200, 0, 0]), 2000);
        // Within half a step of the stored distance's quantisation.
        assert!((v.tsdf() - (-0.25)).abs() <= 0.5 / TSDF_SCALE);
        assert_eq!(v.weight(), 4.0);
        assert_eq!(v.color()[0], 150);
        v.fuse(1.0, 100.0, None, 1000);
        assert_eq!(v.weight as u32, 1000);
    }

    #[test]
    fn frame_runs_merge_consecutive_frames() {
        let mut r = FrameRuns::default();
        for f in [0, 1, 2, 2, 3, 7, 8, 20] {
            r.push(f);
        }
        assert_eq!(r.runs(), &[(0, 3), (7, 8), (20, 20)]);
        assert!(r.contains(8) && !r.contains(5));
        assert_eq!(r.frames().count(), 7);
    }

    #[test]
    fn frame_spans_merge_with_the_runs_they_touch() {
        let mut r = FrameRuns::default();
        r.push(3);
        r.push_span(0, 3);
        assert_eq!(r.runs(), &[(0, 3)]);
        r.push(7);
        r.push_span(5, 8);
        assert_eq!(r.runs(), &[(0, 3), (5, 8)]);
        r.push_span(9, 12);
        assert_eq!(r.runs(), &[(0, 3), (5, 12)]);
        r.push(20);
        r.push_span(4, 21);
        assert_eq!(r.runs(), &[(0, 21)]);
        // The same as pushing the frames one by one.
        let mut one_by_one = FrameRuns::default();
        for f in 0..=21 {
            one_by_one.push(f);
        }
        assert_eq!(r, one_by_one);
    }

    #[test]
    fn frame_runs_stay_bounded_when_a_place_is_revisited() {
        let mut r = FrameRuns::default();
        // A chunk seen for three frames every hundred frames, 50 times.
        for visit in 0..50u32 {
            for f in 0..3 {
                r.push(visit * 100 + f);
            }
        }
        assert_eq!(r.runs().len(), FrameRuns::MAX_RUNS);
        for visit in 0..50u32 {
            assert!(r.contains(visit * 100) && r.contains(visit * 100 + 2), "visit {visit} kept");
        }
        let runs = r.runs();
        assert!(runs.windows(2).all(|w| w[0].1 < w[1].0), "ordered, disjoint: {runs:?}");
    }

    #[test]
    fn allocate_all_hands_out_positions_in_order_of_first_appearance() {
        let mut m = TsdfMap::new(TsdfConfig::default()).expect("valid");
        for x in 0..3 {
            m.allocate(IVec3::new(x, 0, 0));
        }
        let key = |x: i32| IVec3::new(x, 0, 0);
        let slots = m.allocate_all(&[key(7), key(1), key(5), key(7), key(0), key(5)]);
        assert_eq!(slots, vec![3, 1, 4, 3, 0, 4]);
        assert_eq!(m.chunk_count(), 5);
        for (k, &i) in &m.index {
            assert_eq!(m.chunks[i as usize].key, *k);
        }
        assert!(m.allocate_all(&[]).is_empty());
    }

    #[test]
    fn frame_runs_compare_by_their_runs() {
        let mut a = FrameRuns::default();
        let mut b = FrameRuns::default();
        // Nine runs, the first two merged; and the same eight runs recorded directly.
        for f in [8, 10, 20, 30, 40, 50, 60, 70, 80] {
            a.push(f);
        }
        for f in [8, 9, 10, 20, 30, 40, 50, 60, 70, 80] {
            b.push(f);
        }
        assert_eq!(a.runs(), &[(8, 10), (20, 20), (30, 30), (40, 40), (50, 50), (60, 60), (70, 70), (80, 80)]);
        assert_eq!(a, b);
        let mut c = b.clone();
        c.push(81);
        assert_ne!(b, c);
    }

    #[test]
    fn free_keeps_index_consistent() {
        let mut m = TsdfMap::new(TsdfConfig::default()).expect("valid");
        for x in 0..10 {
            m.allocate(IVec3::new(x, 0, 0));
        }
        m.free(vec![2, 9, 0]);
        assert_eq!(m.chunk_count(), 7);
        for (k, &i) in &m.index {
            assert_eq!(m.chunks[i as usize].key, *k);
        }
        assert!(m.chunk(IVec3::new(2, 0, 0)).is_none());
        assert!(m.chunk(IVec3::new(5, 0, 0)).is_some());
    }

    #[test]
    fn config_ranges_are_checked() {
        assert!(TsdfConfig::with_voxel_size(0.001).is_err());
        assert!(TsdfConfig::with_voxel_size(0.02).is_ok());
        let c = TsdfConfig { max_depth: f32::NAN, ..TsdfConfig::default() };
        assert!(c.validate().is_err());
        assert!(TsdfConfig { truncation_noise_factor: -1.0, ..TsdfConfig::default() }.validate().is_err());
        assert!(TsdfConfig { truncation_noise_factor: f32::NAN, ..TsdfConfig::default() }.validate().is_err());
        assert!(TsdfConfig { min_truncation_voxels: 0.5, ..TsdfConfig::default() }.validate().is_err());
    }

    #[test]
    fn band_follows_the_noise_between_its_limits() {
        let c = TsdfConfig { truncation_voxels: 10.0, ..TsdfConfig::default() };
        let voxels = |z: f32| c.band(z) / c.voxel_size;
        // 3 sigma: 4 voxels (the floor) near, 10 (the cap) far, the noise model between.
        assert!((voxels(0.5) - 4.0).abs() < 1e-4 && (voxels(2.0) - 4.0).abs() < 1e-4);
        let sigma = |z: f32| 0.0012 + 0.0019 * (z - 0.4) * (z - 0.4);
        assert!((voxels(2.7) - 3.0 * sigma(2.7) / c.voxel_size).abs() < 1e-3, "{}", voxels(2.7));
        assert!((voxels(3.5) - 10.0).abs() < 1e-4);
        assert!((c.narrowest_band_voxels() - 4.0).abs() < 1e-6);
        // Off: the fixed band everywhere, and the library default (4 voxels) is fixed too.
        let fixed = TsdfConfig { truncation_noise_factor: 0.0, ..c };
        assert!([0.5f32, 2.0, 3.5].iter().all(|&z| fixed.band(z) == fixed.truncation()));
        assert_eq!(fixed.narrowest_band_voxels(), 10.0);
        let d = TsdfConfig::default();
        assert!([0.5f32, 2.0, 4.5].iter().all(|&z| d.band(z) == d.truncation()));
    }
}
