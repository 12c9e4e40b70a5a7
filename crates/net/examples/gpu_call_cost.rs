//! The fixed cost of a GPU call on a small input, for profilers and quick timings:
//! `target/release/examples/gpu_call_cost [CROP_M] [CALLS]` (build with `--features gpu`).
//! Takes the `bench net` room's corner within CROP_M metres (default 0.5: 271 voxels), warms
//! up, then times CALLS (default 30) device hierarchies alone (`GpuEngine::build_hierarchy`,
//! five levels) and CALLS whole s20 calls (`Segmenter::segment`), and prints the fewest and
//! the median host CPU milliseconds of the calling thread (Linux: /proc/thread-self/schedstat)
//! and the wall milliseconds. On lavapipe the kernels run on the driver's threads, so the host
//! CPU is the host's own share; on a GPU it also holds what the driver does in the caller.

use semrecon_data::synth::{generate_room, RoomConfig};
use semrecon_gpu::GpuEngine;
use semrecon_net::dataset::points_per_m2;
use semrecon_net::inference::Device;
use semrecon_net::surface::sample_surface;
use semrecon_net::{NetConfig, Segmenter, VoxelSample, Weights};
use semrecon_sparse::ConvAlgorithm;

/// Nanoseconds the calling thread has run (0 where the kernel does not say).
fn thread_cpu_ns() -> u64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next().and_then(|v| v.parse().ok()))
        .unwrap_or(0)
}

/// Fewest and median of `v`.
fn spread(mut v: Vec<f64>) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    (v.first().copied().unwrap_or(0.0), v.get(v.len() / 2).copied().unwrap_or(0.0))
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let crop: f32 = std::env::args().nth(1).map_or(Ok(0.5), |s| s.parse())?;
    let calls: usize = std::env::args().nth(2).map_or(Ok(30), |s| s.parse())?;
    let config = NetConfig::from_name_or_file("s20")?;
    let room = generate_room(&RoomConfig { seed: 0, style: None });
    let mut cloud = sample_surface(&room.mesh, points_per_m2(config.voxel_size), 0);
    let keep: Vec<usize> = (0..cloud.len()).filter(|&i| cloud.positions[i].max_element() < crop).collect();
    cloud.positions = keep.iter().map(|&i| cloud.positions[i]).collect();
    cloud.colors = keep.iter().map(|&i| cloud.colors[i]).collect();
    cloud.labels = keep.iter().map(|&i| cloud.labels[i]).collect();
    let sample = VoxelSample::from_cloud(&cloud, config.voxel_size)?;
    let engine = GpuEngine::new(ConvAlgorithm::Chunked)?;
    println!("{} voxels on {}", sample.len(), engine.context().adapter_name());
    let mut net = Segmenter::new(Weights::random(&config, 0), config.clone())?;
    net.set_device(Device::Gpu(engine.clone()));
    for _ in 0..3 {
        net.segment(&sample.coords, &sample.features)?;
    }
    let mut hierarchy = Vec::with_capacity(calls);
    for _ in 0..calls {
        let cpu = thread_cpu_ns();
        let h = engine.build_hierarchy(&sample.coords, config.levels)?;
        hierarchy.push((thread_cpu_ns() - cpu) as f64 * 1e-6);
        drop(h);
    }
    let (mut cpu_ms, mut wall_ms) = (Vec::with_capacity(calls), Vec::with_capacity(calls));
    for _ in 0..calls {
        let cpu = thread_cpu_ns();
        let t = std::time::Instant::now();
        net.segment(&sample.coords, &sample.features)?;
        wall_ms.push(t.elapsed().as_secs_f64() * 1e3);
        cpu_ms.push((thread_cpu_ns() - cpu) as f64 * 1e-6);
    }
    let (h0, h1) = spread(hierarchy);
    let (c0, c1) = spread(cpu_ms);
    let (w0, w1) = spread(wall_ms);
    println!("hierarchy alone: host cpu {h0:.3} ms fewest, {h1:.3} ms median");
    println!("whole call:      host cpu {c0:.3} ms fewest, {c1:.3} ms median; wall {w0:.1} / {w1:.1} ms");
    Ok(())
}
