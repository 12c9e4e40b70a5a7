//! Where a map's bytes per square metre of surface go: chunks with and without surface,
//! observed voxels by distance from the surface, per-voxel bytes.
//!
//! ```text
//! cargo run --release -p semrecon-recon --example map_breakdown -- [--seed S] [--frames N]
//!     [--truncation T]
//! ```
//!
//! Fuses synthetic scan `S` (the demo's room and path, 640x480) at the true poses with the
//! pipeline's band (truncation `T` voxels far away, 10 by default, down to 4 near) and
//! prints counts per square metre of the mesh (meshing's recommended settings).

#[path = "common/flags.rs"]
mod flags;

use glam::IVec3;
use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
use semrecon_data::{FrameSource, LabeledMesh};
use semrecon_recon::{extract_mesh_with, MeshConfig, TsdfConfig, TsdfMap, CHUNK_SIDE};

use flags::Flags;

fn area(mesh: &LabeledMesh) -> f64 {
    mesh.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            0.5 * (b - a).cross(c - a).length() as f64
        })
        .sum()
}

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
            "--observe-free-space" => tsdf.observe_free_space = true,
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
    let a = area(&mesh);
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
            let crossing = [IVec3::X, IVec3::Y, IVec3::Z, -IVec3::X, -IVec3::Y, -IVec3::Z].iter().any(|&o| {
                map.voxel(v + o).is_some_and(|u| u.weight() >= 0.25 && (u.tsdf() < 0.0) != (t < 0))
            });
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
        let near = (-1..=1).any(|z| {
            (-1..=1).any(|y| (-1..=1).any(|x| surface_chunk.contains(&(k + IVec3::new(x, y, z)))))
        });
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
    println!("in front at >= 4 voxels (saturated near band): {:.1}% of observed", 100.0 * sat_pos as f64 / observed as f64);
    let mut lo = 0.0;
    for (e, h) in edges.iter().zip(&hist) {
        println!("|d| {lo:>4}..{e:<4} voxels: {:5.1}% of observed", 100.0 * *h as f64 / observed as f64);
        lo = *e;
    }
    println!("map bytes {} ({:.2} MB/m2)", map.memory_bytes(), map.memory_bytes() as f64 / a / 1e6);
    let pv = per_voxel;
    let report = |name: &str, bytes: usize| {
        println!("{name:<60} packed {:>11} B, {:>6.0} B/chunk, {:.2} MB/m2", bytes, bytes as f64 / total as f64, bytes as f64 / a / 1e6)
    };
    type F = dyn Fn(glam::IVec3, &mut [i16; 512], &mut [u16; 512], &mut [[u8; 4]; 512]) + Sync;
    let q_weight = |w: &mut [u16; 512]| {
        for x in w.iter_mut() {
            if *x != 0 {
                *x = ((*x as u32 + 32) / 64).clamp(1, 255) as u16;
            }
        }
    };
    let variants: Vec<(&str, Box<F>)> = vec![
        ("lossless", Box::new(|_, _, _, _| {})),
        ("w8 (w/64), no colour count", Box::new(move |_, _, w, c| {
            q_weight(w);
            c.iter_mut().for_each(|c| c[3] = 0);
        })),
        ("w8, no colour at all", Box::new(move |_, _, w, c| {
            q_weight(w);
            c.iter_mut().for_each(|c| *c = [0; 4]);
        })),
        ("w8, colour only |d|<2", Box::new(move |_, t, w, c| {
            q_weight(w);
            for i in 0..512 {
                c[i][3] = 0;
                if (t[i] as f32 * pv).abs() >= 2.0 { c[i] = [0; 4]; }
            }
        })),
        ("w8, colour |d|<2, tsdf >=4 vox clamped to 4, weight const", Box::new(move |_, t, w, c| {
            q_weight(w);
            for i in 0..512 {
                c[i][3] = 0;
                if (t[i] as f32 * pv).abs() >= 2.0 { c[i] = [0; 4]; }
                if w[i] != 0 && t[i] as f32 * pv >= 4.0 { t[i] = (4.0 / pv) as i16; w[i] = 255; }
            }
        })),
        ("w8, colour |d|<2, |d|>=4 dropped", Box::new(move |_, t, w, c| {
            q_weight(w);
            for i in 0..512 {
                c[i][3] = 0;
                if (t[i] as f32 * pv).abs() >= 2.0 { c[i] = [0; 4]; }
                if (t[i] as f32 * pv).abs() >= 4.0 { t[i] = 0; w[i] = 0; }
            }
        })),
        ("lossless tsdf+weight, no colour", Box::new(|_, _, _, c| { c.iter_mut().for_each(|c| *c = [0; 4]); })),
        ("w8, tsdf>>4, no colour", Box::new(move |_, t, w, c| {
            q_weight(w);
            t.iter_mut().for_each(|t| *t >>= 4);
            c.iter_mut().for_each(|c| *c = [0; 4]);
        })),
    ];
    for (name, f) in &variants {
        report(name, map.experiment_packed_bytes(&**f));
    }
    Ok(())
}

fn main() {
    if let Err(e) = run() {
        eprintln!("map_breakdown: {e}");
        std::process::exit(1);
    }
}
