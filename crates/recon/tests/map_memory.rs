//! Packed and spilled chunks: the map reads the same with and without them (voxels and mesh
//! bits, any thread count), and a spill file that cannot be written or read back is an
//! error, never lost data or a panic.

#[path = "common/scene.rs"]
mod scene;

use std::path::Path;

use glam::Affine3A;
use semrecon_data::{Intrinsics, LabeledMesh};
use semrecon_recon::{IncrementalMesher, ReconError, TsdfConfig, TsdfMap, Voxel};

fn small_camera() -> Intrinsics {
    Intrinsics::new(160, 120, 140.0, 140.0, 79.5, 59.5).expect("valid camera")
}

/// Forward along the test path, then back: the camera returns to chunks packed (and
/// spilled) meanwhile.
fn there_and_back(n: usize) -> Vec<Affine3A> {
    let mut poses = scene::trajectory(n);
    let back: Vec<Affine3A> = poses.iter().rev().copied().collect();
    poses.extend(back);
    poses
}

/// How a run manages memory.
#[derive(Clone, Copy)]
enum Memory<'a> {
    Plain,
    Packed,
    /// Packed, spilling past this budget into this file.
    Spilled(usize, &'a Path),
}

/// Fuses the path, meshing incrementally every 4 frames as the pipeline does at keyframes
/// and compacting every 2 frames; returns the voxels and the incremental mesh.
fn run(memory: Memory, threads: usize) -> (Vec<Vec<Voxel>>, LabeledMesh, TsdfMap) {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
    pool.install(|| {
        let config = TsdfConfig { voxel_size: 0.01, ..TsdfConfig::default() };
        let k = small_camera();
        let mut map = TsdfMap::new(config).expect("valid");
        if let Memory::Spilled(budget, path) = memory {
            map.set_memory_budget(budget, path).expect("spill file");
        }
        let mut mesher = IncrementalMesher::new();
        for (i, pose) in there_and_back(16).into_iter().enumerate() {
            map.integrate(&scene::render(k, pose, i), pose).expect("fusion");
            if i % 4 == 3 {
                mesher.update(&map);
            }
            if !matches!(memory, Memory::Plain) && i % 2 == 1 {
                map.compact(i as u32, 3);
            }
        }
        mesher.update(&map);
        let voxels = map.sorted_keys().iter().map(|&k| map.chunk(k).expect("allocated").voxels().collect()).collect();
        (voxels, mesher.mesh(), map)
    })
}

#[test]
fn packing_and_spilling_change_no_bit_for_any_thread_count() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (voxels, mesh, plain) = run(Memory::Plain, 1);
    assert!(mesh.triangle_count() > 1000);
    let (v, m, packed) = run(Memory::Packed, 2);
    assert!(v == voxels && m == mesh, "packed");
    let all = packed.memory();
    assert!(all.packed_chunks > 0, "{all:?}");
    // A budget a third of the plain map's: the coldest chunks go to disk and come back.
    let budget = plain.memory_bytes() / 3;
    for threads in [1, 2, 4] {
        let path = dir.path().join(format!("map-{threads}.spill"));
        let (v, m, spilled) = run(Memory::Spilled(budget, &path), threads);
        assert!(v == voxels && m == mesh, "spilled, {threads} threads");
        let mem = spilled.memory();
        assert!(spilled.spill_path().is_some_and(|p| p.exists()));
        assert!(mem.spilled_bytes > 0, "{threads} threads: {mem:?}");
    }
}

#[test]
fn a_budget_below_the_chunks_in_view_is_raised_with_a_warning() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut map = TsdfMap::new(TsdfConfig { voxel_size: 0.01, ..TsdfConfig::default() }).expect("valid");
    map.set_memory_budget(1000, &dir.path().join("map.spill")).expect("spill file");
    let pose = scene::trajectory(1)[0];
    map.integrate(&scene::render(small_camera(), pose, 0), pose).expect("fusion");
    let out = map.compact(0, 3);
    assert!(out.warnings.iter().any(|w| w.contains("raised")), "{:?}", out.warnings);
    let (asked, raised) = map.memory_budget().expect("budget set");
    assert_eq!(asked, 1000);
    assert!(raised.is_some_and(|r| r >= map.memory_bytes()), "{raised:?}");
}

#[test]
fn an_unwritable_spill_place_is_an_error_naming_the_file() {
    let mut map = TsdfMap::new(TsdfConfig::default()).expect("valid");
    let e = map.set_memory_budget(1, Path::new("/proc/semrecon-no-such/map.spill")).expect_err("cannot create");
    assert!(e.to_string().contains("/proc/semrecon-no-such/map.spill"), "{e}");
    assert!(map.memory_budget().is_none());
}

#[test]
fn a_damaged_spill_file_is_an_error_not_a_panic_and_the_map_is_kept() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("map.spill");
    let config = TsdfConfig { voxel_size: 0.01, ..TsdfConfig::default() };
    let mut map = TsdfMap::new(config).expect("valid");
    map.set_memory_budget(1, &path).expect("spill file");
    let poses = scene::trajectory(16);
    for (i, &pose) in poses.iter().enumerate().take(8) {
        map.integrate(&scene::render(small_camera(), pose, i), pose).expect("fusion");
    }
    // Everything quiet for long: all chunks spill (the budget of 1 byte is then raised).
    map.compact(1000, 3);
    assert!(map.memory().spilled_chunks > 0);
    let chunks = map.chunk_count();
    // Cut the file in half: reading back for the next frame fails with an error naming it.
    let bytes = std::fs::read(&path).expect("spill file");
    std::fs::write(&path, &bytes[..bytes.len() / 2]).expect("truncate");
    let pose = poses[0];
    let err = map.integrate(&scene::render(small_camera(), pose, 1001), pose).expect_err("damaged");
    assert!(matches!(err, ReconError::Spill(_)) && err.to_string().contains("map.spill"), "{err}");
    assert_eq!(map.chunk_count(), chunks, "no chunk lost");
    let err = map.restore_all().expect_err("damaged");
    assert!(err.to_string().contains("map.spill"), "{err}");
}
