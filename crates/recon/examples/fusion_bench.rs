//! Fusion and meshing benchmark: per-stage milliseconds per frame at 640x480.
//!
//! ```text
//! cargo run --release -p semrecon-recon --example fusion_bench -- [--frames N] [--voxel M]
//!     [--7scenes DIR] [--out mesh.ply] [--keyframe K] [--trunc VOXELS]
//!     [--band-factor K] [--min-band VOXELS] [--remesh-tol VOXELS] [--mesh-repeat N]
//!     [--mesh-budget CHUNKS] [--color-every N] [--behind-band K]
//!     [--far-group-beyond M] [--far-group-frames N]
//! ```
//!
//! `--far-group-beyond`/`--far-group-frames` fuse far chunks from groups of frames as the
//! pipeline does ([`semrecon_recon::GroupedFusion`]; selection is then timed with integration).
//! Without `--7scenes` the frames are ray-cast from an analytic scene (floor, wall, sphere).
//! With it, `DIR` is a 7-Scenes sequence folder (`frame-NNNNNN.depth.png` in millimetres with
//! 0 and 65535 invalid, `.color.png`/`.color.jpg`, `.pose.txt` 4x4 camera-to-world) read with
//! the reference poses. Thread count: `RAYON_NUM_THREADS`. `--out` writes the final mesh as
//! binary PLY (a minimal writer local to this example). `--band-factor` is
//! `TsdfConfig::truncation_noise_factor` (0: the fixed band of `--trunc` voxels), `--min-band`
//! its `min_truncation_voxels`. `--remesh-tol` is the incremental mesher's
//! `RemeshTolerance::distance_voxels` (default 0: exact). `--mesh-budget` caps the chunks
//! one keyframe re-meshes (`IncrementalMesher::with_budget`; 0, the default: no cap); the
//! final mesh is then brought up to date without it. `--color-every` is
//! `TsdfConfig::color_every` (1: colour from every frame, as before issue 20). `--behind-band`
//! is `TsdfConfig::behind_band` (1: the one-sided clamp before session 26).
//! `--mesh-repeat N` re-meshes the final map N more times, alternately from an empty cache
//! (the incremental path over every chunk) and with `extract_mesh`, and prints the best and
//! median CPU and wall time of each: a meshing-only load for profilers. The fusion kernel is
//! the widest the CPU has; `SEMRECON_FUSION_SIMD=avx2|portable` forces a lower one. The
//! printed map fingerprint (every voxel and frame run) must not depend on the kernel or the thread count.
//! Meshing's vertex kernel is chosen the same way (`SEMRECON_MESH_SIMD=avx2|scalar`); the
//! mesh written by `--out` is the same file with any of them.

#[path = "common/cpu_time.rs"]
mod cpu_time;
#[path = "common/flags.rs"]
mod flags;
#[path = "../tests/common/scene.rs"]
mod scene;
#[path = "../tests/common/seven_scenes.rs"]
mod seven_scenes;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Affine3A;
use semrecon_data::{Frame, Intrinsics, LabeledMesh};
use semrecon_recon::{GroupedFusion, IncrementalMesher, RemeshTolerance, TsdfConfig, TsdfMap};

use cpu_time::cpu_ns;
use flags::Flags;

struct Args {
    frames: usize,
    voxel: f32,
    seven_scenes: Option<PathBuf>,
    out: Option<PathBuf>,
    keyframe: usize,
    truncation: f32,
    band_factor: f32,
    min_band: f32,
    remesh_tol: f32,
    mesh_repeat: usize,
    mesh_budget: usize,
    color_every: usize,
    behind_band: f32,
    pair_far: f32,
    group_frames: usize,
}

fn parse_args() -> Result<Args, String> {
    let mut a = Args {
        frames: 100,
        voxel: 0.005,
        seven_scenes: None,
        out: None,
        keyframe: 10,
        truncation: 10.0,
        band_factor: TsdfConfig::default().truncation_noise_factor,
        min_band: TsdfConfig::default().min_truncation_voxels,
        remesh_tol: 0.0,
        mesh_repeat: 0,
        mesh_budget: 0,
        color_every: TsdfConfig::default().color_every,
        behind_band: TsdfConfig::default().behind_band,
        pair_far: 0.0,
        group_frames: 2,
    };
    let mut flags = Flags::from_env();
    while let Some(flag) = flags.next_flag() {
        match flag.as_str() {
            "--frames" => a.frames = flags.value(&flag)?,
            "--voxel" => a.voxel = flags.value(&flag)?,
            "--trunc" => a.truncation = flags.value(&flag)?,
            "--band-factor" => a.band_factor = flags.value(&flag)?,
            "--min-band" => a.min_band = flags.value(&flag)?,
            "--remesh-tol" => a.remesh_tol = flags.value(&flag)?,
            "--mesh-repeat" => a.mesh_repeat = flags.value(&flag)?,
            "--mesh-budget" => a.mesh_budget = flags.value(&flag)?,
            "--color-every" => a.color_every = flags.value(&flag)?,
            "--behind-band" => a.behind_band = flags.value(&flag)?,
            "--far-group-beyond" => a.pair_far = flags.value(&flag)?,
            "--far-group-frames" => a.group_frames = flags.value(&flag)?,
            "--keyframe" => a.keyframe = flags.value(&flag)?,
            "--7scenes" => a.seven_scenes = Some(flags.value(&flag)?),
            "--out" => a.out = Some(flags.value(&flag)?),
            other => return Err(format!("unknown argument {other}")),
        }
    }
    if a.keyframe == 0 {
        return Err("--keyframe must be at least 1".into());
    }
    Ok(a)
}

/// Binary little-endian PLY with positions, normals, colours and triangles, written to a
/// temporary file and renamed.
fn write_ply(path: &Path, mesh: &LabeledMesh) -> std::io::Result<()> {
    let tmp = path.with_extension("ply.tmp");
    {
        let mut w = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        write!(
            w,
            "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\n\
             property float z\nproperty float nx\nproperty float ny\nproperty float nz\n\
             property uchar red\nproperty uchar green\nproperty uchar blue\nelement face {}\n\
             property list uchar int vertex_indices\nend_header\n",
            mesh.vertex_count(),
            mesh.triangle_count()
        )?;
        for i in 0..mesh.vertex_count() {
            for v in mesh.positions[i].to_array().into_iter().chain(mesh.normals[i].to_array()) {
                w.write_all(&v.to_le_bytes())?;
            }
            w.write_all(&mesh.colors[i])?;
        }
        for t in &mesh.triangles {
            w.write_all(&[3])?;
            for i in t {
                w.write_all(&(*i as i32).to_le_bytes())?;
            }
        }
        w.flush()?;
    }
    std::fs::rename(&tmp, path)
}

/// FNV-1a over the sorted chunk keys and every voxel (distance, weight, colour, count) and
/// the chunks' frame runs: equal fingerprints mean bit-identical maps, so kernels and thread
/// counts can be compared run against run.
fn fingerprint(map: &TsdfMap) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
        }
    };
    for key in map.sorted_keys() {
        let Some(chunk) = map.chunk(key) else { continue };
        for c in key.to_array() {
            eat(&c.to_le_bytes());
        }
        for v in chunk.voxels() {
            eat(&v.tsdf().to_le_bytes());
            eat(&v.weight().to_le_bytes());
            eat(&v.color());
        }
        for &(a, b) in chunk.frames().runs() {
            eat(&a.to_le_bytes());
            eat(&b.to_le_bytes());
        }
    }
    h
}

fn stats(label: &str, ms: &mut [f64]) {
    if ms.is_empty() {
        return;
    }
    ms.sort_by(f64::total_cmp);
    let mean = ms.iter().sum::<f64>() / ms.len() as f64;
    let median = ms[ms.len() / 2];
    let p95 = ms[(ms.len() * 95 / 100).min(ms.len() - 1)];
    println!("{label:<28} mean {mean:7.2}  median {median:7.2}  p95 {p95:7.2}  max {:7.2} ms", ms[ms.len() - 1]);
}

fn main() {
    let args = match parse_args() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("fusion_bench: {e}");
            std::process::exit(2);
        }
    };
    let config = match TsdfConfig::with_voxel_size(args.voxel)
        .map(|c| TsdfConfig {
            truncation_voxels: args.truncation,
            truncation_noise_factor: args.band_factor,
            min_truncation_voxels: args.min_band,
            color_every: args.color_every,
            behind_band: args.behind_band,
            far_group_beyond_m: args.pair_far,
            far_group_frames: args.group_frames,
            ..c
        })
        .and_then(|c| c.validate().map(|()| c))
    {
        Ok(c) => c,
        Err(e) => {
            eprintln!("fusion_bench: {e}");
            std::process::exit(2);
        }
    };
    let t_load = Instant::now();
    let frames: Vec<(Frame, Affine3A)> = match &args.seven_scenes {
        Some(dir) => {
            let mut v = Vec::new();
            for i in 0..args.frames {
                match seven_scenes::read_frame(dir, i) {
                    Ok(f) => v.push(f),
                    Err(e) => {
                        eprintln!("fusion_bench: {e}");
                        std::process::exit(1);
                    }
                }
            }
            v
        }
        None => {
            let k = Intrinsics::new(640, 480, 525.0, 525.0, 319.5, 239.5).expect("constant camera");
            scene::trajectory(args.frames).into_iter().enumerate().map(|(i, p)| (scene::render(k, p, i), p)).collect()
        }
    };
    println!(
        "{} frames ({}) loaded in {:.1} s; voxel {} mm, {} threads",
        frames.len(),
        args.seven_scenes.as_ref().map_or("analytic scene".to_string(), |d| d.display().to_string()),
        t_load.elapsed().as_secs_f64(),
        config.voxel_size * 1000.0,
        rayon::current_num_threads()
    );
    let mut map = match TsdfMap::new(config) {
        Ok(m) => m,
        Err(e) => {
            eprintln!("fusion_bench: {e}");
            std::process::exit(2);
        }
    };
    let mut mesher = match IncrementalMesher::with_tolerance(RemeshTolerance { distance_voxels: args.remesh_tol }) {
        Ok(m) => m.with_budget(std::num::NonZeroUsize::new(args.mesh_budget)),
        Err(e) => {
            eprintln!("fusion_bench: {e}");
            std::process::exit(2);
        }
    };
    let (mut sel_ms, mut int_ms, mut tot_ms, mut mesh_ms) = (vec![], vec![], vec![], vec![]);
    let (mut sel_cpu, mut int_cpu, mut mesh_cpu) = (vec![], vec![], vec![]);
    let (mut visited, mut updated, mut remeshed, mut changed) = (0usize, 0usize, 0usize, 0usize);
    let (mut pending, mut max_pending) = (0usize, 0usize);
    let (mut upd_chunks, mut band_chunks, mut new_chunks, mut freed_chunks) = (0usize, 0usize, 0usize, 0usize);
    // `FUSION_BENCH_FLUSH_MB=N`: N MB of other memory written between frames (untimed), as a
    // whole run's tracking, rendering or decoding does, so that fusion starts with cold caches.
    let flush_mb: usize = std::env::var("FUSION_BENCH_FLUSH_MB").ok().and_then(|v| v.parse().ok()).unwrap_or(0);
    let mut flush = vec![0u8; flush_mb << 20];
    let mut pairing = GroupedFusion::new(args.pair_far, args.group_frames);
    let t_all = Instant::now();
    for (i, (frame, pose)) in frames.iter().enumerate() {
        if !flush.is_empty() {
            flush.iter_mut().for_each(|b| *b = b.wrapping_add(i as u8));
            std::hint::black_box(&flush);
        }
        let c0 = cpu_ns();
        let t0 = Instant::now();
        // With `--far-group-beyond`, selection and integration both happen in the pairing (timed as
        // integration).
        let keys = if pairing.is_on() {
            Vec::new()
        } else {
            match map.select_chunks(frame, *pose) {
                Ok(k) => k,
                Err(e) => {
                    eprintln!("fusion_bench: {e}");
                    continue;
                }
            }
        };
        let t1 = Instant::now();
        let c1 = cpu_ns();
        let fused = if pairing.is_on() {
            pairing.integrate(&mut map, frame, *pose)
        } else {
            map.integrate_chunks(frame, *pose, &keys)
        };
        match fused {
            Ok(s) => {
                visited += s.visited_chunks;
                updated += s.updated_voxels;
                upd_chunks += s.updated_chunks;
                band_chunks += s.band_chunks;
                new_chunks += s.new_chunks;
                freed_chunks += s.freed_chunks;
            }
            Err(e) => eprintln!("fusion_bench: {e}"),
        }
        let t2 = Instant::now();
        let c2 = cpu_ns();
        sel_cpu.push((c1 - c0) as f64 * 1e-6);
        int_cpu.push((c2 - c1) as f64 * 1e-6);
        sel_ms.push((t1 - t0).as_secs_f64() * 1e3);
        int_ms.push((t2 - t1).as_secs_f64() * 1e3);
        tot_ms.push((t2 - t0).as_secs_f64() * 1e3);
        if (i + 1) % args.keyframe == 0 {
            let c = cpu_ns();
            let t = Instant::now();
            let st = mesher.update(&map);
            remeshed += st.remeshed_chunks;
            changed += st.changed_chunks;
            pending += st.pending_chunks;
            max_pending = max_pending.max(st.pending_chunks);
            mesh_ms.push(t.elapsed().as_secs_f64() * 1e3);
            mesh_cpu.push((cpu_ns() - c) as f64 * 1e-6);
        }
    }
    if let Err(e) = pairing.flush(&mut map) {
        eprintln!("fusion_bench: {e}");
    }
    if pairing.is_on() {
        let p = pairing.stats();
        println!(
            "grouped {} far passes, {:.1} % of candidate pixels averaged, {} frames fused alone",
            p.groups,
            100.0 * p.paired_pixels as f64 / p.candidate_pixels.max(1) as f64,
            p.flushed_frames
        );
    }
    let wall = t_all.elapsed().as_secs_f64();
    println!("map fingerprint {:016x}", fingerprint(&map));
    let n = frames.len().max(1);
    println!(
        "chunks {} ({:.1} MB, {} bytes/chunk), visited {:.0} chunks/frame, {:.2} M voxel updates/frame",
        map.chunk_count(),
        map.memory_bytes() as f64 / 1e6,
        TsdfMap::bytes_per_chunk(),
        visited as f64 / n as f64,
        updated as f64 / n as f64 / 1e6
    );
    println!(
        "per frame: {:.0} chunks updated, {:.0} with a voxel in the band, {:.0} new, {:.0} freed",
        upd_chunks as f64 / n as f64,
        band_chunks as f64 / n as f64,
        new_chunks as f64 / n as f64,
        freed_chunks as f64 / n as f64
    );
    stats("chunk selection", &mut sel_ms);
    stats("integration", &mut int_ms);
    stats("fusion (selection+integr.)", &mut tot_ms);
    stats(&format!("incremental mesh / {} fr", args.keyframe), &mut mesh_ms);
    let keyframes = mesh_ms.len().max(1) as f64;
    println!(
        "per keyframe: {:.0} chunks changed, {:.0} re-meshed (with neighbours); remesh tolerance {} voxels, snapshots {:.1} MB",
        changed as f64 / keyframes,
        remeshed as f64 / keyframes,
        args.remesh_tol,
        mesher.snapshot_bytes() as f64 / 1e6
    );
    if args.mesh_budget > 0 {
        println!(
            "budget {} chunks per keyframe: {:.0} left pending per keyframe on average, at most {}",
            args.mesh_budget,
            pending as f64 / keyframes,
            max_pending
        );
    }
    println!("CPU time (all threads):");
    stats("chunk selection", &mut sel_cpu);
    stats("integration", &mut int_cpu);
    stats(&format!("incremental mesh / {} fr", args.keyframe), &mut mesh_cpu);
    let c = cpu_ns();
    let t = Instant::now();
    let full = semrecon_recon::extract_mesh(&map);
    let full_ms = t.elapsed().as_secs_f64() * 1e3;
    let full_cpu = (cpu_ns() - c) as f64 * 1e-6;
    if args.mesh_budget > 0 {
        let t = Instant::now();
        let st = mesher.update_all(&map);
        println!(
            "final update without the budget: {} chunks re-meshed in {:.1} ms",
            st.remeshed_chunks,
            t.elapsed().as_secs_f64() * 1e3
        );
    }
    let t = Instant::now();
    let assembled = mesher.mesh();
    let assemble_ms = t.elapsed().as_secs_f64() * 1e3;
    println!(
        "full-map marching cubes {full_ms:.1} ms, CPU {full_cpu:.1} ms ({} triangles, {} vertices); assembling cached meshes {assemble_ms:.1} ms",
        full.triangle_count(),
        full.vertex_count()
    );
    if args.mesh_repeat > 0 {
        // Alternately: a fresh incremental mesher over every chunk, and `extract_mesh`.
        let mut times = [(vec![], vec![]), (vec![], vec![])];
        for _ in 0..args.mesh_repeat {
            for (k, (wall_ms, cpu_ms)) in times.iter_mut().enumerate() {
                let c = cpu_ns();
                let t = Instant::now();
                if k == 0 {
                    IncrementalMesher::new().update(&map);
                } else {
                    semrecon_recon::extract_mesh(&map);
                }
                wall_ms.push(t.elapsed().as_secs_f64() * 1e3);
                cpu_ms.push((cpu_ns() - c) as f64 * 1e-6);
            }
        }
        for (label, (wall_ms, cpu_ms)) in ["whole-map re-mesh", "extract_mesh"].iter().zip(&mut times) {
            wall_ms.sort_by(f64::total_cmp);
            cpu_ms.sort_by(f64::total_cmp);
            println!(
                "{label} x{}: CPU best {:.1} median {:.1} ms, wall best {:.1} median {:.1} ms",
                args.mesh_repeat,
                cpu_ms[0],
                cpu_ms[cpu_ms.len() / 2],
                wall_ms[0],
                wall_ms[wall_ms.len() / 2]
            );
        }
    }
    println!("whole run {:.2} s ({:.1} ms/frame with meshing)", wall, wall * 1e3 / n as f64);
    if let Some(out) = &args.out {
        match write_ply(out, &assembled) {
            Ok(()) => println!("mesh written to {}", out.display()),
            Err(e) => {
                eprintln!("fusion_bench: {}: {e}", out.display());
                std::process::exit(1);
            }
        }
    }
}
