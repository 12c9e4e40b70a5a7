//! The map's surface read straight from the TSDF chunks, for the semantic map: the points where
//! the signed distance crosses zero on the edges between neighbouring voxels.
//!
//! The semantic passes used to read the surface through the incremental mesh, so every chunk
//! that changed had to be re-meshed before a keyframe's pass (45-59 ms a keyframe on 7-Scenes),
//! and a meshing budget, which leaves refreshes keyframes late, cost labels. Reading the
//! chunks that changed since the last pass decouples the two: meshing can keep its budget and
//! the labels see every change at once.
//!
//! A surface point is what marching cubes would make a vertex of: on the edge from voxel `a`
//! to its neighbour `b` along x, y or z, both observed with at least the mesh's minimum weight
//! ([`MeshConfig::min_weight`]), of opposite signs (negative against non-negative), not
//! jumping by more than the mesher's seam limit ([`max_edge_jump`]), and with a cell around it
//! whose 8 corners are observed; it lies at `a + s (b - a)`, `s = d_a / (d_a - d_b)`, with the
//! colour interpolated as the mesher does. The points are then the mesh's vertices, bit for
//! bit in position and colour, but for a few in a thousand at the borders of holes: the cells
//! looked at are those of the chunk (the mesher also asks the lower neighbours' cells, which
//! would make a chunk's points depend on all 26 neighbours), and a cell with a seam on another
//! edge still counts (tested against a full mesh of the same map). Without the cell test,
//! crossings along the borders of holes, which the mesh leaves out, added 2 % more points at
//! the silhouettes of objects. So the network keeps seeing the kind of input it was trained on
//! (mesh vertices summarised per cell).
//!
//! A point's normal is the TSDF's gradient from forward differences at the edge's ends
//! (exact on a plane, where the distance is linear), where the mesher takes central
//! differences, which would need the lower neighbours. The edge's signed axis alone, summed
//! over a cell, gives a plane's normal only on average: quantised per cell, it tilted the up
//! estimate by 4 degrees in a map frame tilted 30 degrees from the room.
//!
//! A chunk owns the edges whose lower voxel it holds, so its points read its own voxels and the
//! lower faces of its three upper face neighbours: when a chunk changes, its points and those
//! of its three lower face neighbours ([`readers_of`]) are re-made.

use glam::{IVec3, Vec3};
use semrecon_recon::cache_hint::prefetch;
use semrecon_recon::map::{split_voxel, TSDF_SCALE};
use semrecon_recon::marching_cubes::{edge_color, max_edge_jump};
use semrecon_recon::{Chunk, ChunkKey, MeshConfig, TsdfConfig, TsdfMap, CHUNK_SIDE};
use wide::{i16x16, u16x16};

/// Which zero crossings of the TSDF count as surface (those the mesher meshes).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceRule {
    /// Smallest stored weight of a voxel that counts as observed (at least 1).
    pub min_stored_weight: u16,
    /// Largest distance difference across an edge, in truncation units, that is a crossing
    /// and not a seam.
    pub max_jump: f32,
    /// Voxel edge, metres.
    pub voxel_size: f32,
}

impl SurfaceRule {
    /// The rule of a mesher with options `mesh` over a map of `tsdf`.
    pub fn new(tsdf: &TsdfConfig, mesh: &MeshConfig) -> Self {
        Self { min_stored_weight: mesh.stored_min_weight(), max_jump: max_edge_jump(tsdf), voxel_size: tsdf.voxel_size }
    }
}

/// One surface point: where an edge between two neighbouring voxels crosses zero.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfacePoint {
    /// The edge's lower voxel (global voxel coordinates): on the other two axes the point's
    /// position is this voxel's, `low * voxel_size` exactly.
    pub low: IVec3,
    /// Metres, map frame.
    pub position: Vec3,
    /// Colour interpolated between the two voxels' (those that have one).
    pub color: [u8; 3],
    /// The edge's axis (0 x, 1 y, 2 z).
    pub axis: u8,
    /// Unit normal toward free space (zero where the distances give no gradient): the
    /// distance's difference along the edge and, across it, the forward differences at the
    /// edge's two ends averaged (those whose voxels are observed and read by the chunk).
    pub normal: Vec3,
}

/// Unit steps along x, y and z.
const AXES: [IVec3; 3] = [IVec3::X, IVec3::Y, IVec3::Z];

/// The chunks whose points read voxels of chunk `key`: itself and its lower face neighbours.
pub fn readers_of(key: ChunkKey) -> [ChunkKey; 4] {
    [key, key - IVec3::X, key - IVec3::Y, key - IVec3::Z]
}

/// A chunk whose cells can hold a zero crossing, with the upper neighbours whose lower faces
/// its cells read: what [`SurfaceChunk::for_each_point`] needs, looked up once.
#[derive(Clone, Copy)]
pub struct SurfaceChunk<'a> {
    key: ChunkKey,
    own: &'a Chunk,
    upper: [Option<&'a Chunk>; 3],
}

impl<'a> SurfaceChunk<'a> {
    /// Chunk `key` when its own voxels or its upper neighbours' lower faces have both signs
    /// (from the sign summaries alone, [`Chunk::sign_bits`]); `None` when they cannot, or when
    /// it is not allocated. Most chunks a fused frame touches are free space or lie behind
    /// the surface and end here, without a voxel read.
    #[inline]
    pub fn find(map: &'a TsdfMap, key: ChunkKey) -> Option<Self> {
        let own = map.chunk(key)?;
        let mut signs = own.sign_bits() & 3;
        let upper: [Option<&Chunk>; 3] = AXES.map(|a| map.chunk(key + a));
        for (a, c) in upper.iter().enumerate() {
            if let Some(c) = c {
                signs |= (c.sign_bits() >> (2 + 2 * a)) & 3;
            }
        }
        (signs == 3).then_some(Self { key, own, upper })
    }

    /// The chunk's key.
    pub fn key(&self) -> ChunkKey {
        self.key
    }

    /// Asks for the voxels [`SurfaceChunk::for_each_point`] reads first (the chunk's
    /// distances and weights), so that a caller going through many chunks overlaps one
    /// chunk's cache misses with the work on the one before: a hint, with no effect on
    /// results.
    pub fn prefetch(&self) {
        prefetch(self.own.stored_tsdf(), 64, 2 * CHUNK_SIDE * CHUNK_SIDE);
        prefetch(self.own.stored_weights(), 64, 2 * CHUNK_SIDE * CHUNK_SIDE);
    }
}

/// Calls `visit` for every surface point on the edges chunk `key` owns (none when it is not
/// allocated), in an order of its own.
///
/// Which edges cross, and which have a whole cell around them, is found with bit masks over
/// rows of eight voxels (observed, negative): only the crossing edges, a few per hundred, are
/// then read. Chunks whose own voxels and
/// whose upper neighbours' lower faces cannot have both signs are skipped from their sign
/// summaries alone ([`Chunk::sign_bits`]). The points are those of
/// [`chunk_points_reference`], the specification.
pub fn for_each_chunk_point(map: &TsdfMap, key: ChunkKey, rule: &SurfaceRule, visit: impl FnMut(SurfacePoint)) {
    if let Some(chunk) = SurfaceChunk::find(map, key) {
        chunk.for_each_point(rule, visit);
    }
}

impl SurfaceChunk<'_> {
    /// [`for_each_chunk_point`] of this chunk.
    pub fn for_each_point(&self, rule: &SurfaceRule, mut visit: impl FnMut(SurfacePoint)) {
        const N: usize = CHUNK_SIDE;
        let (key, own, upper) = (self.key, self.own, self.upper);
        let min_weight = rule.min_stored_weight;
        let (tsdf, weight, color) = (own.stored_tsdf(), own.stored_weights(), own.stored_colors());
        // The chunk's voxels, read in order, the hardware prefetches; the neighbours' faces (a
        // voxel every 16 or 128 bytes) and the colours of the crossings (scattered) it does not,
        // and their cache misses were most of the scan: asked for now, they arrive while the
        // masks are made.
        // Face x = 0: every line; y = 0: the first row of each z slice; z = 0: the first slice's rows.
        for (c, (stride, count)) in upper.iter().zip([(64, 2 * N * N), (2 * N * N, N), (64, 2)]) {
            if let Some(c) = c {
                prefetch(c.stored_tsdf(), stride, count);
                prefetch(c.stored_weights(), stride, count);
            }
        }
        prefetch(color, 64, std::mem::size_of_val(color) / 64);
        // Per row r = y + 8 z (voxels x + 8 r): bit x set for observed, and for observed negative,
        // voxels; bit 8 is the +x neighbour's voxel (0, y, z).
        let mut observed = [0u16; N * N];
        let mut negative = [0u16; N * N];
        // Two rows (16 voxels) at a time: two compares and a mask move each, where voxel by voxel
        // the masks cost more than all the points of a chunk.
        let min_lanes = u16x16::splat(min_weight);
        for (r, (t, w)) in tsdf.as_chunks::<16>().0.iter().zip(weight.as_chunks::<16>().0).enumerate() {
            let o = u16x16::from(*w).simd_ge(min_lanes);
            let n: u16x16 = wide::bytemuck::cast(i16x16::from(*t).simd_lt(i16x16::ZERO));
            let (o, n) = (o.to_bitmask(), (n & o).to_bitmask());
            observed[2 * r] = (o & 0xff) as u16;
            observed[2 * r + 1] = (o >> 8) as u16;
            negative[2 * r] = (n & 0xff) as u16;
            negative[2 * r + 1] = (n >> 8) as u16;
        }
        if let Some(c) = upper[0] {
            let (t, w) = (c.stored_tsdf(), c.stored_weights());
            for r in 0..N * N {
                let i = r * N;
                let o = (w[i] >= min_weight) as u16;
                observed[r] |= o << N;
                negative[r] |= (o & (t[i] < 0) as u16) << N;
            }
        }
        // The +y neighbour's rows (y = 0, z) and the +z neighbour's rows (y, z = 0), bits x.
        let face_rows = |c: Option<&Chunk>, row_of: fn(usize) -> usize| -> [(u16, u16); N] {
            let mut rows = [(0u16, 0u16); N];
            if let Some(c) = c {
                let (t, w) = (c.stored_tsdf(), c.stored_weights());
                for (j, row) in rows.iter_mut().enumerate() {
                    let s = row_of(j) * N;
                    *row = row_masks(&t[s..s + N], &w[s..s + N], min_weight);
                }
            }
            rows
        };
        let face_y = face_rows(upper[1], |z| N * z);
        let face_z = face_rows(upper[2], |y| y);
        // Observed bits of the row (y, z), 0 ..= 8 each, over what the chunk reads.
        let observed_row = |y: usize, z: usize| -> u16 {
            match (y < N, z < N) {
                (true, true) => observed[y + N * z],
                (false, true) => face_y[z].0,
                (true, false) => face_z[y].0,
                (false, false) => 0,
            }
        };
        // Per row of cells (y, z): bit x set when cell (x, y, z) has its 8 corners observed.
        let mut full_cells = [0u16; N * N];
        for (r, cells) in full_cells.iter_mut().enumerate() {
            let (y, z) = (r % N, r / N);
            let c = observed_row(y, z) & observed_row(y + 1, z) & observed_row(y, z + 1) & observed_row(y + 1, z + 1);
            *cells = c & (c >> 1) & 0xff;
        }
        let cells_at = |y: usize, z: usize| full_cells[y + N * z];
        // The distance of the observed voxel at local (x, y, z), 0 ..= 8 each, among those the
        // chunk reads (at most one coordinate 8: the upper neighbours' lower faces).
        let read = |[x, y, z]: [usize; 3]| -> Option<i16> {
            let (c, i) = match (x < N, y < N, z < N) {
                (true, true, true) => (own, x + N * (y + N * z)),
                (false, true, true) => (upper[0]?, N * (y + N * z)),
                (true, false, true) => (upper[1]?, x + N * N * z),
                (true, true, false) => (upper[2]?, x + N * y),
                _ => return None,
            };
            (c.stored_weights()[i] >= min_weight).then(|| c.stored_tsdf()[i])
        };
        let key_voxel = key * N as i32;
        for r in 0..N * N {
            let (y, z) = (r % N, r / N);
            let (o, n) = (observed[r], negative[r]);
            let (oy, ny) = if y + 1 < N { (observed[r + 1], negative[r + 1]) } else { face_y[z] };
            let (oz, nz) = if z + 1 < N { (observed[r + N], negative[r + N]) } else { face_z[y] };
            // Edges with a whole cell around them (of those the chunk owns): x edges have their
            // cells at (x, y - 1 ..= y, z - 1 ..= z), y edges at (x - 1 ..= x, y, z - 1 ..= z), z
            // edges at (x - 1 ..= x, y - 1 ..= y, z).
            let below_y = if y > 0 { cells_at(y - 1, z) } else { 0 };
            let below_z = if z > 0 { cells_at(y, z - 1) } else { 0 };
            let below_yz = if y > 0 && z > 0 { cells_at(y - 1, z - 1) } else { 0 };
            let own = cells_at(y, z);
            let around_x = own | below_y | below_z | below_yz;
            let around_y = (own | below_z) | (own | below_z) << 1;
            let around_z = (own | below_y) | (own | below_y) << 1;
            let crossings = [
                o & (o >> 1) & (n ^ (n >> 1)) & around_x & 0xff,
                o & oy & (n ^ ny) & around_y & 0xff,
                o & oz & (n ^ nz) & around_z & 0xff,
            ];
            for (axis, mut bits) in crossings.into_iter().enumerate() {
                while bits != 0 {
                    let x = bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    let ia = x + N * r;
                    // The far end: in this chunk, or on the upper neighbour's lower face.
                    let (tb, cb) = match axis {
                        0 if x + 1 < N => (tsdf[ia + 1], color[ia + 1]),
                        1 if y + 1 < N => (tsdf[ia + N], color[ia + N]),
                        2 if z + 1 < N => (tsdf[ia + N * N], color[ia + N * N]),
                        _ => {
                            let Some(c) = upper[axis] else { continue };
                            let j = match axis {
                                0 => N * r,
                                1 => x + N * N * z,
                                _ => x + N * y,
                            };
                            (c.stored_tsdf()[j], c.stored_colors()[j])
                        }
                    };
                    let low = key_voxel + IVec3::new(x as i32, y as i32, z as i32);
                    let (a, mut b) = ([x, y, z], [x, y, z]);
                    b[axis] += 1;
                    let across = [1, 2].map(|j| {
                        let k = (axis + j) % 3;
                        let (mut a, mut b) = (a, b);
                        a[k] += 1;
                        b[k] += 1;
                        [read(a), read(b)]
                    });
                    if let Some(p) = crossing(rule, low, axis, (tsdf[ia], color[ia]), (tb, cb), across) {
                        visit(p);
                    }
                }
            }
        }
    }
}

/// Bit masks (bit x) of the observed and of the observed negative voxels of one row of 8.
#[inline(always)]
fn row_masks(tsdf: &[i16], weight: &[u16], min_weight: u16) -> (u16, u16) {
    let (mut observed, mut negative) = (0u16, 0u16);
    for (x, (&t, &w)) in tsdf.iter().zip(weight).enumerate() {
        let o = (w >= min_weight) as u16;
        observed |= o << x;
        negative |= (o & (t < 0) as u16) << x;
    }
    (observed, negative)
}

/// The surface point on the edge from voxel `low` (distance and colour `a`) one step along
/// `axis` to a voxel of `b`, both observed and of opposite signs; `None` when the edge is a
/// seam. Positions and colours with the mesher's arithmetic, operation for operation.
/// `across[j]`: the distances one step further along axis `(axis + 1 + j) % 3` from `a` and
/// from `b` (`None`: unobserved or not read), for the normal.
#[inline]
fn crossing(
    rule: &SurfaceRule,
    low: IVec3,
    axis: usize,
    a: (i16, [u8; 4]),
    b: (i16, [u8; 4]),
    across: [[Option<i16>; 2]; 2],
) -> Option<SurfacePoint> {
    let (fa, fb) = (a.0 as f32 * (1.0 / TSDF_SCALE), b.0 as f32 * (1.0 / TSDF_SCALE));
    if (fa - fb).abs() > rule.max_jump {
        return None;
    }
    let s = fa / (fa - fb);
    let mut p = low.as_vec3();
    p[axis] += s;
    // The gradient in stored units per voxel: forward differences, exact on a plane (the
    // distance is linear near a surface), from the voxels the chunk has at hand; the mesher's
    // central differences would need the lower neighbours too.
    let mut gradient = Vec3::ZERO;
    gradient[axis] = f32::from(b.0) - f32::from(a.0);
    for (j, [next_a, next_b]) in across.into_iter().enumerate() {
        let differences =
            [next_a.map(|v| f32::from(v) - f32::from(a.0)), next_b.map(|v| f32::from(v) - f32::from(b.0))];
        let (sum, n) = differences.into_iter().flatten().fold((0.0, 0.0), |(s, n), d| (s + d, n + 1.0));
        if n > 0.0 {
            gradient[(axis + 1 + j) % 3] = sum / n;
        }
    }
    Some(SurfacePoint {
        low,
        position: p * rule.voxel_size,
        color: edge_color(a.1, b.1, s),
        axis: axis as u8,
        normal: gradient.normalize_or_zero(),
    })
}

/// [`for_each_chunk_point`] one voxel and one edge at a time, through global voxel
/// coordinates: the specification. Points in (voxel z, y, x, axis) order.
pub fn chunk_points_reference(map: &TsdfMap, key: ChunkKey, rule: &SurfaceRule) -> Vec<SurfacePoint> {
    let mut points = Vec::new();
    if map.chunk(key).is_none() {
        return points;
    }
    let side = CHUNK_SIDE as i32;
    // Distance and colour of an observed voxel the chunk reads (its own, and those of its
    // upper neighbours' lower faces: local coordinates 0 ..= 8 with at most one 8); None when
    // unobserved, not allocated or not read.
    let voxel = |v: IVec3| -> Option<(i16, [u8; 4])> {
        let local = v - key * side;
        let inside = local.cmpge(IVec3::ZERO).all() && local.cmple(IVec3::splat(side)).all();
        if !inside || local.to_array().iter().filter(|&&l| l == side).count() > 1 {
            return None;
        }
        let (k, i) = split_voxel(v);
        let c = map.chunk(k)?;
        (c.stored_weights()[i] >= rule.min_stored_weight).then(|| (c.stored_tsdf()[i], c.stored_colors()[i]))
    };
    // Whether the cell with lowest corner `c` is the chunk's and has its 8 corners observed.
    let full_cell = |c: IVec3| -> bool {
        let local = c - key * side;
        local.cmpge(IVec3::ZERO).all()
            && local.cmplt(IVec3::splat(side)).all()
            && (0..8).all(|k| voxel(c + IVec3::new(k & 1, (k >> 1) & 1, k >> 2)).is_some())
    };
    for z in 0..side {
        for y in 0..side {
            for x in 0..side {
                let low = key * side + IVec3::new(x, y, z);
                let Some(a) = voxel(low) else { continue };
                for (axis, step) in AXES.iter().enumerate() {
                    let Some(b) = voxel(low + *step) else { continue };
                    if (a.0 < 0) == (b.0 < 0) {
                        continue;
                    }
                    // The four cells around the edge: its low end moved back on the other axes.
                    let (u, w) = (AXES[(axis + 1) % 3], AXES[(axis + 2) % 3]);
                    if ![IVec3::ZERO, u, w, u + w].iter().any(|d| full_cell(low - *d)) {
                        continue;
                    }
                    let across = [1, 2].map(|j| {
                        let next = AXES[(axis + j) % 3];
                        [voxel(low + next).map(|v| v.0), voxel(low + *step + next).map(|v| v.0)]
                    });
                    points.extend(crossing(rule, low, axis, a, b, across));
                }
            }
        }
    }
    points
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
    use semrecon_data::FrameSource;
    use semrecon_recon::extract_mesh_with;

    /// A map of a short synthetic scan at 2 cm, with some frames of random depth fused into
    /// it: noise, seams between free space and surfaces, light and unobserved voxels.
    fn noisy_map(seed: u64) -> TsdfMap {
        let mut config = SyntheticScanConfig::new(seed);
        config.frames = 6;
        config.intrinsics = config.intrinsics.scaled(80, 60);
        let (_room, scan) = synthetic_scan(&config).expect("scan");
        let tsdf = TsdfConfig { voxel_size: 0.02, truncation_voxels: 4.0, ..TsdfConfig::default() };
        let mut map = TsdfMap::new(tsdf).expect("map");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        for i in 0..scan.len() {
            let mut frame = scan.frame(i).expect("frame");
            let pose = frame.world_from_camera.expect("pose");
            if i % 3 == 2 {
                for d in frame.depth.iter_mut() {
                    *d = match rng.random_range(0..10) {
                        0 => 0.0,
                        1 => rng.random_range(0.3..4.0),
                        _ => *d + rng.random_range(-0.03..0.03),
                    };
                }
            }
            map.integrate(&frame, pose).expect("fusion");
        }
        map
    }

    fn sorted(mut points: Vec<SurfacePoint>) -> Vec<SurfacePoint> {
        points.sort_by_key(|p| (p.position.to_array().map(f32::to_bits), p.axis));
        points
    }

    #[test]
    fn masked_scan_finds_the_points_of_the_voxel_by_voxel_reference() {
        for seed in 1..4 {
            let map = noisy_map(seed);
            for (min_weight, jump) in [(0.0, None), (0.25, None), (1.5, Some(0.3)), (0.25, Some(1.0))] {
                let mesh = MeshConfig { min_weight, min_component_triangles: 0 };
                let mut rule = SurfaceRule::new(map.config(), &mesh);
                if let Some(j) = jump {
                    rule.max_jump = j;
                }
                let mut total = 0;
                for key in map.sorted_keys() {
                    let mut fast = Vec::new();
                    for_each_chunk_point(&map, key, &rule, |p| fast.push(p));
                    let reference = chunk_points_reference(&map, key, &rule);
                    total += reference.len();
                    assert_eq!(sorted(fast), sorted(reference), "seed {seed}, chunk {key}, rule {rule:?}");
                }
                assert!(total > 1000, "seed {seed}: {total} points");
            }
            assert!(chunk_points_reference(
                &map,
                IVec3::splat(1000),
                &SurfaceRule::new(map.config(), &MeshConfig::RECOMMENDED)
            )
            .is_empty());
        }
    }

    /// The vertices of a full mesh of the map are the surface points with the same positions
    /// and colours, bit for bit, but for about one in a hundred at hole borders and seams (see the
    /// module documentation).
    #[test]
    fn the_mesh_vertices_are_the_surface_points() {
        for seed in 1..4 {
            let map = noisy_map(seed);
            for min_weight in [0.0, 0.25] {
                let config = MeshConfig { min_weight, min_component_triangles: 0 };
                let rule = SurfaceRule::new(map.config(), &config);
                let mesh = extract_mesh_with(&map, config).expect("mesh");
                // Colours by position: crossings exactly at a voxel (distance 0, frequent at
                // 1/2047 steps) share a position across edges, and an edge with an uncoloured
                // end takes the other end's colour, so one position can carry several colours.
                let mut points = std::collections::HashMap::<_, Vec<[u8; 3]>>::new();
                for key in map.sorted_keys() {
                    for_each_chunk_point(&map, key, &rule, |p| {
                        points.entry(p.position.to_array().map(f32::to_bits)).or_default().push(p.color);
                    });
                }
                assert!(mesh.positions.len() > 1000);
                let mut shared = 0;
                for (p, c) in mesh.positions.iter().zip(&mesh.colors) {
                    if let Some(found) = points.get(&p.to_array().map(f32::to_bits)) {
                        assert!(
                            found.contains(c),
                            "seed {seed}: the point at vertex {p} has another colour: {found:?} {c:?}"
                        );
                        shared += 1;
                    }
                }
                let (missing, extra) = (mesh.positions.len() - shared, points.len().saturating_sub(shared));
                eprintln!(
                    "seed {seed}, min weight {min_weight}: {} vertices, {missing} not points, {extra} points not vertices",
                    mesh.positions.len()
                );
                // Measured on these maps, whose random depth frames make seams and holes
                // everywhere: at most 1.3 % missed and 1.8 % more.
                assert!(missing * 50 < mesh.positions.len(), "{missing} of {} vertices missed", mesh.positions.len());
                assert!(extra * 40 < points.len(), "{extra} of {} points off the mesh", points.len());
            }
        }
    }

    /// On a tilted plane the normals are the plane's (forward differences of a linear field
    /// are exact), pointing to free space, whatever the edge.
    #[test]
    fn point_normals_are_the_planes() {
        let rule = SurfaceRule { min_stored_weight: 1, max_jump: 1.0, voxel_size: 0.01 };
        let n = Vec3::new(0.3, -0.5, 0.8).normalize();
        // Distance in stored units at voxel v of the plane n . v = 0.4 (voxels), with a
        // truncation of 11 voxels.
        let d = |v: IVec3| ((n.dot(v.as_vec3()) - 0.4) * (TSDF_SCALE / 11.0)).round() as i16;
        let mut points = 0;
        for low in [IVec3::ZERO, IVec3::new(-1, 1, 0), IVec3::new(1, 1, 0), IVec3::new(0, 0, 1)] {
            for (axis, step) in AXES.iter().enumerate() {
                let (a, b) = (d(low), d(low + *step));
                if (a < 0) == (b < 0) {
                    continue;
                }
                let across = [1, 2].map(|j| {
                    let next = AXES[(axis + j) % 3];
                    [Some(d(low + next)), Some(d(low + *step + next))]
                });
                let p = crossing(&rule, low, axis, (a, [0; 4]), (b, [0; 4]), across).expect("no seam");
                assert!(p.normal.dot(n) > 0.9999, "{:?} against {n}", p.normal);
                points += 1;
            }
        }
        assert!(points >= 3);
        assert_eq!(readers_of(IVec3::ONE)[3], IVec3::new(1, 1, 0));
    }
}
