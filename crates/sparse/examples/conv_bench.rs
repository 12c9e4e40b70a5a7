//! Sparse convolution benchmark on the procedural room: chunked vs rulebook, every pass.
//!
//! `cargo run --release -p semrecon-sparse --example conv_bench -- [--voxel 0.02]
//!  [--channels 64] [--repeats 5] [--threads N] [--sweep] [--no-rulebook]`
//!
//! `--sweep` times the chunked forward and backward passes over a grid of chunk sides and
//! cache budgets (how the default [`ChunkConfig`] was chosen).

use semrecon_sparse::bench::{room_voxels, run_conv_bench, BenchOptions};
use semrecon_sparse::ChunkConfig;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut voxel = 0.02f32;
    let mut channels = 64usize;
    let mut repeats = 5usize;
    let mut threads = 0usize;
    let mut sweep = false;
    let mut rulebook = true;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().ok_or_else(|| format!("{a} needs a value"));
        match a.as_str() {
            "--voxel" => voxel = value()?.parse()?,
            "--channels" => channels = value()?.parse()?,
            "--repeats" => repeats = value()?.parse()?,
            "--threads" => threads = value()?.parse()?,
            "--sweep" => sweep = true,
            "--no-rulebook" => rulebook = false,
            other => return Err(format!("unknown argument {other}").into()),
        }
    }
    if threads > 0 {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build_global()?;
    }
    let coords = room_voxels(voxel)?;
    let scene = "procedural_room";
    if sweep {
        println!(
            "{:>5} {:>6} {:>6} {:>7} {:>6} {:>9} {:>9} {:>9}",
            "side", "levels", "budget", "chunks", "halo", "fwd ms", "dx ms", "dw ms"
        );
        for side in [8u32, 16, 32] {
            for budget in [64usize, 128, 256, 512, 1024, 4096] {
                let chunk = ChunkConfig {
                    chunk_side: side,
                    levels: 3,
                    max_region_rows: budget,
                };
                let r = run_conv_bench(
                    scene,
                    &coords,
                    voxel,
                    channels,
                    channels,
                    &BenchOptions {
                        repeats,
                        chunk,
                        rulebook: false,
                    },
                )?;
                println!(
                    "{side:>5} {:>6} {budget:>6} {:>7} {:>6.2} {:>9.2} {:>9.2} {:>9.2}",
                    3, r.chunks, r.halo_ratio, r.rows[0].ms, r.rows[1].ms, r.rows[2].ms
                );
            }
        }
        return Ok(());
    }
    let r = run_conv_bench(
        scene,
        &coords,
        voxel,
        channels,
        channels,
        &BenchOptions {
            repeats,
            rulebook,
            ..BenchOptions::default()
        },
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
    println!(
        "{:<9} {:<16} {:>9} {:>8} {:>8}",
        "kernel", "pass", "ms", "GFLOP/s", "%sgemm"
    );
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
        let ms = |k: &str| {
            r.rows
                .iter()
                .find(|x| x.kernel == k && x.pass == pass)
                .map_or(f64::NAN, |x| x.ms)
        };
        println!(
            "chunked speed-up over rulebook, {pass}: {:.2}x",
            ms("rulebook") / ms("chunked")
        );
    }
    Ok(())
}
