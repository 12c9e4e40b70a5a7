//! The `semrecon` command-line program: every capability of the workspace behind one binary.

use clap::{Parser, Subcommand};

mod cli_values;
mod commands;
mod device;
mod interrupt;
mod live_view;
mod map_report;
mod process_memory;
mod progress;
mod reconstruction;
mod timing;
mod tracking_log;

/// Live semantic 3D perception from RGB-D streams, on the CPU.
#[derive(Parser)]
#[command(name = "semrecon", version, about, long_about = None, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// AR view: virtual balls thrown into a scanned room, drawn over its RGB frames (PNG + GIF).
    Ar(commands::ar::ArArgs),
    /// Benchmarks (table + JSON): rendering, sparse convolution, the network.
    Bench(commands::bench::BenchArgs),
    /// Measure a depth camera's radial depth bias from a scan with walls or floor in view (JSON for `run --depth-calibration`).
    CalibrateDepth(commands::calibrate_depth::CalibrateDepthArgs),
    /// Run the whole pipeline on a built-in synthetic scene and write the outputs.
    Demo(commands::demo::DemoArgs),
    /// Evaluate against ground truth: trajectory (ATE, RPE), mesh (accuracy, completeness, F-score) or segmentation (IoU).
    Eval(commands::eval::EvalArgs),
    /// Describe a dataset: frame count, resolution, intrinsics, depth range, ground truth.
    Info(commands::info::InfoArgs),
    /// Training data: reconstructions of rendered scans of synthetic rooms, every vertex labelled.
    MakeScans(commands::make_scans::MakeScansArgs),
    /// Reconstruct a dataset: poses, TSDF fusion, meshing; writes mesh, trajectory and report.
    Run(commands::run::RunArgs),
    /// Live session on a camera (OpenNI2 device or .oni, RealSense .bag, simulated): real time, late frames dropped; Ctrl-C writes the outputs.
    Live(commands::live::LiveArgs),
    /// Label every vertex of a point cloud or mesh (PLY) with the network: adds a `label` property.
    Segment(commands::segment::SegmentArgs),
    /// Generate a synthetic labelled room and render an RGB-D scan of it (7-Scenes layout).
    Synth(commands::synth::SynthArgs),
    /// Render a mesh to a PNG (bird's-eye corner view), in its colours or class colours.
    Snapshot(commands::snapshot::SnapshotArgs),
    /// Throw a virtual ball into a labelled mesh; bounces use the class's material.
    Throw(commands::throw::ThrowArgs),
    /// Train the semantic network (CBSCN) on labelled rooms; needs the `train` cargo feature.
    Train(commands::train::TrainArgs),
    /// Show a labelled mesh in a local web page (127.0.0.1); click to throw balls.
    View(commands::view::ViewArgs),
    /// Write the viewer as a static page (works from file://) with precomputed throws.
    ExportViewer(commands::view::ExportViewerArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Ar(args) => commands::ar::run(args),
        Command::Bench(args) => commands::bench::run(args),
        Command::CalibrateDepth(args) => commands::calibrate_depth::run(args),
        Command::Demo(args) => commands::demo::run(args),
        Command::Eval(args) => commands::eval::run(args),
        Command::Info(args) => commands::info::run(args),
        Command::Live(args) => commands::live::run(args),
        Command::MakeScans(args) => commands::make_scans::run(args),
        Command::Run(args) => commands::run::run(args),
        Command::Segment(args) => commands::segment::run(args),
        Command::Synth(args) => commands::synth::run(args),
        Command::Snapshot(args) => commands::snapshot::run(args),
        Command::Throw(args) => commands::throw::run(args),
        Command::Train(args) => commands::train::run(args),
        Command::View(args) => commands::view::run(args),
        Command::ExportViewer(args) => commands::view::run_export(args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {}", error_message(&err));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error and its causes joined with ": ", leaving out a cause whose text the message
/// already ends with (library errors that print their source as part of their own text, as
/// `DataError::Io` does, would otherwise repeat it).
fn error_message(err: &anyhow::Error) -> String {
    let mut message = String::new();
    for cause in err.chain() {
        let text = cause.to_string();
        if message.ends_with(&text) {
            continue;
        }
        if !message.is_empty() {
            message.push_str(": ");
        }
        message.push_str(&text);
    }
    message
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn causes_already_in_the_message_are_not_repeated() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "No such file");
        let err = anyhow::Error::new(semrecon_data::DataError::Io { path: "/x.ply".into(), source: io })
            .context("reading the mesh");
        assert_eq!(error_message(&err), "reading the mesh: /x.ply: No such file");
        let plain = anyhow::anyhow!("inner").context("outer");
        assert_eq!(error_message(&plain), "outer: inner");
    }
}

#[cfg(test)]
mod command_line_tests {
    use clap::CommandFactory;

    use super::*;

    /// Every subcommand's arguments are consistent (no two flattened groups define the same
    /// flag, e.g. `live --device` naming a camera and the network's `--device`).
    #[test]
    fn command_line_is_consistent() {
        Cli::command().debug_assert();
    }

    /// `--device` parses on the commands that run the network.
    #[test]
    fn device_flag_parses() {
        for args in [
            &["semrecon", "demo", "--device", "auto"][..],
            &["semrecon", "segment", "--input", "a.ply", "--out", "b.ply", "--device", "gpu"],
            &["semrecon", "bench", "conv", "--device", "cpu"],
            &["semrecon", "bench", "net", "--device", "auto"],
        ] {
            assert!(Cli::try_parse_from(args).is_ok(), "{args:?}");
        }
        assert!(Cli::try_parse_from(["semrecon", "demo", "--device", "tpu"]).is_err());
    }
}
