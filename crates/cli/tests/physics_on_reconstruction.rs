//! A ball dropped onto the table of a *reconstructed* scene behaves as a table (issue 7):
//! a generated room is rendered from a few views around a table, fused into a TSDF, meshed,
//! and the mesh's vertices take the class the label images show at their projection (a
//! stand-in for the network, which labels live maps in the full pipeline). The ball must
//! report its first contact on `table`, with the table's restitution.

use glam::{Affine3A, Mat3, Vec3};
use semrecon_data::class::UNLABELED;
use semrecon_data::synth::{generate_room, RoomConfig, RoomStyle};
use semrecon_data::{Frame, Intrinsics, PreparedMesh, Renderer, SemanticClass};
use semrecon_physics::{throw_into_mesh, MaterialTable, SceneConfig};
use semrecon_recon::{extract_mesh, TsdfConfig, TsdfMap};

fn look_at(eye: Vec3, at: Vec3) -> Affine3A {
    let forward = (at - eye).normalize();
    let right = forward.cross(Vec3::Z).normalize();
    let down = forward.cross(right);
    Affine3A::from_mat3_translation(Mat3::from_cols(right, down, forward), eye)
}

#[test]
fn a_ball_dropped_on_a_reconstructed_table_bounces_as_on_a_table() {
    let room = generate_room(&RoomConfig { seed: 7, style: Some(RoomStyle::Conference) });
    let mesh = &room.mesh;
    // The middle of an upward-facing table-top triangle with nothing on it (no vertex of
    // another class within 15 cm horizontally and 60 cm above it).
    let clear = |c: Vec3| {
        mesh.positions.iter().zip(&mesh.vertex_labels).all(|(p, &l)| {
            l == SemanticClass::Table.id()
                || p.z <= c.z + 0.005
                || p.z > c.z + 0.6
                || (p.truncate() - c.truncate()).length() > 0.15
        })
    };
    let centre = mesh
        .triangles
        .iter()
        .zip(&mesh.triangle_labels)
        .filter(|(_, &l)| l == SemanticClass::Table.id())
        .map(|(t, _)| t.map(|i| mesh.positions[i as usize]))
        .filter(|[a, b, c]| {
            let n = (*b - *a).cross(*c - *a);
            n.z > 0.0 && n.normalize().z > 0.95 && a.z > 0.6 && n.length() > 0.01
        })
        .map(|[a, b, c]| (a + b + c) / 3.0)
        .find(|&c| clear(c))
        .expect("a conference room has a clear spot on a table");

    let k = Intrinsics::new(320, 240, 262.5, 262.5, 159.5, 119.5).expect("camera");
    let mut renderer = Renderer::new(k).expect("renderer");
    let prepared = PreparedMesh::new(mesh).expect("mesh");
    let mut config = TsdfConfig::with_voxel_size(0.01).expect("config");
    config.truncation_voxels = 4.0;
    let mut map = TsdfMap::new(config).expect("map");
    let mut views: Vec<(Affine3A, Frame)> = Vec::new();
    for i in 0..8 {
        let a = i as f32 / 8.0 * std::f32::consts::TAU;
        let eye = centre + Vec3::new(1.0 * a.cos(), 1.0 * a.sin(), 0.8);
        let pose = look_at(eye, centre);
        let frame = renderer.render_frame(&prepared, pose, i);
        map.integrate(&frame, pose).expect("fuse");
        views.push((pose, frame));
    }
    let mut recon = extract_mesh(&map);
    assert!(recon.triangle_count() > 1000, "{} triangles", recon.triangle_count());

    // Label transfer: the class the first view that sees a vertex shows at its pixel.
    recon.vertex_labels = recon
        .positions
        .iter()
        .map(|&p| {
            views
                .iter()
                .find_map(|(pose, frame)| {
                    let q = pose.inverse().transform_point3(p);
                    if q.z <= 0.05 {
                        return None;
                    }
                    let uv = k.project(q);
                    let (u, v) = (uv.x.round(), uv.y.round());
                    if u < 0.0 || v < 0.0 || u >= k.width as f32 || v >= k.height as f32 {
                        return None;
                    }
                    let i = v as usize * k.width as usize + u as usize;
                    let d = frame.depth[i];
                    (d > 0.0 && (d - q.z).abs() < 0.02).then(|| frame.labels.as_ref().map_or(UNLABELED, |l| l[i]))
                })
                .unwrap_or(UNLABELED)
        })
        .collect();

    let throw = throw_into_mesh(
        &recon,
        MaterialTable::defaults(),
        SceneConfig::default(),
        centre + Vec3::Z * 0.5,
        -Vec3::Z,
        0.1,
        1.5,
    )
    .expect("throw");
    let first = throw.contacts.first().expect("the ball hits something");
    assert_eq!(first.class, "table", "first contact {first:?}");
    let table = MaterialTable::defaults().class(SemanticClass::Table);
    assert!((first.restitution - table.restitution).abs() < 1e-6);
    assert!((first.position[2] - centre.z).abs() < 0.03, "contact at {:?}, table top at {}", first.position, centre.z);
}
