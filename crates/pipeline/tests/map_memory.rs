//! The map's memory settings change no output bit: with exact packing, packing cold chunks and
//! spilling them past a budget give the same trajectory (tracking ray-casts the map), labelled
//! mesh and labels as a plain map, for 1, 2 and 4 threads; with the default coarse far
//! distances, spilling gives the same outputs as packing alone for any thread count; a spill
//! file that cannot be made stops the pipeline before any frame.

use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
use semrecon_data::{Frame, FrameSource, LabeledMesh};
use semrecon_net::{NetConfig, Segmenter, Weights};
use semrecon_pipeline::{MapMemoryConfig, Pipeline, PipelineConfig, PoseMode};

/// Every third frame of a `3 n`-frame scan at 160x120: the camera moves on far enough for
/// chunks to go quiet and spill.
fn frames(seed: u64, n: usize) -> Vec<Frame> {
    let mut config = SyntheticScanConfig::new(seed);
    config.frames = 3 * n;
    config.intrinsics = config.intrinsics.scaled(160, 120);
    let (_room, scan) = synthetic_scan(&config).expect("scan");
    (0..scan.len()).step_by(3).map(|i| scan.frame(i).expect("frame")).collect()
}

fn config(memory: MapMemoryConfig) -> PipelineConfig {
    config_with(memory, 0.0)
}

/// [`config`] with packed distances in steps of `far_step` voxels far from the surface (0:
/// exact).
fn config_with(memory: MapMemoryConfig, far_step: f32) -> PipelineConfig {
    let mut c = PipelineConfig { poses: PoseMode::Track, keyframe_every: 5, memory, ..PipelineConfig::default() };
    c.tsdf.packed_far_step_voxels = far_step;
    c.tsdf.voxel_size = 0.02;
    c.tsdf.truncation_voxels = 4.0;
    c.tracker.fine_stride = 1;
    // Meshing lags behind fusion: chunks wait while their neighbours go cold.
    c.mesh_budget = std::num::NonZeroUsize::new(16);
    c
}

type Outputs = (LabeledMesh, Vec<(glam::IVec3, u8)>, Vec<glam::Affine3A>, semrecon_recon::MapMemory);

fn run(frames: &[Frame], memory: MapMemoryConfig, threads: usize) -> Outputs {
    run_with(frames, memory, threads, 0.0)
}

fn run_with(frames: &[Frame], memory: MapMemoryConfig, threads: usize, far_step: f32) -> Outputs {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
    pool.install(|| {
        let c = NetConfig::new("tiny", 3, 8, 0.05);
        let net = Segmenter::new(Weights::random(&c, 9), c).expect("net");
        let mut p = Pipeline::new(config_with(memory, far_step), frames[0].intrinsics, Some(net)).expect("pipeline");
        for f in frames {
            p.push_frame(f).expect("frame");
        }
        let mesh = p.finish().expect("finish");
        let poses = p.trajectory().poses.clone();
        (mesh, p.cell_labels(), poses, p.map().memory())
    })
}

#[test]
fn exact_packing_and_spilling_change_no_output_bit() {
    let frames = frames(11, 40);
    let plain = MapMemoryConfig { cold_after_frames: 0, ..MapMemoryConfig::default() };
    let (mesh, labels, poses, memory) = run(&frames, plain, 2);
    assert_eq!(memory.packed_chunks, 0);
    assert!(mesh.triangle_count() > 500);
    let dir = tempfile::tempdir().expect("temp dir");
    for (threads, budget) in [(1, None), (2, Some(memory.in_memory() / 4)), (4, Some(memory.in_memory() / 4))] {
        let memory = MapMemoryConfig {
            cold_after_frames: 3,
            compact_every: 1,
            budget_bytes: budget,
            spill_path: Some(dir.path().join(format!("{threads}.spill"))),
        };
        let (m, l, p, after) = run(&frames, memory, threads);
        let what = format!("{threads} threads, budget {budget:?}");
        assert!(after.packed_chunks + after.spilled_chunks > 0, "{what}: {after:?}");
        if budget.is_some() {
            // `finish` sent every packed chunk to the spill file.
            assert!(after.spilled_chunks > 0 && after.packed_chunks == 0, "{what}: {after:?}");
        }
        assert_eq!(p, poses, "{what}: trajectory");
        assert_eq!(m, mesh, "{what}: labelled mesh");
        assert_eq!(l, labels, "{what}: cell labels");
    }
}

#[test]
fn with_coarse_far_distances_spilling_changes_no_output_bit() {
    let frames = frames(11, 40);
    let step = semrecon_recon::TsdfConfig::default().packed_far_step_voxels;
    let packed = MapMemoryConfig { cold_after_frames: 3, compact_every: 1, ..MapMemoryConfig::default() };
    let (mesh, labels, poses, memory) = run_with(&frames, packed.clone(), 1, step);
    assert!(memory.packed_chunks > 0, "{memory:?}");
    let dir = tempfile::tempdir().expect("temp dir");
    for threads in [2, 4] {
        let spilling = MapMemoryConfig {
            budget_bytes: Some(memory.in_memory() / 4),
            spill_path: Some(dir.path().join(format!("{threads}.spill"))),
            ..packed.clone()
        };
        let (m, l, p, after) = run_with(&frames, spilling, threads, step);
        assert!(after.spilled_chunks > 0, "{threads} threads: {after:?}");
        assert_eq!(p, poses, "{threads} threads: trajectory");
        assert!(m == mesh, "{threads} threads: labelled mesh");
        assert_eq!(l, labels, "{threads} threads: cell labels");
    }
}

#[test]
fn an_unwritable_spill_file_stops_the_pipeline_before_any_frame() {
    let dir = tempfile::tempdir().expect("temp dir");
    let taken = dir.path().join("taken.spill");
    std::fs::write(&taken, b"someone's file").expect("write");
    let memory = MapMemoryConfig { budget_bytes: Some(1 << 20), spill_path: Some(taken.clone()), ..Default::default() };
    let k = frames(11, 1)[0].intrinsics;
    let e = Pipeline::new(config(memory), k, None).expect_err("the spill file exists");
    assert!(e.to_string().contains("taken.spill"), "{e}");
    assert_eq!(std::fs::read(&taken).expect("read"), b"someone's file", "not overwritten");
}
