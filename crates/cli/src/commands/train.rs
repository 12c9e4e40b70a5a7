//! `semrecon train`: trains CBSCN with burn on labelled rooms (synthetic, S3DIS, ScanNet,
//! labelled PLY reconstructions) and writes checkpoints, the best weights by validation mIoU
//! and a JSON-lines log (see docs/model.md for the recipe). Training needs the `train` cargo
//! feature (burn takes minutes to build); without it the command explains how to get it.

use std::path::PathBuf;

/// Arguments of `semrecon train`.
#[derive(clap::Args)]
pub struct TrainArgs {
    /// Network configuration: a name (s20, s50, live) or a JSON/TOML file.
    #[arg(long)]
    config: String,
    /// Training data sources: synth:A..B[:style,...], s3dis:PATH, scannet:PATH, ply:PATH.
    #[arg(long, required = true, num_args = 1..)]
    data: Vec<String>,
    /// Validation data sources (same forms; never augmented). Default: synth:1000000..1000040.
    #[arg(long, num_args = 1..)]
    val: Vec<String>,
    /// Output folder: last.safetensors, best.safetensors, state.json, adam.bin, log.jsonl.
    #[arg(long)]
    out: PathBuf,
    /// Optimiser steps (the length of the learning-rate schedule).
    #[arg(long, default_value_t = 10_000)]
    steps: u64,
    /// Wall-clock budget in minutes: the schedule ends at whichever of --steps and the budget
    /// comes first.
    #[arg(long)]
    minutes: Option<f64>,
    /// Rooms per step.
    #[arg(long, default_value_t = 2)]
    batch: usize,
    /// Peak learning rate (Adam; warm-up then cosine decay).
    #[arg(long, default_value_t = 1e-3)]
    lr: f32,
    /// Largest sample in voxels (bigger rooms are cut around a random voxel).
    #[arg(long, default_value_t = 60_000)]
    max_voxels: usize,
    /// Per-class loss weights, 13 comma-separated numbers (default: uniform).
    #[arg(long)]
    class_weights: Option<String>,
    /// Validate every N steps (and every 10 minutes, and at the end).
    #[arg(long, default_value_t = 500)]
    val_every: u64,
    /// Write a checkpoint every N steps (and every 5 minutes, and at the end).
    #[arg(long, default_value_t = 200)]
    checkpoint_every: u64,
    /// Continue from the checkpoint in --out (weights, optimiser state, data position,
    /// elapsed time); starts afresh when --out holds no checkpoint.
    #[arg(long)]
    resume: bool,
    /// Seed of initialisation, room order and augmentation.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Augmentation recipe: `training` (rotations, flips, scaling, elastic distortion, box
    /// crops, dropout, colour), `live-maps` (the same plus a short walk's view and rugs on
    /// the floor, to imitate the partial maps the live pipeline labels), `casual-scans`
    /// (`live-maps` plus cuts above 1.0-2.2 m, as a scan that rarely looks up) or
    /// `real-rooms` (`casual-scans` plus a real camera's colours half of the time),
    /// `real-scans` (`real-rooms` with the ceiling dropped half of the time, the floor 15 %)
    /// or `real-homes` (`real-scans` with walls, doors and furniture repainted in other
    /// materials, each class 15 % of the time) or `real-fragments` (`real-homes` with the
    /// walls along some sides of the room dropped 20 % of the time).
    #[arg(long, default_value = "training", value_parser = semrecon_net::dataset::Augment::RECIPES)]
    augment: String,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Start from these weights (e.g. the shipped model, to fine-tune it) instead of a random
    /// initialisation; ignored when --resume finds a checkpoint.
    #[arg(long)]
    init: Option<PathBuf>,
}

/// Runs `semrecon train`.
#[cfg(not(feature = "train"))]
pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let _ = args;
    anyhow::bail!(
        "this semrecon was built without training support; build it with the `train` feature: \
         cargo run --release --features train -- train ..."
    )
}

/// Runs `semrecon train`.
#[cfg(feature = "train")]
pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    use anyhow::Context;
    use semrecon_net::dataset::{rooms_of, DataSource};
    use semrecon_net::train::{train, TrainOptions};
    use semrecon_net::NetConfig;

    if let Some(t) = args.threads {
        rayon::ThreadPoolBuilder::new().num_threads(t.max(1)).build_global().context("setting up the thread pool")?;
    }
    let config = NetConfig::from_name_or_file(&args.config)?;
    let parse_all = |specs: &[String]| -> anyhow::Result<Vec<DataSource>> {
        specs.iter().map(|s| DataSource::parse(s).map_err(anyhow::Error::from)).collect()
    };
    let train_rooms = rooms_of(&parse_all(&args.data)?)?;
    let val_specs = if args.val.is_empty() { vec!["synth:1000000..1000040".to_string()] } else { args.val.clone() };
    let val_rooms = rooms_of(&parse_all(&val_specs)?)?;
    let class_weights = match &args.class_weights {
        Some(s) => Some(
            s.split(',')
                .map(|x| x.trim().parse::<f32>().with_context(|| format!("--class-weights: `{x}` is not a number")))
                .collect::<anyhow::Result<Vec<f32>>>()?,
        ),
        None => None,
    };
    let mut opts = TrainOptions::new(config.clone(), train_rooms, val_rooms, args.out.clone());
    opts.steps = args.steps;
    opts.time_budget = args.minutes.map(|m| std::time::Duration::from_secs_f64((m * 60.0).max(0.0)));
    opts.batch = args.batch.max(1);
    opts.lr = args.lr;
    opts.max_voxels = args.max_voxels;
    opts.class_weights = class_weights;
    opts.val_every_steps = args.val_every.max(1);
    opts.checkpoint_every_steps = args.checkpoint_every.max(1);
    opts.resume = args.resume;
    opts.init = args.init.clone();
    opts.seed = args.seed;
    opts.augment = semrecon_net::dataset::Augment::from_recipe(&args.augment).with_context(|| {
        format!("--augment {}: not one of {:?}", args.augment, semrecon_net::dataset::Augment::RECIPES)
    })?;
    eprintln!(
        "training {} on {} rooms, validating on {} rooms, output {}",
        config.summary(),
        opts.train_rooms.len(),
        opts.val_rooms.len(),
        args.out.display()
    );
    let bar = crate::progress::progress_bar(opts.steps, "train");
    if let Ok(style) = indicatif::ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} eta {eta}") {
        bar.set_style(style.progress_chars("=> "));
    }
    let state = train(&opts, &mut |p| {
        bar.set_position(p.step);
        let val = p.val_miou.map_or("-".to_string(), |m| format!("{:.1}%", m * 100.0));
        bar.set_message(format!(
            "loss {:.3} (mean {:.3}) lr {:.1e} val mIoU {val} {:.2} rooms/s {:.2} s/step",
            p.loss, p.mean_loss, p.lr, p.rooms_per_s, p.secs_per_step
        ));
        if let Some(m) = &p.message {
            bar.println(m);
        }
        // Without a terminal (nohup, CI) the bar is hidden: print a status line now and then.
        if bar.is_hidden() && (p.message.is_some() || p.step % 20 == 0) {
            eprintln!(
                "step {}/{}: loss {:.3} (mean {:.3}) lr {:.1e} val mIoU {val} {:.2} rooms/s {:.2} s/step{}",
                p.step,
                p.steps,
                p.loss,
                p.mean_loss,
                p.lr,
                p.rooms_per_s,
                p.secs_per_step,
                p.message.as_deref().map_or(String::new(), |m| format!("\n{m}"))
            );
        }
    })?;
    bar.finish();
    eprintln!(
        "done: {} steps in {:.0} s; best validation mIoU {} (step {}); weights in {}",
        state.step,
        state.elapsed_secs,
        state.best_miou.map_or("-".into(), |m| format!("{:.1} %", m * 100.0)),
        state.best_step.map_or("-".into(), |s| s.to_string()),
        args.out.display()
    );
    Ok(())
}
