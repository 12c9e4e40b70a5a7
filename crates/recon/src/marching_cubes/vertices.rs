//! Making the mesh's vertices: one job per crossed edge, made sixteen at a time (position on
//! the edge, colour and normal interpolated from its ends) by the widest kernel the CPU has,
//! the scalar [`vertex`] being the definition that the AVX2 and AVX-512 kernels match bit for
//! bit.

use glam::{IVec3, Vec3};

use super::{edge_color, ChunkMesh, PaddedBlock, PAD, PAD2};

/// Vertices made at once.
pub(super) const LANES: usize = 16;

/// One vertex to make, packed into a `u32`: bits 0..11 the padded index of the edge's lower
/// end, 11..13 the edge's axis, then 4 bits per axis of the lower end's local coordinates
/// (0 ..= 8).
pub(super) struct VertexJob;

impl VertexJob {
    #[inline]
    pub(super) fn pack(lower: usize, axis: usize, low: [usize; 3]) -> u32 {
        (lower | axis << 11 | low[0] << 13 | low[1] << 17 | low[2] << 21) as u32
    }

    /// (padded index of the lower end, axis, local coordinates of the lower end).
    #[inline]
    pub(super) fn unpack(job: u32) -> (usize, usize, [i32; 3]) {
        let j = job as usize;
        (j & 0x7ff, (j >> 11) & 3, [(j >> 13) as i32 & 15, (j >> 17) as i32 & 15, (j >> 21) as i32 & 15])
    }
}

/// Padded index step per axis.
pub(super) const STRIDES: [usize; 3] = [1, PAD, PAD2];

/// A batch of made vertices, lane `k` for job `k`: positions and normals by axis, colours
/// as `r | g << 8 | b << 16`.
#[derive(Debug, Default, Clone, PartialEq)]
pub(super) struct VertexLanes {
    pub(super) position: [[f32; LANES]; 3],
    pub(super) normal: [[f32; LANES]; 3],
    pub(super) color: [u32; LANES],
}

/// Which code makes vertex batches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum VertexKernel {
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
    pub(super) fn detect() -> Self {
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
pub(super) fn vertex(block: &PaddedBlock, job: u32, key_voxel: IVec3, voxel_size: f32) -> (Vec3, [u8; 3], Vec3) {
    let (ia, axis, low) = VertexJob::unpack(job);
    let ib = ia + STRIDES[axis];
    let s = edge_parameter(block, job);
    let color = edge_color(block.color(ia), block.color(ib), s);
    let g = block.inner_gradient(ia).lerp(block.inner_gradient(ib), s);
    (position_on_edge(key_voxel, low, axis, s, voxel_size), color, g.normalize_or_zero())
}

/// Where on its edge the vertex of `job` lies: 0 at the lower end, 1 at the upper (the
/// distances' zero crossing, linear between the ends).
#[inline]
pub(super) fn edge_parameter(block: &PaddedBlock, job: u32) -> f32 {
    let (ia, axis, _) = VertexJob::unpack(job);
    let (fa, fb) = (block.tsdf(ia), block.tsdf(ia + STRIDES[axis]));
    fa / (fa - fb)
}

/// The position, metres, of a vertex `s` along the edge along `axis` from voxel `low` of the
/// chunk whose first voxel is `key_voxel` (the arithmetic every vertex kernel matches).
#[inline]
pub(super) fn position_on_edge(key_voxel: IVec3, low: [i32; 3], axis: usize, s: f32, voxel_size: f32) -> Vec3 {
    let mut p = (key_voxel + IVec3::from(low)).as_vec3();
    p[axis] += s;
    p * voxel_size
}

/// [`vertex`] for each of a batch of jobs.
pub(super) fn vertices_scalar(
    block: &PaddedBlock,
    jobs: &[u32; LANES],
    key_voxel: IVec3,
    voxel_size: f32,
    out: &mut VertexLanes,
) {
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
pub(super) fn make_vertices(
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
            VertexKernel::Avx2 => unsafe { super::avx2::vertices(block, batch, key_voxel, voxel_size, lanes) },
            #[cfg(target_arch = "x86_64")]
            VertexKernel::Avx512 => unsafe { super::avx512::vertices(block, batch, key_voxel, voxel_size, lanes) },
        }
        // Interleaved on the stack and appended at once: three pushes a vertex, with their
        // capacity checks, cost more than making the vertex.
        let [px, py, pz] = &lanes.position;
        let [nx, ny, nz] = &lanes.normal;
        let positions: [Vec3; LANES] = std::array::from_fn(|k| Vec3::new(px[k], py[k], pz[k]));
        // Rounded to what the live mesh keeps of them (see `packed_mesh.rs`).
        let normals: [Vec3; LANES] =
            std::array::from_fn(|k| super::packed_mesh::quantised_normal(Vec3::new(nx[k], ny[k], nz[k])));
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
