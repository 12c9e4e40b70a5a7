//! Loop closure inside the live pipeline: a tracked synthetic scan that returns to its start
//! finds its loop, keeps the output bits for any thread count, and `enabled: false` keeps
//! the poses as tracked.

use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
use semrecon_data::{Frame, FrameSource, LabeledMesh};
use semrecon_pipeline::{Pipeline, PipelineConfig, PoseMode};

fn frames() -> Vec<Frame> {
    scan_frames(None)
}

/// The same scan through a sensor with an uncalibrated radial depth bias: tracking drifts,
/// so that the loop corrects the poses and the map follows.
fn drifting_frames() -> Vec<Frame> {
    scan_frames(Some(semrecon_data::sensor::SensorModel::kinect_uncalibrated()))
}

/// 300 frames (320x240) of the generated scan of seed 2, through `sensor` or the scan's own.
fn scan_frames(sensor: Option<semrecon_data::sensor::SensorModel>) -> Vec<Frame> {
    let mut config = SyntheticScanConfig::new(2);
    config.frames = 300;
    config.intrinsics = config.intrinsics.scaled(320, 240);
    if let Some(sensor) = sensor {
        config.sensor = sensor;
    }
    let (_room, scan) = synthetic_scan(&config).expect("scan");
    (0..scan.len()).map(|i| scan.frame(i).expect("frame")).collect()
}

fn config(loop_closure: bool) -> PipelineConfig {
    let mut c = PipelineConfig { poses: PoseMode::Track, keyframe_every: 10, ..PipelineConfig::default() };
    c.tsdf.voxel_size = 0.01;
    c.tsdf.truncation_voxels = 6.0;
    c.tracker.fine_stride = 1;
    c.loop_closure.enabled = loop_closure;
    c
}

fn run(frames: &[Frame], config: PipelineConfig) -> (Pipeline, LabeledMesh) {
    let mut p = Pipeline::new(config, frames[0].intrinsics, None).expect("pipeline");
    for f in frames {
        p.push_frame(f).expect("frame");
    }
    let mesh = p.finish().expect("finish");
    (p, mesh)
}

/// The same run on 1 and 2 threads.
fn run_on_1_and_2_threads(frames: &[Frame], config: &PipelineConfig) -> Vec<(Pipeline, LabeledMesh)> {
    [1, 2]
        .iter()
        .map(|&threads| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            pool.install(|| run(frames, config.clone()))
        })
        .collect()
}

/// The runs' trajectories and meshes are the same bits.
fn assert_same_bits(runs: &[(Pipeline, LabeledMesh)]) {
    for r in &runs[1..] {
        assert_eq!(runs[0].0.trajectory().poses, r.0.trajectory().poses);
        assert_eq!(runs[0].1.positions, r.1.positions);
        assert_eq!(runs[0].1.triangles, r.1.triangles);
    }
}

#[test]
fn a_returning_scan_finds_its_loop_with_the_same_bits_for_any_thread_count() {
    let frames = frames();
    let runs = run_on_1_and_2_threads(&frames, &config(true));
    let report = runs[0].0.loop_closure().expect("on");
    assert!(report.keyframes >= 30, "{} keyframes", report.keyframes);
    assert!(report.loops.iter().any(|l| l.accepted), "{:#?}", report.loops);
    assert_same_bits(&runs);
    assert!(runs[0].0.timings().summary("global pose optimisation").is_some());
    // Off: no report, and the trajectory is the tracked one. Live fusion groups far
    // surfaces alike with and without loop closure while no re-integration runs.
    let (off, _) = run(&frames[..60], config(false));
    assert!(off.loop_closure().is_none() && off.tracked_trajectory().is_none());
    let (on, _) = run(&frames[..60], config(true));
    assert_eq!(on.tracked_trajectory().expect("on").poses, on.trajectory().poses, "nothing to correct in 60 frames");
    assert_eq!(off.trajectory().poses, on.trajectory().poses);
}

/// Far surfaces grouped under loop closure (most of the room beyond 1 m here; a drifting
/// scan whose every loop is a correction the map follows at once): the held
/// group is flushed before a re-integration starts and frames fuse whole while it runs, with
/// the same bits for any thread count, and the run is the grouped run without loop closure
/// until the first correction.
#[test]
fn grouped_fusion_under_loop_closure_keeps_the_bits_for_any_thread_count() {
    let frames = drifting_frames();
    let grouped = |loop_closure: bool| {
        let mut c = config(loop_closure);
        c.tsdf.far_group_beyond_m = 1.0;
        // Every loop's small disagreement with the drifted poses is a correction the map
        // follows at once.
        c.loop_closure.follow_every = 1;
        c.loop_closure.min_loop_chi2 = 0.0;
        c.loop_closure.min_move = 1e-4;
        c.loop_closure.min_chunk_move_voxels = 0.05;
        c
    };
    let runs = run_on_1_and_2_threads(&frames, &grouped(true));
    let report = runs[0].0.loop_closure().expect("on");
    eprintln!(
        "grouped under loop closure: {} loops accepted, {} corrections, {} re-integrations, {} skipped",
        report.loops.iter().filter(|l| l.accepted).count(),
        report.corrections.len(),
        report.reintegrations.len(),
        report.skipped_reintegrations
    );
    assert!(!report.reintegrations.is_empty(), "no re-integration ran: the flush before one is not exercised");
    assert_same_bits(&runs);
    let (off, off_mesh) = run(&frames[..60], grouped(false));
    let (on, on_mesh) = run(&frames[..60], grouped(true));
    assert_eq!(on.tracked_trajectory().expect("on").poses, on.trajectory().poses, "nothing to correct in 60 frames");
    assert_eq!(off.trajectory().poses, on.trajectory().poses);
    assert_eq!(off_mesh.positions, on_mesh.positions);
}
