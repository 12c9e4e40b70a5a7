//! Orthographic rasteriser shared by the room-viewing examples (`room_topdown`,
//! `library_room`), included with `#[path]`.

use glam::{Mat3, Vec3};
use semrecon_data::{LabeledMesh, SemanticClass};

/// View-space box `(lo, hi)` of the vertices of `mesh` that pass `keep` (world positions),
/// after `view * p`.
pub fn view_bounds(mesh: &LabeledMesh, view: Mat3, keep: impl Fn(Vec3) -> bool) -> (Vec3, Vec3) {
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for &q in &mesh.positions {
        if keep(q) {
            let p = view * q;
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    (lo, hi)
}

/// Orthographic render, `px` pixels square, looking down the view's -z (after `view * p`):
/// largest view z wins. The view-space box `bounds` fills the image less a 4-pixel margin.
/// Only triangles for which `draw(triangle, label, view-space unit normal)` holds are drawn,
/// in class colours (`by_class`) or interpolated vertex colours, shaded by the angle to a
/// fixed light when `shaded`.
pub fn render(
    mesh: &LabeledMesh,
    view: Mat3,
    px: u32,
    bounds: (Vec3, Vec3),
    by_class: bool,
    shaded: bool,
    draw: impl Fn(&[u32; 3], u8, Vec3) -> bool,
) -> image::RgbImage {
    let (lo, hi) = bounds;
    let pts: Vec<Vec3> = mesh.positions.iter().map(|&p| view * p).collect();
    let scale = (px as f32 - 8.0) / (hi.x - lo.x).max(hi.y - lo.y);
    let to_px = |p: Vec3| Vec3::new((p.x - lo.x) * scale + 4.0, (hi.y - p.y) * scale + 4.0, p.z);
    let mut img = image::RgbImage::from_pixel(px, px, image::Rgb([255, 255, 255]));
    let mut depth = vec![f32::MIN; (px * px) as usize];
    let light = (view * Vec3::new(0.3, 0.5, 1.0)).normalize();
    for (t, &label) in mesh.triangles.iter().zip(&mesh.triangle_labels) {
        let [a, b, c] = t.map(|i| to_px(pts[i as usize]));
        let [wa, wb, wc] = t.map(|i| pts[i as usize]);
        let n = (wb - wa).cross(wc - wa).normalize_or_zero();
        if !draw(t, label, n) {
            continue;
        }
        let shade = if shaded { 0.55 + 0.45 * n.dot(light).abs() } else { 1.0 };
        let area = (b.x - a.x) * (c.y - a.y) - (b.y - a.y) * (c.x - a.x);
        if area.abs() < 1e-9 {
            continue;
        }
        let x0 = a.x.min(b.x).min(c.x).floor().max(0.0) as u32;
        let x1 = (a.x.max(b.x).max(c.x).ceil() as u32).min(px - 1);
        let y0 = a.y.min(b.y).min(c.y).floor().max(0.0) as u32;
        let y1 = (a.y.max(b.y).max(c.y).ceil() as u32).min(px - 1);
        for y in y0..=y1 {
            for x in x0..=x1 {
                let (fx, fy) = (x as f32 + 0.5, y as f32 + 0.5);
                let w0 = ((b.x - fx) * (c.y - fy) - (b.y - fy) * (c.x - fx)) / area;
                let w1 = ((c.x - fx) * (a.y - fy) - (c.y - fy) * (a.x - fx)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                let z = w0 * a.z + w1 * b.z + w2 * c.z;
                let slot = (y * px + x) as usize;
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

/// Lays equal square panels out left to right, `cols` to a row.
pub fn tile(panels: &[image::RgbImage], cols: u32) -> image::RgbImage {
    let px = panels[0].width();
    let n = panels.len() as u32;
    let mut canvas = image::RgbImage::new(px * cols.min(n), px * n.div_ceil(cols));
    for (i, panel) in (0..).zip(panels) {
        image::imageops::overlay(&mut canvas, panel, (i % cols * px) as i64, (i / cols * px) as i64);
    }
    canvas
}
