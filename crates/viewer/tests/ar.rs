//! The AR view end to end: frames rendered inside a closed box room, balls thrown from the
//! camera, PNG frames and a GIF written, balls visible in the frames.

use glam::{Affine3A, Mat3, Quat, Vec3};
use semrecon_data::{Frame, FrameSource, Intrinsics, LabeledMesh, PreparedMesh, Renderer};
use semrecon_physics::MaterialTable;
use semrecon_viewer::ar::{render_ar, ArOptions};

/// A closed 4 x 4 x 2.5 m box, floor class 1, the rest walls (2), grey.
fn room() -> LabeledMesh {
    let mut m = LabeledMesh::default();
    let mut quad = |c: [Vec3; 4], label: u8, colour: [u8; 3]| {
        let base = m.positions.len() as u32;
        m.positions.extend(c);
        m.colors.extend([colour; 4]);
        m.triangles.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]]);
        m.triangle_labels.extend([label, label]);
    };
    let v = Vec3::new;
    let (x, y, z) = (4.0, 4.0, 2.5);
    quad([v(0., 0., 0.), v(x, 0., 0.), v(x, y, 0.), v(0., y, 0.)], 1, [90, 90, 90]);
    quad([v(0., 0., z), v(0., y, z), v(x, y, z), v(x, 0., z)], 2, [120, 120, 120]);
    quad([v(0., 0., 0.), v(0., 0., z), v(x, 0., z), v(x, 0., 0.)], 2, [120, 120, 120]);
    quad([v(0., y, 0.), v(x, y, 0.), v(x, y, z), v(0., y, z)], 2, [120, 120, 120]);
    quad([v(0., 0., 0.), v(0., y, 0.), v(0., y, z), v(0., 0., z)], 2, [120, 120, 120]);
    quad([v(x, 0., 0.), v(x, 0., z), v(x, y, z), v(x, y, 0.)], 2, [120, 120, 120]);
    m
}

struct Frames(Vec<Frame>, Intrinsics);

impl FrameSource for Frames {
    fn name(&self) -> String {
        "box".into()
    }
    fn len(&self) -> usize {
        self.0.len()
    }
    fn intrinsics(&self) -> Intrinsics {
        self.1
    }
    fn has_ground_truth(&self) -> bool {
        true
    }
    fn frame(&self, index: usize) -> semrecon_data::Result<Frame> {
        Ok(self.0[index].clone())
    }
}

#[test]
fn balls_are_drawn_over_the_frames_and_a_gif_is_written() {
    let mesh = room();
    let intrinsics = Intrinsics::new(80, 60, 70.0, 70.0, 40.0, 30.0).expect("intrinsics");
    let prepared = PreparedMesh::new(&mesh).expect("prepared");
    let mut renderer = Renderer::new(intrinsics).expect("renderer");
    // Camera at the side of the room looking along +x, slightly down.
    let forward = Vec3::new(1.0, 0.0, -0.2).normalize();
    let right = forward.cross(Vec3::Z).normalize();
    let down = forward.cross(right);
    let pose = Affine3A::from_rotation_translation(
        Quat::from_mat3(&Mat3::from_cols(right, down, forward)),
        Vec3::new(0.5, 2.0, 1.4),
    );
    let frames: Vec<Frame> = (0..20).map(|i| renderer.render_frame(&prepared, pose, i)).collect();
    let plain: Vec<Vec<[u8; 3]>> = frames.iter().map(|f| f.color.clone()).collect();
    let dir = tempfile::tempdir().expect("tempdir");
    let options = ArOptions { max_frames: 20, speed: 2.0, throw_every_s: 0.3, gif_width: 40, ..ArOptions::default() };
    let summary =
        render_ar(&Frames(frames, intrinsics), &mesh, MaterialTable::defaults(), dir.path(), &options).expect("ar");
    assert_eq!(summary.frames, 20);
    assert!(summary.balls >= 2, "{summary:?}");
    assert!(summary.ball_pixels.0 > 50, "{summary:?}");
    let gif = std::fs::read(&summary.gif).expect("gif");
    assert_eq!(&gif[..6], b"GIF89a");
    assert_eq!(gif.last(), Some(&0x3B));
    // A later frame differs from the plain render where the balls are.
    let shown = image::open(dir.path().join("frame-000010.png")).expect("png").to_rgb8();
    let changed = shown.pixels().zip(&plain[10]).filter(|(a, b)| a.0 != **b).count();
    assert!(changed > 5, "{changed} pixels changed");
}
