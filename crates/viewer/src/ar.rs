//! The AR view of `semrecon ar`: virtual balls drawn over the RGB frames of a scan, the
//! paper's application seen through the camera. Balls are thrown from the camera every few
//! seconds and simulated with the class materials; each frame draws them from that frame's
//! pose, hidden where the real room is in front of them (depth test against the model
//! rendered from the same pose, so occlusion follows the reconstruction rather than the
//! sensor's holes). Output: one PNG per frame and a small animated GIF preview.

use std::path::{Path, PathBuf};

use glam::{Affine3A, Vec3};
use semrecon_data::atomic_file::write_atomic;
use semrecon_data::depth_image::write_color_png;
use semrecon_data::{FrameSource, Intrinsics, LabeledMesh, MeshGravity, PreparedMesh, Renderer};
use semrecon_physics::{ArScene, BallId, MaterialTable, SceneConfig};

use crate::error::{Result, ViewerError};
use crate::gif;

/// Settings of an AR rendering.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArOptions {
    /// At most this many frames (from the first).
    pub max_frames: usize,
    /// Throw speed, m/s.
    pub speed: f32,
    /// A new ball every this many seconds of the scan.
    pub throw_every_s: f32,
    /// Width of the GIF preview in pixels (frames are shrunk by a whole factor to about this).
    pub gif_width: u32,
    /// Gravity in the scan's world frame, as its mesh file records it
    /// ([`semrecon_data::read_ply_with_gravity`]): gravity pulls against its up, balls are
    /// tossed a little along it, and a recorded floor puts a ground plane under the scan's
    /// holes ([`SceneConfig::with_gravity`]). `None`: +z up (generated rooms), no plane.
    pub gravity: Option<MeshGravity>,
}

impl Default for ArOptions {
    fn default() -> Self {
        Self { max_frames: 300, speed: 3.0, throw_every_s: 1.5, gif_width: 320, gravity: None }
    }
}

/// What an AR rendering produced.
#[derive(Debug, Clone, PartialEq)]
pub struct ArSummary {
    /// Frames written (`frame-NNNNNN.png`).
    pub frames: usize,
    /// Balls thrown.
    pub balls: usize,
    /// Ball pixels drawn, and ball pixels hidden behind the room.
    pub ball_pixels: (usize, usize),
    /// The animated preview.
    pub gif: PathBuf,
}

/// Renders the AR view of `source` (frames with poses) against `mesh` into `out`.
pub fn render_ar(
    source: &dyn FrameSource,
    mesh: &LabeledMesh,
    materials: MaterialTable,
    out: &Path,
    options: &ArOptions,
) -> Result<ArSummary> {
    let bad = |m: String| ViewerError::NoMesh { dir: out.to_path_buf(), message: m };
    let n = source.len().min(options.max_frames);
    if n == 0 {
        return Err(bad(format!("{}: no frames", source.name())));
    }
    if !(options.throw_every_s.is_finite() && options.throw_every_s > 0.0) {
        return Err(bad(format!("throw interval {} s must be positive", options.throw_every_s)));
    }
    std::fs::create_dir_all(out).map_err(|e| semrecon_data::DataError::io(out, e))?;
    let intrinsics = source.intrinsics();
    let fps = source.frame_rate().clamp(1.0, 240.0) as f32;
    let throw_every = ((options.throw_every_s * fps).round() as usize).max(1);
    let prepared = PreparedMesh::new(mesh)?;
    let mut renderer = Renderer::new(intrinsics)?;
    let mut scene = ArScene::with_mesh(mesh, materials, SceneConfig::default().with_gravity(options.gravity))?;
    let radius = scene.config().ball_radius;
    let mut balls: Vec<BallId> = Vec::new();
    let mut pixels = (0, 0);
    // The GIF keeps at most 120 frames and a whole-factor downscale.
    let gif_step = n.div_ceil(120).max(1);
    let shrink = (intrinsics.width.div_ceil(options.gif_width.max(16))).max(1);
    let (gw, gh) = (intrinsics.width / shrink, intrinsics.height / shrink);
    let mut gif_frames = Vec::new();
    for i in 0..n {
        let frame = source.frame(i)?;
        let world_from_camera = frame
            .world_from_camera
            .ok_or_else(|| bad(format!("{}: frame {i} has no pose (the AR view needs posed frames)", source.name())))?;
        if frame.color.len() != intrinsics.pixel_count() {
            return Err(bad(format!(
                "{}: frame {i} colour is not {}x{}",
                source.name(),
                intrinsics.width,
                intrinsics.height
            )));
        }
        let model_depth = renderer.render(&prepared, world_from_camera).depth.clone();
        if i % throw_every == 0 {
            let forward = Vec3::from(world_from_camera.matrix3.z_axis).normalize_or(Vec3::X);
            // Released as from a hand in front of the camera: 40 cm ahead and 10 cm below
            // the view's centre (15 cm ahead, a 4 cm ball filled a third of the picture),
            // nearer when the room's surface in the middle of the view is closer than that.
            let centre = model_depth
                [(intrinsics.height as usize / 2) * intrinsics.width as usize + intrinsics.width as usize / 2];
            let ahead = if centre > 0.0 { (centre - 2.0 * radius - 0.05).clamp(0.1, 0.4) } else { 0.4 };
            let up = scene.config().up;
            let from = Vec3::from(world_from_camera.translation) + forward * ahead - up * (0.25 * ahead);
            balls.push(scene.throw_ball(from, forward + up * 0.3, options.speed)?);
        }
        let mut color = frame.color;
        let camera_from_world = world_from_camera.inverse();
        for &b in &balls {
            if let Some((p, _)) = scene.ball_state(b) {
                let (seen, hidden) = draw_ball(&mut color, &model_depth, intrinsics, &camera_from_world, p, radius);
                pixels.0 += seen;
                pixels.1 += hidden;
            }
        }
        write_color_png(out.join(format!("frame-{i:06}.png")), intrinsics.width, intrinsics.height, &color)?;
        if i % gif_step == 0 {
            gif_frames.push(shrink_image(&color, intrinsics.width, shrink, gw, gh));
        }
        scene.simulate(1.0 / fps)?;
    }
    let delay_cs = ((100.0 * gif_step as f32 / fps).round() as u16).max(2);
    let gif_path = out.join("ar.gif");
    write_atomic(&gif_path, &gif::encode(gw as u16, gh as u16, &gif_frames, delay_cs))?;
    Ok(ArSummary { frames: n, balls: balls.len(), ball_pixels: pixels, gif: gif_path })
}

/// Draws a shaded ball of `radius` at `p_world` where it is in front of `model_depth`;
/// returns (pixels drawn, pixels hidden by the room).
///
/// # Shapes
/// `color` and `model_depth` are `width * height` of `intrinsics`, row-major.
fn draw_ball(
    color: &mut [[u8; 3]],
    model_depth: &[f32],
    intrinsics: Intrinsics,
    camera_from_world: &Affine3A,
    p_world: Vec3,
    radius: f32,
) -> (usize, usize) {
    let c = camera_from_world.transform_point3(p_world);
    if c.z <= radius + 0.05 {
        return (0, 0);
    }
    let centre = intrinsics.project(c);
    let r_px = intrinsics.fx * radius / c.z;
    let (w, h) = (intrinsics.width as i64, intrinsics.height as i64);
    let (x0, x1) = (((centre.x - r_px).floor() as i64).max(0), ((centre.x + r_px).ceil() as i64).min(w - 1));
    let (y0, y1) = (((centre.y - r_px).floor() as i64).max(0), ((centre.y + r_px).ceil() as i64).min(h - 1));
    let light = Vec3::new(-0.4, -0.6, -0.7).normalize();
    let (mut seen, mut hidden) = (0, 0);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let d = glam::Vec2::new((x as f32 + 0.5 - centre.x) / r_px, (y as f32 + 0.5 - centre.y) / r_px);
            let d2 = d.length_squared();
            if d2 > 1.0 {
                continue;
            }
            let bulge = (1.0 - d2).sqrt();
            let z = c.z - radius * bulge;
            let k = (y * w + x) as usize;
            let model = model_depth[k];
            // A small margin: a ball resting on the floor touches it.
            if model > 0.0 && z > model + 0.01 {
                hidden += 1;
                continue;
            }
            seen += 1;
            let normal = Vec3::new(d.x, d.y, -bulge);
            let diffuse = normal.dot(light).max(0.0);
            let specular = normal.dot(light).max(0.0).powi(24);
            let base = Vec3::new(255.0, 215.0, 40.0);
            let v = base * (0.35 + 0.65 * diffuse) + Vec3::splat(255.0 * 0.6 * specular);
            color[k] = v.min(Vec3::splat(255.0)).to_array().map(|x| x as u8);
        }
    }
    (seen, hidden)
}

/// Box-filtered downscale by a whole `factor` to `w x h`.
fn shrink_image(color: &[[u8; 3]], width: u32, factor: u32, w: u32, h: u32) -> Vec<[u8; 3]> {
    let mut out = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let mut sum = [0u32; 3];
            for dy in 0..factor {
                for dx in 0..factor {
                    let p = color[((y * factor + dy) * width + x * factor + dx) as usize];
                    for k in 0..3 {
                        sum[k] += p[k] as u32;
                    }
                }
            }
            out.push(sum.map(|s| (s / (factor * factor)) as u8));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ball_hidden_behind_nearer_surface_and_drawn_in_front() {
        let intr = Intrinsics::new(64, 48, 50.0, 50.0, 32.0, 24.0).expect("intrinsics");
        let identity = Affine3A::IDENTITY;
        let ball = Vec3::new(0.0, 0.0, 2.0);
        let mut color = vec![[0u8; 3]; 64 * 48];
        let (seen, hidden) = draw_ball(&mut color, &vec![1.0; 64 * 48], intr, &identity, ball, 0.2);
        assert_eq!(seen, 0);
        assert!(hidden > 20);
        assert!(color.iter().all(|c| *c == [0, 0, 0]));
        let (seen, hidden) = draw_ball(&mut color, &vec![3.0; 64 * 48], intr, &identity, ball, 0.2);
        assert!(seen > 20 && hidden == 0);
        assert!(color[24 * 64 + 32][0] > 50, "the centre pixel is drawn");
        // Behind the camera: nothing.
        assert_eq!(draw_ball(&mut color, &vec![0.0; 64 * 48], intr, &identity, -ball, 0.2), (0, 0));
    }
}
