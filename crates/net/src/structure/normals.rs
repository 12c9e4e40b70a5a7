//! Voxel normals: the direction of least spread of each voxel's occupied 26-neighbourhood
//! (principal component analysis), with the small symmetric eigen solver that takes it. The
//! normals weigh the edges of the segmentation graph (a crease between two surfaces separates
//! segments) and pick the horizontal voxels among which the floor and ceiling are searched.
//! A normal depends only on which neighbours are occupied, so each distinct pattern is solved
//! once.

use glam::Vec3;
use rayon::prelude::*;
use semrecon_sparse::Coord;

use super::neighbours::{NEIGHBOUR_OFFSETS, NO_NEIGHBOUR};

/// Eigen-decomposition of a symmetric 3x3 matrix by cyclic Jacobi rotations: eigenvalues
/// ascending and the matching unit eigenvectors.
pub fn symmetric_eigen3(a: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let mut m = a;
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _ in 0..32 {
        let off = m[0][1].abs() + m[0][2].abs() + m[1][2].abs();
        let scale = m[0][0].abs() + m[1][1].abs() + m[2][2].abs();
        if off <= 1e-15 * scale.max(1e-300) {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if m[p][q] == 0.0 {
                continue;
            }
            let theta = (m[q][q] - m[p][p]) / (2.0 * m[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            // m <- J^T m J with J the rotation in the (p, q) plane.
            for row in &mut m {
                let (mrp, mrq) = (row[p], row[q]);
                row[p] = c * mrp - s * mrq;
                row[q] = s * mrp + c * mrq;
            }
            let (mp, mq) = (m[p], m[q]);
            m[p] = std::array::from_fn(|r| c * mp[r] - s * mq[r]);
            m[q] = std::array::from_fn(|r| s * mp[r] + c * mq[r]);
            for row in &mut v {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    let mut order = [0usize, 1, 2];
    order.sort_by(|&i, &j| m[i][i].total_cmp(&m[j][j]));
    let values = order.map(|i| m[i][i]);
    let vectors = order.map(|i| [v[0][i], v[1][i], v[2][i]]);
    (values, vectors)
}

/// Unit normal of every voxel: the direction of least spread of the centres of the voxel
/// and its occupied neighbours (principal component analysis), signed with `z >= 0`; zero
/// where fewer than three voxels are around or they lie on a line.
///
/// The normal depends only on which of the 26 neighbours are occupied, and a room's surfaces
/// show few of the 2^26 patterns: each distinct pattern is solved once.
///
/// # Shapes
/// `coords`, `neighbours`: `[n]`; result `[n]` in voxel units (unit length or zero).
pub fn voxel_normals(coords: &[Coord], neighbours: &[[u32; 26]]) -> Vec<Vec3> {
    debug_assert_eq!(coords.len(), neighbours.len());
    let masks: Vec<u32> = neighbours
        .par_iter()
        .map(|nb| nb.iter().enumerate().fold(0u32, |m, (b, &j)| if j == NO_NEIGHBOUR { m } else { m | 1 << b }))
        .collect();
    let mut patterns = masks.clone();
    patterns.par_sort_unstable();
    patterns.dedup();
    let normals: Vec<Vec3> = patterns.par_iter().map(|&m| normal_of_pattern(m)).collect();
    masks.par_iter().map(|m| patterns.binary_search(m).map_or(Vec3::ZERO, |i| normals[i])).collect()
}

/// The PCA normal of a voxel whose occupied neighbours are the set bits of `mask`
/// ([`NEIGHBOUR_OFFSETS`] order).
fn normal_of_pattern(mask: u32) -> Vec3 {
    let mut pts: Vec<[f64; 3]> = Vec::with_capacity(27);
    pts.push([0.0; 3]);
    for (b, o) in NEIGHBOUR_OFFSETS.iter().enumerate() {
        if mask & (1 << b) != 0 {
            pts.push(o.map(f64::from));
        }
    }
    normal_of_points(&pts)
}

/// The PCA normal of a small point set (see [`voxel_normals`]).
fn normal_of_points(pts: &[[f64; 3]]) -> Vec3 {
    if pts.len() < 3 {
        return Vec3::ZERO;
    }
    let inv = 1.0 / pts.len() as f64;
    let mut mean = [0.0; 3];
    for p in pts {
        for a in 0..3 {
            mean[a] += p[a] * inv;
        }
    }
    let mut cov = [[0.0; 3]; 3];
    for p in pts {
        let d = [p[0] - mean[0], p[1] - mean[1], p[2] - mean[2]];
        for a in 0..3 {
            for b in 0..3 {
                cov[a][b] += d[a] * d[b] * inv;
            }
        }
    }
    let (values, vectors) = symmetric_eigen3(cov);
    // A line (two tiny eigenvalues) has no normal.
    if values[1] <= 1e-9 * values[2].max(1e-300) {
        return Vec3::ZERO;
    }
    let v = vectors[0];
    let s = if v[2] < 0.0 { -1.0 } else { 1.0 };
    Vec3::new((v[0] * s) as f32, (v[1] * s) as f32, (v[2] * s) as f32).normalize_or_zero()
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::structure::voxel_neighbours;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    #[allow(clippy::needless_range_loop)]
    fn eigen_matches_the_definition_on_random_matrices() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for _ in 0..500 {
            let mut a = [[0.0f64; 3]; 3];
            for i in 0..3 {
                for j in i..3 {
                    let v = rng.random_range(-2.0..2.0);
                    a[i][j] = v;
                    a[j][i] = v;
                }
            }
            let (values, vectors) = symmetric_eigen3(a);
            assert!(values[0] <= values[1] && values[1] <= values[2]);
            for (lambda, v) in values.iter().zip(vectors) {
                let norm = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                assert!((norm - 1.0).abs() < 1e-9);
                for i in 0..3 {
                    let av: f64 = (0..3).map(|j| a[i][j] * v[j]).sum();
                    assert!((av - lambda * v[i]).abs() < 1e-9, "{a:?}");
                }
            }
            // The smallest eigenvalue is the minimum of the Rayleigh quotient.
            for _ in 0..50 {
                let u = [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0f64)];
                let uu: f64 = u.iter().map(|x| x * x).sum();
                let uau: f64 = (0..3).map(|i| (0..3).map(|j| u[i] * a[i][j] * u[j]).sum::<f64>()).sum();
                assert!(uau / uu >= values[0] - 1e-9);
            }
        }
    }

    #[test]
    fn normals_match_digital_planes() {
        // A tilted digital plane: normals close to the plane's.
        let mut plane = Vec::new();
        for x in -10..10 {
            for y in -10..10 {
                plane.push([x, y, (0.3 * x as f32 + 0.1 * y as f32).round() as i32, 0]);
            }
        }
        let normals = voxel_normals(&plane, &voxel_neighbours(&plane));
        let want = Vec3::new(-0.3, -0.1, 1.0).normalize();
        let inner: Vec<f32> = plane
            .iter()
            .zip(&normals)
            .filter(|(c, _)| c[0].abs() < 8 && c[1].abs() < 8)
            .map(|(_, n)| n.dot(want))
            .collect();
        let mean = inner.iter().sum::<f32>() / inner.len() as f32;
        assert!(mean > 0.97, "{mean}");
        // Horizontal planes give exactly vertical normals.
        let flat: Vec<Coord> = (0..100).map(|i| [i % 10, i / 10, 3, 0]).collect();
        assert!(voxel_normals(&flat, &voxel_neighbours(&flat)).iter().all(|n| (n.z - 1.0).abs() < 1e-6));
    }
}
