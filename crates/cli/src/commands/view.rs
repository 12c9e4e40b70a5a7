//! `semrecon view` and `semrecon export-viewer`: the labelled mesh of an output folder in a
//! web page, with the camera trajectory, the class legend, the material table and balls
//! thrown with a click (simulated by the same physics as `semrecon throw`).

use std::path::PathBuf;

use anyhow::Context;
use semrecon_viewer::server::print_summary;
use semrecon_viewer::{export_static, ViewerFolder, ViewerServer, DEFAULT_EXPORT_THROWS};

/// Arguments of `semrecon view`.
#[derive(clap::Args)]
pub struct ViewArgs {
    /// Folder to show: an output folder of `run`/`demo` (mesh.ply, trajectory.txt), a `synth`
    /// dataset (scene.ply, groundtruth.txt), any folder with a PLY mesh, or a PLY file.
    dir: PathBuf,
    /// Port on 127.0.0.1 (a free one when absent).
    #[arg(long)]
    port: Option<u16>,
    /// Materials per class (TOML); the shipped defaults when absent.
    #[arg(long)]
    materials: Option<PathBuf>,
}

/// Arguments of `semrecon export-viewer`.
#[derive(clap::Args)]
pub struct ExportViewerArgs {
    /// Folder to show (as for `semrecon view`).
    dir: PathBuf,
    /// Output folder for index.html, data.js and three-LICENSE.txt (open index.html from disk).
    #[arg(long)]
    out: PathBuf,
    /// Number of precomputed throws replayed on click.
    #[arg(long, default_value_t = DEFAULT_EXPORT_THROWS)]
    throws: usize,
    /// Materials per class (TOML); the shipped defaults when absent.
    #[arg(long)]
    materials: Option<PathBuf>,
}

/// Runs `semrecon view`: serves until interrupted.
pub fn run(args: ViewArgs) -> anyhow::Result<()> {
    let folder = ViewerFolder::load(&args.dir, args.materials.as_deref())?;
    print_summary(&folder);
    let server = ViewerServer::start(folder, args.port)?;
    println!("semrecon viewer at {} (Ctrl-C to stop)", server.url());
    server.wait();
    Ok(())
}

/// Runs `semrecon export-viewer`.
pub fn run_export(args: ExportViewerArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.throws <= 100, "--throws {} is too many (at most 100)", args.throws);
    let folder = ViewerFolder::load(&args.dir, args.materials.as_deref())?;
    print_summary(&folder);
    let summary = export_static(&folder, &args.out, args.throws)
        .with_context(|| format!("exporting the viewer to {}", args.out.display()))?;
    println!(
        "wrote {} ({} precomputed throws, {:.1} MB); open it in a browser",
        summary.index.display(),
        summary.throws,
        summary.bytes as f64 / 1e6
    );
    Ok(())
}
