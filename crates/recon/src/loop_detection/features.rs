//! Appearance features of a keyframe and the alignment they give, for loops beyond the drift
//! the pose-based search covers.
//!
//! The pose-based search (the parent module) finds a revisit only while the drifted poses
//! still put the two views within `search_radius` of each other, and its ICP converges only
//! from a few centimetres. After a long walk (20 cm of drift and more) neither holds. Here the
//! views are related by what they look like instead: FAST-9 corners on the grey image (at
//! half resolution from VGA up; the strongest per 16x16-pixel cell), each with a 256-bit BRIEF descriptor and
//! its 3D point from the depth image; descriptors are matched (mutual nearest neighbours,
//! ratio test) and RANSAC over three-point rigid fits finds the motion that most matches
//! agree with. That motion then starts the same ICP and the same acceptance tests as a
//! pose-based candidate.
//!
//! FAST and BRIEF are written here (about a hundred lines) rather than taken from
//! `imageproc` 0.27: it would add rand 0.10 (beside the workspace's 0.9), rand_distr,
//! rustdct, num and itertools to the default build (42 s on two cores, measured in session
//! 25), for two small functions, and its BRIEF draws its test pairs from an unseeded
//! generator unless given them. Everything is
//! sequential with fixed seeds: the same features, matches and motion every run.

use glam::{DAffine3, DMat3, DVec3, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use semrecon_data::Frame;

use crate::linalg::horn_rotation;

/// Corners are kept one per cell of this many half-resolution pixels.
const CELL: usize = 8;
/// FAST's intensity threshold (0-255).
const FAST_THRESHOLD: i32 = 6;
/// BRIEF test points lie within this many half-resolution pixels of the corner.
const PATCH_RADIUS: i32 = 12;
/// Intensities are box means of (2 * SMOOTH + 1)^2 pixels (BRIEF's smoothing).
const SMOOTH: i32 = 2;
/// Margin a corner keeps from the image border.
const BORDER: usize = (PATCH_RADIUS + SMOOTH + 1) as usize;
/// Depths usable for a feature's point, metres.
const DEPTH_RANGE: (f32, f32) = (0.3, 5.0);

/// A keyframe's features: camera-frame points and their descriptors (same order).
#[derive(Debug, Clone, Default)]
pub(crate) struct Features {
    pub(crate) points: Vec<DVec3>,
    pub(crate) descriptors: Vec<[u64; 4]>,
}

impl Features {
    /// The features of `frame`; empty without colour.
    pub(crate) fn of(frame: &Frame) -> Self {
        let k = frame.intrinsics;
        let (w, h) = (k.width as usize, k.height as usize);
        if frame.color.len() != w * h || frame.depth.len() != w * h || w < 6 * BORDER || h < 6 * BORDER {
            return Self::default();
        }
        // VGA and larger at half resolution: 2x2 means of luma (noise and blur halved, four
        // times fewer pixels); smaller frames as they are.
        let f = if w >= 640 { 2 } else { 1 };
        let (hw, hh) = (w / f, h / f);
        let luma = |c: [u8; 3]| 299 * c[0] as u32 + 587 * c[1] as u32 + 114 * c[2] as u32;
        let grey: Vec<u8> = (0..hw * hh)
            .map(|i| {
                let (x, y) = (f * (i % hw), f * (i / hw));
                let mut sum = 0;
                for dy in 0..f {
                    for dx in 0..f {
                        sum += luma(frame.color[(y + dy) * w + x + dx]);
                    }
                }
                (sum / (1000 * (f * f) as u32)).min(255) as u8
            })
            .collect();
        let integral = Integral::new(&grey, hw, hh);
        let pairs = test_pairs();
        // The strongest corner of every cell.
        let (cw, ch) = (hw.div_ceil(CELL), hh.div_ceil(CELL));
        let mut best: Vec<Option<(u32, usize, usize)>> = vec![None; cw * ch];
        for y in BORDER..hh - BORDER {
            for x in BORDER..hw - BORDER {
                if let Some(score) = fast9_score(&grey, hw, x, y, FAST_THRESHOLD) {
                    let cell = (y / CELL) * cw + x / CELL;
                    if best[cell].is_none_or(|(s, _, _)| score > s) {
                        best[cell] = Some((score, x, y));
                    }
                }
            }
        }
        let mut out = Self::default();
        for (_, x, y) in best.into_iter().flatten() {
            // The full-resolution pixel under the corner; its depth must agree with its
            // neighbours' (no point on a depth edge, where it belongs to neither side).
            let (u, v) = (f * x, f * y);
            let d = frame.depth[v * w + u];
            if !(d >= DEPTH_RANGE.0 && d <= DEPTH_RANGE.1) {
                continue;
            }
            let steady = [(u - 2, v), (u + 2, v), (u, v - 2), (u, v + 2)]
                .iter()
                .filter(|&&(a, b)| (frame.depth[b * w + a] - d).abs() <= 0.02 * d)
                .count()
                >= 3;
            if !steady {
                continue;
            }
            let p: Vec3 = k.unproject(u as f32, v as f32, d);
            out.points.push(p.as_dvec3());
            out.descriptors.push(brief(&integral, x as i32, y as i32, &pairs));
        }
        out
    }
}

/// FAST-9's score at `(x, y)` (the summed excess over the threshold of the longest arc's
/// circle pixels), `None` when no arc of 9 contiguous circle pixels is all brighter or all
/// darker than the centre by more than `t`.
fn fast9_score(img: &[u8], w: usize, x: usize, y: usize, t: i32) -> Option<u32> {
    const CIRCLE: [(i32, i32); 16] = [
        (0, -3),
        (1, -3),
        (2, -2),
        (3, -1),
        (3, 0),
        (3, 1),
        (2, 2),
        (1, 3),
        (0, 3),
        (-1, 3),
        (-2, 2),
        (-3, 1),
        (-3, 0),
        (-3, -1),
        (-2, -2),
        (-1, -3),
    ];
    let c = img[y * w + x] as i32;
    let at = |k: usize| {
        let (dx, dy) = CIRCLE[k % 16];
        img[(y as i32 + dy) as usize * w + (x as i32 + dx) as usize] as i32
    };
    // Quick rejection on the four compass pixels: an arc of 9 covers at least two of them.
    let compass = [at(0), at(4), at(8), at(12)];
    let bright = compass.iter().filter(|&&p| p > c + t).count();
    let dark = compass.iter().filter(|&&p| p < c - t).count();
    if bright < 2 && dark < 2 {
        return None;
    }
    let mut score = None;
    for sign in [1, -1] {
        let passes = |k: usize| sign * (at(k) - c) > t;
        let (mut run, mut longest) = (0, 0);
        for k in 0..32 {
            if passes(k) {
                run += 1;
                longest = longest.max(run);
            } else {
                run = 0;
            }
        }
        if longest >= 9 {
            let excess: i32 = (0..16).map(|k| (sign * (at(k) - c) - t).max(0)).sum();
            score = Some(score.unwrap_or(0).max(excess as u32));
        }
    }
    score
}

/// Summed-area table of a grey image, for box means in constant time.
struct Integral {
    w: usize,
    sums: Vec<u32>,
}

impl Integral {
    fn new(img: &[u8], w: usize, h: usize) -> Self {
        let mut sums = vec![0u32; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0u32;
            for x in 0..w {
                row += img[y * w + x] as u32;
                sums[(y + 1) * (w + 1) + x + 1] = sums[y * (w + 1) + x + 1] + row;
            }
        }
        Self { w, sums }
    }

    /// Sum of the box of radius [`SMOOTH`] around `(x, y)` (inside the image).
    fn box_sum(&self, x: i32, y: i32) -> u32 {
        let s = |x: i32, y: i32| self.sums[y as usize * (self.w + 1) + x as usize];
        let (x0, y0, x1, y1) = (x - SMOOTH, y - SMOOTH, x + SMOOTH + 1, y + SMOOTH + 1);
        s(x1, y1) + s(x0, y0) - s(x0, y1) - s(x1, y0)
    }
}

/// BRIEF's 256 point pairs, offsets from the corner: a fixed draw (seeded) from a Gaussian of
/// a fifth of the patch's width, clamped to the patch, as Calonder et al. found best.
fn test_pairs() -> Vec<[(i32, i32); 2]> {
    let mut rng = ChaCha8Rng::seed_from_u64(0x5EED_B41E);
    let sigma = (2 * PATCH_RADIUS + 1) as f32 / 5.0;
    let mut gauss = move || {
        // Sum of four uniforms: close enough to a Gaussian for test positions.
        let u: f32 = (0..4).map(|_| rng.random::<f32>()).sum::<f32>() - 2.0;
        ((u * sigma * 1.732).round() as i32).clamp(-PATCH_RADIUS, PATCH_RADIUS)
    };
    (0..256).map(|_| [(gauss(), gauss()), (gauss(), gauss())]).collect()
}

/// The BRIEF descriptor of the corner at `(x, y)`: bit `i` says whether the first point of
/// pair `i` is darker than the second (box means).
fn brief(integral: &Integral, x: i32, y: i32, pairs: &[[(i32, i32); 2]]) -> [u64; 4] {
    let mut d = [0u64; 4];
    for (i, [a, b]) in pairs.iter().enumerate() {
        if integral.box_sum(x + a.0, y + a.1) < integral.box_sum(x + b.0, y + b.1) {
            d[i / 64] |= 1 << (i % 64);
        }
    }
    d
}

fn hamming(a: &[u64; 4], b: &[u64; 4]) -> u32 {
    a.iter().zip(b).map(|(x, y)| (x ^ y).count_ones()).sum()
}

/// Largest Hamming distance of a match (of 256 bits).
const MAX_HAMMING: u32 = 80;
/// A match's best distance must be below this share of the second best.
const RATIO: f32 = 0.9;

/// Matches of `new`'s features to `old`'s: `(new, old)` index pairs that are each other's
/// nearest descriptors, close enough and clearly closer than the second nearest.
pub(crate) fn match_features(new: &Features, old: &Features) -> Vec<(usize, usize)> {
    let nearest = |d: &[u64; 4], among: &[[u64; 4]]| -> Option<(usize, u32, u32)> {
        let mut best = (usize::MAX, u32::MAX, u32::MAX);
        for (j, e) in among.iter().enumerate() {
            let h = hamming(d, e);
            if h < best.1 {
                best = (j, h, best.1);
            } else if h < best.2 {
                best.2 = h;
            }
        }
        (best.0 != usize::MAX).then_some(best)
    };
    let mut out = Vec::new();
    for (i, d) in new.descriptors.iter().enumerate() {
        let Some((j, h, second)) = nearest(d, &old.descriptors) else { continue };
        if h > MAX_HAMMING || (h as f32) >= RATIO * second as f32 {
            continue;
        }
        if nearest(&old.descriptors[j], &new.descriptors).map(|b| b.0) == Some(i) {
            out.push((i, j));
        }
    }
    out
}

/// What RANSAC found: `old_from_new` refitted on its inliers, and their count.
#[derive(Debug, Clone, Copy)]
pub(crate) struct FeatureAlignment {
    pub(crate) old_from_new: DAffine3,
    pub(crate) inliers: usize,
}

/// RANSAC iterations (three-point fits).
const RANSAC_ITERATIONS: usize = 1000;
/// A match agrees with a motion within this many metres, plus 1 % of its depth.
const INLIER_DISTANCE: f64 = 0.03;
/// Fewest agreeing matches for an alignment.
pub(crate) const MIN_INLIERS: usize = 12;

/// The rigid motion `old_from_new` that most of `matches` agree with, by RANSAC over
/// three-point fits (seeded by `seed`), refitted on its inliers; `None` with fewer than
/// [`MIN_INLIERS`] agreeing.
pub(crate) fn ransac(
    new: &Features,
    old: &Features,
    matches: &[(usize, usize)],
    seed: u64,
) -> Option<FeatureAlignment> {
    if matches.len() < MIN_INLIERS {
        return None;
    }
    let pairs: Vec<(DVec3, DVec3)> = matches.iter().map(|&(i, j)| (new.points[i], old.points[j])).collect();
    let agree = |m: &DAffine3| -> Vec<usize> {
        (0..pairs.len())
            .filter(|&k| {
                let (a, b) = pairs[k];
                (m.transform_point3(a) - b).length() <= INLIER_DISTANCE + 0.01 * a.z
            })
            .collect()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut best: Vec<usize> = Vec::new();
    for _ in 0..RANSAC_ITERATIONS {
        let s: [usize; 3] = std::array::from_fn(|_| rng.random_range(0..pairs.len()));
        if s[0] == s[1] || s[1] == s[2] || s[0] == s[2] {
            continue;
        }
        // A sample spanning too small a triangle fixes the rotation badly.
        let (a, b, c) = (pairs[s[0]].0, pairs[s[1]].0, pairs[s[2]].0);
        if (b - a).cross(c - a).length() < 0.01 {
            continue;
        }
        let Some(m) = rigid_fit(&s.map(|k| pairs[k])) else { continue };
        let inliers = agree(&m);
        if inliers.len() > best.len() {
            best = inliers;
        }
    }
    if best.len() < MIN_INLIERS {
        return None;
    }
    let fitted: Vec<(DVec3, DVec3)> = best.iter().map(|&k| pairs[k]).collect();
    let m = rigid_fit(&fitted)?;
    let inliers = agree(&m).len();
    (inliers >= MIN_INLIERS).then_some(FeatureAlignment { old_from_new: m, inliers })
}

/// The rigid motion `m` minimising `sum |m a - b|^2` over the pairs `(a, b)` (Horn).
fn rigid_fit(pairs: &[(DVec3, DVec3)]) -> Option<DAffine3> {
    let n = pairs.len() as f64;
    let ca = pairs.iter().map(|p| p.0).sum::<DVec3>() / n;
    let cb = pairs.iter().map(|p| p.1).sum::<DVec3>() / n;
    let mut s = [[0.0f64; 3]; 3];
    for (a, b) in pairs {
        let (a, b) = (*a - ca, *b - cb);
        for i in 0..3 {
            for j in 0..3 {
                s[i][j] += a[i] * b[j];
            }
        }
    }
    let r = horn_rotation(&s);
    let rotation = DMat3::from_cols_array_2d(&r).transpose();
    let m = DAffine3 { matrix3: rotation, translation: cb - rotation * ca };
    m.is_finite().then_some(m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rigid_fit_and_ransac_recover_a_motion_among_wrong_matches() {
        let truth = DAffine3::from_rotation_translation(
            glam::DQuat::from_euler(glam::EulerRot::XYZ, 0.3, -0.5, 0.8),
            DVec3::new(0.4, -0.2, 0.7),
        );
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut new = Features::default();
        let mut old = Features::default();
        for i in 0..60 {
            let p = DVec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(1.0..3.0));
            new.points.push(p);
            // Two thirds right (with millimetres of noise), a third anywhere.
            let q = if i % 3 == 2 {
                DVec3::new(rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0), rng.random_range(0.0..3.0))
            } else {
                truth.transform_point3(p) + DVec3::splat(rng.random_range(-0.003..0.003))
            };
            old.points.push(q);
        }
        let matches: Vec<(usize, usize)> = (0..60).map(|i| (i, i)).collect();
        let found = ransac(&new, &old, &matches, 7).expect("a motion");
        assert_eq!(found.inliers, 40);
        let err = found.old_from_new * truth.inverse();
        assert!(err.translation.length() < 0.003, "{:?}", err.translation);
        assert!(DMat3::IDENTITY.abs_diff_eq(err.matrix3, 0.003), "{:?}", err.matrix3);
        // Too few agreeing: nothing.
        assert!(ransac(&new, &old, &matches[..10], 7).is_none());
    }

    #[test]
    fn brief_matches_a_shifted_view_of_a_textured_wall() {
        // A wall of random blobs 2 m ahead; the second view is the first moved 6 cm to the
        // right (18 pixels at 640x480): the matched points must agree with that motion.
        let k = semrecon_data::Intrinsics::new(640, 480, 525.0, 525.0, 319.5, 239.5).expect("camera");
        // Random grey squares of 3 cm: corners everywhere, no two neighbourhoods alike.
        let texture = |x: f32, y: f32| {
            let (i, j) = ((x / 0.03).floor() as i64, (y / 0.03).floor() as i64);
            let h = (i.wrapping_mul(73_856_093) ^ j.wrapping_mul(19_349_663)).wrapping_mul(0x9E37_79B9) as u64;
            (h >> 24) as u8
        };
        let view = |shift: f32| {
            let mut frame = Frame::from_depth(k, vec![2.0; 640 * 480]);
            frame.color = (0..640 * 480)
                .map(|i| {
                    let p = k.unproject((i % 640) as f32, (i / 640) as f32, 2.0);
                    let g = texture(p.x + shift, p.y);
                    [g, g, g]
                })
                .collect();
            frame
        };
        let (a, b) = (Features::of(&view(0.0)), Features::of(&view(0.06)));
        assert!(a.points.len() > 100, "{} features", a.points.len());
        let matches = match_features(&b, &a);
        assert!(matches.len() > 50, "{} matches", matches.len());
        let found = ransac(&b, &a, &matches, 1).expect("a motion");
        // Camera b sits 6 cm right of a: a point of b's frame is 6 cm further right in a's.
        assert!((found.old_from_new.translation - DVec3::new(0.06, 0.0, 0.0)).length() < 0.01, "{found:?}");
        assert!(found.inliers * 10 >= matches.len() * 8, "{} of {}", found.inliers, matches.len());
    }
}
