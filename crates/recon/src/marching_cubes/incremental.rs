//! The incremental mesher: chunk meshes cached and re-made only where the map changed
//! materially since the last update (a compact snapshot of each chunk's voxels tells), within
//! an optional budget of chunks per update.

use super::*;

/// What one incremental update did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MeshingStats {
    /// Chunks whose map revision changed (or that were freed) since the last update.
    pub changed_chunks: usize,
    /// Chunks re-meshed (the materially changed ones and the allocated neighbours that read
    /// their changed voxels; in exact mode every changed chunk and all its neighbours).
    pub remeshed_chunks: usize,
    /// Triangles over all cached chunk meshes after the update.
    pub triangles: usize,
    /// Chunks due for re-meshing that a [budget](IncrementalMesher::with_budget) left for
    /// later updates (0 without one).
    pub pending_chunks: usize,
}

/// How far the cached meshes of an [`IncrementalMesher`] may lag behind the map.
///
/// A chunk that fusion touched may have changed only by noise averaging: a voxel observed
/// many times moves by a small fraction of a voxel per frame, which moves the surface far
/// less than anything visible. With a tolerance the mesher keeps, per chunk with both signs,
/// a snapshot of the voxels as the meshes that read them were made, and re-meshes only where
/// a voxel changed *materially*: its observedness or sign changed, its distance moved by more
/// than half of [`distance_voxels`](Self::distance_voxels), or its colour left its 5-6-5 bit
/// bucket. Neighbours are re-meshed only when such a voxel lies in the part of the chunk they
/// read. The check is one pass over the chunk's 512 voxels.
///
/// # Bound (tested against a full re-mesh)
/// Every voxel a cached mesh was made from has, in the current map, the same observedness
/// (weight at or above the mesher's [`MeshConfig::min_weight`]) and sign and a distance within `distance_voxels` voxels (the snapshot is at most half of
/// it from both), so every cell has the same case and the incremental mesh has exactly the
/// topology of a full re-mesh ([`extract_mesh_with`] with the same options), chunk by chunk and triangle by triangle.
/// The one exception is the seam rule, which drops cells with an edge jump above 1.5
/// narrowest bands: a cell with an edge whose jump is within twice `distance_voxels` of that
/// limit may be dropped in one mesh and kept in the other. A vertex lies on the same cell edge as in the
/// full re-mesh, at most `distance_voxels / |d_a - d_b|` voxels from it and never more than
/// one voxel, where `d_a`, `d_b` are the distances at the edge's ends in voxels: on a real
/// surface (`|d_a - d_b|` about a voxel) about `distance_voxels` voxels. Normals follow from
/// the same distances; vertex colours come from voxel colours in the same 5-6-5 bucket
/// (under 8 levels per channel), moved along the edge with the vertex.
///
/// # Measured
/// On the first 100 frames of 7-Scenes redkitchen (5 mm voxels) it barely helps: per
/// keyframe every chunk with a surface has a dozen newly observed voxels and a dozen sign
/// flips (the zero crossing wanders with the noise), so 0.1 and even 1 voxel re-mesh about
/// 2% fewer chunks than exact mode. The default is therefore exact; a tolerance pays off
/// where the weights have saturated (a camera dwelling on or revisiting a surface).
///
/// 0 is exact mode: every change re-meshes the chunk and its 26 neighbours, and the result
/// equals a full re-mesh bit for bit (no snapshots are kept).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RemeshTolerance {
    /// Largest difference, in voxels, between a distance a cached mesh was made from and the
    /// map's current one (0 to 1; 0 is exact).
    pub distance_voxels: f32,
}

impl RemeshTolerance {
    /// Exact mode: the incremental mesh equals a full re-mesh.
    pub const EXACT: Self = Self { distance_voxels: 0.0 };
    /// 0.1 voxel (0.5 mm at 5 mm voxels): a tenth of the Kinect's best axial noise.
    pub const NOISE: Self = Self { distance_voxels: 0.1 };

    /// Checks the documented range.
    pub fn validate(&self) -> crate::Result<()> {
        if !(0.0..=1.0).contains(&self.distance_voxels) {
            return Err(crate::ReconError::InvalidConfig(format!(
                "remesh tolerance {} voxels is outside 0..1",
                self.distance_voxels
            )));
        }
        Ok(())
    }
}

impl Default for RemeshTolerance {
    /// Exact mode (see the type for why).
    fn default() -> Self {
        Self::EXACT
    }
}

/// Heap bytes of an [`IncrementalMesher`] ([`IncrementalMesher::memory`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MeshStoreMemory {
    /// The packed chunk meshes' buffers as allocated (what the allocator holds).
    pub mesh_bytes: usize,
    /// What the packed meshes need of them.
    pub mesh_used_bytes: usize,
    /// Entries, the key index, the slot table and snapshots.
    pub bookkeeping_bytes: usize,
}

impl MeshStoreMemory {
    /// All heap bytes.
    pub fn total(&self) -> usize {
        self.mesh_bytes + self.bookkeeping_bytes
    }
}

/// A chunk's voxels as the cached meshes that read them were made (see [`RemeshTolerance`]):
/// raw distances, 5-6-5 colours and observed bits, 2112 bytes.
#[derive(Debug, Clone)]
struct Snapshot {
    tsdf: [i16; CHUNK_VOXELS],
    color: [u16; CHUNK_VOXELS],
    observed: [u64; CHUNK_VOXELS / 64],
}

/// Bytes a snapshot costs on the heap (kept only for chunks with both signs).
const SNAPSHOT_BYTES: usize = std::mem::size_of::<Snapshot>();

/// 5-6-5 bit quantised colour: the bucket that a snapshot remembers.
#[inline]
fn rgb565(c: [u8; 4]) -> u16 {
    (c[0] as u16 >> 3) << 11 | (c[1] as u16 >> 2) << 5 | c[2] as u16 >> 3
}

impl Snapshot {
    fn of(chunk: &Chunk, min_weight: u16) -> Box<Self> {
        let v = &chunk.voxels;
        let mut s = Box::new(Snapshot { tsdf: v.tsdf, color: [0; CHUNK_VOXELS], observed: [0; CHUNK_VOXELS / 64] });
        for (d, &c) in s.color.iter_mut().zip(&v.color) {
            *d = rgb565(c);
        }
        for (z, o) in s.observed.iter_mut().enumerate() {
            *o = observed_bits(&v.weight[z * 64..(z + 1) * 64], min_weight);
        }
        s
    }

    /// Bit mask (bit `i % 64` of word `i / 64`) of the voxels that changed materially since
    /// the snapshot (see [`RemeshTolerance`]; `tolerance` in stored distance units, observed
    /// meaning a stored weight of at least `min_weight`); refreshes exactly those voxels in
    /// the snapshot.
    fn refresh_material(&mut self, chunk: &Chunk, tolerance: i32, min_weight: u16) -> [u64; CHUNK_VOXELS / 64] {
        let v = &chunk.voxels;
        let mut out = [0u64; CHUNK_VOXELS / 64];
        for (z, word) in out.iter_mut().enumerate() {
            let range = z * 64..(z + 1) * 64;
            let now_observed = observed_bits(&v.weight[range.clone()], min_weight);
            // Branch-free over 64 voxels into bytes, packed afterwards: vectorises.
            let mut moved = [0u8; 64];
            for (i, f) in moved.iter_mut().enumerate() {
                let j = range.start + i;
                let (t, s) = (v.tsdf[j] as i32, self.tsdf[j] as i32);
                let changed =
                    ((t < 0) != (s < 0)) | ((t - s).abs() > tolerance) | (rgb565(v.color[j]) != self.color[j]);
                *f = changed as u8;
            }
            let m = (pack_bytes(&moved) & now_observed) | (now_observed ^ self.observed[z]);
            if m == 0 {
                continue;
            }
            *word = m;
            let mut bits = m;
            while bits != 0 {
                let i = bits.trailing_zeros() as usize;
                bits &= bits - 1;
                let j = range.start + i;
                self.tsdf[j] = v.tsdf[j];
                self.color[j] = rgb565(v.color[j]);
            }
            self.observed[z] = now_observed;
        }
        out
    }
}

/// Packs 64 bytes of 0 or 1 into a bit mask (byte `i` to bit `i`), eight at a time by a
/// multiply that moves byte `k`'s bit to bit `56 + k` without carries.
#[inline]
pub(super) fn pack_bytes(bytes: &[u8; 64]) -> u64 {
    let mut m = 0u64;
    for (k, chunk) in bytes.chunks_exact(8).enumerate() {
        let mut w = [0u8; 8];
        w.copy_from_slice(chunk);
        let x = u64::from_le_bytes(w) & 0x0101_0101_0101_0101;
        m |= (x.wrapping_mul(0x0102_0408_1020_4080) >> 56) << (8 * k);
    }
    m
}

/// Bit mask of the observed voxels (stored weight at least `min_weight`, at least 1) among 64.
#[inline]
fn observed_bits(weight: &[u16], min_weight: u16) -> u64 {
    let mut bytes = [0u8; 64];
    for (b, &w) in bytes.iter_mut().zip(weight) {
        *b = (w >= min_weight) as u8;
    }
    pack_bytes(&bytes)
}

/// Which chunks read the voxels in `changed` (bit mask as from
/// [`Snapshot::refresh_material`]): bit `(dx + 1) + 3 (dy + 1) + 9 (dz + 1)` stands for the
/// chunk at offset `(dx, dy, dz)`. A chunk meshes its cells from its padded block, local
/// `-1 ..= 9`: the chunk one lower on an axis reads local 0 and 1 there, the one higher
/// reads local 7, and the ones level with it everything.
pub(super) fn readers(changed: &[u64; CHUNK_VOXELS / 64]) -> u32 {
    // Per offset -1, 0, +1: bits of a 64-voxel z slice (`x + 8 y`) with x, y in range.
    const X: [u64; 3] = [0x0303_0303_0303_0303, !0, 0x8080_8080_8080_8080];
    const Y: [u64; 3] = [0xffff, !0, 0xff00_0000_0000_0000];
    let z_words = |o: usize| match o {
        0 => changed[0] | changed[1],
        1 => changed.iter().fold(0, |a, w| a | w),
        _ => changed[CHUNK_SIDE - 1],
    };
    let mut out = 0u32;
    for oz in 0..3 {
        let w = z_words(oz);
        if w == 0 {
            continue;
        }
        for (oy, y) in Y.iter().enumerate() {
            for (ox, x) in X.iter().enumerate() {
                if w & x & y != 0 {
                    out |= 1 << (ox + 3 * oy + 9 * oz);
                }
            }
        }
    }
    out
}

/// One cached chunk: its key, the map revision last seen, when it was meshed, and with a
/// tolerance the snapshot its readers' meshes were made from. The mesh itself is kept apart
/// (`IncrementalMesher::meshes`): every update scans all entries a few times, and with
/// the meshes inline those scans read four times the memory.
#[derive(Debug, Clone)]
struct CacheEntry {
    key: ChunkKey,
    revision: u64,
    /// The [`IncrementalMesher::generation`] of the update that last re-meshed it (0: never).
    meshed_at: u64,
    /// The generation of the update that first found it due and left it for later (under a
    /// budget); [`NOT_PENDING`] when its mesh is up to date.
    pending_since: u64,
    snapshot: Option<Box<Snapshot>>,
}

/// Revision of an entry not meshed yet (map revisions count up from 0 and never reach it).
const UNSEEN: u64 = u64::MAX;

/// [`CacheEntry::pending_since`] of an entry with nothing left to re-mesh.
const NOT_PENDING: u64 = u64::MAX;

/// Per-chunk mesh cache that re-meshes only what changed in the map (materially, with a
/// [`RemeshTolerance`]), optionally at most a budget of chunks per update.
///
/// # Budget
/// On a hand-held scan nearly every chunk in view changes between two keyframes (with their
/// neighbours about 13,600 at 5 mm on 7-Scenes, see docs/benchmarks.md), so re-meshing them all costs the
/// same at every keyframe however the surface moved. With a budget of `B` chunks
/// ([`IncrementalMesher::with_budget`]) an update re-meshes at most `B` of the chunks due:
/// first those never meshed and the due chunks whose cells read their voxels (newly seen
/// surface appears at once, with no open seam along its chunks' edges), then the ones due
/// the longest, then in key order (deterministic). The rest stay due, keeping their place
/// however often they change again: while new surface takes a small part of the budget, a
/// chunk waits about `due / B` updates, so its mesh lags the map by that many updates.
/// [`IncrementalMesher::update_all`] ignores the budget (the end of a scan, an export).
#[derive(Debug, Clone)]
pub struct IncrementalMesher {
    /// Chunk key -> position in `entries`.
    index: HashMap<ChunkKey, u32, ChunkHashBuilder>,
    /// Entries in a slab, so that re-meshing can write into them in parallel.
    entries: Vec<CacheEntry>,
    /// The chunk meshes, packed (see `packed_mesh.rs`), in the same positions as `entries`.
    meshes: Vec<PackedChunkMesh>,
    /// Voxel size of the map last meshed, metres (unpacking positions needs it).
    voxel_size: f32,
    /// Triangles over all of `meshes`.
    triangles: usize,
    tolerance: RemeshTolerance,
    config: MeshConfig,
    /// Most chunks one [`IncrementalMesher::update`] re-meshes (`None`: all that are due).
    budget: Option<std::num::NonZeroUsize>,
    /// Map slot -> entry at the last update: where to look first for a chunk's entry.
    slot_entry: Vec<u32>,
    /// Updates so far.
    generation: u64,
}

impl Default for IncrementalMesher {
    fn default() -> Self {
        Self::new()
    }
}

impl IncrementalMesher {
    /// An empty cache in exact mode meshing every observed voxel: the mesh always equals
    /// [`extract_mesh`].
    pub fn new() -> Self {
        Self {
            index: HashMap::default(),
            entries: Vec::new(),
            meshes: Vec::new(),
            voxel_size: 0.0,
            triangles: 0,
            tolerance: RemeshTolerance::EXACT,
            config: MeshConfig::ALL_OBSERVED,
            budget: None,
            slot_entry: Vec::new(),
            generation: 0,
        }
    }

    /// The same cache re-meshing at most `budget` chunks per [`IncrementalMesher::update`]
    /// (see [Budget](IncrementalMesher#budget)); `None` re-meshes everything due.
    pub fn with_budget(self, budget: Option<std::num::NonZeroUsize>) -> Self {
        Self { budget, ..self }
    }

    /// Most chunks one update re-meshes (`None`: no limit).
    pub fn budget(&self) -> Option<std::num::NonZeroUsize> {
        self.budget
    }

    /// Chunks due for re-meshing that the budget left for later updates.
    pub fn pending_chunks(&self) -> usize {
        self.entries.iter().filter(|e| e.pending_since != NOT_PENDING).count()
    }

    /// An empty cache with the given tolerance; fails outside its documented range.
    pub fn with_tolerance(tolerance: RemeshTolerance) -> crate::Result<Self> {
        Self::with_config(MeshConfig::ALL_OBSERVED, tolerance)
    }

    /// An empty cache with the given meshing options and tolerance; in exact mode the mesh
    /// always equals [`extract_mesh_with`] with the same options. Fails when either is outside
    /// its documented range.
    pub fn with_config(config: MeshConfig, tolerance: RemeshTolerance) -> crate::Result<Self> {
        config.validate()?;
        tolerance.validate()?;
        Ok(Self { tolerance, config, ..Self::new() })
    }

    /// The tolerance.
    pub fn tolerance(&self) -> RemeshTolerance {
        self.tolerance
    }

    /// The meshing options.
    pub fn config(&self) -> MeshConfig {
        self.config
    }

    /// Heap bytes of the snapshots (one per chunk with both signs when the tolerance is not
    /// 0, 2112 bytes each), on top of the chunk meshes.
    pub fn snapshot_bytes(&self) -> usize {
        self.entries.iter().filter(|e| e.snapshot.is_some()).count() * SNAPSHOT_BYTES
    }

    /// Where the cache's heap bytes are (see [`MeshStoreMemory`]): what a whole home's live
    /// mesh costs beside its map.
    pub fn memory(&self) -> MeshStoreMemory {
        let (mut allocated, mut used) = (0, 0);
        for m in &self.meshes {
            let (a, u) = m.heap_bytes();
            allocated += a;
            used += u;
        }
        let bookkeeping = self.entries.capacity() * std::mem::size_of::<CacheEntry>()
            + self.meshes.capacity() * std::mem::size_of::<PackedChunkMesh>()
            + self.index.capacity() * (std::mem::size_of::<(ChunkKey, u32)>() + 1)
            + self.slot_entry.capacity() * std::mem::size_of::<u32>()
            + self.snapshot_bytes();
        MeshStoreMemory { mesh_bytes: allocated, mesh_used_bytes: used, bookkeeping_bytes: bookkeeping }
    }

    /// Re-meshes the chunks that changed since the last update (materially, see
    /// [`RemeshTolerance`]), and their neighbours that read the changed voxels, at most the
    /// [budget](IncrementalMesher#budget) of them (those left over first at the next update);
    /// drops meshes of freed chunks. Parallel over chunks, deterministic.
    pub fn update(&mut self, map: &TsdfMap) -> MeshingStats {
        self.update_within(map, self.budget.map(|b| b.get()))
    }

    /// [`IncrementalMesher::update`] without the budget: afterwards every chunk mesh is up to
    /// date (in exact mode the mesh equals [`extract_mesh_with`]).
    pub fn update_all(&mut self, map: &TsdfMap) -> MeshingStats {
        self.update_within(map, None)
    }

    fn update_within(&mut self, map: &TsdfMap, budget: Option<usize>) -> MeshingStats {
        self.generation += 1;
        self.voxel_size = map.config().voxel_size;
        // The entry of each map chunk: where the last update found it, when that entry still
        // holds its key (chunks move only when the map frees others), else from the index.
        // The index is asked only for moved and new chunks, not for every chunk of the map.
        let cached = std::mem::take(&mut self.slot_entry);
        let found: Vec<Option<u32>> = map
            .chunks
            .par_iter()
            .enumerate()
            .map(|(slot, c)| match cached.get(slot) {
                Some(&e) if self.entries.get(e as usize).is_some_and(|entry| entry.key == c.key) => Some(e),
                _ => self.index.get(&c.key).copied(),
            })
            .collect();
        // Entries no map chunk claims belong to freed chunks: dropped highest position first
        // (swap_remove moves only entries that stay); `moved_to` says where each entry went.
        let mut claimed = vec![false; self.entries.len()];
        for &e in found.iter().flatten() {
            claimed[e as usize] = true;
        }
        let freed_entries: Vec<u32> = (0..self.entries.len() as u32).filter(|&e| !claimed[e as usize]).collect();
        let freed: Vec<ChunkKey> = freed_entries.iter().map(|&i| self.entries[i as usize].key).collect();
        let mut original: Vec<u32> = (0..self.entries.len() as u32).collect();
        for &i in freed_entries.iter().rev() {
            let removed = self.entries.swap_remove(i as usize);
            self.triangles -= self.meshes.swap_remove(i as usize).triangles();
            original.swap_remove(i as usize);
            self.index.remove(&removed.key);
            if let Some(moved) = self.entries.get(i as usize) {
                self.index.insert(moved.key, i);
            }
        }
        let mut moved_to = vec![u32::MAX; claimed.len()];
        for (now, &was) in original.iter().enumerate() {
            moved_to[was as usize] = now as u32;
        }
        // New chunks get an entry, in slab order (deterministic).
        let entry_of: Vec<u32> = map
            .chunks
            .iter()
            .zip(found)
            .map(|(c, f)| match f {
                Some(e) => moved_to[e as usize],
                None => {
                    let i = self.entries.len() as u32;
                    self.entries.push(CacheEntry {
                        key: c.key,
                        revision: UNSEEN,
                        meshed_at: 0,
                        pending_since: NOT_PENDING,
                        snapshot: None,
                    });
                    self.meshes.push(PackedChunkMesh::default());
                    self.index.insert(c.key, i);
                    i
                }
            })
            .collect();
        // Per entry, the map slot of its chunk when that changed.
        let mut changed_slot = vec![u32::MAX; self.entries.len()];
        let mut changed_count = 0;
        for (slot, (c, &e)) in map.chunks.iter().zip(&entry_of).enumerate() {
            if self.entries[e as usize].revision != c.revision {
                changed_slot[e as usize] = slot as u32;
                changed_count += 1;
            }
        }
        // Per changed chunk, which of its neighbours (and itself) read what changed.
        let tolerant = self.tolerance.distance_voxels > 0.0;
        let tolerance =
            (0.5 * self.tolerance.distance_voxels / map.config().truncation_voxels * TSDF_SCALE).floor() as i32;
        let min_weight = self.config.stored_min_weight();
        let readers_of: Vec<(ChunkKey, u32)> = self
            .entries
            .par_iter_mut()
            .zip(&changed_slot)
            .filter(|(_, &slot)| slot != u32::MAX)
            .map(|(e, &slot)| {
                let chunk = &map.chunks[slot as usize];
                e.revision = chunk.revision;
                if !tolerant {
                    return (chunk.key, ALL_READERS);
                }
                let mask = match &mut e.snapshot {
                    Some(s) => readers(&s.refresh_material(chunk, tolerance, min_weight)),
                    None => ALL_READERS,
                };
                // Single-signed chunks hold no surface of their own; their changes re-mesh
                // all readers instead of costing a snapshot.
                if chunk.signs & 3 != 3 {
                    e.snapshot = None;
                } else if e.snapshot.is_none() {
                    e.snapshot = Some(Snapshot::of(chunk, min_weight));
                }
                (chunk.key, mask)
            })
            .collect();
        // The map slots to re-mesh: the changed chunks' readers, and all neighbours of the
        // freed ones.
        let mut marks = readers_of;
        marks.extend(freed.iter().map(|&k| (k, ALL_READERS)));
        let mut remesh: Vec<bool> = self.entries.iter().map(|e| e.pending_since != NOT_PENDING).collect();
        for slot in reader_marks::marked_slots(map, &marks) {
            remesh[entry_of[slot as usize] as usize] = true;
        }
        // Re-meshed in key order, each worker over a run of neighbouring chunks: a chunk's
        // upper neighbours, whose voxels it reads, are the next ones meshed, so their blocks
        // are still cached (the slab's creation order scattered them).
        // The order is sorted as (key, entry) pairs, then the jobs (each holding a mesh) are
        // made in it: sorting the jobs themselves moved their 136 bytes at every swap.
        let mut order: Vec<((i32, i32, i32), u32)> = self
            .entries
            .iter()
            .enumerate()
            .filter(|(i, _)| remesh[*i])
            .map(|(i, e)| (key_order(e.key), i as u32))
            .collect();
        let pending = match budget {
            Some(budget) if order.len() > budget => {
                // Chunks never meshed, and the due chunks whose cells reach into them (the lower
                // neighbours): meshed apart, a new chunk would leave an open seam one cell wide
                // along its edges. The upper neighbours read it only for their normals.
                let new: Vec<(ChunkKey, u32)> = order
                    .iter()
                    .map(|&(_, i)| &self.entries[i as usize])
                    .filter(|e| e.meshed_at == 0)
                    .map(|e| (e.key, CELL_READERS))
                    .collect();
                let mut urgent = vec![false; self.entries.len()];
                for slot in reader_marks::marked_slots(map, &new) {
                    urgent[entry_of[slot as usize] as usize] = true;
                }
                self.defer_over_budget(&mut order, &urgent, budget)
            }
            _ => {
                for &(_, i) in &order {
                    self.entries[i as usize].pending_since = NOT_PENDING;
                }
                0
            }
        };
        order.par_sort_unstable();
        let mut jobs: Vec<(ChunkKey, u32, PackedChunkMesh, Option<PackedChunkMesh>)> = order
            .iter()
            .map(|&(_, i)| {
                let mesh = std::mem::take(&mut self.meshes[i as usize]);
                self.triangles -= mesh.triangles();
                (self.entries[i as usize].key, i, mesh, None)
            })
            .collect();
        let remeshed = jobs.len();
        jobs.par_iter_mut().for_each_init(Scratch::new, |s, (key, _, mesh, fresh)| {
            *fresh = remesh_into(map, *key, min_weight, s, mesh);
        });
        // Buffers that must be allocated anew are, here, on this thread (see
        // `PackedChunkMesh::sized_for`); the workers then copy into them.
        let mut resized = false;
        for (_, _, mesh, fresh) in &mut jobs {
            if let Some(fresh) = fresh {
                *mesh = PackedChunkMesh::sized_for(fresh.heap_bytes().1);
                resized = true;
            }
        }
        if resized {
            jobs.par_iter_mut().for_each(|(_, _, mesh, fresh)| {
                if let Some(fresh) = fresh.take() {
                    mesh.copy_from(&fresh);
                }
            });
        }
        for (_, i, mesh, _) in jobs {
            self.triangles += mesh.triangles();
            self.meshes[i as usize] = mesh;
            self.entries[i as usize].meshed_at = self.generation;
        }
        self.slot_entry = entry_of;
        MeshingStats {
            changed_chunks: changed_count + freed.len(),
            remeshed_chunks: remeshed,
            triangles: self.triangles,
            pending_chunks: pending,
        }
    }

    /// Keeps in `order` the `budget` due chunks that go first (`urgent` ones, then those due
    /// the longest, then by key) and marks the others pending; returns how many those are.
    fn defer_over_budget(&mut self, order: &mut Vec<((i32, i32, i32), u32)>, urgent: &[bool], budget: usize) -> usize {
        let generation = self.generation;
        let entries = &mut self.entries;
        let rank = |&(key, i): &((i32, i32, i32), u32)| {
            let e = &entries[i as usize];
            (!urgent[i as usize], e.pending_since.min(generation), key)
        };
        let mut ranked: Vec<_> = order.iter().map(|o| (rank(o), o.1)).collect();
        ranked.select_nth_unstable(budget);
        for &(_, i) in &ranked[..budget] {
            entries[i as usize].pending_since = NOT_PENDING;
        }
        for &(_, i) in &ranked[budget..] {
            let e = &mut entries[i as usize];
            e.pending_since = e.pending_since.min(generation);
        }
        *order = ranked[..budget].iter().map(|&((_, _, key), i)| (key, i)).collect();
        ranked.len() - budget
    }

    /// The cached mesh of chunk `key` (unpacked: the cache keeps it packed).
    pub fn chunk_mesh(&self, key: ChunkKey) -> Option<ChunkMesh> {
        self.index.get(&key).map(|&i| self.unpack(key, &self.meshes[i as usize], &mut Unpacker::new()))
    }

    fn unpack(&self, key: ChunkKey, packed: &PackedChunkMesh, unpacker: &mut Unpacker) -> ChunkMesh {
        let mut mesh = ChunkMesh::default();
        packed.unpack(key, self.voxel_size, unpacker, &mut mesh);
        mesh
    }

    /// The number of [`IncrementalMesher::update`] calls so far: a consumer that remembers it
    /// can ask [`IncrementalMesher::remeshed_since`] for what changed after.
    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// The chunks re-meshed by the updates after `generation`, with their meshes (in cache
    /// order, which depends on the history of the map: sort the keys where order matters).
    /// Chunks freed since are simply absent from the cache ([`IncrementalMesher::chunk_mesh`]).
    pub fn remeshed_since(&self, generation: u64) -> impl Iterator<Item = (ChunkKey, ChunkMesh)> + '_ {
        let mut unpacker = Unpacker::new();
        self.entries
            .iter()
            .zip(&self.meshes)
            .filter(move |(e, _)| e.meshed_at > generation)
            .map(move |(e, m)| (e.key, self.unpack(e.key, m, &mut unpacker)))
    }

    /// Number of cached chunk meshes.
    pub fn chunk_count(&self) -> usize {
        self.entries.len()
    }

    /// The whole surface as one welded mesh (chunks in (z, y, x) key order; no labels).
    pub fn mesh(&self) -> LabeledMesh {
        let mut order: Vec<((i32, i32, i32), ChunkKey, &PackedChunkMesh)> = self
            .entries
            .iter()
            .zip(&self.meshes)
            .filter(|(_, m)| !m.is_empty())
            .map(|(e, m)| (key_order(e.key), e.key, m))
            .collect();
        order.sort_unstable_by_key(|(k, _, _)| *k);
        let meshes: Vec<(ChunkKey, &PackedChunkMesh)> = order.into_iter().map(|(_, key, m)| (key, m)).collect();
        assemble_from(PackedMeshes::new(meshes, self.voxel_size), self.config.min_component_triangles, |_| {})
    }

    /// [`IncrementalMesher::mesh`], taking the cache's memory with it: each chunk mesh is
    /// freed as soon as it is copied, so that the whole mesh grows as the cache goes instead
    /// of beside all of it (a whole home's live mesh is about half a gigabyte packed, its
    /// whole mesh nearly twice that). The cache is left empty, with its tolerance, options and budget: the next
    /// update meshes every chunk of the map again. `freed(bytes)` is called once the cache's
    /// bookkeeping and empty chunk meshes are gone (with 0), after every 64 MiB or so of
    /// chunk meshes (and the assembly's index behind them) freed, and at the end, with the
    /// bytes freed since the last call
    /// (see [`MeshStoreMemory`]): for a process whose allocator keeps freed memory until asked
    /// to return it. The same mesh as [`IncrementalMesher::mesh`].
    pub fn take_mesh(&mut self, mut freed: impl FnMut(usize)) -> LabeledMesh {
        let entries = std::mem::take(&mut self.entries);
        let meshes = std::mem::take(&mut self.meshes);
        // The generation goes on: readers of `remeshed_since` see every chunk meshed again.
        *self = Self {
            tolerance: self.tolerance,
            config: self.config,
            budget: self.budget,
            generation: self.generation,
            voxel_size: self.voxel_size,
            ..Self::new()
        };
        // Empty chunk meshes (most of a map's chunks) add nothing: they go at once, with the
        // entries, before the assembly's index arrays are made.
        let mut order: Vec<((i32, i32, i32), ChunkKey, PackedChunkMesh)> = entries
            .into_iter()
            .zip(meshes)
            .filter(|(_, m)| !m.is_empty())
            .map(|(e, m)| (key_order(e.key), e.key, m))
            .collect();
        freed(0);
        order.sort_unstable_by_key(|(k, _, _)| *k);
        let meshes: Vec<(ChunkKey, PackedChunkMesh)> = order.into_iter().map(|(_, key, m)| (key, m)).collect();
        assemble_from(PackedMeshes::new(meshes, self.voxel_size), self.config.min_component_triangles, freed)
    }
}
