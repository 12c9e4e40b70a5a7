//! End-to-end tests of `semrecon snapshot` on point clouds (PLY files without faces), and
//! that meshes still go through the triangle rasteriser.

mod common;

use common::{s, semrecon, stderr, stdout};
use glam::Vec3;
use semrecon_data::depth_image::load_color;
use semrecon_data::synth::{generate_room, RoomConfig};
use semrecon_data::{write_ply, LabeledMesh, PlyEncoding, SemanticClass};

/// A small labelled cloud: a 2 m x 2 m floor (2 cm spacing), a wall along x = 0 and a
/// 40 cm "chair" block on the floor.
fn small_cloud() -> LabeledMesh {
    let mut m = LabeledMesh::default();
    let mut push = |p: Vec3, class: SemanticClass, color: [u8; 3]| {
        m.positions.push(p);
        m.colors.push(color);
        m.vertex_labels.push(class.id());
    };
    for i in 0..100 {
        for j in 0..100 {
            push(Vec3::new(i as f32 * 0.02, j as f32 * 0.02, 0.0), SemanticClass::Floor, [150, 120, 90]);
        }
    }
    for j in 0..100 {
        for k in 1..60 {
            push(Vec3::new(0.0, j as f32 * 0.02, k as f32 * 0.02), SemanticClass::Wall, [200, 200, 200]);
        }
    }
    for i in 0..20 {
        for j in 0..20 {
            push(Vec3::new(1.0 + i as f32 * 0.02, 1.0 + j as f32 * 0.02, 0.4), SemanticClass::Chair, [40, 40, 200]);
        }
    }
    m
}

/// Pixels that are not the white background.
fn drawn(png: &std::path::Path) -> Vec<[u8; 3]> {
    let image = load_color(png).expect("a PNG");
    image.pixels.into_iter().filter(|&p| p != [255, 255, 255]).collect()
}

#[test]
fn a_point_cloud_renders_in_both_colourings() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cloud = dir.path().join("cloud.ply");
    write_ply(&cloud, &small_cloud(), PlyEncoding::BinaryLittleEndian).expect("write the cloud");

    let rgb = dir.path().join("rgb.png");
    let o = semrecon(&["snapshot", s(&cloud), "--out", s(&rgb), "--width", "320"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("points drawn"), "{}", stdout(&o));
    let pixels = drawn(&rgb);
    // Framed to the points: a good part of the 320x240 picture is covered.
    assert!(pixels.len() > 320 * 240 / 5, "{} pixels drawn", pixels.len());

    let classes = dir.path().join("classes.png");
    let o = semrecon(&["snapshot", s(&cloud), "--out", s(&classes), "--width", "320", "--classes"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("floor"), "the class shares are printed: {}", stdout(&o));
    let pixels = drawn(&classes);
    // Shaded class colours: hue kept, so floor-brown (R > G > B) and chair-red (R >> G, B)
    // pixels are both there.
    let brown = pixels.iter().filter(|p| p[0] > p[1] && p[1] > p[2] && p[0] > 60).count();
    let red = pixels.iter().filter(|p| p[0] > 60 && p[0] > 3 * p[1].max(p[2])).count();
    assert!(brown > 1000 && red > 50, "brown {brown}, red {red}");

    // Cutting everything away is an error, not an empty picture.
    let o = semrecon(&["snapshot", s(&cloud), "--out", s(&rgb), "--cut-above", "-1"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("nothing left to draw"), "{}", stderr(&o));

    // The same file turned: a y-up copy with --up 0,1,0 draws as many points.
    let mut yup = small_cloud();
    yup.positions.iter_mut().for_each(|p| *p = Vec3::new(p.x, p.z, -p.y));
    let yup_path = dir.path().join("yup.ply");
    write_ply(&yup_path, &yup, PlyEncoding::BinaryLittleEndian).expect("write");
    let turned = dir.path().join("turned.png");
    let o = semrecon(&["snapshot", s(&yup_path), "--out", s(&turned), "--width", "320", "--up", "0,1,0"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let a = drawn(&rgb).len() as f64;
    let b = drawn(&turned).len() as f64;
    assert!((a - b).abs() < 0.05 * a, "{a} vs {b} pixels");
}

#[test]
fn a_mesh_still_renders_as_triangles() {
    let dir = tempfile::tempdir().expect("tempdir");
    let room = generate_room(&RoomConfig { seed: 5, style: None });
    let mesh = dir.path().join("room.ply");
    write_ply(&mesh, &room.mesh, PlyEncoding::BinaryLittleEndian).expect("write the mesh");
    let png = dir.path().join("room.png");
    let o = semrecon(&["snapshot", s(&mesh), "--out", s(&png), "--width", "200", "--classes", "--cut-above", "2.2"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stdout(&o).contains("triangles drawn"), "{}", stdout(&o));
    assert!(drawn(&png).len() > 200 * 150 / 10);
}
