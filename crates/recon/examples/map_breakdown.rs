//! Where a map's bytes per square metre of surface go: chunks with and without surface,
//! observed voxels by distance from the surface, per-voxel bytes.
//!
//! ```text
//! cargo run --release -p semrecon-recon --example map_breakdown -- [--seed S] [--frames N]
//!     [--truncation T] [--color-band V] [--packed-step V] [--packed-exact-band V]
//! ```
//!
//! Fuses synthetic scan `S` (the demo's room and path, 640x480) at the true poses with the
//! pipeline's band (truncation `T` voxels far away, 10 by default, down to 4 near) and
//! prints counts per square metre of the mesh (meshing's recommended settings), and the
//! bytes with every chunk packed. `--color-band V` sets
//! [`TsdfConfig::color_band_voxels`], `--packed-step V` and `--packed-exact-band V`
//! [`TsdfConfig::packed_far_step_voxels`] and [`TsdfConfig::packed_exact_band_voxels`]
//! ([`TsdfConfig`]).

#[path = "common/flags.rs"]
mod flags;

use glam::IVec3;
use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
use semrecon_data::FrameSource;
use semrecon_recon::{extract_mesh_with, MeshConfig, TsdfConfig, TsdfMap, CHUNK_SIDE};

use flags::Flags;

fn run() -> Result<(), String> {
    let (mut seed, mut frames, mut truncation) = (1u64, 300usize, 10.0f32);
    let mut tsdf = TsdfConfig::default();
    let mut flags = Flags::from_env();
    while let Some(flag) = flags.next_flag() {
        match flag.as_str() {
            "--seed" => seed = flags.value(&flag)?,
            "--frames" => frames = flags.value(&flag)?,
            "--truncation" => truncation = flags.value(&flag)?,
            "--color-band" => tsdf.color_band_voxels = flags.value(&flag)?,
            "--packed-step" => tsdf.packed_far_step_voxels = flags.value(&flag)?,
            "--packed-exact-band" => tsdf.packed_exact_band_voxels = flags.value(&flag)?,
            other => return Err(format!("unknown argument {other}")),
        }
    }
    let mut config = SyntheticScanConfig::new(seed);
    config.frames = frames;
    let (_room, scan) = synthetic_scan(&config).map_err(|e| e.to_string())?;
    let tsdf = TsdfConfig { truncation_voxels: truncation, ..tsdf };
    let mut map = TsdfMap::new(tsdf).map_err(|e| e.to_string())?;
    for i in 0..scan.len() {
        let frame = scan.frame(i).map_err(|e| e.to_string())?;
        let pose = frame.world_from_camera.ok_or("synthetic frames carry their pose")?;
        map.integrate(&frame, pose).map_err(|e| e.to_string())?;
    }
    let mesh = extract_mesh_with(&map, MeshConfig::RECOMMENDED).map_err(|e| e.to_string())?;
    let a = f64::from(mesh.surface_area());
    let min_w = (0.25 * semrecon_recon::map::WEIGHT_SCALE) as u16;
    let per_voxel = truncation / semrecon_recon::map::TSDF_SCALE;
    // Voxel classes: |distance| in voxels.
    let edges = [0.5f32, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 10.1];
    let mut hist = vec![0usize; edges.len()];
    let (mut observed, mut light, mut surface_voxels) = (0usize, 0usize, 0usize);
    let (mut chunks_surface, mut chunks_near_surface) = (0usize, 0usize);
    let mut sat_pos = 0usize;
    let n = CHUNK_SIDE as i32;
    let keys = map.sorted_keys();
    let mut surface_chunk = std::collections::HashSet::new();
    for &k in &keys {
        let c = map.chunk(k).ok_or("chunk")?;
        let mut any = false;
        for i in 0..512 {
            let w = c.stored_weights()[i];
            if w == 0 {
                continue;
            }
            observed += 1;
            if w < min_w {
                light += 1;
            }
            let t = c.stored_tsdf()[i];
            let d = (t as f32 * per_voxel).abs();
            let b = edges.iter().position(|&e| d < e).unwrap_or(edges.len() - 1);
            hist[b] += 1;
            // In front and saturated at the near band (4 voxels) or more.
            if t as f32 * per_voxel >= 3.99 {
                sat_pos += 1;
            }
            if w < min_w {
                continue;
            }
            // A sign change to a heavy enough 6-neighbour: meshing needs this voxel.
            let l = IVec3::new(i as i32 % n, (i as i32 / n) % n, i as i32 / (n * n));
            let v = k * n + l;
            let crossing = [IVec3::X, IVec3::Y, IVec3::Z, -IVec3::X, -IVec3::Y, -IVec3::Z]
                .iter()
                .any(|&o| map.voxel(v + o).is_some_and(|u| u.weight() >= 0.25 && (u.tsdf() < 0.0) != (t < 0)));
            if crossing {
                surface_voxels += 1;
                any = true;
            }
        }
        if any {
            chunks_surface += 1;
            surface_chunk.insert(k);
        }
    }
    for &k in &keys {
        let near =
            (-1..=1).any(|z| (-1..=1).any(|y| (-1..=1).any(|x| surface_chunk.contains(&(k + IVec3::new(x, y, z))))));
        chunks_near_surface += near as usize;
    }
    let total = keys.len();
    println!("synth:{seed}, {frames} frames, truncation {truncation} voxels (band 4..{truncation})");
    println!("mesh area {a:.3} m2; chunks {total} ({:.0}/m2)", total as f64 / a);
    println!(
        "chunks with a surface voxel {chunks_surface} ({:.1}%), within one chunk of one {chunks_near_surface} ({:.1}%)",
        100.0 * chunks_surface as f64 / total as f64,
        100.0 * chunks_near_surface as f64 / total as f64
    );
    let voxels = total * 512;
    println!(
        "voxels allocated {voxels} ({:.0}/m2), observed {observed} ({:.1}%, {:.0}/m2), below mesh weight {light} ({:.1}% of observed), surface voxels {surface_voxels} ({:.0}/m2)",
        voxels as f64 / a,
        100.0 * observed as f64 / voxels as f64,
        observed as f64 / a,
        100.0 * light as f64 / observed as f64,
        surface_voxels as f64 / a
    );
    println!(
        "in front at >= 4 voxels (saturated near band): {:.1}% of observed",
        100.0 * sat_pos as f64 / observed as f64
    );
    let mut lo = 0.0;
    for (e, h) in edges.iter().zip(&hist) {
        println!("|d| {lo:>4}..{e:<4} voxels: {:5.1}% of observed", 100.0 * *h as f64 / observed as f64);
        lo = *e;
    }
    println!("map bytes {} ({:.2} MB/m2)", map.memory_bytes(), map.memory_bytes() as f64 / a / 1e6);
    // Every chunk packed (losslessly): what the map costs once the camera has left.
    let mut packed = map.clone();
    packed.compact(u32::MAX, 0);
    let m = packed.memory();
    println!(
        "every chunk packed: {} bytes ({:.0} B/chunk of voxels, records {:.0} B/chunk), {:.2} MB/m2",
        m.in_memory(),
        m.packed_bytes as f64 / total as f64,
        m.record_bytes as f64 / total as f64,
        m.in_memory() as f64 / a / 1e6
    );
    Ok(())
}

fn main() {
    if let Err(e) = run() {
        eprintln!("map_breakdown: {e}");
        std::process::exit(1);
    }
}
