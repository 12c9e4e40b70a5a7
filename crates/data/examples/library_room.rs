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
        let mut canvas = image::RgbImage::new(PX * 2, PX * 2);
        for (i, (view, cut, by_class)) in
            [(top, false, true), (top, false, false), (oblique, true, true), (oblique, true, false)]
                .into_iter()
                .enumerate()
        {
            let panel = render(&room.mesh, view, cut.then_some((w, d)), by_class);
            image::imageops::overlay(&mut canvas, &panel, (i as u32 % 2 * PX) as i64, (i as u32 / 2 * PX) as i64);
        }
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
    let keep = |t: &[u32; 3], l: u8| {
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
    let pts: Vec<Vec3> = mesh.positions.iter().map(|&p| view * p).collect();
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for p in &pts {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    let scale = (PX as f32 - 8.0) / (hi.x - lo.x).max(hi.y - lo.y);
    let to_px = |p: Vec3| Vec3::new((p.x - lo.x) * scale + 4.0, (hi.y - p.y) * scale + 4.0, p.z);
    let mut img = image::RgbImage::from_pixel(PX, PX, image::Rgb([255, 255, 255]));
    let mut depth = vec![f32::MIN; (PX * PX) as usize];
    let light = (view * Vec3::new(0.3, 0.5, 1.0)).normalize();
    for (t, &label) in mesh.triangles.iter().zip(&mesh.triangle_labels) {
        if !keep(t, label) {
            continue;
        }
        let [a, b, c] = t.map(|i| to_px(pts[i as usize]));
        let [wa, wb, wc] = t.map(|i| pts[i as usize]);
        let n = (wb - wa).cross(wc - wa).normalize_or_zero();
        let shade = if by_class { 0.55 + 0.45 * n.dot(light).abs() } else { 1.0 };
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
