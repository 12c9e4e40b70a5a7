//! Packed and spilled chunks: with exact packing the map reads the same with and without them
//! (voxels and mesh bits, any thread count); with the default coarse far distances, spilling
//! changes no bit of the packed map and packing moves only distances far from the surface;
//! a spill file that cannot be written or read back is an error, never lost data or a panic.

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
    run_with(memory, threads, 0.0)
}

/// [`run`] with packed distances in steps of `far_step` voxels beyond the exact band (0:
/// exact).
fn run_with(memory: Memory, threads: usize, far_step: f32) -> (Vec<Vec<Voxel>>, LabeledMesh, TsdfMap) {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
    pool.install(|| {
        let config = TsdfConfig { voxel_size: 0.01, packed_far_step_voxels: far_step, ..TsdfConfig::default() };
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
fn exact_packing_and_spilling_change_no_bit_for_any_thread_count() {
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
fn coarse_far_distances_move_only_far_voxels_and_spilling_adds_nothing() {
    let dir = tempfile::tempdir().expect("temp dir");
    let step = TsdfConfig::default().packed_far_step_voxels;
    assert!(step > 0.0, "the default packs far distances coarsely");
    let (plain, plain_mesh, map) = run_with(Memory::Plain, 1, step);
    let (packed, mesh, _) = run_with(Memory::Packed, 2, step);
    // Weights and colours are as fusion left them; a distance moved by at most a step (a
    // voxel packed far out and fused nearer since keeps what is left of its step), and only
    // where it was far from the surface when packed.
    let config = TsdfConfig { voxel_size: 0.01, ..TsdfConfig::default() };
    let unit = 1.0 / config.truncation_voxels; // one voxel in truncation units
    let mut moved = 0;
    for (a, b) in plain.iter().flatten().zip(packed.iter().flatten()) {
        assert_eq!((a.weight(), a.color()), (b.weight(), b.color()));
        assert!((a.tsdf() - b.tsdf()).abs() <= step * unit + 1e-4, "{} -> {}", a.tsdf(), b.tsdf());
        if a.tsdf() != b.tsdf() {
            moved += 1;
            assert!(a.tsdf().abs() > unit, "a voxel within a voxel of the surface moved: {}", a.tsdf());
        }
    }
    assert!(moved > 0, "no far distance moved");
    // The surface lies in the exact band; a crossing's far end may have moved a little.
    let (a, b) = (plain_mesh.triangle_count() as f64, mesh.triangle_count() as f64);
    assert!((a - b).abs() <= 0.01 * a, "{a} against {b} triangles");
    let budget = map.memory_bytes() / 3;
    for threads in [1, 2, 4] {
        let path = dir.path().join(format!("coarse-{threads}.spill"));
        let (v, m, spilled) = run_with(Memory::Spilled(budget, &path), threads, step);
        assert!(v == packed && m == mesh, "spilled, {threads} threads");
        assert!(spilled.memory().spilled_bytes > 0);
    }
}

/// Spilling every packed chunk (what the pipeline does at the end of a scan with a budget)
/// leaves only the plain chunks and the records in memory, and the map reads the same: its
/// voxels, and fusion and meshing that go on afterwards.
#[test]
fn spilling_every_packed_chunk_keeps_the_map_and_what_follows() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (voxels, mesh, mut map) = run(Memory::Spilled(usize::MAX, &dir.path().join("all.spill")), 2);
    let before = map.memory();
    assert!(before.packed_chunks > 0 && before.spilled_chunks == 0, "{before:?}");
    let out = map.spill_packed();
    let after = map.memory();
    assert_eq!(out.spilled, before.packed_chunks, "{out:?}");
    assert!(out.warnings.is_empty(), "{:?}", out.warnings);
    assert_eq!((after.packed_chunks, after.spilled_chunks), (0, before.packed_chunks), "{after:?}");
    assert_eq!(after.hot_chunks, before.hot_chunks);
    assert!(after.in_memory() < before.in_memory(), "{before:?} -> {after:?}");
    let read: Vec<Vec<Voxel>> =
        map.sorted_keys().iter().map(|&k| map.chunk(k).expect("allocated").voxels().collect()).collect();
    assert!(read == voxels);
    // A second call finds nothing left to move.
    assert_eq!(map.spill_packed().spilled, 0);
    // The scan goes on: fusion reads the spilled chunks it needs back, as after any spill.
    let mut plain = TsdfMap::new(*map.config()).expect("valid");
    let k = small_camera();
    let mut mesher = IncrementalMesher::new();
    for (i, pose) in there_and_back(16).into_iter().enumerate() {
        plain.integrate(&scene::render(k, pose, i), pose).expect("fusion");
    }
    let pose = scene::trajectory(3)[2];
    let frame = scene::render(k, pose, 99);
    plain.integrate(&frame, pose).expect("fusion");
    map.integrate(&frame, pose).expect("fusion after the spill");
    mesher.update(&map);
    let mut plain_mesher = IncrementalMesher::new();
    plain_mesher.update(&plain);
    assert!(mesher.mesh() == plain_mesher.mesh() && mesh.triangle_count() > 0);
}

/// Without a budget there is no spill file: nothing moves.
#[test]
fn spilling_without_a_budget_moves_nothing() {
    let (_, _, mut map) = run(Memory::Packed, 1);
    let before = map.memory();
    assert!(before.packed_chunks > 0);
    assert_eq!(map.spill_packed().spilled, 0);
    assert_eq!(map.memory(), before);
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
