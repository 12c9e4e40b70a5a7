//! Dense coloured, labelled point samples of a mesh surface: how a labelled mesh (a synthetic
//! room, a reconstruction) becomes network input. Vertices alone are too sparse on large flat
//! triangles, so points are drawn uniformly over the area at a chosen density (several per
//! voxel), with colours interpolated from the vertices and the label of their triangle.

use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use semrecon_data::class::UNLABELED;
use semrecon_data::{LabeledMesh, LabeledPointCloud};

/// About `points_per_m2` points per square metre of `mesh`'s surface, uniform over the area
/// (per triangle a stochastically rounded count, uniform barycentric positions), seeded.
/// Colours are interpolated from the vertex colours; labels are the triangle's label, else
/// the nearest corner's vertex label, else [`UNLABELED`].
pub fn sample_surface(mesh: &LabeledMesh, points_per_m2: f32, seed: u64) -> LabeledPointCloud {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = LabeledPointCloud::default();
    let density = points_per_m2.max(0.0);
    let n_vertices = mesh.positions.len();
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if tri.iter().any(|&i| i as usize >= n_vertices) {
            continue;
        }
        let [a, b, c] = tri.map(|i| mesh.positions[i as usize]);
        let area = 0.5 * (b - a).cross(c - a).length();
        let expected = area * density;
        let mut count = expected.floor() as usize;
        if rng.random::<f32>() < expected - expected.floor() {
            count += 1;
        }
        let col = tri.map(|i| {
            mesh.colors.get(i as usize).map_or(Vec3::splat(128.0), |c| Vec3::new(c[0].into(), c[1].into(), c[2].into()))
        });
        for _ in 0..count {
            let (mut u, mut v): (f32, f32) = (rng.random(), rng.random());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            let w = 1.0 - u - v;
            out.positions.push(a * w + b * u + c * v);
            let rgb = col[0] * w + col[1] * u + col[2] * v;
            out.colors.push(rgb.to_array().map(|x| x.round().clamp(0.0, 255.0) as u8));
            let label = mesh.triangle_labels.get(t).copied().unwrap_or_else(|| {
                let corner = if w >= u && w >= v {
                    0
                } else if u >= v {
                    1
                } else {
                    2
                };
                mesh.vertex_labels.get(tri[corner] as usize).copied().unwrap_or(UNLABELED)
            });
            out.labels.push(label);
        }
    }
    out
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn density_colours_and_labels() {
        let mesh = LabeledMesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::new(1.0, 1.0, 0.0)],
            colors: vec![[0, 0, 0], [200, 0, 0], [0, 200, 0], [200, 200, 0]],
            triangles: vec![[0, 1, 2], [1, 3, 2]],
            triangle_labels: vec![1, 2],
            ..Default::default()
        };
        let pc = sample_surface(&mesh, 10_000.0, 1);
        assert!((pc.len() as i64 - 10_000).abs() < 200, "{}", pc.len());
        pc.validate().unwrap();
        for ((p, c), &l) in pc.positions.iter().zip(&pc.colors).zip(&pc.labels) {
            assert!(p.x >= -1e-6 && p.y >= -1e-6 && p.x <= 1.0 + 1e-6 && p.z == 0.0);
            // Colour is linear in position: red = 200 x, green = 200 y.
            assert!((f32::from(c[0]) - 200.0 * p.x).abs() <= 1.0);
            assert!((f32::from(c[1]) - 200.0 * p.y).abs() <= 1.0);
            assert_eq!(l, if p.x + p.y <= 1.0 { 1 } else { 2 }, "{p}");
        }
        assert_eq!(pc, sample_surface(&mesh, 10_000.0, 1));
    }
}
