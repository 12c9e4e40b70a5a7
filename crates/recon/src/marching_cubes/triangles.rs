//! The cell passes of a chunk's meshing: classify the cells from the padded block's row masks,
//! then make the triangles, numbering each crossed edge's vertex when first used and skipping
//! the seams between free space and the back of a surface.

use super::*;

/// Padded offset of cell corner `c` from the cell's lowest corner.
pub(super) const CORNER_OFFSET: [usize; 8] = {
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
pub(super) fn classify(masks: &[(u16, u16); PAD2], cells: &mut Vec<(u16, u8)>) -> usize {
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
pub(super) struct EdgeSlots {
    /// Local cell-edge index -> `stamp << 12 | vertex` (vertices of a chunk are fewer than
    /// its 2187 cell edges, below 2^12): a slot holds a vertex of the current chunk only when
    /// its stamp is `stamp`, so nothing is cleared between chunks.
    pub(super) vertex: Vec<u32>,
    pub(super) stamp: u32,
}

impl EdgeSlots {
    pub(super) fn new() -> Self {
        Self { vertex: vec![0; ES * ES * ES * 3], stamp: 0 }
    }

    /// Forgets every vertex (a new stamp; the slots are cleared when stamps run out).
    pub(super) fn next_chunk(&mut self) {
        self.stamp += 1;
        if self.stamp == 1 << 20 {
            self.vertex.fill(0);
            self.stamp = 1;
        }
    }
}

/// Per case, its crossed edges in the order its triangles first use them (and how many):
/// the order in which a cell of that case numbers its new vertices.
pub(super) fn first_uses() -> &'static [([u8; 12], u8); 256] {
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
pub(super) const EDGE_JOB: [u32; 12] = {
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
pub(super) const SHARED_EDGES: [u16; 27] = {
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
/// make before the seam test ([`classify`]). `cells` keeps the cells that made triangles
/// (those without a seam edge), in order: what the live mesh keeps of a chunk's topology
/// (`packed_mesh.rs`).
///
/// The seam test runs with AVX2 where the CPU has it and `kernel` is not the scalar one
/// ([`seam_avx2`]), else edge by edge ([`seam_scalar`]): the same decisions.
#[inline(never)]
#[allow(clippy::too_many_arguments)]
pub(super) fn triangles(
    block: &PaddedBlock,
    cells: &mut Vec<(u16, u8)>,
    triangle_count: usize,
    max_jump: f32,
    edges: &mut EdgeSlots,
    jobs: &mut Vec<u32>,
    mesh: &mut ChunkMesh,
    kernel: VertexKernel,
) {
    #[cfg(target_arch = "x86_64")]
    if kernel != VertexKernel::Scalar && is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2.
        unsafe { triangles_avx2(block, cells, triangle_count, max_jump, edges, jobs, mesh) };
        return;
    }
    let _ = kernel;
    triangles_with(cells, triangle_count, edges, jobs, mesh, |base, case| seam_scalar(block, base, case, max_jump));
}

/// [`triangles`] compiled for AVX2, with [`seam_avx2`] inlined.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn triangles_avx2(
    block: &PaddedBlock,
    cells: &mut Vec<(u16, u8)>,
    triangle_count: usize,
    max_jump: f32,
    edges: &mut EdgeSlots,
    jobs: &mut Vec<u32>,
    mesh: &mut ChunkMesh,
) {
    triangles_with(cells, triangle_count, edges, jobs, mesh, |base, case| seam_avx2(&block.tsdf, base, case, max_jump));
}

/// Whether a crossed edge of the cell with lowest corner at padded index `base` and case
/// `case` jumps by more than `max_jump` truncation units: edge by edge, the definition.
#[inline(always)]
pub(super) fn seam_scalar(block: &PaddedBlock, base: usize, case: u8, max_jump: f32) -> bool {
    pub(super) const ENDS: [(u8, u8); 16] = {
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
pub(super) fn seam_avx2(tsdf: &[i16; PAD * PAD2], base: usize, case: u8, max_jump: f32) -> bool {
    use std::arch::x86_64::*;
    /// Per edge (lane), its first (`.0`) or second end; lanes 12 ..= 15 compare corner 0
    /// with itself.
    pub(super) const fn ends(second: bool) -> [i32; 16] {
        let mut out = [0; 16];
        let mut e = 0;
        while e < 12 {
            out[e] = if second { EDGES[e].1 } else { EDGES[e].0 } as i32;
            e += 1;
        }
        out
    }
    pub(super) const FIRST: [i32; 16] = ends(false);
    pub(super) const SECOND: [i32; 16] = ends(true);
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

/// The body of [`triangles`] with the seam test `seam(base, case)` (true: skip the cell;
/// `cells` is left with the others).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn triangles_with(
    cells: &mut Vec<(u16, u8)>,
    triangle_count: usize,
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
    pub(super) const fn pad<T: Copy>(t: [T; 12], fill: T) -> [T; 16] {
        let mut out = [fill; 16];
        let mut e = 0;
        while e < 12 {
            out[e] = t[e];
            e += 1;
        }
        out
    }
    pub(super) const KEY: [usize; 16] = pad(EDGE_KEY, 0);
    pub(super) const JOB: [u32; 16] = pad(EDGE_JOB, 0);
    let mut kept = 0;
    for i in 0..cells.len() {
        let (cell, case) = cells[i];
        let base = CELL_BASE[cell as usize] as usize;
        if seam(base, case) {
            continue;
        }
        cells[kept] = (cell, case);
        kept += 1;
        let cell = cell as usize;
        let (used, n_used) = &order[case as usize];
        let used = &used[..*n_used as usize];
        let (x, y, z) = (cell % CHUNK_SIDE, (cell / CHUNK_SIDE) % CHUNK_SIDE, cell / (CHUNK_SIDE * CHUNK_SIDE));
        let cell_key = ((z * ES + y) * ES + x) * 3;
        let cell_job = VertexJob::pack(base, 0, [x, y, z]);
        let shared = SHARED_EDGES[CELL_CLASS[cell] as usize];
        let mut local = [0u16; 16];
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
                    mesh.shared.push(SharedVertex::new(v, axis, low));
                }
            }
            local[e] = (*slot & 0xfff) as u16;
        }
        let tris = table.triangles(case);
        for (dst, tri) in mesh.triangles[written..written + tris.len()].iter_mut().zip(tris) {
            *dst = tri.map(|e| local[e as usize & 15]);
        }
        written += tris.len();
    }
    mesh.triangles.truncate(written);
    cells.truncate(kept);
}

/// Per cell (`x + 8 y + 64 z`), the padded index of its lowest corner.
pub(super) const CELL_BASE: [u16; CHUNK_VOXELS] = {
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
pub(super) const CELL_CLASS: [u8; CHUNK_VOXELS] = {
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
