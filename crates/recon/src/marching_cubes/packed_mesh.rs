//! A chunk mesh as the live mesh keeps it: the cells that made triangles, with their cases,
//! and per vertex only what the map alone decided (where on its cell edge it lies, its normal
//! and its colour), in one allocation.
//!
//! Everything else follows. The triangles, which cell edge each vertex sits on and which
//! vertices neighbouring chunks share are what the triangle pass makes of the kept cells (the
//! seam test already applied: it is the pass that made them, run again without it), and a
//! position is its edge's low corner plus the parameter along the edge, by the arithmetic of
//! [`vertex`](super::vertices::vertex). So [`PackedChunkMesh::unpack`] gives the chunk mesh
//! back bit for bit (tested on random maps for every vertex kernel).
//!
//! Why: a whole home's live mesh held 1.27 GB in five vectors per chunk (positions and
//! normals 12 bytes a vertex, colours 3, triangles 12 at two a vertex, shared vertices, each
//! vector with its allocation and slack). Packed, a chunk takes 11 bytes a vertex and 3 a
//! kept cell in one allocation: the same home's live mesh is 450 MB, 18 bytes of mesh and 26
//! in all per vertex of the whole mesh (docs/benchmarks_log.md, "Session 31"). Normals are kept in 32 bits
//! ([`normal_code`]): the meshing kernels round theirs to what that code holds, so every mesh
//! (live or extracted) has the same normals and packing loses nothing.

use super::*;

/// Bytes of the header: kept cells, vertices and triangles, `u16` each.
const HEADER: usize = 6;
/// Bytes per kept cell: its index (`u16`) and case.
const CELL_BYTES: usize = 3;
/// Bytes per vertex: the parameter along its edge (`f32`), its normal ([`normal_code`]), its
/// colour.
const VERTEX_BYTES: usize = 4 + 4 + 3;

/// The code of a zero normal (where the gradient vanishes): outside the codes of directions,
/// whose components are at least `-32767`.
const ZERO_NORMAL: [i16; 2] = [i16::MIN, i16::MIN];

/// A unit normal in 32 bits: its octahedral projection (the unit octahedron's face folded
/// over for the lower half) with 16 bits per coordinate, within 0.004 degrees of the normal.
/// The meshing kernels' normals are stored as [`normal_from_code`] of this
/// ([`quantised_normal`]), so that packing keeps them exactly in 4 bytes instead of 12.
pub(super) fn normal_code(n: Vec3) -> [i16; 2] {
    let l1 = n.x.abs() + n.y.abs() + n.z.abs();
    if !(l1 > 0.0 && l1.is_finite()) {
        return ZERO_NORMAL;
    }
    let (mut u, mut v) = (n.x / l1, n.y / l1);
    if n.z < 0.0 {
        (u, v) = ((1.0 - v.abs()) * sign(u), (1.0 - u.abs()) * sign(v));
    }
    [u, v].map(|c| (c * 32767.0).round().clamp(-32767.0, 32767.0) as i16)
}

/// The unit normal of a [`normal_code`] (zero for the zero normal's code).
pub(super) fn normal_from_code(code: [i16; 2]) -> Vec3 {
    if code == ZERO_NORMAL {
        return Vec3::ZERO;
    }
    let [u, v] = code.map(|c| f32::from(c) / 32767.0);
    let z = 1.0 - u.abs() - v.abs();
    let (x, y) = if z < 0.0 { ((1.0 - v.abs()) * sign(u), (1.0 - u.abs()) * sign(v)) } else { (u, v) };
    Vec3::new(x, y, z).normalize()
}

/// The normal a mesh keeps for the kernels' unit (or zero) normal `n`: within 0.004 degrees.
#[inline]
pub(super) fn quantised_normal(n: Vec3) -> Vec3 {
    normal_from_code(normal_code(n))
}

/// 1 or -1 by the sign bit (-0 counts as negative): a coordinate that decoding leaves at
/// zero keeps the side of the fold its code was on, so the code round-trips.
fn sign(x: f32) -> f32 {
    1.0f32.copysign(x)
}

/// A chunk mesh packed (see the module): empty when the chunk has no triangles.
#[derive(Debug, Clone, Default, PartialEq)]
pub(super) struct PackedChunkMesh {
    /// Header, cells, parameters, normals, colours; the buffer may be longer than they need
    /// (see [`PackedChunkMesh::fits`]).
    bytes: Box<[u8]>,
}

/// Buffers that unpacking reuses from chunk to chunk.
pub(super) struct Unpacker {
    cells: Vec<(u16, u8)>,
    edges: EdgeSlots,
    jobs: Vec<u32>,
}

impl Unpacker {
    pub(super) fn new() -> Self {
        Self { cells: Vec::new(), edges: EdgeSlots::new(), jobs: Vec::new() }
    }
}

impl PackedChunkMesh {
    /// Bytes a mesh of `cells` kept cells and `vertices` vertices needs.
    pub(super) fn needed(cells: usize, vertices: usize) -> usize {
        HEADER + CELL_BYTES * cells + VERTEX_BYTES * vertices
    }

    fn count(&self, field: usize) -> usize {
        self.bytes.get(2 * field..2 * field + 2).map_or(0, |b| usize::from(u16::from_le_bytes([b[0], b[1]])))
    }

    /// Kept cells.
    fn cells(&self) -> usize {
        self.count(0)
    }

    /// Vertices.
    pub(super) fn vertices(&self) -> usize {
        self.count(1)
    }

    /// Triangles.
    pub(super) fn triangles(&self) -> usize {
        self.count(2)
    }

    /// Whether the chunk has no triangles.
    pub(super) fn is_empty(&self) -> bool {
        self.vertices() == 0
    }

    /// Heap bytes: (allocated, needed).
    pub(super) fn heap_bytes(&self) -> (usize, usize) {
        let used = if self.bytes.is_empty() { 0 } else { Self::needed(self.cells(), self.vertices()) };
        (self.bytes.len(), used)
    }

    /// Whether the buffer holds `needed` bytes without more slack than the live mesh keeps:
    /// a quarter (see [`PackedChunkMesh::sized_for`]).
    pub(super) fn fits(&self, needed: usize) -> bool {
        let capacity = self.bytes.len();
        capacity >= needed && capacity <= needed + needed / 4 + 8
    }

    /// An empty buffer for `needed` bytes and an eighth more: a chunk that grows or shrinks
    /// by a few vertices per re-mesh keeps its buffer (see [`PackedChunkMesh::fits`]). The
    /// caller's thread allocates it: the incremental mesher's own, not a meshing worker's,
    /// whose allocator arena the map's chunks share (docs/benchmarks_log.md, "Session 30").
    pub(super) fn sized_for(needed: usize) -> Self {
        Self { bytes: vec![0; needed + needed / 8 + 4].into_boxed_slice() }
    }

    /// An empty buffer of exactly `needed` bytes.
    pub(super) fn exact(needed: usize) -> Self {
        Self { bytes: vec![0; needed].into_boxed_slice() }
    }

    /// Copies `src` into this buffer, which must [fit](PackedChunkMesh::fits) it: no
    /// allocation.
    pub(super) fn copy_from(&mut self, src: &PackedChunkMesh) {
        let needed = src.heap_bytes().1;
        debug_assert!(self.fits(needed));
        self.bytes[..needed].copy_from_slice(&src.bytes[..needed]);
    }

    /// Packs the chunk mesh just made in `scratch` (by [`build`]: its kept cells, vertex jobs
    /// and padded block) into this buffer, which must [fit](PackedChunkMesh::fits) it.
    pub(super) fn pack(&mut self, scratch: &Scratch) {
        let mesh = &scratch.mesh;
        let (cells, vertices) = (scratch.cells.len(), mesh.positions.len());
        let needed = Self::needed(cells, vertices);
        debug_assert!(self.fits(needed) && scratch.jobs.len() >= vertices);
        let out = &mut self.bytes[..needed];
        let (header, rest) = out.split_at_mut(HEADER);
        for (dst, n) in header.chunks_exact_mut(2).zip([cells, vertices, mesh.triangles.len()]) {
            dst.copy_from_slice(&(n as u16).to_le_bytes());
        }
        let (cell_bytes, rest) = rest.split_at_mut(CELL_BYTES * cells);
        for (dst, &(cell, case)) in cell_bytes.chunks_exact_mut(CELL_BYTES).zip(&scratch.cells) {
            let c = cell.to_le_bytes();
            dst.copy_from_slice(&[c[0], c[1], case]);
        }
        let (params, rest) = rest.split_at_mut(4 * vertices);
        for (dst, &job) in params.chunks_exact_mut(4).zip(&scratch.jobs) {
            dst.copy_from_slice(&edge_parameter(&scratch.block, job).to_le_bytes());
        }
        let (normals, colors) = rest.split_at_mut(4 * vertices);
        for (dst, &n) in normals.chunks_exact_mut(4).zip(&mesh.normals) {
            let [u, v] = normal_code(n).map(i16::to_le_bytes);
            dst.copy_from_slice(&[u[0], u[1], v[0], v[1]]);
        }
        for (dst, c) in colors.chunks_exact_mut(3).zip(&mesh.colors) {
            dst.copy_from_slice(c);
        }
    }

    /// The chunk mesh of chunk `key` (voxels of `voxel_size` metres) into `out`: the mesh that
    /// was packed, bit for bit.
    pub(super) fn unpack(&self, key: ChunkKey, voxel_size: f32, unpacker: &mut Unpacker, out: &mut ChunkMesh) {
        out.clear();
        if self.is_empty() {
            return;
        }
        let (cells, vertices) = (self.cells(), self.vertices());
        let rest = &self.bytes[HEADER..Self::needed(cells, vertices)];
        let (cell_bytes, rest) = rest.split_at(CELL_BYTES * cells);
        unpacker.cells.clear();
        unpacker.cells.extend(cell_bytes.chunks_exact(CELL_BYTES).map(|c| (u16::from_le_bytes([c[0], c[1]]), c[2])));
        // The kept cells passed the seam test when they were packed.
        let (edges, jobs) = (&mut unpacker.edges, &mut unpacker.jobs);
        triangles_with(&mut unpacker.cells, self.triangles(), edges, jobs, out, |_, _| false);
        debug_assert_eq!(unpacker.jobs.len(), vertices);
        let f32_at = |b: &[u8]| f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        let (params, rest) = rest.split_at(4 * vertices);
        let (normals, colors) = rest.split_at(4 * vertices);
        let key_voxel = key * CHUNK_SIDE as i32;
        out.positions.extend(unpacker.jobs.iter().zip(params.chunks_exact(4)).map(|(&job, s)| {
            let (_, axis, low) = VertexJob::unpack(job);
            position_on_edge(key_voxel, low, axis, f32_at(s), voxel_size)
        }));
        out.normals.extend(
            normals
                .chunks_exact(4)
                .map(|n| normal_from_code([i16::from_le_bytes([n[0], n[1]]), i16::from_le_bytes([n[2], n[3]])])),
        );
        out.colors.extend(colors.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
    }

    /// Gives the buffer up (the chunk has no triangles now), returning its bytes.
    pub(super) fn release(&mut self) -> usize {
        std::mem::take(&mut self.bytes).len()
    }
}

/// A packed chunk mesh held by the assembly: owned (the live mesh handed over, freed as it is
/// copied) or borrowed.
pub(super) trait PackedStore {
    /// The packed mesh.
    fn packed(&self) -> &PackedChunkMesh;
    /// Frees it where owned; returns the heap bytes freed (0 where borrowed).
    fn release(&mut self) -> usize;
}

impl PackedStore for PackedChunkMesh {
    fn packed(&self) -> &PackedChunkMesh {
        self
    }
    fn release(&mut self) -> usize {
        PackedChunkMesh::release(self)
    }
}

impl PackedStore for &PackedChunkMesh {
    fn packed(&self) -> &PackedChunkMesh {
        self
    }
    fn release(&mut self) -> usize {
        0
    }
}
