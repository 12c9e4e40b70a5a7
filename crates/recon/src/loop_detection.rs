//! Loop detection at keyframes: "which earlier keyframe sees this place again, and where
//! exactly is it?" Candidates come from appearance and position, acceptance from geometry.
//!
//! Every keyframe keeps a small copy of its depth (a quarter of the input resolution, each
//! pixel the mean of a 4x4 block whose depths agree) with vertices and normals, and the
//! relocalisation thumbnail of [`crate::relocalisation`] (block means of depth and
//! normalised intensity). For a new keyframe:
//!
//! 1. **Candidates**: keyframes at least [`LoopConfig::min_keyframe_gap`] keyframes older
//!    whose current pose lies within [`LoopConfig::search_radius`] and
//!    [`LoopConfig::search_angle`] of the new one's (the drift a loop can have while the pose
//!    still says roughly where the camera is), ranked by thumbnail distance, the best
//!    [`LoopConfig::candidates`] of them, each at least [`LoopConfig::min_candidate_spacing`]
//!    keyframes apart.
//! 2. **Geometry**: point-to-plane ICP of the new keyframe's points onto the candidate's
//!    vertex and normal maps (projective association, Huber weights, two pyramid levels),
//!    starting from the relative pose the current poses predict. Accepted when the aligned
//!    views overlap ([`LoopConfig::min_overlap`]), agree ([`LoopConfig::min_inlier_ratio`],
//!    [`LoopConfig::max_residual`]), constrain all six motions
//!    ([`LoopConfig::min_condition`]), the alignment moved the prediction by no more than
//!    the drift a loop can correct ([`LoopConfig::max_correction`]), and it comes back to the
//!    same pose when started 2 cm either side along its least-constrained translation
//!    ([`LoopConfig::basin_shift`]: a view pair whose cost is flat in some direction ends
//!    wherever it starts along it, and would hand the graph the error of its start).
//!
//! 3. **Features**, when no pose-based candidate is accepted: the
//!    [`LoopConfig::feature_candidates`] keyframes most alike in appearance, wherever their
//!    poses are, are aligned by their corners' BRIEF descriptors and 3D points (RANSAC,
//!    `features.rs`), and verified from that alignment as above. This reaches drift beyond
//!    the search radius and the ICP's basin (35 cm on TUM fr2/desk: 10 of 10 views found);
//!    its correction is bounded by [`LoopConfig::feature_max_correction`] (1 m).
//!
//! Repeated structure (twin rooms, identical chairs) fools appearance, not position: two
//! places metres apart are never pose-based candidates, and a loop whose views match only
//! after a jump beyond the correction bound (the pose-based or the feature one) is rejected.
//!
//! Everything is sequential and in fixed order: the verdicts are deterministic.

// Index loops mirror the matrix formulas they implement; negated comparisons reject NaN.
#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]

use glam::{DAffine3, DVec3, Vec3};
use rayon::prelude::*;
use semrecon_data::{Frame, Intrinsics};

use crate::linalg::{cholesky_solve, symmetric_eigen};
use crate::pose_graph::{pose_distance, rotation_exp};
use crate::relocalisation::Thumbnail;
use crate::tracking::conditioning;

/// Downscale of the keyframe copies (640x480 becomes 160x120).
const DOWNSCALE: usize = 4;
/// Depths of a block that differ from its median by more than this (metres, at 1 m; scaled
/// with depth squared) are left out of the block's mean; a block with fewer than half of
/// its pixels kept is invalid.
const BLOCK_AGREEMENT: f32 = 0.02;

/// Parameters of [`LoopDetector`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopConfig {
    /// Candidates are at least this many keyframes older than the new one (a keyframe's
    /// recent predecessors overlap it anyway: that is odometry, not a loop). 20 (about 7 s at
    /// a keyframe every 10 frames): at 10 a 7-Scenes scan that dwells on one counter found a
    /// "loop" at almost every keyframe, each replacing good odometry by a frame-to-frame
    /// alignment and triggering a correction.
    pub min_keyframe_gap: usize,
    /// Candidates' camera centres lie within this many metres of the new one's.
    pub search_radius: f32,
    /// Candidates' viewing directions lie within this many radians of the new one's.
    pub search_angle: f32,
    /// Candidates verified per keyframe (each costs a small ICP, about a millisecond).
    pub candidates: usize,
    /// Verified candidates are at least this many keyframes apart (neighbours would give
    /// the same loop twice).
    pub min_candidate_spacing: usize,
    /// Gauss-Newton iterations at the coarse (80x60) and fine (160x120) level.
    pub iterations: [usize; 2],
    /// Association gate at the fine level, metres (four times that at the coarse one, so that
    /// drift of several centimetres is within reach).
    pub max_distance: f32,
    /// Share of the new keyframe's valid points that must land on the candidate's.
    pub min_overlap: f32,
    /// Share of those within `max_distance` after alignment.
    pub min_inlier_ratio: f32,
    /// Largest RMS point-to-plane residual of the inliers, metres.
    pub max_residual: f32,
    /// Smallest over largest eigenvalue of the scale-normalised normal matrix: below it a
    /// motion is unconstrained (a bare wall) and the loop is rejected.
    pub min_condition: f64,
    /// Largest move of the prediction by the alignment: metres and radians.
    pub max_correction: (f32, f32),
    /// The basin test: the alignment is run again from its own result moved this many
    /// metres either way along its least-constrained translation, and the loop is rejected
    /// ([`LoopRejection::Ambiguous`]) when either run ends more than `basin_tolerance` metres
    /// from the first. A view pair whose cost is flat along some direction (a wall seen
    /// along itself) ends wherever it starts along it: its "loop" then carries the error of
    /// the start into the graph, centimetres that tracking never had. 0: no test.
    pub basin_shift: f32,
    /// See `basin_shift`, metres.
    pub basin_tolerance: f32,
    /// When no pose-based candidate is accepted: this many earlier keyframes, the most alike
    /// in appearance whatever their poses say, are aligned by their features first
    /// ([`features`]: BRIEF matches and RANSAC), then verified like the others. Reaches
    /// drift beyond `search_radius` and the ICP's basin. 0: off.
    pub feature_candidates: usize,
    /// Largest drift a feature-found loop may correct (metres, radians): its alignment
    /// against the current poses' prediction. Twin places metres apart stay apart.
    pub feature_max_correction: (f32, f32),
}

impl Default for LoopConfig {
    fn default() -> Self {
        Self {
            min_keyframe_gap: 20,
            search_radius: 1.0,
            search_angle: 50f32.to_radians(),
            candidates: 2,
            min_candidate_spacing: 3,
            iterations: [8, 8],
            max_distance: 0.03,
            min_overlap: 0.35,
            min_inlier_ratio: 0.7,
            max_residual: 0.012,
            min_condition: 2e-3,
            max_correction: (0.3, 12f32.to_radians()),
            basin_shift: 0.02,
            basin_tolerance: 0.004,
            feature_candidates: 3,
            feature_max_correction: (1.0, 35f32.to_radians()),
        }
    }
}

/// Why a candidate was not accepted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoopRejection {
    /// Too few of the new keyframe's points land on the candidate's view.
    SmallOverlap,
    /// Too few of them agree after alignment.
    FewInliers,
    /// The aligned residual is too large.
    LargeResidual,
    /// The views leave some motion unconstrained.
    Degenerate,
    /// The alignment moved the prediction too far (repeated structure, a wrong minimum).
    LargeCorrection,
    /// The alignment ends elsewhere when started a little away along its weakest direction:
    /// its minimum is not pinned down ([`LoopConfig::basin_shift`]).
    Ambiguous,
}

/// The verdict on one candidate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopVerdict {
    /// The earlier keyframe (its position in the detector).
    pub old: usize,
    /// The new keyframe.
    pub new: usize,
    /// Their frames' indices in the source.
    pub frames: (usize, usize),
    /// `None` when accepted.
    pub rejection: Option<LoopRejection>,
    /// The aligned `old_from_new`.
    pub old_from_new: DAffine3,
    /// Share of the new points landing on the old view.
    pub overlap: f32,
    /// Share of those within the gate.
    pub inlier_ratio: f32,
    /// RMS point-to-plane residual of the inliers, metres.
    pub residual_rms: f32,
    /// How far the alignment moved the prediction: metres and radians.
    pub correction: (f64, f64),
    /// Thumbnail distance (smaller is more alike).
    pub appearance: f32,
    /// Feature matches that agreed with the alignment's start when the candidate came from
    /// features ([`LoopConfig::feature_candidates`]); 0 for a pose-based candidate.
    pub feature_inliers: usize,
    /// The alignment's Gauss-Newton Hessian `JᵀJ` (Huber-weighted) at the final pose, finest
    /// level: left perturbation `(δt, δφ)` of `old_from_new` in the old keyframe's frame, per
    /// square metre of residual ([`crate::pose_graph::alignment_information`] makes an edge's
    /// information of it).
    pub hessian: [[f64; 6]; 6],
}

impl LoopVerdict {
    /// Whether the loop was accepted.
    pub fn accepted(&self) -> bool {
        self.rejection.is_none()
    }
}

/// One pyramid level of a keyframe copy.
#[derive(Debug, Clone)]
struct CloudLevel {
    k: Intrinsics,
    /// Camera-frame vertices; NaN where invalid.
    vertices: Vec<Vec3>,
    /// Unit normals; NaN where invalid.
    normals: Vec<Vec3>,
}

/// What the detector keeps of a keyframe (about 500 KB).
#[derive(Debug, Clone)]
struct KeyframeCloud {
    frame_index: usize,
    thumbnail: Thumbnail,
    /// Corners with descriptors and 3D points, for loops beyond the pose-based search.
    features: features::Features,
    /// Fine (160x120) then coarse (80x60).
    levels: [CloudLevel; 2],
}

/// Keyframes and the loop search over them. See the module documentation.
#[derive(Debug, Clone, Default)]
pub struct LoopDetector {
    config: LoopConfig,
    keyframes: Vec<KeyframeCloud>,
}

impl LoopDetector {
    /// An empty detector.
    pub fn new(config: LoopConfig) -> Self {
        Self { config, keyframes: Vec::new() }
    }

    /// The configuration.
    pub fn config(&self) -> &LoopConfig {
        &self.config
    }

    /// Number of keyframes kept.
    pub fn len(&self) -> usize {
        self.keyframes.len()
    }

    /// Whether no keyframe is kept.
    pub fn is_empty(&self) -> bool {
        self.keyframes.is_empty()
    }

    /// Keeps a copy of a keyframe; returns its position (the pose-graph node when the
    /// caller adds a node per keyframe).
    pub fn add(&mut self, frame: &Frame) -> usize {
        let fine = downscale_depth(frame, DOWNSCALE);
        let coarse_k = fine.k.scaled(fine.k.width / 2, fine.k.height / 2);
        let coarse_depth = halve(&fine_depth_of(&fine), fine.k.width as usize, fine.k.height as usize);
        let coarse = level_from_depth(coarse_k, &coarse_depth);
        self.keyframes.push(KeyframeCloud {
            frame_index: frame.index,
            thumbnail: Thumbnail::of(frame, glam::Affine3A::IDENTITY),
            features: if self.config.feature_candidates > 0 {
                features::Features::of(frame)
            } else {
                Default::default()
            },
            levels: [fine, coarse],
        });
        self.keyframes.len() - 1
    }

    /// Looks for loops of keyframe `new` with earlier keyframes, given every keyframe's
    /// current `world_from_keyframe` (`poses[i]` for keyframe `i`); verdicts on the
    /// candidates tried, accepted or not, best appearance first. Empty when `new` or a pose
    /// is missing.
    pub fn detect(&self, new: usize, poses: &[DAffine3]) -> Vec<LoopVerdict> {
        let c = &self.config;
        let (Some(query), Some(pose_new)) = (self.keyframes.get(new), poses.get(new)) else {
            return Vec::new();
        };
        let mut scored: Vec<(f32, usize)> = Vec::new();
        // At least one keyframe apart, whatever the configuration says.
        let Some(last) = new.checked_sub(c.min_keyframe_gap.max(1)) else { return Vec::new() };
        for old in 0..=last {
            let (Some(kf), Some(pose_old)) = (self.keyframes.get(old), poses.get(old)) else { continue };
            let distance = (pose_new.translation - pose_old.translation).length();
            let angle = pose_new.matrix3.z_axis.angle_between(pose_old.matrix3.z_axis);
            if !(distance <= c.search_radius as f64 && angle <= c.search_angle as f64) {
                continue;
            }
            if let Some(d) = query.thumbnail.distance(&kf.thumbnail) {
                scored.push((d, old));
            }
        }
        // The candidates are aligned side by side: each alignment depends on its pair only,
        // and the verdicts keep the candidates' order, so the result is the same for any
        // thread count (the loop ICP is most of a keyframe's detection time).
        let mut verdicts: Vec<LoopVerdict> = self
            .best_spaced(scored, c.candidates)
            .into_par_iter()
            .filter_map(|(appearance, old)| {
                let prediction = poses[old].inverse() * *pose_new;
                self.verify(old, new, prediction).map(|mut v| {
                    v.appearance = appearance;
                    v
                })
            })
            .collect();
        if c.feature_candidates > 0 && !verdicts.iter().any(LoopVerdict::accepted) {
            verdicts.extend(self.detect_by_features(new, poses, last));
        }
        verdicts
    }

    /// The feature path of [`Self::detect`]: the `feature_candidates` keyframes up to
    /// `last` most alike in appearance, wherever their poses are (the pose-based candidates
    /// again too: their ICP may have failed only for its start), each aligned by its features
    /// and, when RANSAC finds a motion, verified from it; stops at the first accepted. Their
    /// verdicts' `correction` is the alignment's distance from the poses' prediction.
    fn detect_by_features(&self, new: usize, poses: &[DAffine3], last: usize) -> Vec<LoopVerdict> {
        let c = &self.config;
        let query = &self.keyframes[new];
        if query.features.points.len() < features::MIN_INLIERS {
            return Vec::new();
        }
        let scored: Vec<(f32, usize)> = (0..=last)
            .filter_map(|old| Some((query.thumbnail.distance(&self.keyframes.get(old)?.thumbnail)?, old)))
            .collect();
        // Side by side as in `detect` (a RANSAC seed per pair: the same verdicts for any
        // thread count); the verdicts after the first accepted one are dropped, as if the
        // candidates had been tried one by one and stopped there.
        let tried: Vec<LoopVerdict> = self
            .best_spaced(scored, c.feature_candidates)
            .into_par_iter()
            .filter_map(|(appearance, old)| {
                let kf = &self.keyframes[old];
                let matches = features::match_features(&query.features, &kf.features);
                let seed = (old as u64) << 32 | new as u64;
                let found = features::ransac(&query.features, &kf.features, &matches, seed)?;
                let mut v = self.verify_with_bound(old, new, found.old_from_new, (f32::INFINITY, f32::INFINITY))?;
                v.appearance = appearance;
                v.feature_inliers = found.inliers;
                // The drift this loop corrects: its alignment against the poses' prediction.
                let predicted = poses[old].inverse() * poses[new];
                v.correction = pose_distance(&predicted, &v.old_from_new);
                let bound = c.feature_max_correction;
                if v.accepted() && !(v.correction.0 <= bound.0 as f64 && v.correction.1 <= bound.1 as f64) {
                    v.rejection = Some(LoopRejection::LargeCorrection);
                }
                Some(v)
            })
            .collect();
        let kept = tried.iter().position(LoopVerdict::accepted).map_or(tried.len(), |i| i + 1);
        tried.into_iter().take(kept).collect()
    }

    /// The `limit` best `(appearance, keyframe)` pairs of `scored` (smallest distance first,
    /// ties by keyframe), each at least `min_candidate_spacing` keyframes from those chosen
    /// before it (neighbours would give the same loop twice).
    fn best_spaced(&self, mut scored: Vec<(f32, usize)>, limit: usize) -> Vec<(f32, usize)> {
        scored.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut chosen: Vec<(f32, usize)> = Vec::new();
        for (appearance, old) in scored {
            if chosen.len() >= limit {
                break;
            }
            if chosen.iter().all(|&(_, o)| o.abs_diff(old) >= self.config.min_candidate_spacing) {
                chosen.push((appearance, old));
            }
        }
        chosen
    }

    /// Aligns keyframe `new` onto keyframe `old` from `prediction` (`old_from_new`) and
    /// judges the result; `None` when either keyframe is missing or the prediction is not
    /// finite.
    pub fn verify(&self, old: usize, new: usize, prediction: DAffine3) -> Option<LoopVerdict> {
        self.verify_with_bound(old, new, prediction, self.config.max_correction)
    }

    /// [`Self::verify`] with `max_correction` for the bound on the alignment's move.
    fn verify_with_bound(
        &self,
        old: usize,
        new: usize,
        prediction: DAffine3,
        max_correction: (f32, f32),
    ) -> Option<LoopVerdict> {
        let c = &self.config;
        let (src, dst) = (self.keyframes.get(new)?, self.keyframes.get(old)?);
        if !prediction.is_finite() {
            return None;
        }
        let estimate = self.align(src, dst, prediction);
        // Quality at the final pose, finest level.
        let stats = icp_sums(&src.levels[0], &dst.levels[0], &estimate, c.max_distance);
        let overlap = stats.matched as f32 / stats.valid.max(1) as f32;
        let inlier_ratio = stats.inliers as f32 / stats.matched.max(1) as f32;
        let residual_rms = (stats.sq_residual / stats.inliers.max(1) as f64).sqrt() as f32;
        let correction = pose_distance(&prediction, &estimate);
        let rejection = if overlap < c.min_overlap {
            Some(LoopRejection::SmallOverlap)
        } else if inlier_ratio < c.min_inlier_ratio {
            Some(LoopRejection::FewInliers)
        } else if !(residual_rms <= c.max_residual) {
            Some(LoopRejection::LargeResidual)
        } else if !(conditioning(&stats.h, c.min_condition).0 >= c.min_condition) {
            Some(LoopRejection::Degenerate)
        } else if !(correction.0 <= max_correction.0 as f64 && correction.1 <= max_correction.1 as f64) {
            Some(LoopRejection::LargeCorrection)
        } else if c.basin_shift > 0.0 && !self.pinned_down(src, dst, &estimate, &stats.h) {
            Some(LoopRejection::Ambiguous)
        } else {
            None
        };
        Some(LoopVerdict {
            old,
            new,
            frames: (dst.frame_index, src.frame_index),
            rejection,
            old_from_new: estimate,
            overlap,
            inlier_ratio,
            residual_rms,
            correction,
            appearance: 0.0,
            feature_inliers: 0,
            hessian: stats.h,
        })
    }
}

impl LoopDetector {
    /// Point-to-plane ICP of `src` onto `dst` from `start` (`dst_from_src`), coarse level
    /// then fine.
    fn align(&self, src: &KeyframeCloud, dst: &KeyframeCloud, start: DAffine3) -> DAffine3 {
        let c = &self.config;
        let mut estimate = start;
        for level in [1, 0] {
            let gate = c.max_distance * if level == 1 { 4.0 } else { 1.0 };
            for _ in 0..c.iterations[1 - level] {
                let stats = icp_sums(&src.levels[level], &dst.levels[level], &estimate, gate);
                let Some(delta) = cholesky_solve(&damped(&stats.h), &stats.g.map(|v| -v)) else { break };
                let step = DAffine3 {
                    matrix3: rotation_exp(DVec3::new(delta[3], delta[4], delta[5])),
                    translation: DVec3::new(delta[0], delta[1], delta[2]),
                };
                estimate = step * estimate;
                if delta.iter().map(|v| v * v).sum::<f64>() < 1e-12 {
                    break;
                }
            }
        }
        estimate
    }

    /// The basin test ([`LoopConfig::basin_shift`]): whether the alignment comes back to
    /// `estimate` from either side of it along the least-constrained translation of `h`
    /// (translation with the rotation free: the Schur complement's weakest eigenvector).
    fn pinned_down(&self, src: &KeyframeCloud, dst: &KeyframeCloud, estimate: &DAffine3, h: &[[f64; 6]; 6]) -> bool {
        let c = &self.config;
        let Some(weakest) = weakest_translation(h) else { return false };
        let comes_back = |side: f64| {
            let start = DAffine3::from_translation(weakest * (side * c.basin_shift as f64)) * *estimate;
            let end = self.align(src, dst, start);
            pose_distance(&end, estimate).0 <= c.basin_tolerance as f64
        };
        // The two sides are independent alignments: side by side.
        let (plus, minus) = rayon::join(|| comes_back(1.0), || comes_back(-1.0));
        plus && minus
    }
}

/// The unit translation (left perturbation, the old keyframe's frame) that the normal matrix
/// `h` (translation first) constrains least once the rotation may follow it: the weakest
/// eigenvector of `Htt - Htr Hrr⁻¹ Hrt`. `None` when the rotation block is singular.
fn weakest_translation(h: &[[f64; 6]; 6]) -> Option<DVec3> {
    let hrr: [[f64; 3]; 3] = std::array::from_fn(|a| std::array::from_fn(|b| h[3 + a][3 + b]));
    let mut schur = [[0.0; 3]; 3];
    for b in 0..3 {
        // Hrr⁻¹ Hrt's column b.
        let x = cholesky_solve(&hrr, &[h[3][b], h[4][b], h[5][b]])?;
        for a in 0..3 {
            schur[a][b] = h[a][b] - (0..3).map(|k| h[a][3 + k] * x[k]).sum::<f64>();
        }
    }
    for a in 0..3 {
        for b in 0..a {
            let m = 0.5 * (schur[a][b] + schur[b][a]);
            schur[a][b] = m;
            schur[b][a] = m;
        }
    }
    let (_, vectors) = symmetric_eigen(&schur);
    let v = DVec3::from_array(vectors[0]);
    v.is_finite().then_some(v)
}

/// Normal equations and counts of one ICP linearisation.
#[derive(Debug, Clone, Default)]
struct IcpSums {
    h: [[f64; 6]; 6],
    g: [f64; 6],
    valid: usize,
    matched: usize,
    inliers: usize,
    sq_residual: f64,
}

/// `h` with a small Levenberg damping, so that a nearly degenerate view still steps (the
/// verdict's conditioning test rejects it afterwards).
fn damped(h: &[[f64; 6]; 6]) -> [[f64; 6]; 6] {
    let mut d = *h;
    for i in 0..6 {
        d[i][i] += 1e-6 * h[i][i] + 1e-9;
    }
    d
}

/// Point-to-plane sums of `src`'s points moved by `dst_from_src` against `dst`'s maps
/// (projective association; pairs further than `gate` or with normals more than 30 degrees
/// apart are not used; Huber weights at 5 mm), with left-perturbation Jacobians in the
/// order (translation, rotation).
fn icp_sums(src: &CloudLevel, dst: &CloudLevel, dst_from_src: &DAffine3, gate: f32) -> IcpSums {
    const HUBER: f64 = 0.005;
    let min_cos = 30f32.to_radians().cos();
    let r = dst_from_src.matrix3.as_mat3();
    let t = dst_from_src.translation.as_vec3();
    let k = dst.k;
    let (w, h) = (k.width as i64, k.height as i64);
    let mut s = IcpSums::default();
    for (p, n) in src.vertices.iter().zip(&src.normals) {
        if !(p.z > 0.0 && n.is_finite()) {
            continue;
        }
        s.valid += 1;
        let q = r * *p + t;
        if !(q.z > 0.0) {
            continue;
        }
        let u = (k.fx * q.x / q.z + k.cx).round();
        let v = (k.fy * q.y / q.z + k.cy).round();
        if !(u >= 0.0 && v >= 0.0 && (u as i64) < w && (v as i64) < h) {
            continue;
        }
        let i = v as usize * w as usize + u as usize;
        let (dv, dn) = (dst.vertices[i], dst.normals[i]);
        if !(dv.z > 0.0 && dn.is_finite()) {
            continue;
        }
        s.matched += 1;
        let diff = q - dv;
        if !(diff.length() <= gate) {
            continue;
        }
        s.inliers += 1;
        let res = dn.dot(diff) as f64;
        s.sq_residual += res * res;
        if (r * *n).dot(dn) < min_cos {
            continue;
        }
        let weight = if res.abs() <= HUBER { 1.0 } else { HUBER / res.abs() };
        let qd = q.as_dvec3();
        let nd = dn.as_dvec3();
        let rot = qd.cross(nd);
        let j = [nd.x, nd.y, nd.z, rot.x, rot.y, rot.z];
        // The upper triangle only (the matrix is symmetric): 21 products a point, not 36.
        for a in 0..6 {
            let wj = weight * j[a];
            s.g[a] += wj * res;
            for b in a..6 {
                s.h[a][b] += wj * j[b];
            }
        }
    }
    for a in 1..6 {
        for b in 0..a {
            s.h[a][b] = s.h[b][a];
        }
    }
    s
}

/// The block-mean depth of `frame` at `1 / factor` resolution as a cloud level.
fn downscale_depth(frame: &Frame, factor: usize) -> CloudLevel {
    let (w, h) = (frame.intrinsics.width as usize, frame.intrinsics.height as usize);
    let (dw, dh) = (w / factor, h / factor);
    let mut depth = vec![0.0f32; dw * dh];
    let mut block = Vec::with_capacity(factor * factor);
    for by in 0..dh {
        for bx in 0..dw {
            block.clear();
            for y in by * factor..(by + 1) * factor {
                for x in bx * factor..(bx + 1) * factor {
                    let d = frame.depth.get(y * w + x).copied().unwrap_or(0.0);
                    if d > 0.0 && d.is_finite() {
                        block.push(d);
                    }
                }
            }
            depth[by * dw + bx] = agreeing_mean(&mut block, factor * factor);
        }
    }
    let k = frame.intrinsics.scaled(dw as u32, dh as u32);
    level_from_depth(k, &depth)
}

/// Mean of the depths within the agreement band of their median; 0 when fewer than half of
/// `pixels` are kept.
fn agreeing_mean(block: &mut [f32], pixels: usize) -> f32 {
    if block.len() * 2 < pixels {
        return 0.0;
    }
    block.sort_by(f32::total_cmp);
    let median = block[block.len() / 2];
    let band = BLOCK_AGREEMENT * median * median;
    let (mut sum, mut n) = (0.0f32, 0usize);
    for &d in block.iter() {
        if (d - median).abs() <= band {
            sum += d;
            n += 1;
        }
    }
    if n * 2 < pixels {
        0.0
    } else {
        sum / n as f32
    }
}

/// The depths of a level back from its vertices (0 where invalid).
fn fine_depth_of(level: &CloudLevel) -> Vec<f32> {
    level.vertices.iter().map(|v| if v.z > 0.0 { v.z } else { 0.0 }).collect()
}

/// 2x2 block means of agreeing depths.
fn halve(depth: &[f32], w: usize, h: usize) -> Vec<f32> {
    let (hw, hh) = (w / 2, h / 2);
    let mut out = vec![0.0f32; hw * hh];
    let mut block = Vec::with_capacity(4);
    for y in 0..hh {
        for x in 0..hw {
            block.clear();
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let d = depth[(2 * y + dy) * w + 2 * x + dx];
                if d > 0.0 {
                    block.push(d);
                }
            }
            out[y * hw + x] = agreeing_mean(&mut block, 4);
        }
    }
    out
}

/// Vertices and normals (central differences, oriented towards the camera) of a depth map.
fn level_from_depth(k: Intrinsics, depth: &[f32]) -> CloudLevel {
    let (w, h) = (k.width as usize, k.height as usize);
    let nan = Vec3::splat(f32::NAN);
    let vertices: Vec<Vec3> = (0..w * h)
        .map(|i| {
            let d = depth[i];
            if d > 0.0 {
                let (u, v) = ((i % w) as f32, (i / w) as f32);
                Vec3::new((u - k.cx) / k.fx * d, (v - k.cy) / k.fy * d, d)
            } else {
                nan
            }
        })
        .collect();
    let normals = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            if x == 0 || y == 0 || x + 1 >= w || y + 1 >= h {
                return nan;
            }
            let (l, r, u, d) = (vertices[i - 1], vertices[i + 1], vertices[i - w], vertices[i + w]);
            let c = vertices[i];
            // Neighbours across a depth edge would tilt the normal: at most 5 cm at 1 m.
            let near = |p: Vec3| p.z > 0.0 && (p.z - c.z).abs() <= 0.05 * c.z * c.z.max(1.0);
            if !(c.z > 0.0 && near(l) && near(r) && near(u) && near(d)) {
                return nan;
            }
            let n = (r - l).cross(d - u);
            let n = n.normalize_or_zero();
            if n == Vec3::ZERO {
                return nan;
            }
            if n.dot(c) > 0.0 {
                -n
            } else {
                n
            }
        })
        .collect();
    CloudLevel { k, vertices, normals }
}

mod features;
#[cfg(test)]
mod tests;
