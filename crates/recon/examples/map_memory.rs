//! Map memory per square metre of observed surface, with and without packing cold chunks,
//! and the fusion time it costs.
//!
//! ```text
//! cargo run --release -p semrecon-recon --example map_memory -- [--seed S] [--frames N]
//!     [--cold-after F] [--every K] [--budget BYTES] [--no-check]
//! ```
//!
//! Renders synthetic scan `S` (the demo's room and path at 640x480, Kinect-like noise), fuses
//! it at the true poses into two maps: one plain, one compacted every `K` frames (chunks no
//! frame changed for `F` frames packed; past `--budget` the coldest spilled to a temporary
//! file). Prints the share of observed voxels in allocated chunks, bytes per chunk and per
//! square metre of the final mesh's area (marching cubes over all observed voxels), fusion
//! and compaction milliseconds per frame, and checks that both maps hold the same voxels and
//! give the same mesh bits.

#[path = "common/flags.rs"]
mod flags;

use std::time::{Duration, Instant};

use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
use semrecon_data::FrameSource;
use semrecon_recon::{extract_mesh, IncrementalMesher, MeshConfig, RemeshTolerance, TsdfConfig, TsdfMap};

use flags::Flags;

struct Args {
    seed: u64,
    frames: usize,
    cold_after: u32,
    every: usize,
    budget: Option<usize>,
    check: bool,
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args { seed: 1, frames: 300, cold_after: 30, every: 10, budget: None, check: true };
    let mut flags = Flags::from_env();
    while let Some(flag) = flags.next_flag() {
        match flag.as_str() {
            "--seed" => a.seed = flags.value(&flag)?,
            "--frames" => a.frames = flags.value(&flag)?,
            "--cold-after" => a.cold_after = flags.value(&flag)?,
            "--every" => a.every = flags.value(&flag)?,
            "--budget" => a.budget = Some(flags.value(&flag)?),
            "--no-check" => a.check = false,
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if a.every == 0 {
        return Err("--every must be positive".into());
    }
    Ok(a)
}

fn ms(d: Duration, n: usize) -> f64 {
    d.as_secs_f64() * 1e3 / n.max(1) as f64
}

fn run(a: Args) -> Result<(), String> {
    let mut config = SyntheticScanConfig::new(a.seed);
    config.frames = a.frames;
    let (_room, scan) = synthetic_scan(&config).map_err(|e| e.to_string())?;
    let mut plain = TsdfMap::new(TsdfConfig::default()).map_err(|e| e.to_string())?;
    let mut packed = plain.clone();
    let dir = tempfile::tempdir().map_err(|e| e.to_string())?;
    if let Some(budget) = a.budget {
        packed.set_memory_budget(budget, &dir.path().join("map.spill")).map_err(|e| e.to_string())?;
    }
    let (mut t_plain, mut t_packed, mut t_compact) = (Duration::ZERO, Duration::ZERO, Duration::ZERO);
    // Keyframe meshing as the pipeline runs it (every 10 frames, at most 3072 chunks, right
    // after a compaction): the reader that meets packed chunks most.
    let mesher = || {
        IncrementalMesher::with_config(MeshConfig::RECOMMENDED, RemeshTolerance::EXACT)
            .map(|m| m.with_budget(std::num::NonZeroUsize::new(3072)))
            .map_err(|e| e.to_string())
    };
    let (mut mesh_plain, mut mesh_packed) = (mesher()?, mesher()?);
    let (mut tm_plain, mut tm_packed, mut keyframes) = (Duration::ZERO, Duration::ZERO, 0);
    let mut peak = 0;
    let mut packs = 0;
    for i in 0..scan.len() {
        let frame = scan.frame(i).map_err(|e| e.to_string())?;
        let pose = frame.world_from_camera.ok_or("synthetic frames carry their pose")?;
        // Alternate which map goes first, so that cache warmth favours neither.
        for first in [i % 2 == 0, i % 2 != 0] {
            if first {
                let t = Instant::now();
                plain.integrate(&frame, pose).map_err(|e| e.to_string())?;
                t_plain += t.elapsed();
            } else {
                let t = Instant::now();
                packed.integrate(&frame, pose).map_err(|e| e.to_string())?;
                t_packed += t.elapsed();
                if i % a.every == 0 {
                    let t = Instant::now();
                    let out = packed.compact(frame.index as u32, a.cold_after);
                    t_compact += t.elapsed();
                    packs += out.packed;
                    for w in out.warnings {
                        eprintln!("warning: {w}");
                    }
                }
                peak = peak.max(packed.memory_bytes());
            }
        }
        if i % 10 == 0 {
            keyframes += 1;
            for first in [i % 20 == 0, i % 20 != 0] {
                let t = Instant::now();
                if first {
                    mesh_plain.update(&plain);
                    tm_plain += t.elapsed();
                } else {
                    mesh_packed.update(&packed);
                    tm_packed += t.elapsed();
                }
            }
        }
    }
    let n = scan.len();
    let end = packed.memory();
    let mesh = extract_mesh(&plain);
    let area_m2 = f64::from(mesh.surface_area());
    let (mut observed, mut voxels) = (0usize, 0usize);
    for c in plain.chunks() {
        observed += c.stored_weights().iter().filter(|&&w| w != 0).count();
        voxels += c.stored_weights().len();
    }
    let plain_bytes = plain.memory_bytes();
    {
        // Where the information is: saturated distances, capped weights, distinct values.
        let (mut sat, mut capped, mut obs) = (0usize, 0usize, 0usize);
        let mut wh = std::collections::HashMap::<u16, usize>::new();
        let mut th = std::collections::HashMap::<i16, usize>::new();
        for c in plain.chunks() {
            for i in 0..512 {
                let w = c.stored_weights()[i];
                if w == 0 {
                    continue;
                }
                obs += 1;
                let t = c.stored_tsdf()[i];
                sat += (t.unsigned_abs() >= 32767) as usize;
                capped += (w == 64 * 256) as usize;
                *wh.entry(w).or_default() += 1;
                *th.entry(t).or_default() += 1;
            }
        }
        let entropy = |counts: Vec<usize>| -> f64 {
            let n: usize = counts.iter().sum();
            counts
                .iter()
                .map(|&c| {
                    let p = c as f64 / n as f64;
                    -p * p.log2()
                })
                .sum()
        };
        println!("observed {obs}: |tsdf| saturated {:.1}%, weight capped {:.1}%, weight entropy {:.2} bits, tsdf entropy {:.2} bits",
            100.0 * sat as f64 / obs as f64, 100.0 * capped as f64 / obs as f64,
            entropy(wh.into_values().collect()), entropy(th.into_values().collect()));
    }
    println!(
        "synth:{} {} frames at 640x480, 5 mm voxels, compaction every {} frames, cold after {} frames{}",
        a.seed,
        n,
        a.every,
        a.cold_after,
        a.budget.map_or(String::new(), |b| format!(", budget {b} bytes"))
    );
    println!(
        "chunks {}; observed voxels {:.1}% of allocated; mesh area {:.3} m2",
        plain.chunk_count(),
        100.0 * observed as f64 / voxels.max(1) as f64,
        area_m2
    );
    println!("\n| map | bytes in memory | bytes/chunk | bytes/m2 |\n|---|---|---|---|");
    let row = |name: &str, bytes: usize| {
        println!(
            "| {name} | {bytes} | {:.0} | {:.0} |",
            bytes as f64 / plain.chunk_count().max(1) as f64,
            bytes as f64 / area_m2.max(1e-9)
        )
    };
    row("plain", plain_bytes);
    row("packed, end of scan", end.in_memory());
    row("packed, peak", peak);
    packed.compact(u32::MAX, 0);
    let all = packed.memory();
    row("all chunks packed", all.in_memory());
    println!(
        "\nend of scan: {} hot ({} B), {} packed ({} B, {:.0} B/chunk), {} spilled ({} B on disk), records {} B, caches {} B",
        end.hot_chunks,
        end.hot_bytes,
        end.packed_chunks,
        end.packed_bytes,
        end.packed_bytes as f64 / end.packed_chunks.max(1) as f64,
        end.spilled_chunks,
        end.spilled_bytes,
        end.record_bytes,
        end.cache_bytes
    );
    println!(
        "fusion ms/frame: plain {:.2}, packed map {:.2} (+ compaction {:.2}: {packs} chunks packed in all)",
        ms(t_plain, n),
        ms(t_packed, n),
        ms(t_compact, n)
    );
    println!("keyframe meshing ms: plain {:.2}, packed map {:.2}", ms(tm_plain, keyframes), ms(tm_packed, keyframes));
    if a.check {
        packed.restore_all().map_err(|e| e.to_string())?;
        let same_voxels = plain.sorted_keys() == packed.sorted_keys()
            && plain.sorted_keys().iter().all(|&k| match (plain.chunk(k), packed.chunk(k)) {
                (Some(x), Some(y)) => x.voxels().eq(y.voxels()),
                _ => false,
            });
        let other = extract_mesh(&packed);
        let same_mesh = other == mesh;
        println!("same voxels: {same_voxels}; same mesh bits: {same_mesh}");
        if !(same_voxels && same_mesh) {
            return Err("the packed map differs from the plain one".into());
        }
    }
    Ok(())
}

fn main() {
    if let Err(e) = parse_args().and_then(run) {
        eprintln!("map_memory: {e}");
        std::process::exit(1);
    }
}
