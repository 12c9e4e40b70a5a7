//! The convolution benchmark as a library function, so that the CLI (`semrecon bench conv`)
//! and the example share one implementation: a procedural room scene, timings of every kernel
//! and pass on it, and the machine's dense GEMM rate measured in the same run as the roofline.
//!
//! GFLOP/s count useful work only: `2 x pairs x c_in x c_out` for every pass.

use std::time::Instant;

use rayon::prelude::*;
use serde::Serialize;

use crate::backend::ConvBackend;
use crate::chunked::{ChunkConfig, ChunkedConv};
use crate::error::Result;
use crate::gemm::gemm_rows;
use crate::kernel_map::KernelMap;
use crate::key::Coord;
use crate::resident::ResidentBackend;
use crate::rulebook;
use crate::voxelize::voxelize;

/// One timing of one kernel and pass.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BenchRow {
    /// Scene name.
    pub scene: String,
    /// Voxel size in metres.
    pub voxel_size: f32,
    /// Active voxels.
    pub n: usize,
    /// Mean active neighbours per voxel (pairs / n).
    pub mean_neighbours: f64,
    /// Input channels.
    pub c_in: usize,
    /// Output channels.
    pub c_out: usize,
    /// `rulebook` or `chunked`.
    pub kernel: String,
    /// `forward`, `backward_input` or `backward_weight`.
    pub pass: String,
    /// Wall time in milliseconds (fastest of the repeats).
    pub ms: f64,
    /// Useful GFLOP/s.
    pub gflops: f64,
}

/// Everything one benchmark run measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BenchReport {
    /// Timings.
    pub rows: Vec<BenchRow>,
    /// Dense f32 GEMM rate at the layer's channels (`[*, c_in] . [c_in, c_out]`, all threads,
    /// this crate's micro-kernel, cache-resident blocks): the roofline of the sparse kernels.
    pub sgemm_gflops: f64,
    /// Building the submanifold kernel map, ms.
    pub map_ms: f64,
    /// Building the chunk plan, ms.
    pub plan_ms: f64,
    /// Chunks in the plan.
    pub chunks: usize,
    /// Region rows per output row of the plan.
    pub halo_ratio: f64,
    /// The micro-GEMM implementation in use.
    pub simd: String,
    /// Rayon threads.
    pub threads: usize,
}

/// Benchmark settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BenchOptions {
    /// Timed rounds (the fastest is reported), after one warm-up round.
    pub repeats: usize,
    /// Chunking of the chunked kernel.
    pub chunk: ChunkConfig,
    /// Also time the rulebook baseline.
    pub rulebook: bool,
}

impl Default for BenchOptions {
    fn default() -> Self {
        Self { repeats: 5, chunk: ChunkConfig::default(), rulebook: true }
    }
}

/// Surface points of a procedural room: the shell of a 1.8 x 1.5 x 1.0 m room (floor at z = 0),
/// a 0.6 x 0.4 x 0.5 m box on the floor, a table top on four legs and a ball, sampled every
/// `spacing` metres. About 35k voxels at 2 cm.
pub fn room_points(spacing: f32) -> Vec<[f32; 3]> {
    let mut pts = Vec::new();
    let steps = |len: f32| (len / spacing).ceil() as usize;
    // An axis-aligned rectangle: origin, two edge vectors.
    let mut rect = |o: [f32; 3], u: [f32; 3], v: [f32; 3]| {
        let (lu, lv) = (u.iter().map(|a| a * a).sum::<f32>().sqrt(), v.iter().map(|a| a * a).sum::<f32>().sqrt());
        let (nu, nv) = (steps(lu), steps(lv));
        for i in 0..=nu {
            for j in 0..=nv {
                let (s, t) = (i as f32 / nu.max(1) as f32, j as f32 / nv.max(1) as f32);
                pts.push([0, 1, 2].map(|a| o[a] + s * u[a] + t * v[a]));
            }
        }
    };
    let (lx, ly, lz) = (1.8f32, 1.5f32, 1.0f32);
    rect([0.0, 0.0, 0.0], [lx, 0.0, 0.0], [0.0, ly, 0.0]);
    rect([0.0, 0.0, lz], [lx, 0.0, 0.0], [0.0, ly, 0.0]);
    rect([0.0, 0.0, 0.0], [lx, 0.0, 0.0], [0.0, 0.0, lz]);
    rect([0.0, ly, 0.0], [lx, 0.0, 0.0], [0.0, 0.0, lz]);
    rect([0.0, 0.0, 0.0], [0.0, ly, 0.0], [0.0, 0.0, lz]);
    rect([lx, 0.0, 0.0], [0.0, ly, 0.0], [0.0, 0.0, lz]);
    // A box (cabinet) against the wall.
    let (bx, by, bz, bw, bd, bh) = (1.1f32, 0.05f32, 0.0f32, 0.6f32, 0.4f32, 0.5f32);
    rect([bx, by, bz + bh], [bw, 0.0, 0.0], [0.0, bd, 0.0]);
    rect([bx, by + bd, bz], [bw, 0.0, 0.0], [0.0, 0.0, bh]);
    rect([bx, by, bz], [0.0, bd, 0.0], [0.0, 0.0, bh]);
    rect([bx + bw, by, bz], [0.0, bd, 0.0], [0.0, 0.0, bh]);
    // A table: top and four thin legs.
    rect([0.3, 0.7, 0.45], [0.6, 0.0, 0.0], [0.0, 0.5, 0.0]);
    for (x, y) in [(0.32, 0.72), (0.88, 0.72), (0.32, 1.18), (0.88, 1.18)] {
        rect([x, y, 0.0], [0.02, 0.0, 0.0], [0.0, 0.0, 0.45]);
    }
    // A ball on the floor.
    let (r, c) = (0.2f32, [1.4f32, 1.1f32, 0.2f32]);
    let n = steps(std::f32::consts::PI * r);
    for i in 0..=n {
        let th = std::f32::consts::PI * i as f32 / n as f32;
        let m = (2.0 * n as f32 * th.sin()).ceil().max(1.0) as usize;
        for j in 0..m {
            let ph = 2.0 * std::f32::consts::PI * j as f32 / m as f32;
            pts.push([c[0] + r * th.sin() * ph.cos(), c[1] + r * th.sin() * ph.sin(), c[2] + r * th.cos()]);
        }
    }
    pts
}

/// The procedural room voxelised at `voxel_size` (Z-order).
///
/// # Errors
/// A voxel size that is not positive and finite.
pub fn room_voxels(voxel_size: f32) -> Result<Vec<Coord>> {
    let pts = room_points(voxel_size / 2.5);
    Ok(voxelize(&pts, &[], 0, voxel_size, 0)?.tensor.coords().to_vec())
}

/// Fastest of `repeats` runs after a warm-up: on a shared machine the minimum is the run least
/// disturbed by other processes, the best estimate of the kernel's own cost.
fn min_ms(repeats: usize, mut f: impl FnMut()) -> f64 {
    f();
    (0..repeats.max(1))
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64() * 1e3
        })
        .fold(f64::INFINITY, f64::min)
}

fn fill(n: usize, seed: u32) -> Vec<f32> {
    (0..n)
        .map(|i| ((i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed) >> 8) as f32 / (1 << 24) as f32 - 0.5)
        .collect()
}

/// The roofline: a dense f32 GEMM `[m, k] . [k, n]` with this crate's micro-kernel where every
/// thread multiplies its own cache-resident block of 512 rows `reps` times, so that memory
/// bandwidth does not enter: the arithmetic rate any sparse kernel of this shape could reach.
struct DenseGemm {
    a: Vec<f32>,
    b: Vec<f32>,
    c: Vec<f32>,
    k: usize,
    n: usize,
    reps: usize,
    id: Vec<u32>,
}

/// Rows of one thread's block in [`DenseGemm`].
const DENSE_BLOCK: usize = 512;

impl DenseGemm {
    /// About `flop` useful operations per run.
    fn new(k: usize, n: usize, flop: f64) -> Self {
        let threads = rayon::current_num_threads().max(1);
        let m = DENSE_BLOCK * threads;
        let reps = (flop / (2.0 * (m * k * n).max(1) as f64)).ceil().max(1.0) as usize;
        Self {
            a: fill(m * k, 1),
            b: fill(k * n, 2),
            c: vec![0f32; m * n],
            k,
            n,
            reps,
            id: (0..DENSE_BLOCK as u32).collect(),
        }
    }

    fn flop(&self) -> f64 {
        2.0 * (self.c.len() * self.k * self.reps) as f64
    }

    fn run(&mut self) {
        let (a, b, k, n, id, reps) = (&self.a, &self.b, self.k, self.n, &self.id, self.reps);
        if n == 0 {
            return;
        }
        self.c.par_chunks_mut(DENSE_BLOCK * n).enumerate().for_each(|(i, cb)| {
            let rows = cb.len() / n;
            let ab = &a[i * DENSE_BLOCK * k..(i * DENSE_BLOCK + rows) * k];
            for _ in 0..reps {
                gemm_rows(ab, k, &id[..rows], b, k, n, cb, n, &id[..rows], true);
            }
        });
    }
}

/// The roofline rate in GFLOP/s for `[*, k] . [k, n]` on all rayon threads (see the bench
/// module; fastest of `repeats` after a warm-up).
pub fn dense_sgemm_gflops(k: usize, n: usize, repeats: usize) -> f64 {
    let mut d = DenseGemm::new(k, n, 1e9);
    let ms = min_ms(repeats, || d.run());
    d.flop() / (ms * 1e6)
}

/// Times every pass of the chunked kernel (and the rulebook baseline) for a submanifold
/// K = 3 layer on `coords`, with random features and weights.
///
/// # Errors
/// Coordinates outside the key range or a bad chunk configuration.
pub fn run_conv_bench(
    scene: &str,
    coords: &[Coord],
    voxel_size: f32,
    c_in: usize,
    c_out: usize,
    options: &BenchOptions,
) -> Result<BenchReport> {
    let t = Instant::now();
    let map = KernelMap::submanifold(coords, 3)?;
    let map_ms = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let conv = ChunkedConv::new(map.clone(), coords, coords, &options.chunk)?;
    let plan_ms = t.elapsed().as_secs_f64() * 1e3;
    let n = coords.len();
    let x = fill(n * c_in, 3);
    let dy = fill(n * c_out, 4);
    let w = fill(27 * c_in * c_out, 5);
    let flop = 2.0 * map.num_pairs() as f64 * (c_in * c_out) as f64;
    // Every measurement runs once per round, round-robin, so that the load of other processes
    // on a shared machine hits all of them alike; the fastest round of each is kept.
    // Outputs are preallocated (the `_into` entry points), as a training loop would keep them:
    // fresh multi-megabyte buffers cost page faults that are not the kernels' work.
    let mut y = vec![0f32; n * c_out];
    let mut dx = vec![0f32; n * c_in];
    let y_ptr = std::cell::RefCell::new(&mut y);
    let dx_ptr = std::cell::RefCell::new(&mut dx);
    type Pass<'a> = Box<dyn FnMut() -> f32 + 'a>;
    let mut passes: Vec<(&str, &str, Pass)> = Vec::new();
    if options.rulebook {
        passes.push((
            "rulebook",
            "forward",
            Box::new(|| {
                let mut y = y_ptr.borrow_mut();
                rulebook::forward_into(&map, &x, c_in, &w, c_out, &mut y).map_or(0.0, |()| y[0])
            }),
        ));
        passes.push((
            "rulebook",
            "backward_input",
            Box::new(|| {
                let mut dx = dx_ptr.borrow_mut();
                rulebook::backward_input_into(&map, &dy, c_out, &w, c_in, &mut dx).map_or(0.0, |()| dx[0])
            }),
        ));
        passes.push((
            "rulebook",
            "backward_weight",
            Box::new(|| rulebook::backward_weight(&map, &x, c_in, &dy, c_out).map_or(0.0, |v| v[0])),
        ));
    }
    passes.push((
        "chunked",
        "forward",
        Box::new(|| {
            let mut y = y_ptr.borrow_mut();
            conv.forward_into(&x, c_in, &w, c_out, &mut y).map_or(0.0, |()| y[0])
        }),
    ));
    passes.push((
        "chunked",
        "backward_input",
        Box::new(|| {
            let mut dx = dx_ptr.borrow_mut();
            conv.backward_input_into(&dy, c_out, &w, c_in, &mut dx).map_or(0.0, |()| dx[0])
        }),
    ));
    passes.push((
        "chunked",
        "backward_weight",
        Box::new(|| conv.backward_weight(&x, c_in, &dy, c_out).map_or(0.0, |v| v[0])),
    ));
    let mut dense = DenseGemm::new(c_in, c_out, flop);
    let mut best = vec![f64::INFINITY; passes.len() + 1];
    let mut sink = 0f32;
    for round in 0..=options.repeats.max(1) {
        for (i, p) in passes.iter_mut().enumerate() {
            let t = Instant::now();
            sink += (p.2)();
            if round > 0 {
                best[i] = best[i].min(t.elapsed().as_secs_f64() * 1e3);
            }
        }
        let t = Instant::now();
        dense.run();
        if round > 0 {
            best[passes.len()] = best[passes.len()].min(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    std::hint::black_box(sink);
    let rows = passes
        .iter()
        .zip(&best)
        .map(|(p, &ms)| BenchRow {
            scene: scene.to_string(),
            voxel_size,
            n,
            mean_neighbours: map.mean_neighbours(),
            c_in,
            c_out,
            kernel: p.0.to_string(),
            pass: p.1.to_string(),
            ms,
            gflops: flop / (ms * 1e6),
        })
        .collect();
    let sgemm_gflops = dense.flop() / (best[passes.len()] * 1e6);
    drop(passes);
    Ok(BenchReport {
        rows,
        sgemm_gflops,
        map_ms,
        plan_ms,
        chunks: conv.forward_plan().num_chunks(),
        halo_ratio: conv.forward_plan().halo_ratio(),
        simd: format!("{:?}", crate::gemm::simd_level()),
        threads: rayon::current_num_threads(),
    })
}

/// The benchmarked layer of [`run_backend_bench`] and [`run_resident_forward_bench`]: what
/// every row of it repeats.
struct LayerShape<'a> {
    scene: &'a str,
    voxel_size: f32,
    n: usize,
    pairs: usize,
    c_in: usize,
    c_out: usize,
}

impl LayerShape<'_> {
    /// One row of the layer.
    fn row(&self, kernel: String, pass: &str, ms: f64, gflops: f64) -> BenchRow {
        BenchRow {
            scene: self.scene.to_string(),
            voxel_size: self.voxel_size,
            n: self.n,
            mean_neighbours: self.pairs as f64 / self.n.max(1) as f64,
            c_in: self.c_in,
            c_out: self.c_out,
            kernel,
            pass: pass.to_string(),
            ms,
            gflops,
        }
    }
}

/// Times the submanifold forward on an engine's own tensors (pass `forward_resident`): the
/// layer prepared, input and weights uploaded once, then `batch` forwards recorded back to back
/// and one read-back of a single value to wait for them, the fastest of `repeats` such rounds
/// per forward. This is what a peer that keeps its tensors on the device measures (spconv's
/// `SubMConv3d` timed between two `torch.cuda.synchronize()`), unlike [`run_backend_bench`]'s
/// whole calls, which copy features in and out every time. On the CPU engine both are the same
/// work. Returns `None` for an empty voxel set.
///
/// # Errors
/// The engine's errors.
#[allow(clippy::too_many_arguments)]
pub fn run_resident_forward_bench<B: ResidentBackend>(
    engine: &B,
    scene: &str,
    coords: &[Coord],
    voxel_size: f32,
    c_in: usize,
    c_out: usize,
    repeats: usize,
    batch: usize,
) -> std::result::Result<Option<BenchRow>, B::Error> {
    let n = coords.len();
    if n == 0 {
        return Ok(None);
    }
    let layer = engine.submanifold(coords, 3)?;
    let x = engine.upload(&fill(n * c_in, 3))?;
    let w = engine.upload(&fill(27 * c_in * c_out, 5))?;
    let mut y = engine.upload(&[])?;
    engine.reserve(&mut y, n * c_out)?;
    let pairs = KernelMap::submanifold(coords, 3)?.num_pairs();
    let flop = 2.0 * pairs as f64 * (c_in * c_out) as f64;
    let batch = batch.max(1);
    let mut best = f64::INFINITY;
    // The first round is a warm-up (pipelines compiled, workspaces grown).
    for round in 0..=repeats.max(1) {
        let t = Instant::now();
        for _ in 0..batch {
            engine.conv(&layer, &x, c_in, None, &w, c_out, &mut y, false)?;
        }
        engine.download(&y, 1)?;
        if round > 0 {
            best = best.min(t.elapsed().as_secs_f64() * 1e3 / batch as f64);
        }
    }
    let shape = LayerShape { scene, voxel_size, n, pairs, c_in, c_out };
    Ok(Some(shape.row(engine.name(), "forward_resident", best, flop / (best * 1e6))))
}

/// Times any [`ConvBackend`] on a voxel set: the submanifold layer's preparation (kernel map
/// and plans, reported as pass `prepare`), then forward, input and weight gradient, each the
/// fastest of `repeats` rounds after a warm-up. Times are whole calls as a caller sees them
/// (for a GPU engine: uploads, dispatches and read-back included). Rows are named after the
/// engine (`cpu-chunked`, `gpu-rulebook`, ...).
///
/// # Errors
/// The engine's errors.
pub fn run_backend_bench<B: ConvBackend>(
    engine: &B,
    scene: &str,
    coords: &[Coord],
    voxel_size: f32,
    c_in: usize,
    c_out: usize,
    repeats: usize,
) -> std::result::Result<Vec<BenchRow>, B::Error> {
    let t = Instant::now();
    let layer = engine.submanifold(coords, 3)?;
    let prepare_ms = t.elapsed().as_secs_f64() * 1e3;
    let n = coords.len();
    let (x, dy, w) = (fill(n * c_in, 3), fill(n * c_out, 4), fill(27 * c_in * c_out, 5));
    let pairs = KernelMap::submanifold(coords, 3)?.num_pairs();
    let flop = 2.0 * pairs as f64 * (c_in * c_out) as f64;
    let mut best = [f64::INFINITY; 3];
    for _ in 0..repeats.max(1) + 1 {
        let t = Instant::now();
        engine.forward(&layer, &x, c_in, &w, c_out)?;
        best[0] = best[0].min(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        engine.backward_input(&layer, &dy, c_out, &w, c_in)?;
        best[1] = best[1].min(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        engine.backward_weight(&layer, &x, c_in, &dy, c_out)?;
        best[2] = best[2].min(t.elapsed().as_secs_f64() * 1e3);
    }
    let shape = LayerShape { scene, voxel_size, n, pairs, c_in, c_out };
    let row = |pass: &str, ms: f64, gflops: f64| shape.row(engine.name(), pass, ms, gflops);
    let mut rows = vec![row("prepare", prepare_ms, 0.0)];
    for (pass, ms) in ["forward", "backward_input", "backward_weight"].into_iter().zip(best) {
        rows.push(row(pass, ms, flop / (ms * 1e6)));
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ConvAlgorithm, CpuEngine};

    #[test]
    fn resident_forward_row_counts_the_layers_work() {
        let coords = room_voxels(0.4).expect("room");
        let engine = CpuEngine::new(ConvAlgorithm::Chunked);
        let row = run_resident_forward_bench(&engine, "room", &coords, 0.4, 5, 7, 1, 2).expect("bench").expect("a row");
        let pairs = KernelMap::submanifold(&coords, 3).expect("map").num_pairs();
        assert_eq!((row.n, row.c_in, row.c_out, row.pass.as_str()), (coords.len(), 5, 7, "forward_resident"));
        assert!((row.mean_neighbours - pairs as f64 / coords.len() as f64).abs() < 1e-12);
        assert!(row.ms > 0.0 && row.gflops > 0.0);
        assert_eq!(run_resident_forward_bench(&engine, "empty", &[], 0.4, 5, 7, 1, 2).expect("bench"), None);
    }
}
