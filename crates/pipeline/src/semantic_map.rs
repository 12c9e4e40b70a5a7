//! The semantic side of the map: the surface summarised in coarse cells at the network's voxel
//! size (5 cm), kept up to date chunk by chunk, and the class probabilities accumulated per
//! cell over the semantic passes.
//!
//! The surface is the incremental mesh's vertices. At a keyframe the front end has just
//! re-meshed every chunk that changed, so the cells are brought up to date from those chunk
//! meshes alone: no second pass over the voxels (which cost as much as meshing itself), and
//! the network sees the same kind of input it was trained on (reconstructions of rendered
//! scans are meshes too, see `semrecon make-scans`).
//!
//! Cells live on the map frame's grid, not the gravity-aligned one: the up estimate may change
//! from pass to pass, the stored labels must not move with it. Each cell is summarised by
//! integer sums (fixed-point positions, colours, quantised normals, counts), so that a chunk's
//! old contribution can be subtracted exactly when it changes and the result never depends on
//! the order of updates.
//!
//! Probabilities are summed over passes (the label is the arg-max of the sum): a cell's label
//! settles as evidence accumulates instead of flickering with each pass, and later passes, made
//! on more complete geometry, still outvote early ones once they agree with each other.

use std::collections::{BTreeSet, HashMap};
use std::sync::OnceLock;

use glam::{IVec3, Vec3};
use rayon::prelude::*;
use semrecon_data::class::UNLABELED;
use semrecon_recon::map::ChunkHashBuilder;
use semrecon_recon::{ChunkKey, ChunkMesh, IncrementalMesher};
use wide::{f32x8, i32x8};

use crate::gravity::SurfaceSample;
use crate::label_islands::merge_small_islands;

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
    /// Adds one surface point, already in fixed point.
    fn add_point(&mut self, position: [i64; 3], color: [u8; 3], normal: [i64; 3]) {
        for k in 0..3 {
            self.position[k] += position[k];
            self.color[k] += u64::from(color[k]);
            self.normal[k] += normal[k];
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
    /// Mean position of its surface points (mesh vertices), metres, map frame.
    pub position: Vec3,
    /// Mean colour.
    pub color: [u8; 3],
    /// Mean normal (unit, or zero).
    pub normal: Vec3,
    /// Number of surface points.
    pub points: u64,
}

/// A chunk's contribution to the cells it overlaps.
type ChunkCells = Vec<(CellKey, CellSum)>;

/// Order of cells and tiles: z, then y, then x.
fn order(k: IVec3) -> (i32, i32, i32) {
    (k.z, k.y, k.x)
}

/// The surface of the map in coarse cells, updated from changed chunks only.
#[derive(Debug, Clone)]
pub struct SurfaceCells {
    cell_size: f32,
    /// Fixed-point position steps per metre.
    position_scale: f32,
    /// The mesher generation the cells are up to date with.
    generation: u64,
    /// Chunk -> its contribution per cell (chunks whose mesh has vertices only).
    chunks: HashMap<ChunkKey, ChunkCells, ChunkHashBuilder>,
    /// Hashed: a keyframe adds and subtracts a few parts for each of some 10^4 re-meshed
    /// chunks, where a B-tree's lookups cost more than all the summing.
    cells: HashMap<CellKey, CellSum, ChunkHashBuilder>,
    /// The keys of `cells` in (z, y, x) order, for every ordered read.
    ordered: Vec<CellKey>,
    /// Surface points of each cell when it was last reported changed.
    seen: HashMap<CellKey, u64, ChunkHashBuilder>,
}

impl SurfaceCells {
    /// Empty; cells of `cell_size` metres over a map of `voxel_size` metres.
    pub fn new(cell_size: f32, voxel_size: f32) -> Self {
        Self {
            cell_size,
            position_scale: POSITION_STEPS_PER_VOXEL / voxel_size,
            generation: 0,
            chunks: HashMap::default(),
            cells: HashMap::default(),
            ordered: Vec::new(),
            seen: HashMap::default(),
        }
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

    /// Brings the cells up to date with the chunk meshes `mesher` re-made since the last call
    /// (and forgets the chunks it dropped); returns the keys of the chunks whose contribution
    /// changed, sorted (a re-meshed chunk whose sums came out the same is not among them).
    /// Call it after [`IncrementalMesher::update`].
    pub fn update(&mut self, mesher: &IncrementalMesher) -> Vec<ChunkKey> {
        let mut remeshed: Vec<(ChunkKey, &ChunkMesh)> = mesher.remeshed_since(self.generation).collect();
        self.generation = mesher.generation();
        remeshed.sort_unstable_by_key(|(k, _)| order(*k));
        let freed: Vec<ChunkKey> = self.chunks.keys().filter(|k| mesher.chunk_mesh(**k).is_none()).copied().collect();
        // The per-chunk sums in parallel; only merging them is serial.
        let all_parts: Vec<ChunkCells> = remeshed.par_iter().map(|(_, mesh)| self.chunk_cells(mesh)).collect();
        let mut changed = Vec::with_capacity(remeshed.len() + freed.len());
        for ((key, _), parts) in remeshed.iter().zip(all_parts) {
            // A chunk re-meshed for its neighbour's sake often keeps its sums exactly.
            if self.chunks.get(key).map_or(parts.is_empty(), |old| *old == parts) {
                continue;
            }
            for (c, s) in &parts {
                self.cells.entry(*c).or_default().add(s);
            }
            let old = if parts.is_empty() { self.chunks.remove(key) } else { self.chunks.insert(*key, parts) };
            if let Some(old) = old {
                self.remove_parts(&old);
            }
            changed.push(*key);
        }
        for key in &freed {
            if let Some(old) = self.chunks.remove(key) {
                self.remove_parts(&old);
            }
        }
        changed.extend(freed);
        changed.sort_unstable_by_key(|k| order(*k));
        self.ordered = self.cells.keys().copied().collect();
        self.ordered.sort_unstable_by_key(|k| order(*k));
        changed
    }

    /// A chunk mesh's vertices summed per cell, in (z, y, x) cell order.
    ///
    /// The per-vertex conversions (cell, fixed-point position and normal) run 8 vertices at a
    /// time; they were most of the semantic snapshot's time one by one. The integer results,
    /// and so the sums, are exactly those of [`SurfaceCells::chunk_cells_reference`], which a
    /// chunk falls back to if it holds a value the 32-bit lanes cannot carry (a vertex
    /// further than about 40 km from the origin) or its attribute arrays differ in length.
    fn chunk_cells(&self, mesh: &ChunkMesh) -> ChunkCells {
        let n = mesh.positions.len();
        if mesh.colors.len() != n || mesh.normals.len() != n {
            return self.chunk_cells_reference(mesh);
        }
        let cell_size = f32x8::splat(self.cell_size);
        let position_scale = f32x8::splat(self.position_scale);
        let normal_scale = f32x8::splat(NORMAL_SCALE);
        // Up to 8 cells on the stack (a 4 cm chunk meets at most 8 cells of 5 cm): growing a
        // list per chunk cost as much as the sums.
        let mut parts = [((0, 0, 0), CellSum::default()); 8];
        let mut len = 0;
        let mut last = 0;
        for ((ps, ns), cs) in mesh.positions.chunks(8).zip(mesh.normals.chunks(8)).zip(mesh.colors.chunks(8)) {
            let axis = |v: &[Vec3], k: usize| {
                let mut a = [0.0f32; 8];
                for (x, p) in a.iter_mut().zip(v) {
                    *x = p[k];
                }
                f32x8::from(a)
            };
            let (px, py, pz) = (axis(ps, 0), axis(ps, 1), axis(ps, 2));
            let (nx, ny, nz) = (axis(ns, 0), axis(ns, 1), axis(ns, 2));
            let (qx, qy, qz) = (px / cell_size, py / cell_size, pz / cell_size);
            let (sx, sy, sz) = (px * position_scale, py * position_scale, pz * position_scale);
            let (mx, my, mz) = (nx * normal_scale, ny * normal_scale, nz * normal_scale);
            // Every lane must convert exactly: finite and inside i32 (NaN fails the test).
            let limit = f32x8::splat(LANE_LIMIT);
            if ![qx, qy, qz, sx, sy, sz, mx, my, mz].iter().all(|v| v.abs().simd_lt(limit).all()) {
                return self.chunk_cells_reference(mesh);
            }
            let (cx, cy, cz) = (floor_lanes(qx), floor_lanes(qy), floor_lanes(qz));
            let (rx, ry, rz) = (round_lanes(sx), round_lanes(sy), round_lanes(sz));
            let (ox, oy, oz) = (round_lanes(mx), round_lanes(my), round_lanes(mz));
            for (j, color) in cs.iter().enumerate() {
                let c = (cz[j], cy[j], cx[j]);
                if last >= len || parts[last].0 != c {
                    last = match parts[..len].iter().position(|(k, _)| *k == c) {
                        Some(i) => i,
                        None if len < parts.len() => {
                            parts[len] = (c, CellSum::default());
                            len += 1;
                            len - 1
                        }
                        // More cells than a chunk of the usual size meets (cells smaller than
                        // chunks): the reference handles any number.
                        None => return self.chunk_cells_reference(mesh),
                    };
                }
                parts[last].1.add_point(
                    [rx[j], ry[j], rz[j]].map(i64::from),
                    *color,
                    [ox[j], oy[j], oz[j]].map(i64::from),
                );
            }
        }
        let parts = &mut parts[..len];
        parts.sort_unstable_by_key(|(k, _)| *k);
        parts.iter().map(|&((z, y, x), s)| (IVec3::new(x, y, z), s)).collect()
    }

    /// [`SurfaceCells::chunk_cells`] one vertex at a time: the specification.
    fn chunk_cells_reference(&self, mesh: &ChunkMesh) -> ChunkCells {
        // A chunk overlaps a handful of cells (at most 8 when cells are larger than chunks),
        // so a short list searched linearly beats any map; consecutive vertices mostly fall
        // in the same cell, hence the last-hit shortcut.
        let mut parts: Vec<((i32, i32, i32), CellSum)> = Vec::new();
        let mut last = usize::MAX;
        for (i, p) in mesh.positions.iter().enumerate() {
            let c = order(self.cell_of_point(*p));
            if last >= parts.len() || parts[last].0 != c {
                last = match parts.iter().position(|(k, _)| *k == c) {
                    Some(i) => i,
                    None => {
                        parts.push((c, CellSum::default()));
                        parts.len() - 1
                    }
                };
            }
            let color = mesh.colors.get(i).copied().unwrap_or_default();
            let normal = mesh.normals.get(i).copied().unwrap_or_default();
            parts[last].1.add_point(
                [0, 1, 2].map(|k| round_i64(p[k] * self.position_scale)),
                color,
                [0, 1, 2].map(|k| round_i64(normal[k] * NORMAL_SCALE)),
            );
        }
        parts.sort_unstable_by_key(|(k, _)| *k);
        parts.into_iter().map(|((z, y, x), s)| (IVec3::new(x, y, z), s)).collect()
    }

    fn remove_parts(&mut self, parts: &[(CellKey, CellSum)]) {
        for (c, s) in parts {
            if let Some(e) = self.cells.get_mut(c) {
                e.sub(s);
                if e.count == 0 {
                    self.cells.remove(c);
                }
            }
        }
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
        self.ordered_cells()
            .filter_map(|(k, s)| {
                let t = k.div_euclid(IVec3::splat(tile_cells));
                let t = (t.z, t.y, t.x);
                context.contains(&t).then(|| (self.cell(k, s), update.contains(&t)))
            })
            .collect()
    }
}

/// Class probabilities summed per cell over the passes, and the classes read from them.
///
/// A cell's class is the arg-max of its sums, after islands of a class smaller than
/// `min_island_cells` have taken their surroundings' class ([`crate::label_islands`]); the
/// cleaned classes are worked out when first asked for after a change.
#[derive(Debug, Clone, Default)]
pub struct LabelStore {
    probs: HashMap<CellKey, [f32; CLASSES], ChunkHashBuilder>,
    min_island_cells: usize,
    classes: OnceLock<HashMap<CellKey, u8, ChunkHashBuilder>>,
}

impl LabelStore {
    /// An empty store whose islands of fewer than `min_island_cells` cells are merged into
    /// their surroundings (0: none are).
    pub fn new(min_island_cells: usize) -> Self {
        Self { min_island_cells, ..Self::default() }
    }

    /// Adds one pass's probabilities (rows of `CLASSES`, summing to 1) for `keys`.
    pub fn accumulate(&mut self, keys: &[CellKey], probs: &[[f32; CLASSES]]) {
        self.classes.take();
        for (k, p) in keys.iter().zip(probs) {
            let e = self.probs.entry(*k).or_insert([0.0; CLASSES]);
            for (a, b) in e.iter_mut().zip(p) {
                *a += b;
            }
        }
    }

    /// Forgets the labels of the cells for which `keep` is false (cells that lost their
    /// surface: early noise that later observations carved away).
    pub fn retain(&mut self, mut keep: impl FnMut(CellKey) -> bool) {
        self.classes.take();
        self.probs.retain(|k, _| keep(*k));
    }

    /// Cells with a label.
    pub fn len(&self) -> usize {
        self.probs.len()
    }

    /// Whether no cell has a label yet.
    pub fn is_empty(&self) -> bool {
        self.probs.is_empty()
    }

    fn classes(&self) -> &HashMap<CellKey, u8, ChunkHashBuilder> {
        self.classes
            .get_or_init(|| merge_small_islands(&self.raw_labels(), self.min_island_cells).into_iter().collect())
    }

    /// The arg-max classes, in (z, y, x) order.
    fn raw_labels(&self) -> Vec<(CellKey, u8)> {
        let mut v: Vec<(CellKey, u8)> = self.probs.iter().map(|(k, p)| (*k, argmax(p) as u8)).collect();
        v.sort_unstable_by_key(|(k, _)| order(*k));
        v
    }

    /// The class of cell `key` (arg-max of its summed probabilities, the lowest id on ties,
    /// unless its island was merged), [`UNLABELED`] when no pass labelled it.
    pub fn label(&self, key: CellKey) -> u8 {
        self.classes().get(&key).copied().unwrap_or(UNLABELED)
    }

    /// The class of cell `key`, else of the neighbouring cell (26-neighbourhood) with the most
    /// evidence (a vertex can lie in a cell no pass has labelled yet: meshed after the last pass).
    pub fn label_near(&self, key: CellKey) -> u8 {
        let classes = self.classes();
        if let Some(&c) = classes.get(&key) {
            return c;
        }
        let mut best: Option<(f32, CellKey)> = None;
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let n = key + IVec3::new(dx, dy, dz);
                    if let Some(p) = self.probs.get(&n) {
                        let w: f32 = p.iter().sum();
                        if best.is_none_or(|b| w > b.0) {
                            best = Some((w, n));
                        }
                    }
                }
            }
        }
        best.and_then(|b| classes.get(&b.1).copied()).unwrap_or(UNLABELED)
    }

    /// The labelled cells and their classes, in (z, y, x) order.
    pub fn labels(&self) -> Vec<(CellKey, u8)> {
        let classes = self.classes();
        let mut v: Vec<(CellKey, u8)> = classes.iter().map(|(k, c)| (*k, *c)).collect();
        v.sort_unstable_by_key(|(k, _)| order(*k));
        v
    }
}

/// `x.floor() as i32` without the library call `floor` is on x86-64 before SSE4.1 (this runs
/// per mesh vertex at every keyframe); NaN gives 0 and out-of-range values saturate.
fn floor_i32(x: f32) -> i32 {
    let t = x as i32;
    t.saturating_sub(((t as f32) > x) as i32)
}

/// Magnitude below which 8-lane conversions to `i32` are exact (the largest float below 2^31).
const LANE_LIMIT: f32 = 2_147_483_520.0;

/// [`floor_i32`] of 8 lanes, each finite and below [`LANE_LIMIT`] in magnitude.
fn floor_lanes(x: f32x8) -> [i32; 8] {
    let t = x.trunc_int();
    // `t - (t > x)`: the mask is all ones (-1) where truncation rounded up.
    let up: i32x8 = wide::bytemuck::cast(t.round_float().simd_gt(x));
    (t + up).to_array()
}

/// [`round_i64`] of 8 lanes, each finite and below [`LANE_LIMIT`] in magnitude: the same
/// addition of a half with the value's sign, then truncation.
fn round_lanes(x: f32x8) -> [i32; 8] {
    let half = f32x8::splat(0.5) | (x & f32x8::splat(-0.0));
    (x + half).trunc_int().to_array()
}

/// `x.round() as i64` (half away from zero) without the library call, for the fixed-point sums
/// (below 2^23 in magnitude: 160 m of positions at 5 mm voxels); exact except at the float just
/// below one half, which is of no consequence there.
fn round_i64(x: f32) -> i64 {
    (x + 0.5f32.copysign(x)) as i64
}

fn argmax(p: &[f32]) -> usize {
    let mut best = 0;
    for (i, &v) in p.iter().enumerate() {
        if v > p[best] {
            best = i;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Cells kept up to date from the re-meshed chunks at every keyframe equal the cells of
    /// the final mesh summed in one go, and account for every chunk-mesh vertex.
    #[test]
    fn incremental_cells_equal_the_cells_of_the_final_mesh() {
        use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
        use semrecon_data::FrameSource;
        use semrecon_recon::{TsdfConfig, TsdfMap};

        let mut config = SyntheticScanConfig::new(3);
        config.frames = 12;
        config.intrinsics = config.intrinsics.scaled(160, 120);
        let (_room, scan) = synthetic_scan(&config).expect("scan");
        let tsdf = TsdfConfig { voxel_size: 0.02, truncation_voxels: 4.0, ..TsdfConfig::default() };
        let mut map = TsdfMap::new(tsdf).expect("map");
        let mut mesher = IncrementalMesher::new();
        let mut cells = SurfaceCells::new(0.05, 0.02);
        let mut reported = 0;
        for i in 0..scan.len() {
            let frame = scan.frame(i).expect("frame");
            map.integrate(&frame, frame.world_from_camera.expect("pose")).expect("fusion");
            if i % 3 == 2 {
                mesher.update(&map);
                reported += cells.update(&mesher).len();
                // A second call with nothing re-meshed changes nothing.
                assert!(cells.update(&mesher).is_empty());
            }
        }
        assert!(reported > 0);
        let mut full_mesher = IncrementalMesher::new();
        full_mesher.update(&map);
        let mut full = SurfaceCells::new(0.05, 0.02);
        full.update(&full_mesher);
        assert!(full.len() > 50, "{} cells", full.len());
        assert_eq!(cells.cells(), full.cells());
        let vertices: usize = mesher.remeshed_since(0).map(|(_, m)| m.positions.len()).sum();
        assert_eq!(cells.cells().iter().map(|c| c.points as usize).sum::<usize>(), vertices);
        let ordered = cells.cells();
        assert!(ordered.windows(2).all(|w| order(w[0].key) < order(w[1].key)), "(z, y, x) order");
    }

    /// A chunk mesh of `n` random vertices in a 4 cm box at `origin`, some on exact cell
    /// boundaries and fixed-point half steps.
    fn random_chunk_mesh(rng: &mut rand_chacha::ChaCha8Rng, origin: Vec3, n: usize) -> ChunkMesh {
        use rand::Rng;
        let mut mesh = ChunkMesh::default();
        for i in 0..n {
            let mut p = origin + Vec3::new(rng.random(), rng.random(), rng.random()) * 0.04;
            match i % 7 {
                0 => p.x = (p.x / 0.05).round() * 0.05,
                1 => p.y = ((p.y * 51200.0).floor() + 0.5) / 51200.0,
                _ => {}
            }
            mesh.positions.push(p);
            let n = Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
            mesh.normals.push(if i % 11 == 0 { Vec3::ZERO } else { n.normalize_or_zero() });
            mesh.colors.push([rng.random(), rng.random(), rng.random()]);
        }
        mesh
    }

    #[test]
    fn eight_lane_chunk_sums_equal_the_reference() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let cells = SurfaceCells::new(0.05, 0.005);
        for case in 0..300 {
            let origin =
                Vec3::new(rng.random_range(-20.0..20.0), rng.random_range(-20.0..20.0), rng.random_range(-3.0..3.0));
            let n = [0, 1, 7, 8, 9, 40, 123][case % 7];
            let mesh = random_chunk_mesh(&mut rng, origin, n);
            assert_eq!(cells.chunk_cells(&mesh), cells.chunk_cells_reference(&mesh), "case {case}");
        }
        // Vertices whose fixed-point values do not fit 32-bit lanes, and ragged attributes,
        // take the reference path and still agree.
        let mut far = random_chunk_mesh(&mut rng, Vec3::new(5.0e4, 0.0, 0.0), 20);
        assert_eq!(cells.chunk_cells(&far), cells.chunk_cells_reference(&far));
        far.colors.pop();
        assert_eq!(cells.chunk_cells(&far), cells.chunk_cells_reference(&far));
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

    #[test]
    fn labels_settle_on_the_accumulated_evidence() {
        let mut s = LabelStore::default();
        let k = IVec3::new(1, 2, 3);
        let mut a = [0.0; CLASSES];
        a[2] = 0.9;
        a[1] = 0.1;
        let mut b = [0.0; CLASSES];
        b[1] = 0.6;
        b[2] = 0.4;
        s.accumulate(&[k], &[a]);
        s.accumulate(&[k], &[b]);
        // 1.3 for wall against 0.7 for floor: one weak pass does not flip the label.
        assert_eq!(s.label(k), 2);
        assert_eq!(s.label(IVec3::ZERO), UNLABELED);
        assert_eq!(s.label_near(k + IVec3::X), 2);
        assert_eq!(s.label_near(k + IVec3::new(2, 0, 0)), UNLABELED);
    }
}
