//! `semrecon synth`: a labelled synthetic room (or any mesh) rendered along a handheld-like
//! scan (or a given trajectory), written as a dataset in the 7-Scenes layout that
//! `7scenes:DIR` reads back, with the scene mesh and the ground-truth trajectory.

use std::path::PathBuf;

use anyhow::{bail, Context};
use rayon::prelude::*;
use semrecon_data::datasets::synthetic::room_scan_poses;
use semrecon_data::datasets::SevenScenesWriter;
use semrecon_data::synth::{generate_room, RoomConfig, RoomStyle};
use semrecon_data::{
    read_ply, write_ply, FrameSource, Intrinsics, PlyEncoding, RenderedScan, ScanPlan, SensorModel, Trajectory,
};

use crate::progress::progress_bar;

/// Arguments of `semrecon synth`.
#[derive(clap::Args)]
pub struct SynthArgs {
    /// Output folder (created; existing frames are overwritten).
    #[arg(long)]
    out: PathBuf,
    /// Seed of the room, the trajectory and the sensor noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Number of frames (with --traj: at most the trajectory's length; default all of it).
    #[arg(long)]
    frames: Option<usize>,
    /// Room style of the generated room (office, conference, lounge, hallway, or the
    /// held-out classroom, which training never sees); drawn from the seed (never
    /// classroom) when absent.
    #[arg(long, conflicts_with = "mesh")]
    style: Option<RoomStyle>,
    /// Render this mesh (PLY, z up unless --traj is given) instead of a generated room.
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// Camera trajectory (TUM, Redwood .log, or one row-major 4x4 camera-to-world per line)
    /// instead of a generated scan.
    #[arg(long)]
    traj: Option<PathBuf>,
    /// Camera intrinsics fx,fy,cx,cy in pixels (default 525,525 and the image centre).
    #[arg(long, value_parser = parse_intrinsics)]
    intrinsics: Option<[f32; 4]>,
    /// Image size WxH.
    #[arg(long, default_value = "640x480", value_parser = parse_size)]
    size: (u32, u32),
    /// Perfect depth: switch the Kinect-like sensor model off.
    #[arg(long)]
    no_noise: bool,
}

fn parse_intrinsics(s: &str) -> Result<[f32; 4], String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("`{s}`: {e}; expected fx,fy,cx,cy"))?;
    match v[..] {
        [fx, fy, cx, cy] if v.iter().all(|x| x.is_finite()) && fx > 0.0 && fy > 0.0 => Ok([fx, fy, cx, cy]),
        _ => Err(format!("`{s}`: expected four finite numbers fx,fy,cx,cy with positive focal lengths")),
    }
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| format!("`{s}`: expected WxH, e.g. 640x480"))?;
    let w: u32 = w.trim().parse().map_err(|e| format!("`{s}`: width: {e}"))?;
    let h: u32 = h.trim().parse().map_err(|e| format!("`{s}`: height: {e}"))?;
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        return Err(format!("`{s}`: width and height must be 1..=16384"));
    }
    Ok((w, h))
}

/// Runs the command.
pub fn run(args: SynthArgs) -> anyhow::Result<()> {
    let (width, height) = args.size;
    let [fx, fy, cx, cy] = args.intrinsics.unwrap_or([
        525.0 * width as f32 / 640.0,
        525.0 * width as f32 / 640.0,
        (width as f32 - 1.0) / 2.0,
        (height as f32 - 1.0) / 2.0,
    ]);
    let intrinsics = Intrinsics::new(width, height, fx, fy, cx, cy)?;
    let frame_rate = 30.0;

    let (mesh, name, generated) = match &args.mesh {
        Some(path) => {
            let mesh = read_ply(path)?;
            if mesh.triangles.is_empty() {
                bail!("{}: the mesh has no triangles to render", path.display());
            }
            (mesh, format!("mesh {}", path.display()), None)
        }
        None => {
            let room = generate_room(&RoomConfig { seed: args.seed, style: args.style });
            let name = format!("{} room, seed {}", room.style, args.seed);
            (room.mesh.clone(), name, Some(room))
        }
    };

    let poses = match (&args.traj, &generated) {
        (Some(path), _) => {
            let traj = Trajectory::read_any(path)?;
            let n = args.frames.unwrap_or(traj.len()).min(traj.len());
            if n == 0 {
                bail!("{}: the trajectory has no poses", path.display());
            }
            traj.poses[..n].to_vec()
        }
        (None, Some(room)) => room_scan_poses(room, args.seed, args.frames.unwrap_or(300), frame_rate)?,
        (None, None) => ScanPlan::from_mesh_bounds(&mesh, args.seed)?.poses(args.frames.unwrap_or(300))?,
    };

    let sensor = if args.no_noise { SensorModel::ideal() } else { SensorModel::kinect().with_seed(args.seed) };
    let scan = RenderedScan::new(name.clone(), &mesh, poses.clone(), intrinsics, sensor, frame_rate)?;

    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let writer = SevenScenesWriter::new(&args.out, &intrinsics)?;
    let bar = progress_bar(scan.len() as u64, "rendering");
    (0..scan.len()).into_par_iter().try_for_each(|i| -> anyhow::Result<()> {
        let frame = scan.frame(i)?;
        writer.write_frame(&frame)?;
        bar.inc(1);
        Ok(())
    })?;
    bar.finish_and_clear();

    let mut traj = Trajectory::default();
    for (i, pose) in poses.iter().enumerate() {
        traj.push(i as f64 / frame_rate, *pose);
    }
    traj.write_tum(args.out.join("groundtruth.txt"))?;
    write_ply(args.out.join("scene.ply"), &mesh, PlyEncoding::BinaryLittleEndian)?;

    println!(
        "wrote {} frames ({width}x{height}) of {name} to {}: frame-NNNNNN.{{depth,color,label}}.png, .pose.txt, \
         camera-intrinsics.txt, groundtruth.txt (TUM), scene.ply ({} triangles)",
        scan.len(),
        args.out.display(),
        mesh.triangle_count()
    );
    println!("read it back with: semrecon info --dataset 7scenes:{}", args.out.display());
    Ok(())
}
