//! `semrecon run`: the geometric pipeline on a dataset, frame by frame: a pose for every frame
//! (see [`estimate_pose`]), TSDF fusion, incremental meshing every keyframe; writes
//! `DIR/mesh.ply` (binary), `DIR/trajectory.txt` (TUM) and `DIR/report.json`, and prints a
//! timing table.
//!
//! With `--serve` the viewer of `semrecon view` follows the run live on 127.0.0.1: the mesh
//! and trajectory are pushed to it at keyframes (at most once per [`LIVE_PUSH_INTERVAL`] of
//! wall time, outside the timed pipeline stages), and the final result stays served until
//! Ctrl-C (or, with `--serve-exit`, the server stops when the run ends).
//!
//! Bad input never stops a run half-way: a frame that fails to load, has no pose or is
//! rejected by fusion is reported once, counted in `lost_frames`, and skipped, leaving the
//! map as it was. Only problems that make the whole run meaningless (a dataset that does not
//! open, an empty frame range, an unwritable output folder) are errors.

use std::ops::Range;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use semrecon_data::atomic_file::write_atomic;
use semrecon_data::datasets::{open_dataset, DatasetSpec};
use semrecon_data::{LabeledMesh, Trajectory};
use semrecon_eval::{evaluate_trajectory, TrajectoryEvalConfig};
use semrecon_viewer::{LiveScene, ViewerServer};
use serde::Serialize;

use crate::progress::progress_bar;
use crate::reconstruction::{PoseSource, ReconArgs, Reconstruction};

/// Warnings printed one by one before they are only counted.
const MAX_WARNINGS: usize = 10;

/// Shortest wall time between two pushes to the live viewer: building the whole mesh and
/// its collision geometry costs far more than a keyframe's incremental meshing.
pub const LIVE_PUSH_INTERVAL: Duration = Duration::from_secs(1);

/// Arguments of `semrecon run`.
#[derive(clap::Args)]
pub struct RunArgs {
    /// Dataset as KIND:PATH (7scenes:, tum:, redwood:, scannet:, replica:, synth:SEED).
    #[arg(long)]
    dataset: DatasetSpec,
    /// Frames to process as A..B (B excluded; either end may be left out): all by default.
    #[arg(long, value_parser = parse_frame_range)]
    frames: Option<FrameRange>,
    #[command(flatten)]
    recon: ReconArgs,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
    /// Show the growing map live in the viewer on 127.0.0.1 (open the printed URL), and
    /// keep serving the final result after the run until Ctrl-C.
    #[arg(long)]
    serve: bool,
    /// Port of the live viewer (a free port by default).
    #[arg(long, requires = "serve")]
    port: Option<u16>,
    /// Stop the live viewer when the run ends instead of serving on (for scripts and tests).
    #[arg(long, requires = "serve")]
    serve_exit: bool,
}

/// The live viewer of `--serve`.
struct LiveView {
    server: ViewerServer,
    scene: LiveScene,
    /// Fused frame count at the last push (the map has not changed while it is the same).
    pushed_at: Option<usize>,
    last_push: Option<Instant>,
}

impl LiveView {
    fn start(port: Option<u16>) -> anyhow::Result<Self> {
        let (server, scene) = ViewerServer::start_live(port).context("starting the live viewer")?;
        Ok(Self { server, scene, pushed_at: None, last_push: None })
    }

    /// Whether the map changed since the last push and the push interval has passed.
    fn due(&self, fused: usize) -> bool {
        self.pushed_at != Some(fused) && self.last_push.is_none_or(|t| t.elapsed() >= LIVE_PUSH_INTERVAL)
    }

    /// Shows `mesh` and `trajectory`; an empty mesh (nothing surfaced yet) is skipped.
    fn push(&mut self, fused: usize, mesh: &LabeledMesh, trajectory: &Trajectory) -> Result<(), String> {
        if mesh.triangles.is_empty() {
            return Ok(());
        }
        self.scene.update(mesh, trajectory).map_err(|e| format!("live viewer not updated: {e}"))?;
        self.pushed_at = Some(fused);
        self.last_push = Some(Instant::now());
        Ok(())
    }
}

/// A `--frames` value: `A..B`, `A..` or `..B`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameRange {
    start: usize,
    end: Option<usize>,
}

impl FrameRange {
    /// The frame indices of a source with `len` frames, or why there are none.
    fn resolve(self, len: usize) -> anyhow::Result<Range<usize>> {
        let end = self.end.unwrap_or(len).min(len);
        anyhow::ensure!(
            self.start < end,
            "frame range {}..{} selects no frame of a dataset with {len} frames",
            self.start,
            self.end.map(|e| e.to_string()).unwrap_or_default()
        );
        Ok(self.start..end)
    }
}

/// Parses `A..B`, `A..` or `..B` (clap value parser).
pub fn parse_frame_range(s: &str) -> Result<FrameRange, String> {
    let Some((a, b)) = s.split_once("..") else {
        return Err(format!("`{s}`: expected a frame range A..B (B excluded), e.g. 0..100"));
    };
    let number = |t: &str| -> Result<Option<usize>, String> {
        let t = t.trim();
        if t.is_empty() {
            Ok(None)
        } else {
            t.parse::<usize>().map(Some).map_err(|_| format!("`{s}`: `{t}` is not a frame number"))
        }
    };
    let (start, end) = (number(a)?.unwrap_or(0), number(b)?);
    if end.is_some_and(|e| e <= start) {
        return Err(format!("`{s}`: the range is empty (the end is excluded)"));
    }
    Ok(FrameRange { start, end })
}

#[derive(Serialize)]
struct StageJson {
    median_ms: f64,
    p95_ms: f64,
    max_ms: f64,
    count: usize,
}

#[derive(Serialize)]
struct Report {
    dataset: String,
    first_frame: usize,
    frames: usize,
    fused_frames: usize,
    lost_frames: usize,
    failed_loads: usize,
    voxel_size_m: f32,
    keyframe_every: usize,
    poses: &'static str,
    realtime_factor: f64,
    input_s: f64,
    pipeline_s: f64,
    wall_s: f64,
    stages: serde_json::Value,
    memory_mb: f64,
    chunks: usize,
    mesh_vertices: usize,
    mesh_triangles: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    ate_rmse_m: Option<f64>,
}

/// Runs the command.
pub fn run(args: RunArgs) -> anyhow::Result<()> {
    let source = open_dataset(&args.dataset).with_context(|| format!("opening {}", args.dataset))?;
    anyhow::ensure!(!source.is_empty(), "{} has no frames", source.name());
    let range = args.frames.unwrap_or(FrameRange { start: 0, end: None }).resolve(source.len())?;
    let mut recon = Reconstruction::new(args.recon.voxel, args.recon.truncation, args.recon.keyframe_every)?;
    let mut poses: Option<PoseSource> = None;
    let k = source.intrinsics();
    println!(
        "{}: frames {}..{} of {}, {}x{}, voxel {} m",
        source.name(),
        range.start,
        range.end,
        source.len(),
        k.width,
        k.height,
        args.recon.voxel
    );

    let mut live = match args.serve {
        true => {
            let live = LiveView::start(args.port)?;
            println!("live viewer at {} (follows the run; open it in a browser)", live.server.url());
            Some(live)
        }
        false => None,
    };

    let mut gt = Trajectory::default();
    let mut lost = 0usize;
    let mut failed_loads = 0usize;
    let mut warnings = 0usize;
    let bar = progress_bar(range.len() as u64, "run");
    let mut warn = |message: String| {
        warnings += 1;
        if warnings <= MAX_WARNINGS {
            bar.suspend(|| eprintln!("warning: {message}"));
        }
    };
    let start = Instant::now();
    for i in range.clone() {
        let t = Instant::now();
        let frame = match source.frame(i) {
            Ok(frame) => frame,
            Err(e) => {
                warn(format!("frame {i} skipped: {e}"));
                failed_loads += 1;
                lost += 1;
                bar.inc(1);
                continue;
            }
        };
        recon.times.record("loading", t.elapsed());
        if let Some(pose) = frame.world_from_camera {
            gt.push(frame.timestamp, pose);
        }

        let source_of_poses = match &mut poses {
            Some(p) => p,
            None => {
                poses.insert(PoseSource::new(args.recon.poses, frame.world_from_camera, args.recon.keyframe_every)?)
            }
        };
        let t = Instant::now();
        let pose = source_of_poses.estimate(&frame, &recon.map);
        recon.record_pipeline("tracking", t.elapsed());
        let pose = match pose {
            Ok(pose) => pose,
            Err(why) => {
                warn(format!("frame {i} skipped: {why}"));
                lost += 1;
                bar.inc(1);
                continue;
            }
        };
        if let Err(e) = recon.add_frame(&frame, pose) {
            warn(format!("frame {i} not fused: {e}"));
            lost += 1;
        }
        // Only at keyframes, where the incremental mesh was just brought up to date.
        let fused = recon.fused_frames();
        if let Some(live) =
            live.as_mut().filter(|l| fused > 0 && fused % args.recon.keyframe_every == 0 && l.due(fused))
        {
            let t = Instant::now();
            let mesh = recon.mesher.mesh();
            if let Err(why) = live.push(fused, &mesh, &recon.trajectory) {
                warn(why);
            }
            recon.times.record("live view", t.elapsed());
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let mesh = recon.finish();
    let wall_s = start.elapsed().as_secs_f64();
    if let Some(live) = live.as_mut() {
        if let Err(why) = live.push(recon.fused_frames(), &mesh, &recon.trajectory) {
            eprintln!("warning: {why}");
        }
    }
    if warnings > MAX_WARNINGS {
        eprintln!("warning: {} more warnings not shown", warnings - MAX_WARNINGS);
    }

    recon.write_outputs(&args.out, &mesh)?;
    let ate_rmse_m = if source.has_ground_truth() && !recon.trajectory.is_empty() {
        match evaluate_trajectory(&gt, &recon.trajectory, &TrajectoryEvalConfig::default()) {
            Ok(e) => Some(e.ate_rmse_m),
            Err(e) => {
                eprintln!("warning: no ATE: {e}");
                None
            }
        }
    } else {
        None
    };
    let input_s = range.len() as f64 / source.frame_rate();
    let report = Report {
        dataset: source.name(),
        first_frame: range.start,
        frames: range.len(),
        fused_frames: recon.fused_frames(),
        lost_frames: lost,
        failed_loads,
        voxel_size_m: args.recon.voxel,
        keyframe_every: args.recon.keyframe_every,
        poses: poses.as_ref().map_or("none", PoseSource::describe),
        realtime_factor: input_s / recon.pipeline_s.max(1e-9),
        input_s,
        pipeline_s: recon.pipeline_s,
        wall_s,
        stages: stages_json(&recon),
        memory_mb: recon.map.memory_bytes() as f64 / 1e6,
        chunks: recon.map.chunk_count(),
        mesh_vertices: mesh.vertex_count(),
        mesh_triangles: mesh.triangle_count(),
        ate_rmse_m,
    };
    write_atomic(&args.out.join("report.json"), serde_json::to_string_pretty(&report)?.as_bytes())?;

    println!();
    recon.times.print_table();
    println!();
    println!(
        "frames {} (fused {}, lost {}), poses: {}",
        report.frames, report.fused_frames, report.lost_frames, report.poses
    );
    println!(
        "pipeline (tracking + fusion + meshing): {:.2} s for {:.2} s of input, real-time factor {:.2} (wall {:.1} s with loading)",
        report.pipeline_s, input_s, report.realtime_factor, wall_s
    );
    println!(
        "map: {} chunks, {:.1} MB; mesh: {} vertices, {} triangles",
        report.chunks, report.memory_mb, report.mesh_vertices, report.mesh_triangles
    );
    if let Some(ate) = ate_rmse_m {
        println!("ATE rmse {:.4} m against the dataset's ground truth", ate);
    }
    println!("wrote {}/{{mesh.ply, trajectory.txt, report.json}}", args.out.display());
    if let Some(live) = live {
        if args.serve_exit {
            live.server.stop();
        } else {
            println!("live viewer serving the final result at {} (Ctrl-C to stop)", live.server.url());
            live.server.wait();
        }
    }
    Ok(())
}

/// `{stage: {median_ms, p95_ms, max_ms, count}}` with `tracking`, `fusion` and `meshing`
/// always present (zeros when a stage never ran), then the others (`loading`).
fn stages_json(recon: &Reconstruction) -> serde_json::Value {
    let summaries = recon.times.summaries();
    let mut map = serde_json::Map::new();
    let mut names: Vec<&str> = vec!["tracking", "fusion", "meshing"];
    names.extend(summaries.iter().map(|(n, _)| *n).filter(|n| !["tracking", "fusion", "meshing"].contains(n)));
    for name in names {
        let stage = summaries.iter().find(|(n, _)| *n == name).map(|(_, s)| s);
        let json = StageJson {
            median_ms: stage.map_or(0.0, |s| s.median_ms),
            p95_ms: stage.map_or(0.0, |s| s.p95_ms),
            max_ms: stage.map_or(0.0, |s| s.max_ms),
            count: stage.map_or(0, |s| s.count),
        };
        map.insert(name.to_string(), serde_json::to_value(json).unwrap_or_default());
    }
    serde_json::Value::Object(map)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_ranges_parse_and_resolve() {
        assert_eq!(parse_frame_range("0..100"), Ok(FrameRange { start: 0, end: Some(100) }));
        assert_eq!(parse_frame_range("5.."), Ok(FrameRange { start: 5, end: None }));
        assert_eq!(parse_frame_range("..7"), Ok(FrameRange { start: 0, end: Some(7) }));
        assert!(parse_frame_range("5..5").is_err());
        assert!(parse_frame_range("9..3").is_err());
        assert!(parse_frame_range("a..3").is_err());
        assert!(parse_frame_range("12").is_err());
        let r = parse_frame_range("10..1000").expect("valid");
        assert_eq!(r.resolve(300).expect("clamped"), 10..300);
        assert!(parse_frame_range("400..").expect("valid").resolve(300).is_err());
    }
}
