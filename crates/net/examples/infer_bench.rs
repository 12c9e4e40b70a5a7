//! Inference time of the fused CBSCN forward on a voxelised synthetic room, random weights.
//!
//! `cargo run --release -p semrecon-net --example infer_bench -- [--threads 2] [--seed 1]
//! [--configs s20,live] [--repeats 3] [--rulebook]`
//!
//! The room (`semrecon_data::synth::generate_room`) is sampled into coloured points (about
//! nine per voxel face), voxelised at each configuration's voxel size, and segmented
//! with seeded random weights. Reported: voxels per level, the fastest of the repeats (total,
//! geometry = kernel maps + chunk plans + interpolation tables, layers), FLOPs and GFLOP/s,
//! parameters, and the mean CPU time per call (user + system over all threads: on a shared,
//! loaded machine the wall time overstates the cost, the CPU time does not).

use std::time::Instant;

use semrecon_data::synth::{generate_room, RoomConfig};
use semrecon_net::surface::sample_surface;
use semrecon_net::{
    color_features, forward_flops, parameter_count, ConvKernel, NetConfig, Segmenter, Weights,
};
use semrecon_sparse::voxelize;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut threads = 2usize;
    let mut seed = 1u64;
    let mut repeats = 3usize;
    let mut configs = "s20,live".to_string();
    let mut rulebook = false;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().ok_or(format!("{a} needs a value"));
        match a.as_str() {
            "--threads" => threads = value()?.parse()?,
            "--seed" => seed = value()?.parse()?,
            "--repeats" => repeats = value()?.parse::<usize>()?.max(1),
            "--configs" => configs = value()?,
            "--rulebook" => rulebook = true,
            other => return Err(format!("unknown argument {other}").into()),
        }
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()?;
    let room = generate_room(&RoomConfig { seed, style: None });
    println!(
        "room seed {seed} ({}), {} triangles, {threads} threads",
        room.style,
        room.mesh.triangles.len(),
    );
    for name in ["s20", "s50", "live"] {
        if let Some(c) = NetConfig::named(name) {
            println!("parameters {name}: {}", parameter_count(&c));
        }
    }
    for name in configs.split(',') {
        let config = NetConfig::from_name_or_file(name.trim())?;
        // About three points per voxel edge, nine per voxel face.
        let density = (3.0 / config.voxel_size).powi(2);
        let cloud = sample_surface(&room.mesh, density, seed);
        let points: Vec<[f32; 3]> = cloud.positions.iter().map(|p| p.to_array()).collect();
        let feats = color_features(&cloud.colors);
        let t = Instant::now();
        let v = voxelize(&points, &feats, 3, config.voxel_size, 0)?;
        let voxelize_ms = t.elapsed().as_secs_f64() * 1e3;
        let mut net = Segmenter::new(Weights::random(&config, 7), config.clone())?;
        let (coords, f) = (v.tensor.coords(), v.tensor.features());
        net.segment(coords, f)?; // warm-up: workspace growth, page faults
        let mut best = f64::INFINITY;
        let mut best_timing = net.last_timing();
        let cpu0 = cpu_ms();
        for _ in 0..repeats {
            let t = Instant::now();
            let logits = net.segment(coords, f)?;
            let ms = t.elapsed().as_secs_f64() * 1e3;
            std::hint::black_box(logits);
            if ms < best {
                best = ms;
                best_timing = net.last_timing();
            }
        }
        let cpu = cpu0.zip(cpu_ms()).map_or("n/a".to_string(), |(a, b)| {
            format!("{:.0} ms", (b - a) / repeats as f64)
        });
        let voxels: Vec<usize> = net.level_stats().iter().map(|s| s.voxels).collect();
        let flops = forward_flops(&config, net.level_stats()) as f64;
        let fwd_ms = best_timing.forward.as_secs_f64() * 1e3;
        println!(
            "{} ({} points): {} voxels (levels {:?}), mean neighbours {:.1}; total {best:.1} ms = geometry {:.1} ms + layers {fwd_ms:.1} ms (voxelise {voxelize_ms:.1} ms); {:.2} GFLOP, {:.1} GFLOP/s in the layers; CPU time per call {cpu}",
            config.summary(),
            points.len(),
            coords.len(),
            voxels,
            net.level_stats()[0].neighbour_pairs as f64 / coords.len().max(1) as f64,
            best_timing.geometry.as_secs_f64() * 1e3,
            flops / 1e9,
            flops / 1e9 / (fwd_ms / 1e3),
        );
        if rulebook {
            // The same network, weights and kernel maps with the gather-GEMM-scatter kernel.
            net.set_kernel(ConvKernel::Rulebook);
            let mut best_layers = f64::INFINITY;
            let cpu0 = cpu_ms();
            for _ in 0..repeats {
                std::hint::black_box(net.segment(coords, f)?);
                best_layers = best_layers.min(net.last_timing().forward.as_secs_f64() * 1e3);
            }
            let cpu = cpu0.zip(cpu_ms()).map_or("n/a".to_string(), |(a, b)| {
                format!("{:.0} ms", (b - a) / repeats as f64)
            });
            println!(
                "{} with the rulebook kernel: layers {best_layers:.1} ms ({:.1}x the chunked layers); CPU time per call {cpu}",
                config.name,
                best_layers / fwd_ms
            );
        }
    }
    Ok(())
}

/// CPU time (user + system, all threads) of this process so far, from `/proc/self/stat`
/// (Linux; 100 ticks per second assumed): robust to other processes competing for the cores.
fn cpu_ms() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let utime: f64 = fields.get(11)?.parse().ok()?;
    let stime: f64 = fields.get(12)?.parse().ok()?;
    Some((utime + stime) * 10.0)
}
