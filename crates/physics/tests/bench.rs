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

#[test]
#[ignore = "measurement, not a check"]
fn rebound_ratio_per_class() {
    let materials = MaterialTable::defaults();
    for class in SemanticClass::ALL {
        let e = materials.class(class).restitution;
        let mesh = common::patch(0.5, 0.02, 0.0, class);
        let cfg = SceneConfig { record_every: 1, ..SceneConfig::default() };
        let mut scene = ArScene::with_mesh(&mesh, materials.clone(), cfg).expect("scene");
        scene.throw_ball(Vec3::new(0.013, -0.021, 1.0 + cfg.ball_radius), Vec3::NEG_Z, 0.0).expect("throw");
        let t = scene.simulate(2.0).expect("simulate").remove(0);
        let first = t.contacts[0].time;
        let end = t.contacts.get(1).map_or(f32::INFINITY, |c| c.time);
        let apex = t
            .times
            .iter()
            .zip(&t.positions)
            .filter(|(&s, _)| s > first && s < end)
            .map(|(_, p)| p[2] - t.radius)
            .fold(f32::NEG_INFINITY, f32::max);
        println!(
            "{:9} e {:.2}: rebound {:.4} m, e^2 h {:.4} m, ratio {:.4}",
            class.name(),
            e,
            apex,
            e * e,
            apex / (e * e)
        );
    }
}
