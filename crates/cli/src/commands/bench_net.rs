//! `semrecon bench net`: the speed of the whole network (CBSCN `s20` by default) on one
//! voxelised synthetic room, with the chunked convolution kernels and with the rulebook
//! (gather-GEMM-scatter) kernels side by side in one run, interleaved round by round (the
//! machines are shared: only ratios within one run mean something).
//!
//! Per kernel: milliseconds per room (fastest round, and the mean), of which building the
//! geometry (kernel maps, chunk plans, interpolation tables) and running the layers, the
//! useful FLOPs ([`forward_flops`]) and the rate they make. `--export DIR` writes the room
//! (voxels, features), the model, every kernel map and interpolation table of the geometry,
//! and our logits, for the PyTorch peer `bench/peers_net.py`, which runs the same network with
//! the same weights on exactly these maps and checks its output against ours.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use semrecon_data::atomic_file::write_atomic;
use semrecon_data::synth::{generate_room, RoomConfig};
use semrecon_net::dataset::points_per_m2;
use semrecon_net::inference::Device;
use semrecon_net::surface::sample_surface;
use semrecon_net::{forward_flops, ConvKernel, GpuGeometry, NetConfig, NetGeometry, Segmenter, VoxelSample, Weights};
use semrecon_sparse::{ChunkConfig, KernelMap};
use serde::Serialize;

/// Arguments of `semrecon bench net`.
#[derive(clap::Args)]
pub struct NetArgs {
    /// Network configuration (s20, s50, live, or a file).
    #[arg(long, default_value = "s20")]
    config: String,
    /// Trained weights (safetensors); default: seeded random weights with random batch-norm
    /// statistics (the speed does not depend on the values).
    #[arg(long)]
    model: Option<PathBuf>,
    /// Seed of the synthetic room (and of the random weights).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Timed rounds; each runs every kernel once, the fastest round per kernel is kept.
    #[arg(long, default_value_t = 5)]
    repeats: usize,
    /// Write the rows as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write the room, the model, the geometry and our logits to this folder for
    /// `bench/peers_net.py`.
    #[arg(long)]
    export: Option<PathBuf>,
    /// Keep only the room's corner within this many metres of its lower corner (small runs,
    /// e.g. on a software GPU driver); default: the whole room.
    #[arg(long)]
    crop: Option<f32>,
    /// Chunk shape of the chunked kernels, `SIDE/LEVELS/REGION_ROWS` (default 8/3/256, sized
    /// for CPU caches), to tune it for a GPU.
    #[arg(long, value_parser = crate::cli_values::parse_chunk_shape)]
    chunk: Option<ChunkConfig>,
    /// GPU: run every chunked layer with this tile shape (an index in
    /// `semrecon_gpu::CHUNKED_TILES`) instead of the width's default, for tuning.
    #[arg(long)]
    gpu_tile: Option<usize>,
    #[command(flatten)]
    device: crate::device::DeviceArgs,
}

/// One kernel's measurements.
#[derive(Serialize, Clone)]
struct NetRow {
    config: String,
    scene: String,
    voxel_size: f32,
    voxels: usize,
    /// Voxels per level, finest first.
    level_voxels: Vec<usize>,
    kernel: String,
    /// `cpu`, or `gpu (adapter)`.
    device: String,
    /// Fastest round, whole call (geometry and layers).
    ms_per_room: f64,
    /// Mean over the rounds, whole call.
    mean_ms_per_room: f64,
    /// Geometry and layers of the fastest round.
    geometry_ms: f64,
    forward_ms: f64,
    /// Of `forward_ms`: the geometry's upload to the device (0 on the CPU).
    upload_ms: f64,
    /// GPU: kernel dispatches per call, and the host's milliseconds recording them (the
    /// per-dispatch overhead; 0 on the CPU).
    dispatches: u64,
    record_ms: f64,
    /// CPU milliseconds of the calling thread per call, fewest over the rounds: the host's own
    /// work (recording, submitting, buffer creation; not the waits). On a software driver
    /// (lavapipe) the kernels run on the driver's threads, so this is the fixed host cost per
    /// call; 0 where the platform cannot tell.
    host_cpu_ms: f64,
    /// Device milliseconds per kernel of one call (`SEMRECON_GPU_PROFILE=1` only).
    kernel_times: Vec<KernelMs>,
    /// Useful multiply-add FLOPs (2 per multiply-add) of one forward.
    flops: u64,
    /// `flops` over the layers' time.
    gflops: f64,
    /// This kernel's time over the chunked kernel's (1 for the chunked kernel).
    slowdown_vs_chunked: f64,
    threads: usize,
    simd: String,
}

/// Device time of one kernel in one call.
#[derive(Serialize, Clone)]
struct KernelMs {
    kernel: String,
    dispatches: u64,
    ms: f64,
}

/// Runs `semrecon bench net`.
pub fn run(args: NetArgs) -> anyhow::Result<()> {
    let config = NetConfig::from_name_or_file(&args.config)?;
    let weights = match &args.model {
        Some(path) => Weights::load(path, &config)?,
        None => {
            let mut w = Weights::random(&config, args.seed);
            w.perturb_normalisation(args.seed + 1);
            // What a model file stores, so that the exported file and our run agree exactly.
            w.rounded_to_f16()
        }
    };
    let room = generate_room(&RoomConfig { seed: args.seed, style: None });
    let voxel = config.voxel_size;
    let mut cloud = sample_surface(&room.mesh, points_per_m2(voxel), args.seed);
    if let Some(crop) = args.crop {
        anyhow::ensure!(crop > 0.0, "--crop must be positive");
        let keep: Vec<usize> = (0..cloud.len()).filter(|&i| cloud.positions[i].max_element() < crop).collect();
        cloud.positions = keep.iter().map(|&i| cloud.positions[i]).collect();
        cloud.colors = keep.iter().map(|&i| cloud.colors[i]).collect();
        cloud.labels = keep.iter().map(|&i| cloud.labels[i]).collect();
    }
    let sample = VoxelSample::from_cloud(&cloud, voxel)?;
    let scene = match args.crop {
        Some(c) => format!("synthetic {} seed {} ({c} m corner)", room.style, args.seed),
        None => format!("synthetic {} seed {}", room.style, args.seed),
    };
    let device = match (args.device.network_device()?, args.gpu_tile) {
        (Device::Gpu(g), Some(t)) => Device::Gpu(g.with_tile(Some(t))?),
        (_, Some(_)) => anyhow::bail!("--gpu-tile needs --device gpu"),
        (d, None) => d,
    };
    anyhow::ensure!(!sample.is_empty(), "the room has no voxels");

    // On a GPU the chunked kernel runs twice: geometry built on the device (the default) and
    // on the host (neighbour tables uploaded per call), side by side.
    let mut kernels = vec![("chunked", ConvKernel::Chunked, GpuGeometry::Device)];
    if matches!(device, Device::Gpu(_)) {
        kernels.push(("chunked, host geometry", ConvKernel::Chunked, GpuGeometry::Host));
    }
    kernels.push(("rulebook", ConvKernel::Rulebook, GpuGeometry::Host));
    let mut nets = Vec::new();
    for &(_, k, g) in &kernels {
        let mut net = Segmenter::new(weights.clone(), config.clone())?;
        net.set_kernel(k);
        net.set_gpu_geometry(g);
        if let Some(chunk) = args.chunk {
            net.set_chunk(chunk);
        }
        net.set_device(device.clone());
        // Warm-up: workspace buffers allocated, caches and thread pool up.
        net.segment(&sample.coords, &sample.features)?;
        nets.push(net);
    }
    let rounds = args.repeats.max(1);
    // Per kernel: (total, geometry, forward) of every round.
    let mut times: Vec<Vec<(f64, f64, f64, f64)>> = vec![Vec::new(); kernels.len()];
    let mut recorded = vec![(0u64, 0f64); kernels.len()];
    let mut host_cpu = vec![f64::INFINITY; kernels.len()];
    let dispatches = || match &device {
        Device::Gpu(g) => g.context().dispatches(),
        Device::Cpu => (0, 0.0),
    };
    let mut logits = Vec::new();
    for _ in 0..rounds {
        for (q, net) in nets.iter_mut().enumerate() {
            let before = dispatches();
            let cpu = thread_cpu_seconds();
            let t = Instant::now();
            let out = net.segment(&sample.coords, &sample.features)?;
            let total = t.elapsed().as_secs_f64() * 1e3;
            host_cpu[q] = host_cpu[q].min((thread_cpu_seconds() - cpu) * 1e3);
            let after = dispatches();
            recorded[q] = (after.0 - before.0, (after.1 - before.1) * 1e3);
            let timing = net.last_timing();
            let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3;
            times[q].push((total, ms(timing.geometry), ms(timing.forward), ms(timing.upload)));
            if q == 0 {
                logits = out;
            }
        }
    }
    // With SEMRECON_GPU_PROFILE=1: one more call per row, timed per kernel on the device.
    let mut kernel_times = vec![Vec::new(); kernels.len()];
    if let Device::Gpu(g) = &device {
        if g.context().profiling() {
            for (q, net) in nets.iter_mut().enumerate() {
                g.context().kernel_times();
                net.segment(&sample.coords, &sample.features)?;
                kernel_times[q] = g
                    .context()
                    .kernel_times()
                    .into_iter()
                    .map(|k| KernelMs { kernel: k.kernel, dispatches: k.dispatches, ms: k.seconds * 1e3 })
                    .collect();
            }
        }
    }
    let stats = nets[0].level_stats().to_vec();
    let flops = forward_flops(&config, &stats);
    let best: Vec<(f64, f64, f64, f64)> =
        times.iter().map(|t| t.iter().copied().min_by(|a, b| a.0.total_cmp(&b.0)).unwrap_or_default()).collect();
    let rows: Vec<NetRow> = kernels
        .iter()
        .enumerate()
        .map(|(q, (name, _, _))| {
            let (total, geometry, forward, upload) = best[q];
            NetRow {
                config: config.name.clone(),
                scene: scene.clone(),
                voxel_size: voxel,
                voxels: sample.len(),
                level_voxels: stats.iter().map(|s| s.voxels).collect(),
                kernel: (*name).to_string(),
                device: device.describe(),
                ms_per_room: total,
                mean_ms_per_room: times[q].iter().map(|t| t.0).sum::<f64>() / times[q].len() as f64,
                geometry_ms: geometry,
                forward_ms: forward,
                upload_ms: upload,
                dispatches: recorded[q].0,
                record_ms: recorded[q].1,
                host_cpu_ms: host_cpu[q],
                kernel_times: kernel_times[q].clone(),
                flops,
                gflops: flops as f64 / (forward * 1e6),
                slowdown_vs_chunked: total / best[0].0,
                threads: rayon::current_num_threads(),
                simd: format!("{:?}", semrecon_sparse::simd_level()),
            }
        })
        .collect();

    println!(
        "{} on {scene} at {} cm on {}: {} voxels (levels {:?}), {:.2} GFLOP per room, {} threads, best of {rounds}",
        config.summary(),
        voxel * 100.0,
        device.describe(),
        sample.len(),
        rows[0].level_voxels,
        flops as f64 / 1e9,
        rows[0].threads
    );
    println!(
        "{:<22} {:>12} {:>10} {:>12} {:>11} {:>10} {:>9} {:>9} {:>11} {:>10} {:>12}",
        "kernel",
        "ms per room",
        "mean ms",
        "geometry ms",
        "layers ms",
        "upload ms",
        "GFLOP/s",
        "slowdown",
        "dispatches",
        "record ms",
        "host cpu ms"
    );
    for r in &rows {
        println!(
            "{:<22} {:>12.1} {:>10.1} {:>12.1} {:>11.1} {:>10.1} {:>9.1} {:>8.2}x {:>11} {:>10.1} {:>12.2}",
            r.kernel,
            r.ms_per_room,
            r.mean_ms_per_room,
            r.geometry_ms,
            r.forward_ms,
            r.upload_ms,
            r.gflops,
            r.slowdown_vs_chunked,
            r.dispatches,
            r.record_ms,
            r.host_cpu_ms
        );
    }
    for r in rows.iter().filter(|r| !r.kernel_times.is_empty()) {
        let total: f64 = r.kernel_times.iter().map(|k| k.ms).sum();
        println!("device time per kernel, {} ({total:.2} ms in all):", r.kernel);
        for k in &r.kernel_times {
            println!("  {:<44} {:>6} dispatches {:>9.3} ms", k.kernel, k.dispatches, k.ms);
        }
    }
    let rulebook = &rows[rows.len() - 1];
    println!(
        "chunked is {:.2}x faster than rulebook per room ({:.2}x on the layers alone)",
        rulebook.ms_per_room / rows[0].ms_per_room,
        rulebook.forward_ms / rows[0].forward_ms
    );
    if rows.len() == 3 {
        println!(
            "geometry on the device: {:.2}x faster per room than on the host",
            rows[1].ms_per_room / rows[0].ms_per_room
        );
    }

    if let Some(dir) = &args.export {
        let geometry = NetGeometry::build(sample.coords.clone(), &config, &args.chunk.unwrap_or_default())?;
        export(dir, &config, &weights, &sample, &geometry, &logits, &rows)?;
    }
    if let Some(path) = &args.json {
        write_atomic(path, serde_json::to_string_pretty(&rows)?.as_bytes())?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// CPU seconds the calling thread has run so far (0 where the platform cannot tell).
fn thread_cpu_seconds() -> f64 {
    #[cfg(unix)]
    {
        let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
        // SAFETY: clock_gettime only writes the timespec it is given, which lives on this stack.
        if unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) } == 0 {
            return ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9;
        }
    }
    0.0
}

/// Writes `DIR/net.json` and the little-endian arrays it names: `coords` (`[n, 4]` i32, the
/// row order of everything else), `features` (`[n, in]` f32), `logits` (`[n, classes]` f32,
/// ours with the chunked kernels), the model (`model.safetensors`, f16 with the configuration),
/// and per level the kernel maps the layers run on: `subm` (3x3x3 submanifold, 27 offsets),
/// `down` (to the next level, 8 offsets) and `up` (the transpose: coarse rows in, fine rows
/// out, same offsets, same weights `[8, C_(i+1), C_i]`). A map is `in_rows` / `out_rows` (u32,
/// grouped by offset; offset `k` holds `offset_start[k]..offset_start[k + 1]`). `interp`:
/// per fusion path `(t, j)` the trilinear table from level `j` to level `t`, `rows` (u32) and
/// `weights` (f32), 8 per row of level `t`.
fn export(
    dir: &Path,
    config: &NetConfig,
    weights: &Weights,
    sample: &VoxelSample,
    geo: &NetGeometry,
    logits: &[f32],
    rows: &[NetRow],
) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let raw = |name: &str, bytes: Vec<u8>| -> anyhow::Result<String> {
        let file = format!("{name}.bin");
        write_atomic(&dir.join(&file), &bytes)?;
        Ok(file)
    };
    let u32s = |v: &[u32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let f32s = |v: &[f32]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
    let map_json = |name: String, map: &KernelMap| -> anyhow::Result<serde_json::Value> {
        Ok(serde_json::json!({
            "n_in": map.n_in(),
            "n_out": map.n_out(),
            "offset_start": map.offset_start(),
            "in_rows": raw(&format!("{name}_in"), u32s(map.in_rows()))?,
            "out_rows": raw(&format!("{name}_out"), u32s(map.out_rows()))?,
        }))
    };
    let mut levels = Vec::new();
    for i in 0..geo.levels() {
        levels.push(serde_json::json!({
            "n": geo.coords(i).len(),
            "channels": config.channels(i),
            "subm": map_json(format!("level{i}_subm"), geo.submanifold(i).map())?,
            "down": geo.down(i).map(|d| map_json(format!("level{i}_down"), d.map())).transpose()?,
            "up": geo.up(i).map(|u| map_json(format!("level{i}_up"), u.map())).transpose()?,
        }));
    }
    let mut interp = Vec::new();
    for t in 0..config.levels.saturating_sub(2) {
        for j in t + 1..=config.levels - 2 {
            if let Some((r, w)) = geo.interpolation(t, j) {
                interp.push(serde_json::json!({
                    "t": t,
                    "j": j,
                    "rows": raw(&format!("interp_{t}_{j}_rows"), u32s(r))?,
                    "weights": raw(&format!("interp_{t}_{j}_weights"), f32s(w))?,
                }));
            }
        }
    }
    let model = "model.safetensors";
    weights.save(&dir.join(model), config)?;
    let header = serde_json::json!({
        "config": config,
        "n": sample.len(),
        "model": model,
        "coords": raw("coords", sample.coords.iter().flatten().flat_map(|v| v.to_le_bytes()).collect())?,
        "features": raw("features", f32s(&sample.features))?,
        "logits": raw("logits", f32s(logits))?,
        "levels": levels,
        "interp": interp,
        "ours": rows,
    });
    let path = dir.join("net.json");
    write_atomic(&path, serde_json::to_string_pretty(&header)?.as_bytes())?;
    println!("exported the room, model, geometry and logits to {}", path.display());
    Ok(())
}
