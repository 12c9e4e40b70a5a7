//! Meshes built in code for the physics tests.
#![allow(dead_code)]

use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use semrecon_data::{LabeledMesh, SemanticClass};

/// A flat horizontal patch centred on (0, 0) at height `z`, `half` metres each way,
/// tessellated in squares of `step`, every triangle labelled `class`, facing up.
pub fn patch(half: f32, step: f32, z: f32, class: SemanticClass) -> LabeledMesh {
    let n = (2.0 * half / step).round() as u32;
    let mut m = LabeledMesh::default();
    for j in 0..=n {
        for i in 0..=n {
            m.positions.push(Vec3::new(-half + i as f32 * step, -half + j as f32 * step, z));
        }
    }
    m.colors = vec![class.color(); m.positions.len()];
    let w = n + 1;
    for j in 0..n {
        for i in 0..n {
            let a = j * w + i;
            m.triangles.push([a, a + 1, a + w + 1]);
            m.triangles.push([a, a + w + 1, a + w]);
        }
    }
    m.triangle_labels = vec![class.id(); m.triangles.len()];
    m
}

/// `patch` with every vertex height perturbed by uniform noise in `±amplitude` (seeded):
/// a scanned-looking floor.
pub fn bumpy_patch(half: f32, step: f32, amplitude: f32, class: SemanticClass, seed: u64) -> LabeledMesh {
    let mut m = patch(half, step, 0.0, class);
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for p in &mut m.positions {
        p.z += rng.random_range(-amplitude..=amplitude);
    }
    m
}

/// A vertical wall in the plane x = `x`, facing -x, spanning y and z in ±`half` around z = half.
pub fn wall(x: f32, half: f32, step: f32) -> LabeledMesh {
    let mut m = patch(half, step, 0.0, SemanticClass::Wall);
    for p in &mut m.positions {
        *p = Vec3::new(x, p.y, p.x + half);
    }
    m
}

/// An axis-aligned closed box (12 triangles, outward faces) labelled `class`.
pub fn cuboid(lo: Vec3, hi: Vec3, class: SemanticClass) -> LabeledMesh {
    let c = |i: u32| {
        Vec3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        )
    };
    let positions: Vec<Vec3> = (0..8).map(c).collect();
    // Faces as quads, counter-clockwise seen from outside.
    let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
    let triangles: Vec<[u32; 3]> = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
    LabeledMesh {
        colors: vec![class.color(); 8],
        positions,
        triangle_labels: vec![class.id(); triangles.len()],
        triangles,
        ..Default::default()
    }
}

/// A small room: a 4 m floor and a table (top 1.2 x 0.8 m at 0.75 m, 4 legs) at the centre.
pub fn room_with_table() -> LabeledMesh {
    let mut m = patch(2.0, 0.1, 0.0, SemanticClass::Floor);
    m.append(&cuboid(Vec3::new(-0.6, -0.4, 0.72), Vec3::new(0.6, 0.4, 0.75), SemanticClass::Table));
    for (x, y) in [(-0.55, -0.35), (0.55, -0.35), (-0.55, 0.35), (0.55, 0.35)] {
        m.append(&cuboid(
            Vec3::new(x - 0.03, y - 0.03, 0.0),
            Vec3::new(x + 0.03, y + 0.03, 0.72),
            SemanticClass::Table,
        ));
    }
    m
}
