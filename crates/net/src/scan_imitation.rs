//! Augmentations that make a whole generated room look like what the live system labels.
//!
//! The live pipeline labels the map of a scan in progress: a few metres of walk, surfaces
//! seen from one side, nothing behind what was in front, little ceiling. A network trained on
//! whole rooms leans on context such a map lacks (measured on the demo: 90 % mIoU on the whole
//! room, 57 % on the part the scan saw, with the true colours and geometry in both). The
//! `view` crop keeps only the points a short walk would see: a few eye-height viewpoints
//! along a straight line, each looking over a random horizontal sector, with occlusion from a
//! spherical depth buffer per viewpoint (a point is seen when it is within a distance-dependent
//! tolerance of the nearest point in its direction bin). That is far cheaper than rendering
//! and reconstructing, which `make-scans` data does for the other half of the gap (colours and
//! holes of a fused map).
//!
//! Rugs: real floors carry rugs and mats, and generated floors do not; a network that never
//! saw a patterned floor labels a rug-covered floor as sofa (seen on Replica office0). Rugs
//! repaint random floor patches with a random colour and pattern, keeping the label floor.
//! Rugs covering a patch were not enough: Replica office0's floor is one pale shag carpet
//! from wall to wall, and a network trained with patches still called it sofa and ceiling.
//! `cover_floor` repaints most or all of the floor as one carpet (mostly pale, often a shag
//! pile) or as a plain pale floor, again keeping the label floor.

use std::f32::consts::{PI, TAU};

use glam::Vec2;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use semrecon_data::{LabeledPointCloud, SemanticClass};

/// Azimuth bins of the per-viewpoint depth buffer (0.6 degrees each).
const AZIMUTH_BINS: usize = 600;
/// Elevation bins, covering -90..+90 degrees (0.6 degrees each).
const ELEVATION_BINS: usize = 300;
/// Angle of one bin, radians.
const BIN_ANGLE: f32 = PI / ELEVATION_BINS as f32;
/// Half the spacing of the surface samples the training data is made of, metres.
const POINT_RADIUS: f32 = 0.015;
/// Viewpoints along the walk.
const VIEWPOINTS: usize = 4;

/// Marks the points a short walk through the room would see (`true`: kept). `None` when the
/// cloud has no floor point to stand on or the view would keep almost nothing, so that the
/// caller can fall back to another crop.
pub fn visible_from_short_walk(cloud: &LabeledPointCloud, rng: &mut ChaCha8Rng) -> Option<Vec<bool>> {
    let floor = SemanticClass::Floor.id();
    let floor_points: Vec<usize> = (0..cloud.len()).filter(|&i| cloud.labels[i] == floor).collect();
    if floor_points.is_empty() {
        return None;
    }
    let floor_z = floor_points.iter().map(|&i| cloud.positions[i].z).fold(f32::MAX, f32::min);
    // Stand above a floor point, walk up to 2.5 m in some direction (staying above the floor
    // rectangle's bounds), eye height of a handheld device.
    let start = cloud.positions[floor_points[rng.random_range(0..floor_points.len())]];
    let (lo, hi) = floor_points.iter().fold((Vec2::splat(f32::MAX), Vec2::splat(f32::MIN)), |(lo, hi), &i| {
        let p = cloud.positions[i].truncate();
        (lo.min(p), hi.max(p))
    });
    let heading = rng.random_range(0.0..TAU);
    let walk = rng.random_range(0.0..2.5f32);
    let end = (start.truncate() + Vec2::from_angle(heading) * walk).clamp(lo, hi);
    let eye = floor_z + rng.random_range(1.2..1.7f32);
    let range = rng.random_range(3.0..5.5f32);
    // Half-width of the horizontal sector each viewpoint looks over: from a glance to a full
    // turn; pitch from well down to a little up, as people scan.
    let half_width = rng.random_range(0.35..1.0f32) * PI;
    let look = rng.random_range(0.0..TAU);
    let (down, up) = (-rng.random_range(0.9..1.3f32), rng.random_range(0.3..0.7f32));

    let mut keep = vec![false; cloud.len()];
    let mut depth = vec![f32::INFINITY; AZIMUTH_BINS * ELEVATION_BINS];
    let mut bins: Vec<u32> = vec![u32::MAX; cloud.len()];
    for v in 0..VIEWPOINTS {
        let t = v as f32 / (VIEWPOINTS - 1) as f32;
        let camera = start.truncate().lerp(end, t).extend(eye);
        // The gaze sweeps a little as the walk goes on.
        let centre = look + rng.random_range(-0.4..0.4f32);
        depth.fill(f32::INFINITY);
        for (i, p) in cloud.positions.iter().enumerate() {
            bins[i] = u32::MAX;
            let d = *p - camera;
            let dist = d.length();
            if !(dist > 1e-3 && dist <= range) {
                continue;
            }
            let azimuth = d.y.atan2(d.x);
            if angle_between(azimuth, centre) > half_width {
                continue;
            }
            let elevation = (d.z / dist).clamp(-1.0, 1.0).asin();
            if elevation < down || elevation > up {
                continue;
            }
            let a = (((azimuth + PI) / TAU) * AZIMUTH_BINS as f32) as usize;
            let e = (((elevation + PI * 0.5) / PI) * ELEVATION_BINS as f32) as usize;
            let (a, e) = (a.min(AZIMUTH_BINS - 1), e.min(ELEVATION_BINS - 1));
            bins[i] = (a * ELEVATION_BINS + e) as u32;
            // A point stands for a patch of surface about POINT_RADIUS across: near the
            // camera that patch covers many bins, and leaving them empty would let the
            // surface behind show through.
            let radius = ((POINT_RADIUS / dist).atan() / BIN_ANGLE).ceil();
            let re = (radius as usize).min(ELEVATION_BINS / 4);
            let ra = ((radius / elevation.cos().max(0.05)) as usize).min(AZIMUTH_BINS / 4);
            for da in 0..=2 * ra {
                let aa = (a + AZIMUTH_BINS + da - ra) % AZIMUTH_BINS;
                for ee in e.saturating_sub(re)..=(e + re).min(ELEVATION_BINS - 1) {
                    let bin = aa * ELEVATION_BINS + ee;
                    depth[bin] = depth[bin].min(dist);
                }
            }
        }
        for (i, p) in cloud.positions.iter().enumerate() {
            if bins[i] != u32::MAX {
                let dist = (*p - camera).length();
                keep[i] |= dist <= depth[bins[i] as usize] + 0.05 + 0.02 * dist;
            }
        }
    }
    let kept = keep.iter().filter(|&&k| k).count();
    (kept * 20 >= cloud.len()).then_some(keep)
}

/// Smallest absolute difference of two angles, radians (0..PI).
fn angle_between(a: f32, b: f32) -> f32 {
    let d = (a - b).rem_euclid(TAU);
    d.min(TAU - d)
}

/// Repaints one to three random floor patches as rugs: a random base colour, a pattern
/// (plain, stripes, checks or speckle), a border and, on most, a bumpy pile up to 2.5 cm
/// high; all of it still labelled floor.
pub fn paint_rugs(cloud: &mut LabeledPointCloud, rng: &mut ChaCha8Rng) {
    let floor = SemanticClass::Floor.id();
    let floor_points: Vec<usize> = (0..cloud.len()).filter(|&i| cloud.labels[i] == floor).collect();
    if floor_points.is_empty() {
        return;
    }
    for _ in 0..rng.random_range(1..=3) {
        let centre = cloud.positions[floor_points[rng.random_range(0..floor_points.len())]].truncate();
        let half = Vec2::new(rng.random_range(0.4..1.6f32), rng.random_range(0.3..1.2f32));
        let axis = Vec2::from_angle(rng.random_range(0.0..PI));
        let base = random_colour(rng);
        let accent = random_colour(rng);
        let pattern = rng.random_range(0..4u8);
        let period = rng.random_range(0.04..0.3f32);
        let border = rng.random_range(0.0..0.15f32);
        // Pile and wrinkles: real rugs are bumpy at the scale of centimetres, and a bumpy
        // horizontal surface must not mean upholstery when it lies on the floor.
        let bump = if rng.random_bool(0.6) { rng.random_range(0.0..0.025f32) } else { 0.0 };
        let waves: [(Vec2, f32); 3] = std::array::from_fn(|_| {
            (
                Vec2::from_angle(rng.random_range(0.0..TAU)) * (TAU / rng.random_range(0.03..0.15f32)),
                rng.random_range(0.0..TAU),
            )
        });
        for &i in &floor_points {
            let p = cloud.positions[i];
            let local = axis.rotate(p.truncate() - centre);
            if local.x.abs() > half.x || local.y.abs() > half.y {
                continue;
            }
            let near_edge = half.x - local.x.abs() < border || half.y - local.y.abs() < border;
            let stripe = |x: f32| ((x / period).floor() as i32).rem_euclid(2) == 1;
            let use_accent = near_edge
                || match pattern {
                    1 => stripe(local.x),
                    2 => stripe(local.x) ^ stripe(local.y),
                    3 => rng.random::<f32>() < 0.3,
                    _ => false,
                };
            let c = if use_accent { accent } else { base };
            if bump > 0.0 {
                let h: f32 = waves.iter().map(|(k, phase)| (k.dot(local) + phase).sin()).sum::<f32>() / 3.0;
                cloud.positions[i].z += bump * (0.5 + 0.5 * h);
            }
            // Fibre texture: a little per-point brightness noise.
            let shade = 1.0 + rng.random_range(-0.08..0.08f32);
            cloud.colors[i] = c.map(|v| (v * shade).round().clamp(0.0, 255.0) as u8);
        }
    }
}

/// Repaints 70-100 % of the floor (a rectangle of the floor's extent, trimmed on random
/// sides) as one wall-to-wall covering, keeping the label floor. Two kinds:
/// - a carpet (80 %): pale (white, cream, light grey, beige) two times in three, else any
///   colour; plain or a subtle pattern (stripes, checks, mottling only a few percent apart in
///   brightness); most with a shag pile (smooth bumps plus per-fibre jitter, up to 3 cm) and
///   fibre brightness noise;
/// - a plain pale floor (20 %): flat, one colour, little noise.
///
/// Both get a slow brightness gradient across the room, as real lighting gives.
pub fn cover_floor(cloud: &mut LabeledPointCloud, rng: &mut ChaCha8Rng) {
    let floor = SemanticClass::Floor.id();
    let floor_points: Vec<usize> = (0..cloud.len()).filter(|&i| cloud.labels[i] == floor).collect();
    if floor_points.is_empty() {
        return;
    }
    let (lo, hi) = floor_points.iter().fold((Vec2::splat(f32::MAX), Vec2::splat(f32::MIN)), |(lo, hi), &i| {
        let p = cloud.positions[i].truncate();
        (lo.min(p), hi.max(p))
    });
    // Area share of the covered rectangle, split between the two axes, the uncovered strip
    // placed at random on each axis (none at all, wall to wall, a third of the time).
    let share = if rng.random_bool(0.33) { 1.0 } else { rng.random_range(0.7..1.0f32) };
    let share_x = rng.random_range(share..=1.0f32);
    let share_y = (share / share_x).min(1.0);
    let size = hi - lo;
    let (free_x, free_y) = (size.x * (1.0 - share_x), size.y * (1.0 - share_y));
    let start = lo + Vec2::new(free_x * rng.random::<f32>(), free_y * rng.random::<f32>());
    let end = start + Vec2::new(size.x * share_x, size.y * share_y);

    let carpet = rng.random_bool(0.8);
    let base = if !carpet || rng.random_bool(0.67) { pale_colour(rng) } else { random_colour(rng) };
    // Subtle patterns only: a carpet's weave, not a rug's print.
    let pattern = if carpet { rng.random_range(0..5u8) } else { 0 };
    let contrast = rng.random_range(0.03..0.12f32);
    let period = rng.random_range(0.05..0.4f32);
    let pile = if carpet && rng.random_bool(0.75) { rng.random_range(0.005..0.03f32) } else { 0.0 };
    let fibre_noise = if carpet { rng.random_range(0.03..0.15f32) } else { rng.random_range(0.0..0.03f32) };
    let waves: [(Vec2, f32); 3] = std::array::from_fn(|_| {
        (
            Vec2::from_angle(rng.random_range(0.0..TAU)) * (TAU / rng.random_range(0.03..0.2f32)),
            rng.random_range(0.0..TAU),
        )
    });
    // Lighting: brightness varies by up to 15 % across the room.
    let light_dir = Vec2::from_angle(rng.random_range(0.0..TAU));
    let light = rng.random_range(0.0..0.15f32);
    let extent = size.length().max(1e-3);
    let mottle = rng.random_range(0.0..TAU);
    for &i in &floor_points {
        let p = cloud.positions[i].truncate();
        if p.x < start.x || p.x > end.x || p.y < start.y || p.y > end.y {
            continue;
        }
        let local = p - lo;
        let stripe = |x: f32| ((x / period).floor() as i32).rem_euclid(2) == 1;
        let pattern_shade = match pattern {
            1 if stripe(local.x) => contrast,
            2 if stripe(local.x) ^ stripe(local.y) => contrast,
            3 => contrast * ((local.x / period + mottle).sin() * (local.y / period * 1.3 - mottle).sin()),
            _ => 0.0,
        };
        let lighting = light * (light_dir.dot(local) / extent - 0.5);
        let shade = 1.0 + pattern_shade + lighting + rng.random_range(-fibre_noise..=fibre_noise);
        cloud.colors[i] = base.map(|v| (v * shade).round().clamp(0.0, 255.0) as u8);
        if pile > 0.0 {
            let h: f32 = waves.iter().map(|(k, phase)| (k.dot(local) + phase).sin()).sum::<f32>() / 3.0;
            let fibre = rng.random::<f32>();
            cloud.positions[i].z += pile * (0.35 * (0.5 + 0.5 * h) + 0.65 * fibre);
        }
    }
}

/// A pale floor colour: white, cream, light grey or beige.
fn pale_colour(rng: &mut ChaCha8Rng) -> [f32; 3] {
    let value = rng.random_range(165.0..250.0f32);
    // Warm hues (red to yellow) with little saturation give cream and beige; none gives grey.
    let hue = rng.random_range(0.0..1.2f32);
    let saturation =
        if rng.random_bool(0.3) { rng.random_range(0.0..0.04f32) } else { rng.random_range(0.03..0.25f32) };
    let f = |n: f32| {
        let k = (n + hue) % 6.0;
        value * (1.0 - saturation * (k.min(4.0 - k).clamp(0.0, 1.0)))
    };
    [f(5.0), f(3.0), f(1.0)]
}

/// A rug colour: any hue, muted to vivid, dark to light.
fn random_colour(rng: &mut ChaCha8Rng) -> [f32; 3] {
    let hue = rng.random_range(0.0..6.0f32);
    let saturation = rng.random_range(0.1..0.8f32);
    let value = rng.random_range(40.0..230.0f32);
    let f = |n: f32| {
        let k = (n + hue) % 6.0;
        value * (1.0 - saturation * (k.min(4.0 - k).clamp(0.0, 1.0)))
    };
    [f(5.0), f(3.0), f(1.0)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;
    use rand::SeedableRng;

    /// A floor with a wall on each side of the origin, 2 cm spacing.
    fn corridor() -> LabeledPointCloud {
        let mut cloud = LabeledPointCloud::default();
        for i in 0..200 {
            for j in 0..150 {
                let (x, y) = (i as f32 * 0.02 - 2.0, j as f32 * 0.02 - 1.5);
                cloud.positions.push(Vec3::new(x, y, 0.0));
                cloud.colors.push([100, 100, 100]);
                cloud.labels.push(SemanticClass::Floor.id());
            }
            for k in 0..100 {
                for y in [-1.5f32, 1.5] {
                    cloud.positions.push(Vec3::new(i as f32 * 0.02 - 2.0, y, k as f32 * 0.025));
                    cloud.colors.push([200, 200, 200]);
                    cloud.labels.push(SemanticClass::Wall.id());
                }
            }
        }
        cloud
    }

    #[test]
    fn a_short_walk_sees_part_of_the_room_and_nothing_behind_a_wall() {
        let mut cloud = corridor();
        // A second wall right behind the middle of the y = 1.5 one: hidden from any viewpoint
        // inside (the corridor is open at its ends, so not the whole length).
        let n = cloud.len();
        for i in 0..n {
            let p = cloud.positions[i];
            if cloud.labels[i] == SemanticClass::Wall.id() && p.y > 0.0 && p.x.abs() < 1.5 {
                let p = cloud.positions[i] + Vec3::Y * 0.3;
                cloud.positions.push(p);
                cloud.colors.push([0, 0, 0]);
                cloud.labels.push(SemanticClass::Board.id());
            }
        }
        let mut seen_any = false;
        for seed in 0..8 {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            let Some(keep) = visible_from_short_walk(&cloud, &mut rng) else { continue };
            seen_any = true;
            let kept = keep.iter().filter(|&&k| k).count();
            assert!(kept < cloud.len(), "seed {seed}: kept everything");
            let hidden_seen = (n..cloud.len()).filter(|&i| keep[i]).count();
            assert_eq!(hidden_seen, 0, "seed {seed}: saw through a wall");
            // Same seed, same crop.
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            assert_eq!(visible_from_short_walk(&cloud, &mut rng), Some(keep));
        }
        assert!(seen_any);
    }

    #[test]
    fn rugs_repaint_floor_only_and_keep_labels() {
        let cloud = corridor();
        let mut painted = cloud.clone();
        paint_rugs(&mut painted, &mut ChaCha8Rng::seed_from_u64(3));
        assert_eq!(painted.labels, cloud.labels);
        let mut changed = 0;
        for i in 0..cloud.len() {
            let lift = painted.positions[i].z - cloud.positions[i].z;
            assert!((0.0..=0.025).contains(&lift), "lifted by {lift}");
            assert_eq!(painted.positions[i].truncate(), cloud.positions[i].truncate());
            if painted.colors[i] != cloud.colors[i] {
                changed += 1;
                assert_eq!(cloud.labels[i], SemanticClass::Floor.id());
            }
        }
        assert!(changed > 0);
    }

    #[test]
    fn floor_cover_repaints_most_of_the_floor_only_and_is_deterministic() {
        let cloud = corridor();
        let floor = SemanticClass::Floor.id();
        let floor_count = cloud.labels.iter().filter(|&&l| l == floor).count();
        let mut pale = 0;
        for seed in 0..16 {
            let mut covered = cloud.clone();
            cover_floor(&mut covered, &mut ChaCha8Rng::seed_from_u64(seed));
            assert_eq!(covered.labels, cloud.labels);
            let mut changed = 0;
            let mut mean = [0.0f64; 3];
            for i in 0..cloud.len() {
                let lift = covered.positions[i].z - cloud.positions[i].z;
                assert!((0.0..=0.03).contains(&lift), "seed {seed}: lifted by {lift}");
                assert_eq!(covered.positions[i].truncate(), cloud.positions[i].truncate());
                if cloud.labels[i] != floor {
                    assert_eq!(covered.colors[i], cloud.colors[i], "seed {seed}: repainted a wall");
                    assert_eq!(covered.positions[i], cloud.positions[i]);
                } else if covered.colors[i] != cloud.colors[i] || lift > 0.0 {
                    changed += 1;
                    for (m, c) in mean.iter_mut().zip(covered.colors[i]) {
                        *m += f64::from(c);
                    }
                }
            }
            // 70-100 % of the area; a point or two may keep its colour by chance.
            let share = changed as f64 / floor_count as f64;
            assert!((0.68..=1.0).contains(&share), "seed {seed}: covered {share}");
            if mean.iter().all(|m| m / changed as f64 > 150.0) {
                pale += 1;
            }
            let mut again = cloud.clone();
            cover_floor(&mut again, &mut ChaCha8Rng::seed_from_u64(seed));
            assert_eq!(again, covered, "seed {seed}: not deterministic");
        }
        // Most coverings are pale.
        assert!(pale >= 6, "only {pale} of 16 pale");
    }
}
