//! Surface voxels of the TSDF map: the observed, coloured voxels that lie on the zero crossing
//! (|signed distance| below a threshold), with the direction of the distance gradient as a
//! normal. They are what the semantic back end voxelises at the network's coarser size: the
//! mesh would do too, but meshing a region just to throw the triangles away costs far more
//! than one pass over the voxels of its chunks.
//!
//! Extraction works chunk by chunk, so a consumer can cache the result per chunk and redo only
//! the chunks whose [`Chunk::revision`](crate::Chunk::revision) changed.

use glam::{IVec3, Vec3};
use rayon::prelude::*;

use crate::map::{ChunkKey, TsdfMap, CHUNK_SIDE, TSDF_SCALE};

/// One voxel on the surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceVoxel {
    /// Global voxel coordinates (centre at `voxel * voxel_size`, world frame).
    pub voxel: IVec3,
    /// Weighted mean colour of its observations.
    pub color: [u8; 3],
    /// Unit gradient of the signed distance (pointing away from the surface, toward the
    /// free space the camera saw); zero where no neighbour was observed.
    pub normal: Vec3,
}

/// The surface voxels of chunk `key` (empty when it is not allocated), in local index order.
///
/// A voxel qualifies when it was observed, has at least one colour observation and its signed
/// distance is at most `max_distance_voxels` voxels from the surface (about 1 gives a shell two
/// voxels thick, without holes on oblique surfaces). Gradients use central differences inside
/// the chunk, one-sided at its border and where a neighbour is unobserved.
pub fn chunk_surface_voxels(map: &TsdfMap, key: ChunkKey, max_distance_voxels: f32) -> Vec<SurfaceVoxel> {
    let Some(chunk) = map.chunk(key) else { return Vec::new() };
    let limit = max_distance_voxels / map.config().truncation_voxels;
    // Most chunks of the truncation band hold no voxel near the zero crossing: an integer scan
    // of the quantised distances rules them out before any voxel is decoded.
    let limit_q = (limit * TSDF_SCALE).ceil().min(TSDF_SCALE) as u16;
    let block = &chunk.voxels;
    if !block.tsdf.iter().zip(block.weight.iter()).any(|(t, w)| *w != 0 && t.unsigned_abs() <= limit_q) {
        return Vec::new();
    }
    let base = key * CHUNK_SIDE as i32;
    // Neighbours across the chunk border are not read (a hash lookup each, for more than half
    // of a chunk's voxels): border voxels get one-sided differences, exact on planes and
    // plenty for normals that are averaged per cell. The block is read by index directly:
    // this runs over every chunk touched since the last semantic pass.
    let scale = 1.0 / TSDF_SCALE;
    let tsdf_at = |i: usize| -> Option<f32> { (block.weight[i] != 0).then(|| f32::from(block.tsdf[i]) * scale) };
    let mut out = Vec::new();
    for i in 0..CHUNK_SIDE * CHUNK_SIDE * CHUNK_SIDE {
        let centre = f32::from(block.tsdf[i]) * scale;
        if block.weight[i] == 0 || block.color[i][3] == 0 || centre.abs() > limit {
            continue;
        }
        let l = [i % CHUNK_SIDE, (i / CHUNK_SIDE) % CHUNK_SIDE, i / (CHUNK_SIDE * CHUNK_SIDE)];
        let mut g = Vec3::ZERO;
        for (axis, stride) in [1, CHUNK_SIDE, CHUNK_SIDE * CHUNK_SIDE].into_iter().enumerate() {
            let plus = if l[axis] + 1 < CHUNK_SIDE { tsdf_at(i + stride) } else { None };
            let minus = if l[axis] > 0 { tsdf_at(i - stride) } else { None };
            g[axis] = match (plus, minus) {
                (Some(a), Some(b)) => 0.5 * (a - b),
                (Some(a), None) => a - centre,
                (None, Some(b)) => centre - b,
                (None, None) => 0.0,
            };
        }
        let c = block.color[i];
        let local = IVec3::new(l[0] as i32, l[1] as i32, l[2] as i32);
        out.push(SurfaceVoxel { voxel: base + local, color: [c[0], c[1], c[2]], normal: g.normalize_or_zero() });
    }
    out
}

/// [`chunk_surface_voxels`] of several chunks, in parallel; one list per key, in key order.
pub fn surface_voxels(map: &TsdfMap, keys: &[ChunkKey], max_distance_voxels: f32) -> Vec<Vec<SurfaceVoxel>> {
    keys.par_iter().map(|&k| chunk_surface_voxels(map, k, max_distance_voxels)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::{split_voxel, TsdfConfig, Voxel, TSDF_SCALE, WEIGHT_SCALE};

    /// A map holding the plane z = 0.1 m (signed distance = z - 0.1, positive above), observed
    /// on a 24^3-voxel cube at 1 cm voxels.
    fn plane_map() -> TsdfMap {
        let config = TsdfConfig { voxel_size: 0.01, truncation_voxels: 4.0, ..TsdfConfig::default() };
        let mut map = TsdfMap::new(config).expect("valid");
        for z in 0..24 {
            for y in 0..24 {
                for x in 0..24 {
                    let v = IVec3::new(x, y, z);
                    let d = (z as f32 * 0.01 - 0.1) / config.truncation();
                    let (key, local) = split_voxel(v);
                    let (slot, _) = map.allocate(key);
                    let voxel = Voxel {
                        tsdf: (d.clamp(-1.0, 1.0) * TSDF_SCALE).round() as i16,
                        weight: WEIGHT_SCALE as u16,
                        color: [10, 20, 30],
                        color_count: 1,
                    };
                    map.chunks[slot as usize].voxels.set(local, voxel);
                }
            }
        }
        map
    }

    #[test]
    fn the_plane_shell_is_found_with_upward_normals() {
        let map = plane_map();
        let keys = map.sorted_keys();
        let all: Vec<SurfaceVoxel> = surface_voxels(&map, &keys, 1.5).into_iter().flatten().collect();
        // Voxels at z = 9, 10, 11 (within one voxel of 0.1 m), 24 x 24 each.
        assert_eq!(all.len(), 3 * 24 * 24);
        assert!(all.iter().all(|s| (9..=11).contains(&s.voxel.z) && s.color == [10, 20, 30]));
        assert!(all.iter().all(|s| (s.normal - Vec3::Z).length() < 1e-4), "{:?}", all[0]);
        let half: Vec<SurfaceVoxel> = surface_voxels(&map, &keys, 0.5).into_iter().flatten().collect();
        assert_eq!(half.len(), 24 * 24);
    }

    /// The plain definition: voxels decoded one at a time, neighbours by coordinates.
    fn reference(map: &TsdfMap, key: ChunkKey, max_distance_voxels: f32) -> Vec<SurfaceVoxel> {
        let Some(chunk) = map.chunk(key) else { return Vec::new() };
        let limit = max_distance_voxels / map.config().truncation_voxels;
        let side = CHUNK_SIDE as i32;
        let tsdf_at = |l: IVec3| -> Option<f32> {
            let inside = l.cmpge(IVec3::ZERO).all() && l.cmplt(IVec3::splat(side)).all();
            let v = inside.then(|| chunk.voxel((l.x + side * (l.y + side * l.z)) as usize))?;
            v.is_observed().then(|| v.tsdf())
        };
        let mut out = Vec::new();
        for i in 0..CHUNK_SIDE * CHUNK_SIDE * CHUNK_SIDE {
            let v = chunk.voxel(i);
            if !v.is_observed() || v.color_count == 0 || v.tsdf().abs() > limit {
                continue;
            }
            let l = IVec3::new((i % CHUNK_SIDE) as i32, ((i / CHUNK_SIDE) % CHUNK_SIDE) as i32, (i / 64) as i32);
            let mut g = Vec3::ZERO;
            for (axis, unit) in [IVec3::X, IVec3::Y, IVec3::Z].into_iter().enumerate() {
                g[axis] = match (tsdf_at(l + unit), tsdf_at(l - unit)) {
                    (Some(a), Some(b)) => 0.5 * (a - b),
                    (Some(a), None) => a - v.tsdf(),
                    (None, Some(b)) => v.tsdf() - b,
                    (None, None) => 0.0,
                };
            }
            out.push(SurfaceVoxel { voxel: key * side + l, color: v.color(), normal: g.normalize_or_zero() });
        }
        out
    }

    #[test]
    fn extraction_equals_the_plain_definition_on_a_noisy_map() {
        use rand::{Rng, SeedableRng};
        let mut map = plane_map();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for slot in 0..map.chunks.len() {
            for i in 0..CHUNK_SIDE * CHUNK_SIDE * CHUNK_SIDE {
                let mut v = map.chunks[slot].voxels.get(i);
                v.tsdf = v.tsdf.saturating_add(rng.random_range(-2000..2000));
                if rng.random::<f32>() < 0.1 {
                    v.weight = 0;
                }
                if rng.random::<f32>() < 0.1 {
                    v.color_count = 0;
                }
                v.color = [rng.random(), rng.random(), rng.random()];
                map.chunks[slot].voxels.set(i, v);
            }
        }
        let mut total = 0;
        for key in map.sorted_keys() {
            for band in [0.5, 1.0, 2.5] {
                let fast = chunk_surface_voxels(&map, key, band);
                total += fast.len();
                assert_eq!(fast, reference(&map, key, band), "chunk {key} band {band}");
            }
        }
        assert!(total > 1000);
    }

    #[test]
    fn unallocated_chunks_have_no_surface() {
        let map = plane_map();
        assert!(chunk_surface_voxels(&map, IVec3::new(50, 0, 0), 1.0).is_empty());
    }
}
