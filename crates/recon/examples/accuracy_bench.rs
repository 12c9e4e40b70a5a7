//! Accuracy on rendered sequences with exact ground truth: mesh accuracy and completeness with
//! ground-truth poses, and the tracking error (ATE) of frame-to-model tracking.
//!
//! ```text
//! cargo run --release -p semrecon-recon --example accuracy_bench -- SOURCE [--frames N]
//!     [--size WxH] [--voxel M] [--trunc VOXELS] [--band-factor K] [--min-band VOXELS]
//!     [--max-depth M] [--min-weight W[,W...]] [--min-component N[,N...]] [--ideal]
//!     [--skip-tracking] [--color-band VOXELS] [--behind-band K]
//!     [--far-group-beyond M] [--far-group-frames N] [--compare-whole]
//! ```
//!
//! `SOURCE` is `synth:SEED` (a generated room along its generated handheld path) or
//! `replica:DIR` (a Replica scene folder holding `office0_mesh.ply` and `office0/traj.txt`,
//! rendered along the first `N` poses of that trajectory). Frames pass through the Kinect-like
//! sensor model (noise growing with depth, quantisation, dropouts) unless `--ideal`.
//!
//! Mesh metrics (semrecon-eval, 5 mm sampling of the ground truth): accuracy = mean distance
//! of our vertices to the true surface; completeness = share of the true surface within
//! 1 cm of ours, and within 5 cm (about the share the path saw at all: surfaces the camera
//! never faced cannot be reconstructed). The 5 cm share overstates what was seen (hidden
//! floor under furniture, backs of objects near seen surfaces), so completeness is also
//! given over the ground-truth samples some frame saw (rendered without noise from the same
//! poses: the sample projects inside the image, within the fused depth range, within 2 cm of
//! the rendered depth there). `--min-weight` meshes the same map once per listed
//! threshold ([`MeshConfig::min_weight`]: lighter voxels count as unobserved; default 0),
//! and `--min-component` per smallest piece kept (`MeshConfig::min_component_triangles`).
//! `--far-group-beyond`/`--far-group-frames` fuse far chunks from groups of frames as the
//! pipeline does ([`semrecon_recon::GroupedFusion`]; without them every frame is fused whole),
//! and `--compare-whole` reports where that loses surface against fusing frames whole.

#[path = "common/flags.rs"]
mod flags;
#[path = "common/tracked_path.rs"]
mod tracked_path;

use std::path::Path;

use glam::{Affine3A, Mat4, Vec3};
use rayon::prelude::*;
use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
use semrecon_data::{read_ply, FrameSource, Intrinsics, LabeledMesh, RenderedScan, SensorModel};
use semrecon_eval::{evaluate_mesh, sample_surface, MeshEvalConfig, SurfaceIndex};
use semrecon_recon::{extract_mesh_with, GroupedFusion, MeshConfig, Tracker, TrackerConfig, TsdfConfig, TsdfMap};

use flags::Flags;
use tracked_path::track_and_fuse;

struct Args {
    source: String,
    frames: usize,
    size: (u32, u32),
    voxel: f32,
    truncation: f32,
    band_factor: f32,
    min_band: f32,
    ideal: bool,
    skip_tracking: bool,
    max_depth: f32,
    min_weights: Vec<f32>,
    min_components: Vec<usize>,
    color_band: f32,
    behind_band: f32,
    pair_far: f32,
    compare_whole: bool,
    group_frames: usize,
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args {
        source: String::new(),
        frames: 300,
        size: (640, 480),
        voxel: 0.005,
        truncation: 10.0,
        band_factor: TsdfConfig::default().truncation_noise_factor,
        min_band: TsdfConfig::default().min_truncation_voxels,
        ideal: false,
        skip_tracking: false,
        max_depth: TsdfConfig::default().max_depth,
        min_weights: vec![0.0],
        min_components: vec![0],
        color_band: TsdfConfig::default().color_band_voxels,
        behind_band: TsdfConfig::default().behind_band,
        pair_far: 0.0,
        compare_whole: false,
        group_frames: 2,
    };
    let mut flags = Flags::from_env();
    while let Some(flag) = flags.next_flag() {
        match flag.as_str() {
            "--frames" => a.frames = flags.value(&flag)?,
            "--voxel" => a.voxel = flags.value(&flag)?,
            "--trunc" => a.truncation = flags.value(&flag)?,
            "--band-factor" => a.band_factor = flags.value(&flag)?,
            "--min-band" => a.min_band = flags.value(&flag)?,
            "--max-depth" => a.max_depth = flags.value(&flag)?,
            "--min-weight" => a.min_weights = comma_list(&flag, &flags.value::<String>(&flag)?)?,
            "--min-component" => a.min_components = comma_list(&flag, &flags.value::<String>(&flag)?)?,
            "--ideal" => a.ideal = true,
            "--color-band" => a.color_band = flags.value(&flag)?,
            "--behind-band" => a.behind_band = flags.value(&flag)?,
            "--far-group-beyond" => a.pair_far = flags.value(&flag)?,
            "--far-group-frames" => a.group_frames = flags.value(&flag)?,
            "--compare-whole" => a.compare_whole = true,
            "--skip-tracking" => a.skip_tracking = true,
            "--size" => a.size = flags.size(&flag)?,
            s if !s.starts_with("--") && a.source.is_empty() => a.source = s.to_string(),
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if a.source.is_empty() {
        return Err("usage: accuracy_bench synth:SEED|replica:DIR [--frames N] [--size WxH] ...".into());
    }
    Ok(a)
}

/// The first `n` camera-to-world poses of a Replica `traj.txt` (16 floats a line, row-major).
fn replica_poses(path: &Path, n: usize) -> Result<Vec<Affine3A>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut poses = Vec::new();
    for (line_no, line) in text.lines().enumerate().take(n) {
        let v: Vec<f32> = line
            .split_whitespace()
            .map(|t| t.parse::<f32>().map_err(|e| format!("{}:{}: {e}", path.display(), line_no + 1)))
            .collect::<Result<_, _>>()?;
        if v.len() != 16 {
            return Err(format!("{}:{}: expected 16 numbers, got {}", path.display(), line_no + 1, v.len()));
        }
        let m = Mat4::from_cols_array(&v.try_into().map_err(|_| "16 numbers")?).transpose();
        poses.push(Affine3A::from_mat4(m));
    }
    Ok(poses)
}

/// The ground-truth surface samples (5 mm spacing) that some frame saw: rendered without
/// noise from `poses`, the sample projects inside the image, at a depth within
/// `depth_range`, and within 2 cm of the rendered depth of its pixel (not hidden behind
/// another surface; the margin covers a pixel's footprint on surfaces seen at a grazing
/// angle). Also returns the number of samples.
fn seen_samples(
    gt: &LabeledMesh,
    poses: &[Affine3A],
    k: Intrinsics,
    depth_range: (f32, f32),
) -> Result<(Vec<Vec3>, usize), String> {
    let points = sample_surface(gt, 0.005, 2_000_000, 0x5ee7).map_err(|e| e.to_string())?.points;
    let ideal = RenderedScan::new("visibility", gt, poses.to_vec(), k, SensorModel::ideal(), 30.0)
        .map_err(|e| e.to_string())?;
    let mut seen = vec![false; points.len()];
    let (w, h) = (k.width as i64, k.height as i64);
    for (i, pose) in poses.iter().enumerate() {
        let depth = ideal.frame(i).map_err(|e| e.to_string())?.depth;
        let camera_from_world = pose.inverse();
        seen.par_iter_mut().zip(&points).filter(|(s, _)| !**s).for_each(|(s, p)| {
            let q = camera_from_world.transform_point3(*p);
            if !(depth_range.0..=depth_range.1).contains(&q.z) {
                return;
            }
            let uv = k.project(q);
            let (u, v) = ((uv.x + 0.5).floor() as i64, (uv.y + 0.5).floor() as i64);
            if u < 0 || v < 0 || u >= w || v >= h {
                return;
            }
            let d = depth[(v * w + u) as usize];
            *s = d > 0.0 && (d - q.z).abs() < 0.02;
        });
    }
    let total = points.len();
    Ok((points.into_iter().zip(seen).filter(|(_, s)| *s).map(|(p, _)| p).collect(), total))
}

fn run(a: Args) -> Result<(), String> {
    let sensor = |seed: u64| if a.ideal { SensorModel::ideal() } else { SensorModel::kinect().with_seed(seed) };
    let k =
        Intrinsics::new(640, 480, 525.0, 525.0, 319.5, 239.5).map_err(|e| e.to_string())?.scaled(a.size.0, a.size.1);
    let (gt_mesh, scan): (LabeledMesh, RenderedScan) = if let Some(seed) = a.source.strip_prefix("synth:") {
        let seed: u64 = seed.parse().map_err(|e| format!("{}: {e}", a.source))?;
        let mut config = SyntheticScanConfig::new(seed);
        config.frames = a.frames;
        config.intrinsics = k;
        config.sensor = sensor(seed);
        let (room, scan) = synthetic_scan(&config).map_err(|e| e.to_string())?;
        (room.mesh, scan)
    } else if let Some(dir) = a.source.strip_prefix("replica:") {
        let dir = Path::new(dir);
        let mesh = read_ply(dir.join("office0_mesh.ply")).map_err(|e| e.to_string())?;
        let poses = replica_poses(&dir.join("office0/traj.txt"), a.frames)?;
        let scan = RenderedScan::new("replica office0", &mesh, poses, k, sensor(0), 30.0).map_err(|e| e.to_string())?;
        (mesh, scan)
    } else {
        return Err(format!("{}: expected synth:SEED or replica:DIR", a.source));
    };
    let n = scan.len();
    let frames: Vec<_> = (0..n).map(|i| scan.frame(i).map_err(|e| e.to_string())).collect::<Result<_, _>>()?;
    let map_config = TsdfConfig {
        truncation_voxels: a.truncation,
        truncation_noise_factor: a.band_factor,
        min_truncation_voxels: a.min_band,
        max_depth: a.max_depth,
        color_band_voxels: a.color_band,
        behind_band: a.behind_band,
        far_group_beyond_m: a.pair_far,
        far_group_frames: a.group_frames,
        ..TsdfConfig::with_voxel_size(a.voxel).map_err(|e| e.to_string())?
    };
    println!(
        "{} frames of {} at {}x{}, {} sensor, voxel {} mm, truncation {} voxels (band factor {})",
        n,
        a.source,
        a.size.0,
        a.size.1,
        if a.ideal { "ideal" } else { "Kinect-like" },
        a.voxel * 1e3,
        a.truncation,
        a.band_factor
    );

    // Mesh with ground-truth poses.
    let mut map = TsdfMap::new(map_config).map_err(|e| e.to_string())?;
    let mut pairing = GroupedFusion::new(a.pair_far, a.group_frames);
    for f in &frames {
        let pose = f.world_from_camera.ok_or("rendered frames have poses")?;
        pairing.integrate(&mut map, f, pose).map_err(|e| e.to_string())?;
    }
    pairing.flush(&mut map).map_err(|e| e.to_string())?;
    let eval =
        MeshEvalConfig { sample_spacing_m: 0.005, thresholds_m: vec![0.005, 0.01, 0.05], ..MeshEvalConfig::default() };
    let poses: Vec<Affine3A> = frames.iter().filter_map(|f| f.world_from_camera).collect();
    let (seen, samples) = seen_samples(&gt_mesh, &poses, k, (map_config.min_depth, map_config.max_depth))?;
    println!(
        "seen by some frame: {} of {} ground-truth samples ({:.1}%)",
        seen.len(),
        samples,
        100.0 * seen.len() as f64 / samples.max(1) as f64
    );
    let settings: Vec<(f32, usize)> =
        a.min_weights.iter().flat_map(|&w| a.min_components.iter().map(move |&c| (w, c))).collect();
    for (min_weight, min_component) in settings {
        let config = MeshConfig { min_weight, min_component_triangles: min_component };
        let mesh = extract_mesh_with(&map, config).map_err(|e| e.to_string())?;
        let e = evaluate_mesh(&gt_mesh, &mesh, &eval).map_err(|e| e.to_string())?;
        let recall = |i: usize| e.scores[i].recall * 100.0;
        println!(
            "ground-truth poses, min weight {min_weight}, min component {min_component}: {} triangles; accuracy mean {:.2} mm, median {:.2} mm; \
             completeness {:.1}% within 5 mm, {:.1}% within 1 cm, {:.1}% within 5 cm \
             (1 cm over 5 cm: {:.1}% of the surface seen)",
            mesh.triangle_count(),
            e.accuracy_mean_m * 1e3,
            e.accuracy_median_m * 1e3,
            recall(0),
            recall(1),
            recall(2),
            100.0 * recall(1) / recall(2).max(1e-9)
        );
        let d = SurfaceIndex::new(&mesh, &eval, "estimated").map_err(|e| e.to_string())?.distances(&seen);
        let within = |t: f32| 100.0 * d.iter().filter(|&&x| x < t).count() as f64 / d.len().max(1) as f64;
        println!(
            "  of the seen samples: {:.1}% within 5 mm, {:.2}% within 1 cm, {:.1}% within 5 cm",
            within(0.005),
            within(0.01),
            within(0.05)
        );
    }

    if a.compare_whole {
        // Where far groups lose surface: the seen samples within 1 cm of a map fused frame by
        // frame but not of the grouped one, by their distance to the nearest camera.
        let mut whole =
            TsdfMap::new(TsdfConfig { far_group_beyond_m: 0.0, ..map_config }).map_err(|e| e.to_string())?;
        for f in &frames {
            whole.integrate(f, f.world_from_camera.ok_or("pose")?).map_err(|e| e.to_string())?;
        }
        let mc = MeshConfig { min_weight: 0.0, min_component_triangles: 0 };
        let mg = extract_mesh_with(&map, mc).map_err(|e| e.to_string())?;
        let mw = extract_mesh_with(&whole, mc).map_err(|e| e.to_string())?;
        let dg = SurfaceIndex::new(&mg, &eval, "g").map_err(|e| e.to_string())?.distances(&seen);
        let dw = SurfaceIndex::new(&mw, &eval, "w").map_err(|e| e.to_string())?.distances(&seen);
        let cams: Vec<Vec3> = poses.iter().map(|p| Vec3::from(p.translation)).collect();
        let bin = |p: &Vec3| {
            let d = cams.iter().map(|c| c.distance(*p)).fold(f32::MAX, f32::min);
            (d.floor() as usize).min(5)
        };
        let (mut all, mut lost, mut gained) = ([0usize; 6], [0usize; 6], [0usize; 6]);
        for ((p, g), w) in seen.iter().zip(&dg).zip(&dw) {
            let b = bin(p);
            all[b] += 1;
            if *w < 0.01 && *g >= 0.01 {
                lost[b] += 1;
            }
            if *g < 0.01 && *w >= 0.01 {
                gained[b] += 1;
            }
        }
        println!("against every frame fused whole, by nearest-camera distance (m) 0..5+: seen {all:?}\n  within 1 cm only without groups {lost:?}\n  only with groups {gained:?}");
        // Lost samples: how far is the grouped mesh from them?
        let mut far_lost: Vec<f32> =
            dg.iter().zip(&dw).filter(|(g, w)| **w < 0.01 && **g >= 0.01).map(|(g, _)| *g).collect();
        far_lost.sort_by(f32::total_cmp);
        if !far_lost.is_empty() {
            println!(
                "  the first kind's distance to the grouped mesh: median {:.3} m, p90 {:.3} m",
                far_lost[far_lost.len() / 2],
                far_lost[far_lost.len() * 9 / 10]
            );
        }
    }
    if !a.skip_tracking {
        let config = if a.size.0 < 640 {
            TrackerConfig { fine_stride: 1, model_downscale: 2, ..TrackerConfig::default() }
        } else {
            TrackerConfig::default()
        };
        let first = frames.first().and_then(|f| f.world_from_camera).unwrap_or(Affine3A::IDENTITY);
        let mut tracker = Tracker::with_initial_pose(config, first).map_err(|e| e.to_string())?;
        let mut tmap = TsdfMap::new(map_config).map_err(|e| e.to_string())?;
        let path = track_and_fuse(&frames, &mut tmap, |f, tmap| tracker.track(f, tmap).map_err(|e| e.to_string()))?;
        let (ate, lost) = (path.ate_mm(), path.lost);
        println!("tracking: ATE {ate:.2} mm (Horn, no scale), {lost} lost of {n}");
    }
    Ok(())
}

fn main() {
    if let Err(e) = parse_args().and_then(run) {
        eprintln!("accuracy_bench: {e}");
        std::process::exit(1);
    }
}

/// The values of a comma-separated flag value such as `--min-weight 0,0.25,0.5`.
fn comma_list<T: std::str::FromStr>(flag: &str, list: &str) -> Result<Vec<T>, String>
where
    T::Err: std::fmt::Display,
{
    list.split(',').map(|v| v.trim().parse::<T>().map_err(|e| format!("{flag} {v}: {e}"))).collect()
}
