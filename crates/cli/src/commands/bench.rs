//! `semrecon bench`: benchmarks that print a table and write JSON rows, measured side by side
//! in one run (the machines are shared and noisy: compare ratios, not absolute numbers).
//!
//! - `render`: the RGB-D rasteriser (and the sensor model) on generated rooms and, when
//!   `../shared/data` is there, the Replica office0 mesh.
//! - `conv`: the sparse convolution kernels (chunked vs rulebook) on voxelised synthetic rooms,
//!   with the machine's dense GEMM rate measured in the same run; `--export DIR` writes the
//!   voxel sets and kernel maps for the peer benchmark `bench/peers_conv.py`.
//! - `net`: the whole network, chunked vs rulebook kernels (see [`super::bench_net`]).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use glam::Vec3;
use semrecon_data::atomic_file::write_atomic;
use semrecon_data::datasets::synthetic::room_scan_poses;
use semrecon_data::shared_data::shared_data_path;
use semrecon_data::synth::{generate_room, RoomConfig, RoomStyle};
use semrecon_data::{read_ply, Intrinsics, LabeledMesh, PreparedMesh, Renderer, ScanPlan, SensorModel};
use semrecon_gpu::{GpuEngine, CHUNKED_TILES};
use semrecon_sparse::bench::{run_backend_bench, run_conv_bench, run_resident_forward_bench, BenchOptions, BenchRow};
use semrecon_sparse::{ChunkConfig, ConvAlgorithm, KernelMap};
use serde::Serialize;

/// Arguments of `semrecon bench`.
#[derive(clap::Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    which: Which,
}

#[derive(clap::Subcommand)]
enum Which {
    /// Rendering speed: frames per second at 640x480.
    Render(RenderArgs),
    /// Sparse convolution speed: chunked vs rulebook, forward and both gradients.
    Conv(ConvArgs),
    /// Network speed: CBSCN on a voxelised room, chunked vs rulebook kernels.
    Net(super::bench_net::NetArgs),
}

/// Arguments of `semrecon bench render`.
#[derive(clap::Args)]
struct RenderArgs {
    /// Frames rendered per scene.
    #[arg(long, default_value_t = 300)]
    frames: usize,
    /// Write the rows as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
}

/// Arguments of `semrecon bench conv`.
#[derive(clap::Args)]
struct ConvArgs {
    /// Voxel sizes in metres (comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = [0.05, 0.02])]
    voxel: Vec<f32>,
    /// Channel counts, C_in = C_out (comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = [32, 64, 128])]
    channels: Vec<usize>,
    /// Seed of the synthetic room that is voxelised.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Timed repeats per measurement (the fastest is kept).
    #[arg(long, default_value_t = 5)]
    repeats: usize,
    /// Write the rows as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Also write every benchmarked voxel set and its submanifold kernel map to this folder,
    /// for the peer benchmark `bench/peers_conv.py` (see [`export_voxels`]).
    #[arg(long)]
    export: Option<PathBuf>,
    /// `gpu` (or `auto` with a GPU) times the GPU engine's chunked and rulebook kernels instead
    /// of the CPU's: whole calls, uploads and read-back included.
    #[command(flatten)]
    device: crate::device::DeviceArgs,
    /// With the GPU: also time the chunked kernel with these chunk shapes, each
    /// `SIDE/LEVELS/REGION_ROWS` (comma-separated; e.g. `16/2/512`), to tune the CPU planner's
    /// cache-sized chunks for a GPU. Rows are named `gpu-chunked SIDE/LEVELS/ROWS`.
    #[arg(long, value_delimiter = ',', value_parser = crate::cli_values::parse_chunk_shape)]
    gpu_chunks: Vec<ChunkConfig>,
    /// With the GPU: also time the chunked kernel with each of these tile shapes forced
    /// (indices into `semrecon_gpu::CHUNKED_TILES`: 0 = 64x64, 1 = 128x32, 2 = 128x64,
    /// 3 = 64x128; by default the shape follows the layer's width). Rows are named
    /// `gpu-chunked tile ROWSxCHANNELS`.
    #[arg(long, value_delimiter = ',')]
    gpu_tiles: Vec<usize>,
}

/// Runs the command.
pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    match args.which {
        Which::Render(a) => render(a),
        Which::Conv(a) => conv(a),
        Which::Net(a) => super::bench_net::run(a),
    }
}

#[derive(Serialize)]
struct RenderRow {
    scene: String,
    triangles: usize,
    width: u32,
    height: u32,
    frames: usize,
    threads: usize,
    render_ms: f64,
    fps: f64,
    sensor_ms: f64,
}

fn render(args: RenderArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.frames > 0, "--frames must be at least 1");
    let k = Intrinsics::new(640, 480, 525.0, 525.0, 319.5, 239.5)?;
    let mut scenes: Vec<(String, LabeledMesh, Vec<glam::Affine3A>)> = Vec::new();
    for style in RoomStyle::ALL {
        let room = generate_room(&RoomConfig { seed: 0, style: Some(style) });
        let poses = room_scan_poses(&room, 0, args.frames, 30.0)?;
        scenes.push((format!("synthetic {style}"), room.mesh, poses));
    }
    if let Some(path) = shared_data_path("replica-office0/office0_mesh.ply") {
        let mesh = read_ply(&path)?;
        let poses = ScanPlan::from_mesh_bounds(&mesh, 0)?.poses(args.frames)?;
        scenes.push(("replica office0".into(), mesh, poses));
    }
    let sensor = SensorModel::kinect();
    let mut rows = Vec::new();
    for (scene, mesh, poses) in &scenes {
        let prepared = PreparedMesh::new(mesh)?;
        let mut renderer = Renderer::new(k)?;
        renderer.render(&prepared, poses[0]); // warm-up: buffers allocated
        let (mut render_s, mut sensor_s) = (0.0, 0.0);
        for (i, pose) in poses.iter().enumerate() {
            let t = Instant::now();
            let out = renderer.render(&prepared, *pose);
            render_s += t.elapsed().as_secs_f64();
            let mut noisy = out.clone();
            let t = Instant::now();
            sensor.apply(&mut noisy, i);
            sensor_s += t.elapsed().as_secs_f64();
        }
        let n = poses.len() as f64;
        rows.push(RenderRow {
            scene: scene.clone(),
            triangles: prepared.triangle_count(),
            width: k.width,
            height: k.height,
            frames: poses.len(),
            threads: rayon::current_num_threads(),
            render_ms: render_s * 1e3 / n,
            fps: n / render_s,
            sensor_ms: sensor_s * 1e3 / n,
        });
    }
    println!("{:<22} {:>9} {:>11} {:>9} {:>8} {:>10}", "scene", "triangles", "size", "render ms", "fps", "sensor ms");
    for r in &rows {
        println!(
            "{:<22} {:>9} {:>11} {:>9.2} {:>8.0} {:>10.2}",
            r.scene,
            r.triangles,
            format!("{}x{}", r.width, r.height),
            r.render_ms,
            r.fps,
            r.sensor_ms
        );
    }
    write_json(args.json.as_ref(), &rows)
}

#[derive(Serialize)]
struct ConvRow {
    #[serde(flatten)]
    row: BenchRow,
    /// `cpu`, or the GPU adapter's name.
    device: String,
    /// The CPU's dense GEMM rate (0 for GPU rows).
    sgemm_gflops: f64,
    threads: usize,
    simd: String,
}

fn conv(args: ConvArgs) -> anyhow::Result<()> {
    let room = generate_room(&RoomConfig { seed: args.seed, style: None });
    let options = BenchOptions { repeats: args.repeats.max(1), ..BenchOptions::default() };
    let gpu = args.device.gpu_context()?;
    let chunk_shapes = args.gpu_chunks;
    anyhow::ensure!(chunk_shapes.is_empty() || gpu.is_some(), "--gpu-chunks needs the GPU (--device gpu)");
    anyhow::ensure!(args.gpu_tiles.is_empty() || gpu.is_some(), "--gpu-tiles needs the GPU (--device gpu)");
    if let Some(bad) = args.gpu_tiles.iter().find(|&&t| t >= CHUNKED_TILES.len()) {
        anyhow::bail!("--gpu-tiles {bad}: the shapes are 0..{}", CHUNKED_TILES.len() - 1);
    }
    let variants: Vec<GpuVariant> = chunk_shapes
        .iter()
        .map(|&c| GpuVariant::Chunk(c))
        .chain(args.gpu_tiles.iter().map(|&t| GpuVariant::Tile(t)))
        .collect();
    let mut rows = Vec::new();
    println!(
        "{:<26} {:>7} {:>6} {:>4} {:>9} {:>16} {:>9} {:>8} {:>7}",
        "scene", "voxels", "neigh", "C", "kernel", "pass", "ms", "GFLOP/s", "% sgemm"
    );
    for &voxel in &args.voxel {
        anyhow::ensure!(voxel.is_finite() && voxel >= 0.005, "--voxel {voxel}: must be at least 0.005 m");
        let coords = voxelize_surface(&room.mesh, voxel);
        let scene = format!("synthetic {} seed {}", room.style, args.seed);
        if let Some(dir) = &args.export {
            export_voxels(dir, &scene, voxel, &coords)?;
        }
        for &c in &args.channels {
            anyhow::ensure!((1..=1024).contains(&c), "--channels {c}: must be 1..=1024");
            if let Some(ctx) = &gpu {
                rows.extend(gpu_conv(ctx, &scene, &coords, voxel, c, options.repeats, &variants)?);
                continue;
            }
            let report = run_conv_bench(&scene, &coords, voxel, c, c, &options)
                .with_context(|| format!("benchmarking {scene} at {voxel} m, {c} channels"))?;
            for row in report.rows {
                print_conv_row(&row, voxel, Some(100.0 * row.gflops / report.sgemm_gflops));
                rows.push(ConvRow {
                    row,
                    device: "cpu".into(),
                    sgemm_gflops: report.sgemm_gflops,
                    threads: report.threads,
                    simd: report.simd.clone(),
                });
            }
        }
    }
    write_json(args.json.as_ref(), &rows)
}

/// One row of `bench conv`'s table; `percent_of_sgemm` is `None` where no roofline was
/// measured (the GPU engine).
fn print_conv_row(row: &BenchRow, voxel: f32, percent_of_sgemm: Option<f64>) {
    let roofline = percent_of_sgemm.map_or_else(|| "-".to_string(), |p| format!("{p:.0}%"));
    println!(
        "{:<26} {:>7} {:>6.2} {:>4} {:>9} {:>16} {:>9.2} {:>8.1} {:>7}",
        format!("{} @ {} cm", row.scene, voxel * 100.0),
        row.n,
        row.mean_neighbours,
        row.c_in,
        row.kernel,
        row.pass,
        row.ms,
        row.gflops,
        roofline
    );
}

/// A variant of the GPU chunked kernel timed beside the defaults.
#[derive(Clone, Copy)]
enum GpuVariant {
    /// Another chunk shape (`--gpu-chunks`).
    Chunk(ChunkConfig),
    /// A forced tile shape (`--gpu-tiles`).
    Tile(usize),
}

/// Forwards per timed round of the resident rows: enough to hide one submission's latency.
const RESIDENT_BATCH: usize = 10;

/// The GPU engine's rows (chunked and rulebook) of one voxel set and channel count: whole calls
/// (uploads, dispatches, read-back) and the forward on device-resident tensors.
fn gpu_conv(
    ctx: &std::sync::Arc<semrecon_gpu::GpuContext>,
    scene: &str,
    coords: &[semrecon_sparse::Coord],
    voxel: f32,
    c: usize,
    repeats: usize,
    variants: &[GpuVariant],
) -> anyhow::Result<Vec<ConvRow>> {
    let mut rows = Vec::new();
    let default_runs = [(ConvAlgorithm::Chunked, None), (ConvAlgorithm::Rulebook, None)];
    let variant_runs = variants.iter().map(|&v| (ConvAlgorithm::Chunked, Some(v)));
    for (algorithm, variant) in default_runs.into_iter().chain(variant_runs) {
        let mut engine = GpuEngine::with_context(std::sync::Arc::clone(ctx), algorithm);
        let label = match variant {
            None => None,
            Some(GpuVariant::Chunk(shape)) => {
                engine = engine.with_chunk(shape);
                Some(format!("{}/{}/{}", shape.chunk_side, shape.levels, shape.max_region_rows))
            }
            Some(GpuVariant::Tile(t)) => {
                engine = engine.with_tile(Some(t))?;
                Some(format!("tile {}x{}", CHUNKED_TILES[t].rows, CHUNKED_TILES[t].channels))
            }
        };
        let bench = run_backend_bench(&engine, scene, coords, voxel, c, c, repeats)
            .with_context(|| format!("GPU benchmark of {scene} at {voxel} m, {c} channels"))?;
        let resident = run_resident_forward_bench(&engine, scene, coords, voxel, c, c, repeats, RESIDENT_BATCH)
            .with_context(|| format!("GPU resident benchmark of {scene} at {voxel} m, {c} channels"))?;
        for mut row in bench.into_iter().chain(resident) {
            if let Some(label) = &label {
                row.kernel = format!("{} {label}", row.kernel);
            }
            print_conv_row(&row, voxel, None);
            rows.push(ConvRow { row, device: ctx.adapter_name(), sgemm_gflops: 0.0, threads: 0, simd: String::new() });
        }
    }
    Ok(rows)
}

/// Surface voxels of a mesh: points sampled on every triangle at a spacing well below the
/// voxel size, then snapped to the voxel grid (duplicates merged by the engine).
fn voxelize_surface(mesh: &LabeledMesh, voxel: f32) -> Vec<semrecon_sparse::Coord> {
    let step = voxel / 3.0;
    let mut coords = Vec::new();
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
        let n = (((b - a).length().max((c - a).length()) / step).ceil() as usize).max(1);
        for i in 0..=n {
            for j in 0..=(n - i) {
                let p: Vec3 = a + (b - a) * (i as f32 / n as f32) + (c - a) * (j as f32 / n as f32);
                let q = (p / voxel).floor();
                coords.push([q.x as i32, q.y as i32, q.z as i32, 0]);
            }
        }
    }
    coords.sort_unstable();
    coords.dedup();
    coords
}

/// Writes `conv_{voxel in mm}mm.json` and beside it the raw little-endian arrays it names:
/// `coords` (`[n, 4]` i32: x, y, z, batch, in the benchmark's row order) and the K = 3
/// submanifold map as `in_rows` / `out_rows` (u32, grouped by offset; offset `k`'s pairs are
/// `offset_start[k]..offset_start[k + 1]`, offset numbering as in `semrecon_sparse::kernel_map`).
/// The peer benchmark times its own kernels on exactly these pairs.
fn export_voxels(dir: &Path, scene: &str, voxel: f32, coords: &[semrecon_sparse::Coord]) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let map = KernelMap::submanifold(coords, 3)?;
    let stem = format!("conv_{}mm", (voxel * 1000.0).round() as u32);
    let raw = |name: &str, words: &mut dyn Iterator<Item = [u8; 4]>| -> anyhow::Result<String> {
        let file = format!("{stem}_{name}.bin");
        let bytes: Vec<u8> = words.flatten().collect();
        write_atomic(&dir.join(&file), &bytes)?;
        Ok(file)
    };
    let header = serde_json::json!({
        "scene": scene,
        "voxel_size": voxel,
        "n": coords.len(),
        "kernel_size": 3,
        "offset_start": map.offset_start(),
        "coords": raw("coords", &mut coords.iter().flatten().map(|v| v.to_le_bytes()))?,
        "in_rows": raw("in_rows", &mut map.in_rows().iter().map(|v| v.to_le_bytes()))?,
        "out_rows": raw("out_rows", &mut map.out_rows().iter().map(|v| v.to_le_bytes()))?,
    });
    let path = dir.join(format!("{stem}.json"));
    write_atomic(&path, serde_json::to_string_pretty(&header)?.as_bytes())?;
    println!("exported {} voxels, {} pairs to {}", coords.len(), map.num_pairs(), path.display());
    Ok(())
}

fn write_json<T: Serialize>(path: Option<&PathBuf>, rows: &T) -> anyhow::Result<()> {
    if let Some(path) = path {
        write_atomic(path, serde_json::to_string_pretty(rows)?.as_bytes())?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
