//! Inference time of the fused CBSCN forward on a voxelised synthetic room, random weights.
//!
//! `cargo run --release -p semrecon-net --example infer_bench -- [--threads 2] [--seed 1]
//! [--configs s20,live] [--repeats 3] [--rulebook]`
//!
//! The room (`semrecon_data::synth::generate_room`) is sampled into coloured points (about
//! nine per voxel face), voxelised at each configuration's voxel size, and segmented
//! with seeded random weights. Reported: voxels per level, FLOPs, parameters, and per phase
//! (total; geometry = kernel maps + chunk plans + interpolation tables; layers) the fastest
//! wall time of the repeats and the mean CPU time per call (user + system over all threads:
//! on a shared, loaded machine the wall time overstates the cost, the CPU time does not).

use std::time::Instant;

use semrecon_data::synth::{generate_room, RoomConfig};
use semrecon_net::surface::sample_surface;
use semrecon_net::{
    color_features, forward_flops, parameter_count, ConvKernel, NetConfig, NetGeometry, Segmenter, Weights,
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
    rayon::ThreadPoolBuilder::new().num_threads(threads).build_global()?;
    let room = generate_room(&RoomConfig { seed, style: None });
    println!("room seed {seed} ({}), {} triangles, {threads} threads", room.style, room.mesh.triangles.len(),);
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
                                 // The whole call (geometry + layers), then each phase alone.
        let (total, total_cpu) = measure(repeats, || net.segment(coords, f).map(|_| ()))?;
        let stats = net.level_stats().to_vec();
        let (geo_ms, geo_cpu) =
            measure(repeats, || NetGeometry::build(coords.to_vec(), &config, &Default::default()).map(|_| ()))?;
        let geo = NetGeometry::build(coords.to_vec(), &config, &Default::default())?;
        let (layers, layers_cpu) = measure(repeats, || net.segment_geometry(&geo, f).map(|_| ()))?;
        let flops = forward_flops(&config, &stats) as f64;
        println!(
            "{} ({} points, voxelised in {voxelize_ms:.0} ms): {} voxels, levels {:?}, mean neighbours {:.1}, {:.2} GFLOP",
            config.summary(),
            points.len(),
            coords.len(),
            stats.iter().map(|s| s.voxels).collect::<Vec<_>>(),
            stats[0].neighbour_pairs as f64 / coords.len().max(1) as f64,
            flops / 1e9,
        );
        println!(
            "  chunked : total {total:.1} ms (CPU {total_cpu:.0} ms) = geometry {geo_ms:.1} ms (CPU {geo_cpu:.0}) + layers {layers:.1} ms (CPU {layers_cpu:.0}); {:.1} GFLOP/s per CPU-second in the layers",
            flops / 1e9 / (layers_cpu / 1e3),
        );
        if rulebook {
            // The same network, weights and kernel maps with the gather-GEMM-scatter kernel.
            net.set_kernel(ConvKernel::Rulebook);
            net.segment_geometry(&geo, f)?;
            let (rb, rb_cpu) = measure(repeats, || net.segment_geometry(&geo, f).map(|_| ()))?;
            println!(
                "  rulebook: layers {rb:.1} ms (CPU {rb_cpu:.0} ms): chunked layers are {:.2}x faster (wall), {:.2}x (CPU)",
                rb / layers,
                rb_cpu / layers_cpu,
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

/// Fastest wall time and mean CPU time (ms) of `repeats` runs of `f`.
fn measure(repeats: usize, mut f: impl FnMut() -> semrecon_net::Result<()>) -> semrecon_net::Result<(f64, f64)> {
    let mut best = f64::INFINITY;
    let cpu0 = cpu_ms();
    for _ in 0..repeats {
        let t = Instant::now();
        f()?;
        best = best.min(t.elapsed().as_secs_f64() * 1e3);
    }
    let cpu = cpu0.zip(cpu_ms()).map_or(f64::NAN, |(a, b)| (b - a) / repeats as f64);
    Ok((best, cpu))
}
