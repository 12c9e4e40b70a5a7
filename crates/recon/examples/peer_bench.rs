//! Our side of the Open3D comparison (`bench/peers_recon.py`): the same frames, the same
//! threads, the same stages, printed as one JSON object on stdout.
//!
//! ```text
//! cargo run --release -p semrecon-recon --example peer_bench -- SPEC [--frames N]
//!     [--voxel M] [--trunc VOXELS] [--band-factor K] [--max-depth M]
//!     [--mesh-repeats R]
//! ```
//!
//! Stages, each timed per call (wall milliseconds; CPU milliseconds of all threads too, the
//! machine may be shared):
//! - `fusion`: chunk selection + integration of every frame at its ground-truth pose (what
//!   Open3D's `compute_unique_block_coordinates` + `integrate` do);
//! - `mesh_full`: marching cubes over the whole map after the last frame (`extract_mesh`,
//!   Open3D's `extract_triangle_mesh`), the fastest of `--mesh-repeats`;
//! - `tracking`: frame-to-model tracking of every frame (a separate map fed with the tracked
//!   poses), with the ATE (RMS after a rigid Horn alignment) against the ground truth.
//!
//! Thread count: `RAYON_NUM_THREADS`.

#[path = "common/cpu_time.rs"]
mod cpu_time;
#[path = "common/flags.rs"]
mod flags;
#[path = "common/tracked_path.rs"]
mod tracked_path;

use glam::Affine3A;
use semrecon_data::{open_dataset, DatasetSpec, Frame};
use semrecon_recon::{extract_mesh, Tracker, TrackerConfig, TrackingStatus, TsdfConfig, TsdfMap};

use cpu_time::timed;
use flags::Flags;
use tracked_path::track_and_fuse;

struct Args {
    spec: String,
    frames: usize,
    voxel: f32,
    truncation: f32,
    band_factor: f32,
    max_depth: f32,
    mesh_repeats: usize,
}

fn parse_args() -> Result<Args, String> {
    let mut flags = Flags::from_env();
    let mut a = Args {
        spec: String::new(),
        frames: usize::MAX,
        voxel: 0.005,
        truncation: 10.0,
        band_factor: TsdfConfig::default().truncation_noise_factor,
        max_depth: 5.0,
        mesh_repeats: 3,
    };
    while let Some(arg) = flags.next_flag() {
        match arg.as_str() {
            "--frames" => a.frames = flags.value(&arg)?,
            "--voxel" => a.voxel = flags.value(&arg)?,
            "--trunc" => a.truncation = flags.value(&arg)?,
            "--band-factor" => a.band_factor = flags.value(&arg)?,
            "--max-depth" => a.max_depth = flags.value(&arg)?,
            "--mesh-repeats" => a.mesh_repeats = flags.value(&arg)?,
            s if !s.starts_with("--") && a.spec.is_empty() => a.spec = s.to_string(),
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if a.spec.is_empty() {
        return Err("usage: peer_bench SPEC [--frames N] [--voxel M] [--trunc VOXELS] [--max-depth M]".into());
    }
    Ok(a)
}

fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

fn stage(wall: &[f64], cpu: &[f64]) -> String {
    format!(
        "{{\"median_ms\": {:.3}, \"mean_ms\": {:.3}, \"cpu_median_ms\": {:.3}, \"calls\": {}}}",
        median(wall),
        mean(wall),
        median(cpu),
        wall.len()
    )
}

fn run(a: Args) -> Result<(), String> {
    let spec: DatasetSpec = a.spec.parse().map_err(|e| format!("{}: {e}", a.spec))?;
    let source = open_dataset(&spec).map_err(|e| e.to_string())?;
    let n = source.len().min(a.frames);
    let frames: Vec<Frame> = (0..n).map(|i| source.frame(i).map_err(|e| e.to_string())).collect::<Result<_, _>>()?;
    let map_config = TsdfConfig {
        truncation_voxels: a.truncation,
        truncation_noise_factor: a.band_factor,
        max_depth: a.max_depth,
        ..TsdfConfig::with_voxel_size(a.voxel).map_err(|e| e.to_string())?
    };
    map_config.validate().map_err(|e| e.to_string())?;

    // Fusion at the ground-truth poses.
    let mut map = TsdfMap::new(map_config).map_err(|e| e.to_string())?;
    let (mut fuse_wall, mut fuse_cpu) = (Vec::new(), Vec::new());
    for f in &frames {
        let Some(pose) = f.world_from_camera else { continue };
        let (r, w, c) = timed(|| map.integrate(f, pose));
        r.map_err(|e| e.to_string())?;
        fuse_wall.push(w);
        fuse_cpu.push(c);
    }
    let (mut mesh_wall, mut mesh_cpu) = (Vec::new(), Vec::new());
    let mut triangles = 0;
    for _ in 0..a.mesh_repeats.max(1) {
        let (m, w, c) = timed(|| extract_mesh(&map));
        triangles = m.triangle_count();
        mesh_wall.push(w);
        mesh_cpu.push(c);
    }
    let fastest = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);

    // Tracking with its own map.
    let mut tmap = TsdfMap::new(map_config).map_err(|e| e.to_string())?;
    let config = TrackerConfig { max_depth: a.max_depth, ..TrackerConfig::default() };
    let initial = frames.first().and_then(|f| f.world_from_camera).unwrap_or(Affine3A::IDENTITY);
    let mut tracker = Tracker::with_initial_pose(config, initial).map_err(|e| e.to_string())?;
    let (mut track_wall, mut track_cpu) = (Vec::new(), Vec::new());
    let path = track_and_fuse(&frames, &mut tmap, |f, tmap| {
        let (r, w, c) = timed(|| tracker.track(f, tmap));
        let r = r.map_err(|e| e.to_string())?;
        if r.status == TrackingStatus::Tracked {
            track_wall.push(w);
            track_cpu.push(c);
        }
        Ok(r)
    })?;
    let (ate, lost) = (path.ate_mm(), path.lost);
    println!(
        "{{\"name\": \"semrecon\", \"frames\": {n}, \"threads\": {}, \"voxel_m\": {}, \"truncation_voxels\": {}, \
         \"chunks\": {}, \"map_bytes\": {}, \"bytes_per_chunk\": {}, \"fusion\": {}, \
         \"mesh_full\": {{\"median_ms\": {:.3}, \"cpu_median_ms\": {:.3}, \"triangles\": {triangles}}}, \
         \"tracking\": {}, \"ate_mm\": {ate:.3}, \"lost\": {lost}}}",
        rayon::current_num_threads(),
        a.voxel,
        a.truncation,
        map.chunk_count(),
        map.memory_bytes(),
        TsdfMap::bytes_per_chunk(),
        stage(&fuse_wall, &fuse_cpu),
        fastest(&mesh_wall),
        fastest(&mesh_cpu),
        stage(&track_wall, &track_cpu),
    );
    Ok(())
}

fn main() {
    if let Err(e) = parse_args().and_then(run) {
        eprintln!("peer_bench: {e}");
        std::process::exit(1);
    }
}
