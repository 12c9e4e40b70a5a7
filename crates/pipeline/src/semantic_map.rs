//! The semantic side of the map: the surface summarised in coarse cells at the network's voxel
//! size (5 cm), kept up to date chunk by chunk (the class probabilities accumulated per cell
//! over the semantic passes are in [`crate::label_store`]).
//!
//! The surface is the TSDF's zero crossings ([`crate::surface_cells`]): the points where the
//! mesher puts its vertices, read from the chunks that changed since the last pass rather than
//! from the mesh. So the cells do not wait for the mesh: meshing can run within a budget
//! (refreshes keyframes late) while every pass sees the whole change, and the network still
//! sees the kind of input it was trained on (mesh vertices summarised per cell: reconstructions
//! of rendered scans are meshes too, see `semrecon make-scans`).
//!
//! Cells live on the map frame's grid, not the gravity-aligned one: the up estimate may change
//! from pass to pass, the stored labels must not move with it. Each cell is summarised by
//! integer sums (fixed-point positions, colours, quantised normals, counts), so
//! that a chunk's old contribution can be subtracted exactly when it changes and the result
//! never depends on the order of updates or on the number of threads.
//!
//! The labels of the cells are kept in [`crate::label_store`].

use std::collections::hash_map::Entry;
use std::collections::{BTreeSet, HashMap, HashSet};

use glam::{IVec3, Vec3};
use rayon::prelude::*;
use semrecon_recon::map::ChunkHashBuilder;
use semrecon_recon::{ChunkKey, TsdfMap, CHUNK_SIDE};

use crate::gravity::SurfaceSample;
use crate::surface_cells::{readers_of, SurfaceChunk, SurfacePoint, SurfaceRule};

mod chunk_parts;

use chunk_parts::{ChunkParts, PartOrigin};

/// Number of classes of the labels kept here (the S3DIS set).
pub const CLASSES: usize = semrecon_data::SemanticClass::COUNT;

/// Integer coordinates of a coarse cell (cell `c` covers `[c, c + 1) * cell_size` per axis).
pub type CellKey = IVec3;

/// Fixed-point scale of the normal sums.
const NORMAL_SCALE: f32 = 1024.0;

/// Fixed-point steps of the position sums per map voxel (0.02 mm at 5 mm voxels).
const POSITION_STEPS_PER_VOXEL: f32 = 256.0;

/// Exact sums over the surface points of one cell (or of one chunk's part of it).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct CellSum {
    position: [i64; 3],
    color: [u64; 3],
    normal: [i64; 3],
    count: u64,
}

impl CellSum {
    /// Adds one surface point, its position already in fixed point.
    fn add_point(&mut self, position: [i64; 3], point: &SurfacePoint) {
        for ((sum, p), (color, c)) in self.position.iter_mut().zip(position).zip(self.color.iter_mut().zip(point.color))
        {
            *sum += p;
            *color += u64::from(c);
        }
        for (sum, n) in self.normal.iter_mut().zip(point.normal.to_array()) {
            *sum += round_i64(n * NORMAL_SCALE);
        }
        self.count += 1;
    }

    fn add(&mut self, o: &CellSum) {
        for k in 0..3 {
            self.position[k] += o.position[k];
            self.color[k] += o.color[k];
            self.normal[k] += o.normal[k];
        }
        self.count += o.count;
    }

    fn sub(&mut self, o: &CellSum) {
        for k in 0..3 {
            self.position[k] -= o.position[k];
            self.color[k] -= o.color[k];
            self.normal[k] -= o.normal[k];
        }
        self.count -= o.count;
    }
}

/// One cell as the network and the up estimate see it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cell {
    /// The cell.
    pub key: CellKey,
    /// Mean position of its surface points, metres, map frame.
    pub position: Vec3,
    /// Mean colour.
    pub color: [u8; 3],
    /// Mean normal (unit, or zero).
    pub normal: Vec3,
    /// Number of surface points.
    pub points: u64,
}

/// Order of cells and tiles: z, then y, then x.
pub(crate) fn order(k: IVec3) -> (i32, i32, i32) {
    (k.z, k.y, k.x)
}

/// Sorts `keys` in [`order`] and drops repeats.
///
/// A keyframe's re-read list holds about 100,000 keys on the demo (every changed chunk and
/// its three lower neighbours), most of them twice or more; sorted as `(z, y, x)` tuples they
/// took most of the snapshot's serial part (5-6 ms a keyframe). Packed into one integer in
/// the same order they sort several times faster; keys too far out to pack (none on a map of
/// a building) fall back to the tuples.
fn sort_dedup(keys: &mut Vec<ChunkKey>) {
    const BITS: u32 = 21;
    const OFFSET: i32 = 1 << (BITS - 1);
    let packable = |k: &ChunkKey| k.to_array().iter().all(|c| (-OFFSET..OFFSET).contains(c));
    if !keys.iter().all(packable) {
        keys.sort_unstable_by_key(|k| order(*k));
        keys.dedup();
        return;
    }
    let field = |c: i32| u64::from((c + OFFSET) as u32);
    let mut packed: Vec<u64> =
        keys.iter().map(|k| (field(k.z) << (2 * BITS)) | (field(k.y) << BITS) | field(k.x)).collect();
    packed.sort_unstable();
    packed.dedup();
    let mask = (1u64 << BITS) - 1;
    let unpack = |v: u64| (v & mask) as i32 - OFFSET;
    keys.clear();
    keys.extend(packed.into_iter().map(|v| IVec3::new(unpack(v), unpack(v >> BITS), unpack(v >> (2 * BITS)))));
}

/// The surface of the map in coarse cells, updated from changed chunks only.
#[derive(Debug, Clone)]
pub struct SurfaceCells {
    cell_size: f32,
    /// Which zero crossings are surface.
    rule: SurfaceRule,
    /// Fixed-point position steps per metre.
    position_scale: f32,
    /// The largest chunk revision the cells are up to date with.
    revision: u64,
    /// Every map chunk with a revision above 0 at the last update: the map frees chunks only
    /// after loop closure, and this tells which without a lookup per tracked chunk.
    known_chunks: HashSet<ChunkKey, ChunkHashBuilder>,
    /// Chunk -> its contribution per cell (chunks with surface points only), compact
    /// ([`chunk_parts`]: most of the semantic map's memory on a whole home).
    chunks: HashMap<ChunkKey, ChunkParts, ChunkHashBuilder>,
    /// Hashed: a keyframe adds and subtracts a few parts for each of some 10^4 changed
    /// chunks, where a B-tree's lookups cost more than all the summing.
    cells: HashMap<CellKey, CellSum, ChunkHashBuilder>,
    /// The keys of `cells` in (z, y, x) order, for every ordered read.
    ordered: Vec<CellKey>,
    /// Surface points of each cell when it was last reported changed.
    seen: HashMap<CellKey, u64, ChunkHashBuilder>,
    /// A chunk that already has sums is re-read at one update in this many
    /// ([`SurfaceCells::with_refresh_every`]); 1: at every update that finds it changed.
    refresh_every: u32,
    /// Updates so far (the phase of the staggered re-reads).
    updates: u64,
    /// Chunks changed since their sums were made, waiting for their turn.
    pending: HashSet<ChunkKey, ChunkHashBuilder>,
}

impl SurfaceCells {
    /// Empty; cells of `cell_size` metres over a map whose surface `rule` says.
    pub fn new(cell_size: f32, rule: SurfaceRule) -> Self {
        Self {
            cell_size,
            rule,
            position_scale: POSITION_STEPS_PER_VOXEL / rule.voxel_size,
            revision: 0,
            known_chunks: HashSet::default(),
            chunks: HashMap::default(),
            cells: HashMap::default(),
            ordered: Vec::new(),
            seen: HashMap::default(),
            refresh_every: 1,
            updates: 0,
            pending: HashSet::default(),
        }
    }

    /// Re-reads a changed chunk that already has sums at one update in `updates` only (its
    /// turn staggered by its key, so each update re-reads about a fraction `1 / updates` of
    /// them), keeping its old sums until then; a chunk with no sums yet (new surface) and a
    /// freed chunk are read at once. On a live map most of a keyframe's changed chunks hold
    /// surface seen before, which more depth only moves within its voxels, by fractions of a
    /// millimetre: a cell of ten voxels barely feels it, while reading the chunk's surface
    /// is most of the semantic snapshot (the demo: 11,000 surface chunks a keyframe, 48 ms).
    /// [`SurfaceCells::update_with`] with `flush` reads every waiting chunk (the final pass
    /// of a scan); after it, the sums are exactly those of the map. `updates` of 0 or 1: every
    /// changed chunk at every update, as without this.
    pub fn with_refresh_every(mut self, updates: u32) -> Self {
        self.refresh_every = updates.max(1);
        self
    }

    /// Whether some changed chunks are waiting for their turn ([`SurfaceCells::with_refresh_every`]).
    pub fn has_pending(&self) -> bool {
        !self.pending.is_empty()
    }

    /// Cell edge, metres.
    pub fn cell_size(&self) -> f32 {
        self.cell_size
    }

    /// The cell holding map point `p`.
    pub fn cell_of_point(&self, p: Vec3) -> CellKey {
        let q = p / self.cell_size;
        IVec3::new(floor_i32(q.x), floor_i32(q.y), floor_i32(q.z))
    }

    /// The cells with their sums, in (z, y, x) order.
    fn ordered_cells(&self) -> impl Iterator<Item = (CellKey, &CellSum)> + '_ {
        self.ordered.iter().filter_map(|k| self.cells.get(k).map(|s| (*k, s)))
    }

    /// Frees the cells' sums and the per-chunk parts (most of the semantic map's memory) while
    /// no update needs them, e.g. at the end of a scan while the final mesh is assembled beside
    /// the map. Only the surface point count each cell was last reported with stays, so that
    /// [`SurfaceCells::take_changed_cells`] still reports only real changes. The next
    /// [`SurfaceCells::update`] reads every chunk of the map again, and its exact integer sums
    /// come out the same as if nothing had been released.
    pub fn release(&mut self) {
        self.revision = 0;
        self.known_chunks = HashSet::default();
        self.chunks = HashMap::default();
        self.cells = HashMap::default();
        self.ordered = Vec::new();
        self.pending = HashSet::default();
    }

    /// Heap bytes held: the hash tables at their capacity (a control byte an entry), the
    /// chunks' parts and the ordered keys. What the cells cost beside the TSDF map; most of it
    /// is the per-chunk parts.
    pub fn heap_bytes(&self) -> usize {
        let parts: usize = self.chunks.values().map(ChunkParts::heap_bytes).sum();
        set_bytes(&self.known_chunks)
            + table_bytes(&self.chunks)
            + parts
            + table_bytes(&self.cells)
            + self.ordered.capacity() * std::mem::size_of::<CellKey>()
            + table_bytes(&self.seen)
            + set_bytes(&self.pending)
    }

    /// Whether cell `key` has surface.
    pub fn contains(&self, key: CellKey) -> bool {
        self.cells.contains_key(&key)
    }

    /// Number of cells with surface.
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    /// Whether no cell has surface.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// Brings the cells up to date with the chunks of `map` that changed since the last call
    /// (and forgets the chunks it freed); returns the keys of the chunks whose contribution
    /// changed, sorted (a re-read chunk whose sums came out the same is not among them).
    pub fn update(&mut self, map: &TsdfMap) -> Vec<ChunkKey> {
        self.update_with(map, false)
    }

    /// [`SurfaceCells::update`]; with `flush`, every chunk waiting for its turn
    /// ([`SurfaceCells::with_refresh_every`]) is read too.
    pub fn update_with(&mut self, map: &TsdfMap, flush: bool) -> Vec<ChunkKey> {
        let mut changed_chunks = Vec::new();
        let mut revised = 0;
        let mut revision = self.revision;
        for c in map.chunks() {
            revised += usize::from(c.revision() > 0);
            if c.revision() > self.revision {
                changed_chunks.push(c.key());
                revision = revision.max(c.revision());
            }
        }
        self.revision = revision;
        self.known_chunks.extend(changed_chunks.iter().copied());
        // Every chunk with a revision is known, so more known than revised means frees.
        if self.known_chunks.len() > revised {
            let freed: Vec<ChunkKey> = self.known_chunks.iter().filter(|k| map.chunk(**k).is_none()).copied().collect();
            for k in &freed {
                self.known_chunks.remove(k);
            }
            changed_chunks.extend(freed);
        }
        // A chunk's voxels are read by its own points and its lower face neighbours'.
        let mut reread: Vec<ChunkKey> = changed_chunks.iter().flat_map(|k| readers_of(*k)).collect();
        if self.refresh_every > 1 || !self.pending.is_empty() {
            self.updates += 1;
            let every = u64::from(self.refresh_every);
            let phase = self.updates;
            // Deterministic: the turn depends on the key and the update count only.
            let due = |k: &ChunkKey| {
                flush || every <= 1 || {
                    let h = (k.x as u64).wrapping_mul(0x9E37_79B9)
                        ^ (k.y as u64).wrapping_mul(0x85EB_CA6B)
                        ^ (k.z as u64).wrapping_mul(0xC2B2_AE35);
                    h.wrapping_add(phase).is_multiple_of(every)
                }
            };
            reread.extend(self.pending.iter().filter(|k| due(k)).copied());
            sort_dedup(&mut reread);
            reread.retain(|k| {
                let wait = !due(k) && self.chunks.contains_key(k) && map.chunk(*k).is_some();
                if wait {
                    self.pending.insert(*k);
                } else {
                    self.pending.remove(k);
                }
                !wait
            });
        } else {
            sort_dedup(&mut reread);
        }
        // The per-chunk sums in parallel, each worker over runs of neighbouring chunks, asking
        // for the next chunk's voxels while it reads one; only merging them is serial.
        let this = &*self;
        let all_parts: Vec<ChunkParts> = reread
            .par_chunks(64)
            .flat_map_iter(|keys| {
                // Each chunk and its neighbours are looked up once, a chunk ahead.
                let mut next = keys.first().and_then(|k| SurfaceChunk::find(map, *k));
                (0..keys.len()).map(move |i| {
                    let chunk = next;
                    next = keys.get(i + 1).and_then(|k| SurfaceChunk::find(map, *k));
                    if let Some(n) = &next {
                        n.prefetch();
                    }
                    chunk.map_or_else(ChunkParts::empty, |c| {
                        ChunkParts::encode(this.chunk_cells(&c), this.part_origin(c.key()))
                    })
                })
            })
            .collect();
        let mut changed = Vec::with_capacity(reread.len());
        // Cells that gained or lost their entry: the only keys whose place in `ordered` changes.
        let mut appeared_or_gone = Vec::new();
        for (key, parts) in reread.iter().zip(all_parts) {
            // A chunk re-read for its neighbour's sake often keeps its sums exactly.
            if self.chunks.get(key).map_or(parts.is_empty(), |old| *old == parts) {
                continue;
            }
            let origin = self.part_origin(*key);
            parts.for_each(origin, |c, s| match self.cells.entry(c) {
                Entry::Occupied(mut e) => e.get_mut().add(s),
                Entry::Vacant(e) => {
                    e.insert(*s);
                    appeared_or_gone.push(c);
                }
            });
            let old = if parts.is_empty() { self.chunks.remove(key) } else { self.chunks.insert(*key, parts) };
            if let Some(old) = old {
                self.remove_parts(&old, origin, &mut appeared_or_gone);
            }
            changed.push(*key);
        }
        self.reorder(appeared_or_gone);
        changed
    }

    /// The surface points of chunk `key` summed per cell, in (z, y, x) cell order: the cell
    /// and the fixed-point position of each point as [`SurfaceCells::cell_of_point`] and
    /// [`round_i64`] give them (the specification, see `reference_cells` in the tests).
    ///
    /// Off its edge's axis a point sits exactly on its lower voxel's coordinate, so those
    /// coordinates' cells and fixed-point values are looked up from tables made once per
    /// chunk; only the coordinate along the edge is converted per point.
    fn chunk_cells(&self, chunk: &SurfaceChunk) -> Vec<(CellKey, CellSum)> {
        let side = CHUNK_SIDE as i32;
        let first_voxel = chunk.key() * side;
        // Per axis and local voxel coordinate: the cell and the fixed-point coordinate.
        let mut tables: Option<[[(i32, i64); CHUNK_SIDE]; 3]> = None;
        // A chunk overlaps a handful of cells (at most 8 when cells are larger than chunks),
        // so a short list searched linearly beats any map; consecutive points mostly fall in
        // the same cell, hence the last-hit shortcut.
        let mut parts: Vec<((i32, i32, i32), CellSum)> = Vec::new();
        let mut last = usize::MAX;
        chunk.for_each_point(&self.rule, |point| {
            let tables = tables.get_or_insert_with(|| {
                std::array::from_fn(|k| {
                    std::array::from_fn(|i| {
                        let x = (first_voxel[k] + i as i32) as f32 * self.rule.voxel_size;
                        (floor_i32(x / self.cell_size), round_i64(x * self.position_scale))
                    })
                })
            });
            let local = point.low - first_voxel;
            let axis = point.axis as usize;
            let mut cell = [0; 3];
            let mut position = [0; 3];
            for k in 0..3 {
                let (c, p) = if k == axis {
                    let x = point.position[k];
                    (floor_i32(x / self.cell_size), round_i64(x * self.position_scale))
                } else {
                    tables[k][(local[k] as usize) & (CHUNK_SIDE - 1)]
                };
                cell[k] = c;
                position[k] = p;
            }
            let c = (cell[2], cell[1], cell[0]);
            if last >= parts.len() || parts[last].0 != c {
                last = match parts.iter().position(|(k, _)| *k == c) {
                    Some(i) => i,
                    None => {
                        parts.push((c, CellSum::default()));
                        parts.len() - 1
                    }
                };
            }
            parts[last].1.add_point(position, &point);
        });
        parts.sort_unstable_by_key(|(k, _)| *k);
        parts.into_iter().map(|((z, y, x), s)| (IVec3::new(x, y, z), s)).collect()
    }

    /// Where chunk `key`'s parts are measured from (see [`chunk_parts`]).
    fn part_origin(&self, key: ChunkKey) -> PartOrigin {
        let first_voxel = key * CHUNK_SIDE as i32;
        PartOrigin {
            cell: self.cell_of_point(first_voxel.as_vec3() * self.rule.voxel_size),
            position: first_voxel.to_array().map(|v| i64::from(v) * POSITION_STEPS_PER_VOXEL as i64),
        }
    }

    /// Subtracts a chunk's old parts; cells left without points are dropped and listed in
    /// `gone`.
    fn remove_parts(&mut self, parts: &ChunkParts, origin: PartOrigin, gone: &mut Vec<CellKey>) {
        parts.for_each(origin, |c, s| {
            if let Some(e) = self.cells.get_mut(&c) {
                e.sub(s);
                if e.count == 0 {
                    self.cells.remove(&c);
                    gone.push(c);
                }
            }
        });
    }

    /// Brings `ordered` (the keys of `cells` in (z, y, x) order) up to date after the keys
    /// `touched` gained or lost their entry in `cells`: one merge of the few touched keys into
    /// the ordered list, where collecting and sorting every key again took 5-10 ms a
    /// keyframe on a home of 10^5 cells. The same list either way (tested against the sort).
    fn reorder(&mut self, mut touched: Vec<CellKey>) {
        if touched.is_empty() {
            return;
        }
        touched.sort_unstable_by_key(|k| order(*k));
        touched.dedup();
        let mut merged = Vec::with_capacity(self.cells.len());
        let mut old = self.ordered.iter().copied().peekable();
        for t in touched {
            while let Some(o) = old.next_if(|o| order(*o) < order(t)) {
                merged.push(o);
            }
            old.next_if_eq(&t);
            if self.cells.contains_key(&t) {
                merged.push(t);
            }
        }
        merged.extend(old);
        self.ordered = merged;
    }

    fn cell(&self, key: CellKey, s: &CellSum) -> Cell {
        let n = s.count.max(1) as f64;
        let mean = |v: i64| (v as f64 / n / f64::from(self.position_scale)) as f32;
        let position = Vec3::new(mean(s.position[0]), mean(s.position[1]), mean(s.position[2]));
        let color = [0, 1, 2].map(|k| ((s.color[k] as f64 / n).round() as u64).min(255) as u8);
        let normal = Vec3::new(s.normal[0] as f32, s.normal[1] as f32, s.normal[2] as f32).normalize_or_zero();
        Cell { key, position, color, normal, points: s.count }
    }

    /// Every cell, in (z, y, x) order.
    pub fn cells(&self) -> Vec<Cell> {
        self.ordered_cells().map(|(k, s)| self.cell(k, s)).collect()
    }

    /// The cells as samples for the up estimate (weight: surface points), in (z, y, x) order.
    pub fn samples(&self) -> Vec<SurfaceSample> {
        self.ordered_cells()
            .map(|(k, s)| {
                let c = self.cell(k, s);
                SurfaceSample { position: c.position, normal: c.normal, weight: c.points as f32 }
            })
            .collect()
    }

    /// Cells whose surface changed noticeably since they were last reported: new cells, cells
    /// that lost their surface, and cells whose surface point count moved by more than
    /// `min_change` (a fraction) from the count they were last reported with. Re-observing a
    /// surface changes its chunks' revisions at every frame but hardly its cells, so this is
    /// what decides where the network runs again. Cells in (z, y, x) order.
    pub fn take_changed_cells(&mut self, min_change: f32) -> Vec<CellKey> {
        let mut changed = Vec::new();
        for (key, s) in self.ordered_cells() {
            let moved = match self.seen.get(&key) {
                None => true,
                Some(&old) => (s.count as f64 - old as f64).abs() > f64::from(min_change) * old as f64,
            };
            if moved {
                changed.push(key);
            }
        }
        for key in &changed {
            if let Some(s) = self.cells.get(key) {
                self.seen.insert(*key, s.count);
            }
        }
        let mut gone: Vec<CellKey> = self.seen.keys().filter(|k| !self.cells.contains_key(*k)).copied().collect();
        gone.sort_unstable_by_key(|k| order(*k));
        for k in &gone {
            self.seen.remove(k);
        }
        changed.extend(gone);
        changed.sort_unstable_by_key(|k| order(*k));
        changed
    }

    /// Tiles (cubes of `tile_cells` cells) holding the given cells.
    pub fn tiles_of_cells(&self, cells: &[CellKey], tile_cells: i32) -> BTreeSet<(i32, i32, i32)> {
        cells
            .iter()
            .map(|c| {
                let t = c.div_euclid(IVec3::splat(tile_cells));
                (t.z, t.y, t.x)
            })
            .collect()
    }

    /// The cells of a pass: those in `update` tiles (labels to write back) and those within
    /// `context_tiles` tiles of them (input only). With `update` = `None`, every cell is both.
    /// Cells in (z, y, x) order, each with whether its labels are written back.
    pub fn select(
        &self,
        update: Option<&BTreeSet<(i32, i32, i32)>>,
        tile_cells: i32,
        context_tiles: i32,
    ) -> Vec<(Cell, bool)> {
        let Some(update) = update else {
            return self.ordered_cells().map(|(k, s)| (self.cell(k, s), true)).collect();
        };
        let mut context = BTreeSet::new();
        for &(z, y, x) in update {
            for dz in -context_tiles..=context_tiles {
                for dy in -context_tiles..=context_tiles {
                    for dx in -context_tiles..=context_tiles {
                        context.insert((z + dz, y + dy, x + dx));
                    }
                }
            }
        }
        // Cells in (z, y, x) order come in runs along x that share a tile: the two set
        // lookups are made once per run, not per cell (10^5 cells a keyframe on a home).
        let mut last: Option<((i32, i32, i32), Option<bool>)> = None;
        self.ordered_cells()
            .filter_map(|(k, s)| {
                let t = k.div_euclid(IVec3::splat(tile_cells));
                let t = (t.z, t.y, t.x);
                let write_back = match last {
                    Some((tile, w)) if tile == t => w,
                    _ => {
                        let w = context.contains(&t).then(|| update.contains(&t));
                        last = Some((t, w));
                        w
                    }
                };
                write_back.map(|w| (self.cell(k, s), w))
            })
            .collect()
    }
}

/// Heap bytes of a hash map at its capacity: an entry and a control byte a slot (hashbrown's
/// layout; its slack beyond the capacity is not counted).
pub(crate) fn table_bytes<K, V, S>(table: &HashMap<K, V, S>) -> usize {
    table.capacity() * (std::mem::size_of::<(K, V)>() + 1)
}

/// [`table_bytes`] of a hash set.
fn set_bytes<K, S>(set: &HashSet<K, S>) -> usize {
    set.capacity() * (std::mem::size_of::<K>() + 1)
}

/// `x.floor() as i32` without the library call `floor` is on x86-64 before SSE4.1 (this runs
/// per surface point at every keyframe); NaN gives 0 and out-of-range values saturate.
fn floor_i32(x: f32) -> i32 {
    let t = x as i32;
    t.saturating_sub(((t as f32) > x) as i32)
}

/// `x.round() as i64` (half away from zero) without the library call, for the fixed-point sums
/// (below 2^23 in magnitude: 160 m of positions at 5 mm voxels); exact except at the float just
/// below one half, which is of no consequence there.
fn round_i64(x: f32) -> i64 {
    (x + 0.5f32.copysign(x)) as i64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packed_sort_matches_the_tuple_sort() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for range in [3, 40, (1 << 20) - 1, 1 << 20, i32::MAX] {
            let mut keys: Vec<ChunkKey> = (0..5000)
                .map(|_| {
                    IVec3::new(
                        rng.random_range(-range..range),
                        rng.random_range(-range..range),
                        rng.random_range(-range..range),
                    )
                })
                .collect();
            let mut want = keys.clone();
            want.sort_unstable_by_key(|k| order(*k));
            want.dedup();
            sort_dedup(&mut keys);
            assert_eq!(keys, want, "coordinates within {range}");
        }
    }

    /// Fuses `frames` frames of a synthetic scan at 2 cm, calling `keyframe` after every third.
    fn fuse_scan(seed: u64, frames: usize, mut keyframe: impl FnMut(&mut TsdfMap)) -> TsdfMap {
        use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
        use semrecon_data::FrameSource;
        use semrecon_recon::TsdfConfig;

        let mut config = SyntheticScanConfig::new(seed);
        config.frames = frames;
        config.intrinsics = config.intrinsics.scaled(160, 120);
        let (_room, scan) = synthetic_scan(&config).expect("scan");
        let tsdf = TsdfConfig { voxel_size: 0.02, truncation_voxels: 4.0, ..TsdfConfig::default() };
        let mut map = TsdfMap::new(tsdf).expect("map");
        for i in 0..scan.len() {
            let frame = scan.frame(i).expect("frame");
            map.integrate(&frame, frame.world_from_camera.expect("pose")).expect("fusion");
            if i % 3 == 2 {
                keyframe(&mut map);
            }
        }
        map
    }

    fn rule(map: &TsdfMap) -> SurfaceRule {
        SurfaceRule::new(map.config(), &semrecon_recon::MeshConfig::RECOMMENDED)
    }

    /// The cells of a whole map, summed from the reference points of every chunk.
    fn reference_cells(map: &TsdfMap) -> Vec<Cell> {
        let mut cells = SurfaceCells::new(0.05, rule(map));
        for key in map.sorted_keys() {
            for p in crate::surface_cells::chunk_points_reference(map, key, &cells.rule) {
                let position = [0, 1, 2].map(|k| round_i64(p.position[k] * cells.position_scale));
                cells.cells.entry(cells.cell_of_point(p.position)).or_default().add_point(position, &p);
            }
        }
        cells.ordered = cells.cells.keys().copied().collect();
        cells.ordered.sort_unstable_by_key(|k| order(*k));
        cells.cells()
    }

    /// Clears a slab of chunks and frees those left unobserved, as loop closure's
    /// re-integration does between two keyframes.
    fn clear_a_slab(map: &mut TsdfMap) {
        let keys: Vec<ChunkKey> = map.sorted_keys().into_iter().filter(|k| k.x % 3 == 0).collect();
        map.reset_chunks(&keys);
        assert!(map.free_unobserved(&keys) > 0);
    }

    /// Cells kept up to date from the chunks that changed between keyframes equal the cells
    /// of the final map summed in one go from the reference points, also after chunks were
    /// reset and freed (loop closure's re-integration) between two updates.
    #[test]
    fn incremental_cells_equal_the_cells_of_the_final_map() {
        let mut cells = None;
        let mut reported = 0;
        let mut keyframes = 0;
        let map = fuse_scan(3, 15, |map| {
            let cells = cells.get_or_insert_with(|| SurfaceCells::new(0.05, rule(map)));
            keyframes += 1;
            if keyframes == 3 {
                clear_a_slab(map);
            }
            reported += cells.update(map).len();
            // The ordered keys, kept up to date by merging, are the sorted keys.
            let mut sorted: Vec<CellKey> = cells.cells.keys().copied().collect();
            sorted.sort_unstable_by_key(|k| order(*k));
            assert_eq!(cells.ordered, sorted);
            // A second call with nothing changed changes nothing.
            assert!(cells.update(map).is_empty());
        });
        let mut cells = cells.expect("keyframes ran");
        cells.update(&map);
        assert!(reported > 0);
        // A map's chunks always fit the compact parts.
        assert!(cells.chunks.values().all(|p| matches!(p, ChunkParts::Compact(_))));
        assert!(cells.heap_bytes() > 0);
        let expected = reference_cells(&map);
        assert!(expected.len() > 50, "{} cells", expected.len());
        assert_eq!(cells.cells(), expected);
        let ordered = cells.cells();
        assert!(ordered.windows(2).all(|w| order(w[0].key) < order(w[1].key)), "(z, y, x) order");
        // Cells of planes have their normals: most of the surface of a room is walls, floor
        // and furniture faces, whose cells point along an axis of the room's own frame or
        // another, but never nowhere.
        assert!(ordered.iter().all(|c| c.points > 0));
        assert!(ordered.iter().filter(|c| c.normal != Vec3::ZERO).count() * 10 > ordered.len() * 9);
    }

    /// With staggered re-reads, chunks wait for their turn (some updates leave changed
    /// chunks pending), new surface is read at once (a pending chunk always has sums), and a
    /// flush leaves the cells exactly those of the final map, also after resets and frees.
    #[test]
    fn staggered_cells_after_a_flush_equal_the_cells_of_the_final_map() {
        let mut cells = None;
        let mut keyframes = 0;
        let mut waited = 0;
        let map = fuse_scan(3, 15, |map| {
            let cells = cells.get_or_insert_with(|| SurfaceCells::new(0.05, rule(map)).with_refresh_every(3));
            keyframes += 1;
            if keyframes == 3 {
                clear_a_slab(map);
            }
            cells.update(map);
            waited += cells.pending.len();
            assert!(cells.pending.iter().all(|k| cells.chunks.contains_key(k)), "only chunks with sums wait");
        });
        let mut cells = cells.expect("keyframes ran");
        assert!(waited > 0, "no chunk ever waited");
        cells.update_with(&map, true);
        assert!(!cells.has_pending());
        assert_eq!(cells.cells(), reference_cells(&map));
    }

    /// Released cells are empty; the next update reads the whole map again and gives the same
    /// cells, and reports no change where the surface did not change.
    #[test]
    fn released_cells_come_back_the_same() {
        let mut cells = None;
        let map = fuse_scan(5, 9, |map| {
            cells.get_or_insert_with(|| SurfaceCells::new(0.05, rule(map))).update(map);
        });
        let mut cells = cells.expect("keyframes ran");
        cells.update(&map);
        cells.take_changed_cells(0.0);
        let before = cells.cells();
        let bytes = cells.heap_bytes();
        cells.release();
        assert!(cells.is_empty() && cells.cells().is_empty());
        assert!(cells.heap_bytes() * 4 < bytes, "{} of {bytes} bytes kept", cells.heap_bytes());
        assert!(!cells.update(&map).is_empty());
        assert_eq!(cells.cells(), before);
        assert!(cells.take_changed_cells(0.0).is_empty());
        assert!(cells.update(&map).is_empty());
    }

    #[test]
    fn integer_floor_and_round_match_the_library() {
        let mut x = -3.0f32;
        while x < 3.0 {
            assert_eq!(floor_i32(x), x.floor() as i32, "{x}");
            x += 0.0625;
        }
        for x in [-2.5f32, -0.5, -0.3, 0.0, 0.3, 0.5, 1.5, 1e6 + 0.5, -1e6 - 0.5, 12345.678] {
            assert_eq!(floor_i32(x), x.floor() as i32, "{x}");
            assert_eq!(round_i64(x), x.round() as i64, "{x}");
        }
        assert_eq!(floor_i32(f32::NAN), 0);
        assert_eq!(floor_i32(-1e20), i32::MIN);
        assert_eq!(floor_i32(1e20), i32::MAX);
    }
}
