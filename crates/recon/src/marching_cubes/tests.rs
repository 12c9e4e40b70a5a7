//! Tests of marching cubes: the mesh of analytic surfaces, the fast paths against the scalar
//! definitions, the incremental mesher against meshing from scratch.

use super::assembly::{assemble_welded, drop_small_components};
use super::incremental::{pack_bytes, readers};
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
                VertexKernel::Avx512 => unsafe { avx512::vertices(&block, &jobs, key_voxel, voxel_size, &mut lanes) },
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
    assert_eq!(extract_mesh_with(&map, MeshConfig { min_weight: 0.5, ..MeshConfig::default() }).expect("valid"), full);
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
    assert!(!new_keys.is_empty() && 2 * urgent.len() < big.chunk_count(), "{} of {}", urgent.len(), big.chunk_count());
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

/// A shared vertex's compact local edge gives back the global key it stands for, for every
/// axis and every offset a chunk's cells reach, in chunks on either side of the origin.
#[test]
fn shared_vertex_edges_round_trip() {
    for key_voxel in [IVec3::ZERO, IVec3::new(-8, 16, -4000), IVec3::new(4000, -4000, 8)] {
        for axis in 0..3 {
            for low in [[0, 0, 0], [8, 0, 3], [1, 8, 8], [15, 15, 15]] {
                let v = SharedVertex::new(4095, axis, low);
                assert_eq!(v.key(key_voxel), (key_voxel + IVec3::from(low), axis as u8));
                assert_eq!(v.vertex, 4095);
            }
        }
    }
}

/// The one-pass assembly (welding and dropping small pieces on index arrays, the output
/// written at its size) equals welding everything and filtering afterwards, on noisy maps
/// with holes (many pieces of every size) and for minimums that keep all, some and none.
#[test]
fn assembly_matches_welding_then_filtering() {
    use rand::SeedableRng;
    let mut partly_dropped = 0;
    for (seed, holes) in [(1, 0), (2, 20), (3, 45)] {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let map = noisy_map(&mut rng, holes);
        let keys = map.sorted_keys();
        let meshes: Vec<ChunkMesh> = keys.iter().map(|&k| mesh_chunk(&map, k)).collect();
        let chunks: Vec<(ChunkKey, &ChunkMesh)> = keys.iter().copied().zip(&meshes).collect();
        let welded = assemble_welded(&chunks);
        assert!(!welded.triangles.is_empty());
        for min in [0, 1, 2, 3, 8, 50, 400, usize::MAX] {
            let mut want = welded.clone();
            drop_small_components(&mut want, min);
            let got = assemble(&chunks, min);
            assert!(got == want, "seed {seed}, holes {holes}%, min {min}");
            // Packed meshes owned by the assembly, freed as they are copied: the same mesh,
            // every byte reported.
            let owned: Vec<(ChunkKey, PackedChunkMesh)> = keys.iter().map(|&k| (k, packed_chunk(&map, k, 1))).collect();
            let heap: usize = owned.iter().map(|(_, m)| m.heap_bytes().0).sum();
            let mut reported = 0;
            let voxel_size = map.config().voxel_size;
            let took = assemble_from(PackedMeshes::new(owned, voxel_size), min, |bytes| reported += bytes);
            assert!(took == want, "packed: seed {seed}, holes {holes}%, min {min}");
            // (Index blocks freed on the way count too; these meshes fill none.)
            assert_eq!(reported, heap);
            partly_dropped += usize::from(!got.triangles.is_empty() && got.triangles.len() < welded.triangles.len());
            assert_eq!(got.positions.capacity(), got.positions.len());
            assert_eq!(got.triangles.capacity(), got.triangles.len());
        }
    }
    assert!(partly_dropped >= 3, "only {partly_dropped} cases drop some pieces and keep others");
}

/// Chunk `key` meshed and packed as the live mesh keeps it (empty without triangles).
fn packed_chunk(map: &TsdfMap, key: ChunkKey, min_weight: u16) -> PackedChunkMesh {
    let mut packed = PackedChunkMesh::default();
    remesh_into(map, key, min_weight, &mut Scratch::new(), &mut packed).unwrap_or(packed)
}

/// A packed chunk mesh unpacks to the chunk mesh, bit for bit, whichever vertex kernel made
/// it, on noisy maps with holes and seams; repacking into a buffer that fits leaves the same
/// bytes, and a buffer made for it fits.
#[test]
fn packed_chunk_meshes_unpack_bit_for_bit() {
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(23);
    let bits = |m: &ChunkMesh| {
        let b = |v: &[Vec3]| v.iter().map(|p| p.to_array().map(f32::to_bits)).collect::<Vec<_>>();
        (b(&m.positions), b(&m.normals))
    };
    let mut unpacker = Unpacker::new();
    let (mut vertices, mut packed_bytes, mut mesh_bytes) = (0, 0, 0);
    for holes in [0, 5, 30] {
        let map = noisy_map(&mut rng, holes);
        let voxel_size = map.config().voxel_size;
        for kernel in available_kernels() {
            let mut scratch = Scratch { kernel, ..Scratch::new() };
            for key in map.sorted_keys() {
                for min_weight in [1, 40] {
                    let want = mesh_chunk_configured(&map, key, min_weight, &mut scratch);
                    let mut packed = PackedChunkMesh::default();
                    if let Some(fresh) = remesh_into(&map, key, min_weight, &mut scratch, &mut packed) {
                        let mut sized = PackedChunkMesh::sized_for(fresh.heap_bytes().1);
                        assert!(sized.fits(fresh.heap_bytes().1));
                        sized.copy_from(&fresh);
                        packed = sized;
                    }
                    assert_eq!(packed.is_empty(), want.triangles.is_empty());
                    assert_eq!((packed.vertices(), packed.triangles()), (want.positions.len(), want.triangles.len()));
                    let mut got = ChunkMesh::default();
                    packed.unpack(key, voxel_size, &mut unpacker, &mut got);
                    assert_eq!(bits(&got), bits(&want), "chunk {key}, {kernel:?}");
                    assert_eq!(got, want, "chunk {key}, {kernel:?}");
                    // Re-meshing into the buffer that holds it changes nothing.
                    let before = packed.clone();
                    assert!(remesh_into(&map, key, min_weight, &mut scratch, &mut packed).is_none());
                    assert_eq!(packed, before);
                    vertices += want.positions.len();
                    packed_bytes += packed.heap_bytes().1;
                    mesh_bytes += want.heap_bytes().1;
                }
            }
        }
    }
    assert!(vertices > 3000, "{vertices} vertices");
    assert!(packed_bytes * 3 < mesh_bytes * 2, "packed {packed_bytes} bytes against {mesh_bytes}");
}

/// A normal's 32-bit code gives back, once rounded, the same code: packing a mesh's normals
/// keeps them exactly. Random directions, the axes, the octahedron's edges and folds, and
/// the zero normal; the rounding stays within 0.004 degrees.
#[test]
fn normal_codes_round_trip_and_stay_close() {
    use super::packed_mesh::{normal_code, normal_from_code, quantised_normal};
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let mut normals: Vec<Vec3> = (0..200_000)
        .map(|_| Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)))
        .filter(|v: &Vec3| v.length() > 1e-3)
        .map(Vec3::normalize)
        .collect();
    for a in [-1.0f32, -0.5, -0.0, 0.0, 0.5, 1.0] {
        for b in [-1.0f32, -0.5, -0.0, 0.0, 0.5, 1.0] {
            for c in [-1.0f32, -0.0, 0.0, 1.0] {
                normals.push(Vec3::new(a, b, c).normalize_or_zero());
            }
        }
    }
    let mut worst = 0.0f32;
    for n in normals {
        let q = quantised_normal(n);
        let code = normal_code(n);
        assert_eq!(normal_code(q), code, "{n}");
        assert_eq!(normal_from_code(code).to_array().map(f32::to_bits), q.to_array().map(f32::to_bits));
        if n == Vec3::ZERO {
            assert_eq!(q, Vec3::ZERO);
        } else {
            assert!((q.length() - 1.0).abs() < 1e-6);
            // The angle from the cross product: acos of a dot product near 1 is coarse in f32.
            assert!(n.dot(q) > 0.0);
            worst = worst.max(n.cross(q).length().asin().to_degrees());
        }
    }
    assert!(worst < 0.004, "worst {worst} degrees");
}
