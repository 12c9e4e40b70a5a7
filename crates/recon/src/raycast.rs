//! Ray-casting the TSDF map into a predicted view: per pixel, the first zero crossing of the
//! signed distance along the viewing ray, with the surface normal and colour there.
//!
//! Tracking aligns each new frame against this prediction (frame-to-model ICP): the fused
//! model is far less noisy than the previous frame, so drift stays small. The same view
//! renders the model for display.
//!
//! The march skips unallocated chunks whole (no surface can be there), steps by the stored
//! distance in observed free space (at most a truncation, at least half a voxel) and, on a
//! positive-to-negative change of the trilinearly interpolated distance, places the surface
//! by linear interpolation between the two samples, refined by one regula falsi step (one
//! more sample, in cache: the crossing no longer depends on where the march happened to
//! start). Unobserved voxels before the first
//! observed sample are crossed a voxel at a time. A negative distance reached without a
//! positive one before it is the back of a surface: the ray stops there without a hit.
//! Normals are the normalised central-difference gradient of the interpolated distance.
//!
//! Rows are cast in parallel with rayon; every pixel depends only on the map and its ray,
//! so the view is bit-identical for any thread count.

// Comparisons are written negated on purpose, so that NaN fails them; index loops mirror
// the matrix formulas they implement.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use glam::{Affine3A, IVec3, Vec3};
use rayon::prelude::*;
use semrecon_data::Intrinsics;

use crate::cache_hint::prefetch;
use crate::map::{depth_noise, split_voxel, BandModel, Chunk, ChunkKey, TsdfMap, VoxelBlock, CHUNK_SIDE, TSDF_SCALE};

/// A predicted view of the map from one camera pose.
///
/// # Shapes
/// `vertices`, `normals` and `colors` are row-major, `intrinsics.width * intrinsics.height`
/// long. A pixel without a surface has a zero vertex and a zero normal (its `z` is 0, like
/// a missing depth).
#[derive(Debug, Clone)]
pub struct ModelView {
    /// Camera of the view.
    pub intrinsics: Intrinsics,
    /// Pose the view was cast from.
    pub world_from_camera: Affine3A,
    /// Surface points in the camera frame, metres.
    pub vertices: Vec<Vec3>,
    /// Unit surface normals in the camera frame, facing the camera.
    pub normals: Vec<Vec3>,
    /// Colour of the voxel nearest to each surface point.
    pub colors: Vec<[u8; 3]>,
}

impl ModelView {
    /// Depth image of the view (metres along the optical axis, 0 where no surface).
    pub fn depth(&self) -> Vec<f32> {
        self.vertices.iter().map(|v| v.z).collect()
    }

    /// Number of pixels with a surface.
    pub fn valid_count(&self) -> usize {
        self.vertices.iter().filter(|v| v.z > 0.0).count()
    }
}

/// Chunk lookup through a dense array of slab positions over the bounding box of the
/// allocated chunks, built once per ray-cast: a march tests a chunk every few centimetres,
/// and an array read is several times cheaper than a hash probe. Maps whose box would need
/// more than [`MAX_GRID_CELLS`] cells fall back to the hash map.
struct ChunkGrid<'a> {
    min: IVec3,
    dims: IVec3,
    /// The voxels of the chunk per cell (one pointer to follow, not slab record, then
    /// chunk record, then voxel box: each a likely cache miss on a large map); empty when
    /// falling back.
    /// The chunk record, not its voxels: a packed (cold) chunk unpacks only when a ray
    /// reaches it.
    slots: Vec<Option<&'a Chunk>>,
    /// One bit per cell, set where a chunk is allocated: most lookups of a march are in
    /// empty space, and this 64x smaller array stays in cache where `slots` (megabytes)
    /// costs a memory access per lookup.
    occupied: Vec<u64>,
}

/// Largest dense chunk grid (16 MB of pointers; a 15 m x 15 m x 4 m site at 5 mm voxels).
const MAX_GRID_CELLS: usize = 2 << 20;

impl<'a> ChunkGrid<'a> {
    fn new(map: &'a TsdfMap) -> Self {
        let mut min = IVec3::MAX;
        let mut max = IVec3::MIN;
        for c in &map.chunks {
            min = min.min(c.key);
            max = max.max(c.key);
        }
        let dims = (max - min + 1).max(IVec3::ZERO);
        let cells = dims.x as usize * dims.y as usize * dims.z as usize;
        if map.chunks.is_empty() || cells > MAX_GRID_CELLS {
            return Self { min, dims: IVec3::ZERO, slots: Vec::new(), occupied: Vec::new() };
        }
        let mut slots = vec![None; cells];
        let mut occupied = vec![0u64; cells.div_ceil(64)];
        for c in &map.chunks {
            let l = c.key - min;
            let i = (l.x + dims.x * (l.y + dims.y * l.z)) as usize;
            slots[i] = Some(c);
            occupied[i / 64] |= 1 << (i % 64);
        }
        Self { min, dims, slots, occupied }
    }
}

/// Entries of a reader's chunk cache (a power of two).
const RECENT_CHUNKS: usize = 128;

/// Reads voxels through the chunk grid and a small direct-mapped cache of the chunks met
/// lately (a cast looks up about as many chunks as it reads cells: cells at chunk faces,
/// the gradient's samples either side of one, neighbouring rays).
///
/// The cast is bound by memory latency: its reads depend on each other along a ray and
/// the map is far larger than the caches. A chunk met for the first time is therefore
/// asked for whole (its distances and weights, 32 cache lines), so that the march's
/// later reads in it find it in cache; with the tile's expected chunks asked for before
/// its rays march (see [`raycast_with`]), the demo's casts took 13-15 % less time. The
/// cache alone, without the prefetch, saved nothing measurable.
struct VoxelReader<'a> {
    map: &'a TsdfMap,
    grid: &'a ChunkGrid<'a>,
    recent: [(ChunkKey, Option<&'a VoxelBlock>); RECENT_CHUNKS],
}

impl<'a> VoxelReader<'a> {
    fn new(map: &'a TsdfMap, grid: &'a ChunkGrid<'a>) -> Self {
        Self { map, grid, recent: [(ChunkKey::MAX, None); RECENT_CHUNKS] }
    }

    #[inline]
    fn chunk(&mut self, key: ChunkKey) -> Option<&'a VoxelBlock> {
        // Neighbouring chunks differ in one coordinate by one: x + 5 y + 25 z gives the
        // chunks of any 5 x 5 x 5 block different slots (125 consecutive values).
        let h =
            (key.x as u32).wrapping_add((key.y as u32).wrapping_mul(5)).wrapping_add((key.z as u32).wrapping_mul(25));
        let slot = &self.recent[h as usize % RECENT_CHUNKS];
        if slot.0 == key {
            return slot.1;
        }
        let found = self.lookup(key);
        if let Some(b) = found {
            prefetch(&b.tsdf, 64, usize::MAX);
            prefetch(&b.weight, 64, usize::MAX);
        }
        self.recent[h as usize % RECENT_CHUNKS] = (key, found);
        found
    }

    /// The chunk at `key`, through the grid (not the cache).
    #[inline]
    fn lookup(&self, key: ChunkKey) -> Option<&'a VoxelBlock> {
        if self.grid.slots.is_empty() {
            return self.map.chunk(key).map(|c| &*c.voxels);
        }
        let l = key - self.grid.min;
        let d = self.grid.dims;
        if l.cmplt(IVec3::ZERO).any() || l.cmpge(d).any() {
            return None;
        }
        let i = (l.x + d.x * (l.y + d.y * l.z)) as usize;
        if self.grid.occupied[i / 64] & (1 << (i % 64)) == 0 {
            None
        } else {
            self.grid.slots[i].map(|c| &*c.voxels)
        }
    }

    /// The eight voxels around `p` (voxel units), `c[x + 2 y + 4 z]` in truncation units,
    /// with `p`'s position inside their cell; `None` unless all eight are observed.
    #[inline]
    fn corners(&mut self, p: Vec3) -> Option<([f32; 8], Vec3)> {
        let b = floor_i(p);
        let f = p - b.as_vec3();
        let mut c = [0.0f32; 8];
        let (key, i) = split_voxel(b);
        let local = b - key * CHUNK_SIDE as i32;
        if local.cmplt(IVec3::splat(CHUNK_SIDE as i32 - 1)).all() {
            // All eight corners in one chunk: read them all, then test (no branch per
            // corner; the slices let the compiler drop the bounds checks).
            let ch = self.chunk(key)?;
            const S: usize = CHUNK_SIDE;
            const SPAN: usize = S * S + S + 2;
            const OFFSETS: [usize; 8] = [0, 1, S, S + 1, S * S, S * S + 1, S * S + S, S * S + S + 1];
            let weight = &ch.weight[i..i + SPAN];
            let tsdf = &ch.tsdf[i..i + SPAN];
            let min_weight = OFFSETS.iter().fold(u16::MAX, |m, &o| m.min(weight[o]));
            if min_weight == 0 {
                return None;
            }
            for (c, &o) in c.iter_mut().zip(&OFFSETS) {
                *c = tsdf[o] as f32;
            }
        } else {
            // The cell straddles a chunk face (a third of all cells): its corners lie in up
            // to eight chunks, each found in the reader's cache.
            for (j, c) in c.iter_mut().enumerate() {
                let o = IVec3::new((j & 1) as i32, ((j >> 1) & 1) as i32, (j >> 2) as i32);
                let (k, i) = split_voxel(b + o);
                let block = self.chunk(k)?;
                if block.weight[i] == 0 {
                    return None;
                }
                *c = block.tsdf[i] as f32;
            }
        }
        Some((c.map(|v| v * (1.0 / TSDF_SCALE)), f))
    }

    /// Trilinear distance at `p` in voxel units (truncation units out), when all eight
    /// surrounding voxels are observed.
    #[inline]
    fn trilinear(&mut self, p: Vec3) -> Option<f32> {
        let (c, f) = self.corners(p)?;
        let x0 = c[0] + (c[1] - c[0]) * f.x;
        let x1 = c[2] + (c[3] - c[2]) * f.x;
        let x2 = c[4] + (c[5] - c[4]) * f.x;
        let x3 = c[6] + (c[7] - c[6]) * f.x;
        let y0 = x0 + (x1 - x0) * f.y;
        let y1 = x2 + (x3 - x2) * f.y;
        Some(y0 + (y1 - y0) * f.z)
    }

    /// Colour of the voxel nearest to `p` (voxel units).
    #[inline]
    fn color(&mut self, p: Vec3) -> [u8; 3] {
        let (key, i) = split_voxel(round_i(p));
        match self.chunk(key) {
            Some(c) => {
                let c = c.color[i];
                [c[0], c[1], c[2]]
            }
            None => [0; 3],
        }
    }
}

/// One ray's march in voxel units: returns the hit point (voxel units) and the distance
/// along the unit ray in metres.
#[inline]
fn march(
    reader: &mut VoxelReader,
    origin: Vec3,
    dir: Vec3,
    t_min: f32,
    t_max: f32,
    voxel_size: f32,
    truncation: f32,
) -> Option<(Vec3, f32)> {
    let inv_voxel = 1.0 / voxel_size;
    let chunk_side = CHUNK_SIDE as f32;
    let half_voxel = 0.5 * voxel_size;
    let unobserved_step = voxel_size;
    let mut t = t_min;
    // Last sample with an interpolated distance: (t, distance in truncation units).
    let mut prev: Option<(f32, f32)> = None;
    while t < t_max {
        let p = (origin + dir * t) * inv_voxel;
        let (key, _) = split_voxel(round_i(p));
        if reader.chunk(key).is_none() {
            // Jump to just past the chunk's exit: chunk k spans voxel cells
            // [8k - 0.5, 8k + 7.5) on each axis.
            let lo = key.as_vec3() * chunk_side - 0.5;
            let hi = lo + chunk_side;
            let mut exit = f32::INFINITY;
            for a in 0..3 {
                let d = dir[a];
                if d > 1e-9 {
                    exit = exit.min((hi[a] - p[a]) / d);
                } else if d < -1e-9 {
                    exit = exit.min((lo[a] - p[a]) / d);
                }
            }
            t += (exit * voxel_size).max(0.0) + 0.01 * voxel_size;
            prev = None;
            continue;
        }
        match reader.trilinear(p) {
            Some(sdf) => {
                if sdf < 0.0 {
                    let (tp, sp) = prev?;
                    // Linear interpolation of the zero crossing between the two samples,
                    // then one regula falsi step on the side of the bracket that keeps
                    // the sign change.
                    let mut th = tp + (t - tp) * sp / (sp - sdf);
                    if let Some(sm) = reader.trilinear((origin + dir * th) * inv_voxel) {
                        if sm > 0.0 {
                            th += (t - th) * sm / (sm - sdf);
                        } else if sm < 0.0 {
                            th = tp + (th - tp) * sp / (sp - sm);
                        }
                    }
                    let hit = (origin + dir * th) * inv_voxel;
                    return Some((hit, th));
                }
                prev = Some((t, sdf));
                t += (0.8 * sdf * truncation).max(half_voxel);
            }
            None => {
                // Unobserved corners near the surface (dropouts): keep the last positive
                // sample, the crossing is interpolated across the gap. Before any
                // observed sample (unobserved voxels of an allocated chunk, a third of all
                // samples on 7-Scenes) a whole voxel: the interpolation needs all eight
                // corners observed, so it is defined only a voxel into observed space
                // anyway. (A fifth of the truncation, 2 voxels at 10, saved 20% more
                // samples but moved the 24-frame Kinect-noise test from 2.2 to 3.3 mm.)
                t += if prev.is_some() { half_voxel } else { unobserved_step };
            }
        }
    }
    None
}

/// Ray-casts `map` from `world_from_camera` with camera `intrinsics` between `min_depth`
/// and `max_depth` metres (along the optical axis).
///
/// `start_depth`, when given, holds per pixel a depth (same shape as the view, 0 = none)
/// measured from this pose, so free space up to about that depth: the march then runs
/// only within the truncation band plus three times the depth noise of it (see
/// `hinted_range`). Pixels without one march from the nearest to the farthest depth of
/// their 5x5 neighbourhood (with the same margins: the background behind a depth edge is
/// among the neighbours); pixels with none there are
/// not cast (the measurement saw nothing there). Marching those to `max_depth` instead
/// spent 40% of all steps on 7% of the rays. The previous frame's depth at the same
/// pose is such a bound, and it saves most of the march through empty space.
///
/// # Shapes
/// `start_depth`: `width * height`, row-major, like the returned view.
pub fn raycast(
    map: &TsdfMap,
    intrinsics: Intrinsics,
    world_from_camera: Affine3A,
    min_depth: f32,
    max_depth: f32,
    start_depth: Option<&[f32]>,
) -> ModelView {
    raycast_with(map, intrinsics, world_from_camera, min_depth, max_depth, start_depth, true)
}

/// [`raycast`], with the colours read only when `with_colors` (otherwise all black): the
/// colour of a hit is one more memory access per ray (a separate array of the voxel
/// block), which tracking without its photometric term does not use.
pub(crate) fn raycast_with(
    map: &TsdfMap,
    intrinsics: Intrinsics,
    world_from_camera: Affine3A,
    min_depth: f32,
    max_depth: f32,
    start_depth: Option<&[f32]>,
    with_colors: bool,
) -> ModelView {
    let (w, h) = (intrinsics.width as usize, intrinsics.height as usize);
    let n = w * h;
    let c = map.config();
    let (voxel_size, truncation) = (c.voxel_size, c.truncation());
    let start_depth = start_depth.filter(|s| s.len() == n);
    let mut vertices = vec![Vec3::ZERO; n];
    let mut normals = vec![Vec3::ZERO; n];
    let mut colors = vec![[0u8; 3]; n];
    let rot = glam::Mat3::from(world_from_camera.matrix3);
    let origin = Vec3::from(world_from_camera.translation);
    let camera_from_world_rot = rot.transpose();
    let valid_pose = world_from_camera.is_finite() && min_depth < max_depth;
    let band_model = c.band_model();
    let grid = ChunkGrid::new(map);
    let inv_voxel = 1.0 / voxel_size;
    // Bands of TILE rows in parallel, each walked tile by tile (TILE x TILE pixels): rays
    // of a tile meet the same few chunks, so their voxels stay in cache (row order evicts
    // them before the next row comes back).
    const TILE: usize = 8;
    vertices
        .par_chunks_mut(TILE * w)
        .zip(normals.par_chunks_mut(TILE * w))
        .zip(colors.par_chunks_mut(TILE * w))
        .enumerate()
        .for_each(|(band, ((vert_band, norm_band), color_band))| {
            if !valid_pose {
                return;
            }
            let rows = vert_band.len() / w;
            let mut reader = VoxelReader::new(map, &grid);
            let mut rays: Vec<TileRay> = Vec::with_capacity(TILE * TILE);
            for u0 in (0..w).step_by(TILE) {
                // First the tile's rays, asking for the chunk where each expects its
                // surface (the hint's depth): the voxels are on their way while earlier
                // rays march. A march is a chain of dependent reads, each a likely cache
                // miss; asked for ahead (with the whole chunk, see `VoxelReader::chunk`),
                // the cast took 13-15 % less time on the demo scan.
                rays.clear();
                for r in 0..rows {
                    let v = band * TILE + r;
                    for u in u0..(u0 + TILE).min(w) {
                        let ray_cam = intrinsics.unproject(u as f32, v as f32, 1.0);
                        // Depth per metre along the unit ray.
                        let z_per_t = 1.0 / ray_cam.length();
                        let dir = rot * (ray_cam * z_per_t);
                        let (mut d0, mut d1) = (min_depth, max_depth);
                        if let Some(s) = start_depth {
                            match hint(s, w, h, u, v) {
                                Some((near, far)) => {
                                    (d0, d1) = hinted_range(d0, d1, near, far, band_model, truncation);
                                    let expected = (origin + dir * (near / z_per_t)) * inv_voxel;
                                    reader.chunk(split_voxel(round_i(expected)).0);
                                }
                                None => continue,
                            }
                        }
                        rays.push(TileRay {
                            pixel: r * w + u,
                            ray_cam,
                            z_per_t,
                            dir,
                            t0: d0 / z_per_t,
                            t1: d1 / z_per_t,
                        });
                    }
                }
                for ray in &rays {
                    let Some((hit, t)) = march(&mut reader, origin, ray.dir, ray.t0, ray.t1, voxel_size, truncation)
                    else {
                        continue;
                    };
                    let Some(g) = gradient(&mut reader, hit) else {
                        continue;
                    };
                    let len = g.length();
                    if !(len > 1e-6) {
                        continue;
                    }
                    let n_cam = camera_from_world_rot * (g / len);
                    let p_cam = ray.ray_cam * (t * ray.z_per_t);
                    vert_band[ray.pixel] = p_cam;
                    norm_band[ray.pixel] = if n_cam.dot(p_cam) > 0.0 { -n_cam } else { n_cam };
                    if with_colors {
                        color_band[ray.pixel] = reader.color(hit);
                    }
                }
            }
        });
    ModelView { intrinsics, world_from_camera, vertices, normals, colors }
}

/// One ray of a tile, ready to march.
struct TileRay {
    /// Index in the band's rows.
    pixel: usize,
    /// Direction through the pixel at unit depth, camera frame.
    ray_cam: Vec3,
    /// Depth per metre along the unit ray.
    z_per_t: f32,
    /// Unit direction, world frame.
    dir: Vec3,
    /// March range along `dir`, metres.
    t0: f32,
    t1: f32,
}

/// Gradient of the interpolated distance at `p` (voxel units; any scale): differences of
/// interpolated values a voxel either side (smooth across cells), else the analytic
/// gradient of the trilinear cell around `p`.
#[inline]
fn gradient(reader: &mut VoxelReader, p: Vec3) -> Option<Vec3> {
    // The value at `p` only serves one-sided differences: read on first need.
    let mut f0: Option<Option<f32>> = None;
    let central = (|| {
        Some(Vec3::new(
            diff(reader, p, Vec3::X, &mut f0)?,
            diff(reader, p, Vec3::Y, &mut f0)?,
            diff(reader, p, Vec3::Z, &mut f0)?,
        ))
    })();
    if central.is_some() {
        return central;
    }
    let (c, f) = reader.corners(p)?;
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let bilerp = |v00: f32, v10: f32, v01: f32, v11: f32, s: f32, t: f32| lerp(lerp(v00, v10, s), lerp(v01, v11, s), t);
    Some(Vec3::new(
        bilerp(c[1] - c[0], c[3] - c[2], c[5] - c[4], c[7] - c[6], f.y, f.z),
        bilerp(c[2] - c[0], c[3] - c[1], c[6] - c[4], c[7] - c[5], f.x, f.z),
        bilerp(c[4] - c[0], c[5] - c[1], c[6] - c[2], c[7] - c[3], f.x, f.y),
    ))
}

/// Difference of the interpolated distance along `axis` at `p` (voxel units), per voxel:
/// central where both neighbours are observed, one-sided against the value at `p` (read
/// into `f0` on first use) where only one is (dropouts leave unobserved voxels near
/// surfaces).
#[inline]
fn diff(reader: &mut VoxelReader, p: Vec3, axis: Vec3, f0: &mut Option<Option<f32>>) -> Option<f32> {
    let (a, b) = (reader.trilinear(p + axis), reader.trilinear(p - axis));
    if let (Some(a), Some(b)) = (a, b) {
        return Some(0.5 * (a - b));
    }
    let f = (*f0.get_or_insert_with(|| reader.trilinear(p)))?;
    match (a, b) {
        (Some(a), None) => Some(a - f),
        (None, Some(b)) => Some(f - b),
        _ => None,
    }
}

/// The march range `d0..d1` (depths along the optical axis) narrowed to `near` and `far`,
/// the nearest and farthest start depth around the pixel, each widened by its truncation
/// band plus three times the sensor's depth noise there.
///
/// The model surface lies within the depth noise of a depth measured from this pose (the
/// start depth is the last tracked frame's, fused at this pose, and block-averaged), and
/// the march must begin in front of the band so that its first samples are positive. A
/// fixed margin of three truncations (the earlier rule) marched 6 cm of free space before a
/// near surface at a 4-voxel truncation and 15 cm at the pipeline's 10 voxels, yet left
/// less than three sigma at 4 m with 4 voxels.
#[inline]
fn hinted_range(d0: f32, d1: f32, near: f32, far: f32, band: BandModel, truncation: f32) -> (f32, f32) {
    let margin = |z: f32| band.relative(z) * truncation + 3.0 * depth_noise(z);
    (d0.max(near - margin(near)), d1.min(far + margin(far)))
}

/// The depth range to march for pixel `(u, v)` from the start-depth image: its own depth
/// (both ends), else the nearest and the farthest valid depth of its 5x5 neighbourhood;
/// `None` when all are missing.
#[inline]
fn hint(s: &[f32], w: usize, h: usize, u: usize, v: usize) -> Option<(f32, f32)> {
    let own = s[v * w + u];
    if own.is_finite() && own > 0.0 {
        return Some((own, own));
    }
    let (mut near, mut far) = (f32::INFINITY, 0.0f32);
    for y in v.saturating_sub(2)..(v + 3).min(h) {
        for x in u.saturating_sub(2)..(u + 3).min(w) {
            let d = s[y * w + x];
            if d.is_finite() && d > 0.0 {
                near = near.min(d);
                far = far.max(d);
            }
        }
    }
    near.is_finite().then_some((near, far))
}

/// `floor` per component as integers (`f32::floor` is a library call on baseline x86-64).
#[inline]
fn floor_i(p: Vec3) -> IVec3 {
    let t = p.as_ivec3();
    t - p.cmplt(t.as_vec3()).into_ivec3_mask()
}

/// Nearest integer per component (halves away from the floor).
#[inline]
fn round_i(p: Vec3) -> IVec3 {
    floor_i(p + 0.5)
}

/// Boolean mask to 0/1 integers.
trait MaskToInt {
    fn into_ivec3_mask(self) -> IVec3;
}

impl MaskToInt for glam::BVec3 {
    #[inline]
    fn into_ivec3_mask(self) -> IVec3 {
        IVec3::new(self.x as i32, self.y as i32, self.z as i32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::TsdfConfig;
    use semrecon_data::Frame;

    #[test]
    fn corners_match_voxel_by_voxel_reads_across_chunk_faces() {
        // A tilted wall a metre away, fused once: cells of its band straddle chunk faces
        // on every axis, and some of their corners are unobserved.
        let k = Intrinsics::new(64, 48, 50.0, 50.0, 31.5, 23.5).expect("camera");
        let depth: Vec<f32> = (0..64 * 48).map(|i| 1.0 + 0.003 * (i % 64) as f32 + 0.002 * (i / 64) as f32).collect();
        let frame = Frame::from_depth(k, depth);
        let mut map = TsdfMap::new(TsdfConfig::default()).expect("config");
        map.integrate(&frame, Affine3A::IDENTITY).expect("fusion");
        let grid = ChunkGrid::new(&map);
        let mut reader = VoxelReader::new(&map, &grid);
        let inv_voxel = 1.0 / map.config().voxel_size;
        let (mut straddling, mut some, mut none) = (0, 0, 0);
        for i in 0..20_000 {
            // Points along the viewing rays around the surface, in voxel units.
            let u = (i % 64) as f32;
            let v = ((i / 64) % 48) as f32;
            let z = 0.95 + 0.15 * ((i * 7919) % 1000) as f32 / 1000.0;
            let p = k.unproject(u, v, z) * inv_voxel;
            let b = floor_i(p);
            let want: Option<[f32; 8]> = (0..8)
                .map(|j| {
                    let o = IVec3::new(j & 1, (j >> 1) & 1, j >> 2);
                    map.voxel(b + o).filter(|v| v.is_observed()).map(|v| v.tsdf())
                })
                .collect::<Option<Vec<f32>>>()
                .map(|c| c.try_into().expect("eight corners"));
            let (key, _) = split_voxel(b);
            if (b - key * CHUNK_SIDE as i32).cmpeq(IVec3::splat(CHUNK_SIDE as i32 - 1)).any() {
                straddling += 1;
            }
            let got = reader.corners(p).map(|(c, _)| c);
            assert_eq!(got, want, "at {p}");
            if got.is_some() {
                some += 1;
            } else {
                none += 1;
            }
        }
        assert!(straddling > 1000 && some > 1000 && none > 1000, "{straddling} {some} {none}");
    }
    #[test]
    fn grid_cast_matches_rays_cast_through_the_hash_map() {
        // A wall with a box in front (depth edges, rays that miss), fused from two poses.
        let k = Intrinsics::new(96, 72, 80.0, 80.0, 47.5, 35.5).expect("camera");
        let depth: Vec<f32> = (0..96 * 72)
            .map(|i| {
                let (x, y) = (i % 96, i / 96);
                if (30..60).contains(&x) && (20..50).contains(&y) {
                    0.8 + 0.002 * x as f32
                } else if x < 5 {
                    0.0
                } else {
                    1.5 + 0.003 * y as f32
                }
            })
            .collect();
        let frame = Frame::from_depth(k, depth.clone());
        // A fixed band and a depth-dependent one (a narrower march range).
        let wide_truncation = TsdfConfig { truncation_voxels: 10.0, ..TsdfConfig::default() };
        assert!(wide_truncation.band(0.8) < wide_truncation.truncation());
        for config in [TsdfConfig::default(), wide_truncation] {
            let mut map = TsdfMap::new(config).expect("config");
            let moved =
                Affine3A::from_rotation_translation(glam::Quat::from_rotation_y(0.05), Vec3::new(0.03, 0.0, 0.0));
            map.integrate(&frame, Affine3A::IDENTITY).expect("fusion");
            map.integrate(&frame, moved).expect("fusion");
            let pose = Affine3A::from_translation(Vec3::new(0.01, -0.01, 0.0));
            let start_depth: Vec<f32> =
                depth.iter().enumerate().map(|(i, &d)| if i % 7 == 0 { 0.0 } else { d }).collect();
            let no_grid = ChunkGrid { min: IVec3::ZERO, dims: IVec3::ZERO, slots: Vec::new(), occupied: Vec::new() };
            let c = map.config();
            let (voxel_size, truncation) = (c.voxel_size, c.truncation());
            for start in [None, Some(&start_depth[..])] {
                let view = raycast(&map, k, pose, 0.1, 5.0, start);
                let mut hits = 0;
                for i in 0..96 * 72 {
                    let (u, v) = (i % 96, i / 96);
                    // One ray alone, every voxel read through the map's hash index.
                    let mut reader = VoxelReader::new(&map, &no_grid);
                    let ray_cam = k.unproject(u as f32, v as f32, 1.0);
                    let z_per_t = 1.0 / ray_cam.length();
                    let dir = glam::Mat3::from(pose.matrix3) * (ray_cam * z_per_t);
                    let (mut d0, mut d1) = (0.1f32, 5.0f32);
                    let mut want = (Vec3::ZERO, Vec3::ZERO);
                    let range = match start {
                        Some(sd) => hint(sd, 96, 72, u, v),
                        None => Some((d0, d1)),
                    };
                    if let Some((near, far)) = range {
                        if start.is_some() {
                            (d0, d1) = hinted_range(d0, d1, near, far, c.band_model(), truncation);
                        }
                        let origin = Vec3::from(pose.translation);
                        let found = march(&mut reader, origin, dir, d0 / z_per_t, d1 / z_per_t, voxel_size, truncation);
                        if let Some((p, t)) = found {
                            if let Some(g) = gradient(&mut reader, p).filter(|g| g.length() > 1e-6) {
                                let n = glam::Mat3::from(pose.matrix3).transpose() * (g / g.length());
                                let p_cam = ray_cam * (t * z_per_t);
                                want = (p_cam, if n.dot(p_cam) > 0.0 { -n } else { n });
                            }
                        }
                    }
                    assert_eq!((view.vertices[i], view.normals[i]), want, "pixel {u}, {v}");
                    hits += (want.0.z > 0.0) as usize;
                }
                assert!(hits > 96 * 72 / 2, "{hits}");
            }
        }
    }
}
