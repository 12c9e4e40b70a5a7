//! `semrecon demo`: the whole pipeline, as far as it is built, on a built-in synthetic scene:
//! a generated room, a handheld scan rendered through the Kinect-like sensor model, TSDF
//! fusion and incremental meshing; outputs written to a folder and a timing table printed.
//!
//! Camera tracking and semantic segmentation are not built yet: the demo fuses with the
//! ground-truth poses and says so in its table and report.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use semrecon_data::atomic_file::write_atomic;
use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
use semrecon_data::{write_ply, FrameSource, PlyEncoding};
use serde::Serialize;

use crate::progress::progress_bar;
use crate::reconstruction::Reconstruction;

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
    /// TSDF voxel size in metres.
    #[arg(long, default_value_t = 0.005)]
    voxel: f32,
    /// Re-mesh every this many frames (a keyframe).
    #[arg(long, default_value_t = 10)]
    keyframe_every: usize,
}

#[derive(Serialize)]
struct Report {
    scene: String,
    frames: usize,
    voxel_size_m: f32,
    poses: &'static str,
    not_built_yet: Vec<&'static str>,
    realtime_factor: f64,
    stages: serde_json::Value,
    chunks: usize,
    memory_mb: f64,
    mesh_vertices: usize,
    mesh_triangles: usize,
}

/// Runs the command.
pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.frames > 0, "--frames must be at least 1");
    anyhow::ensure!(args.keyframe_every > 0, "--keyframe-every must be at least 1");
    let mut config = SyntheticScanConfig::new(args.seed);
    config.frames = args.frames;
    let (room, scan) = synthetic_scan(&config)?;
    let scene = format!("synthetic {} room, seed {}", room.style, args.seed);
    println!("{scene}: {} triangles, {} frames {}x{}", room.mesh.triangle_count(), scan.len(), config.intrinsics.width, config.intrinsics.height);

    let mut recon = Reconstruction::new(args.voxel, args.keyframe_every)?;
    let bar = progress_bar(scan.len() as u64, "fusing");
    let start = Instant::now();
    for i in 0..scan.len() {
        let t = Instant::now();
        let frame = scan.frame(i)?;
        recon.times.record("sensor simulation", t.elapsed());
        let pose = frame.world_from_camera.context("synthetic frames carry their pose")?;
        recon.add_frame(&frame, pose)?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    let mesh = recon.finish();
    let wall = start.elapsed().as_secs_f64();

    recon.write_outputs(&args.out, &mesh)?;
    write_ply(args.out.join("ground_truth.ply"), &room.mesh, PlyEncoding::BinaryLittleEndian)?;
    let (map, times, pipeline_s) = (&recon.map, &recon.times, recon.pipeline_s);

    let input_s = scan.len() as f64 / scan.frame_rate();
    let report = Report {
        scene: scene.clone(),
        frames: scan.len(),
        voxel_size_m: args.voxel,
        poses: "ground truth (tracking not built yet)",
        not_built_yet: vec!["tracking", "global pose optimisation", "semantic segmentation"],
        realtime_factor: input_s / pipeline_s.max(1e-9),
        stages: times.to_json(),
        chunks: map.chunk_count(),
        memory_mb: map.memory_bytes() as f64 / 1e6,
        mesh_vertices: mesh.vertex_count(),
        mesh_triangles: mesh.triangle_count(),
    };
    write_atomic(&args.out.join("report.json"), serde_json::to_string_pretty(&report)?.as_bytes())?;

    println!();
    times.print_table();
    println!();
    println!("pipeline (fusion + meshing): {:.2} s for {:.1} s of input, real-time factor {:.2}", pipeline_s, input_s, report.realtime_factor);
    println!("total wall time {wall:.1} s (includes rendering the synthetic input)");
    println!("map: {} chunks, {:.0} MB; mesh: {} vertices, {} triangles", report.chunks, report.memory_mb, report.mesh_vertices, report.mesh_triangles);
    println!("not built yet: {}", report.not_built_yet.join(", "));
    println!("wrote {}/{{mesh.ply, ground_truth.ply, trajectory.txt, report.json}}", args.out.display());
    Ok(())
}
