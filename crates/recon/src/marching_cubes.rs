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

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;
mod reader_marks;
use crate::map::{
    key_order, Chunk, ChunkHashBuilder, ChunkKey, TsdfMap, CHUNK_SIDE, CHUNK_VOXELS, TSDF_SCALE, WEIGHT_SCALE,
};
use reader_marks::{ALL_READERS, CELL_READERS};

/// Largest TSDF difference across a cell edge that still counts as a surface crossing, in
/// units of the narrowest truncation band: a real surface changes the TSDF by about one
/// voxel per voxel, the seam between free space and the back of a surface by two bands or
/// more (with the band depending on depth, the narrowest band bounds that seam from below).
/// 1.5 bands, not less: far away (3-4 m) the averaged Kinect noise makes real crossings
/// jump by several voxels, and a tighter limit (one narrowest band, 4 voxels) punched holes
/// into the demo's far floor and walls. Never more than one whole truncation distance, the
/// limit of the fixed band.
const MAX_EDGE_JUMP_BANDS: f32 = 1.5;

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
    /// Unit vertex normals toward free space (zero where the gradient vanishes).
    pub normals: Vec<Vec3>,
    /// Triangles, counter-clockwise seen from free space.
    pub triangles: Vec<[u32; 3]>,
    /// Vertices on cell edges that neighbouring chunks also use, with the edge's global key
    /// (ascending vertex order); the assembly welds them.
    shared: Vec<(u32, EdgeKey)>,
}

impl ChunkMesh {
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
fn voxel_color(nb: &[Option<&Chunk>; 27], p: [usize; 3]) -> [u8; 4] {
    let ((ox, ix), (oy, iy), (oz, iz)) = (SPLIT[p[0]], SPLIT[p[1]], SPLIT[p[2]]);
    match nb[ox as usize + 3 * oy as usize + 9 * oz as usize] {
        Some(c) => c.voxels.color[ix as usize + CHUNK_SIDE * (iy as usize + CHUNK_SIDE * iz as usize)],
        None => [0; 4],
    }
}

/// Colour of a vertex at fraction `s` (0 ..= 1) of the way from a voxel of colour `ca` to
/// one of colour `cb` (`[r, g, b, count]`), interpolated only between voxels that have a
/// colour (count not 0).
///
/// Four lanes at once with the operations, and their order, of the per-channel
/// `(a + s (b - a) + 0.5) as u8` (the sum lies in 0 ..= 255.5, so truncating to `i32`
/// then `u8` is that cast), which took twice the instructions.
#[inline]
fn edge_color(ca: [u8; 4], cb: [u8; 4], s: f32) -> [u8; 3] {
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

/// The chunk and its 26 neighbours at `(dx + 1) + 3 (dy + 1) + 9 (dz + 1)`, or None when
/// the chunk's cells cannot hold a surface ([`PaddedBlock::may_have_surface`]). The chunk and
/// its 7 upper neighbours are looked up first: most chunks stop there.
fn neighbours_if_surface(map: &TsdfMap, key: ChunkKey) -> Option<[Option<&Chunk>; 27]> {
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
    Some(nb)
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
        nb: &[Option<&Chunk>; 27],
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
                        t_row.copy_from_slice(&c.voxels.tsdf[src..src + N]);
                        w_row.copy_from_slice(&c.voxels.weight[src..src + N]);
                    }
                    None => w_row.fill(0),
                }
                // Padded x 9: local x 0 of the upper neighbour.
                match nb[nb_row + 2] {
                    Some(c) => {
                        b.tsdf[dst + 1 + N] = c.voxels.tsdf[src];
                        weight[dst + 1 + N] = c.voxels.weight[src];
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
    fn gather_shell(&mut self, nb: &[Option<&Chunk>; 27], weight: &[u16; PAD * PAD2]) {
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
        let one = |c: Option<&Chunk>, j: usize| match c {
            Some(c) => packed_voxel(c.voxels.tsdf[j], c.voxels.weight[j], min_weight),
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
                self.color[dst + PAD - 2] = nb[nb_row + 2].map_or([0; 4], |c| c.voxels.color[src]);
                let row = &mut self.color[dst + 1..dst + 1 + N];
                match nb[nb_row + 1] {
                    Some(c) => row.copy_from_slice(&c.voxels.color[src..src + N]),
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
                            let t = &c.voxels.tsdf.as_chunks::<N>().0[row / N];
                            let w = &c.voxels.weight.as_chunks::<N>().0[row / N];
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
    fn gradient(&self, nb: &[Option<&Chunk>; 27], i: usize, p: [usize; 3]) -> Vec3 {
        let outer = |q: [usize; 3]| -> Option<f32> {
            let ((ox, ix), (oy, iy), (oz, iz)) = (SPLIT[q[0]], SPLIT[q[1]], SPLIT[q[2]]);
            let c = nb[ox as usize + 3 * oy as usize + 9 * oz as usize]?;
            let j = ix as usize + CHUNK_SIDE * (iy as usize + CHUNK_SIDE * iz as usize);
            (c.voxels.weight[j] >= self.min_weight).then_some(c.voxels.tsdf[j] as f32)
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
    /// Crossed cells of the current chunk: local cell index and case.
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

/// Vertices made at once.
const LANES: usize = 16;

/// One vertex to make, packed into a `u32`: bits 0..11 the padded index of the edge's lower
/// end, 11..13 the edge's axis, then 4 bits per axis of the lower end's local coordinates
/// (0 ..= 8).
struct VertexJob;

impl VertexJob {
    #[inline]
    fn pack(lower: usize, axis: usize, low: [usize; 3]) -> u32 {
        (lower | axis << 11 | low[0] << 13 | low[1] << 17 | low[2] << 21) as u32
    }

    /// (padded index of the lower end, axis, local coordinates of the lower end).
    #[inline]
    fn unpack(job: u32) -> (usize, usize, [i32; 3]) {
        let j = job as usize;
        (j & 0x7ff, (j >> 11) & 3, [(j >> 13) as i32 & 15, (j >> 17) as i32 & 15, (j >> 21) as i32 & 15])
    }
}

/// Padded index step per axis.
const STRIDES: [usize; 3] = [1, PAD, PAD2];

/// A batch of made vertices, lane `k` for job `k`: positions and normals by axis, colours
/// as `r | g << 8 | b << 16`.
#[derive(Debug, Default, Clone, PartialEq)]
struct VertexLanes {
    position: [[f32; LANES]; 3],
    normal: [[f32; LANES]; 3],
    color: [u32; LANES],
}

/// Which code makes vertex batches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum VertexKernel {
    /// [`vertices_scalar`], the definition.
    Scalar,
    /// AVX2 intrinsics, eight lanes twice, chosen at run time without AVX-512F; the same bits.
    #[cfg(target_arch = "x86_64")]
    Avx2,
    /// AVX-512F intrinsics, chosen at run time; the same bits.
    #[cfg(target_arch = "x86_64")]
    Avx512,
}

impl VertexKernel {
    /// The widest kernel the CPU has, unless `SEMRECON_MESH_SIMD=avx2|scalar` asks for a
    /// narrower one (all give the same bits).
    fn detect() -> Self {
        static KERNEL: std::sync::OnceLock<VertexKernel> = std::sync::OnceLock::new();
        *KERNEL.get_or_init(|| {
            #[cfg(target_arch = "x86_64")]
            {
                let forced = std::env::var("SEMRECON_MESH_SIMD").unwrap_or_default();
                if forced != "scalar" && forced != "avx2" && is_x86_feature_detected!("avx512f") {
                    return VertexKernel::Avx512;
                }
                if forced != "scalar" && is_x86_feature_detected!("avx2") {
                    return VertexKernel::Avx2;
                }
            }
            VertexKernel::Scalar
        })
    }
}

/// The vertex of one [`VertexJob`] in chunk `key_voxel` (its lowest voxel) with voxels of
/// `voxel_size` metres: position on the crossed edge (linear in the distances), colour
/// interpolated from the ends' ([`edge_color`]), unit normal the interpolated gradient
/// ([`PaddedBlock::inner_gradient`]; zero where it vanishes).
#[inline]
fn vertex(block: &PaddedBlock, job: u32, key_voxel: IVec3, voxel_size: f32) -> (Vec3, [u8; 3], Vec3) {
    let (ia, axis, low) = VertexJob::unpack(job);
    let ib = ia + STRIDES[axis];
    let (fa, fb) = (block.tsdf(ia), block.tsdf(ib));
    let s = fa / (fa - fb);
    let mut p = (key_voxel + IVec3::from(low)).as_vec3();
    p[axis] += s;
    let color = edge_color(block.color(ia), block.color(ib), s);
    let g = block.inner_gradient(ia).lerp(block.inner_gradient(ib), s);
    (p * voxel_size, color, g.normalize_or_zero())
}

/// [`vertex`] for each of a batch of jobs.
fn vertices_scalar(block: &PaddedBlock, jobs: &[u32; LANES], key_voxel: IVec3, voxel_size: f32, out: &mut VertexLanes) {
    for (k, &job) in jobs.iter().enumerate() {
        let (p, c, n) = vertex(block, job, key_voxel, voxel_size);
        for a in 0..3 {
            out.position[a][k] = p[a];
            out.normal[a][k] = n[a];
        }
        out.color[k] = u32::from_le_bytes([c[0], c[1], c[2], 0]);
    }
}

/// Makes the vertices of `jobs` (padded to whole batches by repeating the first) with
/// `kernel` and appends them to `mesh`.
#[inline(never)]
fn make_vertices(
    block: &PaddedBlock,
    jobs: &mut Vec<u32>,
    key_voxel: IVec3,
    voxel_size: f32,
    kernel: VertexKernel,
    lanes: &mut VertexLanes,
    mesh: &mut ChunkMesh,
) {
    let n = jobs.len();
    let Some(&first) = jobs.first() else { return };
    jobs.resize(n.div_ceil(LANES) * LANES, first);
    mesh.positions.reserve(n);
    mesh.normals.reserve(n);
    mesh.colors.reserve(n);
    let (batches, _) = jobs.as_chunks::<LANES>();
    for (b, batch) in batches.iter().enumerate() {
        match kernel {
            VertexKernel::Scalar => vertices_scalar(block, batch, key_voxel, voxel_size, lanes),
            // SAFETY: `VertexKernel::Avx2` and `Avx512` are only chosen where the CPU has AVX2,
            // AVX-512F, and every job comes from a crossed edge of the block's cells.
            #[cfg(target_arch = "x86_64")]
            VertexKernel::Avx2 => unsafe { avx2::vertices(block, batch, key_voxel, voxel_size, lanes) },
            #[cfg(target_arch = "x86_64")]
            VertexKernel::Avx512 => unsafe { avx512::vertices(block, batch, key_voxel, voxel_size, lanes) },
        }
        // Interleaved on the stack and appended at once: three pushes a vertex, with their
        // capacity checks, cost more than making the vertex.
        let [px, py, pz] = &lanes.position;
        let [nx, ny, nz] = &lanes.normal;
        let positions: [Vec3; LANES] = std::array::from_fn(|k| Vec3::new(px[k], py[k], pz[k]));
        let normals: [Vec3; LANES] = std::array::from_fn(|k| Vec3::new(nx[k], ny[k], nz[k]));
        let colors: [[u8; 3]; LANES] = std::array::from_fn(|k| {
            let c = lanes.color[k].to_le_bytes();
            [c[0], c[1], c[2]]
        });
        let count = (n - b * LANES).min(LANES);
        mesh.positions.extend_from_slice(&positions[..count]);
        mesh.normals.extend_from_slice(&normals[..count]);
        mesh.colors.extend_from_slice(&colors[..count]);
    }
    jobs.truncate(n);
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
    /// noise and true poses (docs/benchmarks.md, "Mesh accuracy, session 6") it cuts the
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

    /// The threshold in stored weight units: at least 1, so that 0 means "observed at all".
    /// A stored weight `w` passes exactly when `w / WEIGHT_SCALE >= min_weight`.
    fn stored_min_weight(&self) -> u16 {
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

/// Re-meshes chunk `key` into `dst`, reusing its buffers: in steady state a re-mesh
/// allocates and frees nothing (a fifth of the incremental update went to the allocator).
fn remesh_into(map: &TsdfMap, key: ChunkKey, min_weight: u16, scratch: &mut Scratch, dst: &mut ChunkMesh) {
    if !build(map, key, min_weight, scratch) {
        *dst = ChunkMesh::default();
        return;
    }
    let src = &scratch.mesh;
    fn copy<T: Copy>(dst: &mut Vec<T>, src: &[T]) {
        dst.clear();
        // Slack beyond twice the length would let the cache grow with the surface's history.
        if dst.capacity() > 2 * src.len() + 8 {
            dst.shrink_to(src.len());
        }
        dst.extend_from_slice(src);
    }
    copy(&mut dst.positions, &src.positions);
    copy(&mut dst.colors, &src.colors);
    copy(&mut dst.normals, &src.normals);
    copy(&mut dst.triangles, &src.triangles);
    copy(&mut dst.shared, &src.shared);
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
    let max_jump = (MAX_EDGE_JUMP_BANDS * config.narrowest_band_voxels() / config.truncation_voxels).min(1.0);
    let key_voxel = key * CHUNK_SIDE as i32;
    triangles(
        &scratch.block,
        &scratch.cells,
        triangle_count,
        max_jump,
        key_voxel,
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

/// Padded offset of cell corner `c` from the cell's lowest corner.
const CORNER_OFFSET: [usize; 8] = {
    let mut t = [0usize; 8];
    let mut c = 0;
    while c < 8 {
        t[c] = (c & 1) + PAD * ((c >> 1) & 1) + PAD2 * ((c >> 2) & 1);
        c += 1;
    }
    t
};

/// Pass 1: the cells the surface crosses (every corner observed, both signs), with their
/// cases, into `cells` in cell order; returns how many triangles they make at most, so that
/// the mesh buffers are allocated once.
#[inline(never)]
fn classify(masks: &[(u16, u16); PAD2], cells: &mut Vec<(u16, u8)>) -> usize {
    let table = case_table();
    cells.clear();
    let mut triangle_count = 0;
    // Per padded row, bit x: cell x's two corners along x are both observed, one is negative,
    // both are negative; a row of cells combines four padded rows (each used by up to four).
    // Separate arrays of the three (all rows at once; rows outside 1 ..= 9 are never read),
    // so that both loops run eight rows per instruction.
    let (mut both_obs, mut one_neg, mut both_neg) = ([0u16; PAD2], [0u16; PAD2], [0u16; PAD2]);
    for r in 0..PAD2 {
        let (neg, obs) = masks[r];
        both_obs[r] = (obs >> 1) & (obs >> 2);
        one_neg[r] = (neg >> 1) | (neg >> 2);
        both_neg[r] = (neg >> 1) & (neg >> 2);
    }
    let eight = |a: &[u16; PAD2], r: usize| -> [u16; 8] { a[r..r + 8].try_into().unwrap_or([0; 8]) };
    for z in 0..CHUNK_SIDE {
        // Rows y = 0 .. 8 of this slab of cells.
        let r0 = 1 + PAD * (z + 1);
        let mut crossed_rows = [0u16; CHUNK_SIDE];
        let [o0, o1, o2, o3] = [0, 1, PAD, PAD + 1].map(|o| eight(&both_obs, r0 + o));
        let [a0, a1, a2, a3] = [0, 1, PAD, PAD + 1].map(|o| eight(&one_neg, r0 + o));
        let [n0, n1, n2, n3] = [0, 1, PAD, PAD + 1].map(|o| eight(&both_neg, r0 + o));
        for y in 0..CHUNK_SIDE {
            let all_obs = o0[y] & o1[y] & o2[y] & o3[y] & 0xff;
            let any_neg = a0[y] | a1[y] | a2[y] | a3[y];
            let all_neg = n0[y] & n1[y] & n2[y] & n3[y];
            crossed_rows[y] = all_obs & any_neg & !all_neg;
        }
        for (y, &crossed) in crossed_rows.iter().enumerate() {
            let r = r0 + y;
            let mut crossed = crossed;
            // Every corner of a crossed cell is observed, so its negative bits are its case's
            // (corner bit 1: y + 1, the next row; bit 2: z + 1, the next slab).
            let neg = [masks[r].0, masks[r + 1].0, masks[r + PAD].0, masks[r + PAD + 1].0].map(u32::from);
            while crossed != 0 {
                let x = crossed.trailing_zeros() as usize;
                crossed &= crossed - 1;
                let case = ((neg[0] >> (x + 1)) & 3
                    | ((neg[1] >> (x + 1)) & 3) << 2
                    | ((neg[2] >> (x + 1)) & 3) << 4
                    | ((neg[3] >> (x + 1)) & 3) << 6) as u8;
                cells.push(((x + CHUNK_SIDE * (y + CHUNK_SIDE * z)) as u16, case));
                triangle_count += table.triangles(case).len();
            }
        }
    }
    triangle_count
}

/// Per-chunk cell-edge bookkeeping of [`triangles`].
struct EdgeSlots {
    /// Local cell-edge index -> `stamp << 12 | vertex` (vertices of a chunk are fewer than
    /// its 2187 cell edges, below 2^12): a slot holds a vertex of the current chunk only when
    /// its stamp is `stamp`, so nothing is cleared between chunks.
    vertex: Vec<u32>,
    stamp: u32,
}

impl EdgeSlots {
    fn new() -> Self {
        Self { vertex: vec![0; ES * ES * ES * 3], stamp: 0 }
    }

    /// Forgets every vertex (a new stamp; the slots are cleared when stamps run out).
    fn next_chunk(&mut self) {
        self.stamp += 1;
        if self.stamp == 1 << 20 {
            self.vertex.fill(0);
            self.stamp = 1;
        }
    }
}

/// Per case, its crossed edges in the order its triangles first use them (and how many):
/// the order in which a cell of that case numbers its new vertices.
fn first_uses() -> &'static [([u8; 12], u8); 256] {
    static ORDER: std::sync::OnceLock<[([u8; 12], u8); 256]> = std::sync::OnceLock::new();
    ORDER.get_or_init(|| {
        std::array::from_fn(|case| {
            let mut order = ([0u8; 12], 0u8);
            for &e in case_table().triangles(case as u8).iter().flatten() {
                if !order.0[..order.1 as usize].contains(&e) {
                    order.0[order.1 as usize] = e;
                    order.1 += 1;
                }
            }
            order
        })
    })
}

/// Per edge, its [`VertexJob`] relative to its cell's (`VertexJob::pack(base, 0, [x, y, z])`:
/// the fields add without carries).
const EDGE_JOB: [u32; 12] = {
    let mut t = [0u32; 12];
    let mut e = 0;
    while e < 12 {
        let a = EDGES[e].0 as usize;
        let low = [a & 1, (a >> 1) & 1, (a >> 2) & 1];
        t[e] = (CORNER_OFFSET[a] | (e / 4) << 11 | low[0] << 13 | low[1] << 17 | low[2] << 21) as u32;
        e += 1;
    }
    t
};

/// Per cell position class (per axis 0: first cell, 1: inner, 2: last; `x + 3 y + 9 z`), the
/// edges whose vertex neighbouring chunks share: a coordinate across the edge's axis on the
/// chunk boundary (0 or `CHUNK_SIDE`).
const SHARED_EDGES: [u16; 27] = {
    let mut t = [0u16; 27];
    let mut class = 0;
    while class < 27 {
        let c = [class % 3, class / 3 % 3, class / 9];
        let mut e = 0;
        while e < 12 {
            let a = EDGES[e].0 as usize;
            let mut q = 0;
            while q < 3 {
                let bit = (a >> q) & 1;
                if q != e / 4 && ((c[q] == 0 && bit == 0) || (c[q] == 2 && bit == 1)) {
                    t[class] |= 1 << e;
                }
                q += 1;
            }
            e += 1;
        }
        class += 1;
    }
    t
};

/// Pass 2: the triangles of the crossed cells without a seam edge (an edge jumping by more
/// than `max_jump` truncation units), numbering each cell edge's vertex when first used and
/// recording its [`VertexJob`] (vertices are made afterwards, in batches) and, for edges
/// neighbouring chunks share, its global key. `triangle_count`: how many triangles `cells`
/// make before the seam test ([`classify`]).
///
/// The seam test runs with AVX2 where the CPU has it and `kernel` is not the scalar one
/// ([`seam_avx2`]), else edge by edge ([`seam_scalar`]): the same decisions.
#[inline(never)]
#[allow(clippy::too_many_arguments)]
fn triangles(
    block: &PaddedBlock,
    cells: &[(u16, u8)],
    triangle_count: usize,
    max_jump: f32,
    key_voxel: IVec3,
    edges: &mut EdgeSlots,
    jobs: &mut Vec<u32>,
    mesh: &mut ChunkMesh,
    kernel: VertexKernel,
) {
    #[cfg(target_arch = "x86_64")]
    if kernel != VertexKernel::Scalar && is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2.
        unsafe { triangles_avx2(block, cells, triangle_count, max_jump, key_voxel, edges, jobs, mesh) };
        return;
    }
    let _ = kernel;
    triangles_with(cells, triangle_count, key_voxel, edges, jobs, mesh, |base, case| {
        seam_scalar(block, base, case, max_jump)
    });
}

/// [`triangles`] compiled for AVX2, with [`seam_avx2`] inlined.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
unsafe fn triangles_avx2(
    block: &PaddedBlock,
    cells: &[(u16, u8)],
    triangle_count: usize,
    max_jump: f32,
    key_voxel: IVec3,
    edges: &mut EdgeSlots,
    jobs: &mut Vec<u32>,
    mesh: &mut ChunkMesh,
) {
    triangles_with(cells, triangle_count, key_voxel, edges, jobs, mesh, |base, case| {
        seam_avx2(&block.tsdf, base, case, max_jump)
    });
}

/// Whether a crossed edge of the cell with lowest corner at padded index `base` and case
/// `case` jumps by more than `max_jump` truncation units: edge by edge, the definition.
#[inline(always)]
fn seam_scalar(block: &PaddedBlock, base: usize, case: u8, max_jump: f32) -> bool {
    const ENDS: [(u8, u8); 16] = {
        let mut out = [(0, 0); 16];
        let mut e = 0;
        while e < 12 {
            out[e] = EDGES[e];
            e += 1;
        }
        out
    };
    let f: [f32; 8] = std::array::from_fn(|c| block.tsdf(base + CORNER_OFFSET[c]));
    let (used, n_used) = &first_uses()[case as usize];
    // Only crossed edges can be seams (all corners are observed here, so the case bits
    // are the signs), and the crossed edges are the used ones.
    let mut jump = false;
    for &e in &used[..*n_used as usize] {
        let (a, b) = ENDS[e as usize & 15];
        jump |= (f[a as usize & 7] - f[b as usize & 7]).abs() > max_jump;
    }
    jump
}

/// [`seam_scalar`] with AVX2: the eight corners converted at once, all twelve edges'
/// differences in two permutes, subtractions and compares, masked with the case's crossed
/// edges (the used ones: tested). The same arithmetic, so the same decisions.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
fn seam_avx2(tsdf: &[i16; PAD * PAD2], base: usize, case: u8, max_jump: f32) -> bool {
    use std::arch::x86_64::*;
    /// Per edge (lane), its first (`.0`) or second end; lanes 12 ..= 15 compare corner 0
    /// with itself.
    const fn ends(second: bool) -> [i32; 16] {
        let mut out = [0; 16];
        let mut e = 0;
        while e < 12 {
            out[e] = if second { EDGES[e].1 } else { EDGES[e].0 } as i32;
            e += 1;
        }
        out
    }
    const FIRST: [i32; 16] = ends(false);
    const SECOND: [i32; 16] = ends(true);
    // Corners 2k and 2k + 1 are neighbours along x: one 32-bit lane each.
    let pair = |o: usize| (tsdf[base + o] as u16 as u32 | (tsdf[base + o + 1] as u16 as u32) << 16) as i32;
    let corners = _mm_set_epi32(pair(PAD + PAD2), pair(PAD2), pair(PAD), pair(0));
    let f = _mm256_mul_ps(_mm256_cvtepi32_ps(_mm256_cvtepi16_epi32(corners)), _mm256_set1_ps(1.0 / TSDF_SCALE));
    let limit = _mm256_set1_ps(max_jump);
    let mut jumps = 0;
    for half in 0..2 {
        // SAFETY: reads lanes 8 half .. 8 half + 8 of the 16-lane tables.
        let (a, b) = unsafe {
            (
                _mm256_loadu_si256(FIRST.as_ptr().add(8 * half).cast()),
                _mm256_loadu_si256(SECOND.as_ptr().add(8 * half).cast()),
            )
        };
        let d = _mm256_sub_ps(_mm256_permutevar8x32_ps(f, a), _mm256_permutevar8x32_ps(f, b));
        let d = _mm256_andnot_ps(_mm256_set1_ps(-0.0), d);
        jumps |= (_mm256_movemask_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(d, limit)) as u16) << (8 * half);
    }
    jumps & CROSSED[case as usize] != 0
}

/// The body of [`triangles`] with the seam test `seam(base, case)` (true: skip the cell).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn triangles_with(
    cells: &[(u16, u8)],
    triangle_count: usize,
    key_voxel: IVec3,
    edges: &mut EdgeSlots,
    jobs: &mut Vec<u32>,
    mesh: &mut ChunkMesh,
    seam: impl Fn(usize, u8) -> bool,
) {
    let table = case_table();
    let order = first_uses();
    edges.next_chunk();
    let stamp = edges.stamp << 12;
    let edge_vertex = &mut edges.vertex[..ES * ES * ES * 3];
    jobs.clear();
    // Written in place into the reserved length (`triangle_count` counts seam cells too) and
    // cut to size at the end: a push per triangle cost a fifth of this pass.
    let mut written = mesh.triangles.len();
    mesh.triangles.resize(written + triangle_count, [0; 3]);
    // The per-edge tables padded to 16 and indexed with `e & 15` (`f` with `& 7`): edge
    // numbers come from tables, so the bounds checks were not elided.
    const fn pad<T: Copy>(t: [T; 12], fill: T) -> [T; 16] {
        let mut out = [fill; 16];
        let mut e = 0;
        while e < 12 {
            out[e] = t[e];
            e += 1;
        }
        out
    }
    const KEY: [usize; 16] = pad(EDGE_KEY, 0);
    const JOB: [u32; 16] = pad(EDGE_JOB, 0);
    for &(cell, case) in cells {
        let cell = cell as usize;
        let base = CELL_BASE[cell] as usize;
        if seam(base, case) {
            continue;
        }
        let (used, n_used) = &order[case as usize];
        let used = &used[..*n_used as usize];
        let (x, y, z) = (cell % CHUNK_SIDE, (cell / CHUNK_SIDE) % CHUNK_SIDE, cell / (CHUNK_SIDE * CHUNK_SIDE));
        let cell_key = ((z * ES + y) * ES + x) * 3;
        let cell_job = VertexJob::pack(base, 0, [x, y, z]);
        let shared = SHARED_EDGES[CELL_CLASS[cell] as usize];
        let mut local = [0u32; 16];
        for &e in used {
            let e = e as usize & 15;
            let slot = &mut edge_vertex[cell_key + KEY[e]];
            if *slot & !0xfff != stamp {
                let v = jobs.len() as u32;
                *slot = stamp | v;
                let job = cell_job + JOB[e];
                jobs.push(job);
                if shared >> e & 1 != 0 {
                    let (_, axis, low) = VertexJob::unpack(job);
                    mesh.shared.push((v, (key_voxel + IVec3::from(low), axis as u8)));
                }
            }
            local[e] = *slot & 0xfff;
        }
        let tris = table.triangles(case);
        for (dst, tri) in mesh.triangles[written..written + tris.len()].iter_mut().zip(tris) {
            *dst = tri.map(|e| local[e as usize & 15]);
        }
        written += tris.len();
    }
    mesh.triangles.truncate(written);
}

/// Per cell (`x + 8 y + 64 z`), the padded index of its lowest corner.
const CELL_BASE: [u16; CHUNK_VOXELS] = {
    let mut t = [0u16; CHUNK_VOXELS];
    let mut c = 0;
    while c < CHUNK_VOXELS {
        let (x, y, z) = (c % CHUNK_SIDE, c / CHUNK_SIDE % CHUNK_SIDE, c / (CHUNK_SIDE * CHUNK_SIDE));
        t[c] = ((x + 1) + PAD * (y + 1) + PAD2 * (z + 1)) as u16;
        c += 1;
    }
    t
};

/// Per cell, its position class for [`SHARED_EDGES`].
const CELL_CLASS: [u8; CHUNK_VOXELS] = {
    let mut t = [0u8; CHUNK_VOXELS];
    let mut c = 0;
    while c < CHUNK_VOXELS {
        let p = [c % CHUNK_SIDE, c / CHUNK_SIDE % CHUNK_SIDE, c / (CHUNK_SIDE * CHUNK_SIDE)];
        let mut class = 0;
        let mut q = 2;
        loop {
            class = 3 * class + (p[q] != 0) as usize + (p[q] == CHUNK_SIDE - 1) as usize;
            if q == 0 {
                break;
            }
            q -= 1;
        }
        t[c] = class as u8;
        c += 1;
    }
    t
};

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
fn pack_bytes(bytes: &[u8; 64]) -> u64 {
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
fn readers(changed: &[u64; CHUNK_VOXELS / 64]) -> u32 {
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
    /// The chunk meshes, in the same positions as `entries`.
    meshes: Vec<ChunkMesh>,
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
            self.triangles -= self.meshes.swap_remove(i as usize).triangles.len();
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
                    self.meshes.push(ChunkMesh::default());
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
        let mut jobs: Vec<(ChunkKey, u32, ChunkMesh)> = order
            .iter()
            .map(|&(_, i)| {
                let mesh = std::mem::take(&mut self.meshes[i as usize]);
                self.triangles -= mesh.triangles.len();
                (self.entries[i as usize].key, i, mesh)
            })
            .collect();
        let remeshed = jobs.len();
        jobs.par_iter_mut()
            .for_each_init(Scratch::new, |s, (key, _, mesh)| remesh_into(map, *key, min_weight, s, mesh));
        for (_, i, mesh) in jobs {
            self.triangles += mesh.triangles.len();
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

    /// The cached mesh of chunk `key`.
    pub fn chunk_mesh(&self, key: ChunkKey) -> Option<&ChunkMesh> {
        self.index.get(&key).map(|&i| &self.meshes[i as usize])
    }

    /// The number of [`IncrementalMesher::update`] calls so far: a consumer that remembers it
    /// can ask [`IncrementalMesher::remeshed_since`] for what changed after.
    pub fn generation(&self) -> u64 {
        self.generation
    }

    /// The chunks re-meshed by the updates after `generation`, with their meshes (in cache
    /// order, which depends on the history of the map: sort the keys where order matters).
    /// Chunks freed since are simply absent from the cache ([`IncrementalMesher::chunk_mesh`]).
    pub fn remeshed_since(&self, generation: u64) -> impl Iterator<Item = (ChunkKey, &ChunkMesh)> + '_ {
        self.entries.iter().zip(&self.meshes).filter(move |(e, _)| e.meshed_at > generation).map(|(e, m)| (e.key, m))
    }

    /// Number of cached chunk meshes.
    pub fn chunk_count(&self) -> usize {
        self.entries.len()
    }

    /// The whole surface as one welded mesh (chunks in (z, y, x) key order; no labels).
    pub fn mesh(&self) -> LabeledMesh {
        let mut order: Vec<((i32, i32, i32), &ChunkMesh)> =
            self.entries.iter().zip(&self.meshes).map(|(e, m)| (key_order(e.key), m)).collect();
        order.sort_unstable_by_key(|(k, _)| *k);
        let meshes: Vec<&ChunkMesh> = order.into_iter().map(|(_, m)| m).collect();
        let mut mesh = assemble(&meshes);
        drop_small_components(&mut mesh, self.config.min_component_triangles);
        mesh
    }
}

/// Meshes the whole map from scratch (parallel over chunks), every observed voxel counting.
pub fn extract_mesh(map: &TsdfMap) -> LabeledMesh {
    extract_mesh_configured(map, MeshConfig::ALL_OBSERVED.stored_min_weight())
}

/// [`extract_mesh`] with options (see [`MeshConfig`]).
///
/// # Errors
/// [`crate::ReconError::InvalidConfig`] when the config is out of range.
pub fn extract_mesh_with(map: &TsdfMap, config: MeshConfig) -> crate::Result<LabeledMesh> {
    config.validate()?;
    let mut mesh = extract_mesh_configured(map, config.stored_min_weight());
    drop_small_components(&mut mesh, config.min_component_triangles);
    Ok(mesh)
}

fn extract_mesh_configured(map: &TsdfMap, min_weight: u16) -> LabeledMesh {
    let keys = map.sorted_keys();
    let meshes: Vec<ChunkMesh> =
        keys.par_iter().map_init(Scratch::new, |s, &k| mesh_chunk_configured(map, k, min_weight, s)).collect();
    assemble(&meshes.iter().collect::<Vec<_>>())
}

/// Drops the connected pieces of `mesh` (triangles joined through shared vertices) with
/// fewer than `min_triangles` triangles, and the vertices only they use; the rest keeps its
/// order. 0 or 1 changes nothing.
fn drop_small_components(mesh: &mut LabeledMesh, min_triangles: usize) {
    if min_triangles <= 1 || mesh.triangles.is_empty() {
        return;
    }
    // Union-find over vertices, with path halving.
    let mut parent: Vec<u32> = (0..mesh.positions.len() as u32).collect();
    fn root(parent: &mut [u32], mut i: u32) -> u32 {
        while parent[i as usize] != i {
            let grand = parent[parent[i as usize] as usize];
            parent[i as usize] = grand;
            i = grand;
        }
        i
    }
    for t in &mesh.triangles {
        let a = root(&mut parent, t[0]);
        for &v in &t[1..] {
            let b = root(&mut parent, v);
            if a != b {
                parent[b as usize] = a;
            }
        }
    }
    let roots: Vec<u32> = mesh.triangles.iter().map(|t| root(&mut parent, t[0])).collect();
    let mut size = vec![0u32; mesh.positions.len()];
    for &r in &roots {
        size[r as usize] = size[r as usize].saturating_add(1);
    }
    let keep = |r: u32| size[r as usize] as usize >= min_triangles;
    if roots.iter().all(|&r| keep(r)) {
        return;
    }
    let mut used = vec![false; mesh.positions.len()];
    for (t, &r) in mesh.triangles.iter().zip(&roots) {
        if keep(r) {
            for &v in t {
                used[v as usize] = true;
            }
        }
    }
    let mut remap = vec![u32::MAX; mesh.positions.len()];
    let mut next = 0u32;
    for (m, &u) in remap.iter_mut().zip(&used) {
        if u {
            *m = next;
            next += 1;
        }
    }
    fn retain<T: Copy>(v: &mut Vec<T>, used: &[bool]) {
        if v.len() == used.len() {
            let mut i = 0;
            v.retain(|_| {
                i += 1;
                used[i - 1]
            });
        }
    }
    retain(&mut mesh.positions, &used);
    retain(&mut mesh.colors, &used);
    retain(&mut mesh.normals, &used);
    retain(&mut mesh.vertex_labels, &used);
    let kept: Vec<bool> = roots.iter().map(|&r| keep(r)).collect();
    retain(&mut mesh.triangle_labels, &kept);
    let mut i = 0;
    mesh.triangles.retain(|_| {
        i += 1;
        kept[i - 1]
    });
    for t in &mut mesh.triangles {
        *t = t.map(|v| remap[v as usize]);
    }
}

/// Concatenates chunk meshes, welding vertices on shared cell edges.
fn assemble(meshes: &[&ChunkMesh]) -> LabeledMesh {
    let vertices: usize = meshes.iter().map(|m| m.positions.len()).sum();
    let triangles: usize = meshes.iter().map(|m| m.triangles.len()).sum();
    let mut out = LabeledMesh {
        positions: Vec::with_capacity(vertices),
        colors: Vec::with_capacity(vertices),
        normals: Vec::with_capacity(vertices),
        triangles: Vec::with_capacity(triangles),
        ..LabeledMesh::default()
    };
    let mut welded: HashMap<EdgeKey, u32, ChunkHashBuilder> = HashMap::default();
    let mut remap = Vec::new();
    for m in meshes {
        remap.clear();
        let mut shared = m.shared.iter().peekable();
        for i in 0..m.positions.len() {
            if let Some(&(_, key)) = shared.next_if(|s| s.0 == i as u32) {
                if let Some(&j) = welded.get(&key) {
                    remap.push(j);
                    continue;
                }
                welded.insert(key, out.positions.len() as u32);
            }
            remap.push(out.positions.len() as u32);
            out.positions.push(m.positions[i]);
            out.colors.push(m.colors[i]);
            out.normals.push(m.normals[i]);
        }
        out.triangles.extend(m.triangles.iter().map(|t| t.map(|i| remap[i as usize])));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::{split_voxel, TsdfConfig, Voxel, CHUNK_VOXELS};

    /// A map holding the exact truncated SDF of a sphere in every voxel of a box around it.
    fn sphere_map(center: Vec3, radius: f32, observed_box: Option<(IVec3, IVec3)>) -> TsdfMap {
        let config = TsdfConfig::default();
        let vs = config.voxel_size;
        let trunc = config.truncation();
        let mut map = TsdfMap::new(config).expect("valid");
        let lo = ((center - Vec3::splat(radius + 2.0 * trunc)) / vs).floor().as_ivec3();
        let hi = ((center + Vec3::splat(radius + 2.0 * trunc)) / vs).ceil().as_ivec3();
        for z in lo.z..=hi.z {
            for y in lo.y..=hi.y {
                for x in lo.x..=hi.x {
                    let v = IVec3::new(x, y, z);
                    if let Some((a, b)) = observed_box {
                        if v.cmplt(a).any() || v.cmpgt(b).any() {
                            continue;
                        }
                    }
                    let sdf = (v.as_vec3() * vs - center).length() - radius;
                    let (key, local) = split_voxel(v);
                    let (slot, _) = map.allocate(key);
                    let mut vox = Voxel::default();
                    vox.fuse((sdf / trunc).clamp(-1.0, 1.0), 1.0, Some([10, 200, 30]), 256);
                    map.chunks[slot as usize].voxels.set(local, vox);
                }
            }
        }
        for c in &mut map.chunks {
            c.signs = c.voxels.signs();
        }
        map
    }

    fn edge_uses(mesh: &LabeledMesh) -> HashMap<(u32, u32), (u32, u32)> {
        // Undirected edge -> (uses a->b, uses b->a).
        let mut uses: HashMap<(u32, u32), (u32, u32)> = HashMap::new();
        for t in &mesh.triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let e = uses.entry((a.min(b), a.max(b))).or_default();
                if a < b {
                    e.0 += 1;
                } else {
                    e.1 += 1;
                }
            }
        }
        uses
    }

    #[test]
    fn readers_match_the_padded_ranges_and_bytes_pack_in_order() {
        // Reference: the chunk at offset o reads our local coordinate l on an axis when its
        // padded range, -1 ..= 9 in its own coordinates, holds l - 8 o.
        let reads = |o: i32, l: i32| (-1..=9).contains(&(l - 8 * o));
        for i in (0..CHUNK_VOXELS).step_by(7).chain([0, 7, 63, 511]) {
            let mut changed = [0u64; CHUNK_VOXELS / 64];
            changed[i / 64] |= 1 << (i % 64);
            let l = [(i % 8) as i32, ((i / 8) % 8) as i32, (i / 64) as i32];
            let mut want = 0u32;
            for b in 0..27 {
                let o = [b % 3 - 1, (b / 3) % 3 - 1, b / 9 - 1];
                if (0..3).all(|a| reads(o[a], l[a])) {
                    want |= 1 << b;
                }
            }
            assert_eq!(readers(&changed), want, "voxel {l:?}");
        }
        let bytes: [u8; 64] = std::array::from_fn(|i| (i % 3 == 0 || i == 63) as u8);
        let want = (0..64).filter(|&i| bytes[i] == 1).fold(0u64, |m, i| m | 1 << i);
        assert_eq!(pack_bytes(&bytes), want);
    }

    #[test]
    fn fast_paths_match_their_plain_definitions() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        // Vertex colours: the per-channel formula, with the colourless-voxel rule.
        let plain = |ca: [u8; 4], cb: [u8; 4], s: f32| -> [u8; 3] {
            let (ca, cb) = match (ca[3], cb[3]) {
                (0, 0) | (1.., 1..) => (ca, cb),
                (0, _) => (cb, cb),
                (_, 0) => (ca, ca),
            };
            std::array::from_fn(|k| (ca[k] as f32 + s * (cb[k] as f32 - ca[k] as f32) + 0.5) as u8)
        };
        for i in 0..200_000 {
            let mut c = || -> [u8; 4] { [rng.random(), rng.random(), rng.random(), rng.random_range(0..3)] };
            let (ca, cb) = (c(), c());
            let s = match i % 4 {
                0 => 0.0,
                1 => 1.0,
                _ => {
                    // As meshing makes it: a / (a - b) of quantised distances of both signs.
                    let a = rng.random_range(0..=i16::MAX) as f32 / TSDF_SCALE;
                    let b = rng.random_range(i16::MIN..0) as f32 / TSDF_SCALE;
                    a / (a - b)
                }
            };
            assert_eq!(edge_color(ca, cb, s), plain(ca, cb, s), "{ca:?} {cb:?} {s}");
        }
    }

    /// A wavy surface through 3x3x3 chunks around the origin, with noise, jumps, unobserved
    /// voxels (`holes` percent) and weights of 1/256 ..= 2, and its chunks' sign summaries.
    fn noisy_map(rng: &mut rand_chacha::ChaCha8Rng, holes: u32) -> TsdfMap {
        use rand::Rng;
        let mut map = TsdfMap::new(TsdfConfig::default()).expect("valid");
        let trunc = map.config().truncation_voxels;
        for z in -12..12 {
            for y in -12..12 {
                for x in -12..12 {
                    let v = IVec3::new(x, y, z);
                    if rng.random_range(0..100) < holes {
                        continue;
                    }
                    let surface = 2.0 * (0.3 * x as f32).sin() + (0.2 * y as f32).cos();
                    let mut t = (z as f32 - surface) / trunc + rng.random_range(-0.05..0.05);
                    if rng.random_range(0..100) < 5 {
                        t = rng.random_range(-1.0..1.0);
                    }
                    let (key, local) = split_voxel(v);
                    let (slot, _) = map.allocate(key);
                    let mut vox = Voxel::default();
                    let weight = rng.random_range(1..=512) as f32 / WEIGHT_SCALE;
                    let color = [rng.random(), rng.random(), rng.random()];
                    vox.fuse(t.clamp(-1.0, 1.0), weight, Some(color), u16::MAX);
                    if rng.random_range(0..100) < 10 {
                        // Observed without a colour now and then.
                        vox = Voxel::default();
                        vox.fuse(t.clamp(-1.0, 1.0), weight, None, u16::MAX);
                    }
                    map.chunks[slot as usize].voxels.set(local, vox);
                }
            }
        }
        for c in &mut map.chunks {
            c.signs = c.voxels.signs();
        }
        map
    }

    #[test]
    fn the_completed_block_matches_the_chunks() {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut scratch = Scratch::new();
        let mut checked = 0;
        for holes in [3, 30] {
            let map = noisy_map(&mut rng, holes);
            // The outer chunks miss neighbours on some sides.
            for key in map.sorted_keys() {
                let Some(nb) = neighbours_if_surface(&map, key) else { continue };
                for min_weight in [1, 40] {
                    let block = &mut scratch.block;
                    block.gather(&nb, min_weight, &mut scratch.weight, &mut scratch.masks);
                    block.gather_shell(&nb, &scratch.weight);
                    for z in 1..PAD - 1 {
                        for y in 1..PAD - 1 {
                            for x in 1..PAD - 1 {
                                let i = x + PAD * y + PAD2 * z;
                                let (fast, reference) = (block.inner_gradient(i), block.gradient(&nb, i, [x, y, z]));
                                assert_eq!(fast.to_array().map(f32::to_bits), reference.to_array().map(f32::to_bits));
                                assert_eq!(block.color(i), voxel_color(&nb, [x, y, z]));
                                assert_eq!(block.packed[i] >> 16, block.tsdf[i] as i32);
                                checked += 1;
                            }
                        }
                    }
                }
            }
        }
        assert!(checked > 10_000);
    }

    #[test]
    fn row_masks_and_packed_lanes_match_the_scalar_reference() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        for _ in 0..20_000 {
            let t: [i16; 16] = std::array::from_fn(|_| if rng.random_bool(0.1) { 0 } else { rng.random() });
            let w: [u16; 16] = std::array::from_fn(|_| match rng.random_range(0..4) {
                0 => 0,
                1 => rng.random_range(0..80),
                2 => u16::MAX - rng.random_range(0..3),
                _ => rng.random(),
            });
            let min_weight = [1, 2, 40, 0x8000, u16::MAX][rng.random_range(0..5)];
            let reference = row_masks_scalar(&t, &w, min_weight);
            let packed: [i32; 8] = std::array::from_fn(|k| packed_voxel(t[k], w[k], min_weight));
            assert_eq!(packed_lanes(&t[..8], &w[..8], min_weight), packed);
            assert_eq!(row_masks(&t, &w, 0, min_weight), reference);
            #[cfg(target_arch = "x86_64")]
            assert_eq!(row_masks_sse2(&t, &w, min_weight), reference);
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn the_avx2_seam_test_matches_the_scalar_one() {
        use rand::{Rng, SeedableRng};
        if !is_x86_feature_detected!("avx2") {
            return;
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(23);
        let mut block = PaddedBlock::new();
        let mut seams = 0;
        for round in 0..50 {
            // Smooth and rough blocks, so that both answers are common.
            let spread = [300, 3000, 30000][round % 3];
            for t in block.tsdf.iter_mut() {
                *t = rng.random_range(-spread..=spread) as i16;
            }
            for _ in 0..2000 {
                let base = CELL_BASE[rng.random_range(0..CHUNK_VOXELS)] as usize;
                let case = rng.random_range(1..255) as u8;
                let max_jump = [0.01, 0.05, 0.2, 0.5, 1.0][rng.random_range(0..5)];
                let reference = seam_scalar(&block, base, case, max_jump);
                // SAFETY: the CPU has AVX2 (checked above).
                assert_eq!(unsafe { seam_avx2(&block.tsdf, base, case, max_jump) }, reference);
                seams += reference as usize;
            }
        }
        assert!(seams > 10_000 && seams < 90_000, "{seams}");
    }

    /// The vertex kernels this CPU can run, the scalar one first.
    fn available_kernels() -> Vec<VertexKernel> {
        let mut kernels = vec![VertexKernel::Scalar];
        #[cfg(target_arch = "x86_64")]
        {
            if is_x86_feature_detected!("avx2") {
                kernels.push(VertexKernel::Avx2);
            } else {
                eprintln!("no AVX2 on this machine: the AVX2 vertex kernel is not tested");
            }
            if is_x86_feature_detected!("avx512f") {
                kernels.push(VertexKernel::Avx512);
            } else {
                eprintln!("no AVX-512F on this machine: the AVX-512 vertex kernel is not tested");
            }
        }
        kernels
    }

    #[test]
    fn vertex_kernels_agree_bit_for_bit() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(13);
        let kernels = available_kernels();
        let mut block = PaddedBlock::new();
        let mut made = Vec::new();
        for round in 0..200 {
            for (p, c) in block.packed.iter_mut().zip(block.color.iter_mut()) {
                let t: i16 = match rng.random_range(0..4) {
                    0 => i16::MIN + rng.random_range(0..3),
                    1 => i16::MAX - rng.random_range(0..3),
                    _ => rng.random(),
                };
                // Mostly observed, and every pattern of unobserved neighbours now and then.
                let observed = (rng.random_range(0..10) < 10 - round % 5) as i32;
                *p = (t as i32) << 16 | ((t < 0) as i32 & observed) | observed << 1;
                *c = [rng.random(), rng.random(), rng.random(), rng.random_range(0..3)];
            }
            for (t, &p) in block.tsdf.iter_mut().zip(&block.packed) {
                *t = (p >> 16) as i16;
            }
            // Crossed edges between padded 1 ..= 9, as meshing makes them: ends of both signs
            // (zero counts as positive), a zero lower end among them.
            let jobs: [u32; LANES] = std::array::from_fn(|_| loop {
                let axis = rng.random_range(0..3);
                let low: [usize; 3] = std::array::from_fn(|a| rng.random_range(0..if a == axis { 8 } else { 9 }));
                let ia = (low[0] + 1) + PAD * (low[1] + 1) + PAD2 * (low[2] + 1);
                if rng.random_range(0..8) == 0 {
                    block.tsdf[ia] = 0;
                    block.packed[ia] &= 0xffff;
                }
                let (a, b) = (block.tsdf[ia], block.tsdf[ia + STRIDES[axis]]);
                if (a < 0) != (b < 0) {
                    break VertexJob::pack(ia, axis, low);
                }
            });
            let key_voxel = IVec3::new(rng.random_range(-4000..4000), rng.random_range(-4000..4000), -8);
            let voxel_size = rng.random_range(0.001..0.05);
            made.clear();
            for &kernel in &kernels {
                let mut lanes = VertexLanes::default();
                match kernel {
                    VertexKernel::Scalar => vertices_scalar(&block, &jobs, key_voxel, voxel_size, &mut lanes),
                    // SAFETY: AVX2 and AVX-512F were detected above; the jobs are crossed edges in
                    // the block.
                    #[cfg(target_arch = "x86_64")]
                    VertexKernel::Avx2 => unsafe { avx2::vertices(&block, &jobs, key_voxel, voxel_size, &mut lanes) },
                    #[cfg(target_arch = "x86_64")]
                    VertexKernel::Avx512 => unsafe {
                        avx512::vertices(&block, &jobs, key_voxel, voxel_size, &mut lanes)
                    },
                }
                let bits = |v: &[[f32; LANES]; 3]| v.map(|a| a.map(f32::to_bits));
                made.push((bits(&lanes.position), bits(&lanes.normal), lanes.color));
            }
            for m in &made[1..] {
                assert_eq!(m, &made[0], "round {round}");
            }
        }
    }

    #[test]
    fn edge_tables_match_their_definitions() {
        // Every crossed edge is used, once, by the case's triangles.
        for case in 0..=255u8 {
            let (edges, n) = first_uses()[case as usize];
            let mask = edges[..n as usize].iter().fold(0u16, |m, &e| m | 1 << e);
            assert_eq!((mask, mask.count_ones()), (CROSSED[case as usize], n as u32), "case {case}");
        }
        for cell in 0..CHUNK_VOXELS {
            let c = [cell % CHUNK_SIDE, cell / CHUNK_SIDE % CHUNK_SIDE, cell / (CHUNK_SIDE * CHUNK_SIDE)];
            let class = |c: usize| (c != 0) as usize + (c == CHUNK_SIDE - 1) as usize;
            let base = (c[0] + 1) + PAD * (c[1] + 1) + PAD2 * (c[2] + 1);
            for e in 0..12 {
                let a = EDGES[e].0 as usize;
                let axis = e / 4;
                let low: [usize; 3] = std::array::from_fn(|q| c[q] + ((a >> q) & 1));
                let shared = (0..3).any(|q| q != axis && (low[q] == 0 || low[q] == CHUNK_SIDE));
                assert_eq!(SHARED_EDGES[class(c[0]) + 3 * class(c[1]) + 9 * class(c[2])] >> e & 1 != 0, shared);
                assert_eq!(SHARED_EDGES[CELL_CLASS[cell] as usize] >> e & 1 != 0, shared);
                assert_eq!(CELL_BASE[cell] as usize, base);
                let job = VertexJob::pack(base, 0, c) + EDGE_JOB[e];
                assert_eq!(job, VertexJob::pack(base + CORNER_OFFSET[a], axis, low));
                let low = low.map(|l| l as i32);
                assert_eq!(VertexJob::unpack(job), (base + CORNER_OFFSET[a], axis, low));
            }
        }
    }

    #[test]
    fn chunk_meshes_do_not_depend_on_the_vertex_kernel() {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        let map = noisy_map(&mut rng, 5);
        let mut scratches: Vec<Scratch> =
            available_kernels().into_iter().map(|kernel| Scratch { kernel, ..Scratch::new() }).collect();
        let mut vertices = 0;
        for key in map.sorted_keys() {
            for min_weight in [1, 40] {
                let bits = |m: &ChunkMesh| {
                    let b = |v: &[Vec3]| v.iter().map(|p| p.to_array().map(f32::to_bits)).collect::<Vec<_>>();
                    (b(&m.positions), b(&m.normals))
                };
                let meshes: Vec<ChunkMesh> =
                    scratches.iter_mut().map(|s| mesh_chunk_configured(&map, key, min_weight, s)).collect();
                for m in &meshes[1..] {
                    assert_eq!(bits(m), bits(&meshes[0]));
                    assert_eq!(m, &meshes[0]);
                }
                vertices += meshes[0].positions.len();
            }
        }
        assert!(vertices > 1000, "{vertices} vertices");
    }

    /// The cells of chunk `key` that meshing keeps, by the plain definition (every corner
    /// observed with a weight of at least `min_weight`, both signs, no crossed edge jumping
    /// by more than the seam limit), with their cases, in cell order.
    fn kept_cells_plain(map: &TsdfMap, key: ChunkKey, min_weight: f32, seams: &mut usize) -> Vec<(u16, u8)> {
        let config = map.config();
        let max_jump = (MAX_EDGE_JUMP_BANDS * config.narrowest_band_voxels() / config.truncation_voxels).min(1.0);
        let voxel = |v: IVec3| {
            let (k, i) = split_voxel(v);
            map.chunk(k).map(|c| c.voxel(i)).filter(|v| v.weight() > 0.0 && v.weight() >= min_weight)
        };
        let mut out = Vec::new();
        for i in 0..CHUNK_VOXELS {
            let cell = key * CHUNK_SIDE as i32 + IVec3::new((i % 8) as i32, (i / 8 % 8) as i32, (i / 64) as i32);
            let corners: Vec<Option<Voxel>> =
                (0..8).map(|c| voxel(cell + IVec3::new(c & 1, (c >> 1) & 1, (c >> 2) & 1))).collect();
            let Some(f) = corners.iter().map(|c| c.map(|v| v.tsdf())).collect::<Option<Vec<f32>>>() else { continue };
            let case = (0..8).fold(0u8, |m, c| m | ((f[c] < 0.0) as u8) << c);
            let seam = EDGES.iter().any(|&(a, b)| {
                let (a, b) = (f[a as usize], f[b as usize]);
                (a < 0.0) != (b < 0.0) && (a - b).abs() > max_jump
            });
            if case != 0 && case != 255 {
                if seam {
                    *seams += 1;
                } else {
                    out.push((i as u16, case));
                }
            }
        }
        out
    }

    #[test]
    fn kept_cells_match_the_plain_definition_on_random_maps() {
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        for round in 0..4 {
            // A wavy surface through 3x3x3 chunks, with noise, jumps and unobserved voxels.
            let map = noisy_map(&mut rng, 3 + 4 * round);
            for min_weight in [0.0, 1.0 / WEIGHT_SCALE, 0.1, 0.25] {
                let (mut kept, mut seams) = (0, 0);
                for key in map.sorted_keys() {
                    let want = kept_cells_plain(&map, key, min_weight, &mut seams);
                    let want_triangles: usize = want.iter().map(|&(_, case)| case_table().triangles(case).len()).sum();
                    let config = MeshConfig { min_weight, ..MeshConfig::default() };
                    let mesh = mesh_chunk_with(&map, key, config).expect("valid");
                    assert_eq!(mesh.triangles.len(), want_triangles, "chunk {key}, round {round}, {min_weight}");
                    if min_weight == 0.0 {
                        assert_eq!(mesh, mesh_chunk(&map, key));
                    }
                    kept += want.len();
                }
                let least = if min_weight < 0.01 { 150 } else { 20 };
                assert!(kept > least && seams > least / 5, "{kept} cells kept, {seams} seams at {min_weight}");
            }
        }
    }

    #[test]
    fn small_pieces_are_dropped_with_their_vertices() {
        // A strip of 3 triangles (vertices 0, 1, 2, 4, 5), a lone triangle (3, 6, 7), and an
        // unused vertex 8.
        let p = |i: usize| Vec3::new(i as f32, (i * i) as f32, 0.0);
        let mut mesh = LabeledMesh {
            positions: (0..9).map(p).collect(),
            colors: (0..9).map(|i| [i as u8; 3]).collect(),
            normals: vec![Vec3::Z; 9],
            triangles: vec![[0, 1, 2], [3, 6, 7], [1, 2, 4], [2, 4, 5]],
            ..LabeledMesh::default()
        };
        let original = mesh.clone();
        for min in [0, 1] {
            drop_small_components(&mut mesh, min);
            assert_eq!(mesh, original);
        }
        drop_small_components(&mut mesh, 2);
        let want = [0, 1, 2, 4, 5];
        assert_eq!(mesh.positions, want.map(p).to_vec());
        assert_eq!(mesh.colors, want.map(|i| [i as u8; 3]).to_vec());
        assert_eq!(mesh.triangles, vec![[0, 1, 2], [1, 2, 3], [2, 3, 4]]);
        mesh.validate().expect("valid");
        drop_small_components(&mut mesh, 4);
        assert!(mesh.triangles.is_empty() && mesh.positions.is_empty());
    }

    #[test]
    fn light_voxels_are_unobserved_to_a_thresholded_mesher() {
        let mut map = sphere_map(Vec3::new(0.011, 0.003, -0.02), 0.07, None);
        let full = extract_mesh(&map);
        assert_eq!(extract_mesh_with(&map, MeshConfig::default()).expect("valid"), full);
        // Halve the weight of every voxel with x > 0: a threshold between the two weights
        // leaves the half x <= 0 (and the cells straddling x = 0 open).
        for c in &mut map.chunks {
            for i in 0..CHUNK_VOXELS {
                let x = c.key.x * CHUNK_SIDE as i32 + (i % CHUNK_SIDE) as i32;
                if x > 0 {
                    c.voxels.weight[i] /= 2;
                }
            }
        }
        let half = extract_mesh_with(&map, MeshConfig { min_weight: 0.75, ..MeshConfig::default() }).expect("valid");
        assert!(half.triangle_count() > full.triangle_count() / 3);
        assert!(half.triangle_count() < full.triangle_count() * 2 / 3);
        assert!(half.positions.iter().all(|p| p.x <= 1e-6), "no vertex beyond the heavy half");
        assert_eq!(
            extract_mesh_with(&map, MeshConfig { min_weight: 0.5, ..MeshConfig::default() }).expect("valid"),
            full
        );
        // The closed sphere is one piece: a size limit up to its triangle count keeps it.
        let pieces = |n| MeshConfig { min_weight: 0.5, min_component_triangles: n };
        assert_eq!(extract_mesh_with(&map, pieces(full.triangle_count())).expect("valid"), full);
        assert!(extract_mesh_with(&map, pieces(full.triangle_count() + 1)).expect("valid").positions.is_empty());
        for bad in [-0.1, f32::NAN, 256.0] {
            let config = MeshConfig { min_weight: bad, ..MeshConfig::default() };
            assert!(config.validate().is_err());
            assert!(IncrementalMesher::with_config(config, RemeshTolerance::EXACT).is_err());
        }
    }

    #[test]
    fn a_budgeted_mesher_meshes_new_surface_first_and_catches_up() {
        use std::collections::HashSet;
        use std::num::NonZeroUsize;
        let center = Vec3::new(0.011, 0.003, -0.02);
        let small = sphere_map(center, 0.07, None);
        let mut big = sphere_map(center, 0.08, None);
        for c in &mut big.chunks {
            c.revision = 1;
        }
        let new_keys: HashSet<ChunkKey> =
            big.chunks.iter().map(|c| c.key).filter(|k| !small.index.contains_key(k)).collect();
        // New chunks and their lower neighbours, whose cells reach into them (all due: every
        // chunk changed), go first.
        let urgent: HashSet<ChunkKey> = new_keys
            .iter()
            .flat_map(|&k| reader_marks::bits(CELL_READERS).map(move |b| k + reader_marks::reader_offset(b)))
            .filter(|k| big.index.contains_key(k))
            .collect();
        assert!(
            !new_keys.is_empty() && 2 * urgent.len() < big.chunk_count(),
            "{} of {}",
            urgent.len(),
            big.chunk_count()
        );
        let budget = urgent.len() + 3;
        let mut mesher = IncrementalMesher::new().with_budget(NonZeroUsize::new(budget));
        // Everything is due at first: it takes ceil(chunks / budget) updates.
        let mut updates = 0;
        loop {
            let st = mesher.update(&small);
            updates += 1;
            assert!(st.remeshed_chunks <= budget);
            assert_eq!(st.pending_chunks, mesher.pending_chunks());
            if st.pending_chunks == 0 {
                break;
            }
        }
        assert_eq!(updates, small.chunk_count().div_ceil(budget));
        assert_eq!(mesher.mesh(), extract_mesh(&small));
        // Every chunk changes and new ones appear: the new ones are meshed first.
        let g = mesher.generation();
        let st = mesher.update(&big);
        assert_eq!((st.remeshed_chunks, st.pending_chunks), (budget, big.chunk_count() - budget));
        let first: HashSet<ChunkKey> = mesher.remeshed_since(g).map(|(k, _)| k).collect();
        assert!(urgent.is_subset(&first));
        let left: HashSet<ChunkKey> = big.chunks.iter().map(|c| c.key).filter(|k| !first.contains(k)).collect();
        assert!(left.len() > budget, "the test needs more left over than one budget");
        // Everything changes again: what was left over goes before what is due anew.
        for c in &mut big.chunks {
            c.revision = 2;
        }
        let g = mesher.generation();
        mesher.update(&big);
        assert!(mesher.remeshed_since(g).all(|(k, _)| left.contains(&k)));
        // Without the budget, everything is brought up to date.
        let st = mesher.update_all(&big);
        assert_eq!(st.pending_chunks, 0);
        assert_eq!(st.remeshed_chunks, big.chunk_count() - budget);
        assert_eq!(mesher.mesh(), extract_mesh(&big));
        assert_eq!(mesher.update(&big).remeshed_chunks, 0);
    }

    #[test]
    fn the_cache_follows_chunks_that_the_map_frees_and_moves() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let center = Vec3::new(0.011, 0.003, -0.02);
        let mut map = sphere_map(center, 0.08, None);
        let donor = sphere_map(center + Vec3::new(0.05, -0.02, 0.0), 0.08, None);
        for budget in [None, std::num::NonZeroUsize::new(40)] {
            let mut mesher = IncrementalMesher::new().with_budget(budget);
            mesher.update_all(&map);
            for round in 0..6u64 {
                // Free about a tenth of the chunks: the map moves its last ones into their places.
                let slots: Vec<u32> = (0..map.chunk_count() as u32).filter(|_| rng.random_range(0..10) == 0).collect();
                assert!(!slots.is_empty());
                map.free(slots);
                // Chunks (re)appear with other voxels.
                for c in donor.chunks.iter().filter(|_| rng.random_range(0..8) == 0) {
                    let (slot, _) = map.allocate(c.key);
                    let chunk = &mut map.chunks[slot as usize];
                    chunk.voxels = c.voxels.clone();
                    chunk.signs = c.signs;
                    chunk.revision = 100 + round;
                }
                mesher.update(&map);
                assert_eq!(mesher.chunk_count(), map.chunk_count());
                let stats = mesher.update_all(&map);
                assert_eq!(mesher.mesh(), extract_mesh(&map), "round {round}, budget {budget:?}");
                let triangles: usize = mesher.remeshed_since(0).map(|(_, m)| m.triangles.len()).sum();
                assert_eq!(stats.triangles, triangles, "the running count");
            }
        }
    }

    #[test]
    fn meshes_do_not_depend_on_the_thread_count() {
        let map = sphere_map(Vec3::new(0.011, 0.003, -0.02), 0.07, None);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            pool.install(|| {
                let mut mesher = IncrementalMesher::new();
                mesher.update(&map);
                (mesher.mesh(), extract_mesh(&map))
            })
        };
        let (one, one_full) = run(1);
        assert!(one.triangle_count() > 1000);
        assert_eq!(one, one_full);
        assert_eq!(run(3), (one.clone(), one));
    }

    #[test]
    fn sphere_mesh_is_accurate_closed_and_outward() {
        let (center, radius) = (Vec3::new(0.0131, -0.0217, 0.0072), 0.1);
        let map = sphere_map(center, radius, None);
        assert!(map.chunk_count() > 27, "the sphere spans many chunks, negative keys included");
        let mesh = extract_mesh(&map);
        mesh.validate().expect("valid mesh");
        assert!(mesh.triangle_count() > 5000);
        let vs = map.config().voxel_size;
        for (p, n) in mesh.positions.iter().zip(&mesh.normals) {
            let r = *p - center;
            assert!((r.length() - radius).abs() < 0.02 * vs, "vertex {p} off the sphere");
            assert!(n.dot(r.normalize()) > 0.98, "normal {n} at {p}");
        }
        assert!(mesh.colors.iter().all(|c| *c == [10, 200, 30]));
        // Closed and consistently wound: every edge once in each direction.
        for (e, (ab, ba)) in edge_uses(&mesh) {
            assert!(ab == 1 && ba == 1, "edge {e:?} used {ab} + {ba} times");
        }
        // Counter-clockwise seen from outside.
        let mut outward = 0.0;
        for t in &mesh.triangles {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            outward += (b - a).cross(c - a).dot((a + b + c) / 3.0 - center);
        }
        assert!(outward > 0.0);
        for t in &mesh.triangles {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            let n = (b - a).cross(c - a);
            if n.length() > 1e-9 {
                assert!(n.dot((a + b + c) / 3.0 - center) > 0.0, "inward triangle {t:?}");
            }
        }
        // Euler characteristic of a sphere.
        let v = mesh.vertex_count() as i64;
        let f = mesh.triangle_count() as i64;
        assert_eq!(v - 3 * f / 2 + f, 2);
    }

    #[test]
    fn unobserved_voxels_leave_an_open_border_not_a_phantom_surface() {
        let (center, radius) = (Vec3::new(0.0, 0.0, 0.0), 0.1);
        // Only the half x < 0.02 m is observed.
        let lo = IVec3::splat(-100);
        let hi = IVec3::new(4, 100, 100);
        let map = sphere_map(center, radius, Some((lo, hi)));
        let mesh = extract_mesh(&map);
        assert!(mesh.triangle_count() > 1000);
        let vs = map.config().voxel_size;
        for p in &mesh.positions {
            assert!(((*p - center).length() - radius).abs() < 0.02 * vs);
            assert!(p.x <= 4.0 * vs + 1e-6, "vertex {p} beyond the observed voxels");
        }
        let border = edge_uses(&mesh).values().filter(|(a, b)| a + b == 1).count();
        assert!(border > 0, "the cut is an open border");
    }

    #[test]
    fn free_space_next_to_the_back_of_a_surface_makes_no_triangles() {
        let mut map = TsdfMap::new(TsdfConfig::default()).expect("valid");
        let (slot, _) = map.allocate(IVec3::ZERO);
        for i in 0..CHUNK_VOXELS {
            // Free space (+1) for x < 4, the far side of a surface (-1) beyond.
            let t = if i % 8 < 4 { 1.0 } else { -1.0 };
            let mut v = Voxel::default();
            v.fuse(t, 1.0, None, 256);
            map.chunks[slot as usize].voxels.set(i, v);
        }
        map.chunks[slot as usize].signs = map.chunks[slot as usize].voxels.signs();
        assert!(mesh_chunk(&map, IVec3::ZERO).triangles.is_empty());
    }
}
