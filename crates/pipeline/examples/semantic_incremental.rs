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
    let out = PathBuf::from(arg("--out").unwrap_or_else(|| "bench/results/semantic_incremental.json".into()));

    let mut scan_config = SyntheticScanConfig::new(seed);
    scan_config.frames = frames;
    scan_config.style = arg("--style").map(|s| s.parse()).transpose()?;
    let (room, scan) = synthetic_scan(&scan_config)?;
    println!("synthetic {} room, seed {seed}, {frames} frames, network {net_spec}", room.style);
    let loaded: Vec<_> = (0..scan.len()).map(|i| scan.frame(i)).collect::<Result<_, _>>()?;

    let mut runs: Vec<(&str, Vec<SemanticPass>, Vec<(glam::IVec3, u8)>, f64)> = Vec::new();
    for (name, mode) in [("full", SemanticMode::Full), ("incremental", SemanticMode::Incremental { context_m: 1.0 })] {
        let mut config = PipelineConfig { poses: PoseMode::GroundTruth, keyframe_every: 10, ..PipelineConfig::default() };
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
        runs.push((name, p.semantic_passes().to_vec(), p.cell_labels(), wall));
    }
    let full: HashMap<glam::IVec3, u8> = runs[0].2.iter().copied().collect();
    let inc = &runs[1].2;
    let same = inc.iter().filter(|(k, l)| full.get(k) == Some(l)).count();
    let agreement = same as f64 / inc.len().max(1) as f64;
    println!("final labels: {:.2}% of {} cells agree between full and incremental passes", agreement * 100.0, inc.len());

    println!("\n{:>6} {:>9} | {:>10} {:>9} | {:>10} {:>9} {:>11}", "frame", "map cells", "full cells", "full ms", "inc cells", "inc ms", "snapshot ms");
    for (f, i) in runs[0].1.iter().zip(&runs[1].1) {
        println!(
            "{:>6} {:>9} | {:>10} {:>9.1} | {:>10} {:>9.1} {:>11.1}",
            f.frame, f.map_cells, f.input_cells, f.network_ms, i.input_cells, i.network_ms, i.snapshot_ms
        );
    }
    let json = serde_json::json!({
        "scene": format!("synthetic {} room, seed {seed}", room.style),
        "frames": frames,
        "network": net_spec,
        "context_m": 1.0,
        "agreement": agreement,
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
