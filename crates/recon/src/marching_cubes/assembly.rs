//! The whole mesh from chunk meshes: vertices on cell edges that neighbouring chunks share
//! are welded into one, and connected pieces with fewer triangles than a minimum (specks of
//! noise in free space) are left out.
//!
//! Both happen before the output is allocated, on index arrays alone (16 bytes a vertex),
//! and the output is then written once at its exact size. Welding the whole mesh first and
//! filtering it in place afterwards held the filter's arrays (18 bytes a vertex, with two
//! triangles a vertex) beside the whole mesh and the live mesh it came from: with the map
//! compacted before the assembly, a whole home's peak went from 3.46 to 3.27 GB (exact
//! chunk-mesh capacities; docs/benchmarks_log.md, "Session 29"). The output is the same:
//! the references `assemble_welded` and `drop_small_components` below, compiled for the
//! tests only.

use super::*;

/// Union-find root of `i`, with path halving.
fn root(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let grand = parent[parent[i as usize] as usize];
        parent[i as usize] = grand;
        i = grand;
    }
    i
}

/// Chunk meshes in assembly order, read one at a time and as often as the assembly needs:
/// whole (a fresh extraction) or packed (the live mesh, unpacked on the way).
pub(super) trait ChunkMeshes {
    /// How many chunks.
    fn count(&self) -> usize;
    /// Vertices of chunk `i` (without unpacking it).
    fn vertices(&self, i: usize) -> usize;
    /// Triangles of chunk `i` (without unpacking it).
    fn triangles(&self, i: usize) -> usize;
    /// Chunk `i`'s key and mesh.
    fn get(&mut self, i: usize) -> (ChunkKey, &ChunkMesh);
    /// Frees chunk `i`'s storage where this owns it; returns the heap bytes freed.
    fn release(&mut self, i: usize) -> usize;
}

impl ChunkMeshes for &[(ChunkKey, &ChunkMesh)] {
    fn count(&self) -> usize {
        self.len()
    }
    fn vertices(&self, i: usize) -> usize {
        self[i].1.positions.len()
    }
    fn triangles(&self, i: usize) -> usize {
        self[i].1.triangles.len()
    }
    fn get(&mut self, i: usize) -> (ChunkKey, &ChunkMesh) {
        self[i]
    }
    fn release(&mut self, _: usize) -> usize {
        0
    }
}

/// Packed chunk meshes (owned or borrowed, see [`PackedStore`]) unpacked one at a time.
pub(super) struct PackedMeshes<P> {
    meshes: Vec<(ChunkKey, P)>,
    voxel_size: f32,
    unpacker: Unpacker,
    current: ChunkMesh,
    /// The chunk in `current`.
    unpacked: Option<usize>,
}

impl<P: PackedStore> PackedMeshes<P> {
    /// The chunks `meshes` in assembly order, of a map with voxels of `voxel_size` metres.
    pub(super) fn new(meshes: Vec<(ChunkKey, P)>, voxel_size: f32) -> Self {
        Self { meshes, voxel_size, unpacker: Unpacker::new(), current: ChunkMesh::default(), unpacked: None }
    }
}

impl<P: PackedStore> ChunkMeshes for PackedMeshes<P> {
    fn count(&self) -> usize {
        self.meshes.len()
    }
    fn vertices(&self, i: usize) -> usize {
        self.meshes[i].1.packed().vertices()
    }
    fn triangles(&self, i: usize) -> usize {
        self.meshes[i].1.packed().triangles()
    }
    fn get(&mut self, i: usize) -> (ChunkKey, &ChunkMesh) {
        let (key, packed) = &self.meshes[i];
        if self.unpacked != Some(i) {
            packed.packed().unpack(*key, self.voxel_size, &mut self.unpacker, &mut self.current);
            self.unpacked = Some(i);
        }
        (*key, &self.current)
    }
    fn release(&mut self, i: usize) -> usize {
        self.meshes[i].1.release()
    }
}

/// Calls `f` with every chunk's triangles in order, each with the position of its chunk's
/// first vertex among all chunk vertices.
fn for_each_triangle(meshes: &mut impl ChunkMeshes, mut f: impl FnMut(usize, [u16; 3])) {
    let mut offset = 0;
    for i in 0..meshes.count() {
        let (_, m) = meshes.get(i);
        for &t in &m.triangles {
            f(offset, t);
        }
        offset += m.positions.len();
    }
}

/// Concatenates chunk meshes, each with its chunk's key, welding vertices on shared cell
/// edges, and drops the connected pieces (triangles joined through shared vertices) with
/// fewer than `min_triangles` triangles with the vertices only they use (0 or 1 keeps all).
/// Vertices keep the order in which the chunks first use them, triangles their chunk order.
pub(super) fn assemble(meshes: &[(ChunkKey, &ChunkMesh)], min_triangles: usize) -> LabeledMesh {
    assemble_from(meshes, min_triangles, |_| {})
}

/// [`assemble`] from any chunk meshes, freeing those it owns as soon as they are copied: the
/// whole mesh then grows as the chunk meshes go, instead of beside all of them (a whole
/// home's live mesh is most of a gigabyte). `freed(bytes)` is called after every
/// [`FREED_REPORT_BYTES`] or so of heap freed (chunk meshes, and the index entries of the
/// chunks written) and once at the end, with the bytes freed since the last call, for an
/// allocator that keeps freed memory until asked to return it.
pub(super) fn assemble_from(
    mut meshes: impl ChunkMeshes,
    min_triangles: usize,
    freed: impl FnMut(usize),
) -> LabeledMesh {
    let plan = AssemblyPlan::new(&mut meshes, min_triangles);
    plan.write(&mut meshes, freed)
}

/// Heap freed (chunk meshes and index blocks) between two reports of [`assemble_from`].
pub(super) const FREED_REPORT_BYTES: usize = 64 << 20;

/// A `u32` per chunk vertex (chunk vertices concatenated in chunk order), in blocks that the
/// writing pass frees behind it: a chunk's triangles use only its own vertices, so once a
/// chunk is written nothing reads the entries before it (a whole home has over 20 million
/// chunk vertices, 80 MB of index held beside the finished mesh otherwise).
struct ChunkVertexIndex {
    blocks: Vec<Vec<u32>>,
    len: usize,
    capacity: usize,
    /// Blocks already freed (the first ones).
    freed: usize,
}

/// Entries per [`ChunkVertexIndex`] block (4 MiB).
const INDEX_BLOCK: usize = 1 << 20;

impl ChunkVertexIndex {
    fn with_capacity(capacity: usize) -> Self {
        Self { blocks: Vec::with_capacity(capacity.div_ceil(INDEX_BLOCK)), len: 0, capacity, freed: 0 }
    }

    fn push(&mut self, value: u32) {
        if self.len.is_multiple_of(INDEX_BLOCK) {
            // The last block only as long as what is left of the capacity.
            let size = self.capacity.saturating_sub(self.len).clamp(1, INDEX_BLOCK);
            self.blocks.push(Vec::with_capacity(size));
        }
        if let Some(block) = self.blocks.last_mut() {
            block.push(value);
        }
        self.len += 1;
    }

    #[inline]
    fn get(&self, i: usize) -> u32 {
        self.blocks[i / INDEX_BLOCK][i % INDEX_BLOCK]
    }

    /// Replaces every entry `v` with `f(v)`.
    fn map_in_place(&mut self, f: impl Fn(u32) -> u32) {
        for v in self.blocks.iter_mut().flatten() {
            *v = f(*v);
        }
    }

    /// Frees the whole blocks before entry `i` not freed yet; returns the bytes freed.
    fn free_before(&mut self, i: usize) -> usize {
        let upto = (i / INDEX_BLOCK).max(self.freed);
        let bytes = self.blocks[self.freed..upto]
            .iter_mut()
            .map(|block| std::mem::take(block).capacity() * std::mem::size_of::<u32>())
            .sum();
        self.freed = upto;
        bytes
    }
}

/// Where every chunk vertex and triangle goes in the whole mesh: built from index arrays
/// alone, before the output is allocated.
struct AssemblyPlan {
    /// Every chunk vertex's output index (`u32::MAX`: dropped with a small piece). Output
    /// vertices are numbered in order of first use, so a chunk vertex adds one exactly where
    /// its index is the next one.
    out_index: ChunkVertexIndex,
    out_vertices: usize,
    out_triangles: usize,
}

impl AssemblyPlan {
    fn new(meshes: &mut impl ChunkMeshes, min_triangles: usize) -> Self {
        // Pass 1: every chunk vertex's welded index, new indices in order of first use.
        let chunk_vertices: usize = (0..meshes.count()).map(|i| meshes.vertices(i)).sum();
        let mut welded_index = ChunkVertexIndex::with_capacity(chunk_vertices);
        let mut vertices = 0u32;
        {
            let mut welded: HashMap<EdgeKey, u32, ChunkHashBuilder> = HashMap::default();
            for c in 0..meshes.count() {
                let (chunk, m) = meshes.get(c);
                let key_voxel = chunk * CHUNK_SIDE as i32;
                let mut shared = m.shared.iter().peekable();
                for i in 0..m.positions.len() {
                    if let Some(s) = shared.next_if(|s| usize::from(s.vertex) == i) {
                        let next = vertices;
                        let j = *welded.entry(s.key(key_voxel)).or_insert(next);
                        if j != next {
                            welded_index.push(j);
                            continue;
                        }
                    }
                    welded_index.push(vertices);
                    vertices += 1;
                }
            }
        }
        let global = |base: usize, t: [u16; 3], index: &ChunkVertexIndex| t.map(|v| index.get(base + usize::from(v)));

        // Pass 2: the pieces, and the output index of each kept vertex (`u32::MAX`: dropped),
        // with how many vertices and triangles are kept.
        let filtered: Option<(Vec<u32>, usize, usize)> = (min_triangles > 1)
            .then(|| {
                let mut parent: Vec<u32> = (0..vertices).collect();
                for_each_triangle(meshes, |base, t| {
                    let [a, b, c] = global(base, t, &welded_index);
                    let a = root(&mut parent, a);
                    for v in [b, c] {
                        let r = root(&mut parent, v);
                        if a != r {
                            parent[r as usize] = a;
                        }
                    }
                });
                // Triangles per piece, at the piece's root (0 elsewhere).
                let mut size = vec![0u32; vertices as usize];
                for_each_triangle(meshes, |base, t| {
                    let r = root(&mut parent, global(base, t, &welded_index)[0]);
                    size[r as usize] = size[r as usize].saturating_add(1);
                });
                if !size.iter().any(|&n| n > 0 && (n as usize) < min_triangles) {
                    return None;
                }
                // From here `parent` becomes each vertex's state, then its output index, so
                // that two index arrays live at a time, not three: `DROPPED` (its piece is
                // small), `UNUSED` (kept piece, no kept triangle yet), `USED`.
                const DROPPED: u32 = 0;
                const UNUSED: u32 = 1;
                const USED: u32 = 2;
                // Every vertex pointing at its root first (path halving never moves a vertex
                // that already does), then each reads only its own entry and `size`.
                for v in 0..vertices {
                    parent[v as usize] = root(&mut parent, v);
                }
                for p in parent.iter_mut() {
                    *p = if size[*p as usize] as usize >= min_triangles { UNUSED } else { DROPPED };
                }
                drop(size);
                let mut state = parent;
                let mut kept_triangles = 0;
                for_each_triangle(meshes, |base, t| {
                    let t = global(base, t, &welded_index);
                    // A triangle's vertices are all in its piece.
                    if state[t[0] as usize] != DROPPED {
                        kept_triangles += 1;
                        for v in t {
                            state[v as usize] = USED;
                        }
                    }
                });
                // Vertices used by kept triangles, numbered in order.
                let mut kept_vertices = 0;
                for s in state.iter_mut() {
                    if *s == USED {
                        *s = kept_vertices;
                        kept_vertices += 1;
                    } else {
                        *s = u32::MAX;
                    }
                }
                let (index, kept_vertices) = (state, kept_vertices as usize);
                Some((index, kept_vertices, kept_triangles))
            })
            .flatten();
        match filtered {
            Some((kept_index, out_vertices, out_triangles)) => {
                // One index array from here on, not two.
                let mut out_index = welded_index;
                out_index.map_in_place(|w| kept_index[w as usize]);
                Self { out_index, out_vertices, out_triangles }
            }
            None => Self {
                out_index: welded_index,
                out_vertices: vertices as usize,
                out_triangles: (0..meshes.count()).map(|i| meshes.triangles(i)).sum(),
            },
        }
    }

    /// Pass 3: the output at its exact size, from the chunk meshes in the plan's order, each
    /// released once its vertices and triangles are copied (see [`assemble_from`] for
    /// `freed`).
    fn write(self, meshes: &mut impl ChunkMeshes, mut freed: impl FnMut(usize)) -> LabeledMesh {
        let Self { mut out_index, out_vertices, out_triangles } = self;
        let mut out = LabeledMesh {
            positions: Vec::with_capacity(out_vertices),
            colors: Vec::with_capacity(out_vertices),
            normals: Vec::with_capacity(out_vertices),
            triangles: Vec::with_capacity(out_triangles),
            ..LabeledMesh::default()
        };
        // A chunk vertex adds an output vertex where its output index is the next one (kept
        // welded vertices are met for the first time in increasing order). A triangle's
        // vertices are all numbered by then: each is in its own chunk, met there or before.
        let mut chunk_vertex = 0;
        let mut freed_bytes = 0;
        for c in 0..meshes.count() {
            let (_, m) = meshes.get(c);
            for i in 0..m.positions.len() {
                if out_index.get(chunk_vertex + i) as usize == out.positions.len() {
                    out.positions.push(m.positions[i]);
                    out.colors.push(m.colors[i]);
                    out.normals.push(m.normals[i]);
                }
            }
            for t in &m.triangles {
                let t = t.map(|v| out_index.get(chunk_vertex + usize::from(v)));
                if t[0] != u32::MAX {
                    out.triangles.push(t);
                }
            }
            chunk_vertex += m.positions.len();
            freed_bytes += meshes.release(c) + out_index.free_before(chunk_vertex);
            if freed_bytes >= FREED_REPORT_BYTES {
                freed(freed_bytes);
                freed_bytes = 0;
            }
        }
        freed(freed_bytes);
        out
    }
}

/// The reference of [`assemble`]'s filter: drops the connected pieces of `mesh` (triangles joined through shared vertices) with
/// fewer than `min_triangles` triangles, and the vertices only they use; the rest keeps its
/// order. 0 or 1 changes nothing.
#[cfg(test)]
pub(super) fn drop_small_components(mesh: &mut LabeledMesh, min_triangles: usize) {
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

/// Concatenates chunk meshes, each with its chunk's key, welding vertices on shared cell edges
/// (the reference of [`assemble`] with `min_triangles` 0).
#[cfg(test)]
pub(super) fn assemble_welded(meshes: &[(ChunkKey, &ChunkMesh)]) -> LabeledMesh {
    let vertices: usize = meshes.iter().map(|m| m.1.positions.len()).sum();
    let triangles: usize = meshes.iter().map(|m| m.1.triangles.len()).sum();
    let mut out = LabeledMesh {
        positions: Vec::with_capacity(vertices),
        colors: Vec::with_capacity(vertices),
        normals: Vec::with_capacity(vertices),
        triangles: Vec::with_capacity(triangles),
        ..LabeledMesh::default()
    };
    let mut welded: HashMap<EdgeKey, u32, ChunkHashBuilder> = HashMap::default();
    let mut remap = Vec::new();
    for &(chunk, m) in meshes {
        remap.clear();
        let key_voxel = chunk * CHUNK_SIDE as i32;
        let mut shared = m.shared.iter().peekable();
        for i in 0..m.positions.len() {
            if let Some(s) = shared.next_if(|s| u32::from(s.vertex) == i as u32) {
                let key = s.key(key_voxel);
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
mod index_tests {
    use super::*;

    /// Entries read back across blocks; blocks freed once each, only whole ones behind the
    /// given entry, the bytes counted once; entries after it still read.
    #[test]
    fn the_chunk_vertex_index_frees_whole_blocks_behind_it_once() {
        let n = 2 * INDEX_BLOCK + 5;
        let mut index = ChunkVertexIndex::with_capacity(n);
        for v in 0..n as u32 {
            index.push(v ^ 0x5a5a);
        }
        index.map_in_place(|v| v ^ 0x5a5a);
        assert_eq!(index.get(INDEX_BLOCK + 7), (INDEX_BLOCK + 7) as u32);
        assert_eq!(index.free_before(INDEX_BLOCK - 1), 0);
        assert_eq!(index.free_before(INDEX_BLOCK + 3), 4 * INDEX_BLOCK);
        assert_eq!(index.free_before(INDEX_BLOCK + 9), 0, "a block is freed once");
        assert_eq!(index.get(INDEX_BLOCK + 3), (INDEX_BLOCK + 3) as u32);
        assert_eq!(index.free_before(n), 4 * INDEX_BLOCK);
        assert_eq!(index.get(n - 1), (n - 1) as u32, "the last, partial block stays");
        assert_eq!(index.blocks[2].capacity(), 5, "the last block as long as the capacity left");
    }
}
