//! Writes a generated flat (`semrecon_data::synth::flat`) as a labelled PLY, and its walk
//! through the rooms as a TUM trajectory, for looking at them (`semrecon snapshot`) and for
//! the docs' top view; prints the rooms, doorways and sizes.
//!
//! Usage: `cargo run --release -p semrecon-data --example flat_mesh -- [SEED] [home|two-rooms] [OUT_DIR]`

use std::path::PathBuf;

use semrecon_data::datasets::flat_scan_plan;
use semrecon_data::synth::{generate_flat, FlatConfig, FlatKind};
use semrecon_data::{write_ply, PlyEncoding, Trajectory};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let seed: u64 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(1);
    let kind = match args.next().as_deref() {
        None | Some("home") => FlatKind::Home,
        Some("two-rooms") => FlatKind::TwoRooms,
        Some(other) => return Err(format!("unknown flat `{other}` (home or two-rooms)").into()),
    };
    let out = PathBuf::from(args.next().unwrap_or_else(|| "target/flat".into()));
    std::fs::create_dir_all(&out)?;
    let t = std::time::Instant::now();
    let flat = generate_flat(&FlatConfig { seed, kind })?;
    println!(
        "{kind:?} {seed}: {:.1} m^2 of floor in {:.1} x {:.1} m, {} triangles, {} vertices, {:.0} ms",
        flat.floor_area(),
        flat.floor_max.x,
        flat.floor_max.y,
        flat.mesh.triangle_count(),
        flat.mesh.vertex_count(),
        t.elapsed().as_secs_f64() * 1e3
    );
    for r in &flat.rooms {
        println!("  {:<12} {:<10} {:.1} m^2 at {}..{}", r.name, r.style.name(), r.area(), r.floor_min, r.floor_max);
    }
    for d in &flat.doorways {
        println!("  doorway {}-{} {:.2} m wide at {}", d.rooms[0], d.rooms[1], d.width, d.centre());
    }
    write_ply(out.join("flat.ply"), &flat.mesh, PlyEncoding::BinaryLittleEndian)?;
    let poses = flat_scan_plan(&flat, seed, 30.0).poses(9000)?;
    let timestamps = (0..poses.len()).map(|i| i as f64 / 30.0).collect();
    Trajectory { timestamps, poses }.write_tum(out.join("walk.txt"))?;
    println!("wrote {}/flat.ply and walk.txt", out.display());
    Ok(())
}
