//! Rendering throughput: renders frames at 640x480 along a loop through a room and prints
//! frames per second.
//!
//! `cargo run --release -p semrecon-data --example render_bench -- [FRAMES] [MESH.ply]`
//! renders a synthetic 50k-triangle room, or the given binary PLY mesh (z up, e.g.
//! Replica office0), `FRAMES` times (default 300).

use std::path::Path;
use std::time::Instant;

use glam::{Affine3A, Mat3, Vec3};
use semrecon_data::{Intrinsics, LabeledMesh, PreparedMesh, Renderer};

/// Adds an axis-aligned box whose faces are split into `n x n` quads.
fn add_box(mesh: &mut LabeledMesh, lo: Vec3, hi: Vec3, n: u32, color: [u8; 3], label: u8) {
    let size = hi - lo;
    // Each face: origin corner and two spanning edges.
    let faces = [
        (lo, Vec3::new(size.x, 0.0, 0.0), Vec3::new(0.0, size.y, 0.0)),
        (Vec3::new(lo.x, lo.y, hi.z), Vec3::new(size.x, 0.0, 0.0), Vec3::new(0.0, size.y, 0.0)),
        (lo, Vec3::new(size.x, 0.0, 0.0), Vec3::new(0.0, 0.0, size.z)),
        (Vec3::new(lo.x, hi.y, lo.z), Vec3::new(size.x, 0.0, 0.0), Vec3::new(0.0, 0.0, size.z)),
        (lo, Vec3::new(0.0, size.y, 0.0), Vec3::new(0.0, 0.0, size.z)),
        (Vec3::new(hi.x, lo.y, lo.z), Vec3::new(0.0, size.y, 0.0), Vec3::new(0.0, 0.0, size.z)),
    ];
    for (f, (origin, u, v)) in faces.into_iter().enumerate() {
        let base = mesh.positions.len() as u32;
        for j in 0..=n {
            for i in 0..=n {
                mesh.positions.push(origin + u * (i as f32 / n as f32) + v * (j as f32 / n as f32));
                let shade = (((i + j + f as u32) % 4) * 20) as u8;
                mesh.colors.push(color.map(|c| c.saturating_add(shade)));
            }
        }
        for j in 0..n {
            for i in 0..n {
                let a = base + j * (n + 1) + i;
                let (b, c, d) = (a + 1, a + n + 1, a + n + 2);
                mesh.triangles.push([a, b, d]);
                mesh.triangles.push([a, d, c]);
                mesh.triangle_labels.extend([label, label]);
            }
        }
    }
}

/// A 7 x 5 x 2.8 m room (walls split into a 50x50 grid each) with 24 pieces of furniture:
/// about 50k triangles.
fn synthetic_room() -> LabeledMesh {
    let mut mesh = LabeledMesh::default();
    add_box(&mut mesh, Vec3::ZERO, Vec3::new(7.0, 5.0, 2.8), 50, [180, 170, 160], 2);
    for i in 0..24 {
        let x = 0.4 + (i % 6) as f32 * 1.1;
        let y = if i < 12 { 0.3 } else { 3.9 };
        let h = 0.4 + 0.1 * (i % 7) as f32;
        add_box(&mut mesh, Vec3::new(x, y + 0.1 * (i / 6 % 2) as f32, 0.0), Vec3::new(x + 0.7, y + 0.7, h), 9, [90, 60 + 5 * i as u8, 40], 7 + (i % 5) as u8);
    }
    mesh
}

// TODO: use semrecon_data::ply once merged
/// Minimal binary little-endian PLY reader (float x/y/z, uchar r/g/b, triangles as
/// `list uchar int`); enough for the Replica office0 mesh.
fn read_binary_ply(path: &Path) -> Result<LabeledMesh, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let end = b"end_header\n";
    let header_len = bytes.windows(end.len()).position(|w| w == end).ok_or("no PLY header")? + end.len();
    let header = String::from_utf8_lossy(&bytes[..header_len]);
    let (mut nv, mut nf, mut stride, mut in_vertex) = (0usize, 0usize, 0usize, false);
    let mut offsets = std::collections::HashMap::new();
    for line in header.lines() {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["element", "vertex", n] => (nv, in_vertex) = (n.parse().map_err(|_| "bad count")?, true),
            ["element", "face", n] => (nf, in_vertex) = (n.parse().map_err(|_| "bad count")?, false),
            ["property", t, name] if in_vertex => {
                offsets.insert(name.to_string(), stride);
                stride += if t.contains("char") { 1 } else { 4 };
            }
            _ => {}
        }
    }
    let get = |o: usize| -> Result<[u8; 4], String> { bytes.get(o..o + 4).and_then(|s| s.try_into().ok()).ok_or("truncated PLY".into()) };
    let off = |name: &str| offsets.get(name).copied().ok_or(format!("no vertex property {name}"));
    let (ox, oy, oz, or, og, ob) = (off("x")?, off("y")?, off("z")?, off("red")?, off("green")?, off("blue")?);
    let mut mesh = LabeledMesh::default();
    for v in 0..nv {
        let b = header_len + v * stride;
        let f = |o: usize| get(b + o).map(f32::from_le_bytes);
        mesh.positions.push(Vec3::new(f(ox)?, f(oy)?, f(oz)?));
        mesh.colors.push([bytes[b + or], bytes[b + og], bytes[b + ob]]);
    }
    let mut o = header_len + nv * stride;
    for _ in 0..nf {
        let idx = |j: usize| get(o + 1 + 4 * j).map(u32::from_le_bytes);
        mesh.triangles.push([idx(0)?, idx(1)?, idx(2)?]);
        o += 13;
    }
    Ok(mesh)
}

/// User + system CPU time of this process from `/proc/self/stat` (Linux), in seconds.
fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &stat[stat.rfind(')')? + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().collect();
    let frames: usize = args.get(1).map(|s| s.parse().map_err(|_| format!("bad frame count {s}"))).transpose()?.unwrap_or(300);
    let (mesh, name) = match args.get(2) {
        Some(path) => (read_binary_ply(Path::new(path))?, path.clone()),
        None => (synthetic_room(), "synthetic room".to_string()),
    };
    let (lo, hi) = mesh.bounds().ok_or("empty mesh")?;
    let prepared = PreparedMesh::new(&mesh).map_err(|e| e.to_string())?;
    let k = Intrinsics::new(640, 480, 525.0, 525.0, 319.5, 239.5).map_err(|e| e.to_string())?;
    let mut renderer = Renderer::new(k);
    // Walk an ellipse at 0.3 of the extent around the centre, eye at 1.5 m (or mid height),
    // looking outward and slightly down.
    let centre = (lo + hi) * 0.5;
    let radius = (hi - lo) * 0.3;
    let eye_z = (lo.z + 1.5).min(centre.z + 0.3 * (hi.z - lo.z));
    let pose = |i: usize| {
        let a = i as f32 / frames as f32 * std::f32::consts::TAU;
        let eye = Vec3::new(centre.x + radius.x * a.cos(), centre.y + radius.y * a.sin(), eye_z);
        let forward = Vec3::new(a.cos(), a.sin(), -0.3).normalize();
        let right = forward.cross(Vec3::Z).normalize();
        let down = forward.cross(right);
        Affine3A::from_mat3_translation(Mat3::from_cols(right, down, forward), eye)
    };
    // Warm up buffers and threads.
    renderer.render(&prepared, pose(0));
    let cpu_start = process_cpu_seconds();
    let start = Instant::now();
    let mut valid = 0usize;
    for i in 0..frames {
        let out = renderer.render(&prepared, pose(i));
        valid += out.depth.iter().filter(|&&d| d > 0.0).count();
    }
    let secs = start.elapsed().as_secs_f64();
    // CPU time tells the work per frame on a machine shared with other jobs, where wall
    // time depends on the load.
    if let (Some(a), Some(b)) = (cpu_start, process_cpu_seconds()) {
        println!("cpu time {:.2} ms/frame (all threads together)", 1000.0 * (b - a) / frames as f64);
    }
    println!(
        "{name}: {} triangles, {frames} frames at 640x480 on {} threads: {:.1} fps ({:.2} ms/frame), {:.1}% pixels valid",
        prepared.triangle_count(),
        rayon::current_num_threads(),
        frames as f64 / secs,
        1000.0 * secs / frames as f64,
        100.0 * valid as f64 / (frames * k.pixel_count()) as f64
    );
    Ok(())
}
