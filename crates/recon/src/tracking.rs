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

use glam::{Affine3A, Mat3, Mat3A, Quat, Vec2, Vec3};
use rayon::prelude::*;
use semrecon_data::{Frame, Intrinsics};
use wide::f32x8;

use crate::error::{ReconError, Result};
use crate::linalg::{cholesky_solve, symmetric_eigen};
use crate::map::TsdfMap;
use crate::raycast::{raycast_with, ModelView};

#[cfg(target_arch = "x86_64")]
mod avx2;
mod normal_equations;
mod pyramid;
mod support;
pub(crate) use normal_equations::conditioning;
#[allow(clippy::wildcard_imports)]
use normal_equations::*;
#[allow(clippy::wildcard_imports)]
use pyramid::*;
use support::translation_support;

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
    /// Weight of the photometric term for frames whose depth alone leaves the alignment
    /// poorly conditioned (0: off). With `photometric_weight` 0, each frame is aligned on
    /// depth first; when the scale-normalised normal matrix's condition is below
    /// `degenerate_condition` (a bare wall, a floor, a corridor: motions along the surface
    /// are barely seen by depth), the estimate departs from the prediction by more than
    /// `degenerate_departure`, or a direction of translation lacks support (`min_support`),
    /// the frame is aligned again from the prediction with the
    /// colour term at this weight, so only those frames pay for it (the term costs about four
    /// times a depth-only alignment). Only meaningful when colour is registered to depth.
    pub degenerate_photometric_weight: f32,
    /// Condition (smallest over largest scale-normalised eigenvalue of the depth-only normal
    /// matrix) below which `degenerate_photometric_weight` applies. 5e-3: on the demo's
    /// generated scans the condition's median is 1e-2 to 4e-2 a scan where depth tracks well,
    /// 2e-3 on the two that drift facing bare walls (seeds 14 and 19).
    pub degenerate_condition: f64,
    /// The colour fallback applies too when the depth-only estimate departs from the
    /// constant-velocity prediction by more than this many metres: a handheld camera departs
    /// by 1-6 mm a frame (the demo at most 2.8 mm, TUM fr2/desk 5.6 mm), and a jump of
    /// 2-4 cm that the pose-jump bound still lets through is depth locking onto the wrong
    /// surface (`synth-loop:1:noisy` at frame 1415, where a ceiling fixture enters the view:
    /// 21 mm, then a 0.2 m slide; 28.5 -> 4.6 mm ATE over the scan, docs/benchmarks_log.md,
    /// "Session 41"). It catches what the condition cannot: there the condition read
    /// 0.03-0.2, healthy, because noisy normals lend every axis some information.
    pub degenerate_departure: f32,
    /// A surface point leans towards a direction when its normal's component along it is at
    /// least this (0.3: 17 degrees, past the few degrees of a ray-cast model's noise).
    pub support_tilt: f32,
    /// A direction of translation along which fewer than this fraction of the model's
    /// surface points lean ([`TrackerConfig::support_tilt`]) is unheld: the colour fallback
    /// runs (where `degenerate_photometric_weight` allows), and a depth-only alignment keeps
    /// the camera where it last was along it, rather than letting the normals' noise slide
    /// it (the normal matrix's condition cannot tell: it reads 1e-2 there). 0 turns the check
    /// off. 0.02: `synth-loop:3:noisy` slid 0.35 m up a wall beside a flush door with a
    /// support of 0.1-1.7 % (ATE 169 -> 17.4 mm); 7-Scenes and TUM fr2/desk read 14 % and more
    /// on every frame (docs/benchmarks_log.md, "Session 42").
    pub min_support: f32,
    /// Lost when fewer than this fraction of the frame pixels that land on the model lie
    /// within `max_distance` of it (the normal test is left out here, see
    /// [`TrackingResult::inlier_ratio`]).
    pub min_inlier_ratio: f32,
    /// Lost when fewer than this fraction of the valid pixels land on the model.
    pub min_overlap: f32,
    /// Lost when the RMS point-to-plane residual of the inliers, normalised to 1 m depth
    /// (divided by depth squared, as depth noise grows), exceeds this many metres.
    pub max_residual: f32,
    /// Lost when the estimate is further than this many metres from the prediction, per
    /// frame since the last tracked one (a frame after a dropped or lost one may be that much
    /// further). 0.05: a handheld camera departs from constant velocity by at most 1-2 cm a
    /// frame at 30 fps (7-Scenes redkitchen 16 mm, TUM fr2/desk 6 mm, the generated walks
    /// 17 mm); past that the alignment has slid along surfaces that barely hold it, and the
    /// constant-velocity prediction would carry the slide on from frame to frame (a
    /// generated two-room loop slid 0.4-2 m in four frames with 0.15, the bound before
    /// session 39; docs/benchmarks_log.md, "Session 39").
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
            degenerate_photometric_weight: 0.0,
            degenerate_condition: 5e-3,
            degenerate_departure: 0.015,
            support_tilt: 0.3,
            min_support: 0.02,
            min_inlier_ratio: 0.5,
            min_overlap: 0.2,
            max_residual: 0.01,
            max_translation_jump: 0.05,
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
    /// Frames' worth of [`TrackerConfig::max_translation_jump`] that a departure from the
    /// prediction may take where the prediction is known to be poor: the first frame after a
    /// restart at a keyframe's pose (relocalisation puts the camera near, not at, where it
    /// is), and, for the pipeline, the largest pose jump still treated as a small one (the
    /// frame after it is tracked before relocalisation is tried). 3: the 15 cm of the bound
    /// before session 39.
    pub const WIDE_JUMP_FRAMES: f32 = 3.0;

    /// The colour fallback's weight ([`TrackerConfig::degenerate_photometric_weight`]) for a
    /// source whose colour is, or is not, registered to its depth: 0.1, or 0 (a colour term
    /// on unregistered colour would pull the pose by the two cameras' offset). The
    /// library's own default stays 0; the CLI and the Python package start from this.
    /// Session 34, demo seeds 1-40: the five scans whose tracking slid along a door or a bare
    /// wall (ATE 21-382 mm) came back to 3.6-125 mm; seven others moved by 0.2-5 mm (seed 16:
    /// 2.8 -> 7.9), the rest are the same bits (docs/benchmarks_log.md, "Session 34").
    pub fn colour_fallback_weight(color_registered: bool) -> f32 {
        if color_registered {
            0.1
        } else {
            0.0
        }
    }

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
        if !(self.degenerate_photometric_weight >= 0.0 && self.degenerate_photometric_weight.is_finite()) {
            return bad(format!(
                "photometric weight for degenerate frames {} must be >= 0",
                self.degenerate_photometric_weight
            ));
        }
        if !(self.degenerate_departure > 0.0) {
            return bad(format!("degenerate_departure {} must be > 0 (infinity: off)", self.degenerate_departure));
        }
        if !(self.support_tilt > 0.0 && self.support_tilt < 1.0) {
            return bad(format!("support_tilt {} is outside 0..1 (exclusive)", self.support_tilt));
        }
        if !(0.0..1.0).contains(&self.min_support) {
            return bad(format!("min_support {} is outside 0..1", self.min_support));
        }
        if !(0.0..1.0).contains(&self.degenerate_condition) {
            return bad(format!("degenerate_condition {} is outside 0..1", self.degenerate_condition));
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
    /// Standard deviation of the estimated position along its least determined axis, metres,
    /// from the normal matrix and the residuals (rotation free; see `translation_sigma`): a
    /// diagnostic (`tracking.csv`). It is a lower bound: the normal matrix counts the noise
    /// in the model's normals as information, so a view of vertical walls reads 0.2 mm along
    /// the vertical that nothing in it holds (session 41; as a trigger for the colour
    /// fallback it was not kept).
    pub translation_sigma_m: f64,
    /// How many of the six motion directions the alignment constrained (6 normally; fewer
    /// when some were kept at the motion prediction, see
    /// [`TrackerConfig::min_constrained`]).
    pub constrained: usize,
    /// The alignment's Gauss-Newton normal matrix `JᵀJ` at the final pose (finest level,
    /// robustly weighted, per square metre of residual) as a right perturbation
    /// `(δt, δφ)`, translation first, of `world_from_camera` in the camera's own frame
    /// (`T ← T · exp(δ)`). Its shape says which motions this frame pinned down and which it
    /// barely saw (along a corridor, across a bare wall); loop closure can weigh odometry by
    /// it ([`crate::pose_graph::odometry_information`]). Zeros when the frame was not aligned.
    pub camera_hessian: [[f64; 6]; 6],
    /// Whether this frame became a keyframe.
    pub keyframe: bool,
    /// Whether the frame was aligned again with the photometric term because depth alone
    /// left it poorly conditioned ([`TrackerConfig::degenerate_photometric_weight`]).
    pub colour_fallback: bool,
    /// Wall time of the model ray-cast, milliseconds (0 when the cached view was reused).
    pub raycast_ms: f64,
    /// Wall time of the whole call, milliseconds.
    pub total_ms: f64,
    /// How far the alignment's estimate lies from the constant-velocity prediction, metres
    /// (0 when nothing was aligned); a frame is lost as a [`LostReason::PoseJump`] past
    /// [`TrackerConfig::max_translation_jump`] per frame since the last tracked one.
    pub departure_m: f32,
    /// The smallest fraction of the model's surface points leaning towards any principal
    /// direction of their normals by [`TrackerConfig::support_tilt`] (1 when nothing was
    /// aligned): below [`TrackerConfig::min_support`] that direction of translation was
    /// unheld.
    pub support: f32,
    /// How many directions of translation no surface in view held
    /// ([`TrackerConfig::min_support`]): the colour fallback aligned them, or, without colour,
    /// they stayed where the camera last was.
    pub unheld: usize,
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
    /// Source index of the last tracked frame: the jump bound grows with the frames since.
    last_index: Option<usize>,
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
            last_index: None,
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
        let mut pyramid = build_pyramid(frame, &c);
        let last_pose = self.last.unwrap_or(self.initial_pose);
        let mut result = TrackingResult {
            status: TrackingStatus::Lost(LostReason::NoDepth),
            world_from_camera: last_pose,
            inlier_ratio: 0.0,
            residual_rms: 0.0,
            condition: 0.0,
            translation_sigma_m: f64::INFINITY,
            constrained: 0,
            camera_hessian: [[0.0; 6]; 6],
            keyframe: false,
            colour_fallback: false,
            raycast_ms: 0.0,
            total_ms: 0.0,
            departure_m: 0.0,
            support: 1.0,
            unheld: 0,
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
            result.translation_sigma_m = 0.0;
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

        // Frames since the last tracked one (dropped by a live camera, or lost), bounded so
        // that a source with arbitrary indices cannot switch the jump test off.
        let frames_since = self.last_index.map_or(1, |i| frame.index.saturating_sub(i).clamp(1, 10));
        // reference_from_current, predicted with constant velocity (per frame) over them.
        let mut step = self.velocity;
        for _ in 1..frames_since {
            step *= self.velocity;
        }
        let prediction = reference.inverse() * last * step;
        // Directions of translation that no surface in view holds: a depth-only alignment
        // keeps them where the camera last was (the motion model would carry a hand's bob
        // on for as long as the view lasts), and the colour fallback runs where it can.
        let support = translation_support(
            &model.view.normals,
            model.view.intrinsics.width as usize,
            c.support_tilt,
            c.min_support,
        );
        let held_at = Vec3::from((reference.inverse() * last).translation);
        let pins: Vec<Pin> = support.unheld().iter().map(|&e| Pin { direction: e, at: e.dot(held_at) }).collect();
        result.support = support.weakest_fraction;
        result.unheld = pins.len();
        // With colour in every alignment, colour holds what depth does not.
        let depth_pins: &[Pin] = if c.photometric_weight > 0.0 && !frame.color.is_empty() { &[] } else { &pins };
        let (mut estimate, mut stats, mut singular) = align(&pyramid, &model, prediction, depth_pins, &c);
        let mut conditioned = conditioning(&stats.symmetric(), c.min_condition);
        let fallback = c.photometric_weight <= 0.0 && c.degenerate_photometric_weight > 0.0 && !frame.color.is_empty();
        let departure = Vec3::from((prediction.inverse() * estimate).translation).length();
        let weakly_held =
            conditioned.0 < c.degenerate_condition || departure > c.degenerate_departure || !pins.is_empty();
        if fallback && !singular && weakly_held {
            // Depth alone barely sees some motion: align again with colour.
            let colour = TrackerConfig { photometric_weight: c.degenerate_photometric_weight, ..c.clone() };
            add_intensity(&mut pyramid, frame);
            let (intensity, gradient) = model_intensity(&model.view);
            let model = Model { view: Arc::clone(&model.view), intensity, gradient };
            // Unpinned: on `synth-loop:3:noisy` frames 1100-1300 colour alone held the
            // height to 1.1 mm (ATE), colour with the pins 5.7 mm, the pins alone 6.1 mm
            // (they hold the camera still while it bobs by a centimetre).
            (estimate, stats, singular) = align(&pyramid, &model, prediction, &[], &colour);
            conditioned = conditioning(&stats.symmetric(), c.min_condition);
            result.colour_fallback = true;
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
        let (cond, constrained) = conditioned;
        let h = stats.symmetric();
        result.condition = cond;
        result.translation_sigma_m = translation_sigma(&h, result.residual_rms as f64);
        result.constrained = constrained;
        result.camera_hessian = camera_hessian(&h, estimate);
        let jump = prediction.inverse() * estimate;
        let jump_t = Vec3::from(jump.translation).length();
        result.departure_m = jump_t;
        let jump_r = Quat::from_mat3a(&jump.matrix3).to_axis_angle().1;
        let jump_r = jump_r.min(std::f32::consts::TAU - jump_r);
        result.world_from_camera = reference * estimate;
        // Each frame since the last tracked one may add a frame's worth of departure from the
        // prediction. After a restart at a keyframe's pose (relocalisation), which is not
        // where the camera last was, three frames' worth: the 15 cm of the bound before.
        let jump_frames = if self.last_index.is_some() { frames_since as f32 } else { TrackerConfig::WIDE_JUMP_FRAMES };
        result.status = if singular || constrained < c.min_constrained {
            TrackingStatus::Lost(LostReason::Degenerate)
        } else if result.inlier_ratio < c.min_inlier_ratio || overlap_ratio < c.min_overlap {
            TrackingStatus::Lost(LostReason::FewInliers)
        } else if !((stats.sq_normalised / stats.inliers.max(1) as f64).sqrt() <= c.max_residual as f64) {
            TrackingStatus::Lost(LostReason::LargeResidual)
        } else if !(jump_t <= c.max_translation_jump * jump_frames
            && jump_r <= c.max_rotation_jump
            && result.world_from_camera.is_finite())
        {
            TrackingStatus::Lost(LostReason::PoseJump)
        } else {
            TrackingStatus::Tracked
        };
        if result.should_fuse() {
            self.velocity = per_frame(orthonormalised(last.inverse() * result.world_from_camera), frames_since);
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
        self.last_index = None;
    }

    /// Records an accepted frame: pose, keyframe, march-start depth.
    fn accept(&mut self, frame: &Frame, result: &mut TrackingResult, model_level: &Level) {
        self.last = Some(result.world_from_camera);
        self.last_index = Some(frame.index);
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
                    self.config.photometric_weight > 0.0 || self.config.degenerate_photometric_weight > 0.0,
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

/// Gauss-Newton alignment of `pyramid` to `model` over the pyramid levels, coarse to fine,
/// from `prediction` (reference_from_current): the estimate, the last iteration's sums and
/// whether a step was singular.
fn align(
    pyramid: &[Level],
    model: &Model,
    prediction: Affine3A,
    pins: &[Pin],
    c: &TrackerConfig,
) -> (Affine3A, Normals, bool) {
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
                Some(p) => p.normal_equations(model, &estimate, max_distance, c),
                None => normal_equations(data, pyramid.get(level + 1), model, &estimate, max_distance, stride, c),
            };
            let mut h = stats.symmetric();
            let mut neg_g = stats.g.map(|v| -v);
            pin_translation(&mut h, &mut neg_g, pins, Vec3::from(estimate.translation));
            let Some(xi) = gauss_newton_step(&h, &neg_g, c) else {
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
    (estimate, stats, singular)
}

/// A direction of translation held at a position: the estimate's translation
/// (`reference_from_current`) keeps `direction · t = at`.
#[derive(Debug, Clone, Copy)]
struct Pin {
    direction: Vec3,
    at: f32,
}

/// How much stiffer a pin is than the stiffest direction of translation the surfaces hold:
/// the pinned direction moves by a ten-thousandth of what a hold as stiff as the stiffest
/// would move it (a millionth of what the normals' noise would, `support.rs`), and f64
/// solves the system as well as without it.
const PIN_STIFFNESS: f64 = 1e4;

/// Adds each pin to one Gauss-Newton step's normal equations as a stiff quadratic prior on
/// the translation step `υ` (entries 3..6 of the twist): `k (e · (t + υ) - at)²`. The left
/// twist moves the translation by `υ` plus the rotation's turn of `t`, a few millimetres'
/// lever at most over a frame; the prior leaves that out.
fn pin_translation(h: &mut [[f64; 6]; 6], neg_g: &mut [f64; 6], pins: &[Pin], t: Vec3) {
    if pins.is_empty() {
        return;
    }
    let stiffness = PIN_STIFFNESS * (3..6).map(|i| h[i][i]).fold(0.0, f64::max).max(1e-12);
    for pin in pins {
        let e = pin.direction.to_array().map(f64::from);
        let off = f64::from(pin.direction.dot(t) - pin.at);
        for i in 0..3 {
            for j in 0..3 {
                h[3 + i][3 + j] += stiffness * e[i] * e[j];
            }
            neg_g[3 + i] -= stiffness * e[i] * off;
        }
    }
}

/// One frame's share of `motion`, a rigid motion over `frames` frames: the constant
/// velocity that, applied `frames` times, gives `motion` (the rotation's angle divided by
/// `frames`, and the translation that the repeated steps sum to `motion`'s). `motion`
/// itself for one frame.
fn per_frame(motion: Affine3A, frames: usize) -> Affine3A {
    if frames <= 1 {
        return motion;
    }
    let (axis, angle) = Quat::from_mat3a(&motion.matrix3).to_axis_angle();
    let rotation = Mat3A::from_quat(Quat::from_axis_angle(axis, angle / frames as f32));
    // Steps (R, u) compose to (R^k, (I + R + ... + R^(k-1)) u): solve that sum for u. It is
    // invertible for any turn below a full one over the frames (a camera turns degrees).
    let mut sum = Mat3A::IDENTITY;
    let mut power = Mat3A::IDENTITY;
    for _ in 1..frames {
        power = rotation * power;
        sum += power;
    }
    let step = sum.inverse() * motion.translation;
    Affine3A { matrix3: rotation, translation: step }
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
    let r = crate::linalg::horn_rotation(&s);
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
mod tests;
