//! The up direction of the map, and the gravity-aligned frame the network sees.
//!
//! The SLAM map frame is whatever the first camera's frame (or the dataset's world frame) was;
//! the network was trained on rooms with z up and the floor at z = 0. Up is estimated from the
//! map itself: indoor scenes are full of horizontal planes (floor, table tops, seats, ceiling),
//! so the surface normals that lie near the camera's average "up" (-y of the camera; people
//! hold cameras roughly upright) are averaged, in narrowing cones, to the dominant horizontal
//! direction. The floor is then the lowest height band that holds a large share of the upward
//! facing surface below the cameras (a handheld camera is carried above the floor, so table
//! tops and shelves seen before the floor are not taken for it; with no such surface yet the
//! floor is put [`HANDHELD_HEIGHT_M`] below the lowest camera). A known gravity direction (an IMU, a dataset's gravity file) replaces the
//! estimate.
//!
//! Only the network's input is rotated: the map, the mesh and every output stay in the map
//! frame.

use glam::{Affine3A, Mat3, Vec3};

/// Where an up direction came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum UpSource {
    /// Given by the caller (gravity sensor, dataset file).
    Given,
    /// The dominant horizontal planes of the map.
    Planes,
    /// The cameras' average up alone (too few horizontal surfaces yet).
    CameraPrior,
    /// Perpendicular to the walls: the horizontal surfaces were too few to trust, and the
    /// vertical ones face at least two different ways.
    Walls,
}

/// One surface sample for the estimate: a position, a unit normal (or zero) and a weight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceSample {
    /// Position, metres, map frame.
    pub position: Vec3,
    /// Unit normal or zero.
    pub normal: Vec3,
    /// Weight (for instance the number of fine voxels the sample stands for).
    pub weight: f32,
}

/// The gravity-aligned frame of a map.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UpEstimate {
    /// Unit up direction in the map frame.
    pub up: Vec3,
    /// Height of the floor along `up`, metres (map frame origin at 0).
    pub floor_height: f32,
    /// Where `up` came from.
    pub source: UpSource,
    /// Share of the surface weight that is horizontal (within 15 degrees of `up`).
    pub horizontal_share: f32,
}

impl UpEstimate {
    /// `aligned_from_map`: rotates `up` onto +z and moves the floor to z = 0; x is the map's
    /// x axis (or y, when x is nearly vertical) made horizontal.
    pub fn aligned_from_map(&self) -> Affine3A {
        let z = self.up.normalize_or(Vec3::Z);
        let seed = if z.dot(Vec3::X).abs() < 0.9 { Vec3::X } else { Vec3::Y };
        let x = (seed - z * seed.dot(z)).normalize();
        let y = z.cross(x);
        // Rows x, y, z: the map-frame axes of the aligned frame.
        let rotation = Mat3::from_cols(x, y, z).transpose();
        Affine3A::from_mat3_translation(rotation, Vec3::new(0.0, 0.0, -self.floor_height))
    }

    /// Angle between this estimate's up and `other`, degrees.
    pub fn angle_to_deg(&self, other: Vec3) -> f32 {
        self.up.dot(other.normalize_or_zero()).clamp(-1.0, 1.0).acos().to_degrees()
    }
}

/// The up direction the cameras suggest (map frame); `None` when there is no pose or they
/// cancel out.
///
/// A handheld camera barely rolls, so its x axis stays (nearly) horizontal however it is
/// pitched: once the cameras have panned, up is the direction most orthogonal to all their
/// x axes (the smallest eigenvector of their scatter), signed like the cameras' average -y.
/// The average -y alone leans towards wherever the cameras looked: a scan spent looking
/// 40 degrees down at tables tilts it 40 degrees, beyond the horizontal-plane search's
/// first cone. Without panning (x axes spread over less than about 10 degrees) the x axes
/// leave up undetermined and the average -y is the prior.
pub fn camera_up_prior(poses: &[Affine3A]) -> Option<Vec3> {
    let minus_y = poses.iter().map(|p| -p.transform_vector3(Vec3::Y)).sum::<Vec3>().try_normalize()?;
    let mut scatter = nalgebra::Matrix3::<f64>::zeros();
    for p in poses {
        let x = p.transform_vector3(Vec3::X).as_dvec3();
        let x = nalgebra::Vector3::new(x.x, x.y, x.z);
        scatter += x * x.transpose();
    }
    let eigen = scatter.symmetric_eigen();
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
    let (smallest, middle) = (eigen.eigenvalues[order[0]], eigen.eigenvalues[order[1]]);
    // The middle eigenvalue is the x axes' spread across their mean: sin^2 of about 10
    // degrees per pose at least, and clearly more than the roll left in the smallest.
    let panned = middle > 0.03 * poses.len() as f64 && smallest < 0.2 * middle;
    if !panned {
        return Some(minus_y);
    }
    let v = eigen.eigenvectors.column(order[0]);
    let up = Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32).try_normalize()?;
    Some(if up.dot(minus_y) < 0.0 { -up } else { up })
}

/// Usual height of a handheld camera above the floor, metres.
pub const HANDHELD_HEIGHT_M: f32 = 1.4;

/// Estimates up and the floor from surface samples, starting from `prior` (the cameras'
/// average up); `cameras` are the camera positions (map frame). Falls back to the prior when
/// less than 3 % of the surface weight is horizontal.
pub fn estimate_up(samples: &[SurfaceSample], prior: Vec3, cameras: &[Vec3]) -> UpEstimate {
    let first = estimate_up_from_cone(samples, prior, cameras, 35.0);
    if first.source == UpSource::Planes && first.horizontal_share >= WIDE_CONE_MIN_SHARE {
        return first;
    }
    // A camera that looks 35-40 degrees down without panning much puts its prior just beyond
    // the first cone: a live scan of generated room 3 lost its floor half-way (0.2 degrees
    // off, then the prior's 39, every label wrong). A wider first cone is the second try.
    // Taken only when a good share of the surface is then horizontal (half of it in that
    // scan): a few per cent is sloped or scattered surface the wider cone also lets in (demo
    // seed 16: 3 % at 17 degrees off, against 4.5 from the prior, and 94.8 -> 48.4 % mIoU).
    if first.source != UpSource::Planes {
        let wide = estimate_up_from_cone(samples, prior, cameras, 50.0);
        if wide.source == UpSource::Planes && wide.horizontal_share >= WIDE_CONE_MIN_SHARE {
            return wide;
        }
    }
    // Little horizontal surface: a camera that has looked at walls and furniture sides
    // from above, its prior pitched with it. Demo seed 16 (a column and a door, 3-4 % of
    // the surface horizontal) had its up 17 degrees off from the prior and from the few
    // sloped surfaces alike, and its labels collapsed (94.8 -> 32 % mIoU) whenever the
    // last pass took either. Walls, which such views are full of, are perpendicular to up:
    // when they face two different ways they pin it (docs/model.md, "Up from the walls").
    // Their normals are noisier than a floor's (furniture sides, slanted backs), so they
    // overrule the estimate only where they disagree with it: demo seed 36's first passes
    // found up 0.2 degrees off from 5-13 % of horizontal surface, and the walls' 0.5-2.4
    // cost it 9 points of mIoU.
    match walls_up(samples, first.up) {
        Some(up) if up.dot(first.up) < WALLS_OVERRULE_DEG.to_radians().cos() => {
            estimate_for(samples, up, cameras, UpSource::Walls)
        }
        _ => first,
    }
}

/// How far the walls' up must lie from the estimate of the scarce horizontal surfaces (or
/// the cameras' prior) to replace it, degrees.
const WALLS_OVERRULE_DEG: f32 = 5.0;

/// Up as the direction perpendicular to the walls, refined from `start`: the least
/// eigenvector of the scatter of the normals within [`WALL_BAND_DEG`] of horizontal, re-chosen
/// three times; `None` when those normals hold less than half the surface weight, do not face
/// two clearly different ways (a single wall leaves up free within its plane), or lead more
/// than [`WALL_BAND_DEG`] away from `start`.
fn walls_up(samples: &[SurfaceSample], start: Vec3) -> Option<Vec3> {
    let total: f32 = samples.iter().map(|s| s.weight).sum();
    let band = WALL_BAND_DEG.to_radians().sin();
    let mut up = start.try_normalize()?;
    for _ in 0..3 {
        let mut scatter = nalgebra::Matrix3::<f64>::zeros();
        let mut weight = 0.0f32;
        for s in samples.iter().filter(|s| s.normal.dot(up).abs() <= band) {
            let n = s.normal.as_dvec3();
            let n = nalgebra::Vector3::new(n.x, n.y, n.z);
            scatter += n * n.transpose() * f64::from(s.weight);
            weight += s.weight;
        }
        if !(weight >= 0.5 * total && weight > 0.0) {
            return None;
        }
        let eigen = scatter.symmetric_eigen();
        let mut order = [0usize, 1, 2];
        order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
        let [least, middle, most] = order.map(|i| eigen.eigenvalues[i]);
        // Two ways faced: the middle spread is a real share of the largest; a clear null
        // direction: the least is small beside the middle.
        if !(middle >= 0.1 * most && least <= 0.05 * middle) {
            return None;
        }
        let v = eigen.eigenvectors.column(order[0]);
        let next = Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32).try_normalize()?;
        up = if next.dot(start) < 0.0 { -next } else { next };
    }
    (up.dot(start.normalize()) >= WALL_BAND_DEG.to_radians().cos()).then_some(up)
}

/// How far from horizontal a normal may lean and still count as a wall's, degrees; also the
/// most the walls' up may lie from the estimate it refines.
const WALL_BAND_DEG: f32 = 25.0;

/// Smallest horizontal share of the surface for [`estimate_up`]'s wider second try.
const WIDE_CONE_MIN_SHARE: f32 = 0.15;

/// [`estimate_up`] with its first cone `first_cone_deg` wide.
fn estimate_up_from_cone(samples: &[SurfaceSample], prior: Vec3, cameras: &[Vec3], first_cone_deg: f32) -> UpEstimate {
    let prior = prior.normalize_or(Vec3::Z);
    let total: f32 = samples.iter().map(|s| s.weight).sum();
    let mut up = prior;
    let mut planes = false;
    // Cones of 35 (or the given first), 20 and 10 degrees: the first catches a tilted prior,
    // the last rejects sloped surfaces from the average.
    for cone_deg in [first_cone_deg, 20.0, 10.0] {
        let cos = cone_deg.to_radians().cos();
        let (mut acc, mut w) = (Vec3::ZERO, 0.0f32);
        for s in samples {
            let d = s.normal.dot(up);
            if d.abs() >= cos {
                acc += s.normal * d.signum() * s.weight;
                w += s.weight;
            }
        }
        if w <= 0.03 * total || w <= 0.0 {
            break;
        }
        if let Some(u) = acc.try_normalize() {
            up = u;
            planes = true;
        }
    }
    if up.dot(prior) < 0.0 {
        up = -up;
    }
    let cos15 = 15f32.to_radians().cos();
    let horizontal: f32 = samples.iter().filter(|s| s.normal.dot(up).abs() >= cos15).map(|s| s.weight).sum();
    let horizontal_share = if total > 0.0 { horizontal / total } else { 0.0 };
    if horizontal_share < 0.03 {
        up = prior;
        planes = false;
    }
    UpEstimate {
        up,
        floor_height: floor_height(samples, up, cameras),
        source: if planes { UpSource::Planes } else { UpSource::CameraPrior },
        horizontal_share,
    }
}

/// The estimate for a known up direction: only the floor is looked for.
pub fn given_up(samples: &[SurfaceSample], up: Vec3, cameras: &[Vec3]) -> UpEstimate {
    estimate_for(samples, up.normalize_or(Vec3::Z), cameras, UpSource::Given)
}

/// The estimate for the unit direction `up` from `source`: the floor under it and the share
/// of the surface that is horizontal (within 15 degrees).
fn estimate_for(samples: &[SurfaceSample], up: Vec3, cameras: &[Vec3], source: UpSource) -> UpEstimate {
    let cos15 = 15f32.to_radians().cos();
    let total: f32 = samples.iter().map(|s| s.weight).sum();
    let horizontal: f32 = samples.iter().filter(|s| s.normal.dot(up).abs() >= cos15).map(|s| s.weight).sum();
    UpEstimate {
        up,
        floor_height: floor_height(samples, up, cameras),
        source,
        horizontal_share: if total > 0.0 { horizontal / total } else { 0.0 },
    }
}

/// Up of a finished mesh, for maps without a semantic pass (which estimates it from the map
/// as it grows): the same estimate over at most [`MESH_UP_SAMPLES`] of its vertices with a
/// normal, evenly spread, from the cameras' prior (`poses`, the trajectory). `None` without a
/// camera pose or a vertex normal.
pub fn mesh_up(positions: &[Vec3], normals: &[Vec3], poses: &[Affine3A]) -> Option<UpEstimate> {
    let prior = camera_up_prior(poses)?;
    if normals.len() != positions.len() || positions.is_empty() {
        return None;
    }
    let step = positions.len().div_ceil(MESH_UP_SAMPLES).max(1);
    let samples: Vec<SurfaceSample> = positions
        .iter()
        .zip(normals)
        .step_by(step)
        .filter(|(_, n)| n.is_finite() && n.length_squared() > 0.5)
        .map(|(&position, &normal)| SurfaceSample { position, normal, weight: 1.0 })
        .collect();
    let cameras: Vec<Vec3> = poses.iter().map(|p| Vec3::from(p.translation)).collect();
    Some(estimate_up(&samples, prior, &cameras))
}

/// Most vertices [`mesh_up`] reads: the horizontal planes of a room are millions of vertices,
/// and their average direction is settled long before.
pub const MESH_UP_SAMPLES: usize = 200_000;

/// Height band of 5 cm.
const FLOOR_BIN_M: f32 = 0.05;

/// The lowest 5 cm band of upward-facing surface at least 0.3 m below the lowest camera
/// holding a quarter of the weight of the fullest such band; without one,
/// [`HANDHELD_HEIGHT_M`] below the lowest camera, or the lowest sample when there is no
/// camera; 0 without either.
fn floor_height(samples: &[SurfaceSample], up: Vec3, cameras: &[Vec3]) -> f32 {
    let cos15 = 15f32.to_radians().cos();
    let lowest_camera = cameras.iter().map(|c| c.dot(up)).reduce(f32::min);
    let ceiling = lowest_camera.map_or(f32::INFINITY, |c| c - 0.3);
    let heights: Vec<(f32, f32)> = samples
        .iter()
        .filter(|s| s.normal.dot(up) >= cos15 && s.position.dot(up) < ceiling)
        .map(|s| (s.position.dot(up), s.weight))
        .collect();
    if heights.is_empty() {
        if let Some(c) = lowest_camera {
            return c - HANDHELD_HEIGHT_M;
        }
        return samples.iter().map(|s| s.position.dot(up)).reduce(f32::min).unwrap_or(0.0);
    }
    let lo = heights.iter().map(|h| h.0).fold(f32::INFINITY, f32::min);
    let bins = (((heights.iter().map(|h| h.0).fold(f32::NEG_INFINITY, f32::max) - lo) / FLOOR_BIN_M) as usize + 1)
        .min(100_000);
    let mut hist = vec![0f32; bins];
    for (h, w) in &heights {
        hist[(((h - lo) / FLOOR_BIN_M) as usize).min(bins - 1)] += w;
    }
    let peak = hist.iter().copied().fold(0.0, f32::max);
    let bin = hist.iter().position(|&w| w >= 0.25 * peak).unwrap_or(0);
    // Mean height of the band.
    let (mut sum, mut w) = (0.0f32, 0.0f32);
    for (h, wt) in &heights {
        if (((h - lo) / FLOOR_BIN_M) as usize).min(bins - 1) == bin {
            sum += h * wt;
            w += wt;
        }
    }
    if w > 0.0 {
        sum / w
    } else {
        lo
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A box room (floor at z = 0, ceiling at 2.5 m, four walls) with a table top at 0.7 m,
    /// sampled on a 10 cm grid, in a frame rotated by `map_from_world`.
    fn room(map_from_world: Affine3A) -> Vec<SurfaceSample> {
        let mut s = Vec::new();
        let mut push = |p: Vec3, n: Vec3| {
            s.push(SurfaceSample {
                position: map_from_world.transform_point3(p),
                normal: map_from_world.transform_vector3(n),
                weight: 1.0,
            })
        };
        for i in 0..40 {
            for j in 0..40 {
                let (a, b) = (i as f32 * 0.1, j as f32 * 0.1);
                push(Vec3::new(a, b, 0.0), Vec3::Z);
                push(Vec3::new(a, b, 2.5), -Vec3::Z);
                if j < 25 {
                    push(Vec3::new(a, 0.0, b), Vec3::Y);
                    push(Vec3::new(0.0, a, b), Vec3::X);
                }
                if i < 10 && j < 8 {
                    push(Vec3::new(1.0 + a, 1.0 + b, 0.7), Vec3::Z);
                }
            }
        }
        s
    }

    #[test]
    fn up_and_floor_are_found_in_a_tilted_frame() {
        // A camera-like frame: pitched 25 degrees, rolled 8, and moved.
        let map_from_world = Affine3A::from_rotation_translation(
            glam::Quat::from_rotation_x(-(90f32 + 25.0).to_radians()) * glam::Quat::from_rotation_y(0.14),
            Vec3::new(0.3, -1.2, 2.0),
        );
        let samples = room(map_from_world);
        let true_up = map_from_world.transform_vector3(Vec3::Z);
        // A prior 20 degrees off.
        let prior = glam::Quat::from_rotation_x(0.35) * true_up;
        let e = estimate_up(&samples, prior, &[map_from_world.transform_point3(Vec3::new(2.0, 2.0, 1.5))]);
        assert_eq!(e.source, UpSource::Planes);
        assert!(e.angle_to_deg(true_up) < 0.5, "{} deg", e.angle_to_deg(true_up));
        // The floor maps to z = 0 and the table top to 0.7 m.
        let aligned = e.aligned_from_map() * map_from_world;
        assert!(aligned.transform_point3(Vec3::new(2.0, 2.0, 0.0)).z.abs() < 0.01);
        assert!((aligned.transform_point3(Vec3::new(1.2, 1.2, 0.7)).z - 0.7).abs() < 0.01);
        assert!((aligned.transform_vector3(Vec3::Z) - Vec3::Z).length() < 0.01);
    }

    #[test]
    fn without_horizontal_surfaces_the_prior_stays() {
        let samples: Vec<SurfaceSample> = (0..100)
            .map(|i| SurfaceSample { position: Vec3::new(i as f32 * 0.1, 0.0, 0.0), normal: Vec3::Y, weight: 1.0 })
            .collect();
        let e = estimate_up(&samples, Vec3::Z, &[]);
        assert_eq!((e.up, e.source), (Vec3::Z, UpSource::CameraPrior));
        let g = given_up(&samples, Vec3::new(0.0, 0.0, 2.0), &[]);
        assert_eq!((g.up, g.source), (Vec3::Z, UpSource::Given));
    }

    #[test]
    fn camera_prior_is_minus_camera_y() {
        // Camera looking along +x of a z-up world: camera y (down) is -z.
        let pose = Affine3A::from_mat3(Mat3::from_cols(-Vec3::Y, -Vec3::Z, Vec3::X));
        assert!((camera_up_prior(&[pose]).expect("one pose") - Vec3::Z).length() < 1e-6);
        assert_eq!(camera_up_prior(&[]), None);
    }

    /// World z up; a camera at yaw `yaw`, pitched `pitch` below the horizon, rolled `roll`
    /// (radians), all in a map frame rotated by `map_from_world`.
    fn handheld(map_from_world: glam::Quat, yaw: f32, pitch: f32, roll: f32) -> Affine3A {
        let level = Mat3::from_cols(-Vec3::Y, -Vec3::Z, Vec3::X); // looking along +x
        let r = glam::Quat::from_rotation_z(yaw) * glam::Quat::from_rotation_y(pitch);
        let r = Mat3::from_quat(map_from_world * r) * level * Mat3::from_rotation_z(roll);
        Affine3A::from_mat3(r)
    }

    #[test]
    fn panning_cameras_give_up_however_far_down_they_look() {
        let map_from_world = glam::Quat::from_rotation_x(-1.9) * glam::Quat::from_rotation_z(0.4);
        let true_up = map_from_world * Vec3::Z;
        // Looking 40 degrees down while panning over 70 degrees, with a little roll.
        let poses: Vec<Affine3A> = (0..60)
            .map(|i| {
                let u = i as f32 / 59.0;
                handheld(map_from_world, (u * 70.0).to_radians(), 40f32.to_radians(), 0.03 * (u * 9.0).sin())
            })
            .collect();
        let prior = camera_up_prior(&poses).expect("poses");
        assert!(prior.angle_between(true_up).to_degrees() < 2.0, "{prior} against {true_up}");
        // The average -y alone would lean 40 degrees; without panning it is all there is.
        let still: Vec<Affine3A> = (0..60).map(|_| handheld(map_from_world, 0.2, 40f32.to_radians(), 0.0)).collect();
        let prior = camera_up_prior(&still).expect("poses");
        assert!((prior.angle_between(true_up).to_degrees() - 40.0).abs() < 0.5);
    }

    #[test]
    fn a_mesh_gives_its_up_from_its_normals_and_the_cameras() {
        let map_from_world = Affine3A::from_quat(glam::Quat::from_rotation_x(-1.9) * glam::Quat::from_rotation_z(0.4));
        let samples = room(map_from_world);
        let positions: Vec<Vec3> = samples.iter().map(|s| s.position).collect();
        let normals: Vec<Vec3> = samples.iter().map(|s| s.normal).collect();
        let true_up = map_from_world.transform_vector3(Vec3::Z);
        let q = glam::Quat::from_rotation_x(-1.9) * glam::Quat::from_rotation_z(0.4);
        let poses: Vec<Affine3A> = (0..30).map(|i| handheld(q, (i as f32 * 3.0).to_radians(), 0.3, 0.0)).collect();
        let e = mesh_up(&positions, &normals, &poses).expect("an estimate");
        assert!(e.angle_to_deg(true_up) < 0.5, "{} deg", e.angle_to_deg(true_up));
        // No normals or no cameras: no estimate.
        assert!(mesh_up(&positions, &[], &poses).is_none());
        assert!(mesh_up(&positions, &normals, &[]).is_none());
    }

    /// Demo seed 16's view, made up: two walls at a corner and a column's four faces, all
    /// vertical, and 3 % of sloped surface whose normals lean 17 degrees, as the camera prior
    /// does. The horizontal evidence is too thin to trust; the walls give up to within a
    /// degree. A single wall (one way faced) leaves up to the other rules.
    #[test]
    fn walls_facing_two_ways_give_up_when_horizontal_surface_is_scarce() {
        let map_from_world = glam::Quat::from_rotation_x(-1.7) * glam::Quat::from_rotation_z(0.3);
        let true_up = map_from_world * Vec3::Z;
        let tilt = glam::Quat::from_rotation_x(17f32.to_radians());
        let mut samples = Vec::new();
        let mut push = |p: Vec3, n: Vec3| {
            samples.push(SurfaceSample { position: map_from_world * p, normal: map_from_world * n, weight: 1.0 });
        };
        for i in 0..40 {
            for j in 0..25 {
                let (a, b) = (i as f32 * 0.1, j as f32 * 0.1);
                push(Vec3::new(a, 0.0, b), Vec3::Y);
                push(Vec3::new(0.0, a, b), Vec3::X);
                if i < 4 {
                    push(Vec3::new(2.0 + a, 2.0, b), -Vec3::Y);
                    push(Vec3::new(2.0, 2.0 + a, b), -Vec3::X);
                }
            }
        }
        for i in 0..70 {
            push(Vec3::new(1.0 + i as f32 * 0.01, 1.0, 0.9), tilt * Vec3::Z);
        }
        let prior = map_from_world * (tilt * Vec3::Z);
        let e = estimate_up(&samples, prior, &[map_from_world * Vec3::new(1.0, 1.0, 1.5)]);
        assert_eq!(e.source, UpSource::Walls);
        assert!(e.angle_to_deg(true_up) < 1.0, "{} deg", e.angle_to_deg(true_up));
        // One wall only: up is free within its plane, so the walls say nothing.
        let one_wall: Vec<SurfaceSample> =
            samples.iter().filter(|s| s.normal.dot(map_from_world * Vec3::Y) > 0.99).copied().collect();
        assert_ne!(estimate_up(&one_wall, prior, &[]).source, UpSource::Walls);
    }

    #[test]
    fn a_prior_just_beyond_the_first_cone_still_finds_the_floor() {
        // The room z up; a prior 40 degrees off (a camera looking down without panning).
        let samples = room(Affine3A::IDENTITY);
        let prior = glam::Quat::from_rotation_x(40f32.to_radians()) * Vec3::Z;
        let e = estimate_up(&samples, prior, &[Vec3::new(2.0, 2.0, 1.5)]);
        assert_eq!(e.source, UpSource::Planes);
        assert!(e.angle_to_deg(Vec3::Z) < 0.5, "{} deg", e.angle_to_deg(Vec3::Z));
        // A little horizontal surface among walls: the wider cone's few per cent are not taken.
        let mut walls: Vec<SurfaceSample> = (0..1000)
            .map(|i| SurfaceSample { position: Vec3::new(0.0, i as f32 * 0.01, 1.0), normal: Vec3::X, weight: 1.0 })
            .collect();
        walls.extend((0..50).map(|i| SurfaceSample {
            position: Vec3::new(i as f32 * 0.01, 1.0, 0.0),
            // 45 degrees from the prior: outside the first cone, inside the wider one.
            normal: glam::Quat::from_rotation_x(-5f32.to_radians()) * Vec3::Z,
            weight: 1.0,
        }));
        let e = estimate_up(&walls, prior, &[]);
        assert_eq!((e.source, e.up), (UpSource::CameraPrior, prior.normalize()));
    }
}
