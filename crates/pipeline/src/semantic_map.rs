//! The semantic side of the map: the surface summarised in coarse cells at the network's voxel
//! size (5 cm), kept up to date chunk by chunk, and the class probabilities accumulated per
//! cell over the semantic passes.
//!
//! Cells live on the map frame's grid, not the gravity-aligned one: the up estimate may change
//! from pass to pass, the stored labels must not move with it. Each cell is summarised by
//! integer sums (fine voxel coordinates, colours, quantised normals, counts), so that a chunk's
//! old contribution can be subtracted exactly when it changes and the result never depends on
//! the order of updates.
//!
//! Probabilities are summed over passes (the label is the arg-max of the sum): a cell's label
//! settles as evidence accumulates instead of flickering with each pass, and later passes, made
//! on more complete geometry, still outvote early ones once they agree with each other.

use std::collections::{BTreeMap, BTreeSet, HashMap};

use glam::{IVec3, Vec3};
use rayon::prelude::*;
use semrecon_data::class::UNLABELED;
use semrecon_recon::map::ChunkHashBuilder;
use semrecon_recon::surface_voxels::chunk_surface_voxels;
use semrecon_recon::{ChunkKey, TsdfMap};

use crate::gravity::SurfaceSample;

/// Number of classes of the labels kept here (the S3DIS set).
pub const CLASSES: usize = semrecon_data::SemanticClass::COUNT;

/// Integer coordinates of a coarse cell (cell `c` covers `[c, c + 1) * cell_size` per axis).
pub type CellKey = IVec3;

/// Fixed-point scale of the normal sums.
const NORMAL_SCALE: f32 = 1024.0;

/// Exact sums over the surface voxels of one cell (or of one chunk's part of it).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct CellSum {
    voxel: [i64; 3],
    color: [u64; 3],
    normal: [i64; 3],
    count: u64,
}

impl CellSum {
    fn add(&mut self, o: &CellSum) {
        for k in 0..3 {
            self.voxel[k] += o.voxel[k];
            self.color[k] += o.color[k];
            self.normal[k] += o.normal[k];
        }
        self.count += o.count;
    }

    fn sub(&mut self, o: &CellSum) {
        for k in 0..3 {
            self.voxel[k] -= o.voxel[k];
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
    /// Mean position of its surface voxels, metres, map frame.
    pub position: Vec3,
    /// Mean colour.
    pub color: [u8; 3],
    /// Mean normal (unit, or zero).
    pub normal: Vec3,
    /// Number of surface voxels.
    pub voxels: u64,
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
    voxel_size: f32,
    band_voxels: f32,
    /// Chunk -> (revision seen, its contribution per cell).
    chunks: HashMap<ChunkKey, (u64, ChunkCells), ChunkHashBuilder>,
    cells: BTreeMap<(i32, i32, i32), CellSum>,
    /// Surface voxels of each cell when it was last reported changed.
    seen: HashMap<CellKey, u64, ChunkHashBuilder>,
}

impl SurfaceCells {
    /// Empty; cells of `cell_size` metres over a map of `voxel_size`, surface voxels within
    /// `band_voxels` of the zero crossing.
    pub fn new(cell_size: f32, voxel_size: f32, band_voxels: f32) -> Self {
        Self {
            cell_size,
            voxel_size,
            band_voxels,
            chunks: HashMap::default(),
            cells: BTreeMap::new(),
            seen: HashMap::default(),
        }
    }

    /// Cell edge, metres.
    pub fn cell_size(&self) -> f32 {
        self.cell_size
    }

    /// The cell holding map point `p`.
    pub fn cell_of_point(&self, p: Vec3) -> CellKey {
        (p / self.cell_size).floor().as_ivec3()
    }

    fn cell_of_voxel(&self, v: IVec3) -> CellKey {
        self.cell_of_point(v.as_vec3() * self.voxel_size)
    }

    /// Whether cell `key` has surface.
    pub fn contains(&self, key: CellKey) -> bool {
        self.cells.contains_key(&order(key))
    }

    /// Number of cells with surface.
    pub fn len(&self) -> usize {
        self.cells.len()
    }

    /// Whether no cell has surface.
    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    /// Re-extracts the chunks whose revision changed since the last call (and forgets freed
    /// ones); returns their keys, sorted.
    pub fn update(&mut self, map: &TsdfMap) -> Vec<ChunkKey> {
        let mut changed: Vec<ChunkKey> = map
            .chunks()
            .filter(|c| self.chunks.get(&c.key()).map(|e| e.0) != Some(c.revision()))
            .map(|c| c.key())
            .collect();
        let freed: Vec<ChunkKey> = self.chunks.keys().filter(|k| map.chunk(**k).is_none()).copied().collect();
        changed.sort_unstable_by_key(|k| order(*k));
        // Extraction and the per-chunk sums in parallel; only merging the sums is serial.
        let all_parts: Vec<ChunkCells> = changed
            .par_iter()
            .map(|key| {
                // A chunk overlaps a handful of cells (at most 8 when cells are larger than
                // chunks), so a short list searched linearly beats any map; consecutive
                // voxels mostly fall in the same cell, hence the last-hit shortcut.
                let mut parts: Vec<((i32, i32, i32), CellSum)> = Vec::new();
                let mut last = usize::MAX;
                for s in chunk_surface_voxels(map, *key, self.band_voxels) {
                    let c = order(self.cell_of_voxel(s.voxel));
                    if last >= parts.len() || parts[last].0 != c {
                        last = match parts.iter().position(|(k, _)| *k == c) {
                            Some(i) => i,
                            None => {
                                parts.push((c, CellSum::default()));
                                parts.len() - 1
                            }
                        };
                    }
                    let e = &mut parts[last].1;
                    for k in 0..3 {
                        e.voxel[k] += i64::from(s.voxel[k]);
                        e.color[k] += u64::from(s.color[k]);
                        e.normal[k] += (s.normal[k] * NORMAL_SCALE).round() as i64;
                    }
                    e.count += 1;
                }
                parts.sort_unstable_by_key(|(k, _)| *k);
                parts.into_iter().map(|((z, y, x), s)| (IVec3::new(x, y, z), s)).collect()
            })
            .collect();
        for (key, parts) in changed.iter().zip(all_parts) {
            for (c, s) in &parts {
                self.cells.entry(order(*c)).or_default().add(s);
            }
            let revision = map.chunk(*key).map_or(0, |c| c.revision());
            if let Some((_, old)) = self.chunks.insert(*key, (revision, parts)) {
                self.remove_parts(&old);
            }
        }
        for key in &freed {
            if let Some((_, old)) = self.chunks.remove(key) {
                self.remove_parts(&old);
            }
        }
        changed.extend(freed);
        changed.sort_unstable_by_key(|k| order(*k));
        changed
    }

    fn remove_parts(&mut self, parts: &[(CellKey, CellSum)]) {
        for (c, s) in parts {
            if let Some(e) = self.cells.get_mut(&order(*c)) {
                e.sub(s);
                if e.count == 0 {
                    self.cells.remove(&order(*c));
                }
            }
        }
    }

    fn cell(&self, key: (i32, i32, i32), s: &CellSum) -> Cell {
        let n = s.count.max(1) as f64;
        let mean = |v: i64| (v as f64 / n) as f32;
        let position = Vec3::new(mean(s.voxel[0]), mean(s.voxel[1]), mean(s.voxel[2])) * self.voxel_size;
        let color = [0, 1, 2].map(|k| ((s.color[k] as f64 / n).round() as u64).min(255) as u8);
        let normal = Vec3::new(s.normal[0] as f32, s.normal[1] as f32, s.normal[2] as f32).normalize_or_zero();
        Cell { key: IVec3::new(key.2, key.1, key.0), position, color, normal, voxels: s.count }
    }

    /// Every cell, in (z, y, x) order.
    pub fn cells(&self) -> Vec<Cell> {
        self.cells.iter().map(|(k, s)| self.cell(*k, s)).collect()
    }

    /// The cells as samples for the up estimate (weight: surface voxels), in (z, y, x) order.
    pub fn samples(&self) -> Vec<SurfaceSample> {
        self.cells
            .iter()
            .map(|(k, s)| {
                let c = self.cell(*k, s);
                SurfaceSample { position: c.position, normal: c.normal, weight: c.voxels as f32 }
            })
            .collect()
    }

    /// Cells whose surface changed noticeably since they were last reported: new cells, cells
    /// that lost their surface, and cells whose surface voxel count moved by more than
    /// `min_change` (a fraction) from the count they were last reported with. Re-observing a
    /// surface changes its chunks' revisions at every frame but hardly its cells, so this is
    /// what decides where the network runs again. Cells in (z, y, x) order.
    pub fn take_changed_cells(&mut self, min_change: f32) -> Vec<CellKey> {
        let mut changed = Vec::new();
        for (k, s) in &self.cells {
            let key = IVec3::new(k.2, k.1, k.0);
            let moved = match self.seen.get(&key) {
                None => true,
                Some(&old) => (s.count as f64 - old as f64).abs() > f64::from(min_change) * old as f64,
            };
            if moved {
                changed.push(key);
            }
        }
        for key in &changed {
            if let Some(s) = self.cells.get(&order(*key)) {
                self.seen.insert(*key, s.count);
            }
        }
        let mut gone: Vec<CellKey> =
            self.seen.keys().filter(|k| !self.cells.contains_key(&order(**k))).copied().collect();
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
            return self.cells.iter().map(|(k, s)| (self.cell(*k, s), true)).collect();
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
        self.cells
            .iter()
            .filter_map(|(k, s)| {
                let t = IVec3::new(k.2, k.1, k.0).div_euclid(IVec3::splat(tile_cells));
                let t = (t.z, t.y, t.x);
                context.contains(&t).then(|| (self.cell(*k, s), update.contains(&t)))
            })
            .collect()
    }
}

/// Class probabilities summed per cell over the passes.
#[derive(Debug, Clone, Default)]
pub struct LabelStore {
    probs: HashMap<CellKey, [f32; CLASSES], ChunkHashBuilder>,
}

impl LabelStore {
    /// Adds one pass's probabilities (rows of `CLASSES`, summing to 1) for `keys`.
    pub fn accumulate(&mut self, keys: &[CellKey], probs: &[[f32; CLASSES]]) {
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

    /// The class of cell `key` (arg-max of its summed probabilities; the lowest id on ties),
    /// [`UNLABELED`] when no pass labelled it.
    pub fn label(&self, key: CellKey) -> u8 {
        self.probs.get(&key).map_or(UNLABELED, |p| argmax(p) as u8)
    }

    /// The class of cell `key`, else of the neighbouring cell (26-neighbourhood) with the most
    /// evidence (a mesh vertex can sit just outside the cells that hold surface voxels).
    pub fn label_near(&self, key: CellKey) -> u8 {
        if let Some(p) = self.probs.get(&key) {
            return argmax(p) as u8;
        }
        let mut best: Option<(f32, u8)> = None;
        for dz in -1..=1 {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    if let Some(p) = self.probs.get(&(key + IVec3::new(dx, dy, dz))) {
                        let w: f32 = p.iter().sum();
                        if best.is_none_or(|b| w > b.0) {
                            best = Some((w, argmax(p) as u8));
                        }
                    }
                }
            }
        }
        best.map_or(UNLABELED, |b| b.1)
    }

    /// The labelled cells and their classes, in (z, y, x) order.
    pub fn labels(&self) -> Vec<(CellKey, u8)> {
        let mut v: Vec<(CellKey, u8)> = self.probs.iter().map(|(k, p)| (*k, argmax(p) as u8)).collect();
        v.sort_unstable_by_key(|(k, _)| order(*k));
        v
    }
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
