//! Frame-to-model camera tracking: the pose of each new frame found by aligning its depth
//! (and, optionally, its intensity) against the map ray-cast at the previous pose.
//!
//! Per frame: a three-level depth pyramid (full, half, quarter resolution; each level
//! averages the valid depths of a 2x2 block that agree with their median, so that depth
//! edges are not blurred into phantom surfaces), vertices and normals per level, then
//! coarse-to-fine Gauss-Newton on SE(3) starting from a constant-velocity prediction. Each
//! iteration associates every frame vertex projectively with the ray-cast model (the model
//! pixel it lands on, rejected beyond a distance or a normal angle), and minimises the
//! point-to-plane distances plus, where colour is registered to depth and the weight is
//! non-zero, intensity differences, both under Huber weights.
//!
//! Each level's visited pixels with a depth and a normal are gathered once per frame into
//! structure-of-arrays blocks of rows; every iteration associates them eight at a time
//! (AVX2 intrinsics in `avx2.rs` where the CPU has them, picked at run time, with the
//! portable lanes' bits), sums the
//! normal equations per lane in f32 and per fixed block in f64, and adds the blocks in
//! order, so poses are bit-identical for any rayon thread count; a level stops iterating
//! once the update is negligible. (The photometric term keeps a scalar per-pixel path.) The model is
//! ray-cast at a reduced resolution (default a quarter) every `model_interval` tracked
//! frames and serves every pyramid level; the last tracked frame's depth bounds where the
//! march runs, which removes most of its cost.
//!
//! A quality check (inlier ratio, residual, jump from the prediction, conditioning of the
//! system) declares the frame lost instead of returning a doubtful pose; the caller then
//! does not fuse it, so a bad frame never damages the map. Tracking resumes from the last
//! good pose with the next frame.

// Comparisons are written negated on purpose, so that NaN fails them; index loops mirror
// the matrix formulas they implement.
#![allow(clippy::neg_cmp_op_on_partial_ord, clippy::needless_range_loop)]

use std::sync::Arc;
use std::time::Instant;

use glam::{Affine3A, Mat3, Quat, Vec2, Vec3};
use rayon::prelude::*;
use semrecon_data::{Frame, Intrinsics};
use wide::f32x8;

use crate::error::{ReconError, Result};
use crate::linalg::{cholesky_solve, symmetric_eigen};
use crate::map::TsdfMap;
use crate::raycast::{raycast_with, ModelView};

#[cfg(target_arch = "x86_64")]
mod avx2;

/// Pyramid levels (0 = input resolution).
pub const LEVELS: usize = 3;

/// Gauss-Newton stops at a level once an update is smaller than this (radians and metres
/// together): 10 µm at most, a tenth of what depth noise moves the estimate by, and it
/// ends most coarse levels after three or four of their iterations (7-Scenes: the same
/// trajectory error as 1e-6, a quarter less association work).
const CONVERGED_STEP: f64 = 1e-5;

/// Rows per block of the normal-equation reduction (fixed, so the summation order does not
/// depend on the thread count).
const ROWS_PER_BLOCK: usize = 8;

/// Parameters of [`Tracker`].
#[derive(Debug, Clone, PartialEq)]
pub struct TrackerConfig {
    /// Gauss-Newton iterations per pyramid level, finest (input resolution) first; a level
    /// with 0 iterations is skipped.
    pub iterations: [usize; LEVELS],
    /// The model is ray-cast at the input resolution divided by this (1, 2 or 4; the
    /// default 4 casts 160x120 rays for a 640x480 sensor: on 7-Scenes a 320x240 model
    /// costs four times as much for the same trajectory error).
    pub model_downscale: u32,
    /// Depths outside `min_depth..=max_depth` metres (and non-finite ones) are ignored.
    pub min_depth: f32,
    /// See `min_depth`.
    pub max_depth: f32,
    /// Association rejects pairs further apart than this many metres at the finest level
    /// (doubled per coarser level).
    pub max_distance: f32,
    /// Association rejects pairs whose normals differ by more than this angle, radians.
    pub max_normal_angle: f32,
    /// Huber threshold of the point-to-plane residual, metres at 1 m depth (residuals are
    /// normalised by depth squared, the growth of depth noise).
    pub huber_geometric: f32,
    /// Weight of the photometric term relative to the geometric one (intensity in 0..1
    /// against metres; 0 turns it off). Only meaningful when colour is registered to depth.
    pub photometric_weight: f32,
    /// Huber threshold of the intensity residual (intensity in 0..1).
    pub huber_photometric: f32,
    /// Lost when fewer than this fraction of the frame pixels that land on the model lie
    /// within `max_distance` of it (the normal test is left out here, see
    /// [`TrackingResult::inlier_ratio`]).
    pub min_inlier_ratio: f32,
    /// Lost when fewer than this fraction of the valid pixels land on the model.
    pub min_overlap: f32,
    /// Lost when the RMS point-to-plane residual of the inliers, normalised to 1 m depth
    /// (divided by depth squared, as depth noise grows), exceeds this many metres.
    pub max_residual: f32,
    /// Lost when the estimate is further than this many metres from the prediction.
    pub max_translation_jump: f32,
    /// Lost when the estimate turns more than this many radians away from the prediction.
    pub max_rotation_jump: f32,
    /// Directions whose scale-normalised eigenvalue is below this fraction of the largest
    /// count as unconstrained (a plane or a corridor leaves motions unconstrained; see
    /// `min_constrained`). The default 1e-4 lets a floor with a few chair legs on it hold
    /// the slide along the floor: at 1e-3 a rendered scan drifted 63 mm over 40 frames of
    /// such a view (0.55 mm at 1e-4), and a 900-frame one 27 mm (6.3 mm). One generated
    /// scan of twenty did worse (a bare wall with a thin door-frame strip, whose weak
    /// constraint misleads: 32 -> 49 mm); the rest and 7-Scenes are unchanged.
    pub min_condition: f64,
    /// Fewest motion directions (of six) the alignment must constrain for the frame to
    /// count as tracked. Directions whose scale-normalised eigenvalue is below
    /// `min_condition` times the largest are left at the constant-velocity prediction and
    /// the rest are aligned, instead of declaring the frame lost: a glance at a ceiling
    /// corner or along a bare wall leaves a slide along it unconstrained, and a frame lost
    /// there is never fused, so the map never grows into the new view and tracking stays
    /// lost while the camera moves on (a 900-frame rendered scan lost its last 317 frames
    /// that way). A sliding error along a plane barely changes what is fused of that plane.
    /// 6 restores the strict check (any unconstrained direction: lost).
    pub min_constrained: usize,
    /// Fewer valid depth pixels than this fraction of the image: lost (nothing to align).
    pub min_valid_ratio: f32,
    /// A keyframe every this many tracked frames (the first frame is one).
    pub keyframe_interval: usize,
    /// The finest level associates every `fine_stride`-th pixel in both directions (1 = all):
    /// neighbouring pixels of a 640x480 frame carry nearly the same constraint, and the
    /// finest level's iterations cost more than the rest of tracking at stride 1 (7-Scenes:
    /// the same trajectory error at 2). The default 2 suits 640x480; use 1 at 320x240 and
    /// below, where a strided finest level has no more pixels than the next one.
    pub fine_stride: usize,
    /// The model is ray-cast anew after this many tracked frames and reused in between
    /// (frames are aligned to the view cast at an earlier pose; 1 casts every frame). The
    /// ray-cast is the largest cost of tracking, and a model a frame or two old differs
    /// from the current one only by what those frames added. The default 4 casts a quarter
    /// of the frames: on 7-Scenes (500 frames) the trajectory error is the same for 2, 3 and
    /// 4 (25.8 / 25.8 / 25.7 mm; rendered `synth:3` 2.84 / 2.82 / 2.81 mm), and with the
    /// narrower march of session 5 4 is a little better than 3 everywhere measured
    /// (7-Scenes 25.53 / 25.68 mm, at a 10-voxel truncation 26.57 / 26.64 mm, `synth:1`
    /// 4.42 / 4.60 mm, `synth:3` 2.80 / 2.81 mm) for a fifth less mean tracking CPU.
    pub model_interval: usize,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            iterations: [2, 4, 8],
            model_downscale: 4,
            min_depth: 0.1,
            max_depth: 5.0,
            max_distance: 0.05,
            max_normal_angle: 45f32.to_radians(),
            huber_geometric: 0.005,
            photometric_weight: 0.0,
            huber_photometric: 0.1,
            min_inlier_ratio: 0.5,
            min_overlap: 0.2,
            max_residual: 0.01,
            max_translation_jump: 0.15,
            max_rotation_jump: 20f32.to_radians(),
            min_condition: 1e-4,
            min_constrained: 3,
            min_valid_ratio: 0.05,
            keyframe_interval: 10,
            fine_stride: 2,
            model_interval: 4,
        }
    }
}

impl TrackerConfig {
    /// Checks every field against its documented range.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(ReconError::InvalidConfig(m));
        if ![1, 2, 4].contains(&self.model_downscale) {
            return bad(format!("model downscale {} is not 1, 2 or 4", self.model_downscale));
        }
        if self.iterations.iter().all(|&i| i == 0) || self.iterations.iter().any(|&i| i > 100) {
            return bad(format!("iterations {:?}: need at least one, at most 100 per level", self.iterations));
        }
        if !(self.min_depth >= 0.0 && self.min_depth < self.max_depth && self.max_depth.is_finite()) {
            return bad(format!("depth range {}..{} m is empty or not finite", self.min_depth, self.max_depth));
        }
        let positive = [
            ("max_distance", self.max_distance),
            ("max_normal_angle", self.max_normal_angle),
            ("huber_geometric", self.huber_geometric),
            ("huber_photometric", self.huber_photometric),
            ("max_residual", self.max_residual),
            ("max_translation_jump", self.max_translation_jump),
            ("max_rotation_jump", self.max_rotation_jump),
        ];
        for (name, v) in positive {
            if !(v > 0.0 && v.is_finite()) {
                return bad(format!("{name} = {v} must be positive and finite"));
            }
        }
        if !(self.photometric_weight >= 0.0 && self.photometric_weight.is_finite()) {
            return bad(format!("photometric weight {} must be >= 0", self.photometric_weight));
        }
        for (name, v) in [
            ("min_inlier_ratio", self.min_inlier_ratio),
            ("min_overlap", self.min_overlap),
            ("min_valid_ratio", self.min_valid_ratio),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return bad(format!("{name} = {v} is outside 0..1"));
            }
        }
        if !(0.0..1.0).contains(&self.min_condition) {
            return bad(format!("min_condition {} is outside 0..1", self.min_condition));
        }
        if !(1..=6).contains(&self.min_constrained) {
            return bad(format!("min_constrained {} is outside 1..=6", self.min_constrained));
        }
        if self.keyframe_interval == 0 {
            return bad("keyframe interval must be at least 1".into());
        }
        if !(1..=8).contains(&self.model_interval) {
            return bad(format!("model interval {} is outside 1..8", self.model_interval));
        }
        if !(1..=8).contains(&self.fine_stride) {
            return bad(format!("fine stride {} is outside 1..8", self.fine_stride));
        }
        Ok(())
    }
}

/// Why a frame was not tracked.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LostReason {
    /// Too few valid depth pixels.
    NoDepth,
    /// The ray-cast model is (nearly) empty at the last pose.
    NoModel,
    /// Too few pixels landed on the model, or too few of those agreed with it.
    FewInliers,
    /// The aligned residual is too large.
    LargeResidual,
    /// The estimate jumped too far from the motion prediction.
    PoseJump,
    /// The alignment leaves some motion unconstrained (or the system was singular).
    Degenerate,
}

/// What tracking made of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackingStatus {
    /// The first frame: its pose is the initial pose, nothing was aligned.
    Initialized,
    /// Aligned and passed the quality check.
    Tracked,
    /// Not tracked: do not fuse this frame.
    Lost(LostReason),
}

/// A keyframe: a frame index and its pose when it was tracked.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keyframe {
    /// The frame's index in its source.
    pub frame_index: usize,
    /// Its pose.
    pub world_from_camera: Affine3A,
}

/// The outcome of [`Tracker::track`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackingResult {
    /// Tracked, initialised or lost.
    pub status: TrackingStatus,
    /// The frame's pose when tracked or initialised; the last good pose when lost.
    pub world_from_camera: Affine3A,
    /// Fraction of the frame pixels landing on the model that lie within `max_distance` of
    /// it (finest level used). Pairs whose normals disagree count: far from the sensor, depth
    /// noise alone turns many normals past the angle test.
    pub inlier_ratio: f32,
    /// RMS point-to-plane residual of the inliers, metres.
    pub residual_rms: f32,
    /// Smallest over largest eigenvalue of the scale-normalised normal matrix.
    pub condition: f64,
    /// How many of the six motion directions the alignment constrained (6 normally; fewer
    /// when some were kept at the motion prediction, see
    /// [`TrackerConfig::min_constrained`]).
    pub constrained: usize,
    /// Whether this frame became a keyframe.
    pub keyframe: bool,
    /// Wall time of the model ray-cast, milliseconds (0 when the cached view was reused).
    pub raycast_ms: f64,
    /// Wall time of the whole call, milliseconds.
    pub total_ms: f64,
}

impl TrackingResult {
    /// Whether the caller should fuse the frame at `world_from_camera`.
    pub fn should_fuse(&self) -> bool {
        !matches!(self.status, TrackingStatus::Lost(_))
    }
}

/// One pyramid level of the current frame.
struct Level {
    k: Intrinsics,
    depth: Vec<f32>,
    vertices: Vec<Vec3>,
    normals: Vec<Vec3>,
    /// Empty when the photometric term is off or the frame has no colour.
    intensity: Vec<f32>,
    valid: usize,
    /// The normals computed from this level's own vertices, which the next finer level takes
    /// (`normals` holds those of the next coarser level); empty on levels 0 and the coarsest.
    own_normals: Vec<Vec3>,
}

impl Level {
    /// The normal pixel `(x, y)` of depth `d` on the next finer level takes from this level:
    /// `normals` of the 2x2 block it lies in, when their depths agree within 5 % (pixels at
    /// depth edges get none).
    fn normal_for_finer(&self, normals: &[Vec3], x: usize, y: usize, d: f32) -> Option<Vec3> {
        let (cw, ch) = (self.k.width as usize, self.k.height as usize);
        let ci = (y / 2).min(ch - 1) * cw + (x / 2).min(cw - 1);
        (d > 0.0 && (d - self.depth[ci]).abs() <= 0.05 * d).then(|| normals[ci])
    }
}

/// The model view with its intensity image and gradients, ready for association.
struct Model {
    /// Shared with the tracker's cache (half a megabyte at 160x120: not copied a frame).
    view: Arc<ModelView>,
    intensity: Vec<f32>,
    /// Intensity gradient per pixel, NaN where a neighbour has no surface (both empty when
    /// the photometric term is off).
    gradient: Vec<Vec2>,
}

/// Sums of one block of pixels: normal equations and statistics.
#[derive(Clone, Copy)]
struct Normals {
    h: [[f64; 6]; 6],
    g: [f64; 6],
    sq_residual: f64,
    /// Squared residuals normalised by depth squared (noise at 1 m).
    sq_normalised: f64,
    inliers: u64,
    /// Pairs rejected by the distance test.
    far: u64,
    /// Pairs rejected by the normal test.
    turned: u64,
    /// Pixels with a valid depth among those visited.
    sampled: u64,
}

impl Normals {
    const ZERO: Self = Self {
        h: [[0.0; 6]; 6],
        g: [0.0; 6],
        sq_residual: 0.0,
        sq_normalised: 0.0,
        inliers: 0,
        far: 0,
        turned: 0,
        sampled: 0,
    };

    /// The plain f64 accumulation [`RowSums`] replaces (its test reference).
    #[cfg(test)]
    fn add(&mut self, j: [f64; 6], r: f64, w: f64) {
        for a in 0..6 {
            let wa = w * j[a];
            for b in a..6 {
                self.h[a][b] += wa * j[b];
            }
            self.g[a] += wa * r;
        }
    }

    fn merge(&mut self, o: &Self) {
        for a in 0..6 {
            for b in a..6 {
                self.h[a][b] += o.h[a][b];
            }
            self.g[a] += o.g[a];
        }
        self.sq_residual += o.sq_residual;
        self.sq_normalised += o.sq_normalised;
        self.inliers += o.inliers;
        self.far += o.far;
        self.turned += o.turned;
        self.sampled += o.sampled;
    }

    fn symmetric(&self) -> [[f64; 6]; 6] {
        let mut h = self.h;
        for a in 0..6 {
            for b in 0..a {
                h[a][b] = h[b][a];
            }
        }
        h
    }
}

/// Per-row partial sums of the normal equations in f32 SIMD lanes: lane `b` of `rows[a]`
/// sums `w j_a j_b` (`b < 6`) and lane 6 sums `w j_a r`. Six 8-lane multiply-adds per
/// pixel instead of 27 scalar f64 ones (the association visits up to 600 k pixels per
/// frame); the f32 sums cover at most one row of pixels before [`RowSums::flush`] adds them
/// into the f64 [`Normals`], so their rounding stays below 1e-5 relative, far below the
/// noise of the constraints.
#[derive(Clone, Copy)]
struct RowSums {
    rows: [f32x8; 6],
}

impl RowSums {
    const ZERO: Self = Self { rows: [f32x8::ZERO; 6] };

    /// Adds the constraint with Jacobian `j`, residual `r` and weight `w`.
    #[inline(always)]
    fn add(&mut self, j: [f32; 6], r: f32, w: f32) {
        let v = f32x8::from([j[0], j[1], j[2], j[3], j[4], j[5], r, 0.0]);
        for a in 0..6 {
            self.rows[a] = f32x8::splat(w * j[a]).mul_add(v, self.rows[a]);
        }
    }

    /// Adds the partial sums into `n` (upper triangle and gradient) and clears them.
    #[inline]
    fn flush(&mut self, n: &mut Normals) {
        for a in 0..6 {
            let lanes = self.rows[a].to_array();
            for b in a..6 {
                n.h[a][b] += lanes[b] as f64;
            }
            n.g[a] += lanes[6] as f64;
        }
        *self = Self::ZERO;
    }
}

/// Frame-to-model tracker: feed frames in order with [`Tracker::track`], fuse those whose
/// result says so.
#[derive(Debug, Clone)]
pub struct Tracker {
    config: TrackerConfig,
    initial_pose: Affine3A,
    /// Last good pose and the one before it (constant-velocity prediction).
    last: Option<Affine3A>,
    velocity: Affine3A,
    /// Depth of the last tracked frame at the model resolution (march start bound).
    last_depth: Option<Vec<f32>>,
    tracked: usize,
    keyframes: Vec<Keyframe>,
    cache: Option<CachedModel>,
}

/// The last model view, reused while neither the pose nor the map changed (after a lost
/// frame).
#[derive(Debug, Clone)]
struct CachedModel {
    /// Tracked frames accepted since the cast.
    age: usize,
    pose: Affine3A,
    stamp: (u64, usize),
    view: Arc<ModelView>,
}

impl Tracker {
    /// A tracker whose first frame gets the identity pose.
    pub fn new(config: TrackerConfig) -> Result<Self> {
        Self::with_initial_pose(config, Affine3A::IDENTITY)
    }

    /// A tracker whose first frame gets `world_from_camera`.
    pub fn with_initial_pose(config: TrackerConfig, world_from_camera: Affine3A) -> Result<Self> {
        config.validate()?;
        if !world_from_camera.is_finite() {
            return Err(ReconError::InvalidConfig("initial pose is not finite".into()));
        }
        Ok(Self {
            config,
            initial_pose: world_from_camera,
            last: None,
            velocity: Affine3A::IDENTITY,
            last_depth: None,
            tracked: 0,
            keyframes: Vec::new(),
            cache: None,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &TrackerConfig {
        &self.config
    }

    /// The last good pose (`None` before the first frame).
    pub fn pose(&self) -> Option<Affine3A> {
        self.last
    }

    /// Keyframes so far, in order.
    pub fn keyframes(&self) -> &[Keyframe] {
        &self.keyframes
    }

    /// Tracks `frame` against `map` (which should hold every frame fused so far).
    ///
    /// Errors only on a frame whose buffers do not match its camera; bad depth values,
    /// empty frames and failed alignments give [`TrackingStatus::Lost`].
    pub fn track(&mut self, frame: &Frame, map: &TsdfMap) -> Result<TrackingResult> {
        let t0 = Instant::now();
        let n = frame.intrinsics.pixel_count();
        if frame.depth.len() != n || (!frame.color.is_empty() && frame.color.len() != n) {
            return Err(ReconError::InvalidFrame {
                index: frame.index,
                message: format!(
                    "depth has {} and colour {} pixels, the camera {n}",
                    frame.depth.len(),
                    frame.color.len()
                ),
            });
        }
        let c = self.config.clone();
        let pyramid = build_pyramid(frame, &c);
        let last_pose = self.last.unwrap_or(self.initial_pose);
        let mut result = TrackingResult {
            status: TrackingStatus::Lost(LostReason::NoDepth),
            world_from_camera: last_pose,
            inlier_ratio: 0.0,
            residual_rms: 0.0,
            condition: 0.0,
            constrained: 0,
            keyframe: false,
            raycast_ms: 0.0,
            total_ms: 0.0,
        };
        let finish = |mut r: TrackingResult| {
            r.total_ms = t0.elapsed().as_secs_f64() * 1e3;
            Ok(r)
        };
        if (pyramid[0].valid as f32) < c.min_valid_ratio * n as f32 || pyramid[0].valid == 0 {
            return finish(result);
        }
        let model_level = c.model_downscale.trailing_zeros() as usize;
        let Some(last) = self.last else {
            result.status = TrackingStatus::Initialized;
            result.inlier_ratio = 1.0;
            result.condition = 1.0;
            result.constrained = 6;
            self.accept(frame, &mut result, &pyramid[model_level]);
            return finish(result);
        };

        // Model at the last pose (or a recent earlier one: `reference`).
        let t_cast = Instant::now();
        let (model, reference, cast) = self.model(map, last, pyramid[model_level].k);
        result.raycast_ms = if cast { t_cast.elapsed().as_secs_f64() * 1e3 } else { 0.0 };
        let model_valid = model.view.valid_count();
        if (model_valid as f32) < c.min_valid_ratio * model.view.vertices.len() as f32 {
            result.status = TrackingStatus::Lost(LostReason::NoModel);
            return finish(result);
        }

        // reference_from_current, predicted with constant velocity.
        let prediction = reference.inverse() * last * self.velocity;
        let mut estimate = prediction;
        let mut stats = Normals::ZERO;
        let mut singular = false;
        for level in (0..LEVELS).rev() {
            let iters = c.iterations[level];
            if iters == 0 {
                continue;
            }
            let data = &pyramid[level];
            let max_distance = c.max_distance * (1u32 << level) as f32;
            let stride = if level == 0 { c.fine_stride } else { 1 };
            // Without the photometric term, the level's points are gathered once for all
            // its iterations.
            let photometric = c.photometric_weight > 0.0 && !data.intensity.is_empty() && !model.intensity.is_empty();
            let points = (!photometric).then(|| LevelPoints::new(data, pyramid.get(level + 1), stride));
            for _ in 0..iters {
                stats = match &points {
                    Some(p) => p.normal_equations(&model, &estimate, max_distance, &c),
                    None => normal_equations(data, pyramid.get(level + 1), &model, &estimate, max_distance, stride, &c),
                };
                let h = stats.symmetric();
                let neg_g = stats.g.map(|v| -v);
                let Some(xi) = gauss_newton_step(&h, &neg_g, &c) else {
                    singular = true;
                    break;
                };
                estimate = se3_exp(xi) * estimate;
                estimate = orthonormalised(estimate);
                let step = xi.iter().map(|v| v * v).sum::<f64>().sqrt();
                if step < CONVERGED_STEP {
                    break;
                }
            }
            if singular {
                break;
            }
        }
        // Quality from the last iteration's sums (at the pose before its small final
        // step): a separate pass at the finest level would cost as much as an iteration.
        let overlap = stats.inliers + stats.far + stats.turned;
        // Agreement in position only: the normal test stays in the alignment, but at a few
        // metres a Kinect-like sensor's depth noise (2 cm at 3.5 m) turns half the frame's
        // normals past it while the pose is right, and a rendered scan that began facing a
        // room's far side was lost from its second frame to its last.
        result.inlier_ratio = (stats.inliers + stats.turned) as f32 / overlap.max(1) as f32;
        let overlap_ratio = overlap as f32 / stats.sampled.max(1) as f32;
        result.residual_rms = (stats.sq_residual / stats.inliers.max(1) as f64).sqrt() as f32;
        let (cond, constrained) = conditioning(&stats.symmetric(), c.min_condition);
        result.condition = cond;
        result.constrained = constrained;
        let jump = prediction.inverse() * estimate;
        let jump_t = Vec3::from(jump.translation).length();
        let jump_r = Quat::from_mat3a(&jump.matrix3).to_axis_angle().1;
        let jump_r = jump_r.min(std::f32::consts::TAU - jump_r);
        result.world_from_camera = reference * estimate;
        result.status = if singular || constrained < c.min_constrained {
            TrackingStatus::Lost(LostReason::Degenerate)
        } else if result.inlier_ratio < c.min_inlier_ratio || overlap_ratio < c.min_overlap {
            TrackingStatus::Lost(LostReason::FewInliers)
        } else if !((stats.sq_normalised / stats.inliers.max(1) as f64).sqrt() <= c.max_residual as f64) {
            TrackingStatus::Lost(LostReason::LargeResidual)
        } else if !(jump_t <= c.max_translation_jump
            && jump_r <= c.max_rotation_jump
            && result.world_from_camera.is_finite())
        {
            TrackingStatus::Lost(LostReason::PoseJump)
        } else {
            TrackingStatus::Tracked
        };
        if result.should_fuse() {
            self.velocity = orthonormalised(last.inverse() * result.world_from_camera);
            self.accept(frame, &mut result, &pyramid[model_level]);
        } else {
            result.world_from_camera = last;
            // A lost frame breaks the motion model: predict no motion next time.
            self.velocity = Affine3A::IDENTITY;
        }
        finish(result)
    }

    /// Moves the tracker into a corrected map frame after loop closure: its last pose and
    /// keyframes become `corrected_from_old` times what they were; the motion model (a
    /// relative motion) is kept, and the cached model view, cast from the old map, is dropped.
    pub fn correct(&mut self, corrected_from_old: Affine3A) {
        if let Some(last) = self.last {
            self.last = Some(orthonormalised(corrected_from_old * last));
        }
        for k in &mut self.keyframes {
            k.world_from_camera = orthonormalised(corrected_from_old * k.world_from_camera);
        }
        self.cache = None;
    }

    /// Continues from `world_from_camera` as if it were the last good pose, at rest, with no
    /// cached model (it belongs to the old pose) and `start_depth` (depth seen from the new
    /// pose, at the model's resolution) bounding the next ray-cast's march: for
    /// relocalisation.
    pub(crate) fn restart_at(&mut self, world_from_camera: Affine3A, start_depth: Option<Vec<f32>>) {
        self.last = Some(world_from_camera);
        self.velocity = Affine3A::IDENTITY;
        self.cache = None;
        self.last_depth = start_depth;
    }

    /// Records an accepted frame: pose, keyframe, march-start depth.
    fn accept(&mut self, frame: &Frame, result: &mut TrackingResult, model_level: &Level) {
        self.last = Some(result.world_from_camera);
        if let Some(cache) = &mut self.cache {
            cache.age += 1;
        }
        if self.tracked.is_multiple_of(self.config.keyframe_interval) {
            result.keyframe = true;
            self.keyframes.push(Keyframe { frame_index: frame.index, world_from_camera: result.world_from_camera });
        }
        self.tracked += 1;
        self.last_depth = Some(model_level.depth.clone());
    }

    /// The model view to align against and the pose it was cast from: the cached view while
    /// it is younger than `model_interval` tracked frames (or while neither the pose nor the
    /// map changed), else one cast now at `pose`; and whether it was cast now.
    fn model(&mut self, map: &TsdfMap, pose: Affine3A, k: Intrinsics) -> (Model, Affine3A, bool) {
        let stamp = (map.next_revision, map.chunk_count());
        let interval = self.config.model_interval;
        let cached = self.cache.take().filter(|m| {
            m.view.intrinsics == k && ((m.pose == pose && m.stamp == stamp) || (m.age > 0 && m.age < interval))
        });
        let (view, reference, age, cast) = match cached {
            Some(m) => (m.view, m.pose, m.age, false),
            None => (
                Arc::new(raycast_with(
                    map,
                    k,
                    pose,
                    self.config.min_depth,
                    self.config.max_depth,
                    self.last_depth.as_deref(),
                    self.config.photometric_weight > 0.0,
                )),
                pose,
                0,
                true,
            ),
        };
        self.cache = Some(CachedModel { age, pose: reference, stamp, view: Arc::clone(&view) });
        let (intensity, gradient) =
            if self.config.photometric_weight > 0.0 { model_intensity(&view) } else { (Vec::new(), Vec::new()) };
        (Model { view, intensity, gradient }, reference, cast)
    }
}

/// Intensity in 0..1 from sRGB (Rec. 601 luma).
#[inline]
fn luma(c: [u8; 3]) -> f32 {
    (0.299 * c[0] as f32 + 0.587 * c[1] as f32 + 0.114 * c[2] as f32) * (1.0 / 255.0)
}

/// The model's intensity image and its central-difference gradient.
fn model_intensity(view: &ModelView) -> (Vec<f32>, Vec<Vec2>) {
    let (w, h) = (view.intrinsics.width as usize, view.intrinsics.height as usize);
    let intensity: Vec<f32> =
        view.colors.iter().zip(&view.vertices).map(|(c, v)| if v.z > 0.0 { luma(*c) } else { f32::NAN }).collect();
    let mut gradient = vec![Vec2::NAN; w * h];
    gradient.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        if y == 0 || y + 1 >= h {
            return;
        }
        for x in 1..w.saturating_sub(1) {
            let i = y * w + x;
            let gx = 0.5 * (intensity[i + 1] - intensity[i - 1]);
            let gy = 0.5 * (intensity[i + w] - intensity[i - w]);
            row[x] = Vec2::new(gx, gy);
        }
    });
    (intensity, gradient)
}

/// The depth pyramid with vertices, normals and intensity per level.
fn build_pyramid(frame: &Frame, c: &TrackerConfig) -> Vec<Level> {
    let k0 = frame.intrinsics;
    // Filtered and counted in one pass, bands of rows in parallel (a plain loop per band,
    // which the compiler vectorises). A kept depth is positive: `-0.0` becomes `0.0`, which
    // every later test reads as missing all the same.
    let band = 16 * k0.width as usize;
    let mut depth0 = vec![0.0f32; frame.depth.len()];
    let valid0: usize = depth0
        .par_chunks_mut(band)
        .zip(frame.depth.par_chunks(band))
        .map(|(out, src)| {
            let mut valid = 0;
            for (o, &d) in out.iter_mut().zip(src) {
                // NaN fails every comparison, and the range is finite.
                let keep = (d > 0.0) & (d >= c.min_depth) & (d <= c.max_depth);
                *o = if keep { d } else { 0.0 };
                valid += keep as usize;
            }
            valid
        })
        .sum();
    // Intensity only feeds the photometric term: empty at every level when it is off.
    let intensity0: Vec<f32> = if frame.color.is_empty() || c.photometric_weight <= 0.0 {
        Vec::new()
    } else {
        frame.color.iter().map(|&c| luma(c)).collect()
    };
    // Level 0 takes its normals from level 1, and its vertices are one multiply-add away from
    // its depth: both are formed where association visits a pixel (a stride of them).
    let mut levels = vec![Level {
        k: k0,
        depth: depth0,
        vertices: Vec::new(),
        normals: Vec::new(),
        intensity: intensity0,
        valid: valid0,
        own_normals: Vec::new(),
    }];
    for _ in 1..LEVELS {
        let prev = levels.last().expect("level 0 exists");
        let (pw, ph) = (prev.k.width as usize, prev.k.height as usize);
        let (w, h) = ((pw / 2).max(1), (ph / 2).max(1));
        let k = prev.k.scaled(w as u32, h as u32);
        let mut depth = vec![0.0f32; w * h];
        let mut intensity = vec![0.0f32; if prev.intensity.is_empty() { 0 } else { w * h }];
        let has_intensity = !intensity.is_empty();
        depth.par_chunks_mut(w).enumerate().for_each(|(y, drow)| {
            // A row past the edge (odd heights) reads as invalid, as does a column.
            let src_row = |sy: usize| if sy < ph { &prev.depth[sy * pw..(sy + 1) * pw] } else { &[][..] };
            block_depth_row(src_row(2 * y), src_row(2 * y + 1), drow);
        });
        if has_intensity {
            intensity.par_chunks_mut(w).enumerate().for_each(|(y, irow)| {
                for (x, out) in irow.iter_mut().enumerate() {
                    let (mut inten, mut m) = (0.0, 0);
                    for (sx, sy) in [(2 * x, 2 * y), (2 * x + 1, 2 * y), (2 * x, 2 * y + 1), (2 * x + 1, 2 * y + 1)] {
                        if sx < pw && sy < ph {
                            inten += prev.intensity[sy * pw + sx];
                            m += 1;
                        }
                    }
                    if m > 0 {
                        *out = inten / m as f32;
                    }
                }
            });
        }
        levels.push(make_level(k, depth, intensity, true));
    }
    // Normals of a level come from the next coarser level: neighbouring pixels of a noisy,
    // disparity-quantised depth image differ by about as much in depth as in position, so
    // their normals scatter by tens of degrees; the coarser level averages 2x2 blocks and
    // spans twice the baseline. Pixels whose depth disagrees with the coarse one (edges)
    // get none.
    for l in 1..LEVELS - 1 {
        let (fine, coarse) = levels.split_at_mut(l + 1);
        let (fine, coarse) = (&mut fine[l], &coarse[0]);
        let w = fine.k.width as usize;
        let fine_depth = &fine.depth;
        fine.own_normals = fine.normals.clone();
        fine.normals.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, n) in row.iter_mut().enumerate() {
                *n = coarse.normal_for_finer(&coarse.normals, x, y, fine_depth[y * w + x]).unwrap_or(Vec3::ZERO);
            }
        });
    }
    levels
}

/// The depth of a 2x2 block (0 = invalid in and out): the mean of its valid depths within
/// 3% of their median (the lower one of an even count), summed in ascending order.
#[inline]
fn block_depth(block: [f32; 4]) -> f32 {
    let n = block.iter().filter(|&&d| d > 0.0).count();
    if n == 0 {
        return 0.0;
    }
    // Invalid depths sort last, past the `n` valid ones.
    let mut vals = block.map(|d| if d > 0.0 { d } else { f32::INFINITY });
    sort4(&mut vals);
    let median = vals[(n - 1) / 2];
    let (mut sum, mut cnt) = (0.0f32, 0u32);
    for (k, &d) in vals.iter().enumerate() {
        let keep = k < n && (d - median).abs() <= 0.03 * median;
        // Adding 0 to a positive sum leaves its bits: the same as skipping.
        sum += if keep { d } else { 0.0 };
        cnt += keep as u32;
    }
    sum / cnt as f32
}

/// One row of 2x2 block depths from two source rows (`out[x]` from columns `2x, 2x + 1`; a
/// missing row or column reads as invalid): [`block_depth`] eight blocks at a time where
/// all their columns exist, the same operations per lane (the same bits, tested), else
/// block by block.
fn block_depth_row(r0: &[f32], r1: &[f32], out: &mut [f32]) {
    let full = if r0.len() == r1.len() { (r0.len() / 2).min(out.len()) / LANES * LANES } else { 0 };
    for (x8, o) in out[..full].chunks_exact_mut(LANES).enumerate() {
        let base = 2 * LANES * x8;
        let col = |r: &[f32], odd: usize| f32x8::new(std::array::from_fn(|l| r[base + 2 * l + odd]));
        o.copy_from_slice(&block_depth_lanes([col(r0, 0), col(r0, 1), col(r1, 0), col(r1, 1)]).to_array());
    }
    let at = |r: &[f32], sx: usize| r.get(sx).copied().unwrap_or(0.0);
    for (x, d) in out.iter_mut().enumerate().skip(full) {
        *d = block_depth([at(r0, 2 * x), at(r0, 2 * x + 1), at(r1, 2 * x), at(r1, 2 * x + 1)]);
    }
}

/// [`block_depth`] of eight blocks, one per lane (the four depths of block `l` in lane `l`
/// of `block[0..4]`): the same comparisons, selections and sums in the same order, without
/// the branches.
#[inline]
fn block_depth_lanes(block: [f32x8; 4]) -> f32x8 {
    let (zero, one) = (f32x8::ZERO, f32x8::ONE);
    let valid = block.map(|d| d.simd_gt(zero));
    let n = valid.iter().fold(zero, |n, &m| n + m.select(one, zero));
    let mut v: [f32x8; 4] = std::array::from_fn(|k| valid[k].select(block[k], f32x8::splat(f32::INFINITY)));
    // `sort4`'s network; depths are never NaN and never -0, so min and max need no care.
    for (i, j) in [(0, 1), (2, 3), (0, 2), (1, 3), (1, 2)] {
        let (a, b) = (v[i], v[j]);
        v[i] = a.fast_min(b);
        v[j] = a.fast_max(b);
    }
    // The lower median: the second value of three or four, else the first.
    let median = n.simd_ge(f32x8::splat(3.0)).select(v[1], v[0]);
    let tolerance = f32x8::splat(0.03) * median;
    let (mut sum, mut count) = (zero, zero);
    for (k, &d) in v.iter().enumerate() {
        let keep = n.simd_gt(f32x8::splat(k as f32)) & (d - median).abs().simd_le(tolerance);
        sum += keep.select(d, zero);
        count += keep.select(one, zero);
    }
    n.simd_gt(zero).select(sum / count, zero)
}

/// Sorts four depths ascending with a five-comparison network (the pyramid's median of a
/// 2x2 block; a library sort is an out-of-line call per block). Depths are never NaN.
#[inline]
fn sort4(v: &mut [f32; 4]) {
    let mut cmp = |i: usize, j: usize| {
        let (a, b) = (v[i], v[j]);
        v[i] = a.min(b);
        v[j] = a.max(b);
    };
    cmp(0, 1);
    cmp(2, 3);
    cmp(0, 2);
    cmp(1, 3);
    cmp(1, 2);
}

/// `(u - cx) / fx` per column and `(v - cy) / fy` per row: [`Intrinsics::unproject`] is
/// these times the depth, so the table gives its bits without its two divisions a pixel.
struct RayTable {
    x: Vec<f32>,
    y: Vec<f32>,
}

impl RayTable {
    fn new(k: Intrinsics) -> Self {
        Self {
            x: (0..k.width).map(|u| (u as f32 - k.cx) / k.fx).collect(),
            y: (0..k.height).map(|v| (v as f32 - k.cy) / k.fy).collect(),
        }
    }

    /// `k.unproject(x, y, d)`, bit for bit.
    #[inline]
    fn unproject(&self, x: usize, y: usize, d: f32) -> Vec3 {
        Vec3::new(self.x[x] * d, self.y[y] * d, d)
    }
}

/// Vertices and normals of one level.
fn make_level(k: Intrinsics, depth: Vec<f32>, intensity: Vec<f32>, with_normals: bool) -> Level {
    let (w, h) = (k.width as usize, k.height as usize);
    let mut vertices = vec![Vec3::ZERO; w * h];
    let rays = RayTable::new(k);
    vertices.par_chunks_mut(w).zip(depth.par_chunks(w)).enumerate().for_each(|(y, (row, drow))| {
        for (x, (p, &d)) in row.iter_mut().zip(drow).enumerate() {
            if d > 0.0 {
                *p = rays.unproject(x, y, d);
            }
        }
    });
    let mut normals = vec![Vec3::ZERO; w * h];
    normals.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        if !with_normals || y == 0 || y + 1 >= h {
            return;
        }
        let inner = w.saturating_sub(2);
        let lanes_end = 1 + inner / LANES * LANES;
        for x in (1..lanes_end).step_by(LANES) {
            row[x..x + LANES].copy_from_slice(&normals_lanes(&rays, &depth, w, x, y));
        }
        for x in lanes_end..w.saturating_sub(1) {
            row[x] = pixel_normal(&vertices, w, y * w + x);
        }
    });
    let valid = depth.iter().filter(|&&d| d > 0.0).count();
    Level { k, depth, vertices, normals, intensity, valid, own_normals: Vec::new() }
}

/// The normal of inner pixel `i` of a level from its four neighbours' vertices (zero where
/// a neighbour is missing or more than 5% of the depth away: a depth edge), facing the
/// camera.
#[inline]
fn pixel_normal(vertices: &[Vec3], w: usize, i: usize) -> Vec3 {
    let p = vertices[i];
    if p.z <= 0.0 {
        return Vec3::ZERO;
    }
    let (l, r, u, d) = (vertices[i - 1], vertices[i + 1], vertices[i - w], vertices[i + w]);
    let jump = 0.05 * p.z;
    if [l, r, u, d].iter().any(|q| q.z <= 0.0 || (q.z - p.z).abs() > jump) {
        return Vec3::ZERO;
    }
    let n = (d - u).cross(r - l);
    let len = n.length();
    if !(len > 0.0) {
        return Vec3::ZERO;
    }
    let n = n / len;
    if n.dot(p) > 0.0 {
        -n
    } else {
        n
    }
}

/// [`pixel_normal`] of the eight inner pixels `x..x + 8` of row `y`, one per lane, with the
/// vertices formed from the depths as [`RayTable::unproject`] forms them (contiguous loads
/// instead of interleaved vectors): the same operations in the same order, so the same
/// bits (tested).
#[inline]
fn normals_lanes(rays: &RayTable, depth: &[f32], w: usize, x: usize, y: usize) -> [Vec3; LANES] {
    let load = |s: &[f32], at: usize| f32x8::new(std::array::from_fn(|l| s[at + l]));
    let i = y * w + x;
    let (dp, dl, dr, du, dd) =
        (load(depth, i), load(depth, i - 1), load(depth, i + 1), load(depth, i - w), load(depth, i + w));
    let (rx, rxl, rxr) = (load(&rays.x, x), load(&rays.x, x - 1), load(&rays.x, x + 1));
    let (ry, ryu, ryd) = (f32x8::splat(rays.y[y]), f32x8::splat(rays.y[y - 1]), f32x8::splat(rays.y[y + 1]));
    let zero = f32x8::ZERO;
    let jump = f32x8::splat(0.05) * dp;
    // Depths are never NaN: `!(a > b)` is `a <= b`.
    let mut ok = dp.simd_gt(zero);
    for q in [dl, dr, du, dd] {
        ok &= q.simd_gt(zero) & (q - dp).abs().simd_le(jump);
    }
    let p = [rx * dp, ry * dp, dp];
    let (l, r) = ([rxl * dl, ry * dl, dl], [rxr * dr, ry * dr, dr]);
    let (u, d) = ([rx * du, ryu * du, du], [rx * dd, ryd * dd, dd]);
    let a = [d[0] - u[0], d[1] - u[1], d[2] - u[2]];
    let b = [r[0] - l[0], r[1] - l[1], r[2] - l[2]];
    // glam's `cross`, `length`, division and `dot`, operation for operation.
    let n = [a[1] * b[2] - b[1] * a[2], a[2] * b[0] - b[2] * a[0], a[0] * b[1] - b[0] * a[1]];
    let len = ((n[0] * n[0] + n[1] * n[1]) + n[2] * n[2]).sqrt();
    ok &= len.simd_gt(zero);
    let n = n.map(|c| c / len);
    let flip = ((n[0] * p[0] + n[1] * p[1]) + n[2] * p[2]).simd_gt(zero);
    let n = n.map(|c| ok.select(flip.select(-c, c), zero).to_array());
    std::array::from_fn(|l| Vec3::new(n[0][l], n[1][l], n[2][l]))
}

/// Normal equations of one Gauss-Newton step at `estimate` (`reference_from_current`: the model view's camera from the frame's).
/// Visits every `stride`-th pixel of every `stride`-th row. A level without vertices
/// (level 0) forms them from its depth and takes its normals from `coarse`, the next level.
#[allow(clippy::too_many_arguments)]
fn normal_equations(
    data: &Level,
    coarse: Option<&Level>,
    model: &Model,
    estimate: &Affine3A,
    max_distance: f32,
    stride: usize,
    c: &TrackerConfig,
) -> Normals {
    let w = data.k.width as usize;
    let h = data.k.height as usize;
    let mk = model.view.intrinsics;
    let (mw, mh) = (mk.width as usize, mk.height as usize);
    let rot = Mat3::from(estimate.matrix3);
    let trans = Vec3::from(estimate.translation);
    let min_cos = c.max_normal_angle.cos();
    let max_d2 = max_distance * max_distance;
    let photometric = c.photometric_weight > 0.0 && !data.intensity.is_empty() && !model.intensity.is_empty();
    let lambda = c.photometric_weight;
    let rows: Vec<usize> = (0..h).step_by(stride).collect();
    let blocks: Vec<Normals> = rows
        .par_chunks(ROWS_PER_BLOCK)
        .map(|rows| {
            let mut acc = Normals::ZERO;
            let mut sums = RowSums::ZERO;
            for &y in rows {
                sums.flush(&mut acc);
                for x in (0..w).step_by(stride) {
                    let i = y * w + x;
                    let d = data.depth[i];
                    acc.sampled += (d > 0.0) as u64;
                    let (p_cur, n_cur) = if data.vertices.is_empty() {
                        // As `build_pyramid` does for level 1 from level 2.
                        let Some(n) = coarse.and_then(|c| c.normal_for_finer(&c.own_normals, x, y, d)) else {
                            continue;
                        };
                        (data.k.unproject(x as f32, y as f32, d), n)
                    } else {
                        (data.vertices[i], data.normals[i])
                    };
                    if n_cur == Vec3::ZERO {
                        continue;
                    }
                    let q = rot * p_cur + trans;
                    if q.z <= 0.0 {
                        continue;
                    }
                    let uv = mk.project(q);
                    // Nearest model pixel; truncation is floor on the non-negative range
                    // kept (`floor` is a library call on baseline x86-64).
                    let (fu, fv) = (uv.x + 0.5, uv.y + 0.5);
                    if !(fu >= 0.0 && fv >= 0.0 && fu < mw as f32 && fv < mh as f32) {
                        continue;
                    }
                    let mi = fv as usize * mw + fu as usize;
                    let mvtx = model.view.vertices[mi];
                    if mvtx.z <= 0.0 {
                        continue;
                    }
                    let mn = model.view.normals[mi];
                    let diff = q - mvtx;
                    if diff.length_squared() > max_d2 {
                        acc.far += 1;
                        continue;
                    }
                    if (rot * n_cur).dot(mn) < min_cos {
                        acc.turned += 1;
                        continue;
                    }
                    let r = mn.dot(diff);
                    // Depth noise grows about with the square of depth: residuals are
                    // measured in units of the noise at 1 m (Huber on the normalised
                    // residual, information weight 1/scale²). Far points then no longer
                    // dominate, which matters because fusion biases the model surface by
                    // a fraction of the noise where it nears the truncation distance.
                    let scale = mvtx.z.max(0.5) * mvtx.z.max(0.5);
                    let wgt = huber(r / scale, c.huber_geometric) / (scale * scale);
                    // The lever arm from the model point, not the measured one: the measured
                    // point's depth noise is in the residual too, and a Jacobian correlated
                    // with the residual biases the solution (by a few millimetres per frame
                    // at Kinect noise levels).
                    let qxn = mvtx.cross(mn);
                    sums.add([qxn.x, qxn.y, qxn.z, mn.x, mn.y, mn.z], r, wgt);
                    let (r, scale) = (r as f64, scale as f64);
                    acc.sq_residual += r * r;
                    acc.sq_normalised += (r / scale) * (r / scale);
                    acc.inliers += 1;
                    if photometric {
                        if let Some((rp, jp)) = photometric_term(model, uv, q, data.intensity[i]) {
                            let wp = lambda * huber(rp, c.huber_photometric);
                            sums.add(jp, rp, wp);
                        }
                    }
                }
            }
            sums.flush(&mut acc);
            acc
        })
        .collect();
    let mut total = Normals::ZERO;
    for b in &blocks {
        total.merge(b);
    }
    total
}

/// Lanes of the vectorised association (one AVX register of f32).
const LANES: usize = 8;

/// The points of one pyramid level that association visits, gathered once per frame into
/// structure-of-arrays blocks: every pixel on the visited grid with a depth and a normal
/// (at the finest level formed from the depth and the next level, as [`normal_equations`]
/// does), in row-major order. The iterations of a level then run over dense lanes instead
/// of re-testing every pixel, and a block's eight lanes go through the same arithmetic
/// together.
struct LevelPoints {
    blocks: Vec<PointBlock>,
    /// Pixels with a valid depth among those visited (the overlap test's denominator).
    sampled: u64,
}

/// The points of [`ROWS_PER_BLOCK`] visited rows.
///
/// # Shapes
/// `coords[0..3]` are the vertex x, y, z and `coords[3..6]` the normal x, y, z, each `len`
/// long, then zero-padded to a multiple of [`LANES`].
struct PointBlock {
    coords: [Vec<f32>; 6],
    len: usize,
}

impl LevelPoints {
    /// Gathers the points of `data` on every `stride`-th pixel of every `stride`-th row; a
    /// level without vertices forms them from its depth and takes normals from `coarse`.
    fn new(data: &Level, coarse: Option<&Level>, stride: usize) -> Self {
        let (w, h) = (data.k.width as usize, data.k.height as usize);
        let rows: Vec<usize> = (0..h).step_by(stride).collect();
        let rays = RayTable::new(data.k);
        let blocks: Vec<(PointBlock, u64)> = rows
            .par_chunks(ROWS_PER_BLOCK)
            .map(|rows| {
                // Written by index into zeroed buffers sized for every visited pixel (the
                // padding is then already zero), not pushed: six capacity checks a point.
                let capacity = (rows.len() * w.div_ceil(stride)).next_multiple_of(LANES);
                let mut coords: [Vec<f32>; 6] = std::array::from_fn(|_| vec![0.0; capacity]);
                let [cx, cy, cz, cnx, cny, cnz] = &mut coords;
                let (mut len, mut sampled) = (0usize, 0u64);
                for &y in rows {
                    let drow = &data.depth[y * w..(y + 1) * w];
                    for x in (0..w).step_by(stride) {
                        let d = drow[x];
                        sampled += (d > 0.0) as u64;
                        let (p, n) = if data.vertices.is_empty() {
                            let Some(n) = coarse.and_then(|c| c.normal_for_finer(&c.own_normals, x, y, d)) else {
                                continue;
                            };
                            (rays.unproject(x, y, d), n)
                        } else {
                            let i = y * w + x;
                            (data.vertices[i], data.normals[i])
                        };
                        if n == Vec3::ZERO {
                            continue;
                        }
                        (cx[len], cy[len], cz[len]) = (p.x, p.y, p.z);
                        (cnx[len], cny[len], cnz[len]) = (n.x, n.y, n.z);
                        len += 1;
                    }
                }
                for v in &mut coords {
                    v.truncate(len.next_multiple_of(LANES));
                }
                (PointBlock { coords, len }, sampled)
            })
            .collect();
        let sampled = blocks.iter().map(|b| b.1).sum();
        Self { blocks: blocks.into_iter().map(|b| b.0).collect(), sampled }
    }

    /// The normal equations of one Gauss-Newton step at `estimate`, as [`normal_equations`]
    /// forms them without the photometric term: the same pairs, residuals and weights
    /// (bit for bit), summed per lane in f32 within a block (as many terms per lane as a
    /// row of the scalar path sums), then in f64.
    fn normal_equations(&self, model: &Model, estimate: &Affine3A, max_distance: f32, c: &TrackerConfig) -> Normals {
        let step = StepParams::new(model, estimate, max_distance, c);
        let blocks: Vec<Normals> = self.blocks.par_iter().map(|b| block_sums(b, &step)).collect();
        let mut total = Normals::ZERO;
        for b in &blocks {
            total.merge(b);
        }
        total.sampled = self.sampled;
        total
    }
}

/// What one association step needs, unpacked for the lanes.
struct StepParams<'a> {
    /// Rotation columns and translation of `reference_from_current`.
    rot: [[f32; 3]; 3],
    trans: [f32; 3],
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    mw: usize,
    mh: usize,
    vertices: &'a [Vec3],
    normals: &'a [Vec3],
    max_d2: f32,
    min_cos: f32,
    huber: f32,
}

impl<'a> StepParams<'a> {
    fn new(model: &'a Model, estimate: &Affine3A, max_distance: f32, c: &TrackerConfig) -> Self {
        let m = Mat3::from(estimate.matrix3);
        let k = model.view.intrinsics;
        Self {
            rot: [m.x_axis.to_array(), m.y_axis.to_array(), m.z_axis.to_array()],
            trans: Vec3::from(estimate.translation).to_array(),
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            mw: k.width as usize,
            mh: k.height as usize,
            vertices: &model.view.vertices,
            normals: &model.view.normals,
            max_d2: max_distance * max_distance,
            min_cos: c.max_normal_angle.cos(),
            huber: c.huber_geometric,
        }
    }

    /// Whether the model buffers cover every pixel index association can form, with
    /// component offsets (`3 i + 2`) that fit an `i32` (what the AVX2 gathers rely on).
    #[cfg(target_arch = "x86_64")]
    fn gather_safe(&self) -> bool {
        let pixels = self.mw * self.mh;
        self.vertices.len() >= pixels && self.normals.len() >= pixels && pixels <= (i32::MAX as usize) / 4
    }
}

/// [`block_sums_lanes`] in AVX2 intrinsics where the CPU has it (the same IEEE operations
/// in the same order, so both give the same bits), else the portable lanes.
fn block_sums(b: &PointBlock, s: &StepParams) -> Normals {
    #[cfg(target_arch = "x86_64")]
    if avx2_available() && s.gather_safe() {
        // SAFETY: the CPU has AVX2 and FMA (checked at run time), the model buffers cover
        // its pixels with i32 indices (checked above), and blocks are padded to whole lanes.
        return unsafe { avx2::block_sums(b, s) };
    }
    block_sums_lanes(b, s)
}

/// Whether the CPU has AVX2 and FMA (`SEMRECON_TRACKING_SIMD=portable` says no).
#[cfg(target_arch = "x86_64")]
fn avx2_available() -> bool {
    static AVX2: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *AVX2.get_or_init(|| {
        std::env::var("SEMRECON_TRACKING_SIMD").map_or(true, |v| v != "portable")
            && is_x86_feature_detected!("avx2")
            && is_x86_feature_detected!("fma")
    })
}

/// Per-lane sums of one block: the upper triangle of H (21, row by row) then g (6), the
/// squared residuals and the test counts, reduced to [`Normals`] in a fixed order.
struct LaneSums {
    sums: [[f32; LANES]; 27],
    sq_res: [f64; LANES],
    sq_norm: [f64; LANES],
    inliers: [u32; LANES],
    far: [u32; LANES],
    turned: [u32; LANES],
}

impl LaneSums {
    const ZERO: Self = Self {
        sums: [[0.0; LANES]; 27],
        sq_res: [0.0; LANES],
        sq_norm: [0.0; LANES],
        inliers: [0; LANES],
        far: [0; LANES],
        turned: [0; LANES],
    };

    fn into_normals(self) -> Normals {
        let mut n = Normals::ZERO;
        let mut k = 0;
        for a in 0..6 {
            for bb in a..6 {
                n.h[a][bb] = self.sums[k].iter().fold(0.0f64, |acc, &v| acc + v as f64);
                k += 1;
            }
            n.g[a] = self.sums[21 + a].iter().fold(0.0f64, |acc, &v| acc + v as f64);
        }
        n.sq_residual = self.sq_res.iter().sum();
        n.sq_normalised = self.sq_norm.iter().sum();
        n.inliers = self.inliers.iter().map(|&v| v as u64).sum();
        n.far = self.far.iter().map(|&v| v as u64).sum();
        n.turned = self.turned.iter().map(|&v| v as u64).sum();
        n
    }
}

/// The association and normal-equation sums of one block, [`LANES`] points at a time.
/// Written as per-lane loops over fixed-size arrays, which the compiler turns into vector
/// instructions of whatever width the enclosing function is compiled for; a rejected lane
/// contributes exact zeros.
#[inline(always)]
fn block_sums_lanes(b: &PointBlock, s: &StepParams) -> Normals {
    type L = [f32; LANES];
    let mut out = LaneSums::ZERO;
    let LaneSums { sums, sq_res, sq_norm, inliers, far, turned } = &mut out;
    let [r0, r1, r2] = s.rot;
    let t = s.trans;
    let (mwf, mhf) = (s.mw as f32, s.mh as f32);
    fn lanes(v: &[f32]) -> impl Iterator<Item = [f32; LANES]> + '_ {
        v.chunks_exact(LANES).map(|c| std::array::from_fn(|l| c[l]))
    }
    let [px, py, pz, nx, ny, nz] = &b.coords;
    let points = lanes(px).zip(lanes(py)).zip(lanes(pz)).zip(lanes(nx)).zip(lanes(ny)).zip(lanes(nz));
    for (g, (((((px, py), pz), nx), ny), nz)) in (0..b.len).step_by(LANES).zip(points) {
        let (mut qx, mut qy, mut qz) = ([0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES]);
        let mut mi = [0usize; LANES];
        let mut ok = [false; LANES];
        for l in 0..LANES {
            // glam's `rot * p + trans`, operation for operation.
            qx[l] = ((r0[0] * px[l] + r1[0] * py[l]) + r2[0] * pz[l]) + t[0];
            qy[l] = ((r0[1] * px[l] + r1[1] * py[l]) + r2[1] * pz[l]) + t[1];
            qz[l] = ((r0[2] * px[l] + r1[2] * py[l]) + r2[2] * pz[l]) + t[2];
            let fu = s.fx * qx[l] / qz[l] + s.cx + 0.5;
            let fv = s.fy * qy[l] / qz[l] + s.cy + 0.5;
            ok[l] = g + l < b.len && qz[l] > 0.0 && fu >= 0.0 && fv >= 0.0 && fu < mwf && fv < mhf;
            mi[l] = if ok[l] { fv as i32 as usize * s.mw + fu as i32 as usize } else { 0 };
        }
        // The model pixels (a gather: scalar loads).
        let (mut mx, mut my, mut mz, mut mnx, mut mny, mut mnz) =
            ([0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES]);
        for l in 0..LANES {
            let (v, n) = (s.vertices[mi[l]], s.normals[mi[l]]);
            (mx[l], my[l], mz[l], mnx[l], mny[l], mnz[l]) = (v.x, v.y, v.z, n.x, n.y, n.z);
        }
        let mut j: [L; 6] = [[0.0; LANES]; 6];
        let (mut r, mut wgt) = ([0.0f32; LANES], [0.0f32; LANES]);
        for l in 0..LANES {
            let on_model = ok[l] && mz[l] > 0.0;
            let (dx, dy, dz) = (qx[l] - mx[l], qy[l] - my[l], qz[l] - mz[l]);
            let is_far = on_model && (dx * dx + dy * dy) + dz * dz > s.max_d2;
            let near = on_model && !is_far;
            let nrx = (r0[0] * nx[l] + r1[0] * ny[l]) + r2[0] * nz[l];
            let nry = (r0[1] * nx[l] + r1[1] * ny[l]) + r2[1] * nz[l];
            let nrz = (r0[2] * nx[l] + r1[2] * ny[l]) + r2[2] * nz[l];
            let is_turned = near && (nrx * mnx[l] + nry * mny[l]) + nrz * mnz[l] < s.min_cos;
            let inlier = near && !is_turned;
            far[l] += is_far as u32;
            turned[l] += is_turned as u32;
            inliers[l] += inlier as u32;
            let res = (mnx[l] * dx + mny[l] * dy) + mnz[l] * dz;
            let z = mz[l].max(0.5);
            let scale = z * z;
            let a = (res / scale).abs();
            let hub = if a <= s.huber { 1.0 } else { s.huber / a };
            let w = hub / (scale * scale);
            // The lever arm from the model point (see `normal_equations`).
            let jac = [
                my[l] * mnz[l] - mny[l] * mz[l],
                mz[l] * mnx[l] - mnz[l] * mx[l],
                mx[l] * mny[l] - mnx[l] * my[l],
                mnx[l],
                mny[l],
                mnz[l],
            ];
            for (ja, v) in j.iter_mut().zip(jac) {
                ja[l] = if inlier { v } else { 0.0 };
            }
            r[l] = if inlier { res } else { 0.0 };
            wgt[l] = if inlier { w } else { 0.0 };
            let (rd, sd) = (r[l] as f64, if inlier { scale as f64 } else { 1.0 });
            sq_res[l] += rd * rd;
            sq_norm[l] += (rd / sd) * (rd / sd);
        }
        let mut k = 0;
        for a in 0..6 {
            let wa: L = std::array::from_fn(|l| wgt[l] * j[a][l]);
            for bb in a..6 {
                for l in 0..LANES {
                    sums[k][l] += wa[l] * j[bb][l];
                }
                k += 1;
            }
            for l in 0..LANES {
                sums[21 + a][l] += wa[l] * r[l];
            }
        }
    }
    out.into_normals()
}

/// Intensity residual `I_model(π(q)) - I_frame` and its Jacobian with respect to a left
/// twist `(ω, υ)` of `q`; `None` where the model has no gradient.
#[inline]
fn photometric_term(model: &Model, uv: Vec2, q: Vec3, intensity: f32) -> Option<(f32, [f32; 6])> {
    let k = model.view.intrinsics;
    let w = k.width as usize;
    if !(uv.x >= 0.0 && uv.y >= 0.0) {
        return None;
    }
    let (x0, y0) = ((uv.x as u32) as f32, (uv.y as u32) as f32);
    if !(x0 + 1.0 < k.width as f32 && y0 + 1.0 < k.height as f32) {
        return None;
    }
    let (fx, fy) = (uv.x - x0, uv.y - y0);
    let i = y0 as usize * w + x0 as usize;
    let idx = [i, i + 1, i + w, i + w + 1];
    let wts = [(1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy];
    let (mut val, mut grad) = (0.0f32, Vec2::ZERO);
    for (&j, &wt) in idx.iter().zip(&wts) {
        val += wt * model.intensity[j];
        grad += wt * model.gradient[j];
    }
    if !(val.is_finite() && grad.is_finite()) {
        return None;
    }
    let inv_z = 1.0 / q.z;
    // dπ/dq transposed times the image gradient.
    let g = Vec3::new(
        grad.x * k.fx * inv_z,
        grad.y * k.fy * inv_z,
        -(grad.x * k.fx * q.x + grad.y * k.fy * q.y) * inv_z * inv_z,
    );
    let qxg = q.cross(g);
    Some((val - intensity, [qxg.x, qxg.y, qxg.z, g.x, g.y, g.z]))
}

/// Huber weight of residual `r` with threshold `delta`.
#[inline]
fn huber(r: f32, delta: f32) -> f32 {
    let a = r.abs();
    if a <= delta {
        1.0
    } else {
        delta / a
    }
}

/// `exp` of a left twist `(ω, υ)`: rotation by `ω`, then translation by `υ` (the first-order
/// model the Jacobians use).
fn se3_exp(xi: [f64; 6]) -> Affine3A {
    let omega = Vec3::new(xi[0] as f32, xi[1] as f32, xi[2] as f32);
    let v = Vec3::new(xi[3] as f32, xi[4] as f32, xi[5] as f32);
    Affine3A::from_rotation_translation(Quat::from_scaled_axis(omega), v)
}

/// The same transform with its rotation re-orthonormalised (accumulated f32 products drift).
fn orthonormalised(t: Affine3A) -> Affine3A {
    let q = Quat::from_mat3a(&t.matrix3).normalize();
    Affine3A::from_rotation_translation(q, t.translation.into())
}

/// Smallest over largest eigenvalue of `h` after scaling it to a unit diagonal, so that
/// rotation (m²) and translation (1) entries compare.
/// The Jacobi scaling of `h` (1 / sqrt of the diagonal; 0 where the diagonal is not
/// positive) and the eigen-decomposition of the scaled matrix (ascending eigenvalues,
/// eigenvectors as rows).
type ScaledEigen = ([f64; 6], [f64; 6], [[f64; 6]; 6]);

fn scaled_eigen(h: &[[f64; 6]; 6]) -> ScaledEigen {
    // A diagonal that is rounding noise (a perfect plane leaves exact zeros that come out
    // as 1e-20) would be scaled up into a direction that looks constrained.
    let floor = 1e-12 * (0..6).map(|i| h[i][i]).fold(0.0, f64::max);
    let d: [f64; 6] = std::array::from_fn(|i| if h[i][i] > floor { 1.0 / h[i][i].sqrt() } else { 0.0 });
    let s: [[f64; 6]; 6] = std::array::from_fn(|i| std::array::from_fn(|j| h[i][j] * d[i] * d[j]));
    let (vals, vecs) = symmetric_eigen(&s);
    (d, vals, vecs)
}

/// Smallest over largest eigenvalue of the scale-normalised `h` (0 when a direction has
/// no constraint at all), and how many eigenvalues are at least `min_condition` times the
/// largest: the motion directions the alignment constrains.
pub(crate) fn conditioning(h: &[[f64; 6]; 6], min_condition: f64) -> (f64, usize) {
    let (d, vals, _) = scaled_eigen(h);
    if !(vals[5] > 0.0) {
        return (0.0, 0);
    }
    let constrained = vals.iter().filter(|&&v| v >= min_condition * vals[5]).count();
    let unconstrained_axes = d.iter().filter(|&&v| v == 0.0).count();
    let cond = if unconstrained_axes > 0 { 0.0 } else { (vals[0] / vals[5]).max(0.0) };
    (cond, constrained.min(6 - unconstrained_axes))
}

/// One Gauss-Newton step: solves `h xi = neg_g`. A well-conditioned system is solved
/// as it is; otherwise, when `config.min_constrained` allows it, only along the scaled
/// eigen-directions that are constrained (eigenvalue at least `min_condition` times the
/// largest), so the unconstrained ones stay where the estimate started: at the motion
/// prediction. `None` for a singular or non-finite system.
fn gauss_newton_step(h: &[[f64; 6]; 6], neg_g: &[f64; 6], config: &TrackerConfig) -> Option<[f64; 6]> {
    if config.min_constrained >= 6 {
        return cholesky_solve(h, neg_g);
    }
    let (d, vals, vecs) = scaled_eigen(h);
    let well_conditioned = d.iter().all(|&v| v > 0.0) && vals[0] >= config.min_condition * vals[5];
    if well_conditioned || !(vals[5] > 0.0) {
        // The first keeps the same bits as a plain solve wherever nothing is degenerate.
        return cholesky_solve(h, neg_g);
    }
    // xi = D pinv(D h D) D neg_g, truncated to the constrained directions.
    let b: [f64; 6] = std::array::from_fn(|i| d[i] * neg_g[i]);
    let mut y = [0.0f64; 6];
    for (val, vec) in vals.iter().zip(&vecs) {
        if *val >= config.min_condition * vals[5] {
            let along = vec.iter().zip(&b).map(|(v, b)| v * b).sum::<f64>() / val;
            for (y, v) in y.iter_mut().zip(vec) {
                *y += along * v;
            }
        }
    }
    let xi: [f64; 6] = std::array::from_fn(|i| d[i] * y[i]);
    xi.iter().all(|v| v.is_finite()).then_some(xi)
}

/// Trajectory error after rigid alignment.
///
/// `estimated` and `reference` are matching camera positions (same length, in order).
/// Aligns `estimated` onto `reference` with the rotation and translation (no scale) that
/// minimise the squared distances (Horn's closed form, quaternion method) and returns the
/// RMS distance, metres; `None` for fewer than 3 positions or a length mismatch.
pub fn ate_rmse(estimated: &[Vec3], reference: &[Vec3]) -> Option<f64> {
    if estimated.len() != reference.len() || estimated.len() < 3 {
        return None;
    }
    let n = estimated.len() as f64;
    let mean = |v: &[Vec3]| {
        v.iter().fold([0.0f64; 3], |a, p| [a[0] + p.x as f64, a[1] + p.y as f64, a[2] + p.z as f64]).map(|s| s / n)
    };
    let (ce, cr) = (mean(estimated), mean(reference));
    // Cross-covariance S = sum (e - ce)(r - cr)^T.
    let mut s = [[0.0f64; 3]; 3];
    for (e, r) in estimated.iter().zip(reference) {
        let a = [e.x as f64 - ce[0], e.y as f64 - ce[1], e.z as f64 - ce[2]];
        let b = [r.x as f64 - cr[0], r.y as f64 - cr[1], r.z as f64 - cr[2]];
        for i in 0..3 {
            for j in 0..3 {
                s[i][j] += a[i] * b[j];
            }
        }
    }
    let [[sxx, sxy, sxz], [syx, syy, syz], [szx, szy, szz]] = s;
    let nm = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    let (_, vecs) = symmetric_eigen(&nm);
    let [w, x, y, z] = vecs[3];
    // Rotation matrix of the unit quaternion (w, x, y, z), f64.
    let r = [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ];
    let mut sum = 0.0;
    for (e, rf) in estimated.iter().zip(reference) {
        let a = [e.x as f64 - ce[0], e.y as f64 - ce[1], e.z as f64 - ce[2]];
        for i in 0..3 {
            let ai = r[i][0] * a[0] + r[i][1] * a[1] + r[i][2] * a[2] + cr[i];
            let d = ai - rf[i] as f64;
            sum += d * d;
        }
    }
    Some((sum / n).sqrt())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `J^T J` and `J^T r` of `rows` random Jacobian rows, each with its component along
    /// `null` removed when given (so that motion along `null` is unconstrained).
    fn normal_system(seed: u64, rows: usize, null: Option<[f64; 6]>) -> ([[f64; 6]; 6], [f64; 6]) {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let (mut h, mut g) = ([[0.0f64; 6]; 6], [0.0f64; 6]);
        for _ in 0..rows {
            let mut j: [f64; 6] = std::array::from_fn(|k| rng.random_range(-1.0..1.0) * if k < 3 { 0.5 } else { 2.0 });
            if let Some(u) = null {
                let along: f64 = j.iter().zip(&u).map(|(a, b)| a * b).sum();
                j.iter_mut().zip(&u).for_each(|(a, b)| *a -= along * b);
            }
            let r: f64 = rng.random_range(-0.01..0.01);
            for a in 0..6 {
                for b in 0..6 {
                    h[a][b] += j[a] * j[b];
                }
                g[a] += j[a] * r;
            }
        }
        (h, g)
    }

    #[test]
    fn a_well_conditioned_step_is_the_plain_solve() {
        let c = TrackerConfig::default();
        for seed in 0..20 {
            let (h, g) = normal_system(seed, 50, None);
            assert_eq!(gauss_newton_step(&h, &g, &c), cholesky_solve(&h, &g), "seed {seed}");
        }
    }

    #[test]
    fn a_degenerate_step_solves_the_constrained_part_and_leaves_the_rest() {
        let c = TrackerConfig::default();
        for seed in 0..20u64 {
            // A unit direction mixing rotation and translation, unconstrained by every row.
            let raw: [f64; 6] = std::array::from_fn(|k| ((seed as f64 + 1.0) * (k as f64 + 0.7)).sin());
            let norm = raw.iter().map(|v| v * v).sum::<f64>().sqrt();
            let u = raw.map(|v| v / norm);
            let (h, g) = normal_system(seed, 50, Some(u));
            assert_eq!(conditioning(&h, c.min_condition).1, 5, "seed {seed}");
            let xi = gauss_newton_step(&h, &g, &c).expect("a step");
            // The system is consistent (g lies in the range of h): the step solves it...
            let hx: [f64; 6] = std::array::from_fn(|a| (0..6).map(|b| h[a][b] * xi[b]).sum());
            let scale = g.iter().map(|v| v.abs()).fold(0.0, f64::max);
            for a in 0..6 {
                assert!((hx[a] - g[a]).abs() < 1e-6 * scale, "seed {seed}: {hx:?} against {g:?}");
            }
            // ...with nothing along the unconstrained direction in the scaled metric
            // (`D^-1 xi` orthogonal to the null vector `D^-1 u` of `D h D`).
            let d: [f64; 6] = std::array::from_fn(|i| 1.0 / h[i][i].sqrt());
            let along: f64 = (0..6).map(|i| (xi[i] / d[i]) * (u[i] / d[i])).sum();
            let size: f64 = (0..6).map(|i| (xi[i] / d[i]).powi(2)).sum::<f64>().sqrt();
            assert!(along.abs() <= 1e-6 * size.max(1e-12), "seed {seed}: {along} of {size}");
        }
    }

    #[test]
    fn horn_alignment_removes_a_rigid_motion() {
        let pts: Vec<Vec3> = (0..20)
            .map(|i| {
                let t = i as f32 * 0.3;
                Vec3::new(t.sin(), t.cos() * 0.5, 0.1 * t)
            })
            .collect();
        let m = Affine3A::from_rotation_translation(
            Quat::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 1.2),
            Vec3::new(1.0, -2.0, 0.5),
        );
        let moved: Vec<Vec3> = pts.iter().map(|p| m.transform_point3(*p)).collect();
        let e = ate_rmse(&moved, &pts).expect("enough points");
        assert!(e < 1e-5, "{e}");
        let mut noisy = moved.clone();
        noisy[3].x += 0.1;
        let e = ate_rmse(&noisy, &pts).expect("enough points");
        assert!(e > 0.01 && e < 0.1 / (20f64).sqrt() + 1e-3, "{e}");
    }

    #[test]
    fn pyramid_averages_only_agreeing_depths() {
        let k = Intrinsics::new(8, 8, 10.0, 10.0, 3.5, 3.5).expect("camera");
        let mut depth = vec![1.0f32; 64];
        depth[0] = 3.0; // an outlier in the first 2x2 block
        depth[9] = f32::NAN;
        let frame = Frame {
            index: 0,
            timestamp: 0.0,
            depth,
            color: vec![[10, 20, 30]; 64],
            intrinsics: k,
            world_from_camera: None,
            labels: None,
        };
        let p = build_pyramid(&frame, &TrackerConfig::default());
        assert_eq!(p[1].k.width, 4);
        assert_eq!(p[1].depth[0], 1.0);
        assert_eq!(p[0].depth[9], 0.0);
        assert_eq!(p[2].depth.len(), 4);
    }

    #[test]
    fn simd_row_sums_match_the_plain_f64_accumulation() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let (mut plain, mut simd) = (Normals::ZERO, Normals::ZERO);
        let mut sums = RowSums::ZERO;
        for i in 0..20_000 {
            // Jacobians as the association forms them: lever arms of metres, unit normals.
            let j: [f32; 6] = std::array::from_fn(|k| rng.random_range(-1.0..1.0) * if k < 3 { 3.0 } else { 1.0 });
            let r: f32 = rng.random_range(-0.01..0.01);
            let w: f32 = rng.random_range(0.1..1.0);
            plain.add(j.map(|v| v as f64), r as f64, w as f64);
            sums.add(j, r, w);
            if i % 320 == 319 {
                sums.flush(&mut simd);
            }
        }
        sums.flush(&mut simd);
        for a in 0..6 {
            for b in a..6 {
                let (p, s) = (plain.h[a][b], simd.h[a][b]);
                assert!((p - s).abs() <= 1e-5 * plain.h[a][a].max(plain.h[b][b]), "h[{a}][{b}]: {p} vs {s}");
            }
            // The gradient sums signed terms that cancel: compare with the scale of its terms.
            let scale = (plain.h[a][a] * 0.01f64.powi(2) * 20_000.0).sqrt();
            assert!((plain.g[a] - simd.g[a]).abs() <= 1e-4 * scale, "g[{a}]: {} vs {}", plain.g[a], simd.g[a]);
        }
    }

    #[test]
    fn block_depth_matches_the_sorted_median_rule() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for _ in 0..5000 {
            // Invalid, close and outlying depths, repeats included.
            let block: [f32; 4] = std::array::from_fn(|_| match rng.random_range(0..4) {
                0 => 0.0,
                1 => 2.0,
                2 => 2.0 + rng.random_range(-0.05..0.05),
                _ => rng.random_range(0.5..4.0),
            });
            let mut valid: Vec<f32> = block.iter().copied().filter(|&d| d > 0.0).collect();
            valid.sort_by(f32::total_cmp);
            let want = if valid.is_empty() {
                0.0
            } else {
                let median = valid[(valid.len() - 1) / 2];
                let kept: Vec<f32> = valid.into_iter().filter(|d| (d - median).abs() <= 0.03 * median).collect();
                kept.iter().fold(0.0f32, |s, d| s + d) / kept.len() as f32
            };
            assert_eq!(block_depth(block).to_bits(), want.to_bits(), "{block:?}");
        }
    }

    #[test]
    fn block_depth_rows_match_block_by_block() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        // Odd and even widths, rows past the edge, invalid, close and outlying depths.
        for pw in [1usize, 7, 16, 33, 64, 161] {
            let row = |rng: &mut rand_chacha::ChaCha8Rng| -> Vec<f32> {
                (0..pw)
                    .map(|_| match rng.random_range(0..4) {
                        0 => 0.0,
                        1 => 2.0,
                        2 => 2.0 + rng.random_range(-0.05..0.05),
                        _ => rng.random_range(0.5..4.0),
                    })
                    .collect()
            };
            for missing_row in [false, true] {
                let (r0, r1) = (row(&mut rng), if missing_row { Vec::new() } else { row(&mut rng) });
                let w = (pw / 2).max(1);
                let mut got = vec![-1.0f32; w];
                block_depth_row(&r0, &r1, &mut got);
                let at = |r: &[f32], sx: usize| r.get(sx).copied().unwrap_or(0.0);
                for (x, g) in got.iter().enumerate() {
                    let want = block_depth([at(&r0, 2 * x), at(&r0, 2 * x + 1), at(&r1, 2 * x), at(&r1, 2 * x + 1)]);
                    assert_eq!(g.to_bits(), want.to_bits(), "width {pw}, block {x}");
                }
            }
        }
    }

    #[test]
    fn lane_normals_match_the_pixel_rule() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(13);
        // Widths with and without a scalar tail; bumps, holes and depth edges.
        for w in [3usize, 10, 37, 64] {
            let h = 9;
            let k = Intrinsics::new(w as u32, h as u32, 30.0, 31.0, w as f32 / 2.0, 4.0).expect("camera");
            let depth: Vec<f32> = (0..w * h)
                .map(|i| match rng.random_range(0..10) {
                    0 => 0.0,
                    1 => rng.random_range(0.5..4.0),
                    _ => 1.5 + 0.01 * (i % w) as f32 + rng.random_range(-0.004..0.004),
                })
                .collect();
            let level = make_level(k, depth, Vec::new(), true);
            let (mut set, mut zero) = (0, 0);
            for y in 1..h - 1 {
                for x in 1..w - 1 {
                    let want = pixel_normal(&level.vertices, w, y * w + x);
                    let got = level.normals[y * w + x];
                    assert_eq!(got.to_array().map(f32::to_bits), want.to_array().map(f32::to_bits), "{x}, {y}");
                    if want == Vec3::ZERO {
                        zero += 1;
                    } else {
                        set += 1;
                    }
                }
            }
            assert!(w < 10 || (set > 0 && zero > 0), "{set} {zero}");
        }
    }

    #[test]
    fn sort4_sorts_like_the_library() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for _ in 0..1000 {
            let n = rng.random_range(0..=4);
            let mut v = [f32::INFINITY; 4];
            for d in v.iter_mut().take(n) {
                // Repeated values too.
                *d = rng.random_range(0..6) as f32 * 0.5;
            }
            let mut want = v;
            want.sort_by(f32::total_cmp);
            sort4(&mut v);
            assert_eq!(v, want);
        }
    }

    #[test]
    fn exp_of_a_small_twist_matches_its_linearisation() {
        let xi = [1e-4, -2e-4, 3e-4, 1e-3, 0.0, -1e-3];
        let t = se3_exp(xi);
        let q = Vec3::new(0.3, -0.2, 1.5);
        let lin = q + Vec3::new(1e-4, -2e-4, 3e-4).cross(q) + Vec3::new(1e-3, 0.0, -1e-3);
        assert!((t.transform_point3(q) - lin).length() < 1e-6);
    }

    #[test]
    fn lazy_finest_level_equals_the_materialised_one() {
        // A tilted, bumpy plane; the model is the frame's own half-resolution level.
        let c = TrackerConfig { fine_stride: 1, ..TrackerConfig::default() };
        let (pyramid, model) = bumpy_plane(&c);
        let (k, l1) = (pyramid[0].k, &pyramid[1]);
        // The materialised level 0: its vertices, and level 1's own normals per 2x2 block.
        let mut eager = make_level(k, pyramid[0].depth.clone(), Vec::new(), false);
        for (i, n) in eager.normals.iter_mut().enumerate() {
            let (x, y) = (i % 64, i / 64);
            let ci = (y / 2).min(23) * 32 + (x / 2).min(31);
            let d = eager.depth[i];
            if d > 0.0 && (d - l1.depth[ci]).abs() <= 0.05 * d {
                *n = l1.own_normals[ci];
            }
        }
        let motion = se3_exp([0.001, -0.002, 0.0005, 0.002, 0.001, -0.003]);
        for stride in [1, 2] {
            let lazy = normal_equations(&pyramid[0], Some(l1), &model, &motion, 0.05, stride, &c);
            let full = normal_equations(&eager, None, &model, &motion, 0.05, stride, &c);
            assert!(lazy.inliers > 100);
            assert_eq!((lazy.h, lazy.g, lazy.inliers, lazy.sampled), (full.h, full.g, full.inliers, full.sampled));
        }
    }

    /// The level-1 model and pyramid of a tilted, bumpy plane (shared by the association
    /// tests).
    fn bumpy_plane(c: &TrackerConfig) -> (Vec<Level>, Model) {
        let k = Intrinsics::new(64, 48, 60.0, 60.0, 31.5, 23.5).expect("camera");
        let depth: Vec<f32> =
            (0..64 * 48).map(|i| 1.0 + 0.004 * (i % 64) as f32 + 0.01 * ((i / 64) as f32 * 0.7).sin()).collect();
        let pyramid = build_pyramid(&Frame::from_depth(k, depth), c);
        let l1 = &pyramid[1];
        let view = ModelView {
            intrinsics: l1.k,
            world_from_camera: Affine3A::IDENTITY,
            vertices: l1.vertices.clone(),
            normals: l1.normals.clone(),
            colors: vec![[0; 3]; l1.vertices.len()],
        };
        (pyramid, Model { view: Arc::new(view), intensity: Vec::new(), gradient: Vec::new() })
    }

    fn normals_key(n: &Normals) -> ([[f64; 6]; 6], [f64; 6], f64, f64, [u64; 4]) {
        (n.h, n.g, n.sq_residual, n.sq_normalised, [n.inliers, n.far, n.turned, n.sampled])
    }

    #[test]
    fn lane_association_matches_the_scalar_path() {
        // A tight distance and angle gate, so that both rejections occur.
        let c = TrackerConfig { fine_stride: 1, max_normal_angle: 10f32.to_radians(), ..TrackerConfig::default() };
        let (pyramid, model) = bumpy_plane(&c);
        let motion = se3_exp([0.001, -0.002, 0.0005, 0.002, 0.001, -0.003]);
        let mut totals = (0, 0, 0);
        for (level, stride, max_distance) in
            [(0, 1, 0.012), (0, 1, 0.03), (0, 2, 0.03), (0, 3, 0.03), (1, 1, 0.04), (2, 1, 0.08)]
        {
            let data = &pyramid[level];
            let scalar = normal_equations(data, pyramid.get(level + 1), &model, &motion, max_distance, stride, &c);
            let lanes = LevelPoints::new(data, pyramid.get(level + 1), stride).normal_equations(
                &model,
                &motion,
                max_distance,
                &c,
            );
            let counts = |n: &Normals| (n.inliers, n.far, n.turned, n.sampled);
            assert_eq!(counts(&lanes), counts(&scalar), "level {level} stride {stride}");
            totals.0 += scalar.inliers;
            totals.1 += scalar.far;
            totals.2 += scalar.turned;
            for a in 0..6 {
                let scale = scalar.h[a][a].max(1e-30);
                for b in a..6 {
                    let tol = 1e-5 * scalar.h[a][a].max(scalar.h[b][b]);
                    assert!((lanes.h[a][b] - scalar.h[a][b]).abs() <= tol, "h[{a}][{b}] at level {level}");
                }
                let g_tol = 1e-4 * (scale * scalar.sq_residual).sqrt();
                assert!((lanes.g[a] - scalar.g[a]).abs() <= g_tol, "g[{a}] at level {level}");
            }
            assert!((lanes.sq_residual - scalar.sq_residual).abs() <= 1e-12 * scalar.sq_residual);
            assert!((lanes.sq_normalised - scalar.sq_normalised).abs() <= 1e-12 * scalar.sq_normalised);
        }
        assert!(totals.0 > 2000 && totals.1 > 100 && totals.2 > 100, "{totals:?}");
    }

    #[test]
    fn avx2_lanes_give_the_portable_bits() {
        #[cfg(target_arch = "x86_64")]
        if avx2_available() {
            // Tight and loose gates (far and turned pairs), and a motion that moves part of
            // the frame off the model's image.
            let (mut far, mut turned, mut off) = (0, 0, 0);
            for (angle, max_distance, xi) in [
                (45f32, 0.01, [0.001, -0.002, 0.0005, 0.002, 0.001, -0.003]),
                (10.0, 0.03, [0.001, -0.002, 0.0005, 0.002, 0.001, -0.003]),
                (45.0, 0.05, [0.02, -0.1, 0.01, 0.3, 0.04, -0.02]),
            ] {
                let c =
                    TrackerConfig { fine_stride: 1, max_normal_angle: angle.to_radians(), ..TrackerConfig::default() };
                let (pyramid, model) = bumpy_plane(&c);
                let step = StepParams::new(&model, &se3_exp(xi), max_distance, &c);
                assert!(step.gather_safe());
                for level in 0..3 {
                    let points = LevelPoints::new(&pyramid[level], pyramid.get(level + 1), 1);
                    for b in &points.blocks {
                        let portable = block_sums_lanes(b, &step);
                        // SAFETY: checked above; blocks are padded to whole lanes.
                        let avx2 = unsafe { avx2::block_sums(b, &step) };
                        assert_eq!(normals_key(&portable), normals_key(&avx2));
                        far += avx2.far;
                        turned += avx2.turned;
                        off += b.len as u64 - (avx2.inliers + avx2.far + avx2.turned);
                    }
                }
            }
            assert!(far > 100 && turned > 100 && off > 100, "{far} {turned} {off}");
        }
    }

    #[test]
    fn ray_table_unprojects_like_the_camera() {
        let k = Intrinsics::new(640, 480, 525.0, 523.5, 319.5, 239.25).expect("camera");
        let rays = RayTable::new(k);
        for (i, d) in [0.31f32, 1.0, 2.75, 4.9].into_iter().enumerate() {
            for y in (i..480).step_by(7) {
                for x in (i..640).step_by(5) {
                    assert_eq!(rays.unproject(x, y, d), k.unproject(x as f32, y as f32, d));
                }
            }
        }
    }
}
