//! Rendering throughput: renders frames at 640x480 along a generated handheld scan of a
//! room and prints frames per second, then the cost of the Kinect sensor model.
//!
//! `cargo run --release -p semrecon-data --example render_bench -- [FRAMES] [MESH.ply]`
//! renders a synthetic 50k-triangle room, or the given PLY mesh (z up, e.g.
//! Replica office0), `FRAMES` times (default 300).

use std::path::Path;
use std::time::Instant;

use glam::{Vec2, Vec3};
use semrecon_data::{read_ply, Intrinsics, LabeledMesh, PreparedMesh, Renderer, RoomLayout, ScanPlan, SensorModel};

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
/// about 50k triangles, and its layout for the scan planner.
fn synthetic_room() -> (LabeledMesh, RoomLayout) {
    let mut mesh = LabeledMesh::default();
    let mut room = RoomLayout {
        floor_min: Vec2::ZERO,
        floor_max: Vec2::new(7.0, 5.0),
        floor_z: 0.0,
        ceiling_height: 2.8,
        obstacles: Vec::new(),
        interest_points: Vec::new(),
        tall_obstacles: Vec::new(),
    };
    add_box(&mut mesh, Vec3::ZERO, Vec3::new(7.0, 5.0, 2.8), 50, [180, 170, 160], 2);
    for i in 0..24 {
        let x = 0.4 + (i % 6) as f32 * 1.1;
        let y = if i < 12 { 0.3 } else { 3.9 };
        let h = 0.4 + 0.1 * (i % 7) as f32;
        let (lo, hi) = (Vec3::new(x, y + 0.1 * (i / 6 % 2) as f32, 0.0), Vec3::new(x + 0.7, y + 0.7, h));
        add_box(&mut mesh, lo, hi, 9, [90, 60 + 5 * i as u8, 40], 7 + (i % 5) as u8);
        room.obstacles.push((lo.truncate(), hi.truncate()));
        room.interest_points.push((lo + hi) * 0.5);
    }
    (mesh, room)
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
    let frames: usize =
        args.get(1).map(|s| s.parse().map_err(|_| format!("bad frame count {s}"))).transpose()?.unwrap_or(300);
    let (mesh, room, name) = match args.get(2) {
        Some(path) => (read_ply(Path::new(path)).map_err(|e| e.to_string())?, None, path.clone()),
        None => {
            let (mesh, room) = synthetic_room();
            (mesh, Some(room), "synthetic room".to_string())
        }
    };
    let prepared = PreparedMesh::new(&mesh).map_err(|e| e.to_string())?;
    let k = Intrinsics::new(640, 480, 525.0, 525.0, 319.5, 239.5).map_err(|e| e.to_string())?;
    let mut renderer = Renderer::new(k).map_err(|e| e.to_string())?;
    let plan = match &room {
        Some(room) => ScanPlan::new(room.clone(), 1),
        None => ScanPlan::from_mesh_bounds(&mesh, 1).map_err(|e| e.to_string())?,
    };
    let poses = plan.poses(frames).map_err(|e| e.to_string())?;
    let pose = |i: usize| poses[i];
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
    let sensor = SensorModel::kinect();
    let mut out = renderer.render(&prepared, pose(0)).clone();
    let clean = out.clone();
    let cpu_start = process_cpu_seconds();
    let start = Instant::now();
    let noisy_frames = frames.min(100);
    for i in 0..noisy_frames {
        out.clone_from(&clean);
        sensor.apply(&mut out, i);
    }
    let secs = start.elapsed().as_secs_f64();
    let cpu = match (cpu_start, process_cpu_seconds()) {
        (Some(a), Some(b)) => format!(", cpu time {:.2} ms/frame", 1000.0 * (b - a) / noisy_frames as f64),
        _ => String::new(),
    };
    println!("kinect sensor model: {:.2} ms/frame{cpu}", 1000.0 * secs / noisy_frames as f64);
    Ok(())
}
