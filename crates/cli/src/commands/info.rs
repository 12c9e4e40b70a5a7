//! `semrecon info`: what a dataset holds, as a table or JSON.

use anyhow::Context;
use semrecon_data::datasets::{open_dataset, DatasetSpec};
use serde::Serialize;

/// Arguments of `semrecon info`.
#[derive(clap::Args)]
pub struct InfoArgs {
    /// Dataset as KIND:PATH (7scenes:, tum:, redwood:, scannet:, replica:, oni:FILE, bag:FILE, synth:SEED),
    /// or a dataset folder or recording (the kind read from its files).
    #[arg(long, required_unless_present = "dataset_positional", conflicts_with = "dataset_positional")]
    dataset: Option<DatasetSpec>,
    /// The same, given without `--dataset` (`semrecon info ../shared/data/tum-fr2-desk-50`).
    #[arg(value_name = "DATASET")]
    dataset_positional: Option<DatasetSpec>,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// Frames sampled (evenly spaced) to estimate the depth range; 0 skips it.
    #[arg(long, default_value_t = 10)]
    depth_samples: usize,
}

#[derive(Serialize)]
struct Info {
    dataset: String,
    frames: usize,
    width: u32,
    height: u32,
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    frame_rate: f64,
    has_gt: bool,
    depth_min_m: Option<f32>,
    depth_max_m: Option<f32>,
    /// What else the reader says (depth units, registration, library).
    notes: Vec<String>,
}

/// Runs the command.
pub fn run(args: InfoArgs) -> anyhow::Result<()> {
    let spec = args
        .dataset
        .or(args.dataset_positional)
        .context("name a dataset: semrecon info DATASET (or --dataset DATASET)")?;
    let source = open_dataset(&spec).with_context(|| format!("opening {spec}"))?;
    let k = source.intrinsics();
    let mut range: Option<(f32, f32)> = None;
    let n = source.len();
    let samples = args.depth_samples.min(n);
    for s in 0..samples {
        // Evenly spaced, first and last included.
        let i = if samples == 1 { 0 } else { s * (n - 1) / (samples - 1) };
        let frame = source.frame(i)?;
        if let Some((lo, hi)) = frame.depth_range() {
            range = Some(match range {
                None => (lo, hi),
                Some((a, b)) => (a.min(lo), b.max(hi)),
            });
        }
    }
    let info = Info {
        dataset: source.name(),
        frames: n,
        width: k.width,
        height: k.height,
        fx: k.fx,
        fy: k.fy,
        cx: k.cx,
        cy: k.cy,
        frame_rate: source.frame_rate(),
        has_gt: source.has_ground_truth(),
        depth_min_m: range.map(|r| r.0),
        depth_max_m: range.map(|r| r.1),
        notes: source.notes(),
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&info)?);
    } else {
        println!("dataset      {}", info.dataset);
        println!("frames       {}", info.frames);
        println!("resolution   {}x{}", info.width, info.height);
        println!("intrinsics   fx {} fy {} cx {} cy {}", info.fx, info.fy, info.cx, info.cy);
        println!("frame rate   {} Hz", info.frame_rate);
        match range {
            Some((lo, hi)) => println!("depth range  {lo:.3} .. {hi:.3} m (over {samples} sampled frames)"),
            None => println!("depth range  none valid in {samples} sampled frames"),
        }
        println!("ground truth {}", if info.has_gt { "yes" } else { "no" });
        for note in &info.notes {
            println!("note         {note}");
        }
    }
    Ok(())
}
