//! What the semantic snapshot's surface extraction costs per keyframe: the map's surface cells
//! brought up to date from the TSDF chunks that changed ([`SurfaceCells::update`]), beside the
//! incremental mesher's update of the same keyframe (no budget, and within one), on 7-Scenes
//! with the reference poses.
//!
//! ```text
//! cargo run --release -p semrecon-pipeline --example surface_cells_bench -- \
//!     DIR [--frames 200] [--keyframe 10] [--mesh-budget 3072] [--repeat N]
//! ```
//!
//! `--repeat N` then reads the final map's surface N more times from scratch (every chunk
//! changed) and prints the fastest wall time: a steadier measure on a busy machine, and a
//! load for profilers.
//!
//! Per keyframe it prints nothing; at the end the median and p95 wall milliseconds of: the
//! scan alone (surface points of the changed chunks and their lower neighbours, counted, not
//! summed), the whole cell update, and the two meshers, with the mean surface points and
//! changed chunks a keyframe. Threads: `RAYON_NUM_THREADS`.

use std::time::Instant;

use semrecon_data::datasets::SevenScenes;
use semrecon_data::FrameSource;
use semrecon_pipeline::semantic_map::SurfaceCells;
use semrecon_pipeline::surface_cells::{for_each_chunk_point, readers_of, SurfaceRule};
use semrecon_recon::{IncrementalMesher, MeshConfig, RemeshTolerance, TsdfConfig, TsdfMap};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let arg = |name: &str| args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).cloned();
    let dir = args.get(1).filter(|a| !a.starts_with("--")).ok_or("usage: surface_cells_bench DIR [--frames N]")?;
    let frames: usize = arg("--frames").map_or(Ok(200), |v| v.parse())?;
    let keyframe: usize = arg("--keyframe").map_or(Ok(10), |v| v.parse())?;
    let budget: usize = arg("--mesh-budget").map_or(Ok(3072), |v| v.parse())?;
    let repeat: usize = arg("--repeat").map_or(Ok(0), |v| v.parse())?;
    let source = SevenScenes::open(dir)?;
    let tsdf = TsdfConfig { truncation_voxels: 10.0, ..TsdfConfig::default() };
    let mesh = MeshConfig::RECOMMENDED;
    let rule = SurfaceRule::new(&tsdf, &mesh);
    let mut map = TsdfMap::new(tsdf)?;
    let mut cells = SurfaceCells::new(0.05, rule);
    let mut whole = IncrementalMesher::with_config(mesh, RemeshTolerance::EXACT)?;
    let mut budgeted =
        IncrementalMesher::with_config(mesh, RemeshTolerance::EXACT)?.with_budget(std::num::NonZeroUsize::new(budget));
    let (mut scan_ms, mut update_ms, mut whole_ms, mut budget_ms) = (vec![], vec![], vec![], vec![]);
    let (mut points, mut changed, mut last_revision) = (0usize, 0usize, 0u64);
    for i in 0..frames.min(source.len()) {
        let frame = source.frame(i)?;
        let pose = frame.world_from_camera.ok_or("a frame without a reference pose")?;
        map.integrate(&frame, pose)?;
        if (i + 1) % keyframe != 0 {
            continue;
        }
        // The scan alone, over what the update will re-read.
        let t = Instant::now();
        let mut keys: Vec<_> =
            map.chunks().filter(|c| c.revision() > last_revision).flat_map(|c| readers_of(c.key())).collect();
        last_revision = map.chunks().map(|c| c.revision()).max().unwrap_or(0);
        keys.sort_unstable_by_key(|k| (k.z, k.y, k.x));
        keys.dedup();
        use rayon::prelude::*;
        let n: usize = keys
            .par_iter()
            .map(|k| {
                let mut n = 0;
                for_each_chunk_point(&map, *k, &rule, |_| n += 1);
                n
            })
            .sum();
        scan_ms.push(t.elapsed().as_secs_f64() * 1e3);
        points += n;
        changed += keys.len();
        let t = Instant::now();
        cells.update(&map);
        update_ms.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        whole.update(&map);
        whole_ms.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        budgeted.update(&map);
        budget_ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let keyframes = scan_ms.len().max(1);
    println!(
        "{keyframes} keyframes; per keyframe {} chunks re-read, {} surface points; {} cells at the end",
        changed / keyframes,
        points / keyframes,
        cells.len()
    );
    println!("{:<40} {:>10} {:>10}", "wall ms per keyframe", "median", "p95");
    for (name, v) in [
        ("surface scan alone", &mut scan_ms),
        ("surface cells update", &mut update_ms),
        ("meshing, no budget", &mut whole_ms),
        ("meshing, budget", &mut budget_ms),
    ] {
        v.sort_by(f64::total_cmp);
        let at = |q: f64| v.get(((v.len() as f64 - 1.0) * q).round() as usize).copied().unwrap_or(0.0);
        println!("{name:<40} {:>10.2} {:>10.2}", at(0.5), at(0.95));
    }
    let mut best = f64::INFINITY;
    for _ in 0..repeat {
        let mut fresh = SurfaceCells::new(0.05, rule);
        let t = Instant::now();
        fresh.update(&map);
        best = best.min(t.elapsed().as_secs_f64() * 1e3);
    }
    if repeat > 0 {
        println!("whole final map ({} chunks) from scratch, fastest of {repeat}: {best:.2} ms", map.chunk_count());
    }
    Ok(())
}
