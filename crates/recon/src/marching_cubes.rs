//! Surface extraction: marching cubes per chunk, cached, re-run only where the map changed.
//!
//! Cells join 2x2x2 voxel centres. A chunk owns the 8x8x8 cells whose lowest corner is one
//! of its voxels, so the cells between two chunks are computed once, by the lower chunk,
//! reading the upper neighbours' boundary voxels. Cells with an unobserved corner (weight 0,
//! or below [`MeshConfig::min_weight`]) are skipped, and so are cells where a crossed edge jumps by more than the narrowest
//! truncation band (the seam between observed free space and the back of a surface, not a
//! surface), so no phantom surfaces appear. Vertex colours are interpolated from the voxel
//! colours; normals are the interpolated central-difference gradient of the TSDF, pointing
//! to the positive (free-space, camera) side; triangles wind counter-clockwise seen from it.
//!
//! Each chunk is meshed from a padded copy of its cells' corners (its voxels and its upper
//! neighbours' boundary voxels), in three passes: classify the cells, make the triangles
//! (numbering each crossed cell edge's vertex when first used), then make the vertices in
//! batches of 16 (AVX-512 or AVX2 where the CPU has them, the same bits as the scalar
//! definition), reading only the padded block, which for that is completed with the
//! one-voxel shell beyond (the central differences at the corners) and the colours. So a
//! chunk's mesh depends on its 26 neighbours: when a chunk changes, it and its allocated neighbours are
//! re-meshed (with a [`RemeshTolerance`], only when it changed materially, and only the
//! neighbours that read the changed voxels). Chunk meshes are welded into one mesh by the
//! global key of the cell edge each vertex sits on, so the result is watertight where the
//! surface is closed. An [`IncrementalMesher`] may be given a budget of chunks per update,
//! which bounds a keyframe's meshing time at the price of refreshes arriving keyframes late
//! (see its "Budget" section).

use std::collections::HashMap;

use glam::{IVec3, Vec3, Vec4};
use rayon::prelude::*;
use semrecon_data::LabeledMesh;

use crate::cube_cases::{case_table, EDGES};

mod assembly;
#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;
mod incremental;
mod packed_mesh;
mod reader_marks;
mod triangles;
mod vertices;
use crate::map::{
    key_order, Chunk, ChunkHashBuilder, ChunkKey, TsdfMap, VoxelBlock, CHUNK_SIDE, CHUNK_VOXELS, TSDF_SCALE,
    WEIGHT_SCALE,
};
use assembly::{assemble, assemble_from, PackedMeshes};
pub use incremental::{IncrementalMesher, MeshStoreMemory, MeshingStats, RemeshTolerance};
use packed_mesh::{PackedChunkMesh, PackedStore, Unpacker};
use reader_marks::{ALL_READERS, CELL_READERS};
#[allow(clippy::wildcard_imports)]
use triangles::*;
use vertices::{edge_parameter, make_vertices, position_on_edge, VertexJob, VertexKernel, VertexLanes, LANES};
#[cfg(test)]
use vertices::{vertices_scalar, STRIDES};

/// Largest TSDF difference across a cell edge that still counts as a surface crossing, in
/// units of the narrowest truncation band: a real surface changes the TSDF by about one
/// voxel per voxel, the seam between free space and the back of a surface by two bands or
/// more (with the band depending on depth, the narrowest band bounds that seam from below).
/// 1.5 bands, not less: far away (3-4 m) the averaged Kinect noise makes real crossings
/// jump by several voxels, and a tighter limit (one narrowest band, 4 voxels) punched holes
/// into the demo's far floor and walls. Never more than one whole truncation distance, the
/// limit of the fixed band.
const MAX_EDGE_JUMP_BANDS: f32 = 1.5;

/// The largest TSDF difference across a cell edge, in truncation units, that meshing takes
/// for a surface crossing in a map of `config`: 1.5 narrowest bands, at most one truncation
/// (beyond it the edge is a seam between free space and the back of a surface). For other
/// readers of zero crossings (the semantic map's surface cells) to see the surface the mesh
/// shows.
pub fn max_edge_jump(config: &crate::TsdfConfig) -> f32 {
    (MAX_EDGE_JUMP_BANDS * config.narrowest_band_voxels() / config.truncation_voxels).min(1.0)
}

/// Side of the padded block: the chunk plus one voxel on every side.
const PAD: usize = CHUNK_SIDE + 3;
const PAD2: usize = PAD * PAD;
/// Side of the grid of cell-edge low corners.
const ES: usize = CHUNK_SIDE + 1;

/// Global key of a cell edge: its lower voxel and its axis (0 x, 1 y, 2 z).
type EdgeKey = (IVec3, u8);

/// The triangles of one chunk.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ChunkMesh {
    /// Vertex positions, metres, world frame.
    pub positions: Vec<Vec3>,
    /// Vertex colours.
    pub colors: Vec<[u8; 3]>,
    /// Unit vertex normals toward free space (zero where the gradient vanishes), rounded to
    /// 32-bit octahedral codes (within 0.004 degrees; what the live mesh keeps).
    pub normals: Vec<Vec3>,
    /// Triangles, counter-clockwise seen from free space, as indices into this chunk's
    /// vertices (a chunk has fewer than 4096).
    pub triangles: Vec<[u16; 3]>,
    /// Vertices on cell edges that neighbouring chunks also use, with their edges
    /// (ascending vertex order); the assembly welds them.
    shared: Vec<SharedVertex>,
}

/// A chunk's vertex on a cell edge that neighbouring chunks also use, with the edge local to
/// the chunk: the edge's low corner as a voxel offset from the chunk's first voxel (4 bits
/// per axis) and its axis: 4 bytes where the global key took 20.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct SharedVertex {
    vertex: u16,
    edge: u16,
}

impl SharedVertex {
    /// Vertex `vertex` (below 4096) on the edge along `axis` from voxel offset `low` (each
    /// 0..16).
    fn new(vertex: u32, axis: usize, low: [i32; 3]) -> Self {
        debug_assert!(vertex < 1 << 12 && axis < 3 && low.iter().all(|c| (0..16).contains(c)));
        let edge = low[0] as u16 | (low[1] as u16) << 4 | (low[2] as u16) << 8 | (axis as u16) << 12;
        Self { vertex: vertex as u16, edge }
    }

    /// The edge's global key in the chunk whose first voxel is `key_voxel`.
    fn key(self, key_voxel: IVec3) -> EdgeKey {
        let e = i32::from(self.edge);
        (key_voxel + IVec3::new(e & 15, e >> 4 & 15, e >> 8 & 15), (e >> 12) as u8)
    }
}

impl ChunkMesh {
    /// Heap bytes of the vectors: (at their capacities, at their lengths).
    pub fn heap_bytes(&self) -> (usize, usize) {
        fn bytes<T>(v: &Vec<T>) -> (usize, usize) {
            let size = std::mem::size_of::<T>();
            (v.capacity() * size, v.len() * size)
        }
        [bytes(&self.positions), bytes(&self.colors), bytes(&self.normals), bytes(&self.triangles), bytes(&self.shared)]
            .into_iter()
            .fold((0, 0), |(a, u), (x, y)| (a + x, u + y))
    }

    fn clear(&mut self) {
        self.positions.clear();
        self.colors.clear();
        self.normals.clear();
        self.triangles.clear();
        self.shared.clear();
    }
}

/// A padded copy of one chunk with its one-voxel shell (laid out over padded coordinates
/// 0 ..= 10): [`PaddedBlock::gather`] fills 1 ..= 9, the cells' corners, which is all that
/// classifying cells needs; [`PaddedBlock::gather_shell`], run only for chunks with crossed
/// cells, adds the six faces of the shell (padded 0 or 10 on one axis, 1 ..= 9 on the
/// others: the central differences of the corners read nothing else) and the corners'
/// colours, so that making a vertex reads only this block.
///
/// Distances stay quantised (`i16`) until a vertex needs them; which voxels are observed
/// (stored weight at least `min_weight`, see [`MeshConfig`]) and negative is kept as row bit
/// masks (from the gather) and as flag bits in `packed` (from the shell gather).
struct PaddedBlock {
    tsdf: [i16; PAD * PAD2],
    /// Per voxel `tsdf << 16 | flags` (bit 0 negative and observed, bit 1 observed) over
    /// padded 1 ..= 9 and the shell's faces (from [`PaddedBlock::gather_shell`]): one load (or gather) reads a neighbour's distance and
    /// whether it is observed.
    packed: [i32; PAD * PAD2],
    /// Colours `[r, g, b, count]` of padded 1 ..= 9; unallocated voxels 0.
    color: [[u8; 4]; PAD * PAD2],
    /// Smallest stored weight of an observed voxel (at least 1), set by the gather.
    min_weight: u16,
}

/// A voxel as [`PaddedBlock`]'s `packed` holds it: `tsdf << 16 | flags`.
#[inline(always)]
fn packed_voxel(tsdf: i16, weight: u16, min_weight: u16) -> i32 {
    let observed = (weight >= min_weight) as i32;
    (tsdf as i32) << 16 | ((tsdf < 0) as i32 & observed) | observed << 1
}

/// [`packed_voxel`] of eight voxels.
///
/// # Shapes
/// `tsdf`, `weight`: 8 long (fewer: zeros).
#[inline(always)]
fn packed_lanes(tsdf: &[i16], weight: &[u16], min_weight: u16) -> [i32; 8] {
    let (t, w) = (tsdf.try_into().unwrap_or(&[0; 8]), weight.try_into().unwrap_or(&[0; 8]));
    #[cfg(target_arch = "x86_64")]
    {
        packed_lanes_sse2(t, w, min_weight)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        std::array::from_fn(|k| packed_voxel(t[k], w[k], min_weight))
    }
}

/// [`packed_lanes`] with SSE2 (part of x86-64): the flags as 16-bit lanes, interleaved
/// below the distances.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn packed_lanes_sse2(t: &[i16; 8], w: &[u16; 8], min_weight: u16) -> [i32; 8] {
    use std::arch::x86_64::*;
    let mut out = [0i32; 8];
    // SAFETY: SSE2 is part of x86-64; the loads read the two 8-element arrays, the stores
    // write the 8-element `out`.
    unsafe {
        let t = _mm_loadu_si128(t.as_ptr().cast::<__m128i>());
        let w = _mm_loadu_si128(w.as_ptr().cast::<__m128i>());
        // Unsigned `w < min_weight` as a signed compare with both sides' top bits flipped.
        let flip = _mm_set1_epi16(i16::MIN);
        let unobserved = _mm_cmpgt_epi16(_mm_set1_epi16((min_weight ^ 0x8000) as i16), _mm_xor_si128(w, flip));
        let negative = _mm_and_si128(_mm_cmpgt_epi16(_mm_setzero_si128(), t), _mm_set1_epi16(1));
        let flags = _mm_andnot_si128(unobserved, _mm_or_si128(negative, _mm_set1_epi16(OBSERVED as i16)));
        // Little-endian lanes: each i32 is (flags, distance) = distance << 16 | flags.
        _mm_storeu_si128(out.as_mut_ptr().cast::<__m128i>(), _mm_unpacklo_epi16(flags, t));
        _mm_storeu_si128(out.as_mut_ptr().add(4).cast::<__m128i>(), _mm_unpackhi_epi16(flags, t));
    }
    out
}

/// Padded coordinate `p` (local `p - 1`, -1 ..= 9) -> (chunk offset + 1, local coordinate
/// in that chunk).
const SPLIT: [(u8, u8); PAD] = {
    let mut t = [(0u8, 0u8); PAD];
    let mut p = 0;
    while p < PAD {
        let l = p as i32 - 1;
        let o = l.div_euclid(CHUNK_SIDE as i32);
        t[p] = ((o + 1) as u8, (l - o * CHUNK_SIDE as i32) as u8);
        p += 1;
    }
    t
};

/// Colour `[r, g, b, count]` of the voxel at padded coordinates `p` (`-1 ..= 9` local plus
/// one), read from the chunk that holds it; unobserved black when it is not allocated (the
/// reference for [`PaddedBlock::color`]).
#[cfg(test)]
fn voxel_color(nb: &[Option<&VoxelBlock>; 27], p: [usize; 3]) -> [u8; 4] {
    let ((ox, ix), (oy, iy), (oz, iz)) = (SPLIT[p[0]], SPLIT[p[1]], SPLIT[p[2]]);
    match nb[ox as usize + 3 * oy as usize + 9 * oz as usize] {
        Some(c) => c.color[ix as usize + CHUNK_SIDE * (iy as usize + CHUNK_SIDE * iz as usize)],
        None => [0; 4],
    }
}

/// Colour of a vertex at fraction `s` (0 ..= 1) of the way from a voxel of colour `ca` to
/// one of colour `cb` (`[r, g, b, count]`), interpolated only between voxels that have a
/// colour (count not 0). The semantic pass's surface points take their colour from it too,
/// so that they match the mesh's vertices.
///
/// Four lanes at once with the operations, and their order, of the per-channel
/// `(a + s (b - a) + 0.5) as u8` (the sum lies in 0 ..= 255.5, so truncating to `i32`
/// then `u8` is that cast), which took twice the instructions.
#[inline]
pub fn edge_color(ca: [u8; 4], cb: [u8; 4], s: f32) -> [u8; 3] {
    let (ca, cb) = match (ca[3], cb[3]) {
        (0, 0) | (1.., 1..) => (ca, cb),
        (0, _) => (cb, cb),
        (_, 0) => (ca, ca),
    };
    let (a, b) = (Vec4::from(ca.map(f32::from)), Vec4::from(cb.map(f32::from)));
    let c = (a + Vec4::splat(s) * (b - a) + Vec4::splat(0.5)).as_ivec4();
    [c.x as u8, c.y as u8, c.z as u8]
}

/// Per case, bit `e` set when edge `e` joins corners of different signs (crosses the surface):
/// the reference for [`first_uses`] (a test finds them the used edges) and the mask of
/// [`seam_avx2`].
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
const CROSSED: [u16; 256] = {
    let mut t = [0u16; 256];
    let mut case = 0;
    while case < 256 {
        let mut e = 0;
        while e < 12 {
            let (a, b) = EDGES[e];
            if ((case >> a) ^ (case >> b)) & 1 != 0 {
                t[case] |= 1 << e;
            }
            e += 1;
        }
        case += 1;
    }
    t
};

/// Per edge, the offset of its key in the cell-edge grid from its cell's first key
/// (`((z ES + y) ES + x) 3`): its low corner's offset and its axis.
const EDGE_KEY: [usize; 12] = {
    let mut t = [0usize; 12];
    let mut e = 0;
    while e < 12 {
        let a = EDGES[e].0 as usize;
        t[e] = (((a >> 2) & 1) * ES * ES + ((a >> 1) & 1) * ES + (a & 1)) * 3 + e / 4;
        e += 1;
    }
    t
};

/// Bit of an observed voxel in [`PaddedBlock`]'s packed flags (bit 0: negative and observed).
const OBSERVED: u8 = 2;

/// The voxels of the chunk and its 26 neighbours at `(dx + 1) + 3 (dy + 1) + 9 (dz + 1)`, or
/// None when the chunk's cells cannot hold a surface ([`PaddedBlock::may_have_surface`]). The
/// chunk and its 7 upper neighbours are looked up first: most chunks stop there. Each chunk's
/// voxels are reached once here (a packed chunk unpacks, or its cache is found), not at every
/// row the gathers copy.
fn neighbours_if_surface(map: &TsdfMap, key: ChunkKey) -> Option<[Option<&VoxelBlock>; 27]> {
    let mut nb: [Option<&Chunk>; 27] = [None; 27];
    for &i in &UPPER {
        nb[i] = map.chunk(key + NEIGHBOUR_OFFSET[i]);
    }
    if !PaddedBlock::may_have_surface(&nb) {
        return None;
    }
    for &i in &OTHERS {
        nb[i] = map.chunk(key + NEIGHBOUR_OFFSET[i]);
    }
    Some(nb.map(|c| c.map(|c| &*c.voxels)))
}

/// Neighbour `i`'s offset `(i % 3, i / 3 % 3, i / 9) - 1`.
const NEIGHBOUR_OFFSET: [IVec3; 27] = {
    let mut t = [IVec3::ZERO; 27];
    let mut i = 0;
    while i < 27 {
        t[i] = IVec3::new(i as i32 % 3 - 1, (i as i32 / 3) % 3 - 1, i as i32 / 9 - 1);
        i += 1;
    }
    t
};

/// The chunk and its 7 upper neighbours (offsets 0 or +1 on every axis), then the rest.
const UPPER: [usize; 8] = [13, 14, 16, 17, 22, 23, 25, 26];
const OTHERS: [usize; 19] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 15, 18, 19, 20, 21, 24];

/// Bit masks (bit `px`, only padded x 1 ..= 9 set) of the negative observed and of the
/// observed voxels of the padded row starting at `start` (padded x 0), from the distances
/// and weights of padded x 0 ..= 15 (beyond 10: the next row, masked off).
///
/// # Shapes
/// `tsdf` and `weight`: at least `start + 16` long.
#[inline(always)]
fn row_masks(tsdf: &[i16], weight: &[u16], start: usize, min_weight: u16) -> (u16, u16) {
    let (t, w) = (&tsdf[start..start + 16], &weight[start..start + 16]);
    #[cfg(target_arch = "x86_64")]
    {
        row_masks_sse2(t.try_into().unwrap_or(&[0; 16]), w.try_into().unwrap_or(&[0; 16]), min_weight)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        row_masks_scalar(t, w, min_weight)
    }
}

/// [`row_masks`] voxel by voxel: the reference (and the path off x86-64).
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
fn row_masks_scalar(t: &[i16], w: &[u16], min_weight: u16) -> (u16, u16) {
    let (mut neg, mut obs) = (0u16, 0u16);
    for px in 1..PAD - 1 {
        let observed = (w[px] >= min_weight) as u16;
        obs |= observed << px;
        neg |= ((t[px] < 0) as u16 & observed) << px;
    }
    (neg, obs)
}

/// [`row_masks`] with SSE2 (part of x86-64): two compares per eight voxels and one
/// `movemask` per mask, where the byte-flag pass and the bit packing cost about 40
/// instructions per row.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn row_masks_sse2(t: &[i16; 16], w: &[u16; 16], min_weight: u16) -> (u16, u16) {
    use std::arch::x86_64::*;
    // SAFETY: SSE2 is part of x86-64; the loads read the two 16-element arrays.
    unsafe {
        let load = |p: *const i16| _mm_loadu_si128(p.cast::<__m128i>());
        let (t0, t1) = (load(t.as_ptr()), load(t.as_ptr().add(8)));
        let (w0, w1) = (load(w.as_ptr().cast()), load(w.as_ptr().add(8).cast()));
        // Unsigned `w < min_weight` as a signed compare with both sides' top bits flipped.
        let flip = _mm_set1_epi16(i16::MIN);
        let min = _mm_set1_epi16((min_weight ^ 0x8000) as i16);
        let unobserved0 = _mm_cmpgt_epi16(min, _mm_xor_si128(w0, flip));
        let unobserved1 = _mm_cmpgt_epi16(min, _mm_xor_si128(w1, flip));
        let zero = _mm_setzero_si128();
        let neg0 = _mm_andnot_si128(unobserved0, _mm_cmpgt_epi16(zero, t0));
        let neg1 = _mm_andnot_si128(unobserved1, _mm_cmpgt_epi16(zero, t1));
        let unobserved = _mm_movemask_epi8(_mm_packs_epi16(unobserved0, unobserved1)) as u16;
        let neg = _mm_movemask_epi8(_mm_packs_epi16(neg0, neg1)) as u16;
        const INNER: u16 = ((1 << (PAD - 1)) - 1) & !1;
        (neg & INNER, !unobserved & INNER)
    }
}

impl PaddedBlock {
    /// Whether the cells owned by the chunk (corners in it and its 7 upper neighbours) can
    /// hold a surface: they need an observed negative and an observed non-negative voxel.
    ///
    /// An upper neighbour offset along x (alone or with other axes) contributes only voxels of
    /// its x = 0 face, so its face bits suffice (a superset for edge and corner neighbours).
    fn may_have_surface(nb: &[Option<&Chunk>; 27]) -> bool {
        let Some(own) = nb[13] else { return false };
        let mut signs = own.signs & 3;
        for dz in 1..3 {
            for dy in 1..3 {
                for dx in 1..3 {
                    if (dx, dy, dz) == (1, 1, 1) {
                        continue;
                    }
                    if let Some(c) = nb[dx + 3 * dy + 9 * dz] {
                        let face = if dx == 2 {
                            2
                        } else if dy == 2 {
                            4
                        } else {
                            6
                        };
                        signs |= (c.signs >> face) & 3;
                    }
                }
            }
        }
        signs == 3
    }

    fn new() -> Box<Self> {
        Box::new(PaddedBlock {
            tsdf: [0; PAD * PAD2],
            packed: [0; PAD * PAD2],
            color: [[0; 4]; PAD * PAD2],
            min_weight: 1,
        })
    }

    /// Copies the voxels of local coordinates `0 ..= 8` (padded 1 ..= 9: the corners of the
    /// chunk's cells) from the chunk and its upper neighbours (unallocated ones read as
    /// unobserved), and returns per padded row (`py + 11 pz`, rows with `py`, `pz` in 1 ..= 9)
    /// the bit masks (bit `px`, valid for 1 ..= 9) of negative and of observed voxels
    /// (stored weight at least `min_weight`, which is at least 1).
    ///
    /// Distances and weights are copied first, row piece by row piece (fixed lengths the
    /// compiler turns into a few moves), then the masks come from one pass over the copy
    /// ([`row_masks`]): per-element branching on the neighbour cost more than the marching.
    /// The weights stay in `weight` for [`PaddedBlock::gather_shell`].
    #[inline(never)]
    fn gather(
        &mut self,
        nb: &[Option<&VoxelBlock>; 27],
        min_weight: u16,
        weight: &mut [u16; PAD * PAD2],
        masks: &mut [(u16, u16); PAD2],
    ) {
        const N: usize = CHUNK_SIDE;
        let b = self;
        b.min_weight = min_weight;
        // Padded coordinate p holds local voxel p - 1 (-1 ..= 9): in chunk offset -1, 0 or 1.
        let split = |p: usize| -> (usize, usize) {
            let l = p as i32 - 1;
            let o = l.div_euclid(N as i32);
            ((o + 1) as usize, (l - o * N as i32) as usize)
        };
        // Only padded 1 ..= 9 (local 0 ..= 8: the cells' corners): the gradient's outer shell
        // (padded 0 and 10) is read from the chunks for the few vertices on the boundary
        // ([`PaddedBlock::gradient`]). Copying it touched 19 more chunks, and those cache
        // misses cost a fifth of meshing. Entries at padded 0 and 10 keep stale values.
        for pz in 1..PAD - 1 {
            let (oz, iz) = split(pz);
            for py in 1..PAD - 1 {
                let (oy, iy) = split(py);
                let dst = PAD * py + PAD2 * pz;
                let src = N * (iy + N * iz);
                let nb_row = 3 * oy + 9 * oz;
                // Padded x 1..=8: the whole row of the middle chunk.
                let (t_row, w_row) = (&mut b.tsdf[dst + 1..dst + 1 + N], &mut weight[dst + 1..dst + 1 + N]);
                match nb[nb_row + 1] {
                    Some(c) => {
                        t_row.copy_from_slice(&c.tsdf[src..src + N]);
                        w_row.copy_from_slice(&c.weight[src..src + N]);
                    }
                    None => w_row.fill(0),
                }
                // Padded x 9: local x 0 of the upper neighbour.
                match nb[nb_row + 2] {
                    Some(c) => {
                        b.tsdf[dst + 1 + N] = c.tsdf[src];
                        weight[dst + 1 + N] = c.weight[src];
                    }
                    None => weight[dst + 1 + N] = 0,
                }
            }
        }
        // Masks straight from the copied distances and weights, 16 voxels (padded x 0 ..= 15)
        // per row: the flag bytes of padded 1 ..= 9 wait for [`PaddedBlock::gather_shell`],
        // which only chunks with crossed cells run. A separate pass: reading a row right after
        // its piecewise stores would stall on store forwarding.
        for pz in 1..PAD - 1 {
            for py in 1..PAD - 1 {
                let r = py + PAD * pz;
                masks[r] = row_masks(&b.tsdf, &weight[..], r * PAD, min_weight);
            }
        }
    }

    /// Completes the block for making vertices: `packed` over padded 1 ..= 9 and the six
    /// faces of the shell (unallocated voxels unobserved), and the colours of padded 1 ..= 9.
    ///
    /// Run only for chunks with crossed cells (after the classification), since it reads
    /// the 19 other neighbours too. Row pieces are copied as in [`PaddedBlock::gather`]; only
    /// the x faces are read voxel by voxel.
    #[inline(never)]
    fn gather_shell(&mut self, nb: &[Option<&VoxelBlock>; 27], weight: &[u16; PAD * PAD2]) {
        const N: usize = CHUNK_SIDE;
        let min_weight = self.min_weight;
        // The gathered rows, padded x 1 ..= 8 and 2 ..= 9 (eight lanes twice, overlapping):
        // voxel by voxel this loop did not vectorise and cost half the shell.
        for pz in 1..PAD - 1 {
            for py in 1..PAD - 1 {
                let row = PAD * py + PAD2 * pz;
                for start in [row + 1, row + 2] {
                    let lanes = packed_lanes(&self.tsdf[start..start + 8], &weight[start..start + 8], min_weight);
                    self.packed[start..start + 8].copy_from_slice(&lanes);
                }
            }
        }
        let one = |c: Option<&VoxelBlock>, j: usize| match c {
            Some(c) => packed_voxel(c.tsdf[j], c.weight[j], min_weight),
            None => 0,
        };
        // Rows of corners: their x faces (local -1 and 9) and their colours.
        // Index loops: the iterator form clippy suggests cost a tenth more here.
        #[allow(clippy::needless_range_loop)]
        for pz in 1..PAD - 1 {
            let (oz, iz) = SPLIT[pz];
            for py in 1..PAD - 1 {
                let (oy, iy) = SPLIT[py];
                let dst = PAD * py + PAD2 * pz;
                let src = N * (iy as usize + N * iz as usize);
                let nb_row = 3 * oy as usize + 9 * oz as usize;
                self.packed[dst] = one(nb[nb_row], src + N - 1);
                self.packed[dst + PAD - 1] = one(nb[nb_row + 2], src + 1);
                self.color[dst + PAD - 2] = nb[nb_row + 2].map_or([0; 4], |c| c.color[src]);
                let row = &mut self.color[dst + 1..dst + 1 + N];
                match nb[nb_row + 1] {
                    Some(c) => row.copy_from_slice(&c.color[src..src + N]),
                    None => row.fill([0; 4]),
                }
            }
        }
        // The y and z faces: rows of padded x 1 ..= 9.
        for p in 1..PAD - 1 {
            for q in [0, PAD - 1] {
                for (py, pz) in [(q, p), (p, q)] {
                    let ((oy, iy), (oz, iz)) = (SPLIT[py], SPLIT[pz]);
                    let dst = PAD * py + PAD2 * pz;
                    let row = (iy as usize + N * iz as usize) * N;
                    let nb_row = 3 * oy as usize + 9 * oz as usize;
                    let out = &mut self.packed[dst + 1..dst + 1 + N];
                    match nb[nb_row + 1] {
                        Some(c) => {
                            // Whole rows of the chunk as arrays: the loop vectorises.
                            let t = &c.tsdf.as_chunks::<N>().0[row / N];
                            let w = &c.weight.as_chunks::<N>().0[row / N];
                            let mut packed = [0i32; N];
                            for k in 0..N {
                                packed[k] = packed_voxel(t[k], w[k], min_weight);
                            }
                            out.copy_from_slice(&packed);
                        }
                        None => out.fill(0),
                    }
                    self.packed[dst + 1 + N] = one(nb[nb_row + 2], row);
                }
            }
        }
    }

    /// Colour `[r, g, b, count]` at padded index `i` (coordinates 1 ..= 9).
    #[inline]
    fn color(&self, i: usize) -> [u8; 4] {
        self.color[i]
    }

    /// Central-difference TSDF gradient at padded index `i`, coordinates `p` in 1 ..= 9
    /// (one-sided where a neighbour is unobserved), reading the neighbours from the chunks:
    /// the reference for [`PaddedBlock::inner_gradient`] after
    /// [`PaddedBlock::gather_shell`].
    #[cfg(test)]
    fn gradient(&self, nb: &[Option<&VoxelBlock>; 27], i: usize, p: [usize; 3]) -> Vec3 {
        let outer = |q: [usize; 3]| -> Option<f32> {
            let ((ox, ix), (oy, iy), (oz, iz)) = (SPLIT[q[0]], SPLIT[q[1]], SPLIT[q[2]]);
            let c = nb[ox as usize + 3 * oy as usize + 9 * oz as usize]?;
            let j = ix as usize + CHUNK_SIDE * (iy as usize + CHUNK_SIDE * iz as usize);
            (c.weight[j] >= self.min_weight).then_some(c.tsdf[j] as f32)
        };
        let t = self.tsdf[i] as f32;
        let mut g = [0.0f32; 3];
        for a in 0..3 {
            let (mut below, mut above) = (p, p);
            below[a] -= 1;
            above[a] += 1;
            g[a] = match (outer(below), outer(above)) {
                (Some(l), Some(h)) => 0.5 * (h - l),
                (None, Some(h)) => h - t,
                (Some(l), None) => t - l,
                (None, None) => 0.0,
            };
        }
        Vec3::from(g)
    }

    /// Central-difference TSDF gradient at padded index `i` (coordinates 1 ..= 9, after
    /// [`PaddedBlock::gather_shell`]), one-sided where a neighbour is unobserved, in raw
    /// distance units per voxel.
    #[inline(always)]
    fn inner_gradient(&self, i: usize) -> Vec3 {
        let t = (self.packed[i] >> 16) as f32;
        let axis = |s: usize| {
            let (lo, hi) = (self.packed[i - s], self.packed[i + s]);
            let (l, h) = ((lo >> 16) as f32, (hi >> 16) as f32);
            match (lo & OBSERVED as i32 != 0, hi & OBSERVED as i32 != 0) {
                (true, true) => 0.5 * (h - l),
                (false, true) => h - t,
                (true, false) => t - l,
                (false, false) => 0.0,
            }
        };
        Vec3::new(axis(1), axis(PAD), axis(PAD2))
    }

    /// Distance at padded index `i` in truncation units.
    #[inline]
    fn tsdf(&self, i: usize) -> f32 {
        self.tsdf[i] as f32 * (1.0 / TSDF_SCALE)
    }
}

/// Buffers one worker reuses from chunk to chunk (allocating and clearing 20 KB per chunk
/// cost as much as the marching itself).
struct Scratch {
    block: Box<PaddedBlock>,
    /// Padded weights (only their reaching the threshold matters) and per padded row the masks of
    /// negative and observed voxels, from [`PaddedBlock::gather`].
    weight: Box<[u16; PAD * PAD2]>,
    masks: Box<[(u16, u16); PAD2]>,
    /// The mesh being built (copied out at its exact size when the chunk is done).
    mesh: ChunkMesh,
    /// Cell edge -> vertex of the chunk being meshed.
    edges: EdgeSlots,
    /// Crossed cells of the current chunk: local cell index and case (after the triangle
    /// pass, the cells that made triangles).
    cells: Vec<(u16, u8)>,
    /// The vertices to make, one [`VertexJob`] each, in vertex order (padded to whole
    /// batches).
    jobs: Vec<u32>,
    /// Where vertex batches are made.
    kernel: VertexKernel,
    lanes: VertexLanes,
}

impl Scratch {
    fn new() -> Self {
        Self {
            block: PaddedBlock::new(),
            weight: Box::new([0; PAD * PAD2]),
            masks: Box::new([(0, 0); PAD2]),
            mesh: ChunkMesh::default(),
            edges: EdgeSlots::new(),
            cells: Vec::new(),
            jobs: Vec::new(),
            kernel: VertexKernel::detect(),
            lanes: VertexLanes::default(),
        }
    }
}

/// Options of surface extraction (the map's own parameters are in [`crate::TsdfConfig`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshConfig {
    /// Smallest fusion weight ([`crate::Voxel::weight`]) of a voxel that meshing counts as
    /// observed; lighter voxels are treated as unobserved: no cell with such a corner makes
    /// triangles, and gradients do not read them. One observation at depth `d` weighs
    /// `min(1 / d^2, 4)` ([`crate::depth_weight`]), so 0.25 asks for one observation at 2 m,
    /// or four at 4 m: a voxel seen once or twice from far away, or only grazed at a depth
    /// edge, holds a distance centimetres off (the Kinect noise at 3-4 m is 1-3 cm), and is
    /// better left as a hole until more observations come. 0 meshes every observed voxel
    /// (0 to 255).
    pub min_weight: f32,
    /// Connected pieces of the assembled mesh (triangles joined through shared vertices,
    /// across chunks) with fewer triangles than this are dropped, with their vertices: specks
    /// of noise floating in free space, a few voxels across. Only the assembled mesh
    /// ([`IncrementalMesher::mesh`], [`extract_mesh_with`]) is filtered; chunk meshes
    /// ([`IncrementalMesher::chunk_mesh`], [`mesh_chunk_with`]) keep them, since whether a
    /// piece is small depends on its neighbours. 0 keeps everything.
    pub min_component_triangles: usize,
}

impl MeshConfig {
    /// Every observed voxel counts (what [`extract_mesh`] and [`IncrementalMesher::new`] do).
    pub const ALL_OBSERVED: Self = Self { min_weight: 0.0, min_component_triangles: 0 };
    /// What the live pipeline uses: a weight of 0.25 (one observation at 2 m, four at 4 m)
    /// and pieces of at least 50 triangles. On rendered 300-frame scans with Kinect-like
    /// noise and true poses (docs/benchmarks_log.md, "Mesh accuracy, session 6") it cuts the
    /// mean distance of the vertices to the true surface by 12-19 % (1.59 -> 1.37 mm on
    /// `synth:1`: the tail of specks, far rarely seen surface and grazed depth edges) for
    /// under a point of the seen surface within 1 cm (95.2 -> 94.7 %).
    pub const RECOMMENDED: Self = Self { min_weight: 0.25, min_component_triangles: 50 };

    /// Checks the documented range.
    pub fn validate(&self) -> crate::Result<()> {
        if !(self.min_weight.is_finite() && (0.0..=255.0).contains(&self.min_weight)) {
            return Err(crate::ReconError::InvalidConfig(format!(
                "minimum meshing weight {} is outside 0..255",
                self.min_weight
            )));
        }
        Ok(())
    }

    /// The threshold in stored weight units ([`crate::Chunk::stored_weights`]): at least 1,
    /// so that 0 means "observed at all". A stored weight `w` passes exactly when
    /// `w / WEIGHT_SCALE >= min_weight`.
    pub fn stored_min_weight(&self) -> u16 {
        (self.min_weight * WEIGHT_SCALE).ceil().clamp(1.0, u16::MAX as f32) as u16
    }
}

impl Default for MeshConfig {
    /// [`MeshConfig::ALL_OBSERVED`].
    fn default() -> Self {
        Self::ALL_OBSERVED
    }
}

/// Marching cubes over the cells owned by chunk `key` (empty when it is not allocated).
pub fn mesh_chunk(map: &TsdfMap, key: ChunkKey) -> ChunkMesh {
    mesh_chunk_configured(map, key, MeshConfig::ALL_OBSERVED.stored_min_weight(), &mut Scratch::new())
}

/// [`mesh_chunk`] counting only voxels of at least `config.min_weight` as observed.
///
/// # Errors
/// [`crate::ReconError::InvalidConfig`] when the config is out of range.
pub fn mesh_chunk_with(map: &TsdfMap, key: ChunkKey, config: MeshConfig) -> crate::Result<ChunkMesh> {
    config.validate()?;
    Ok(mesh_chunk_configured(map, key, config.stored_min_weight(), &mut Scratch::new()))
}

fn mesh_chunk_configured(map: &TsdfMap, key: ChunkKey, min_weight: u16, scratch: &mut Scratch) -> ChunkMesh {
    if build(map, key, min_weight, scratch) {
        // `clone` allocates each vector at its length.
        scratch.mesh.clone()
    } else {
        ChunkMesh::default()
    }
}

/// Re-meshes chunk `key` into the live mesh's `dst`, packed, reusing its buffer: in steady
/// state a re-mesh allocates and frees nothing (a fifth of the incremental update once went
/// to the allocator). Where `dst`'s buffer must grow or shrink, the packed mesh is returned
/// instead, at its exact size, for a buffer made on the calling thread
/// ([`PackedChunkMesh::sized_for`]).
fn remesh_into(
    map: &TsdfMap,
    key: ChunkKey,
    min_weight: u16,
    scratch: &mut Scratch,
    dst: &mut PackedChunkMesh,
) -> Option<PackedChunkMesh> {
    if !build(map, key, min_weight, scratch) {
        dst.release();
        return None;
    }
    let needed = PackedChunkMesh::needed(scratch.cells.len(), scratch.mesh.positions.len());
    if dst.fits(needed) {
        dst.pack(scratch);
        return None;
    }
    let mut fresh = PackedChunkMesh::exact(needed);
    fresh.pack(scratch);
    Some(fresh)
}

/// Marching cubes over chunk `key` into `scratch.mesh`, voxels of stored weight at least
/// `min_weight` (at least 1) counting as observed; false (and the mesh left stale) when the
/// chunk has no triangles.
fn build(map: &TsdfMap, key: ChunkKey, min_weight: u16, scratch: &mut Scratch) -> bool {
    // The chunks' sign summaries count every voxel of non-zero weight: a superset of the
    // voxels observed here, so the early exit stays valid for any threshold.
    let Some(nb) = neighbours_if_surface(map, key) else { return false };
    scratch.block.gather(&nb, min_weight, &mut scratch.weight, &mut scratch.masks);
    let triangle_count = classify(&scratch.masks, &mut scratch.cells);
    if scratch.cells.is_empty() {
        return false;
    }
    scratch.block.gather_shell(&nb, &scratch.weight);
    // Built in the worker's buffers and copied out at their exact size: growing five vectors
    // per chunk (and freeing the cached mesh it replaces) cost a sixth of meshing in the
    // allocator, and exact sizes keep the cache compact.
    let mut mesh = std::mem::take(&mut scratch.mesh);
    mesh.clear();
    let config = map.config();
    let max_jump = max_edge_jump(config);
    let key_voxel = key * CHUNK_SIDE as i32;
    triangles(
        &scratch.block,
        &mut scratch.cells,
        triangle_count,
        max_jump,
        &mut scratch.edges,
        &mut scratch.jobs,
        &mut mesh,
        scratch.kernel,
    );
    make_vertices(
        &scratch.block,
        &mut scratch.jobs,
        key_voxel,
        config.voxel_size,
        scratch.kernel,
        &mut scratch.lanes,
        &mut mesh,
    );
    scratch.mesh = mesh;
    true
}

/// Meshes the whole map from scratch (parallel over chunks), every observed voxel counting.
pub fn extract_mesh(map: &TsdfMap) -> LabeledMesh {
    extract_mesh_configured(map, MeshConfig::ALL_OBSERVED.stored_min_weight(), 0)
}

/// [`extract_mesh`] with options (see [`MeshConfig`]).
///
/// # Errors
/// [`crate::ReconError::InvalidConfig`] when the config is out of range.
pub fn extract_mesh_with(map: &TsdfMap, config: MeshConfig) -> crate::Result<LabeledMesh> {
    config.validate()?;
    Ok(extract_mesh_configured(map, config.stored_min_weight(), config.min_component_triangles))
}

fn extract_mesh_configured(map: &TsdfMap, min_weight: u16, min_component_triangles: usize) -> LabeledMesh {
    let keys = map.sorted_keys();
    let meshes: Vec<ChunkMesh> =
        keys.par_iter().map_init(Scratch::new, |s, &k| mesh_chunk_configured(map, k, min_weight, s)).collect();
    assemble(&keys.iter().copied().zip(&meshes).collect::<Vec<_>>(), min_component_triangles)
}

#[cfg(test)]
mod tests;
