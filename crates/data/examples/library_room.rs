//! Generates rooms furnished from the installed furniture catalogues
//! (`semrecon_data::library::rooms`), writes each as a PLY file and as a PNG with four
//! panels (top view in class colours and in vertex colours, ceiling left out; an oblique
//! view from the (-x, -y) corner with the two near walls cut away, in class colours and in
//! vertex colours), and prints its size, triangle count and generation time (the second
//! generation of the same room, with the meshes cached).
//!
//! Usage: `cargo run --release -p semrecon-data --example library_room -- [SEED] [KIND|all]
//! [train|held_out] [OUT_DIR]`

use std::path::PathBuf;

use glam::{Mat3, Vec3};
use semrecon_data::library::rooms::{generate_library_room_detailed, HomeRoomKind, LibraryRoomConfig};
use semrecon_data::library::{FurnitureLibrary, Split};
use semrecon_data::{write_ply, LabeledMesh, PlyEncoding, SemanticClass};

#[path = "common/raster.rs"]
mod raster;

const PX: u32 = 480;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let seed: u64 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(1);
    let kinds: Vec<HomeRoomKind> = match args.next().as_deref() {
        None | Some("all") => HomeRoomKind::ALL.to_vec(),
        Some(k) => vec![k.parse()?],
    };
    let split = match args.next().as_deref() {
        None | Some("train") => Split::Train,
        Some("held_out") => Split::HeldOut,
        Some(o) => return Err(format!("split must be train or held_out, not {o:?}").into()),
    };
    let out = PathBuf::from(args.next().unwrap_or_else(|| "target/library_rooms".into()));
    std::fs::create_dir_all(&out)?;
    let t = std::time::Instant::now();
    let lib = FurnitureLibrary::open_default()?;
    println!("opened {} models in {:.2} s", lib.models.len(), t.elapsed().as_secs_f64());
    for kind in kinds {
        let config = LibraryRoomConfig { seed, kind: Some(kind), split };
        let t = std::time::Instant::now();
        let first = generate_library_room_detailed(&config, &lib)?;
        let cold = t.elapsed().as_secs_f64() * 1e3;
        let t = std::time::Instant::now();
        let r = generate_library_room_detailed(&config, &lib)?;
        let warm = t.elapsed().as_secs_f64() * 1e3;
        assert_eq!(first, r, "generation is not deterministic");
        let room = &r.room;
        println!(
            "{kind} seed {seed}: {:.1} x {:.1} x {:.2} m, {} triangles, {} models, {} obstacles, {:.0} ms (first, \
             loading meshes) / {:.0} ms (cached)",
            room.floor_max.x,
            room.floor_max.y,
            room.ceiling_height,
            room.mesh.triangle_count(),
            r.model_ids.len(),
            room.obstacles.len(),
            cold,
            warm
        );
        let stem = format!("{}_{seed}", kind.name());
        write_ply(out.join(format!("{stem}.ply")), &room.mesh, PlyEncoding::BinaryLittleEndian)?;
        let (w, d) = (room.floor_max.x, room.floor_max.y);
        let top = Mat3::IDENTITY;
        let yaw = Mat3::from_rotation_z(std::f32::consts::FRAC_PI_4);
        let tilt = Mat3::from_rotation_x(-0.95);
        let oblique = tilt * yaw;
        let panels: Vec<_> = [(top, false, true), (top, false, false), (oblique, true, true), (oblique, true, false)]
            .into_iter()
            .map(|(view, cut, by_class)| render(&room.mesh, view, cut.then_some((w, d)), by_class))
            .collect();
        let canvas = raster::tile(&panels, 2);
        let png = out.join(format!("{stem}.png"));
        canvas.save_with_format(&png, image::ImageFormat::Png)?;
        println!("  wrote {} and {stem}.ply", png.display());
    }
    Ok(())
}

/// Orthographic render looking down the view's -z: largest view z wins. The ceiling is
/// left out; with `cut`, so are the walls (and what sits in them) at x = 0 and y = 0.
fn render(mesh: &LabeledMesh, view: Mat3, cut: Option<(f32, f32)>, by_class: bool) -> image::RgbImage {
    let shell = |l: u8| {
        [SemanticClass::Wall, SemanticClass::Door, SemanticClass::Window, SemanticClass::Column, SemanticClass::Beam]
            .iter()
            .any(|c| c.id() == l)
    };
    let keep = |t: &[u32; 3], l: u8, _: Vec3| {
        if l == SemanticClass::Ceiling.id() {
            return false;
        }
        match cut {
            Some(_) if shell(l) => {
                t.iter().all(|&i| mesh.positions[i as usize].x > 0.06 && mesh.positions[i as usize].y > 0.06)
            }
            _ => true,
        }
    };
    let bounds = raster::view_bounds(mesh, view, |_| true);
    raster::render(mesh, view, PX, bounds, by_class, by_class, keep)
}
