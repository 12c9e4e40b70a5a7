//! Point clouds for `semrecon snapshot`: every point is drawn as a small disc (a surfel) in a
//! z-buffer.
//!
//! - **Size from the spacing.** A point's disc radius is 0.75 times the mean distance to its
//!   8 nearest neighbours (clamped to 0.5-3 times the cloud's median), so that discs overlap
//!   into a closed surface where the points are sparse (the vertices of a decimated mesh lie
//!   far apart on flat walls) and stay small where they are dense.
//! - **Oriented by the normal.** The file's normals, or else the least-spread direction of
//!   the 12 nearest neighbours, signed towards the middle of the cloud (a room is scanned from
//!   inside). A disc lies in its tangent plane: each pixel intersects its ray with that plane
//!   (exact depth, discs at grazing angles become thin ellipses) and is shaded by the angle
//!   to the viewing ray, as meshes are. Points without a usable normal are flat,
//!   screen-facing discs.
//! - **A doll's house.** Meshes lose the faces turned away from the camera, which opens the
//!   room. A point cloud's estimated normals are only signed by a guess, so only the wall-like
//!   points (normals near horizontal) in a band along the two sides of the bounding box that
//!   face the camera, turned away from it, are dropped: the near walls.
//! - **Smooth edges.** The image is drawn at twice the size and averaged down 2x2.
//!
//! Deterministic: neighbour searches run in parallel per point, the discs one after another
//! in point order.

use glam::{Affine3A, Vec3};
use rayon::prelude::*;
use semrecon_data::{Intrinsics, LabeledMesh};
use semrecon_net::structure::symmetric_eigen3;
use std::collections::HashMap;

/// Neighbours for the disc size.
const SIZE_NEIGHBOURS: usize = 8;
/// Neighbours for the normal estimate.
const NORMAL_NEIGHBOURS: usize = 12;

/// Indices of the `k` nearest other points of every point (fewer where the cloud has fewer
/// points within three cells), nearest first, ties by index, with their distances.
///
/// # Shapes
/// Result `[n]`, each at most `k` long.
pub fn nearest_neighbours(points: &[Vec3], k: usize) -> Vec<Vec<(f32, u32)>> {
    let n = points.len();
    if n == 0 || k == 0 {
        return vec![Vec::new(); n];
    }
    let (lo, hi) = points.iter().fold((points[0], points[0]), |(lo, hi), &p| (lo.min(p), hi.max(p)));
    // A few points per cell on a surface: the largest face of the bounding box over n is
    // roughly the area per point of a surface as big as that face, three times its spacing a
    // cell (most searches end after the first ring).
    let extent = hi - lo;
    let faces = [extent.x * extent.y, extent.y * extent.z, extent.x * extent.z];
    let area = faces.iter().copied().fold(0.0f32, f32::max).max(1e-12);
    let cell = ((area / n as f32).sqrt() * 3.0).max(1e-6);
    let key = |p: Vec3| {
        let q = ((p - lo) / cell).floor();
        (q.x as i32, q.y as i32, q.z as i32)
    };
    let mut order: Vec<u32> = (0..n as u32).collect();
    order.sort_by_key(|&i| (key(points[i as usize]), i));
    let mut cells: HashMap<(i32, i32, i32), (usize, usize)> = HashMap::new();
    let mut start = 0;
    for i in 1..=n {
        if i == n || key(points[order[i] as usize]) != key(points[order[start] as usize]) {
            cells.insert(key(points[order[start] as usize]), (start, i));
            start = i;
        }
    }
    const MAX_RING: i32 = 3;
    (0..n)
        .into_par_iter()
        .map(|i| {
            let p = points[i];
            let (cx, cy, cz) = key(p);
            let mut best: Vec<(f32, u32)> = Vec::with_capacity(k + 1);
            for ring in 0..=MAX_RING {
                for dz in -ring..=ring {
                    for dy in -ring..=ring {
                        for dx in -ring..=ring {
                            if dx.abs().max(dy.abs()).max(dz.abs()) != ring {
                                continue;
                            }
                            let Some(&(a, b)) = cells.get(&(cx + dx, cy + dy, cz + dz)) else { continue };
                            for &j in &order[a..b] {
                                if j as usize == i {
                                    continue;
                                }
                                let d = points[j as usize].distance(p);
                                let worse = |e: &(f32, u32)| e.0.total_cmp(&d).then(e.1.cmp(&j)).is_gt();
                                if best.len() < k || best.last().is_some_and(worse) {
                                    let at = best.partition_point(|e| !worse(e));
                                    best.insert(at, (d, j));
                                    best.truncate(k);
                                }
                            }
                        }
                    }
                }
                // Every point not yet seen is more than `ring * cell` away.
                if best.len() == k && best[k - 1].0 <= ring as f32 * cell {
                    break;
                }
            }
            best
        })
        .collect()
}

/// Unit normal of a point from its neighbours (least-spread direction), or zero.
fn pca_normal(p: Vec3, neighbours: &[(f32, u32)], points: &[Vec3]) -> Vec3 {
    if neighbours.len() < 3 {
        return Vec3::ZERO;
    }
    let pts: Vec<Vec3> = std::iter::once(p).chain(neighbours.iter().map(|&(_, j)| points[j as usize])).collect();
    let mean = pts.iter().copied().sum::<Vec3>() / pts.len() as f32;
    let mut cov = [[0.0f64; 3]; 3];
    for q in &pts {
        let d = (*q - mean).to_array().map(f64::from);
        for a in 0..3 {
            for b in 0..3 {
                cov[a][b] += d[a] * d[b];
            }
        }
    }
    let (values, vectors) = symmetric_eigen3(cov);
    if values[1] <= 1e-9 * values[2].max(1e-300) {
        return Vec3::ZERO;
    }
    Vec3::new(vectors[0][0] as f32, vectors[0][1] as f32, vectors[0][2] as f32).normalize_or_zero()
}

/// Disc radius (metres) and normal (unit, signed towards the middle of the cloud, or zero)
/// of every point; the mesh's own normals where it has them.
pub fn point_discs(mesh: &LabeledMesh) -> (Vec<f32>, Vec<Vec3>) {
    let points = &mesh.positions;
    let k = SIZE_NEIGHBOURS.max(NORMAL_NEIGHBOURS);
    let near = nearest_neighbours(points, k);
    let raw: Vec<f32> = near
        .iter()
        .map(|nb| {
            let m = nb.len().min(SIZE_NEIGHBOURS);
            if m == 0 {
                0.0
            } else {
                0.75 * nb[..m].iter().map(|e| e.0).sum::<f32>() / m as f32
            }
        })
        .collect();
    let mut sorted: Vec<f32> = raw.iter().copied().filter(|&r| r > 0.0).collect();
    sorted.sort_by(f32::total_cmp);
    let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.01);
    let radius = raw.iter().map(|&r| if r > 0.0 { r.clamp(0.5 * median, 3.0 * median) } else { median }).collect();
    let normals = if mesh.normals.len() == points.len() {
        mesh.normals.iter().map(|n| n.normalize_or_zero()).collect()
    } else {
        let (lo, hi) = mesh.bounds().unwrap_or_default();
        let middle = (lo + hi) * 0.5;
        points
            .par_iter()
            .zip(&near)
            .map(|(&p, nb)| {
                let n = pca_normal(p, &nb[..nb.len().min(NORMAL_NEIGHBOURS)], points);
                if n.dot(middle - p) < 0.0 {
                    -n
                } else {
                    n
                }
            })
            .collect()
    };
    (radius, normals)
}

/// Which points to draw: not above `cut_above`, and not one of the near walls (wall-like
/// points within a band of the bounding box's sides that face `eye`, turned away from it).
pub fn visible_points(mesh: &LabeledMesh, normals: &[Vec3], eye: Vec3, cut_above: Option<f32>) -> Vec<bool> {
    let Some((lo, hi)) = mesh.bounds() else { return Vec::new() };
    let middle = (lo + hi) * 0.5;
    let extent = hi - lo;
    let band = |e: f32| (0.08 * e).max(0.35);
    mesh.positions
        .iter()
        .zip(normals)
        .map(|(&p, &n)| {
            if cut_above.is_some_and(|z| p.z > z) {
                return false;
            }
            if n == Vec3::ZERO || n.z.abs() > 0.3 || n.dot(eye - p) >= 0.0 {
                return true;
            }
            let near_side = |axis: usize| {
                let (e, m, q, nn) = (eye[axis], middle[axis], p[axis], n[axis]);
                let side_dist = if e < m { q - lo[axis] } else { hi[axis] - q };
                (e < lo[axis] || e > hi[axis]) && side_dist < band(extent[axis]) && nn.abs() > 0.7
            };
            !(near_side(0) || near_side(1))
        })
        .collect()
}

/// The intrinsics `k` zoomed and shifted so that the points to draw fill `fill` of the
/// image (their centres' bounding box, centred): a point cloud's bounding box holds the cut
/// ceiling and stray points, and framing it alone leaves the room small.
pub fn fit_to_points(
    mesh: &LabeledMesh,
    keep: &[bool],
    world_from_camera: Affine3A,
    k: Intrinsics,
    fill: f32,
) -> Intrinsics {
    let camera_from_world = world_from_camera.inverse();
    let (mut lo, mut hi) = (glam::Vec2::splat(f32::INFINITY), glam::Vec2::splat(f32::NEG_INFINITY));
    for (p, _) in mesh.positions.iter().zip(keep).filter(|(_, &k)| k) {
        let q = camera_from_world.transform_point3(*p);
        if q.z > 0.05 {
            let uv = glam::Vec2::new(q.x / q.z, q.y / q.z);
            lo = lo.min(uv);
            hi = hi.max(uv);
        }
    }
    let size = hi - lo;
    if !(size.x > 0.0 && size.y > 0.0 && size.is_finite()) {
        return k;
    }
    let f = (fill * k.width as f32 / size.x).min(fill * k.height as f32 / size.y);
    let mid = (lo + hi) * 0.5;
    let mut out = k;
    out.fx = f;
    out.fy = f;
    out.cx = (k.width as f32 - 1.0) / 2.0 - f * mid.x;
    out.cy = (k.height as f32 - 1.0) / 2.0 - f * mid.y;
    out
}

/// Draws the points of `mesh` whose `keep` is set as discs seen from `world_from_camera`
/// with intrinsics `k`: per pixel the colour (shaded by the angle to the ray; white where
/// nothing is) of the nearest disc.
///
/// # Shapes
/// `colors`, `radius`, `normals`, `keep`: one per point; result `[k.height * k.width]`.
pub fn render_points(
    mesh: &LabeledMesh,
    radius: &[f32],
    normals: &[Vec3],
    keep: &[bool],
    world_from_camera: Affine3A,
    k: Intrinsics,
) -> Vec<[u8; 3]> {
    // Twice the size, averaged down at the end.
    let (w, h) = (k.width as usize * 2, k.height as usize * 2);
    let (fx, fy, cx, cy) = (k.fx * 2.0, k.fy * 2.0, k.cx * 2.0 + 0.5, k.cy * 2.0 + 0.5);
    let camera_from_world = world_from_camera.inverse();
    let mut depth = vec![f32::INFINITY; w * h];
    let mut color = vec![[255.0f32; 3]; w * h];
    const NEAR: f32 = 0.05;
    for i in 0..mesh.positions.len() {
        if !keep[i] {
            continue;
        }
        let p = camera_from_world.transform_point3(mesh.positions[i]);
        let r = radius[i];
        if p.z <= NEAR + r {
            continue;
        }
        let n = camera_from_world.transform_vector3(normals[i]);
        let (u, v) = (fx * p.x / p.z + cx, fy * p.y / p.z + cy);
        // A bound of the disc's image (at least one pixel), and the screen disc for points
        // without a normal.
        let reach = (fx * r / (p.z - r)).clamp(0.75, 96.0);
        let flat = (fx * r / p.z).max(0.75);
        let (x0, x1) = ((u - reach).floor().max(0.0) as i64, (u + reach).ceil().min(w as f32 - 1.0) as i64);
        let (y0, y1) = ((v - reach).floor().max(0.0) as i64, (v + reach).ceil().min(h as f32 - 1.0) as i64);
        if x0 > x1 || y0 > y1 {
            continue;
        }
        let c = mesh.colors[i].map(f32::from);
        for y in y0..=y1 {
            for x in x0..=x1 {
                let ray = Vec3::new((x as f32 + 0.5 - cx) / fx, (y as f32 + 0.5 - cy) / fy, 1.0);
                let (z, incidence) = if n == Vec3::ZERO {
                    let (du, dv) = (x as f32 + 0.5 - u, y as f32 + 0.5 - v);
                    if du * du + dv * dv > flat * flat {
                        continue;
                    }
                    (p.z, 0.8)
                } else {
                    let denom = n.dot(ray);
                    if denom.abs() < 1e-6 {
                        continue;
                    }
                    let t = n.dot(p) / denom;
                    if t <= NEAR || (ray * t).distance_squared(p) > r * r {
                        continue;
                    }
                    (t, denom.abs() / ray.length())
                };
                let at = y as usize * w + x as usize;
                if z < depth[at] {
                    depth[at] = z;
                    let shade = 0.35 + 0.65 * incidence;
                    color[at] = c.map(|v| v * shade);
                }
            }
        }
    }
    let (ow, oh) = (k.width as usize, k.height as usize);
    (0..ow * oh)
        .map(|o| {
            let (x, y) = (o % ow * 2, o / ow * 2);
            let mut sum = [0.0f32; 3];
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let c = color[(y + dy) * w + x + dx];
                for ch in 0..3 {
                    sum[ch] += c[ch];
                }
            }
            sum.map(|s| (s / 4.0).round().clamp(0.0, 255.0) as u8)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_neighbours_match_brute_force() {
        // A deterministic jumble: a noisy grid plane, a line and a few outliers.
        let mut points = Vec::new();
        for i in 0..400u32 {
            let h = i.wrapping_mul(2_654_435_761);
            let jitter = |s: u32| ((h >> s) & 255) as f32 / 255.0 * 0.01;
            points.push(Vec3::new((i % 20) as f32 * 0.02 + jitter(0), (i / 20) as f32 * 0.02 + jitter(8), jitter(16)));
        }
        points.extend((0..30).map(|i| Vec3::new(1.0, 0.0, i as f32 * 0.05)));
        points.extend([Vec3::splat(5.0), Vec3::new(-3.0, 2.0, 1.0)]);
        let got = nearest_neighbours(&points, 8);
        for (i, p) in points.iter().enumerate() {
            let mut all: Vec<(f32, u32)> =
                points.iter().enumerate().filter(|&(j, _)| j != i).map(|(j, q)| (q.distance(*p), j as u32)).collect();
            all.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            // Far outliers may find fewer than 8 within the search rings; whatever is found
            // is the true nearest.
            let m = got[i].len();
            assert!(m == 8 || p.x > 2.0 || p.x < -1.0, "point {i}: {m} neighbours");
            assert_eq!(got[i], all[..m].to_vec(), "point {i}");
        }
    }
}
