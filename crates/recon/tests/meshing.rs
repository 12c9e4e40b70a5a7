//! Incremental meshing with a remesh tolerance against a full re-mesh: the bound that
//! `RemeshTolerance` documents (same triangles chunk by chunk, every vertex on the same cell
//! edge within `tolerance / |d_a - d_b|` voxels of the full re-mesh's, at most one voxel),
//! also with a minimum meshing weight (`MeshConfig`), where exact mode equals
//! `extract_mesh_with`.

#[path = "common/scene.rs"]
mod scene;
#[path = "common/seven_scenes.rs"]
mod seven_scenes;

use glam::{IVec3, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use semrecon_data::{Frame, Intrinsics};
use semrecon_recon::{
    extract_mesh, extract_mesh_with, mesh_chunk_with, IncrementalMesher, MeshConfig, RemeshTolerance, TsdfConfig,
    TsdfMap,
};

/// Whether chunk `key`'s cells have a crossed edge whose jump is within twice `tolerance`
/// voxels of the seam limit (1.5 narrowest bands, at most one truncation; each end may be
/// `tolerance` off): the documented exception. Voxels lighter than `min_weight` are unobserved.
fn has_seam_edge(map: &TsdfMap, key: IVec3, tolerance: f32, min_weight: f32) -> bool {
    let c = map.config();
    let tv = c.truncation_voxels;
    let limit = (1.5 * c.narrowest_band_voxels()).min(tv);
    let base = key * 8;
    // Cells reach one voxel into the upper neighbours: edges start at local 0 ..= 8.
    (0..729).any(|i| {
        let v = base + IVec3::new(i % 9, (i / 9) % 9, i / 81);
        (0..3).any(|axis| {
            let mut w = v;
            w[axis] += 1;
            match (map.voxel(v), map.voxel(w)) {
                (Some(a), Some(b))
                    if [a, b].iter().all(|v| v.is_observed() && v.weight() >= min_weight)
                        && (a.tsdf() < 0.0) != (b.tsdf() < 0.0) =>
                {
                    ((a.tsdf() - b.tsdf()).abs() * tv - limit).abs() <= 2.0 * tolerance + 1e-3
                }
                _ => false,
            }
        })
    })
}

/// Checks the documented bound for every chunk; returns the largest vertex offset in voxels
/// and the number of chunks whose topology differs by the seam exception.
fn check_bound(map: &TsdfMap, mesher: &IncrementalMesher, context: &str) -> (f32, usize) {
    let tolerance = mesher.tolerance().distance_voxels;
    let config = mesher.config();
    let vs = map.config().voxel_size;
    let tv = map.config().truncation_voxels;
    let distance = |v: IVec3| map.voxel(v).map(|x| x.tsdf() * tv).expect("edge ends are allocated");
    let (mut worst, mut seams) = (0.0f32, 0);
    for key in map.sorted_keys() {
        let full = mesh_chunk_with(map, key, config).expect("valid config");
        let cached = mesher.chunk_mesh(key).expect("every chunk is cached");
        if cached.triangles != full.triangles {
            assert!(
                has_seam_edge(map, key, tolerance, config.min_weight),
                "{context}: chunk {key} topology differs off the seams"
            );
            seams += 1;
            continue;
        }
        assert_eq!(cached.positions.len(), full.positions.len());
        for (a, b) in cached.positions.iter().zip(&full.positions) {
            let d = (*a - *b) / vs;
            if d == Vec3::ZERO {
                continue;
            }
            let axis = d.abs().max_position();
            // Only the coordinate along the edge differs (the others are the same voxel's).
            for q in (0..3).filter(|&q| q != axis) {
                assert_eq!(d[q], 0.0, "{context}: vertex {a} vs {b} not on one edge");
            }
            let mid = (*a + *b) * (0.5 / vs);
            let mut low = mid.round().as_ivec3();
            low[axis] = mid[axis].floor() as i32;
            let mut high = low;
            high[axis] += 1;
            let jump = (distance(low) - distance(high)).abs();
            let bound = (tolerance / jump).min(1.0);
            assert!(
                d[axis].abs() <= bound + 1e-3,
                "{context}: vertex {a} is {} voxels from the full re-mesh's {b}, bound {bound} (jump {jump})",
                d[axis].abs()
            );
            worst = worst.max(d[axis].abs());
        }
    }
    (worst, seams)
}

/// Ray-cast depth with seeded noise of up to `2 a` metres (sum of two uniforms).
fn noisy(k: Intrinsics, pose: glam::Affine3A, index: usize, a: f32, rng: &mut ChaCha8Rng) -> Frame {
    let mut f = scene::render(k, pose, index);
    for d in f.depth.iter_mut().filter(|d| **d > 0.0) {
        *d += rng.random_range(-a..a) + rng.random_range(-a..a);
    }
    f
}

#[test]
fn tolerant_incremental_mesh_stays_within_its_bound_of_a_full_remesh() {
    let k = Intrinsics::new(160, 120, 140.0, 140.0, 79.5, 59.5).expect("valid camera");
    let config = TsdfConfig { voxel_size: 0.01, ..TsdfConfig::default() };
    let mut map = TsdfMap::new(config).expect("valid");
    let tolerance = RemeshTolerance { distance_voxels: 0.25 };
    let mut tolerant = IncrementalMesher::with_tolerance(tolerance).expect("valid");
    let mut exact = IncrementalMesher::new();
    // With a threshold that hides the voxels seen only a few times (depths 1-2.5 m: one
    // observation weighs 0.16-1), and without small pieces.
    let heavy = MeshConfig { min_weight: 1.0, min_component_triangles: 20 };
    let mut heavy_exact = IncrementalMesher::with_config(heavy, RemeshTolerance::EXACT).expect("valid");
    let mut heavy_tolerant = IncrementalMesher::with_config(heavy, tolerance).expect("valid");
    let (mut heavy_fewer, mut heavy_worst) = (0, 0.0f32);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    // A camera dwelling on three views: the weights saturate, as on a long scan. Noisy
    // frames first, then nearly clean ones, which move converged voxels by little.
    let poses = scene::trajectory(3);
    let (mut tolerant_work, mut exact_work, mut worst, mut seams, mut checked) = (0, 0, 0.0f32, 0, 0);
    for i in 0..48 {
        let pose = poses[(i / 4) % 3];
        let noise = if i < 12 { 0.002 } else { 0.0002 };
        map.integrate(&noisy(k, pose, i, noise, &mut rng), pose).expect("fusion");
        if i % 4 == 3 {
            tolerant_work += tolerant.update(&map).remeshed_chunks;
            exact_work += exact.update(&map).remeshed_chunks;
            let (w, s) = check_bound(&map, &tolerant, &format!("after frame {i}"));
            (worst, seams, checked) = (worst.max(w), seams + s, checked + map.chunk_count());
            assert_eq!(exact.mesh(), extract_mesh(&map), "exact mode after frame {i}");
            heavy_exact.update(&map);
            heavy_tolerant.update(&map);
            let heavy_mesh = heavy_exact.mesh();
            assert_eq!(heavy_mesh, extract_mesh_with(&map, heavy).expect("valid"), "thresholded, frame {i}");
            heavy_fewer += (heavy_mesh.triangle_count() < exact.mesh().triangle_count()) as usize;
            let (w, s) = check_bound(&map, &heavy_tolerant, &format!("thresholded, after frame {i}"));
            (heavy_worst, seams, checked) = (heavy_worst.max(w), seams + s, checked + map.chunk_count());
        }
    }
    println!(
        "re-meshed {tolerant_work} chunks (exact {exact_work}); worst vertex offset {worst:.3} voxels; \
         {seams} of {checked} chunk meshes differ at seams"
    );
    assert!(seams * 100 < checked, "seam differences are rare");
    assert!(tolerant_work < exact_work, "the tolerance saves work: {tolerant_work} vs {exact_work}");
    assert!(worst > 0.0 && heavy_worst > 0.0, "stale meshes were kept and checked");
    assert_eq!(heavy_fewer, 12, "the threshold hides voxels after every update");
    assert!(tolerant.snapshot_bytes() > 0);
    assert!(RemeshTolerance { distance_voxels: 1.5 }.validate().is_err());
    assert!(IncrementalMesher::with_tolerance(RemeshTolerance { distance_voxels: f32::NAN }).is_err());
}

#[test]
fn tolerant_incremental_mesh_of_real_frames_stays_within_its_bound() {
    let Some(dir) = seven_scenes::redkitchen() else {
        println!("skipping: ../shared/data not found");
        return;
    };
    let config = TsdfConfig { voxel_size: 0.01, ..TsdfConfig::default() };
    let mut map = TsdfMap::new(config).expect("valid");
    let mut mesher = IncrementalMesher::with_tolerance(RemeshTolerance::NOISE).expect("valid");
    for i in 0..16 {
        let (frame, pose) = seven_scenes::read_frame(&dir, i * 2).expect("7-Scenes frame");
        map.integrate(&frame, pose).expect("fusion");
        if i % 4 == 3 {
            mesher.update(&map);
            let (_, seams) = check_bound(&map, &mesher, &format!("after frame {}", i * 2));
            assert!(seams * 100 < map.chunk_count(), "{seams} seam differences");
        }
    }
    mesher.mesh().validate().expect("valid mesh");
}

#[test]
fn taking_the_mesh_gives_the_same_mesh_and_empties_the_cache() {
    let k = Intrinsics::new(160, 120, 140.0, 140.0, 79.5, 59.5).expect("valid camera");
    let config = TsdfConfig { voxel_size: 0.01, ..TsdfConfig::default() };
    let mut map = TsdfMap::new(config).expect("valid");
    let heavy = MeshConfig { min_weight: 1.0, min_component_triangles: 20 };
    let budget = std::num::NonZeroUsize::new(40);
    let mut mesher = IncrementalMesher::with_config(heavy, RemeshTolerance { distance_voxels: 0.25 })
        .expect("valid")
        .with_budget(budget);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let poses = scene::trajectory(3);
    for i in 0..12 {
        let pose = poses[i % 3];
        map.integrate(&noisy(k, pose, i, 0.002, &mut rng), pose).expect("fusion");
        mesher.update(&map);
    }
    mesher.update_all(&map);
    let want = mesher.mesh();
    assert!(want.triangle_count() > 1000, "a surface to take");
    let generation = mesher.generation();
    let mut freed = 0;
    let took = mesher.take_mesh(|bytes| freed += bytes);
    assert!(took == want, "the taken mesh is the cache's mesh");
    assert!(freed > 0, "the chunk meshes' bytes are reported");
    assert_eq!((mesher.chunk_count(), mesher.memory().mesh_bytes), (0, 0), "the cache is empty");
    assert_eq!((mesher.budget(), mesher.config(), mesher.generation()), (budget, heavy, generation));
    // The next update meshes the whole map again, every chunk newer than before.
    mesher.update_all(&map);
    assert_eq!(mesher.remeshed_since(generation).count(), mesher.chunk_count());
    assert_eq!(mesher.mesh(), extract_mesh_with(&map, heavy).expect("valid"), "meshed afresh");
}
