//! Tracking + fusion benchmark: frame-to-model tracking of a dataset, every tracked frame
//! fused, with the trajectory error against the dataset's ground truth and per-stage times.
//!
//! ```text
//! cargo run --release -p semrecon-recon --example track_bench -- SPEC [--frames N]
//!     [--voxel M] [--trunc VOXELS] [--downscale 1|2|4] [--iters F,M,C] [--photometric W] [--size WxH]
//!     [--fine-stride S] [--model-interval N] [--min-constrained N] [--max-depth M] [--repeat N]
//! ```
//!
//! `SPEC` is a dataset spec (`7scenes:/work/shared/data/7scenes-redkitchen`, `synth:3`).
//! The first frame starts at its ground-truth pose when there is one. ATE is the RMS
//! position error after Horn alignment (rotation + translation, no scale) over the tracked
//! frames; the error with only the first pose aligned is printed too. Tracking is timed in
//! wall and CPU milliseconds (all threads; the machine may be shared). `--size` resamples
//! frames (nearest pixel) before tracking. `--repeat N` then re-tracks the last frame N
//! times on the final map and ray-casts its pose N times alone (steadier medians on a
//! shared machine). Thread count: `RAYON_NUM_THREADS`. `TRACK_BENCH_TRAJECTORY=FILE` writes
//! the poses of the fused frames in the TUM format (`timestamp tx ty tz qx qy qz qw`, as
//! `semrecon run` writes `trajectory.txt`); `TRACK_BENCH_POSITIONS=FILE` the estimated and
//! reference positions, a pair per line; `TRACK_BENCH_LOG=FILE` one line per frame: index,
//! status, condition, constrained directions, inlier ratio, residual (mm), colour fallback.

#[path = "common/cpu_time.rs"]
mod cpu_time;
#[path = "common/flags.rs"]
mod flags;

use std::time::Instant;

use glam::Vec3;
use semrecon_data::{open_dataset, DatasetSpec, Frame};
use semrecon_recon::{ate_rmse, raycast, Tracker, TrackerConfig, TrackingStatus, TsdfConfig, TsdfMap};

use cpu_time::timed;
use flags::Flags;

struct Args {
    spec: String,
    frames: usize,
    voxel: f32,
    photometric: f32,
    size: Option<(u32, u32)>,
    truncation: Option<f32>,
    downscale: Option<u32>,
    iterations: Option<[usize; 3]>,
    fine_stride: Option<usize>,
    model_interval: Option<usize>,
    min_constrained: Option<usize>,
    max_depth: Option<f32>,
    repeat: usize,
}

fn parse_args() -> Result<Args, String> {
    let mut flags = Flags::from_env();
    let mut a = Args {
        spec: String::new(),
        frames: usize::MAX,
        voxel: 0.005,
        photometric: 0.0,
        size: None,
        truncation: None,
        downscale: None,
        iterations: None,
        fine_stride: None,
        model_interval: None,
        min_constrained: None,
        max_depth: None,
        repeat: 0,
    };
    while let Some(arg) = flags.next_flag() {
        match arg.as_str() {
            "--frames" => a.frames = flags.value(&arg)?,
            "--voxel" => a.voxel = flags.value(&arg)?,
            "--photometric" => a.photometric = flags.value(&arg)?,
            "--trunc" => a.truncation = Some(flags.value(&arg)?),
            "--iters" => {
                let v: String = flags.value(&arg)?;
                let parts: Vec<usize> = v
                    .split(',')
                    .map(|p| p.parse().map_err(|e| format!("--iters {v}: {e}")))
                    .collect::<Result<_, _>>()?;
                a.iterations =
                    Some(parts.try_into().map_err(|_| format!("--iters {v}: expected three counts, fine to coarse"))?);
            }
            "--repeat" => a.repeat = flags.value(&arg)?,
            "--max-depth" => a.max_depth = Some(flags.value(&arg)?),
            "--fine-stride" => a.fine_stride = Some(flags.value(&arg)?),
            "--model-interval" => a.model_interval = Some(flags.value(&arg)?),
            "--min-constrained" => a.min_constrained = Some(flags.value(&arg)?),
            "--downscale" => a.downscale = Some(flags.value(&arg)?),
            "--size" => a.size = Some(flags.size(&arg)?),
            s if !s.starts_with("--") && a.spec.is_empty() => a.spec = s.to_string(),
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if a.spec.is_empty() {
        return Err("usage: track_bench SPEC [--frames N] [--voxel M] [--trunc VOXELS] [--downscale 1|2|4] [--iters F,M,C] [--photometric W] [--size WxH] [--repeat N]".into());
    }
    Ok(a)
}

/// Nearest-pixel resampling of a frame to `w x h`.
fn resample(f: Frame, w: u32, h: u32) -> Frame {
    let k0 = f.intrinsics;
    if (k0.width, k0.height) == (w, h) {
        return f;
    }
    let k = k0.scaled(w, h);
    let mut depth = Vec::with_capacity((w * h) as usize);
    let mut color = Vec::with_capacity((w * h) as usize);
    for v in 0..h {
        for u in 0..w {
            let su = (((u as f32 + 0.5) * k0.width as f32 / w as f32) as u32).min(k0.width - 1);
            let sv = (((v as f32 + 0.5) * k0.height as f32 / h as f32) as u32).min(k0.height - 1);
            let i = (sv * k0.width + su) as usize;
            depth.push(f.depth[i]);
            color.push(f.color.get(i).copied().unwrap_or([0; 3]));
        }
    }
    Frame { depth, color, intrinsics: k, labels: None, ..f }
}

fn percentiles(label: &str, ms: &mut [f64]) {
    if ms.is_empty() {
        println!("{label:<22} (none)");
        return;
    }
    ms.sort_by(f64::total_cmp);
    let median = ms[ms.len() / 2];
    let p95 = ms[(ms.len() * 95 / 100).min(ms.len() - 1)];
    let mean = ms.iter().sum::<f64>() / ms.len() as f64;
    println!(
        "{label:<22} median {median:7.2}  mean {mean:7.2}  p95 {p95:7.2}  min {:7.2}  max {:7.2} ms  ({} samples)",
        ms[0],
        ms[ms.len() - 1],
        ms.len()
    );
}

fn run(a: Args) -> Result<(), String> {
    let spec: DatasetSpec = a.spec.parse().map_err(|e| format!("{}: {e}", a.spec))?;
    let source = open_dataset(&spec).map_err(|e| e.to_string())?;
    let n = source.len().min(a.frames);
    let mut map_config = TsdfConfig::with_voxel_size(a.voxel).map_err(|e| e.to_string())?;
    if let Some(t) = a.truncation {
        map_config.truncation_voxels = t;
    }
    if let Some(d) = a.max_depth {
        map_config.max_depth = d;
    }
    let mut map = TsdfMap::new(map_config).map_err(|e| e.to_string())?;
    let mut config = TrackerConfig { photometric_weight: a.photometric, ..TrackerConfig::default() };
    if let Some(d) = a.downscale {
        config.model_downscale = d;
    }
    if let Some(i) = a.iterations {
        config.iterations = i;
    }
    if let Some(s) = a.fine_stride {
        config.fine_stride = s;
    }
    if let Some(m) = a.model_interval {
        config.model_interval = m;
    }
    if let Some(m) = a.min_constrained {
        config.min_constrained = m;
    }
    if let Some(d) = a.max_depth {
        config.max_depth = d;
    }
    let mut tracker: Option<Tracker> = None;
    // The tracker before the last frame and that frame, for `--repeat`.
    let mut before_last: Option<(Tracker, Frame)> = None;
    let (mut track_ms, mut track_cpu_ms, mut cast_ms, mut fuse_ms) = (vec![], vec![], vec![], vec![]);
    let (mut est, mut gt) = (Vec::new(), Vec::new());
    let mut first_err = Vec::new();
    let mut traj_text = String::from("# timestamp tx ty tz qx qy qz qw\n");
    let mut frame_log = String::from("# frame status condition constrained inlier_ratio residual_mm colour_fallback\n");
    let mut lost = Vec::new();
    let mut load_s = 0.0;
    let t_all = Instant::now();
    for i in 0..n {
        let t_load = Instant::now();
        let mut frame = source.frame(i).map_err(|e| e.to_string())?;
        if let Some((w, h)) = a.size {
            frame = resample(frame, w, h);
        }
        load_s += t_load.elapsed().as_secs_f64();
        let tracker = match &mut tracker {
            Some(t) => t,
            None => tracker.insert(
                Tracker::with_initial_pose(config.clone(), frame.world_from_camera.unwrap_or(glam::Affine3A::IDENTITY))
                    .map_err(|e| e.to_string())?,
            ),
        };
        if a.repeat > 0 && i + 1 == n {
            before_last = Some((tracker.clone(), frame.clone()));
        }
        let (r, _, cpu) = timed(|| tracker.track(&frame, &map));
        let r = r.map_err(|e| e.to_string())?;
        frame_log += &format!(
            "{i} {:?} {:.3e} {} {:.3} {:.2} {}\n",
            r.status,
            r.condition,
            r.constrained,
            r.inlier_ratio,
            r.residual_rms * 1e3,
            u8::from(r.colour_fallback)
        );
        if r.status == TrackingStatus::Tracked {
            track_ms.push(r.total_ms);
            track_cpu_ms.push(cpu);
            if r.raycast_ms > 0.0 {
                cast_ms.push(r.raycast_ms);
            }
        }
        if !r.should_fuse() {
            lost.push((i, r.status));
            continue;
        }
        let t = Instant::now();
        map.integrate(&frame, r.world_from_camera).map_err(|e| e.to_string())?;
        fuse_ms.push(t.elapsed().as_secs_f64() * 1e3);
        // TUM lines (`timestamp tx ty tz qx qy qz qw`, world_from_camera) of the fused frames,
        // which `semrecon eval traj` and offline analyses read like `semrecon run`'s output.
        {
            let q = glam::Quat::from_mat3a(&r.world_from_camera.matrix3);
            let t = r.world_from_camera.translation;
            traj_text += &format!("{} {} {} {} {} {} {} {}\n", i as f64 / 30.0, t.x, t.y, t.z, q.x, q.y, q.z, q.w);
        }
        if let Some(g) = frame.world_from_camera {
            let p = Vec3::from(r.world_from_camera.translation);
            let q = Vec3::from(g.translation);
            est.push(p);
            gt.push(q);
            first_err.push((p - q).length_squared() as f64);
        }
    }
    let wall = t_all.elapsed().as_secs_f64() - load_s;
    println!(
        "{}: {n} frames, {} threads, voxel {} mm, truncation {} voxels, model 1/{} every {} frames, iterations {:?}, fine stride {}, photometric weight {}",
        source.name(),
        rayon::current_num_threads(),
        a.voxel * 1e3,
        map_config.truncation_voxels,
        config.model_downscale,
        config.model_interval,
        config.iterations,
        config.fine_stride,
        a.photometric
    );
    println!("lost frames: {} {:?}", lost.len(), &lost[..lost.len().min(10)]);
    if let Ok(path) = std::env::var("TRACK_BENCH_TRAJECTORY") {
        std::fs::write(&path, &traj_text).map_err(|e| format!("{path}: {e}"))?;
    }
    if let Ok(path) = std::env::var("TRACK_BENCH_LOG") {
        std::fs::write(&path, &frame_log).map_err(|e| format!("{path}: {e}"))?;
    }
    if let Ok(path) = std::env::var("TRACK_BENCH_POSITIONS") {
        // Estimated and reference positions, one pair per line (for offline analysis).
        let text: String =
            est.iter().zip(&gt).map(|(e, g)| format!("{} {} {} {} {} {}\n", e.x, e.y, e.z, g.x, g.y, g.z)).collect();
        std::fs::write(&path, text).map_err(|e| format!("{path}: {e}"))?;
    }
    match ate_rmse(&est, &gt) {
        Some(e) => println!(
            "ATE RMSE (Horn, no scale): {:.2} mm; first-pose aligned: {:.2} mm ({} poses)",
            e * 1e3,
            (first_err.iter().sum::<f64>() / first_err.len() as f64).sqrt() * 1e3,
            est.len()
        ),
        None => println!("ATE: no ground truth"),
    }
    percentiles("tracking (per frame)", &mut track_ms);
    percentiles("  CPU, all threads", &mut track_cpu_ms);
    percentiles("  of which ray-cast", &mut cast_ms);
    percentiles("fusion (per frame)", &mut fuse_ms);
    if let Some((tracker, frame)) = before_last {
        repeat_last(&tracker, &frame, &map, a.repeat)?;
    }
    println!(
        "chunks {}, {:.1} MB; {:.2} s without loading ({:.1} ms/frame)",
        map.chunk_count(),
        map.memory_bytes() as f64 / 1e6,
        wall,
        wall * 1e3 / n.max(1) as f64
    );
    Ok(())
}

/// Times the last frame's tracking `repeat` times on the final map, and the ray-cast at its
/// pose alone: the same work each time, so the medians compare builds on a loaded machine
/// better than the whole run does.
fn repeat_last(tracker: &Tracker, frame: &Frame, map: &TsdfMap, repeat: usize) -> Result<(), String> {
    let Some(pose) = tracker.pose() else { return Ok(()) };
    let config = tracker.config();
    let s = config.model_downscale;
    let k = frame.intrinsics.scaled(frame.intrinsics.width / s, frame.intrinsics.height / s);
    // Nearest-pixel march-start depth at the model resolution.
    let hint: Vec<f32> = (0..k.pixel_count())
        .map(|i| {
            let (u, v) = (i % k.width as usize, i / k.width as usize);
            frame.depth[v * s as usize * frame.intrinsics.width as usize + u * s as usize]
        })
        .collect();
    let (mut cast_wall, mut cast_cpu, mut track_wall, mut track_cpu) = (vec![], vec![], vec![], vec![]);
    let mut cast_in_track = false;
    for _ in 0..repeat {
        let (_, w, c) = timed(|| raycast(map, k, pose, config.min_depth, config.max_depth, Some(&hint)));
        cast_wall.push(w);
        cast_cpu.push(c);
        let mut t = tracker.clone();
        let (r, w, c) = timed(|| t.track(frame, map));
        cast_in_track = r.map_err(|e| e.to_string())?.raycast_ms > 0.0;
        track_wall.push(w);
        track_cpu.push(c);
    }
    println!("last frame x{repeat} (tracking {} the ray-cast):", if cast_in_track { "with" } else { "without" });
    percentiles("  ray-cast wall", &mut cast_wall);
    percentiles("  ray-cast CPU", &mut cast_cpu);
    percentiles("  track wall", &mut track_wall);
    percentiles("  track CPU", &mut track_cpu);
    Ok(())
}

fn main() {
    match parse_args().and_then(run) {
        Ok(()) => {}
        Err(e) => {
            eprintln!("track_bench: {e}");
            std::process::exit(1);
        }
    }
}
