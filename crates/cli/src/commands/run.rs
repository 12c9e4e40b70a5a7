//! `semrecon run`: the live pipeline on a dataset, frame by frame: a pose for every frame
//! (tracking, or the dataset's ground truth), TSDF fusion, incremental meshing and a semantic
//! pass of the back end at every keyframe; writes `DIR/mesh.ply` (binary, with a vertex
//! `label`), `DIR/semantic.ply` (class colours), `DIR/trajectory.txt` (TUM),
//! `DIR/tracking.csv` (what the tracker measured of each frame) and `DIR/report.json`, and prints the timing table in the layout of the paper's Table 5.
//!
//! With `--realtime` frames are fed at their capture rate (their timestamps): the front end
//! never drops a frame, but it may fall behind (the report says by how much), and semantic
//! passes run on the freshest map, skipping keyframes while the back end is busy.
//!
//! The up direction for the network is estimated from the map, or read from a
//! `gravity-direction.txt` in a 7-Scenes folder (the direction of gravity in the poses' world
//! frame) when the run starts at the dataset's ground-truth pose.
//!
//! With `--serve` the viewer of `semrecon view` follows the run live on 127.0.0.1: the mesh
//! and trajectory are pushed to it at keyframes (at most once per
//! [`LIVE_PUSH_INTERVAL`](crate::live_view::LIVE_PUSH_INTERVAL) of
//! wall time, outside the timed pipeline stages), and the final result stays served until
//! Ctrl-C (or, with `--serve-exit`, the server stops when the run ends).
//!
//! Bad input never stops a run half-way: a frame that fails to load, has no pose or is
//! rejected by fusion is reported once, counted in `lost_frames`, and skipped, leaving the
//! map as it was; after [`MAX_CONSECUTIVE_FAILED_LOADS`] failed loads in a row the dataset is
//! taken to have ended early and the run stops there, writing its outputs. Only problems that
//! make the whole run meaningless (a dataset that does not open, an empty frame range, an
//! unwritable output folder) are errors.

use std::ops::Range;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use semrecon_data::atomic_file::write_atomic;
use semrecon_data::datasets::{open_dataset, DatasetSpec};
use semrecon_data::Trajectory;
use semrecon_eval::{evaluate_trajectory, TrajectoryEvalConfig};
use semrecon_pipeline::{FrameStatus, Pipeline, UpEstimate};
use serde::Serialize;

use crate::live_view::{LiveView, ServeArgs};
use crate::map_report::MapMemoryReport;
use crate::process_memory::ProcessMemoryReport;
use crate::progress::progress_bar;
use crate::reconstruction::{
    aligned_vertex_accuracy_mm, dataset_up, finish_session, labelled_share, load_network, loop_closure_json,
    loop_closure_summary, pipeline_config, prepare_output_dir, semantic_score, spill_in, vertex_accuracy_mm, PoseMode,
    ReconArgs, SemanticArgs, MAX_WARNINGS,
};
use crate::timing::{print_table, stages_json};

/// Failed loads in a row after which the dataset is taken to have ended early.
pub const MAX_CONSECUTIVE_FAILED_LOADS: usize = 30;

/// Arguments of `semrecon run`.
#[derive(clap::Args)]
pub struct RunArgs {
    /// Dataset as KIND:PATH (7scenes:, tum:, redwood:, scannet:, replica:, oni:FILE, bag:FILE),
    /// a dataset folder or recording (the kind read from its files), or a generated scene: synth:SEED (one room, 10 s), synth-loop:SEED (two rooms, a 60 s
    /// loop through both), synth-flat:SEED (five rooms, a 5 min walk through all); options
    /// after the seed: :noisy (uncalibrated sensor: tracking drifts by centimetres a minute),
    /// :SECONDSs (length), e.g. synth-loop:3:noisy, synth-flat:1:600s.
    #[arg(long)]
    dataset: DatasetSpec,
    /// Frames to process as A..B (B excluded; either end may be left out): all by default.
    #[arg(long, value_parser = parse_frame_range)]
    frames: Option<FrameRange>,
    /// The camera's depth calibration (`semrecon calibrate-depth`): its radial depth bias is
    /// divided out of every frame before tracking and fusion.
    #[arg(long, value_name = "FILE")]
    depth_calibration: Option<PathBuf>,
    #[command(flatten)]
    recon: ReconArgs,
    #[command(flatten)]
    semantics: SemanticArgs,
    #[command(flatten)]
    device: crate::device::DeviceArgs,
    /// Feed frames at their capture rate (timestamps) instead of as fast as possible;
    /// semantic passes skip keyframes while the back end is busy.
    #[arg(long)]
    realtime: bool,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    serve: ServeArgs,
}

/// A `--frames` value: `A..B`, `A..` or `..B`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameRange {
    start: usize,
    end: Option<usize>,
}

impl FrameRange {
    /// Every frame.
    pub(crate) const ALL: FrameRange = FrameRange { start: 0, end: None };

    /// The frame indices of a source with `len` frames, or why there are none.
    pub(crate) fn resolve(self, len: usize) -> anyhow::Result<Range<usize>> {
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
struct UpJson {
    up: [f32; 3],
    floor_height_m: f32,
    source: semrecon_pipeline::UpSource,
    horizontal_share: f32,
}

impl From<UpEstimate> for UpJson {
    fn from(u: UpEstimate) -> Self {
        Self {
            up: u.up.to_array(),
            floor_height_m: u.floor_height,
            source: u.source,
            horizontal_share: u.horizontal_share,
        }
    }
}

#[derive(Serialize)]
struct PendingJson {
    mean: f64,
    max: usize,
}

#[derive(Serialize)]
struct Report {
    dataset: String,
    first_frame: usize,
    frames: usize,
    fused_frames: usize,
    lost_frames: usize,
    /// Fused frames whose pose relocalisation recovered after tracking failed.
    relocalised_frames: usize,
    /// Frames the tracker aligned again with colour because depth alone left them poorly
    /// conditioned (`--degenerate-photometric-weight`).
    colour_fallback_frames: usize,
    failed_loads: usize,
    /// The run stopped before the end of the frame range (the dataset ended early).
    stopped_early_at: Option<usize>,
    voxel_size_m: f32,
    keyframe_every: usize,
    /// Most chunks a keyframe re-meshed (`null`: every changed chunk).
    mesh_budget: Option<usize>,
    /// Under a budget: the chunks left waiting for a refresh after each keyframe, mean and
    /// largest (how far the live mesh lagged; the written mesh is complete).
    mesh_pending_chunks: Option<PendingJson>,
    poses: &'static str,
    realtime: bool,
    /// Real-time mode: the largest delay between a frame's capture time and the end of its
    /// processing by the front end, seconds.
    max_lag_s: Option<f64>,
    realtime_factor: f64,
    input_s: f64,
    pipeline_s: f64,
    wall_s: f64,
    stages: serde_json::Value,
    network: String,
    semantic_passes: usize,
    /// [`semrecon_pipeline::Pipeline::relabelled_passes`].
    semantic_relabels: usize,
    skipped_keyframes: usize,
    labelled_vertices: f64,
    up: Option<UpJson>,
    memory_mb: f64,
    /// Where the map's bytes are, bytes per square metre of surface, the memory budget.
    map_memory: MapMemoryReport,
    /// The live mesh's store and the process's resident peak.
    process_memory: ProcessMemoryReport,
    chunks: usize,
    mesh_vertices: usize,
    mesh_triangles: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    ate_rmse_m: Option<f64>,
    /// Loops tried and corrections, trajectory before and after (`null` without loop closure).
    loop_closure: serde_json::Value,
    /// Mean distance from the mesh vertices to the true surface (synthetic datasets), mm.
    mesh_accuracy_mm: Option<f64>,
    /// The same after moving the mesh by the rigid transform that the ATE aligns the
    /// trajectory with (tracked poses on synthetic datasets): what is left is the map's own
    /// inconsistency (doubled or bent surfaces), not where tracking's first frames set it.
    mesh_accuracy_aligned_mm: Option<f64>,
    /// mIoU of the mesh vertices' classes (synthetic datasets: against the generated room).
    miou: Option<f64>,
}

/// Runs the command.
pub fn run(args: RunArgs) -> anyhow::Result<()> {
    prepare_output_dir(&args.out)?;
    let source = open_dataset(&args.dataset).with_context(|| format!("opening {}", args.dataset))?;
    let source = crate::commands::calibrate_depth::with_calibration(source, args.depth_calibration.as_deref())?;
    anyhow::ensure!(!source.is_empty(), "{} has no frames", source.name());
    let range = args.frames.unwrap_or(FrameRange { start: 0, end: None }).resolve(source.len())?;
    // A dataset's gravity is in its world frame: the map is in it when tracking starts at the
    // first frame's ground-truth pose.
    let up = match &args.dataset {
        DatasetSpec::SevenScenes(dir) if source.has_ground_truth() => dataset_up(Some(dir))?,
        _ => None,
    };
    let mut config = pipeline_config(&args.recon, &args.semantics, args.realtime, up, source.color_registered(), true)?;
    spill_in(&mut config, &args.out);
    let (net, network) = load_network(&args.semantics, &args.device)?;
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
    println!("semantics: {network}{}", if up.is_some() { "; up from the dataset's gravity file" } else { "" });
    let mut pipeline = Pipeline::new(config, k, net)?;

    let mut live = LiveView::serve(&args.serve, "the run")?;

    let mut gt = Trajectory::default();
    let mut other_times = semrecon_pipeline::StageTimes::default();
    let mut lost = 0usize;
    let mut failed_loads = 0usize;
    let mut failed_in_a_row = 0usize;
    let mut stopped_early_at = None;
    let mut warnings = 0usize;
    let mut max_lag_s: Option<f64> = None;
    let mut first_timestamp: Option<f64> = None;
    let mut tracking_log = crate::tracking_log::TrackingLog::default();
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
                failed_in_a_row += 1;
                lost += 1;
                bar.inc(1);
                if failed_in_a_row >= MAX_CONSECUTIVE_FAILED_LOADS {
                    warn(format!(
                        "{failed_in_a_row} frames in a row failed to load: the dataset ends early, stopping at frame {i}"
                    ));
                    stopped_early_at = Some(i + 1);
                    break;
                }
                continue;
            }
        };
        failed_in_a_row = 0;
        other_times.record("loading", t.elapsed());
        if let Some(pose) = frame.world_from_camera {
            gt.push(frame.timestamp, pose);
        }
        // Real time: the frame is delivered at its capture time, never earlier.
        let due = args.realtime.then(|| {
            let t0 = *first_timestamp.get_or_insert(frame.timestamp);
            start + Duration::from_secs_f64((frame.timestamp - t0).max(0.0))
        });
        if let Some(due) = due {
            if let Some(wait) = due.checked_duration_since(Instant::now()) {
                std::thread::sleep(wait);
            }
        }
        let pushed = pipeline.push_frame(&frame);
        if let Ok(r) = &pushed {
            tracking_log.record(r);
        }
        match pushed {
            Ok(r) => match r.status {
                FrameStatus::Lost(reason) => {
                    warn(format!("frame {i} skipped: tracking lost ({reason:?})"));
                    lost += 1;
                }
                FrameStatus::NoPose => {
                    warn(format!("frame {i} skipped: no ground-truth pose"));
                    lost += 1;
                }
                FrameStatus::Relocalised => warn(format!("frame {i}: tracking recovered by relocalisation")),
                FrameStatus::Initialized | FrameStatus::Fused => {}
            },
            Err(e) => {
                warn(format!("frame {i} not fused: {e}"));
                lost += 1;
            }
        }
        if let Some(due) = due {
            let lag = Instant::now().saturating_duration_since(due).as_secs_f64();
            max_lag_s = Some(max_lag_s.map_or(lag, |m: f64| m.max(lag)));
        }
        if let Some(live) = live.as_mut() {
            match live.push_at_keyframe(&pipeline, args.recon.keyframe_every) {
                Ok(Some(took)) => other_times.record("live view", took),
                Ok(None) => {}
                Err(why) => warn(why),
            }
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let (mesh, wall_s) = finish_session(&mut pipeline, live.as_mut(), start, warnings, &args.out)?;
    tracking_log.write(&args.out)?;
    let fused = pipeline.frame_counts().1;
    let trajectory_errors = if source.has_ground_truth() && !pipeline.trajectory().is_empty() {
        match evaluate_trajectory(&gt, pipeline.trajectory(), &TrajectoryEvalConfig::default()) {
            Ok(e) => Some(e),
            Err(e) => {
                eprintln!("warning: no ATE: {e}");
                None
            }
        }
    } else {
        None
    };
    let ate_rmse_m = trajectory_errors.as_ref().map(|e| e.ate_rmse_m);
    // A synthetic dataset's labelled room is the geometric and semantic ground truth.
    let (mesh_accuracy_mm, mesh_accuracy_aligned_mm, miou) = match &args.dataset {
        DatasetSpec::Synth(synthetic) if !mesh.triangles.is_empty() => {
            let truth = synthetic.ground_truth()?;
            let accuracy = vertex_accuracy_mm(&truth, &mesh)?;
            // Tracked poses only: ground-truth ones need no alignment.
            let aligned = match (&trajectory_errors, args.recon.poses) {
                (Some(e), PoseMode::Track) => {
                    let positions: Vec<glam::Vec3> =
                        pipeline.trajectory().poses.iter().map(|p| glam::Vec3::from(p.translation)).collect();
                    aligned_vertex_accuracy_mm(&truth, &mesh, &positions, e.gt_from_est_transform())?
                }
                _ => None,
            };
            let miou = if pipeline.has_semantics() { semantic_score(&truth, &mesh)?.map(|s| s.0) } else { None };
            (accuracy, aligned, miou)
        }
        _ => (None, None, None),
    };
    let mut times = pipeline.timings().clone();
    times.merge(&other_times);
    let processed = stopped_early_at.unwrap_or(range.end) - range.start;
    let input_s = processed as f64 / source.frame_rate();
    let pipeline_s = pipeline.front_end_seconds();
    let map = pipeline.map();
    let map_memory = MapMemoryReport::new(map, pipeline.map_memory(), &mesh);
    let report = Report {
        dataset: source.name(),
        first_frame: range.start,
        frames: processed,
        fused_frames: fused,
        lost_frames: lost,
        relocalised_frames: pipeline.relocalised_frames(),
        colour_fallback_frames: pipeline.colour_fallback_frames(),
        failed_loads,
        stopped_early_at,
        voxel_size_m: args.recon.voxel,
        keyframe_every: args.recon.keyframe_every,
        mesh_budget: pipeline.config().mesh_budget.map(|b| b.get()),
        mesh_pending_chunks: match (pipeline.config().mesh_budget, pipeline.mesh_lag()) {
            (Some(_), Some((mean, max))) => Some(PendingJson { mean, max }),
            _ => None,
        },
        poses: args.recon.poses.describe(),
        realtime: args.realtime,
        max_lag_s,
        realtime_factor: input_s / pipeline_s.max(1e-9),
        input_s,
        pipeline_s,
        wall_s,
        stages: stages_json(&times),
        network,
        semantic_passes: pipeline.semantic_passes().len(),
        semantic_relabels: pipeline.relabelled_passes(),
        skipped_keyframes: pipeline.skipped_keyframes(),
        labelled_vertices: labelled_share(&mesh),
        up: pipeline.up().map(UpJson::from),
        memory_mb: map_memory.bytes_in_memory as f64 / 1e6,
        map_memory,
        process_memory: ProcessMemoryReport::new(pipeline.mesh_store_memory(), pipeline.semantic_map_bytes()),
        chunks: map.chunk_count(),
        mesh_vertices: mesh.vertex_count(),
        mesh_triangles: mesh.triangle_count(),
        ate_rmse_m,
        loop_closure: loop_closure_json(&pipeline, source.has_ground_truth().then_some(&gt)),
        mesh_accuracy_mm,
        mesh_accuracy_aligned_mm,
        miou,
    };
    write_atomic(&args.out.join("report.json"), serde_json::to_string_pretty(&report)?.as_bytes())?;

    println!();
    print_table(&times);
    println!();
    println!(
        "frames {} (fused {}, lost {}, relocalised {}, aligned again with colour {}), poses: {}",
        report.frames,
        report.fused_frames,
        report.lost_frames,
        report.relocalised_frames,
        report.colour_fallback_frames,
        report.poses
    );
    if let Some(at) = stopped_early_at {
        println!("the dataset ended early: stopped at frame {at} after {MAX_CONSECUTIVE_FAILED_LOADS} failed loads");
    }
    println!(
        "front end (tracking + fusion + meshing, final included + semantic snapshot + waits for semantics): {:.2} s for {:.2} s of input, real-time factor {:.2} (wall {:.1} s with loading)",
        report.pipeline_s, input_s, report.realtime_factor, wall_s
    );
    if let (Some(budget), Some(p)) = (report.mesh_budget, &report.mesh_pending_chunks) {
        println!(
            "meshing: at most {budget} chunks a keyframe; {:.0} chunks waited for a refresh after a keyframe on average, {} at most (the written mesh is complete)",
            p.mean, p.max
        );
    }
    if let Some(lag) = max_lag_s {
        println!(
            "real time: the front end fell behind the camera by up to {lag:.2} s; {} keyframes skipped by semantics",
            report.skipped_keyframes
        );
    }
    println!(
        "semantics: {} passes, {:.0}% of vertices labelled{}",
        report.semantic_passes,
        report.labelled_vertices * 100.0,
        miou.map_or(String::new(), |m| format!(", mIoU {:.1}% against the synthetic room", m * 100.0))
    );
    println!("mesh: {} vertices, {} triangles", report.mesh_vertices, report.mesh_triangles);
    println!("{}", report.map_memory.summary());
    println!("{}", report.process_memory.summary());
    if let Some(ate) = ate_rmse_m {
        println!("ATE rmse {:.4} m against the dataset's ground truth", ate);
    }
    println!("{}", loop_closure_summary(&report.loop_closure));
    if let Some(acc) = mesh_accuracy_mm {
        let aligned = mesh_accuracy_aligned_mm.map_or(String::new(), |a| format!("; {a:.1} mm aligned as the ATE is"));
        println!("mesh accuracy {acc:.1} mm (mean vertex distance to the generated room{aligned})");
    }
    println!("wrote {}/{{mesh.ply, semantic.ply, trajectory.txt, tracking.csv, report.json}}", args.out.display());
    if let Some(live) = live {
        if args.serve.serve_exit {
            live.server.stop();
        } else {
            println!("live viewer serving the final result at {} (Ctrl-C to stop)", live.server.url());
            live.server.wait();
        }
    }
    Ok(())
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
