//! Map memory against frame count on a long rendered scan: memory should follow the surface
//! seen, not the number of frames fused.
//!
//! ```text
//! cargo run --release -p semrecon-recon --example memory_growth -- [--seed S] [--frames N]
//!     [--loops L] [--size WxH] [--voxel M] [--trunc VOXELS] [--every K]
//! ```
//!
//! Renders synthetic scan `S` (a generated room, Kinect-like noise) along a path of `N`
//! poses and fuses it at the true poses `L` times over, forward then backward (default 600
//! poses, twice: 1200 frames), as a long scan that keeps coming back to the same places.
//! Prints a table every `K` frames: chunks, map bytes, bytes per chunk, and growth since the
//! previous row.

#[path = "common/flags.rs"]
mod flags;

use std::time::Instant;

use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
use semrecon_data::FrameSource;
use semrecon_recon::{TsdfConfig, TsdfMap};

use flags::Flags;

struct Args {
    seed: u64,
    frames: usize,
    loops: usize,
    size: (u32, u32),
    voxel: f32,
    truncation: f32,
    every: usize,
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args { seed: 3, frames: 600, loops: 2, size: (320, 240), voxel: 0.005, truncation: 10.0, every: 100 };
    let mut flags = Flags::from_env();
    while let Some(flag) = flags.next_flag() {
        match flag.as_str() {
            "--seed" => a.seed = flags.value(&flag)?,
            "--frames" => a.frames = flags.value(&flag)?,
            "--loops" => a.loops = flags.value(&flag)?,
            "--voxel" => a.voxel = flags.value(&flag)?,
            "--trunc" => a.truncation = flags.value(&flag)?,
            "--every" => a.every = flags.value(&flag)?,
            "--size" => a.size = flags.size(&flag)?,
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if a.frames == 0 || a.loops == 0 || a.every == 0 {
        return Err("--frames, --loops and --every must be positive".into());
    }
    Ok(a)
}

fn run(a: Args) -> Result<(), String> {
    let mut config = SyntheticScanConfig::new(a.seed);
    config.frames = a.frames;
    config.intrinsics = config.intrinsics.scaled(a.size.0, a.size.1);
    let (_room, scan) = synthetic_scan(&config).map_err(|e| e.to_string())?;
    let map_config = TsdfConfig {
        truncation_voxels: a.truncation,
        ..TsdfConfig::with_voxel_size(a.voxel).map_err(|e| e.to_string())?
    };
    let mut map = TsdfMap::new(map_config).map_err(|e| e.to_string())?;
    println!(
        "synth:{} at {}x{}, {} poses fused {} times (forward, backward, ...), voxel {} mm, truncation {} voxels; \
         {} bytes per chunk (its frame runs included)",
        a.seed,
        a.size.0,
        a.size.1,
        a.frames,
        a.loops,
        a.voxel * 1e3,
        a.truncation,
        TsdfMap::bytes_per_chunk()
    );
    println!("\n| frames fused | pass | chunks | map MB | bytes/chunk | MB added since previous row |");
    println!("|---|---|---|---|---|---|");
    let t = Instant::now();
    let mut fused = 0usize;
    let mut previous = 0usize;
    for pass in 0..a.loops {
        for step in 0..a.frames {
            let i = if pass % 2 == 0 { step } else { a.frames - 1 - step };
            let mut frame = scan.frame(i).map_err(|e| e.to_string())?;
            // A long scan: every fused frame has a new index.
            frame.index = fused;
            let pose = frame.world_from_camera.ok_or("synthetic frames have poses")?;
            map.integrate(&frame, pose).map_err(|e| e.to_string())?;
            fused += 1;
            if fused.is_multiple_of(a.every) || (pass + 1 == a.loops && step + 1 == a.frames) {
                let bytes = map.memory_bytes();
                println!(
                    "| {fused} | {} | {} | {:.1} | {:.0} | {:+.2} |",
                    pass + 1,
                    map.chunk_count(),
                    bytes as f64 / 1e6,
                    bytes as f64 / map.chunk_count().max(1) as f64,
                    (bytes as f64 - previous as f64) / 1e6
                );
                previous = bytes;
            }
        }
    }
    println!("\n{fused} frames in {:.1} s", t.elapsed().as_secs_f64());
    Ok(())
}

fn main() {
    if let Err(e) = parse_args().and_then(run) {
        eprintln!("memory_growth: {e}");
        std::process::exit(1);
    }
}
