//! `semrecon eval`: how good a reconstruction is, against ground truth.
//!
//! - `traj`: ATE (after a rigid alignment without scale) and RPE per second of an estimated
//!   TUM trajectory against a reference one, as the TUM benchmark tools and `evo` define them
//!   (bench/check_eval_against_evo.sh compares the numbers with `evo`).
//! - `mesh`: accuracy and completeness (mean, median) and precision / recall / F-score at 1,
//!   2 and 5 cm of an estimated mesh against a ground-truth mesh (PLY files).
//! - `seg`: per-class IoU, mIoU, accuracy and time per room of a segmentation model on
//!   labelled rooms (see [`super::eval_seg`]).
//!
//! Both print a table, or JSON with `--json`; `--out FILE` also writes the JSON to a file.

use std::path::{Path, PathBuf};

use anyhow::Context;
use semrecon_data::atomic_file::write_atomic;
use semrecon_data::{read_ply, Trajectory};
use semrecon_eval::{evaluate_mesh, evaluate_trajectory, MeshEvalConfig, TrajectoryEvalConfig};
use serde::Serialize;

/// Arguments of `semrecon eval`.
#[derive(clap::Args)]
pub struct EvalArgs {
    #[command(subcommand)]
    which: Which,
}

#[derive(clap::Subcommand)]
enum Which {
    /// Trajectory errors: ATE (RMSE, mean, median, max) and RPE per second.
    Traj(TrajArgs),
    /// Surface errors: accuracy, completeness, precision / recall / F-score.
    Mesh(MeshArgs),
    /// Segmentation: per-class IoU, mIoU, accuracy and time per room of a model on labelled rooms.
    Seg(super::eval_seg::SegArgs),
}

/// Arguments of `semrecon eval traj`.
#[derive(clap::Args)]
struct TrajArgs {
    /// Reference trajectory (TUM format: timestamp tx ty tz qx qy qz qw).
    #[arg(long)]
    gt: PathBuf,
    /// Estimated trajectory (TUM format).
    #[arg(long)]
    est: PathBuf,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// Also write the JSON to this file.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Largest time difference (seconds) at which two poses are matched.
    #[arg(long, default_value_t = 0.02)]
    max_time_diff: f64,
    /// RPE interval in seconds.
    #[arg(long, default_value_t = 1.0)]
    delta: f64,
}

/// Arguments of `semrecon eval mesh`.
#[derive(clap::Args)]
struct MeshArgs {
    /// Ground-truth mesh (PLY).
    #[arg(long)]
    gt: PathBuf,
    /// Estimated mesh (PLY).
    #[arg(long)]
    est: PathBuf,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// Also write the JSON to this file.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Spacing of the surface samples in metres.
    #[arg(long, default_value_t = 0.002)]
    spacing: f32,
    /// Most surface samples per mesh (the spacing grows beyond it).
    #[arg(long, default_value_t = 2_000_000)]
    max_samples: usize,
    /// Seed of the surface sampling.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

#[derive(Serialize)]
struct TrajReport {
    gt: String,
    est: String,
    pairs: usize,
    ate_rmse_m: f64,
    ate_mean_m: f64,
    ate_median_m: f64,
    ate_max_m: f64,
    rpe_pairs: usize,
    rpe_delta_s: f64,
    rpe_trans_m_per_s: Option<f64>,
    rpe_rot_deg_per_s: Option<f64>,
}

#[derive(Serialize)]
struct MeshReport {
    gt: String,
    est: String,
    accuracy_mean_m: f64,
    accuracy_median_m: f64,
    completeness_mean_m: f64,
    completeness_median_m: f64,
    est_vertices: usize,
    gt_samples: usize,
    precision_1cm: f64,
    recall_1cm: f64,
    fscore_1cm: f64,
    precision_2cm: f64,
    recall_2cm: f64,
    fscore_2cm: f64,
    precision_5cm: f64,
    recall_5cm: f64,
    fscore_5cm: f64,
}

/// Runs the command.
pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    match args.which {
        Which::Traj(a) => traj(a),
        Which::Mesh(a) => mesh(a),
        Which::Seg(a) => super::eval_seg::run(a),
    }
}

fn traj(args: TrajArgs) -> anyhow::Result<()> {
    let gt = Trajectory::read_tum(&args.gt).context("reading the reference trajectory")?;
    let est = Trajectory::read_tum(&args.est).context("reading the estimated trajectory")?;
    let config = TrajectoryEvalConfig { max_time_difference_s: args.max_time_diff, rpe_delta_s: args.delta };
    let e = evaluate_trajectory(&gt, &est, &config)
        .with_context(|| format!("comparing {} with {}", args.est.display(), args.gt.display()))?;
    let report = TrajReport {
        gt: args.gt.display().to_string(),
        est: args.est.display().to_string(),
        pairs: e.pairs,
        ate_rmse_m: e.ate_rmse_m,
        ate_mean_m: e.ate_mean_m,
        ate_median_m: e.ate_median_m,
        ate_max_m: e.ate_max_m,
        rpe_pairs: e.rpe_pairs,
        rpe_delta_s: args.delta,
        rpe_trans_m_per_s: e.rpe_trans_m_per_s,
        rpe_rot_deg_per_s: e.rpe_rot_deg_per_s,
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!("matched poses   {} of {} estimated", e.pairs, est.len());
        println!("ATE rmse        {:.6} m", e.ate_rmse_m);
        println!("ATE mean        {:.6} m", e.ate_mean_m);
        println!("ATE median      {:.6} m", e.ate_median_m);
        println!("ATE max         {:.6} m", e.ate_max_m);
        match (e.rpe_trans_m_per_s, e.rpe_rot_deg_per_s) {
            (Some(t), Some(r)) => {
                println!("RPE trans rmse  {t:.6} m/s   ({} pairs {} s apart)", e.rpe_pairs, args.delta);
                println!("RPE rot rmse    {r:.6} deg/s");
            }
            _ => println!("RPE             none: no two poses {} s apart", args.delta),
        }
    }
    write_json(args.out.as_deref(), &report)
}

fn mesh(args: MeshArgs) -> anyhow::Result<()> {
    let gt = read_ply(&args.gt).context("reading the ground-truth mesh")?;
    let est = read_ply(&args.est).context("reading the estimated mesh")?;
    let config = MeshEvalConfig {
        sample_spacing_m: args.spacing,
        max_samples: args.max_samples,
        seed: args.seed,
        thresholds_m: vec![0.01, 0.02, 0.05],
        ..MeshEvalConfig::default()
    };
    let e = evaluate_mesh(&gt, &est, &config)
        .with_context(|| format!("comparing {} with {}", args.est.display(), args.gt.display()))?;
    let score = |i: usize| e.scores.get(i).map(|s| (s.precision, s.recall, s.fscore)).unwrap_or_default();
    let ((p1, r1, f1), (p2, r2, f2), (p5, r5, f5)) = (score(0), score(1), score(2));
    let report = MeshReport {
        gt: args.gt.display().to_string(),
        est: args.est.display().to_string(),
        accuracy_mean_m: e.accuracy_mean_m,
        accuracy_median_m: e.accuracy_median_m,
        completeness_mean_m: e.completeness_mean_m,
        completeness_median_m: e.completeness_median_m,
        est_vertices: e.est_vertices,
        gt_samples: e.gt_samples,
        precision_1cm: p1,
        recall_1cm: r1,
        fscore_1cm: f1,
        precision_2cm: p2,
        recall_2cm: r2,
        fscore_2cm: f2,
        precision_5cm: p5,
        recall_5cm: r5,
        fscore_5cm: f5,
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!("{:<14} {:>12} {:>12}", "", "mean mm", "median mm");
        println!("{:<14} {:>12.3} {:>12.3}", "accuracy", 1e3 * e.accuracy_mean_m, 1e3 * e.accuracy_median_m);
        println!(
            "{:<14} {:>12.3} {:>12.3}",
            "completeness",
            1e3 * e.completeness_mean_m,
            1e3 * e.completeness_median_m
        );
        println!();
        println!("{:<14} {:>10} {:>10} {:>10}", "threshold", "precision", "recall", "F-score");
        for s in &e.scores {
            println!(
                "{:<14} {:>9.2}% {:>9.2}% {:>9.2}%",
                format!("{} cm", 100.0 * s.threshold_m),
                100.0 * s.precision,
                100.0 * s.recall,
                100.0 * s.fscore
            );
        }
        println!("({} estimated vertices, {} ground-truth surface samples)", e.est_vertices, e.gt_samples);
    }
    write_json(args.out.as_deref(), &report)
}

fn write_json<T: Serialize>(path: Option<&Path>, report: &T) -> anyhow::Result<()> {
    if let Some(path) = path {
        write_atomic(path, serde_json::to_string_pretty(report)?.as_bytes())?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
