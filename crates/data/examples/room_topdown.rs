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
        let mut canvas = image::RgbImage::new(PX * 2, PX * 2);
        for (i, (view, cull, by_class)) in
            [(top, false, true), (top, false, false), (oblique, true, true), (oblique, true, false)]
                .into_iter()
                .enumerate()
        {
            let panel = render(&room.mesh, view, cull, by_class, &|_| true);
            image::imageops::overlay(&mut canvas, &panel, (i as u32 % 2 * PX) as i64, (i as u32 / 2 * PX) as i64);
        }
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
        let mut detail = image::RgbImage::new(PX * 2, PX);
        for (i, by_class) in [true, false].into_iter().enumerate() {
            let panel = render(&room.mesh, oblique, true, by_class, &near);
            image::imageops::overlay(&mut detail, &panel, (i as u32 * PX) as i64, 0);
        }
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
    let pts: Vec<Vec3> = mesh.positions.iter().map(|&p| view * p).collect();
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for (p, &q) in pts.iter().zip(&mesh.positions) {
        if keep(q) {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
    }
    let scale = (PX as f32 - 8.0) / (hi.x - lo.x).max(hi.y - lo.y);
    let to_px = |p: Vec3| Vec3::new((p.x - lo.x) * scale + 4.0, (hi.y - p.y) * scale + 4.0, p.z);
    let mut img = image::RgbImage::from_pixel(PX, PX, image::Rgb([255, 255, 255]));
    let mut depth = vec![f32::MIN; (PX * PX) as usize];
    let light = (view * Vec3::new(0.3, 0.5, 1.0)).normalize();
    for (t, &label) in mesh.triangles.iter().zip(&mesh.triangle_labels) {
        if skip(label) || !t.iter().all(|&i| keep(mesh.positions[i as usize])) {
            continue;
        }
        let [a, b, c] = t.map(|i| to_px(pts[i as usize]));
        let [wa, wb, wc] = t.map(|i| pts[i as usize]);
        let n = (wb - wa).cross(wc - wa).normalize_or_zero();
        if cull && n.z < 0.0 {
            continue;
        }
        let shade = 0.55 + 0.45 * n.dot(light).abs();
        let area = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
        if area.abs() < 1e-9 {
            continue;
        }
        let x0 = a.x.min(b.x).min(c.x).floor().max(0.0) as u32;
        let x1 = (a.x.max(b.x).max(c.x).ceil() as u32).min(PX - 1);
        let y0 = a.y.min(b.y).min(c.y).floor().max(0.0) as u32;
        let y1 = (a.y.max(b.y).max(c.y).ceil() as u32).min(PX - 1);
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
                let w0 = ((b.x - px) * (c.y - py) - (b.y - py) * (c.x - px)) / area;
                let w1 = ((c.x - px) * (a.y - py) - (c.y - py) * (a.x - px)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                let z = w0 * a.z + w1 * b.z + w2 * c.z;
                let slot = (y * PX + x) as usize;
                if z <= depth[slot] {
                    continue;
                }
                depth[slot] = z;
                let base = if by_class {
                    SemanticClass::from_id(label).map(|c| c.color()).unwrap_or([0, 0, 0])
                } else {
                    let cs = t.map(|i| mesh.colors[i as usize]);
                    let mut out = [0u8; 3];
                    for (k, o) in out.iter_mut().enumerate() {
                        *o = (w0 * cs[0][k] as f32 + w1 * cs[1][k] as f32 + w2 * cs[2][k] as f32) as u8;
                    }
                    out
                };
                img.put_pixel(x, y, image::Rgb(base.map(|v| (v as f32 * shade) as u8)));
            }
        }
    }
    img
}
