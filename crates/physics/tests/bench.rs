//! Cost measurements, ignored by default (run with
//! `cargo test --release -p semrecon-physics --test bench -- --ignored --nocapture`).

mod common;

use std::time::Instant;

use common::bumpy_patch;
use glam::Vec3;
use semrecon_data::SemanticClass;
use semrecon_physics::{ArScene, CollisionMesh, CollisionMeshConfig, MaterialTable, SceneConfig};

#[test]
#[ignore = "measurement, not a check"]
fn step_cost_10_balls_on_100k_triangles() {
    // A 4.5 m scanned-like floor at 5 mm (1.6 M triangles, ±1.5 mm noise), clustered at 2 cm.
    let visual = bumpy_patch(2.25, 0.005, 0.0015, SemanticClass::Floor, 3);
    let t = Instant::now();
    let collision = CollisionMesh::build(&visual, &CollisionMeshConfig::default()).expect("build");
    let cluster_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mut scene = ArScene::new(MaterialTable::defaults(), SceneConfig::default()).expect("scene");
    let tris = collision.triangle_count();
    let regions = collision.regions.len();
    scene.replace_collision_mesh(collision).expect("colliders");
    let colliders_s = t.elapsed().as_secs_f64();
    println!(
        "visual {} triangles -> collision {tris} triangles in {regions} regions: clustering {:.0} ms, colliders {:.0} ms",
        visual.triangle_count(),
        cluster_s * 1e3,
        colliders_s * 1e3
    );
    for i in 0..10 {
        let a = i as f32 * 0.628;
        // Steep throws at 1-3 m/s: the balls keep bouncing and rolling on the floor.
        scene
            .throw_ball(Vec3::new(a.cos(), a.sin(), 1.2), Vec3::new(-a.cos(), -a.sin(), -3.0), 1.0 + 0.2 * i as f32)
            .expect("throw");
    }
    let steps = 480; // 2 s at 1/240 s
    let t = Instant::now();
    for _ in 0..steps {
        scene.step();
    }
    let per_step = t.elapsed().as_secs_f64() / steps as f64;
    let on_floor = (0..10)
        .filter_map(|i| scene.ball_state(semrecon_physics::BallId(i)))
        .filter(|(p, _)| p.x.abs() < 2.25 && p.y.abs() < 2.25 && p.z > 0.0)
        .count();
    println!(
        "10 balls ({on_floor} still on the floor after 2 s), {tris} triangles: {:.1} us per step ({:.3} ms per 1/60 s frame of 4 steps)",
        per_step * 1e6,
        per_step * 4e3
    );
}
