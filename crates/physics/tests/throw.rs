//! `throw_from_ply`, the entry point of `semrecon throw`: files in, trajectory out, and
//! every kind of bad input an error rather than a panic.

mod common;

use std::path::Path;

use common::room_with_table;
use glam::Vec3;
use semrecon_data::{write_ply, PlyEncoding};
use semrecon_physics::{throw_from_ply, PhysicsError};

fn room_ply(dir: &Path, labels: bool) -> std::path::PathBuf {
    let mut mesh = room_with_table();
    if !labels {
        mesh.triangle_labels.clear();
    }
    let path = dir.join(if labels { "room.ply" } else { "plain.ply" });
    write_ply(&path, &mesh, PlyEncoding::BinaryLittleEndian).expect("write ply");
    path
}

#[test]
fn throw_onto_the_table_from_a_ply() {
    let dir = tempfile::tempdir().expect("tempdir");
    let ply = room_ply(dir.path(), true);
    let t = throw_from_ply(&ply, None, Vec3::new(-1.0, 0.0, 1.2), Vec3::new(1.0, 0.0, 0.3), 2.5, 1.5).expect("throw");
    assert_eq!(t.contacts[0].class, "table", "{:?}", t.contacts);
    assert!(t.warnings.is_empty());
    assert_eq!(t.times.len(), t.positions.len());
    // A user materials file changes the table's restitution.
    let toml = dir.path().join("m.toml");
    std::fs::write(&toml, "[classes.table]\nrestitution = 0.3\n").expect("write");
    let soft = throw_from_ply(&ply, Some(&toml), Vec3::new(-1.0, 0.0, 1.2), Vec3::new(1.0, 0.0, 0.3), 2.5, 1.5)
        .expect("throw");
    assert_eq!(soft.contacts[0].restitution, 0.3);
    // Same contact, lower rebound.
    assert_eq!(soft.contacts[0].time, t.contacts[0].time);
    let apex = |t: &semrecon_physics::Throw| {
        let t0 = t.contacts[0].time;
        t.times
            .iter()
            .zip(&t.positions)
            .filter(|(&s, _)| s > t0 && s < t0 + 0.3)
            .map(|(_, p)| p[2])
            .fold(0.0f32, f32::max)
    };
    assert!(apex(&soft) < apex(&t));
}

#[test]
fn unlabelled_mesh_uses_the_default_material_and_warns() {
    let dir = tempfile::tempdir().expect("tempdir");
    let ply = room_ply(dir.path(), false);
    let t = throw_from_ply(&ply, None, Vec3::new(0.0, 0.0, 1.2), Vec3::NEG_Z, 0.0, 0.6).expect("throw");
    assert_eq!(t.contacts[0].class, "unlabelled");
    assert_eq!(t.contacts[0].restitution, semrecon_physics::MaterialTable::defaults().unlabelled().restitution);
    assert_eq!(t.warnings.len(), 1, "{:?}", t.warnings);
    let json = serde_json::to_string(&t).expect("json");
    assert!(json.contains("\"warnings\""));
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let dir = tempfile::tempdir().expect("tempdir");
    let ply = room_ply(dir.path(), true);
    let ok = (Vec3::new(0.0, 0.0, 1.0), Vec3::X, 1.0, 1.0);
    let throw = |from: Vec3, d: Vec3, v: f32, s: f32| throw_from_ply(&ply, None, from, d, v, s);

    let missing = dir.path().join("none.ply");
    let e = throw_from_ply(&missing, None, ok.0, ok.1, ok.2, ok.3).expect_err("missing");
    assert!(e.to_string().contains("none.ply"), "{e}");

    let corrupt = dir.path().join("corrupt.ply");
    std::fs::write(
        &corrupt,
        b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nend_header\n\x01\x02",
    )
    .expect("write");
    let e = throw_from_ply(&corrupt, None, ok.0, ok.1, ok.2, ok.3).expect_err("corrupt");
    assert!(e.to_string().contains("corrupt.ply"), "{e}");

    let points = dir.path().join("points.ply");
    let mut cloud = room_with_table();
    cloud.triangles.clear();
    cloud.triangle_labels.clear();
    write_ply(&points, &cloud, PlyEncoding::Ascii).expect("write");
    let e = throw_from_ply(&points, None, ok.0, ok.1, ok.2, ok.3).expect_err("no triangles");
    assert!(matches!(e, PhysicsError::Mesh(_)) && e.to_string().contains("points.ply"), "{e}");

    let bad_toml = dir.path().join("bad.toml");
    std::fs::write(&bad_toml, "[classes.sofa]\nrestitution = 2\n").expect("write");
    let e = throw_from_ply(&ply, Some(&bad_toml), ok.0, ok.1, ok.2, ok.3).expect_err("bad toml");
    assert!(e.to_string().contains("bad.toml") && e.to_string().contains("classes.sofa.restitution"), "{e}");

    let cases: [(Vec3, Vec3, f32, f32, &str); 9] = [
        (Vec3::new(f32::NAN, 0.0, 1.0), ok.1, ok.2, ok.3, "position"),
        (Vec3::new(1e30, 0.0, 1.0), ok.1, ok.2, ok.3, "position"),
        (ok.0, Vec3::ZERO, ok.2, ok.3, "direction"),
        (ok.0, Vec3::new(0.0, f32::INFINITY, 0.0), ok.2, ok.3, "direction"),
        (ok.0, Vec3::splat(1e-30), ok.2, ok.3, "direction"),
        (ok.0, ok.1, f32::NAN, ok.3, "speed"),
        (ok.0, ok.1, 1e9, ok.3, "speed"),
        (ok.0, ok.1, ok.2, -1.0, "duration"),
        (ok.0, ok.1, ok.2, f32::INFINITY, "duration"),
    ];
    for (from, d, v, s, what) in cases {
        let e = throw(from, d, v, s).expect_err(what);
        assert!(matches!(e, PhysicsError::InvalidArgument(_)) && e.to_string().contains(what), "{what}: {e}");
    }
}

/// A reconstruction keeps its dataset's frame (7-Scenes' world is nearly y down) and records
/// that frame's up in the PLY header: the same room turned into such a frame, thrown into
/// from the turned start, gives the same throw turned (same class, same contact time), and
/// never the ball "falling" along the file's -z.
#[test]
fn gravity_follows_the_up_direction_the_file_records() {
    let dir = tempfile::tempdir().expect("tempdir");
    let upright = room_with_table();
    let (from, toward) = (Vec3::new(-1.0, 0.0, 1.2), Vec3::new(1.0, 0.0, 0.3));
    let reference = throw_from_ply(&room_ply(dir.path(), true), None, from, toward, 2.5, 1.5).expect("throw");
    // 7-Scenes redkitchen's gravity file: up = (0.0089, -0.9044, -0.4265).
    let turn = glam::Quat::from_rotation_arc(Vec3::Z, Vec3::new(0.0089, -0.9044, -0.4265).normalize());
    let mut turned = upright.clone();
    turned.positions.iter_mut().for_each(|p| *p = turn * *p);
    turned.normals.iter_mut().for_each(|n| *n = turn * *n);
    let colors = turned.colors.clone();
    let (a, b) = (dir.path().join("turned.ply"), dir.path().join("turned-classes.ply"));
    semrecon_data::write_ply_recoloured(
        &a,
        &b,
        &turned,
        &colors,
        PlyEncoding::BinaryLittleEndian,
        Some(semrecon_data::MeshGravity::up(turn * Vec3::Z)),
    )
    .expect("write");
    let t = throw_from_ply(&a, None, turn * from, turn * toward, 2.5, 1.5).expect("throw");
    assert_eq!(t.contacts[0].class, reference.contacts[0].class, "{:?}", t.contacts);
    assert!(
        (t.contacts[0].time - reference.contacts[0].time).abs() < 0.02,
        "{} against {}",
        t.contacts[0].time,
        reference.contacts[0].time
    );
    for (p, q) in t.positions.iter().zip(&reference.positions).take(30) {
        let back = turn.inverse() * Vec3::from_array(*p);
        assert!(back.distance(Vec3::from_array(*q)) < 0.02, "{back} against {q:?}");
    }
    // Without the recorded up the same file would pull the ball along its -z.
    write_ply(&a, &turned, PlyEncoding::BinaryLittleEndian).expect("write");
    let sideways = throw_from_ply(&a, None, turn * from, turn * toward, 2.5, 1.5).expect("throw");
    let off = turn.inverse() * Vec3::from_array(sideways.positions[10]);
    assert!(off.distance(Vec3::from_array(reference.positions[10])) > 0.05, "{off}: gravity along the file's -z");
}

/// A scan's floor has holes (patches no frame saw): a ball dropped over one falls for ever,
/// unless the file records the floor height, when a ground plane 2 cm below it catches the
/// ball with the floor's material; where the scanned floor exists it takes the contact.
#[test]
fn a_recorded_floor_catches_balls_under_the_scans_holes() {
    let dir = tempfile::tempdir().expect("tempdir");
    // A 2 m x 2 m floor at z = 0 in 10 cm quads, with a 60 cm square hole in its middle.
    let mut mesh = semrecon_data::LabeledMesh::default();
    for i in 0..20 {
        for j in 0..20 {
            let (x, y) = (i as f32 * 0.1 - 1.0, j as f32 * 0.1 - 1.0);
            if (-0.3..0.3).contains(&x) && (-0.3..0.3).contains(&y) {
                continue;
            }
            let k = mesh.positions.len() as u32;
            for (dx, dy) in [(0.0, 0.0), (0.1, 0.0), (0.1, 0.1), (0.0, 0.1)] {
                mesh.positions.push(Vec3::new(x + dx, y + dy, 0.0));
                mesh.colors.push([128; 3]);
                mesh.vertex_labels.push(semrecon_data::SemanticClass::Floor.id());
            }
            mesh.triangles.extend([[k, k + 1, k + 2], [k, k + 2, k + 3]]);
        }
    }
    let path = dir.path().join("holey.ply");
    let drop = |gravity: Option<semrecon_data::MeshGravity>, x: f32| {
        semrecon_data::write_ply_recoloured(
            &path,
            dir.path().join("classes.ply"),
            &mesh,
            &mesh.colors,
            PlyEncoding::BinaryLittleEndian,
            gravity,
        )
        .expect("write");
        throw_from_ply(&path, None, Vec3::new(x, 0.05, 1.0), Vec3::NEG_Z, 0.1, 2.0).expect("throw")
    };
    let radius = drop(None, 0.0).radius;
    // Through the hole without a floor: no contact, metres below.
    let through = drop(Some(semrecon_data::MeshGravity::up(Vec3::Z)), 0.0);
    assert!(through.contacts.is_empty(), "{:?}", through.contacts);
    assert!(through.positions.last().expect("samples")[2] < -5.0);
    // With the floor recorded: caught by the plane 2 cm down, as floor.
    let floor = Some(semrecon_data::MeshGravity { up: Vec3::Z, floor_height: Some(0.0) });
    let caught = drop(floor, 0.0);
    let first = caught.contacts.first().expect("a contact");
    assert_eq!(first.class, "floor");
    assert!((first.position[2] + 0.02).abs() < 1e-3, "{:?}", first.position);
    // It bounces on the plane (the floor's restitution) and never sinks through it.
    let lowest = caught.positions.iter().map(|p| p[2]).fold(f32::INFINITY, f32::min);
    assert!(lowest > radius - 0.02 - 0.005, "lowest centre at {lowest} m");
    assert!(caught.contacts.len() >= 2, "{:?}", caught.contacts);
    // Over the scanned floor the mesh takes the contact, at z = 0.
    let on_mesh = drop(floor, 0.75);
    assert!(on_mesh.contacts[0].position[2].abs() < 1e-3, "{:?}", on_mesh.contacts[0].position);
}
