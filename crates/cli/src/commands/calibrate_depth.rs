//! `semrecon calibrate-depth`: a camera's radial depth bias measured on one of its scans and
//! written as the JSON file `run --depth-calibration` reads (semrecon_data::depth_calibration).

use std::path::{Path, PathBuf};

use anyhow::Context;
use semrecon_data::datasets::{open_dataset, DatasetSpec};
use semrecon_data::depth_calibration::estimate::{calibrate, EstimateConfig};
use semrecon_data::depth_calibration::{CalibratedSource, DepthCalibration};
use semrecon_data::FrameSource;

use crate::commands::run::{parse_frame_range, FrameRange};

/// Arguments of `semrecon calibrate-depth`.
#[derive(clap::Args)]
pub struct CalibrateDepthArgs {
    /// The scan to measure on (any dataset `run` reads): one with a wall, floor or table top
    /// filling much of the view in many frames.
    #[arg(long)]
    dataset: DatasetSpec,
    /// Frames to use as A..B (B excluded): all by default.
    #[arg(long, value_parser = parse_frame_range)]
    frames: Option<FrameRange>,
    /// Use every this many frames.
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..))]
    every: u64,
    /// The frames' estimates may disagree by at most this many percent (robust spread);
    /// beyond it the camera is refused.
    #[arg(long, default_value_t = 0.2)]
    max_spread_percent: f64,
    /// Where to write the calibration (JSON).
    #[arg(long)]
    out: PathBuf,
    /// Print every frame's estimate.
    #[arg(long)]
    verbose: bool,
}

/// Runs the command.
pub fn run(args: CalibrateDepthArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.max_spread_percent.is_finite() && args.max_spread_percent > 0.0,
        "--max-spread-percent must be a positive number, not {}",
        args.max_spread_percent
    );
    let source = open_dataset(&args.dataset).with_context(|| format!("opening {}", args.dataset))?;
    anyhow::ensure!(!source.is_empty(), "{} has no frames", source.name());
    let range = args.frames.unwrap_or(FrameRange::ALL).resolve(source.len())?;
    let config = EstimateConfig { max_spread: args.max_spread_percent / 100.0, ..EstimateConfig::default() };
    let outcome = calibrate(source.as_ref(), range.clone(), args.every as usize, &config)
        .with_context(|| format!("reading {}", source.name()))?;
    if args.verbose {
        println!("frame  radial %  std err %  plane share  rho^2 spread  counts");
        for e in &outcome.estimates {
            println!(
                "{:5}  {:+8.3}  {:9.3}  {:11.2}  {:12.3}  {}",
                e.frame,
                100.0 * e.radial,
                100.0 * e.standard_error,
                e.plane_fraction,
                e.radius_spread,
                if e.counts(&config) { "yes" } else { "no" }
            );
        }
    }
    let calibration = match outcome.calibration {
        Ok(calibration) => calibration,
        Err(why) => anyhow::bail!("{} (frames {range:?}): {why}; no calibration written", source.name()),
    };
    calibration.save(&args.out).with_context(|| format!("writing {}", args.out.display()))?;
    println!(
        "{}: depth {:+.3} % in the image corners (median of {} frames' planes, spread {:.3} %); wrote {}",
        source.name(),
        100.0 * calibration.radial,
        calibration.frames_used,
        100.0 * calibration.spread,
        args.out.display()
    );
    Ok(())
}

/// `source` with its depth corrected by the calibration file at `path`, or as it is.
pub fn with_calibration(source: Box<dyn FrameSource>, path: Option<&Path>) -> anyhow::Result<Box<dyn FrameSource>> {
    let Some(path) = path else { return Ok(source) };
    let calibration = DepthCalibration::load(path)?;
    let name = source.name();
    let calibrated =
        CalibratedSource::new(source, calibration).with_context(|| format!("applying {} to {name}", path.display()))?;
    Ok(Box::new(calibrated))
}
