//! Looks at generated rooms: for each style, rasterises one room into a PNG with four
//! panels — top view in class colours, top view in vertex colours (ceiling and beams left
//! out, highest surface wins), and an oblique cut-away view (back faces culled, so the near
//! walls vanish) in class colours and in vertex colours; and a second PNG with the same
//! oblique views, closer, of a 3.5 m square around the furniture nearest the room centre.
//!
//! Usage: `cargo run --release -p semrecon-data --example room_topdown -- [SEED] [OUT_DIR]`

use std::path::PathBuf;

use glam::{Mat3, Vec3};
use semrecon_data::synth::{generate_room, RoomConfig, RoomStyle};
use semrecon_data::{LabeledMesh, SemanticClass};

#[path = "common/raster.rs"]
mod raster;

const PX: u32 = 420;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let seed: u64 = args.next().map(|s| s.parse()).transpose()?.unwrap_or(1);
    let out = PathBuf::from(args.next().unwrap_or_else(|| "target/rooms".into()));
    std::fs::create_dir_all(&out)?;
    for style in RoomStyle::ALL.into_iter().chain(RoomStyle::HELD_OUT) {
        let t = std::time::Instant::now();
        let room = generate_room(&RoomConfig { seed, style: Some(style) });
        let ms = t.elapsed().as_secs_f64() * 1e3;
        println!(
            "{style}: {:.1} x {:.1} x {:.2} m, {} triangles, {} vertices, {} obstacles, {:.1} ms",
            room.floor_max.x,
            room.floor_max.y,
            room.ceiling_height,
            room.mesh.triangle_count(),
            room.mesh.vertex_count(),
            room.obstacles.len(),
            ms
        );
        let top = Mat3::IDENTITY;
        // Oblique: look down at 50 degrees from the (-x, -y) corner.
        let yaw = Mat3::from_rotation_z(-std::f32::consts::FRAC_PI_4);
        let tilt = Mat3::from_rotation_x(-0.9);
        let oblique = tilt * yaw;
        let panels: Vec<_> = [(top, false, true), (top, false, false), (oblique, true, true), (oblique, true, false)]
            .into_iter()
            .map(|(view, cull, by_class)| render(&room.mesh, view, cull, by_class, &|_| true))
            .collect();
        let canvas = raster::tile(&panels, 2);
        save(&canvas, &out.join(format!("room_{}_{seed}.png", style.name())))?;
        let mid = room.floor_max * 0.5;
        let focus = room
            .interest_points
            .iter()
            .filter(|p| p.z < 1.0)
            .map(|p| p.truncate())
            .min_by(|a, b| a.distance(mid).total_cmp(&b.distance(mid)))
            .unwrap_or(mid);
        let near = |p: Vec3| (p.truncate() - focus).abs().max_element() < 1.75;
        let panels = [true, false].map(|by_class| render(&room.mesh, oblique, true, by_class, &near));
        let detail = raster::tile(&panels, 2);
        save(&detail, &out.join(format!("room_{}_{seed}_detail.png", style.name())))?;
    }
    Ok(())
}

/// Writes `img` as PNG through a temporary file.
fn save(img: &image::RgbImage, path: &std::path::Path) -> Result<(), Box<dyn std::error::Error>> {
    let tmp = path.with_extension("png.tmp");
    img.save_with_format(&tmp, image::ImageFormat::Png)?;
    std::fs::rename(&tmp, path)?;
    println!("  wrote {}", path.display());
    Ok(())
}

/// Orthographic render looking down the view's -z (after `view * p`): largest view z wins.
/// Only triangles whose vertices all pass `keep` (world positions) are drawn.
fn render(mesh: &LabeledMesh, view: Mat3, cull: bool, by_class: bool, keep: &dyn Fn(Vec3) -> bool) -> image::RgbImage {
    // A close-up (a `keep` that drops far points) leaves beams out: they hide the furniture.
    let partial = !keep(Vec3::splat(-1e3));
    let skip = |l: u8| l == SemanticClass::Ceiling.id() || ((!cull || partial) && l == SemanticClass::Beam.id());
    let bounds = raster::view_bounds(mesh, view, keep);
    raster::render(mesh, view, PX, bounds, by_class, true, |t, label, n| {
        !skip(label) && t.iter().all(|&i| keep(mesh.positions[i as usize])) && !(cull && n.z < 0.0)
    })
}
