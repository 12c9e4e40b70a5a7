//! Sparse convolution benchmark on the procedural room: chunked vs rulebook, every pass.
//!
//! `cargo run --release -p semrecon-sparse --example conv_bench -- [--voxel 0.02]
//!  [--channels 64] [--repeats 5] [--threads N] [--sweep] [--build-only] [--no-rulebook] [--json FILE]`
//!
//! `--build-only` times building the kernel map and the chunk plan (once per level).
//!
//! `--sweep` times the chunked forward and backward passes over a grid of chunk sides and
//! cache budgets (how the default [`ChunkConfig`] was chosen).

use semrecon_sparse::bench::{room_voxels, run_conv_bench, BenchOptions};
use std::time::Instant;

use semrecon_sparse::{ChunkConfig, ChunkedConv, KernelMap};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut voxel = 0.02f32;
    let mut channels = 64usize;
    let mut repeats = 5usize;
    let mut threads = 0usize;
    let mut sweep = false;
    let mut build_only = false;
    let mut rulebook = true;
    let mut json: Option<std::path::PathBuf> = None;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().ok_or_else(|| format!("{a} needs a value"));
        match a.as_str() {
            "--voxel" => voxel = value()?.parse()?,
            "--channels" => channels = value()?.parse()?,
            "--repeats" => repeats = value()?.parse()?,
            "--threads" => threads = value()?.parse()?,
            "--sweep" => sweep = true,
            "--build-only" => build_only = true,
            "--no-rulebook" => rulebook = false,
            "--json" => json = Some(value()?.into()),
            other => return Err(format!("unknown argument {other}").into()),
        }
    }
    if threads > 0 {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build_global()?;
    }
    let coords = room_voxels(voxel)?;
    let scene = "procedural_room";
    if sweep {
        return run_sweep(&coords, channels, repeats);
    }
    if build_only {
        let (mut map_ms, mut plan_ms) = (f64::INFINITY, f64::INFINITY);
        for _ in 0..repeats.max(1) {
            let t = Instant::now();
            let map = KernelMap::submanifold(&coords, 3)?;
            map_ms = map_ms.min(t.elapsed().as_secs_f64() * 1e3);
            let t = Instant::now();
            let conv = ChunkedConv::new(map, &coords, &coords, &ChunkConfig::default())?;
            plan_ms = plan_ms.min(t.elapsed().as_secs_f64() * 1e3);
            std::hint::black_box(conv);
        }
        println!("{} voxels: kernel map {map_ms:.2} ms, chunk plan {plan_ms:.2} ms", coords.len());
        return Ok(());
    }
    let r = run_conv_bench(
        scene,
        &coords,
        voxel,
        channels,
        channels,
        &BenchOptions { repeats, rulebook, ..BenchOptions::default() },
    )?;
    println!(
        "scene {scene}: {} voxels at {voxel} m, {:.2} neighbours/voxel, C_in = C_out = {channels}, {} threads, {}",
        coords.len(),
        r.rows[0].mean_neighbours,
        r.threads,
        r.simd
    );
    println!(
        "kernel map {:.1} ms, chunk plan {:.1} ms ({} chunks, halo {:.2}); dense sgemm roofline {:.1} GFLOP/s",
        r.map_ms, r.plan_ms, r.chunks, r.halo_ratio, r.sgemm_gflops
    );
    println!("{:<9} {:<16} {:>9} {:>8} {:>8}", "kernel", "pass", "ms", "GFLOP/s", "%sgemm");
    for row in &r.rows {
        println!(
            "{:<9} {:<16} {:>9.2} {:>8.1} {:>7.0}%",
            row.kernel,
            row.pass,
            row.ms,
            row.gflops,
            100.0 * row.gflops / r.sgemm_gflops
        );
    }
    for pass in ["forward", "backward_input", "backward_weight"] {
        let ms = |k: &str| r.rows.iter().find(|x| x.kernel == k && x.pass == pass).map_or(f64::NAN, |x| x.ms);
        println!("chunked speed-up over rulebook, {pass}: {:.2}x", ms("rulebook") / ms("chunked"));
    }
    if let Some(path) = json {
        // Write beside the target and rename, so that no half-written file is ever seen.
        let tmp = path.with_extension("json.tmp");
        std::fs::write(&tmp, serde_json::to_string_pretty(&r)?).map_err(|e| format!("{}: {e}", tmp.display()))?;
        std::fs::rename(&tmp, &path).map_err(|e| format!("{}: {e}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// Times the chunked passes for a grid of chunk configurations, round-robin so that the load
/// of other processes hits every configuration alike; prints the fastest round of each.
fn run_sweep(coords: &[semrecon_sparse::Coord], c: usize, repeats: usize) -> Result<(), Box<dyn std::error::Error>> {
    let map = KernelMap::submanifold(coords, 3)?;
    let mut configs = Vec::new();
    for side in [4u32, 8, 16, 32] {
        for levels in [1u32, 3] {
            for budget in [64usize, 128, 256, 512, 1024, 1 << 20] {
                if levels == 1 && budget != 1 << 20 {
                    continue;
                }
                let cfg = ChunkConfig { chunk_side: side, levels, max_region_rows: budget };
                configs.push((cfg, ChunkedConv::new(map.clone(), coords, coords, &cfg)?));
            }
        }
    }
    let fill = |n: usize, s: u32| -> Vec<f32> {
        (0..n).map(|i| ((i as u32 * 2_654_435_761 + s) >> 8) as f32 / 16_777_216.0 - 0.5).collect()
    };
    let (x, dy, w) = (fill(coords.len() * c, 1), fill(coords.len() * c, 2), fill(27 * c * c, 3));
    let mut best = vec![[f64::INFINITY; 3]; configs.len()];
    let mut sink = 0f32;
    for round in 0..=repeats {
        for (i, (_, conv)) in configs.iter().enumerate() {
            let mut time = |j: usize, f: &dyn Fn() -> f32| {
                let t = Instant::now();
                sink += f();
                if round > 0 {
                    best[i][j] = best[i][j].min(t.elapsed().as_secs_f64() * 1e3);
                }
            };
            time(0, &|| conv.forward(&x, c, &w, c).map_or(0.0, |v| v[0]));
            time(1, &|| conv.backward_input(&dy, c, &w, c).map_or(0.0, |v| v[0]));
            time(2, &|| conv.backward_weight(&x, c, &dy, c).map_or(0.0, |v| v[0]));
        }
    }
    std::hint::black_box(sink);
    println!(
        "{:>5} {:>6} {:>8} {:>7} {:>6} {:>8} {:>8} {:>8}",
        "side", "levels", "budget", "chunks", "halo", "fwd ms", "dx ms", "dw ms"
    );
    for ((cfg, conv), b) in configs.iter().zip(&best) {
        let plan = conv.forward_plan();
        println!(
            "{:>5} {:>6} {:>8} {:>7} {:>6.2} {:>8.2} {:>8.2} {:>8.2}",
            cfg.chunk_side,
            cfg.levels,
            cfg.max_region_rows,
            plan.num_chunks(),
            plan.halo_ratio(),
            b[0],
            b[1],
            b[2]
        );
    }
    Ok(())
}
