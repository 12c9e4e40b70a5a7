//! An analytic test scene (floor, back wall, a sphere) ray-cast per pixel into exact depth
//! frames, so that fusion can be checked without a renderer. Shared by the tests and the
//! fusion benchmark.
#![allow(dead_code)]

use glam::{Affine3A, Mat3, Vec3};
use semrecon_data::{Frame, Intrinsics};

/// Sphere centre and radius, metres, world frame.
pub const SPHERE: (Vec3, f32) = (Vec3::new(0.12, 1.45, 0.55), 0.3);
/// The back wall is the plane y = WALL_Y.
pub const WALL_Y: f32 = 2.2;

/// A camera at `eye` looking horizontally along the world +y axis, turned by `yaw` radians
/// about the world z axis (camera x right, y down, z forward).
pub fn camera_pose(eye: Vec3, yaw: f32) -> Affine3A {
    // Columns: camera x, y, z axes expressed in the world frame.
    let base = Mat3::from_cols(Vec3::X, -Vec3::Z, Vec3::Y);
    Affine3A::from_mat3_translation(Mat3::from_rotation_z(yaw) * base, eye)
}

/// Distance along the world ray `o + t d` to the first surface, and its colour.
fn cast(o: Vec3, d: Vec3) -> Option<(f32, [u8; 3])> {
    let mut best: Option<(f32, [u8; 3])> = None;
    let mut offer = |t: f32, c: [u8; 3]| {
        if t > 1e-4 && best.is_none_or(|(b, _)| t < b) {
            best = Some((t, c));
        }
    };
    // Floor z = 0, a checkerboard.
    if d.z.abs() > 1e-9 {
        let t = -o.z / d.z;
        let p = o + d * t;
        let check = ((p.x * 5.0).floor() as i32 + (p.y * 5.0).floor() as i32).rem_euclid(2);
        offer(t, if check == 0 { [200, 200, 200] } else { [60, 60, 60] });
    }
    // Back wall.
    if d.y.abs() > 1e-9 {
        offer((WALL_Y - o.y) / d.y, [90, 120, 200]);
    }
    // Sphere.
    let (c, r) = SPHERE;
    let oc = o - c;
    let b = oc.dot(d);
    let a = d.length_squared();
    let disc = b * b - a * (oc.length_squared() - r * r);
    if disc >= 0.0 {
        offer((-b - disc.sqrt()) / a, [220, 40, 30]);
    }
    best
}

/// An exact depth frame of the scene from `world_from_camera`.
pub fn render(k: Intrinsics, world_from_camera: Affine3A, index: usize) -> Frame {
    let n = k.pixel_count();
    let mut depth = vec![0.0f32; n];
    let mut color = vec![[0u8; 3]; n];
    let o = world_from_camera.translation.into();
    for v in 0..k.height as usize {
        for u in 0..k.width as usize {
            // Ray with camera-frame z = 1, so its parameter t is the depth.
            let ray_cam = k.unproject(u as f32, v as f32, 1.0);
            let d = world_from_camera.transform_vector3(ray_cam);
            if let Some((t, c)) = cast(o, d) {
                if t < 8.0 {
                    depth[v * k.width as usize + u] = t;
                    color[v * k.width as usize + u] = c;
                }
            }
        }
    }
    Frame {
        index,
        timestamp: index as f64 / 30.0,
        depth,
        color,
        intrinsics: k,
        world_from_camera: Some(world_from_camera),
        labels: None,
    }
}

/// A short orbit-like sequence of poses around the sphere, `n` frames.
pub fn trajectory(n: usize) -> Vec<Affine3A> {
    (0..n)
        .map(|i| {
            let s = i as f32 / n.max(1) as f32;
            camera_pose(Vec3::new(-0.3 + 0.6 * s, 0.0 + 0.1 * s, 1.1 - 0.2 * s), -0.15 + 0.3 * s)
        })
        .collect()
}
