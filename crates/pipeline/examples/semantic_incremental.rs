//! Time per semantic pass against map size, full against incremental passes, on a synthetic
//! scan; and how far the final labels of the two differ. Writes JSON (for
//! `bench/plot_semantic_incremental.py`) and prints a table.
//!
//! ```text
//! cargo run --release -p semrecon-pipeline --example semantic_incremental -- \
//!     [--frames 450] [--seed 1] [--style hallway] [--net s20|live|FILE.safetensors]
//!     [--out bench/results/semantic_incremental.json]
//! ```
//!
//! Ground-truth poses and 1 cm TSDF voxels keep the front end cheap: the network works at
//! 5 cm either way, and the map's surface (what its cost depends on) is the same.
//!
//! Times measured inside the pipeline share the cores with the front end (and, on a busy
//! machine, with everything else), so the network is also timed alone afterwards on growing
//! slabs of the final map (median of three): `network_curve` gives ms per input size, from
//! which each pass's cost is read off (`estimated_ms`).

use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;

use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
use semrecon_data::FrameSource;
use semrecon_net::{NetConfig, Segmenter, Weights};
use semrecon_pipeline::{Pipeline, PipelineConfig, PoseMode, SemanticMode, SemanticPass};

fn network(spec: &str) -> Result<Segmenter, Box<dyn std::error::Error>> {
    if spec.ends_with(".safetensors") {
        let path = PathBuf::from(spec);
        let config = Weights::read_config(&path)?.unwrap_or_else(NetConfig::s20);
        return Ok(Segmenter::new(Weights::load(&path, &config)?, config)?);
    }
    let config = NetConfig::named(spec).ok_or_else(|| format!("unknown network {spec}"))?;
    Ok(Segmenter::new(Weights::random(&config, 1), config)?)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let arg = |name: &str| args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).cloned();
    let frames: usize = arg("--frames").map_or(Ok(450), |s| s.parse())?;
    let seed: u64 = arg("--seed").map_or(Ok(1), |s| s.parse())?;
    let net_spec = arg("--net").unwrap_or_else(|| "s20".into());
    let context_m: f32 = arg("--context").map_or(Ok(1.0), |s| s.parse())?;
    let out = PathBuf::from(arg("--out").unwrap_or_else(|| "bench/results/semantic_incremental.json".into()));

    let mut scan_config = SyntheticScanConfig::new(seed);
    scan_config.frames = frames;
    scan_config.style = arg("--style").map(|s| s.parse()).transpose()?;
    let (room, scan) = synthetic_scan(&scan_config)?;
    println!("synthetic {} room, seed {seed}, {frames} frames, network {net_spec}", room.style);
    let loaded: Vec<_> = (0..scan.len()).map(|i| scan.frame(i)).collect::<Result<_, _>>()?;

    // (mode, passes, final cell labels)
    type Run = (&'static str, Vec<SemanticPass>, Vec<(glam::IVec3, u8)>);
    let mut runs: Vec<Run> = Vec::new();
    for (name, mode) in [("full", SemanticMode::Full), ("incremental", SemanticMode::Incremental { context_m })] {
        let mut config =
            PipelineConfig { poses: PoseMode::GroundTruth, keyframe_every: 10, ..PipelineConfig::default() };
        config.tsdf.voxel_size = 0.01;
        config.tsdf.truncation_voxels = 5.0;
        config.semantics.mode = mode;
        let mut p = Pipeline::new(config, scan.intrinsics(), Some(network(&net_spec)?))?;
        let t = Instant::now();
        for f in &loaded {
            p.push_frame(f)?;
        }
        p.finish()?;
        let wall = t.elapsed().as_secs_f64();
        println!("{name}: {} passes, {wall:.1} s wall", p.semantic_passes().len());
        runs.push((name, p.semantic_passes().to_vec(), p.cell_labels()));
    }
    let full: HashMap<glam::IVec3, u8> = runs[0].2.iter().copied().collect();
    let inc = &runs[1].2;
    let same = inc.iter().filter(|(k, l)| full.get(k) == Some(l)).count();
    let agreement = same as f64 / inc.len().max(1) as f64;
    println!(
        "final labels: {:.2}% of {} cells agree between full and incremental passes",
        agreement * 100.0,
        inc.len()
    );

    // The network alone on slabs of the final map (cells sorted along x), grey input.
    let mut cells: Vec<glam::IVec3> = inc.iter().map(|(k, _)| *k).collect();
    cells.sort_by_key(|k| (k.x, k.y, k.z));
    let mut net = network(&net_spec)?;
    let mut curve = Vec::new();
    let steps = 8;
    for s in 1..=steps {
        let n = cells.len() * s / steps;
        let coords: Vec<[i32; 4]> = cells[..n].iter().map(|k| [k.x, k.y, k.z, 0]).collect();
        let feats = vec![0.0f32; n * 3];
        let mut ms: Vec<f64> = (0..3)
            .map(|_| {
                let t = Instant::now();
                let _ = net.segment(&coords, &feats);
                t.elapsed().as_secs_f64() * 1e3
            })
            .collect();
        ms.sort_by(f64::total_cmp);
        println!("network alone: {n:>6} cells {:>8.1} ms", ms[1]);
        curve.push((n, ms[1]));
    }
    let estimate = |n: usize| -> f64 {
        let mut prev = (0usize, 0.0f64);
        for &(c, ms) in &curve {
            if n <= c {
                let f = (n - prev.0) as f64 / (c - prev.0).max(1) as f64;
                return prev.1 + f * (ms - prev.1);
            }
            prev = (c, ms);
        }
        prev.1 * n as f64 / prev.0.max(1) as f64
    };
    let estimated = |passes: &[SemanticPass]| -> Vec<f64> { passes.iter().map(|p| estimate(p.input_cells)).collect() };
    let (est_full, est_inc) = (estimated(&runs[0].1), estimated(&runs[1].1));
    let (sum_full, sum_inc): (f64, f64) = (est_full.iter().sum(), est_inc.iter().sum());
    println!("network time over the scan (from the curve): full {sum_full:.0} ms, incremental {sum_inc:.0} ms");

    println!(
        "\n{:>6} {:>9} | {:>10} {:>9} {:>9} | {:>10} {:>9} {:>9} {:>11}",
        "frame", "map cells", "full cells", "full ms", "est. ms", "inc cells", "inc ms", "est. ms", "snapshot ms"
    );
    for (k, f) in runs[0].1.iter().enumerate() {
        // Incremental runs skip keyframes where no cell changed.
        let inc_pass = runs[1].1.iter().position(|i| i.frame == f.frame);
        let (cells, ms, est, snap) = inc_pass.map_or((0, 0.0, 0.0, 0.0), |j| {
            let i = &runs[1].1[j];
            (i.input_cells, i.network_ms, est_inc[j], i.snapshot_ms)
        });
        println!(
            "{:>6} {:>9} | {:>10} {:>9.1} {:>9.1} | {:>10} {:>9.1} {:>9.1} {:>11.1}",
            f.frame, f.map_cells, f.input_cells, f.network_ms, est_full[k], cells, ms, est, snap
        );
    }
    let json = serde_json::json!({
        "scene": format!("synthetic {} room, seed {seed}", room.style),
        "frames": frames,
        "network": net_spec,
        "context_m": context_m,
        "agreement": agreement,
        "network_curve": curve,
        "estimated_ms": {"full": est_full, "incremental": est_inc},
        "cells": inc.len(),
        "full": runs[0].1,
        "incremental": runs[1].1,
    });
    if let Some(dir) = out.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(&out, serde_json::to_string_pretty(&json)?)?;
    println!("wrote {}", out.display());
    Ok(())
}
