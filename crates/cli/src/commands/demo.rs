//! `semrecon demo`: the live pipeline on a built-in synthetic scene: a generated room, a
//! handheld scan rendered through the Kinect-like sensor model, camera tracking, TSDF fusion,
//! incremental meshing, and semantic labelling of the map in the back end at keyframes;
//! outputs written to a folder, the Table 5 timing table printed, and the result measured
//! against the ground truth (ATE, mesh accuracy, mIoU of the mesh's labels).
//!
//! With `--loop-closure` the pipeline closes loops (the generated scan returns to its start)
//! and the summary says what it found and how the ATE changed.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use semrecon_data::atomic_file::write_atomic;
use semrecon_data::datasets::{synthetic_scan, synthetic_scan_of, SyntheticScanConfig};
use semrecon_data::library::rooms::{generate_library_room_detailed, LibraryRoomConfig};
use semrecon_data::library::FurnitureLibrary;
use semrecon_data::{write_ply, FrameSource, PlyEncoding, Trajectory};
use semrecon_eval::{evaluate_mesh, evaluate_trajectory, MeshEvalConfig, TrajectoryEvalConfig};
use semrecon_pipeline::{FrameStatus, Pipeline};
use serde::Serialize;

use crate::map_report::MapMemoryReport;
use crate::process_memory::ProcessMemoryReport;
use crate::progress::{progress_bar, spinner};
use crate::reconstruction::{
    labelled_share, load_network, loop_closure_json, loop_closure_summary, pipeline_config, prepare_output_dir,
    semantic_score, spill_in, write_outputs, ReconArgs, SemanticArgs,
};
use crate::timing::{print_table, stages_json};

/// Arguments of `semrecon demo`.
#[derive(clap::Args)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "demo-out")]
    out: PathBuf,
    /// Seed of the synthetic room, scan and sensor noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Number of frames of the scan (30 per second).
    #[arg(long, default_value_t = 300)]
    frames: usize,
    /// Nod of the camera, degrees: the scan tilts up by this much and down by half of it
    /// about every 8 s, sweeping the walls from floor to ceiling as someone mapping a room
    /// does (0: a casual scan that looks level or down)
    #[arg(long, default_value_t = 0.0)]
    sweep: f32,
    #[command(flatten)]
    recon: ReconArgs,
    #[command(flatten)]
    semantics: SemanticArgs,
    #[command(flatten)]
    device: crate::device::DeviceArgs,
    /// Scan a home or office furnished with real modelled furniture (Debian's
    /// sweethome3d-furniture catalogues) instead of the built-in procedural room.
    #[arg(long)]
    library: bool,
    /// Skip measuring the mesh against the ground truth (saves a few seconds).
    #[arg(long)]
    no_mesh_eval: bool,
}

#[derive(Serialize)]
struct Report {
    scene: String,
    frames: usize,
    voxel_size_m: f32,
    poses: &'static str,
    lost_frames: usize,
    /// Fused frames whose pose relocalisation recovered after tracking failed.
    relocalised_frames: usize,
    /// Frames the tracker aligned again with colour because depth alone left them poorly
    /// conditioned (`--degenerate-photometric-weight`).
    colour_fallback_frames: usize,
    ate_rmse_m: Option<f64>,
    mesh_accuracy_mm: Option<f64>,
    mesh_completeness_mm: Option<f64>,
    /// Fraction of the room's true surface within 5 cm of the mesh (a 10 s scan sees part of
    /// the room, so this is well below 1 and completeness is large).
    mesh_recall_5cm: Option<f64>,
    /// Mean IoU of the mesh vertices' classes against the nearest ground-truth surface's.
    miou: Option<f64>,
    /// The same mean over the classes present in the scanned part of the room only (a class
    /// out of view scores 0 in `miou` once a vertex is predicted as it).
    miou_present_classes: Option<f64>,
    /// Per-class IoU (`null` for classes absent from both).
    class_iou: Option<Vec<Option<f64>>>,
    /// Vertex counts, `confusion[truth][predicted]`, in MISSION.md's class order.
    confusion: Option<Vec<Vec<u64>>>,
    network: String,
    semantic_passes: usize,
    /// [`semrecon_pipeline::Pipeline::relabelled_passes`].
    semantic_relabels: usize,
    labelled_vertices: f64,
    /// Angle between the estimated up direction and the true one, degrees.
    up_error_deg: Option<f32>,
    /// Loops tried and corrections, trajectory before and after (`null` without loop closure).
    loop_closure: serde_json::Value,
    realtime_factor: f64,
    stages: serde_json::Value,
    chunks: usize,
    memory_mb: f64,
    /// Where the map's bytes are, bytes per square metre of surface, the memory budget.
    map_memory: MapMemoryReport,
    /// The live mesh's store and the process's resident peak.
    process_memory: ProcessMemoryReport,
    mesh_vertices: usize,
    mesh_triangles: usize,
}

/// Runs the command.
pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    let command_start = Instant::now();
    anyhow::ensure!(args.frames > 0, "--frames must be at least 1");
    prepare_output_dir(&args.out)?;
    let mut config = pipeline_config(&args.recon, &args.semantics, false, None, true, false)?;
    spill_in(&mut config, &args.out);
    let mut scan_config = SyntheticScanConfig::new(args.seed);
    scan_config.frames = args.frames;
    scan_config.vertical_sweep_deg = args.sweep;
    let (room, scan, scene) = if args.library {
        let library = FurnitureLibrary::open_default()?;
        let furnished = generate_library_room_detailed(&LibraryRoomConfig::new(args.seed), &library)
            .with_context(|| format!("furnishing library room {}", args.seed))?;
        let (room, scan) = synthetic_scan_of(furnished.room, &scan_config)?;
        (room, scan, format!("furnished {} (library), seed {}", furnished.kind, args.seed))
    } else {
        let (room, scan) = synthetic_scan(&scan_config)?;
        let scene = format!("synthetic {} room, seed {}", room.style, args.seed);
        (room, scan, scene)
    };
    println!(
        "{scene}: {} triangles, {} frames {}x{}",
        room.mesh.triangle_count(),
        scan.len(),
        scan_config.intrinsics.width,
        scan_config.intrinsics.height
    );
    let (net, network) = load_network(&args.semantics, &args.device)?;
    println!("semantics: {network}");

    let mut pipeline = Pipeline::new(config, scan.intrinsics(), net)?;
    let mut sensor_times = semrecon_pipeline::StageTimes::default();
    let mut gt = Trajectory::default();
    let mut lost = 0;
    let mut tracking_log = crate::tracking_log::TrackingLog::default();
    let bar = progress_bar(scan.len() as u64, "scanning");
    let start = Instant::now();
    for i in 0..scan.len() {
        let t = Instant::now();
        let frame = scan.frame(i)?;
        sensor_times.record("sensor simulation", t.elapsed());
        let truth = frame.world_from_camera.context("synthetic frames carry their pose")?;
        gt.push(frame.timestamp, truth);
        let r = pipeline.push_frame(&frame)?;
        tracking_log.record(&r);
        if matches!(r.status, FrameStatus::Lost(_) | FrameStatus::NoPose) {
            lost += 1;
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let mesh = pipeline.finish()?;
    let wall = start.elapsed().as_secs_f64();

    let evaluating = spinner("writing the outputs and comparing with the ground truth");
    // The generated room is z up with its floor at z = 0 (its ground truth), whatever the
    // map's estimate says.
    let gravity = semrecon_data::MeshGravity { up: glam::Vec3::Z, floor_height: Some(0.0) };
    write_outputs(&args.out, &mesh, pipeline.trajectory(), Some(gravity))?;
    tracking_log.write(&args.out)?;
    write_ply(args.out.join("ground_truth.ply"), &room.mesh, PlyEncoding::BinaryLittleEndian)?;
    let mut times = pipeline.timings().clone();
    times.merge(&sensor_times);
    let ate_rmse_m =
        evaluate_trajectory(&gt, pipeline.trajectory(), &TrajectoryEvalConfig::default()).map(|e| e.ate_rmse_m).ok();
    let mesh_errors = if args.no_mesh_eval || mesh.triangles.is_empty() {
        None
    } else {
        let t = Instant::now();
        let config = MeshEvalConfig { sample_spacing_m: 0.005, ..MeshEvalConfig::default() };
        let errors = evaluate_mesh(&room.mesh, &mesh, &config).ok();
        times.record("mesh evaluation", t.elapsed());
        errors
    };
    let score = if pipeline.has_semantics() { semantic_score(&room.mesh, &mesh)? } else { None };

    let input_s = scan.len() as f64 / scan.frame_rate();
    let front_s = pipeline.front_end_seconds();
    let map = pipeline.map();
    let map_memory = MapMemoryReport::new(map, pipeline.map_memory(), &mesh);
    let report = Report {
        scene: scene.clone(),
        frames: scan.len(),
        voxel_size_m: args.recon.voxel,
        poses: args.recon.poses.describe(),
        lost_frames: lost,
        relocalised_frames: pipeline.relocalised_frames(),
        colour_fallback_frames: pipeline.colour_fallback_frames(),
        ate_rmse_m,
        mesh_accuracy_mm: mesh_errors.as_ref().map(|e| e.accuracy_mean_m * 1e3),
        mesh_completeness_mm: mesh_errors.as_ref().map(|e| e.completeness_mean_m * 1e3),
        mesh_recall_5cm: mesh_errors
            .as_ref()
            .and_then(|e| e.scores.iter().find(|t| (t.threshold_m - 0.05).abs() < 1e-6).map(|t| t.recall)),
        miou: score.as_ref().map(|s| s.0),
        miou_present_classes: score.as_ref().map(|s| s.1.miou_present()),
        class_iou: score.as_ref().map(|s| s.1.iou()),
        confusion: score.as_ref().map(|s| {
            let cm = &s.1;
            (0..cm.classes()).map(|t| (0..cm.classes()).map(|p| cm.count(t, p)).collect()).collect()
        }),
        network,
        semantic_passes: pipeline.semantic_passes().len(),
        semantic_relabels: pipeline.relabelled_passes(),
        labelled_vertices: labelled_share(&mesh),
        // The map frame is the world frame here (tracking starts at the first true pose).
        up_error_deg: pipeline.up().map(|u| u.angle_to_deg(glam::Vec3::Z)),
        loop_closure: loop_closure_json(&pipeline, Some(&gt)),
        realtime_factor: input_s / front_s.max(1e-9),
        stages: stages_json(&times),
        chunks: map.chunk_count(),
        memory_mb: map_memory.bytes_in_memory as f64 / 1e6,
        map_memory,
        process_memory: ProcessMemoryReport::new(pipeline.mesh_store_memory(), pipeline.semantic_map_bytes()),
        mesh_vertices: mesh.vertex_count(),
        mesh_triangles: mesh.triangle_count(),
    };
    write_atomic(&args.out.join("report.json"), serde_json::to_string_pretty(&report)?.as_bytes())?;
    evaluating.finish_and_clear();

    println!();
    print_table(&times);
    println!();
    println!(
        "front end (tracking + fusion + meshing, final included + semantic snapshot + waits for semantics): {:.2} s for {:.1} s of input, real-time factor {:.2}",
        front_s, input_s, report.realtime_factor
    );
    println!(
        "poses: {}; {} of {} frames lost, {} relocalised, {} aligned again with colour",
        report.poses, report.lost_frames, report.frames, report.relocalised_frames, report.colour_fallback_frames
    );
    let mm = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.1} mm"));
    println!(
        "against the ground truth: ATE {}, mesh accuracy {} (mean), {} of the room's surface seen (within 5 cm)",
        mm(report.ate_rmse_m.map(|m| m * 1e3)),
        mm(report.mesh_accuracy_mm),
        report.mesh_recall_5cm.map_or("n/a".to_string(), |r| format!("{:.0}%", r * 100.0))
    );
    println!(
        "semantics: mIoU {} over the mesh vertices ({} over the classes in view), {} passes{}, {:.0}% of vertices labelled, up {} off",
        report.miou.map_or("n/a".to_string(), |m| format!("{:.1}%", m * 100.0)),
        report.miou_present_classes.map_or("n/a".to_string(), |m| format!("{:.1}%", m * 100.0)),
        report.semantic_passes,
        match report.semantic_relabels {
            0 => String::new(),
            n => format!(" ({n} relabelling all after the up estimate moved)"),
        },
        report.labelled_vertices * 100.0,
        report.up_error_deg.map_or("n/a".to_string(), |d| format!("{d:.1} deg"))
    );
    println!(
        "wall time {wall:.1} s for the scan (includes rendering the synthetic input), {:.1} s in all with the evaluation and outputs",
        command_start.elapsed().as_secs_f64()
    );
    println!("mesh: {} vertices, {} triangles", report.mesh_vertices, report.mesh_triangles);
    println!("{}", report.map_memory.summary());
    println!("{}", report.process_memory.summary());
    println!("{}", loop_closure_summary(&report.loop_closure));
    for w in pipeline.warnings() {
        eprintln!("warning: {w}");
    }
    println!(
        "wrote {}/{{mesh.ply, semantic.ply, ground_truth.ply, trajectory.txt, tracking.csv, report.json}}",
        args.out.display()
    );
    Ok(())
}
