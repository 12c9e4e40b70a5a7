//! `semrecon ar`: the paper's AR application on a recorded scan: virtual balls thrown from
//! the camera bounce around the room (class materials) and are drawn over the RGB frames,
//! hidden behind real geometry; PNG frames and an animated GIF.

use std::path::PathBuf;

use anyhow::Context;
use semrecon_data::datasets::{open_dataset, DatasetSpec};
use semrecon_data::read_ply_with_gravity;
use semrecon_physics::MaterialTable;
use semrecon_viewer::ar::{render_ar, ArOptions};
use semrecon_viewer::folder::find_mesh;

/// Arguments of `semrecon ar`.
#[derive(clap::Args)]
pub struct ArArgs {
    /// Dataset with poses as KIND:PATH (7scenes:, tum:, redwood:, scannet:, replica:), or its
    /// folder (the kind read from its files).
    #[arg(long)]
    dataset: String,
    /// Output folder: frame-NNNNNN.png and ar.gif.
    #[arg(long)]
    out: PathBuf,
    /// Room mesh for collisions and occlusion (labelled PLY); default: the dataset folder's
    /// mesh (e.g. scene.ply of `semrecon synth`).
    #[arg(long)]
    mesh: Option<PathBuf>,
    /// Materials per class (TOML); the shipped defaults when absent.
    #[arg(long)]
    materials: Option<PathBuf>,
    /// Label set of the mesh's `label` property: s3dis (as `run` and `demo` write) or home
    /// (`segment --labels home`); picks the `[classes.*]` or `[home.*]` materials.
    #[arg(long, default_value = "s3dis", value_parser = crate::commands::segment::parse_label_set)]
    labels: semrecon_data::LabelSet,
    /// At most this many frames.
    #[arg(long, default_value_t = 300)]
    frames: usize,
    /// Throw speed in m/s.
    #[arg(long, default_value_t = 3.0)]
    speed: f32,
    /// A new ball every this many seconds.
    #[arg(long, default_value_t = 1.5)]
    every: f32,
}

/// Runs the command.
pub fn run(args: ArArgs) -> anyhow::Result<()> {
    let spec: DatasetSpec = args.dataset.parse()?;
    let source = open_dataset(&spec).with_context(|| format!("opening {}", args.dataset))?;
    let mesh_path = match &args.mesh {
        Some(p) => p.clone(),
        None => {
            let dir = spec.path().context("a generated scene has no room mesh beside it: pass --mesh")?;
            find_mesh(dir).with_context(|| format!("no room mesh for {}: pass --mesh", args.dataset))?
        }
    };
    // A reconstruction's mesh is in its dataset's frame and records that frame's up.
    let (mesh, gravity) = read_ply_with_gravity(&mesh_path)?;
    let materials = match &args.materials {
        Some(p) => MaterialTable::load(p)?,
        None => MaterialTable::defaults(),
    }
    .with_label_set(args.labels);
    let options = ArOptions {
        max_frames: args.frames,
        speed: args.speed,
        throw_every_s: args.every,
        gravity,
        ..Default::default()
    };
    let summary = render_ar(source.as_ref(), &mesh, materials, &args.out, &options)?;
    println!(
        "wrote {} frames with {} balls to {}/frame-NNNNNN.png and {} ({} ball pixels drawn, {} hidden behind the room)",
        summary.frames,
        summary.balls,
        args.out.display(),
        summary.gif.display(),
        summary.ball_pixels.0,
        summary.ball_pixels.1
    );
    Ok(())
}
