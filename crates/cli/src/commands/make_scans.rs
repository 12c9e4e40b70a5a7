//! `semrecon make-scans`: training data that looks like what the live system labels. For
//! every seed, a generated room (as `semrecon synth` makes it) is scanned along a handheld
//! trajectory through the Kinect-like sensor model, the noisy frames are fused into a TSDF
//! map at their ground-truth poses and meshed, and every vertex of the reconstruction gets
//! the class of the nearest ground-truth surface ([`SurfaceLabeler`]). The reconstruction has
//! the sensor's noise, the fusion's smoothing and the holes of an incomplete scan, which clean
//! synthetic meshes do not; `--partial` fuses only a short stretch of the trajectory, like the
//! growing map the live system segments.
//!
//! `--library` scans rooms furnished from the furniture catalogues (homes and offices with
//! modelled furniture, `semrecon_data::library::rooms`, training models only unless
//! `--held-out`) instead of the procedural rooms: the real-rooms training data whose
//! colours, holes and noise are those of a live map.
//!
//! Output: `DIR/room_SEED.ply` (binary) with vertex `x y z red green blue label` and the
//! mesh's faces, readable by the training data source `ply:DIR`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use semrecon_data::class::UNLABELED;
use semrecon_data::datasets::synthetic::{synthetic_scan, synthetic_scan_of, SyntheticScanConfig};
use semrecon_data::library::rooms::{generate_library_room_detailed, LibraryRoomConfig};
use semrecon_data::library::{FurnitureLibrary, Split};
use semrecon_data::synth::RoomStyle;
use semrecon_data::{write_ply, FrameSource, PlyEncoding};
use semrecon_eval::SurfaceLabeler;
use semrecon_recon::{extract_mesh, TsdfConfig, TsdfMap};
use serde::Serialize;

/// Arguments of `semrecon make-scans`.
#[derive(clap::Args)]
pub struct MakeScansArgs {
    /// Room seeds as A..B (B excluded) or one seed.
    #[arg(long, value_parser = parse_seeds)]
    seeds: (u64, u64),
    /// Output folder (created); `room_SEED.ply` per seed, overwritten.
    #[arg(long)]
    out: PathBuf,
    /// Frames of each scan's trajectory (30 per second).
    #[arg(long, default_value_t = 300)]
    frames: usize,
    /// Fuse only a stretch of a quarter of the frames, at a seeded place in the trajectory
    /// (an incomplete map, as the live system sees while scanning).
    #[arg(long)]
    partial: bool,
    /// Scan rooms furnished from the furniture catalogues (Debian's sweethome3d-furniture)
    /// instead of the procedural rooms; the kind is drawn from the seed.
    #[arg(long)]
    library: bool,
    /// With --library: furnish with the held-out models only (furniture training never sees).
    #[arg(long, requires = "library")]
    held_out: bool,
    /// Room style (office, conference, lounge, hallway, or the held-out classroom); drawn
    /// from each seed, among the trained styles, when absent.
    #[arg(long)]
    style: Option<RoomStyle>,
    /// Render through the uncalibrated sensor (more depth noise and a radial depth bias,
    /// `SensorModel::kinect_uncalibrated`): reconstructions with the bent walls of an
    /// uncalibrated camera, as `synth:SEED:noisy` sources give.
    #[arg(long)]
    noisy: bool,
    /// Rendered image size WxH (depth and colour).
    #[arg(long, default_value = "320x240", value_parser = parse_size)]
    size: (u32, u32),
    /// TSDF voxel size in metres.
    #[arg(long, default_value_t = 0.02)]
    voxel: f32,
    /// Vertices further than this (metres) from the ground-truth surface stay unlabelled (255).
    #[arg(long, default_value_t = 0.1)]
    max_distance: f32,
    /// Skip seeds whose file already exists (to resume an interrupted run).
    #[arg(long)]
    keep_existing: bool,
    /// Also write a JSON summary (one row per room) to this file.
    #[arg(long)]
    json: Option<PathBuf>,
}

/// Parses `A..B` (B excluded) or `A`.
fn parse_seeds(s: &str) -> Result<(u64, u64), String> {
    let bad = |e: String| format!("`{s}`: {e}; expected seeds A..B (B excluded) or one seed A");
    let (a, b) = match s.split_once("..") {
        Some((a, b)) => (a.trim(), b.trim()),
        None => (s.trim(), ""),
    };
    let a: u64 = a.parse().map_err(|e| bad(format!("{e}")))?;
    let b: u64 = if b.is_empty() && !s.contains("..") { a + 1 } else { b.parse().map_err(|e| bad(format!("{e}")))? };
    if b <= a {
        return Err(bad("the range is empty".into()));
    }
    Ok((a, b))
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| format!("`{s}`: expected WxH, e.g. 320x240"))?;
    let w: u32 = w.trim().parse().map_err(|e| format!("`{s}`: width: {e}"))?;
    let h: u32 = h.trim().parse().map_err(|e| format!("`{s}`: height: {e}"))?;
    if !(16..=4096).contains(&w) || !(16..=4096).contains(&h) {
        return Err(format!("`{s}`: width and height must be 16..=4096"));
    }
    Ok((w, h))
}

/// What one room produced.
#[derive(Serialize)]
struct RoomRow {
    seed: u64,
    style: String,
    file: String,
    frames_fused: usize,
    vertices: usize,
    triangles: usize,
    /// Share of vertices with a class (the rest were too far from the true surface).
    labelled: f64,
    render_s: f64,
    fusion_s: f64,
    label_s: f64,
    total_s: f64,
}

/// Frames rendered at once (in parallel) before they are fused in order.
const RENDER_BATCH: usize = 16;

/// Runs the command.
pub fn run(args: MakeScansArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.frames >= 4, "--frames {}: at least 4", args.frames);
    anyhow::ensure!(
        args.voxel.is_finite() && (0.002..=0.1).contains(&args.voxel),
        "--voxel {}: must be 0.002..=0.1 m",
        args.voxel
    );
    anyhow::ensure!(args.max_distance > 0.0, "--max-distance must be positive");
    anyhow::ensure!(
        !(args.library && args.style.is_some()),
        "--style names a procedural style: it does not go with --library"
    );
    let library = if args.library { Some(FurnitureLibrary::open_default()?) } else { None };
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let (first, end) = args.seeds;
    let mut rows = Vec::new();
    for seed in first..end {
        let file = args.out.join(format!("room_{seed}.ply"));
        if args.keep_existing && file.exists() {
            println!("seed {seed}: {} exists, kept", file.display());
            continue;
        }
        let row = make_room(&args, library.as_ref(), seed, &file).with_context(|| format!("room of seed {seed}"))?;
        println!(
            "seed {:>4} {:<10} {:>4} frames {:>8} vertices {:>5.1}% labelled  {:>5.1} s (render {:.1}, fuse+mesh {:.1}, label {:.1})  {}",
            row.seed,
            row.style,
            row.frames_fused,
            row.vertices,
            100.0 * row.labelled,
            row.total_s,
            row.render_s,
            row.fusion_s,
            row.label_s,
            row.file
        );
        rows.push(row);
    }
    if !rows.is_empty() {
        let mean = rows.iter().map(|r| r.total_s).sum::<f64>() / rows.len() as f64;
        println!("{} rooms, {mean:.1} s per room, in {}", rows.len(), args.out.display());
    }
    if let Some(path) = &args.json {
        semrecon_data::atomic_file::write_atomic(path, serde_json::to_string_pretty(&rows)?.as_bytes())?;
    }
    Ok(())
}

fn make_room(
    args: &MakeScansArgs,
    library: Option<&FurnitureLibrary>,
    seed: u64,
    file: &std::path::Path,
) -> anyhow::Result<RoomRow> {
    let t0 = Instant::now();
    let mut config = SyntheticScanConfig::new(seed);
    config.frames = args.frames;
    config.style = args.style;
    config.intrinsics = config.intrinsics.scaled(args.size.0, args.size.1);
    if args.noisy {
        config.sensor = semrecon_data::SensorModel::kinect_uncalibrated().with_seed(seed);
    }
    let (room, scan, style) = match library {
        Some(library) => {
            let split = if args.held_out { Split::HeldOut } else { Split::Train };
            let furnished = generate_library_room_detailed(&LibraryRoomConfig { seed, kind: None, split }, library)?;
            let kind = furnished.kind.to_string();
            let (room, scan) = synthetic_scan_of(furnished.room, &config)?;
            (room, scan, kind)
        }
        None => {
            let (room, scan) = synthetic_scan(&config)?;
            let style = room.style.to_string();
            (room, scan, style)
        }
    };
    let frames: Vec<usize> = if args.partial {
        let len = (args.frames / 4).max(2);
        // Another stream than the room's and the trajectory's, so the window is independent.
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7061_7274_6961_6c00);
        let start = rng.random_range(0..=args.frames - len);
        (start..start + len).collect()
    } else {
        (0..scan.len()).collect()
    };
    // Re-meshed once at the end: intermediate meshes are not needed.
    let mut tsdf = TsdfConfig::with_voxel_size(args.voxel).with_context(|| format!("voxel size {} m", args.voxel))?;
    tsdf.truncation_voxels = 4.0;
    let mut map = TsdfMap::new(tsdf)?;
    let mut render_s = 0.0;
    let t_fuse = Instant::now();
    for batch in frames.chunks(RENDER_BATCH) {
        let t = Instant::now();
        let rendered = batch.par_iter().map(|&i| scan.frame(i)).collect::<Result<Vec<_>, _>>()?;
        render_s += t.elapsed().as_secs_f64();
        for frame in &rendered {
            let pose = frame.world_from_camera.context("a synthetic frame without its ground-truth pose")?;
            map.integrate(frame, pose)?;
        }
    }
    let mut mesh = extract_mesh(&map);
    let fusion_s = t_fuse.elapsed().as_secs_f64() - render_s;
    let t = Instant::now();
    let labeler = SurfaceLabeler::new(&room.mesh, args.max_distance)?;
    mesh.vertex_labels = labeler.labels(&mesh.positions);
    mesh.normals.clear();
    mesh.triangle_labels.clear();
    let label_s = t.elapsed().as_secs_f64();
    let labelled = mesh.vertex_labels.iter().filter(|&&l| l != UNLABELED).count();
    write_ply(file, &mesh, PlyEncoding::BinaryLittleEndian)?;
    Ok(RoomRow {
        seed,
        style,
        file: file.display().to_string(),
        frames_fused: frames.len(),
        vertices: mesh.positions.len(),
        triangles: mesh.triangles.len(),
        labelled: labelled as f64 / mesh.positions.len().max(1) as f64,
        render_s,
        fusion_s,
        label_s,
        total_s: t0.elapsed().as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seed_ranges_parse() {
        assert_eq!(parse_seeds("3..7"), Ok((3, 7)));
        assert_eq!(parse_seeds("5"), Ok((5, 6)));
        assert!(parse_seeds("7..3").is_err());
        assert!(parse_seeds("a..3").is_err());
        assert!(parse_seeds("3..").is_err());
    }
}
