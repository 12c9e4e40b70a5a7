//! `semrecon live`: the pipeline on a live camera, in real time. The camera runs on its own
//! thread; the pipeline takes the newest frame each time it is ready for one, and frames that
//! arrive while it is busy are dropped and counted (a one-frame mailbox,
//! [`semrecon_pipeline::live`]): nothing queues, and the map follows the camera as closely as
//! the machine allows.
//!
//! Cameras: an OpenNI2 device (`--device [URI]`), an OpenNI recording played at its recorded
//! times (`--oni FILE`), a RealSense recording played at its capture times (`--bag FILE`), or a
//! simulated camera, a rendered scan of a synthetic room delivered at 30 fps on a timer
//! (`--synth SEED`).
//!
//! A status line shows frames in, fused, dropped, lost and the current real-time factor (how
//! many times faster than the camera the pipeline processes a frame, over the last second).
//! Ctrl-C, the end of the stream, `--max-frames` or `--seconds` finish the session: the
//! pipeline finishes with what it has and writes the outputs of `run` (`mesh.ply`,
//! `semantic.ply`, `trajectory.txt`, `tracking.csv`, `report.json`). A camera that fails (unplugged, a
//! recording cut short) ends the session the same way, with the reason in the report.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Context;
use semrecon_data::atomic_file::write_atomic;
use semrecon_data::datasets::{synthetic_scan, Oni, RealSenseBag, SyntheticScanConfig};
use semrecon_data::depth_calibration::{CalibratedCamera, DepthCalibration};
use semrecon_data::live::{LiveCamera, OpenNiLive, Replay};
use semrecon_data::openni::OniCamera;
use semrecon_data::Trajectory;
use semrecon_eval::{evaluate_trajectory, TrajectoryEvalConfig};
use semrecon_pipeline::{FeedStats, FrameStatus, LiveFeed, Pipeline};
use serde::Serialize;

use crate::interrupt;
use crate::live_view::{LiveView, ServeArgs};
use crate::progress::spinner;
use crate::reconstruction::{
    finish_session, labelled_share, load_network, pipeline_config, prepare_output_dir, ReconArgs, SemanticArgs,
    MAX_WARNINGS,
};
use crate::timing::{print_table, stages_json};

/// Frames of the simulated camera (`--synth`) without `--max-frames`: 5 s at 30 fps, held in
/// memory (2.2 MB a frame).
const SIMULATED_FRAMES: usize = 150;

/// The window of the current real-time factor.
const RATE_WINDOW: Duration = Duration::from_secs(1);

/// Arguments of `semrecon live`.
#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("camera").required(true).args(["device", "oni", "bag", "synth"])))]
pub struct LiveArgs {
    /// An OpenNI2 camera (Kinect v1, Asus Xtion, PrimeSense, Orbbec with its OpenNI2 driver):
    /// the one with this URI, or the first one found when no URI is given. Needs OpenNI2
    /// (Debian: libopenni2-0).
    #[arg(long, value_name = "URI", num_args = 0..=1, default_missing_value = "")]
    device: Option<String>,
    /// An OpenNI .oni recording, played at its recorded speed as if live. Needs OpenNI2.
    #[arg(long, value_name = "FILE")]
    oni: Option<PathBuf>,
    /// A RealSense .bag recording (librealsense), played at its capture times as if live.
    #[arg(long, value_name = "FILE")]
    bag: Option<PathBuf>,
    /// A simulated camera: a rendered scan of the synthetic room SEED (rendered beforehand),
    /// delivered at 30 fps on a timer (150 frames, or --max-frames).
    #[arg(long, value_name = "SEED")]
    synth: Option<u64>,
    /// Finish after this many frames from the camera (dropped ones included).
    #[arg(long)]
    max_frames: Option<usize>,
    /// Finish after this many seconds.
    #[arg(long)]
    seconds: Option<f64>,
    /// The camera's depth calibration (`semrecon calibrate-depth` on a recording of it): its
    /// radial depth bias is divided out of every frame.
    #[arg(long, value_name = "FILE")]
    depth_calibration: Option<PathBuf>,
    #[command(flatten)]
    recon: ReconArgs,
    #[command(flatten)]
    semantics: SemanticArgs,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
    #[command(flatten)]
    serve: ServeArgs,
}

/// Why the session finished.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
enum Stop {
    EndOfStream,
    CameraFailed,
    Interrupted,
    MaxFrames,
    Seconds,
}

impl Stop {
    fn describe(self) -> &'static str {
        match self {
            Self::EndOfStream => "the stream ended",
            Self::CameraFailed => "the camera failed",
            Self::Interrupted => "Ctrl-C",
            Self::MaxFrames => "--max-frames reached",
            Self::Seconds => "--seconds reached",
        }
    }
}

#[derive(Serialize)]
struct Report {
    camera: String,
    notes: Vec<String>,
    width: u32,
    height: u32,
    frame_rate: f64,
    stopped_by: Stop,
    camera_failure: Option<String>,
    /// Frames the camera delivered.
    frames_in: usize,
    /// Frames the pipeline took (the rest were dropped).
    frames_taken: usize,
    fused_frames: usize,
    dropped_frames: usize,
    lost_frames: usize,
    /// Frames the camera could not deliver (damaged).
    skipped_frames: usize,
    relocalised_frames: usize,
    /// Frames the tracker aligned again with colour because depth alone left them poorly
    /// conditioned (`--degenerate-photometric-weight`).
    colour_fallback_frames: usize,
    /// Longest a frame waited for the pipeline, ms (about one frame period at most).
    max_wait_ms: f64,
    frame_period_ms: f64,
    /// Camera time over the pipeline's time per taken frame: above 1, the pipeline keeps up.
    realtime_factor: f64,
    /// Share of the camera's frames that were fused.
    fused_share: f64,
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
    memory_mb: f64,
    chunks: usize,
    mesh_vertices: usize,
    mesh_triangles: usize,
    /// Against the simulated camera's true poses.
    #[serde(skip_serializing_if = "Option::is_none")]
    ate_rmse_m: Option<f64>,
}

/// Opens the camera the arguments name.
fn open_camera(args: &LiveArgs) -> anyhow::Result<Box<dyn LiveCamera>> {
    if let Some(uri) = &args.device {
        let uri = (!uri.is_empty()).then_some(uri.as_str());
        let camera = OniCamera::open_device(uri).context("opening the OpenNI2 camera")?;
        let label = format!("openni:{}", camera.name());
        return Ok(Box::new(OpenNiLive::new(camera, label)));
    }
    if let Some(path) = &args.oni {
        let oni = Oni::open(path).with_context(|| format!("opening the OpenNI recording {}", path.display()))?;
        return Ok(Box::new(Replay::new(Box::new(oni))));
    }
    if let Some(path) = &args.bag {
        let bag =
            RealSenseBag::open(path).with_context(|| format!("opening the RealSense recording {}", path.display()))?;
        return Ok(Box::new(Replay::new(Box::new(bag))));
    }
    if let Some(seed) = args.synth {
        let mut config = SyntheticScanConfig::new(seed);
        config.frames = args.max_frames.unwrap_or(SIMULATED_FRAMES).max(1);
        let (_, scan) = synthetic_scan(&config).context("rendering the simulated camera's scan")?;
        // Rendered beforehand: rendering during the session would take the pipeline's cores.
        println!("rendering the simulated camera's {} frames ...", config.frames);
        return Ok(Box::new(Replay::new(Box::new(scan)).preload()));
    }
    anyhow::bail!("no camera: give --device, --oni, --bag or --synth")
}

/// Processing times of the last [`RATE_WINDOW`], for the current real-time factor.
struct RateWindow {
    samples: VecDeque<(Instant, Duration)>,
}

impl RateWindow {
    fn push(&mut self, took: Duration) {
        let now = Instant::now();
        self.samples.push_back((now, took));
        while self.samples.front().is_some_and(|(t, _)| now.duration_since(*t) > RATE_WINDOW) {
            self.samples.pop_front();
        }
    }

    /// Frame period over the mean processing time.
    fn factor(&self, period: f64) -> Option<f64> {
        let n = self.samples.len();
        let total: f64 = self.samples.iter().map(|(_, d)| d.as_secs_f64()).sum();
        (n > 0 && total > 0.0).then(|| period * n as f64 / total)
    }
}

/// Runs the command.
pub fn run(args: LiveArgs) -> anyhow::Result<()> {
    prepare_output_dir(&args.out)?;
    // From the start: Ctrl-C while the camera opens still finishes with (empty) outputs.
    let caught = interrupt::install();
    let camera = open_camera(&args)?;
    let camera: Box<dyn LiveCamera> = match &args.depth_calibration {
        None => camera,
        Some(path) => {
            let calibration = DepthCalibration::load(path)?;
            Box::new(
                CalibratedCamera::new(camera, calibration).with_context(|| format!("applying {}", path.display()))?,
            )
        }
    };
    let config = pipeline_config(&args.recon, &args.semantics, true, None, true, false)?;
    let (net, network) = load_network(&args.semantics, &crate::device::DeviceArgs::default())?;
    let k = camera.intrinsics();
    let frame_rate = camera.frame_rate();
    let period = 1.0 / frame_rate.max(1e-3);
    let camera_name = camera.name();
    let notes = camera.notes();
    println!(
        "{camera_name}: {}x{} at {frame_rate:.0} Hz, fx {:.1} fy {:.1} cx {:.1} cy {:.1}{}",
        k.width,
        k.height,
        k.fx,
        k.fy,
        k.cx,
        k.cy,
        camera.expected_frames().map(|n| format!(", {n} frames")).unwrap_or_default()
    );
    for note in &notes {
        println!("  {note}");
    }
    println!("semantics: {network}; voxel {} m; Ctrl-C finishes and writes the outputs", args.recon.voxel);
    let mut pipeline = Pipeline::new(config, k, net)?;
    let mut live = LiveView::serve(&args.serve, "the session")?;
    if !caught {
        eprintln!("warning: Ctrl-C cannot be caught here: it ends the session without outputs");
    }

    let mut other_times = semrecon_pipeline::StageTimes::default();
    let mut gt = Trajectory::default();
    let mut tracking_log = crate::tracking_log::TrackingLog::default();
    let mut lost = 0usize;
    let mut warnings = 0usize;
    let mut window = RateWindow { samples: VecDeque::new() };
    let mut busy = Duration::ZERO;
    let status = spinner("live");
    let mut warn = |message: String| {
        warnings += 1;
        if warnings <= MAX_WARNINGS {
            status.suspend(|| eprintln!("warning: {message}"));
        }
    };
    let start = Instant::now();
    let feed = LiveFeed::start(camera);
    let stop = loop {
        if interrupt::requested() {
            break Stop::Interrupted;
        }
        if args.seconds.is_some_and(|s| start.elapsed().as_secs_f64() >= s) {
            break Stop::Seconds;
        }
        let Some(arrived) = feed.next_timeout(Duration::from_millis(100)) else {
            if feed.is_over() {
                break if feed.stats().failure.is_some() { Stop::CameraFailed } else { Stop::EndOfStream };
            }
            continue;
        };
        let frame = arrived.frame;
        if let Some(pose) = frame.world_from_camera {
            gt.push(frame.timestamp, pose);
        }
        let t = Instant::now();
        let pushed = pipeline.push_frame(&frame);
        if let Ok(r) = &pushed {
            tracking_log.record(r);
        }
        match pushed {
            Ok(r) => match r.status {
                FrameStatus::Lost(reason) => {
                    warn(format!("frame {} skipped: tracking lost ({reason:?})", frame.index));
                    lost += 1;
                }
                FrameStatus::NoPose => {
                    warn(format!("frame {} skipped: no pose", frame.index));
                    lost += 1;
                }
                FrameStatus::Relocalised => {
                    warn(format!("frame {}: tracking recovered by relocalisation", frame.index))
                }
                FrameStatus::Initialized | FrameStatus::Fused => {}
            },
            Err(e) => {
                warn(format!("frame {} not fused: {e}", frame.index));
                lost += 1;
            }
        }
        let took = t.elapsed();
        busy += took;
        window.push(took);
        if let Some(live) = live.as_mut() {
            match live.push_at_keyframe(&pipeline, args.recon.keyframe_every) {
                Ok(Some(took)) => other_times.record("live view", took),
                Ok(None) => {}
                Err(why) => warn(why),
            }
        }
        let stats = feed.stats();
        let fused = pipeline.frame_counts().1;
        status.set_message(format!(
            "in {}  fused {fused}  dropped {}  lost {lost}  real-time x{}",
            stats.arrived,
            stats.dropped,
            window.factor(period).map_or("-".into(), |f| format!("{f:.2}"))
        ));
        if args.max_frames.is_some_and(|m| stats.arrived >= m) {
            break Stop::MaxFrames;
        }
    };
    let stats: FeedStats = feed.stop();
    status.finish_and_clear();
    if stop == Stop::Interrupted {
        println!("Ctrl-C: finishing with what the session has (Ctrl-C again to quit at once)");
    }
    if let Some(why) = &stats.failure {
        eprintln!("warning: the camera stopped: {why}");
    }
    for why in &stats.skip_reasons {
        warn(format!("camera frame skipped: {why}"));
    }
    let (mesh, wall_s) = finish_session(&mut pipeline, live.as_mut(), start, warnings, &args.out)?;
    tracking_log.write(&args.out)?;
    let fused = pipeline.frame_counts().1;
    let ate_rmse_m = (gt.len() > 1 && pipeline.trajectory().len() > 1)
        .then(|| evaluate_trajectory(&gt, pipeline.trajectory(), &TrajectoryEvalConfig::default()).ok())
        .flatten()
        .map(|e| e.ate_rmse_m);
    let mut times = pipeline.timings().clone();
    times.merge(&other_times);
    let map = pipeline.map();
    let report = Report {
        camera: camera_name,
        notes,
        width: k.width,
        height: k.height,
        frame_rate,
        stopped_by: stop,
        camera_failure: stats.failure.clone(),
        frames_in: stats.arrived,
        frames_taken: stats.taken,
        fused_frames: fused,
        dropped_frames: stats.dropped,
        lost_frames: lost,
        skipped_frames: stats.skipped,
        relocalised_frames: pipeline.relocalised_frames(),
        colour_fallback_frames: pipeline.colour_fallback_frames(),
        max_wait_ms: stats.max_wait.as_secs_f64() * 1e3,
        frame_period_ms: period * 1e3,
        realtime_factor: if busy.is_zero() { 0.0 } else { stats.taken as f64 * period / busy.as_secs_f64() },
        fused_share: if stats.arrived == 0 { 0.0 } else { fused as f64 / stats.arrived as f64 },
        input_s: stats.arrived as f64 * period,
        pipeline_s: pipeline.front_end_seconds(),
        wall_s,
        stages: stages_json(&times),
        network,
        semantic_passes: pipeline.semantic_passes().len(),
        semantic_relabels: pipeline.relabelled_passes(),
        skipped_keyframes: pipeline.skipped_keyframes(),
        labelled_vertices: labelled_share(&mesh),
        memory_mb: pipeline.map_memory().in_memory() as f64 / 1e6,
        chunks: map.chunk_count(),
        mesh_vertices: mesh.vertex_count(),
        mesh_triangles: mesh.triangle_count(),
        ate_rmse_m,
    };
    write_atomic(&args.out.join("report.json"), serde_json::to_string_pretty(&report)?.as_bytes())?;

    println!();
    print_table(&times);
    println!();
    println!(
        "finished ({}): frames in {}, fused {}, dropped {}, lost {}, skipped by the camera {}",
        stop.describe(),
        report.frames_in,
        report.fused_frames,
        report.dropped_frames,
        report.lost_frames,
        report.skipped_frames
    );
    println!(
        "real-time factor {:.2} (camera time over processing time per frame), {:.0}% of the camera's frames fused; longest wait for the pipeline {:.1} ms (frame period {:.1} ms)",
        report.realtime_factor,
        report.fused_share * 100.0,
        report.max_wait_ms,
        report.frame_period_ms
    );
    println!(
        "semantics: {} passes ({} keyframes skipped while busy), {:.0}% of vertices labelled",
        report.semantic_passes,
        report.skipped_keyframes,
        report.labelled_vertices * 100.0
    );
    println!(
        "map: {} chunks, {:.1} MB; mesh: {} vertices, {} triangles",
        report.chunks, report.memory_mb, report.mesh_vertices, report.mesh_triangles
    );
    if let Some(ate) = ate_rmse_m {
        println!("ATE rmse {ate:.4} m against the simulated camera's true poses");
    }
    println!("wrote {}/{{mesh.ply, semantic.ply, trajectory.txt, tracking.csv, report.json}}", args.out.display());
    if let Some(live) = live {
        if args.serve.serve_exit || stop == Stop::Interrupted {
            live.server.stop();
        } else {
            interrupt::restore_default();
            println!("live viewer serving the final result at {} (Ctrl-C to stop)", live.server.url());
            live.server.wait();
        }
    }
    Ok(())
}
