//! Global consistency for the live pipeline: keyframes in a pose graph, loops found at
//! keyframes ([`semrecon_recon::LoopDetector`]), the graph optimised when a loop disagrees
//! with the poses ([`semrecon_recon::PoseGraph`]), and the map made to follow the corrected
//! poses.
//!
//! Every fused frame is attached to the last keyframe before it (`keyframe_from_camera`,
//! fixed), so a keyframe's corrected pose moves its frames with it. The map follows by
//! re-integration: the chunks that a recorded frame's correction moves by more than half a
//! voxel (`plan`) are rebuilt from every frame recorded in them, in capture order, at the
//! corrected poses: by default from runs of four consecutive frames, their depths averaged
//! onto one ([`LoopClosureConfig::reintegration_stride`]), which keeps their noise averaging
//! for a quarter of the fusions. Fusion has no exact inverse here (capped weights, quantised
//! distances, blended colours), so subtracting a frame ("de-integration") would leave
//! residue; clearing and re-fusing frame by frame gives exactly the map a scan with the
//! corrected poses would have built, and chunks no moved frame touched are left alone (their
//! meshes and semantic cells are not redone). Rigid submaps were the other choice: they avoid re-fusing, but tracking and
//! meshing would then work on overlapping submaps, a larger change. The cost is a copy of
//! every fused frame (1.5 MB at 640x480: depth as `u16` in units of 0.2 mm, the unit of
//! TUM and a fifth of 7-Scenes' millimetre, and colour), bounded by
//! [`LoopClosureConfig::frame_store_mb`]; past it the store thins out to every second frame,
//! then every fourth, ..., each kept frame standing for those after it, so that a scan of
//! any length keeps its loop closure. Timings and memory in docs/loop_closure.md.
//!
//! The loop search and the graph's optimisation run on a back-end thread (`search`), from
//! one keyframe to the next: the front end takes a keyframe's result back at the next
//! keyframe, a frame count, so the output is the same for any thread count. Everything else
//! runs on the front end's thread, in a fixed order. The
//! re-integration after a correction costs about a fusion per frame re-fused, so it is built
//! in a shadow holding only the chunks it changes, a bounded amount at every frame, and
//! swapped in at the keyframe it completes (`shadow`), instead of stalling the front end for
//! seconds.

use glam::{Affine3A, DAffine3};
use semrecon_data::{Frame, Intrinsics, Trajectory};
use semrecon_recon::pose_graph::{
    adjoint, isotropic_information, odometry_information, pose_distance, pull_back, Mat6,
};
use semrecon_recon::{
    EdgeKind, IntegrationStats, LoopConfig, LoopDetector, PoseEdge, PoseGraph, PoseGraphConfig, TsdfMap,
};
use serde::Serialize;

use crate::error::{PipelineError, Result};
use search::{GraphWork, SearchOutcome, SearchThread};
use shadow::Shadow;

/// Depth units of the frame store: metres times this (0.2 mm steps, up to 13 m).
const DEPTH_UNITS_PER_M: f32 = 5000.0;

/// Parameters of loop closure.
#[derive(Debug, Clone, PartialEq)]
pub struct LoopClosureConfig {
    /// On: keyframes and fused frames are kept, loops closed and the map re-fused
    /// (the CLI's `run` turns it on unless `--no-loop-closure`; `demo` and `live` with
    /// `--loop-closure`). Off by default here: on 7-Scenes a correction moves nearly every chunk,
    /// so re-fusing after it costs about a whole pass over the stored frames (spread over
    /// frames now, but still a large part of the real-time factor), and the frame store costs
    /// 1.5 MB a frame, for 1-2 mm of ATE on 7-Scenes (docs/loop_closure.md).
    pub enabled: bool,
    /// Candidate search and geometric acceptance.
    pub detector: LoopConfig,
    /// The optimiser (robust kernel, outlier rejection, bounds on a correction).
    pub graph: PoseGraphConfig,
    /// Standard deviation of the odometry between consecutive keyframes: metres and radians
    /// per keyframe (frame-to-model tracking drifts a few millimetres per ten frames).
    pub odometry_sigma: (f64, f64),
    /// Standard deviation of a loop alignment: metres and radians (with
    /// `loop_information_from_alignment`, the metres are those of the best-constrained
    /// direction and the radians are not used).
    pub loop_sigma: (f64, f64),
    /// A loop edge's information takes its shape from the alignment's Hessian `JᵀJ` (a loop
    /// along a corridor constrains the motion along it little), scaled so that its
    /// best-constrained translation has `loop_sigma`'s metres; off: isotropic `loop_sigma`.
    /// Off by default: on the rendered drifting loops it closed less of the drift (ATE after
    /// 3.9-11.0 mm against 2.4-5.0 mm, seeds 1-5): its weaker directions trigger fewer
    /// corrections and pull less against odometry (docs/loop_closure.md).
    pub loop_information_from_alignment: bool,
    /// An odometry edge's information takes its shape from the tracking between its two
    /// keyframes: the camera-frame normal matrix of the worst-conditioned frame of the
    /// interval ([`semrecon_recon::TrackingResult::camera_hessian`]), scaled so that its
    /// best-constrained translation has `odometry_sigma`'s metres. A stretch where depth
    /// barely constrained some motion (a doorway, a bare wall) then takes more of a loop's
    /// correction than one where tracking was firm; off: isotropic `odometry_sigma`.
    pub odometry_information_from_tracking: bool,
    /// A loop edge's standard deviations (`loop_sigma`) grow with its alignment's RMS
    /// residual past this many metres, in proportion: the pose an ICP finds is about as
    /// uncertain as its residual is large (noisier, farther surfaces), so a loop aligned at
    /// a 9 mm residual weighs a ninth of one at 3 mm instead of the same. 3 mm: the residual
    /// of good loops on generated scans (2-4 mm); 7-Scenes' real Kinect loops have 7-10 mm and
    /// so weigh less than before (17 corrections became 5, ATE 25.2 -> 25.4 mm), and a loop
    /// whose far, noisy surfaces biased it 25 mm (`synth-loop:6`, residual 9.3 mm) no longer
    /// bends a trajectory that was right (2.3 -> 0.9 mm ATE; docs/loop_closure.md). 0: one
    /// `loop_sigma` for every loop.
    pub loop_residual_reference: f64,
    /// The graph is optimised when a new loop edge's chi-square at the current poses exceeds
    /// this: a loop that agrees with the poses changes nothing worth re-fusing the map for.
    pub min_loop_chi2: f64,
    /// An optimisation counts as a correction only when it moves some keyframe's points (at
    /// 2 m) by more than this many metres; smaller changes stay in the graph unreported. 8 mm,
    /// under two 5 mm voxels and under the depth noise at 2 m. (Where the map follows is
    /// decided per chunk: [`LoopClosureConfig::min_chunk_move_voxels`].)
    pub min_move: f64,
    /// The map follows a correction only where it moves the map by more than this many
    /// voxels: a chunk is rebuilt when a frame recorded in it moves the chunk's centre further
    /// than this (its pose change applied to the centre: the depth it saw the chunk at and its
    /// turn both count); a correction that moves no chunk that far leaves the map alone. Half
    /// a voxel: below the quantisation of the surface, and the map follows a frame's
    /// correction only where the frame's view of the surface moved.
    pub min_chunk_move_voxels: f32,
    /// Most megabytes of stored frames (1.5 MB each at 640x480); past it the store keeps the
    /// pixels of every second frame, then every fourth, ... (`LoopClosure::thin`). 2 GB
    /// (1,365 frames, 45 s at 30 Hz, before any thinning): with loop closure on by default in
    /// `run`, the store is the largest part of its memory (a 5-minute walk through a
    /// generated flat peaked at 9.5 GB with 4 GB of it); thinned to every eighth frame a scan
    /// kept its ATE and mesh accuracy (docs/loop_closure.md, "Session 45").
    pub frame_store_mb: usize,
    /// The map follows corrected poses at most every this many keyframes (and at the end
    /// of the scan; [`LoopClosureConfig::FOLLOW_AT_END`]: only there, the CLI's
    /// `--map-follows end`): a revisit finds a loop at keyframe after keyframe, and re-fusing the map
    /// for each costs seconds (7-Scenes: 19 re-integrations of the whole clip at 1, docs/
    /// loop_closure.md). Meanwhile the trajectory is corrected and the tracker stays in the
    /// map's frame.
    pub follow_every: usize,
    /// Frames re-fused per keyframe while the map follows a correction: the corrected chunks
    /// are built in a shadow copy of the map, this many stored frames per keyframe, while the
    /// live map goes on; the shadow is swapped in at the first keyframe at which it holds every
    /// frame (a count of frames: deterministic). Bounds the front end's stall per keyframe to
    /// about this many fusions. Frames fused live meanwhile join the shadow's queue, so it
    /// must exceed the keyframe interval (10 by default) for the shadow to catch up: with 20,
    /// it gains 10 frames a keyframe. 0: re-fuse at once, stalling the front end for the whole
    /// re-integration (seconds on 7-Scenes).
    pub reintegration_frames_per_keyframe: usize,
    /// Stored frames re-fused as one: runs of up to this many consecutive frames are re-fused
    /// once, from their depths averaged onto the run's middle frame pixel by pixel (the warp
    /// of far-surface grouping, [`semrecon_recon::averaged_frame`]), weighing as much as the
    /// run. The average keeps the run's noise averaging; a pixel no other frame of the run
    /// confirms is left out (flying pixels, glimpses past an edge), and a run whose frames
    /// disagree (most pixels unconfirmed) is re-fused frame by frame. 4 (since session 38):
    /// on the rendered drifting loop the re-integrated mesh is more accurate than the exact
    /// re-fusion's (1.87 against 2.30 mm) with 97.6 % of its completeness, for 2-3 times
    /// less work; on 7-Scenes the CPU time of a run with loop closure went from 59-62 to
    /// 45-46 s (docs/loop_closure.md). 1: every frame (the rebuilt chunks are then what
    /// fusing afresh at the corrected poses gives).
    pub reintegration_stride: usize,
}

impl LoopClosureConfig {
    /// [`LoopClosureConfig::follow_every`] for a map that follows the corrections only at
    /// the end of the scan.
    pub const FOLLOW_AT_END: usize = usize::MAX;

    /// Whether the map follows the corrections only at the end of the scan.
    pub fn follows_at_end(&self) -> bool {
        self.follow_every == Self::FOLLOW_AT_END
    }
}

impl Default for LoopClosureConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            detector: LoopConfig::default(),
            graph: PoseGraphConfig::default(),
            odometry_sigma: (0.005, 0.004),
            loop_sigma: (0.004, 0.003),
            loop_information_from_alignment: false,
            odometry_information_from_tracking: false,
            loop_residual_reference: 0.003,
            min_loop_chi2: 6.0,
            min_move: 0.008,
            min_chunk_move_voxels: 0.5,
            frame_store_mb: 2048,
            follow_every: 10,
            reintegration_frames_per_keyframe: 20,
            reintegration_stride: 4,
        }
    }
}

impl LoopClosureConfig {
    /// The standard deviations (metres, radians) of a loop edge whose alignment left an RMS
    /// residual of `residual_m`: `loop_sigma`, scaled by the residual over
    /// `loop_residual_reference` when that is larger (an alignment is as uncertain as its
    /// residual is large).
    pub fn loop_sigmas(&self, residual_m: f32) -> (f64, f64) {
        let (st, sr) = self.loop_sigma;
        let noise = if self.loop_residual_reference > 0.0 && residual_m.is_finite() {
            (f64::from(residual_m) / self.loop_residual_reference).max(1.0)
        } else {
            1.0
        };
        (st * noise, sr * noise)
    }

    /// Checks the ranges of the fields.
    ///
    /// # Errors
    /// [`PipelineError::InvalidConfig`] naming the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(PipelineError::InvalidConfig(m));
        let (a, b) = self.odometry_sigma;
        let (c, d) = self.loop_sigma;
        if ![a, b, c, d].iter().all(|v| v.is_finite() && *v > 0.0) {
            return bad(format!(
                "loop closure sigmas {:?} {:?} must be positive",
                self.odometry_sigma, self.loop_sigma
            ));
        }
        if !(self.min_move.is_finite()
            && self.min_move >= 0.0
            && self.loop_residual_reference.is_finite()
            && self.loop_residual_reference >= 0.0
            && self.min_loop_chi2.is_finite()
            && self.min_loop_chi2 >= 0.0
            && self.min_chunk_move_voxels.is_finite()
            && self.min_chunk_move_voxels >= 0.0)
        {
            return bad("loop closure thresholds must be finite and >= 0".into());
        }
        if self.follow_every == 0 || self.reintegration_stride == 0 {
            return bad("follow_every and reintegration_stride must be at least 1".into());
        }
        if self.detector.min_keyframe_gap == 0 || self.detector.candidates == 0 {
            return bad("loop detection needs a keyframe gap and candidates of at least 1".into());
        }
        Ok(())
    }
}

/// A loop candidate tried, for the report.
#[derive(Debug, Clone, Serialize)]
pub struct LoopRecord {
    /// The frame (a keyframe) at which the loop was looked for.
    pub new_frame: usize,
    /// The earlier keyframe's frame.
    pub old_frame: usize,
    /// Accepted into the graph (and not rejected later by the optimiser).
    pub accepted: bool,
    /// Why not, when not.
    pub rejection: Option<String>,
    /// Share of the new keyframe's points landing on the old one's view.
    pub overlap: f32,
    /// Share of those agreeing after alignment.
    pub inlier_ratio: f32,
    /// RMS point-to-plane residual after alignment, metres.
    pub residual_m: f32,
    /// How far the alignment moved the poses' prediction, metres and degrees.
    pub correction_m: f64,
    /// See `correction_m`.
    pub correction_deg: f64,
    /// Feature matches that started the alignment when the candidate came from appearance
    /// features (drift beyond the pose-based search); 0 for a pose-based candidate.
    pub feature_inliers: usize,
    /// The edge's chi-square at the poses before optimisation (accepted loops).
    pub chi2_before: Option<f64>,
    /// Its graph edge (accepted loops), to follow rejections by the optimiser.
    #[serde(skip)]
    pub edge: Option<usize>,
}

/// One correction of the poses and the map.
#[derive(Debug, Clone, Serialize)]
pub struct CorrectionRecord {
    /// The frame at which the trajectory took it: the keyframe after the one whose loops
    /// found it (the search runs on a back-end thread in between).
    pub frame: usize,
    /// The frame of the keyframe whose loops found it.
    pub found_at: usize,
    /// Keyframes in the graph.
    pub keyframes: usize,
    /// Loop edges in the graph (kept).
    pub loops: usize,
    /// Optimiser iterations.
    pub iterations: usize,
    /// Largest move and turn of a keyframe.
    pub largest_move_m: f64,
    /// See `largest_move_m`, degrees.
    pub largest_turn_deg: f64,
    /// Time of the optimisation, ms.
    pub optimise_ms: f64,
}

/// One re-integration: the map brought to the corrected poses.
#[derive(Debug, Clone, Serialize)]
pub struct ReintegrationRecord {
    /// The frame at which the map took it (the shadow's swap).
    pub frame: usize,
    /// The frame at which it started (the same when done at once).
    pub started_at: usize,
    /// Frames whose correction moves some point of the map by more than the threshold
    /// ([`LoopClosureConfig::min_chunk_move_voxels`]; a bound over the map's extent).
    pub moved_frames: usize,
    /// Frames fused again (into rebuilt chunks, or whole when fused live meanwhile).
    pub refused_frames: usize,
    /// Chunk integrations those fusions cost (a whole frame is a few thousand on 7-Scenes).
    pub refused_chunks: usize,
    /// Chunks rebuilt (cleared and fused again).
    pub rebuilt_chunks: usize,
    /// Done at the end of the scan (in `finish`), not spread over keyframes.
    pub at_end: bool,
    /// Time spent on it, ms (summed over the keyframes it was spread over).
    pub ms: f64,
    /// The most of it done at one frame (the front end's longest stall for it), ms.
    pub longest_stall_ms: f64,
    /// Its start (the plan), ms: part of the first keyframe's share.
    pub start_ms: f64,
    /// Runs of stored frames re-fused from their average
    /// ([`LoopClosureConfig::reintegration_stride`]).
    pub averaged_runs: usize,
    /// Runs re-fused frame by frame because their frames disagreed.
    pub unaveraged_runs: usize,
    /// Of the runs' middle frames' valid pixels, the fraction every other frame of the run
    /// confirmed; 1 with no run.
    pub averaged_pixel_fraction: f64,
}

/// What [`crate::Pipeline::loop_closure`] reports.
#[derive(Debug, Clone, Default, Serialize)]
pub struct LoopClosureReport {
    /// Whether loop closure ran.
    pub enabled: bool,
    /// Why it stopped, when it did (a failed search thread, a pose graph refused).
    pub stopped: Option<String>,
    /// Keyframes in the graph.
    pub keyframes: usize,
    /// Every candidate verified, in order.
    pub loops: Vec<LoopRecord>,
    /// Every correction of the poses.
    pub corrections: Vec<CorrectionRecord>,
    /// Every re-integration of the map.
    pub reintegrations: Vec<ReintegrationRecord>,
    /// Times the map was due to follow a correction that moved no chunk by more than
    /// [`LoopClosureConfig::min_chunk_move_voxels`] (nothing re-fused).
    pub skipped_reintegrations: usize,
    /// How many times the configured `odometry_sigma` the odometry's standard deviations
    /// ended at: above 1 when refused loops agreed once the odometry was trusted less.
    pub odometry_scale: f64,
    /// Frames in the store with their pixels (for re-integration) and the bytes the store
    /// takes.
    pub stored_frames: usize,
    /// See `stored_frames`.
    pub frame_store_bytes: usize,
    /// The store keeps the pixels of every this many fused frames: 1 until the store reached
    /// [`LoopClosureConfig::frame_store_mb`], then 2, 4, ... (see `LoopClosure::thin`).
    pub store_stride: usize,
}

/// A fused frame kept for re-integration.
struct StoredFrame {
    index: usize,
    timestamp: f64,
    node: usize,
    /// Fixed offset from the node's keyframe, measured in the map frame when fused.
    node_from_camera: DAffine3,
    /// The pose the map holds the frame at (the tracked pose, or the corrected one once a
    /// correction moved it by more than [`LoopClosureConfig::min_move`]).
    map_pose: Affine3A,
    /// Its depth and colour; `None` once the store has thinned it out (see
    /// [`LoopClosure::thin`]): the frame then only keeps its place and pose.
    pixels: Option<StoredPixels>,
    /// Frames it stands for in a re-integration, itself included: the thinned-out frames
    /// after it, up to the next frame with pixels (their observations weigh with its own).
    stands_for: usize,
    /// The capture index of the last frame it stands for.
    last_index: usize,
}

/// A stored frame's depth (store units, [`DEPTH_UNITS_PER_M`]) and colour.
struct StoredPixels {
    depth: Vec<u16>,
    color: Vec<[u8; 3]>,
}

impl StoredPixels {
    fn bytes(&self) -> usize {
        self.depth.len() * 2 + self.color.len() * 3
    }
}

impl StoredFrame {
    /// The frame as fused, or `None` when the store thinned its pixels out.
    fn frame(&self, intrinsics: Intrinsics) -> Option<Frame> {
        let pixels = self.pixels.as_ref()?;
        let mut f = Frame::from_depth(
            intrinsics,
            pixels.depth.iter().map(|&d| if d == 0 { 0.0 } else { d as f32 / DEPTH_UNITS_PER_M }).collect(),
        );
        f.index = self.index;
        f.timestamp = self.timestamp;
        f.color.clone_from(&pixels.color);
        Some(f)
    }

    fn bytes(&self) -> usize {
        self.pixels.as_ref().map_or(0, StoredPixels::bytes) + std::mem::size_of::<Self>()
    }
}

/// A frame's depth in the store's units, rounded to nearest; 0 where it is missing or not
/// finite. This runs at every frame on the front end: `f32::round` is a library call on the
/// baseline x86-64 target, so the rounding is `+ 0.5` and a truncating cast (the same
/// result for every depth from 0.1 mm up), in parallel bands.
fn store_depth(depth: &[f32]) -> Vec<u16> {
    use rayon::prelude::*;
    depth
        .par_iter()
        .with_min_len(1 << 14)
        .map(|&d| if d > 0.0 && d.is_finite() { (d * DEPTH_UNITS_PER_M + 0.5).min(u16::MAX as f32) as u16 } else { 0 })
        .collect()
}

/// Corrected poses of the fused frames, from a correction of the graph.
pub(crate) struct PoseUpdate {
    /// Per fused frame, in order: the optimised estimate.
    pub poses: Vec<Affine3A>,
    /// The record, completed by the re-integration.
    pub record: CorrectionRecord,
}

/// Why loop closure stops when its search thread is gone (a panic there).
const SEARCH_THREAD_FAILED: &str = "stopped: the loop search thread failed (a bug: please report it)";

/// Factor on the odometry's standard deviations for an edge across a relocalisation: 5 mm
/// and 0.23 degree become 0.5 m and 23 degrees, an edge that keeps the graph connected but
/// holds nothing. Relocalisation puts the camera back from a keyframe's view after tracking
/// was lost, centimetres off where it converges beside the truth; as odometry at the usual
/// confidence, a loop that later measured that offset was spread over the whole trajectory
/// before it (`synth-flat:1`, relocalised after 4,116 lost frames 13 cm off: ATE 11.9 mm as
/// tracked, 34.9 mm after loop closure).
const RELOCALISED_ODOMETRY_SCALE: f64 = 100.0;

/// Largest factor on the configured odometry standard deviations that agreeing loops may
/// bring (5 mm a keyframe becomes at most 4 cm).
const MAX_ODOMETRY_SCALE: f64 = 8.0;

/// The loop-closure state of a pipeline. See the module documentation.
pub(crate) struct LoopClosure {
    config: LoopClosureConfig,
    intrinsics: Intrinsics,
    /// The keyframe database; away (`None`) while a search has it, so a search is out when
    /// it is away and the thread lives.
    detector: Option<LoopDetector>,
    /// The pose graph as of the last search taken back (a search works on a copy).
    graph: PoseGraph,
    /// The back-end thread of the searches, started at the first.
    search_thread: Option<SearchThread>,
    /// Keyframes not in the database yet: the next search adds them first.
    new_keyframes: Vec<Frame>,
    /// What the search taken back found, until the trajectory takes its correction.
    found: Option<SearchOutcome>,
    /// The back-end time of the search taken back last, ms.
    search_ms: Option<(f64, Option<f64>)>,
    /// Per graph node, the position of its frame in `frames`.
    node_frames: Vec<usize>,
    frames: Vec<StoredFrame>,
    store_bytes: usize,
    /// The store keeps the pixels of the frames at multiples of this position (and, while a
    /// re-integration runs, of every frame it has yet to fuse).
    store_stride: usize,
    report: LoopClosureReport,
    /// Poses of the fused frames as tracked, before any correction.
    tracked: Trajectory,
    /// Whether a correction awaits the map, and keyframes since the map last followed.
    behind: bool,
    keyframes_since_follow: usize,
    /// The re-integration in progress, spread over keyframes.
    shadow: Option<Shadow>,
    /// How many times `odometry_sigma` the odometry's standard deviations are, after loops
    /// showed the scan drifting more than the configured noise allows (see
    /// `retry_with_looser_odometry`); 1 at the start.
    odometry_scale: f64,
    /// Chunks selected by the frames fused live, and those frames: the mean is what a frame
    /// costs, the unit of the per-keyframe budget.
    live_chunks: usize,
    live_frames: usize,
    /// Stored frames per keyframe (the last complete interval), over which a keyframe's
    /// re-integration budget is spread; and the store's size at the last keyframe.
    keyframe_interval: usize,
    frames_at_keyframe: usize,
    /// Since the last graph node, the tracked frame whose alignment was worst conditioned:
    /// its condition, map pose and camera-frame normal matrix (the odometry edge's shape
    /// with [`LoopClosureConfig::odometry_information_from_tracking`]).
    weakest_tracking: Option<(f64, DAffine3, Mat6)>,
}

fn to_f64(p: Affine3A) -> DAffine3 {
    DAffine3 { matrix3: p.matrix3.as_dmat3(), translation: p.translation.as_dvec3() }
}

fn to_f32(p: DAffine3) -> Affine3A {
    Affine3A { matrix3: p.matrix3.as_mat3().into(), translation: p.translation.as_vec3().into() }
}

impl LoopClosure {
    pub fn new(config: LoopClosureConfig, intrinsics: Intrinsics) -> Self {
        Self {
            detector: Some(LoopDetector::new(config.detector)),
            graph: PoseGraph::new(),
            search_thread: None,
            new_keyframes: Vec::new(),
            found: None,
            search_ms: None,
            odometry_scale: 1.0,
            node_frames: Vec::new(),
            intrinsics,
            frames: Vec::new(),
            store_bytes: 0,
            store_stride: 1,
            report: LoopClosureReport { enabled: true, odometry_scale: 1.0, ..LoopClosureReport::default() },
            tracked: Trajectory::default(),
            behind: false,
            keyframes_since_follow: 0,
            shadow: None,
            live_chunks: 0,
            live_frames: 0,
            keyframe_interval: 10,
            frames_at_keyframe: 0,
            weakest_tracking: None,
            config,
        }
    }

    pub fn is_running(&self) -> bool {
        self.report.stopped.is_none()
    }

    pub fn report(&self) -> LoopClosureReport {
        let mut r = self.report.clone();
        r.keyframes = self.graph.poses().len();
        r.stored_frames = self.frames.iter().filter(|f| f.pixels.is_some()).count();
        r.frame_store_bytes = self.store_bytes;
        r.store_stride = self.store_stride;
        for l in &mut r.loops {
            if let Some(e) = l.edge {
                if self.graph.is_rejected(e) {
                    l.accepted = false;
                    l.rejection = Some("rejected by the optimiser (inconsistent with the other edges)".into());
                }
            }
        }
        r
    }

    pub fn tracked(&self) -> &Trajectory {
        &self.tracked
    }

    /// Fuses a tracked frame into the live map (what [`TsdfMap::integrate`] does), first
    /// letting a re-integration in progress copy the chunks the frame is about to change.
    pub fn fuse_live(&mut self, map: &mut TsdfMap, frame: &Frame, pose: Affine3A) -> Result<IntegrationStats> {
        let keys = map.select_chunks(frame, pose)?;
        self.live_chunks += keys.len();
        self.live_frames += 1;
        if let Some(shadow) = self.shadow.as_mut() {
            shadow.before_live_fusion(map, &keys);
        }
        Ok(map.integrate_chunks(frame, pose, &keys)?)
    }

    /// Counts a frame fused outside [`LoopClosure::fuse_live`] (grouped fusion while no
    /// re-integration runs): `chunks` of its selection, for the re-integration's budget.
    pub fn count_live(&mut self, chunks: usize) {
        self.live_chunks += chunks;
        self.live_frames += 1;
    }

    /// Records a fused frame at its tracked pose; a keyframe (`keyframe`, and always the
    /// first frame) becomes a graph node with an odometry edge from the previous one.
    #[cfg(test)]
    pub fn add_frame(&mut self, frame: &Frame, pose: Affine3A, keyframe: bool) -> Result<()> {
        self.add_frame_tracked(frame, pose, keyframe, None, false)
    }

    /// [`LoopClosure::add_frame`] with what the tracker measured of the frame: the
    /// condition of its alignment and its camera-frame normal matrix
    /// ([`semrecon_recon::TrackingResult::camera_hessian`]), and whether it was `relocalised`
    /// (its pose found again from a keyframe after tracking was lost). A relocalised frame
    /// becomes a graph node, joined to the one before by a loose edge
    /// ([`RELOCALISED_ODOMETRY_SCALE`]), so that loops, not the relocalisation's pose, place
    /// what comes after it relative to what came before.
    pub fn add_frame_tracked(
        &mut self,
        frame: &Frame,
        pose: Affine3A,
        keyframe: bool,
        tracking: Option<(f64, Mat6)>,
        relocalised: bool,
    ) -> Result<()> {
        self.tracked.push(frame.timestamp, pose);
        let new_node = keyframe || relocalised || self.graph.poses().is_empty();
        if new_node {
            // The graph this node joins is the one the last search optimised (a relocalised
            // frame between keyframes waits for the search out, if any: a rare stall).
            self.take_search();
        }
        if !self.is_running() {
            return Ok(());
        }
        let pose64 = to_f64(pose);
        let invalid = |e: semrecon_recon::PoseGraphError| PipelineError::InvalidFrame {
            index: frame.index,
            message: format!("loop closure: {e}"),
        };
        if !pose64.is_finite() {
            return Err(invalid(semrecon_recon::PoseGraphError::NonFinitePose(self.graph.poses().len())));
        }
        if let Some((condition, h)) =
            tracking.filter(|(c, h)| c.is_finite() && h.iter().flatten().all(|v| v.is_finite()))
        {
            if self.weakest_tracking.as_ref().is_none_or(|w| condition < w.0) {
                self.weakest_tracking = Some((condition, pose64, h));
            }
        }
        if keyframe && self.frames.len() > self.frames_at_keyframe {
            // Counts of stored frames: deterministic.
            self.keyframe_interval = self.frames.len() + 1 - self.frames_at_keyframe;
            self.frames_at_keyframe = self.frames.len() + 1;
        }
        if new_node {
            // Odometry is measured in the map frame, where the tracker works: from the map
            // pose of the previous keyframe's frame (the graph's own estimate of it may have
            // moved by less than `min_move` since, without the map following).
            let odometry = self.node_frames.last().map(|&f| to_f64(self.frames[f].map_pose).inverse() * pose64);
            let start = match odometry {
                Some(z) => self.graph.poses()[self.graph.poses().len() - 1] * z,
                None => pose64,
            };
            let node = self.graph.add_pose(start).map_err(invalid)?;
            // The node's frame and keyframe copy first: a failed edge below leaves a node
            // without odometry (the optimiser keeps it still), never an inconsistent store.
            self.node_frames.push(self.frames.len());
            // Its view joins the keyframe database on the search thread, before the search
            // (building a keyframe's pyramid and features costs milliseconds).
            self.new_keyframes.push(frame.clone());
            let weakest = self.weakest_tracking.take();
            if let Some(z) = odometry {
                let (st, sr) = self.config.odometry_sigma;
                let scale = self.odometry_scale * if relocalised { RELOCALISED_ODOMETRY_SCALE } else { 1.0 };
                let (st, sr) = (st * scale, sr * scale);
                // The weakest frame's form, carried from its camera frame to the keyframe's.
                let shaped = weakest
                    .filter(|_| self.config.odometry_information_from_tracking)
                    .and_then(|(_, f, h)| odometry_information(&pull_back(&h, &adjoint(&(f.inverse() * pose64))), st));
                self.graph
                    .add_edge(PoseEdge {
                        from: node - 1,
                        to: node,
                        from_from_to: z,
                        information: shaped.unwrap_or_else(|| isotropic_information(st, sr)),
                        kind: EdgeKind::Odometry,
                    })
                    .map_err(invalid)?;
            }
        }
        let node = self.graph.poses().len() - 1;
        let node_map_pose = self.node_frames.get(node).and_then(|&f| self.frames.get(f)).map_or(pose, |f| f.map_pose);
        let position = self.frames.len();
        // A shadow being built fuses every frame fused live meanwhile, so it needs their
        // pixels whatever the stride; off the stride, no copy at all (the front end's cost).
        let keep = self.shadow.is_some() || position.is_multiple_of(self.store_stride);
        let stored = StoredFrame {
            index: frame.index,
            timestamp: frame.timestamp,
            node,
            node_from_camera: to_f64(node_map_pose).inverse() * pose64,
            map_pose: pose,
            pixels: keep.then(|| StoredPixels { depth: store_depth(&frame.depth), color: frame.color.clone() }),
            stands_for: 1,
            last_index: frame.index,
        };
        self.store_bytes += stored.bytes();
        // A frame fused live while a shadow is built joins it at its estimate, where the
        // shadow puts every frame it fuses.
        let planned = self.shadow.is_some().then(|| self.estimate(&stored));
        self.frames.push(stored);
        if !keep {
            // Into the last frame with pixels, at most a stride back (position 0 always has
            // them).
            let keeper = self.frames.iter().rposition(|f| f.pixels.is_some()).unwrap_or(0);
            self.fold(position, keeper);
        }
        if let (Some(shadow), Some(pose)) = (self.shadow.as_mut(), planned) {
            shadow.push_live_frame(position, pose);
        }
        if self.store_bytes > self.config.frame_store_mb << 20 {
            self.thin();
        }
        Ok(())
    }

    /// Brings the store back within [`LoopClosureConfig::frame_store_mb`] by dropping the
    /// pixels of the frames off the stride, doubling the stride until it fits: a long scan
    /// keeps every second, then every fourth, ... frame, instead of loop closure stopping
    /// when the store is full. A kept frame stands for the dropped ones after it (their
    /// weight joins its own when the map follows a correction), so a rebuilt chunk weighs as
    /// much as before and is fused from fewer, equally spaced views: at 30 Hz neighbouring
    /// frames see nearly the same surface, and a re-integration already averages runs of four
    /// ([`LoopClosureConfig::reintegration_stride`]). What a rebuilt chunk loses is what only
    /// the dropped frames saw (the edge of a fast pan). Frames a re-integration in progress
    /// has yet to fuse keep their pixels, and the stride does not grow while it runs: its
    /// queue bounds what the store holds beyond the budget. Positions, not clocks, decide:
    /// the same bits for any thread count.
    fn thin(&mut self) {
        let budget = self.config.frame_store_mb << 20;
        let mut queued = vec![false; self.frames.len()];
        if let Some(shadow) = &self.shadow {
            for p in shadow.queued_frames() {
                queued[p] = true;
            }
        }
        loop {
            let mut keeper = 0;
            for (p, &queued) in queued.iter().enumerate() {
                if self.frames[p].pixels.is_none() {
                    continue;
                }
                if p.is_multiple_of(self.store_stride) || queued {
                    keeper = p;
                } else {
                    self.store_bytes -= self.frames[p].pixels.take().map_or(0, |px| px.bytes());
                    self.fold(p, keeper);
                }
            }
            if self.store_bytes <= budget || self.shadow.is_some() || self.store_stride >= self.frames.len() {
                break;
            }
            self.store_stride *= 2;
        }
    }

    /// Folds frame `dropped`, whose pixels are gone, into `keeper` before it: the keeper
    /// stands for it (and for what it stood for) in a re-integration.
    fn fold(&mut self, dropped: usize, keeper: usize) {
        let (stands_for, last_index) = (self.frames[dropped].stands_for, self.frames[dropped].last_index);
        let k = &mut self.frames[keeper];
        k.stands_for += stands_for;
        k.last_index = k.last_index.max(last_index);
        self.frames[dropped].stands_for = 0;
    }

    fn stop(&mut self, why: String) {
        self.report.stopped = Some(why);
        // The map keeps the poses it holds; the corrections stay in the trajectory.
        self.shadow = None;
        self.frames = Vec::new();
        self.store_bytes = 0;
    }

    /// Takes back the search handed to the back end at the previous keyframe, waiting for it
    /// when it still runs: its graph (optimised, with the loops it accepted) replaces the
    /// front end's copy, its loops join the report, and a correction it found waits for
    /// [`LoopClosure::close_loops`] or [`LoopClosure::finish_search`]. Called at a keyframe
    /// before it joins the graph (a frame count: the same bits for any thread count); nothing
    /// when no search is out.
    pub fn take_search(&mut self) {
        if self.detector.is_some() || self.search_thread.is_none() {
            return;
        }
        match self.search_thread.as_ref().and_then(SearchThread::wait) {
            Some((work, outcome)) => {
                let GraphWork { detector, graph, odometry_scale, .. } = *work;
                self.detector = Some(detector);
                self.graph = graph;
                self.odometry_scale = odometry_scale;
                self.report.odometry_scale = odometry_scale;
                self.report.loops.extend(outcome.loops.iter().cloned());
                self.search_ms = Some((outcome.ms, outcome.cpu_ms));
                self.found = Some(outcome);
            }
            None => {
                self.search_thread = None;
                self.stop(SEARCH_THREAD_FAILED.into());
            }
        }
    }

    /// The back-end time of the search taken back last (the search and the optimisation,
    /// ms: wall time on its thread, and CPU time where the platform says), once.
    pub fn take_search_ms(&mut self) -> Option<(f64, Option<f64>)> {
        self.search_ms.take()
    }

    /// At a keyframe (after [`LoopClosure::add_frame_tracked`]): returns the correction that
    /// the previous keyframe's search found, as every stored frame's corrected pose (frames
    /// since move with their keyframe), and hands this keyframe's search to the back end
    /// (`search`). Warnings for refused optimisations.
    pub fn close_loops(&mut self, frame_index: usize, warnings: &mut Vec<String>) -> Option<PoseUpdate> {
        self.take_search();
        let update = self.adopt_found(frame_index, warnings);
        if self.is_running() && self.graph.poses().len() >= 2 {
            self.submit_search(frame_index);
        }
        update
    }

    /// The end of a scan: waits for the search in flight and returns its correction, as
    /// [`LoopClosure::close_loops`] does, without starting another.
    pub fn finish_search(&mut self, frame_index: usize, warnings: &mut Vec<String>) -> Option<PoseUpdate> {
        self.take_search();
        self.adopt_found(frame_index, warnings)
    }

    fn adopt_found(&mut self, frame_index: usize, warnings: &mut Vec<String>) -> Option<PoseUpdate> {
        let outcome = self.found.take()?;
        warnings.extend(outcome.warnings);
        // Stopped meanwhile: the store is gone, the map keeps its poses.
        let correction = outcome.correction.filter(|_| self.is_running())?;
        Some(PoseUpdate {
            poses: self.estimates(),
            record: CorrectionRecord {
                frame: frame_index,
                found_at: outcome.frame,
                keyframes: self.graph.poses().len(),
                loops: correction.loops,
                iterations: correction.iterations,
                largest_move_m: correction.largest_change.0,
                largest_turn_deg: correction.largest_change.1.to_degrees(),
                optimise_ms: correction.optimise_ms,
            },
        })
    }

    /// Hands the search of the newest keyframe to the back-end thread (started on first use).
    fn submit_search(&mut self, frame_index: usize) {
        if self.search_thread.is_none() {
            match SearchThread::start(self.config.clone()) {
                Ok(thread) => self.search_thread = Some(thread),
                Err(e) => {
                    self.stop(format!("stopped: {e}"));
                    return;
                }
            }
        }
        let Some(detector) = self.detector.take() else { return };
        let work = Box::new(GraphWork {
            detector,
            new_keyframes: std::mem::take(&mut self.new_keyframes),
            graph: self.graph.clone(),
            odometry_scale: self.odometry_scale,
        });
        if !self.search_thread.as_ref().is_some_and(|t| t.submit(work, frame_index)) {
            self.search_thread = None;
            self.stop(SEARCH_THREAD_FAILED.into());
        }
    }

    /// Records a correction adopted by the trajectory; the map is then behind it.
    pub fn record_correction(&mut self, record: CorrectionRecord) {
        self.report.corrections.push(record);
        self.behind = true;
    }

    /// Whether a correction has not reached the map yet (a re-integration in progress
    /// included).
    pub fn is_behind(&self) -> bool {
        self.behind || self.shadow.is_some()
    }

    /// Whether this keyframe's [`LoopClosure::keyframe_follow`] (called next) starts the
    /// map's following of a correction (never when the map follows at the end of the scan).
    pub fn starts_following(&self) -> bool {
        self.shadow.is_none() && self.due_after(self.keyframes_since_follow.saturating_add(1))
    }

    /// Whether the map is due to follow once `keyframes` keyframes have passed since it last
    /// did.
    fn due_after(&self, keyframes: usize) -> bool {
        self.behind && keyframes >= self.config.follow_every
    }

    /// Called once per keyframe: whether the map should follow now.
    fn follow_due(&mut self) -> bool {
        self.keyframes_since_follow = self.keyframes_since_follow.saturating_add(1);
        self.due_after(self.keyframes_since_follow)
    }

    /// Whether a re-integration is being built in a shadow.
    pub fn is_rebuilding(&self) -> bool {
        self.shadow.is_some()
    }

    /// At a keyframe (after [`LoopClosure::close_loops`]): advances the re-integration in
    /// progress by the per-keyframe budget, or starts one when the map is due to follow a
    /// correction (at once when the budget is 0). When one completes, `map` is its result and
    /// this returns the move of the last frame's map pose (`corrected_from_old`, for the
    /// tracker) and every frame's pose estimate (the corrected trajectory).
    pub fn keyframe_follow(&mut self, map: &mut TsdfMap, frame: usize) -> Result<Option<(Affine3A, Vec<Affine3A>)>> {
        let due = self.follow_due();
        if self.shadow.is_none() {
            if !due {
                return Ok(None);
            }
            if self.config.reintegration_frames_per_keyframe == 0 {
                return self.follow_now(map, frame, false).map(Some);
            }
            if !self.start(map, frame) {
                return Ok(None);
            }
        }
        self.advance(map, frame, Some(self.frame_budget()), false, true)
    }

    /// At a fused frame that is not a keyframe, while a re-integration is in progress: fuses
    /// this frame's share of it into the shadow (the swap waits for a keyframe). Spreading
    /// over frames rather than keyframes keeps each stall to about two frame fusions.
    pub fn frame_follow(&mut self, map: &mut TsdfMap, frame: usize) -> Result<()> {
        self.advance(map, frame, Some(self.frame_budget()), false, false).map(|_| ())
    }

    /// Chunk integrations per fused frame: `reintegration_frames_per_keyframe` frames' worth
    /// spread over the frames of a keyframe interval.
    fn frame_budget(&self) -> usize {
        (self.config.reintegration_frames_per_keyframe * self.chunks_per_frame())
            .div_ceil(self.keyframe_interval.max(1))
    }

    /// A frame's worth of chunk integrations: the mean selection of the frames fused live
    /// (a count, so the budget is deterministic), 1 before any.
    fn chunks_per_frame(&self) -> usize {
        self.live_chunks.checked_div(self.live_frames).unwrap_or(1).max(1)
    }

    /// Plans the map's following of the current estimates and starts a shadow for it;
    /// false (and the correction counted as skipped) when it moves no chunk far enough.
    fn start(&mut self, map: &TsdfMap, frame: usize) -> bool {
        self.behind = false;
        self.keyframes_since_follow = 0;
        let t = std::time::Instant::now();
        let tau = self.config.min_chunk_move_voxels * map.config().voxel_size;
        let plan = plan::plan(map, &self.frames, &self.estimates(), tau);
        if plan.is_empty() {
            self.report.skipped_reintegrations += 1;
            return false;
        }
        let mut shadow = Shadow::start(map, plan, &self.frames, frame, self.config.reintegration_stride);
        shadow.start_ms = t.elapsed().as_secs_f64() * 1e3;
        shadow.plan_ms = shadow.start_ms;
        shadow.ms += shadow.start_ms;
        self.shadow = Some(shadow);
        true
    }

    /// Fuses up to `budget` frames (all: `None`) into the shadow in progress and swaps it in
    /// when complete.
    fn advance(
        &mut self,
        map: &mut TsdfMap,
        frame: usize,
        budget: Option<usize>,
        at_end: bool,
        may_swap: bool,
    ) -> Result<Option<(Affine3A, Vec<Affine3A>)>> {
        // A chunk selection costs about a sixth of a whole frame's fusion.
        let selection_cost = self.chunks_per_frame() / 6;
        let Some(shadow) = self.shadow.as_mut() else { return Ok(None) };
        let budget = if shadow.must_finish() { None } else { budget };
        if !shadow.step(map, &self.frames, self.intrinsics, budget, selection_cost)? || !may_swap {
            return Ok(None);
        }
        let Some(mut shadow) = self.shadow.take() else { return Ok(None) };
        let poses = std::mem::take(&mut shadow.poses);
        self.report.reintegrations.push(ReintegrationRecord {
            frame,
            started_at: shadow.started_at,
            moved_frames: shadow.moved,
            refused_frames: shadow.fused,
            refused_chunks: shadow.chunk_fusions,
            rebuilt_chunks: shadow.rebuilt_chunks(),
            ms: shadow.ms,
            longest_stall_ms: shadow.longest_ms,
            start_ms: shadow.plan_ms,
            at_end,
            averaged_runs: shadow.averaged_runs,
            unaveraged_runs: shadow.unaveraged_runs,
            averaged_pixel_fraction: if shadow.candidate_pixels == 0 {
                1.0
            } else {
                shadow.averaged_pixels as f64 / shadow.candidate_pixels as f64
            },
        });
        shadow.swap_into(map);
        let corrected_from_old = self.adopt(&poses);
        Ok(Some((corrected_from_old, self.estimates())))
    }

    /// The map holds the frames at `poses` now: returns the move of the last one.
    fn adopt(&mut self, poses: &[Affine3A]) -> Affine3A {
        let old = self.frames.last().map(|f| f.map_pose);
        for (f, p) in self.frames.iter_mut().zip(poses) {
            f.map_pose = *p;
        }
        match (old, poses.last()) {
            (Some(o), Some(n)) => *n * o.inverse(),
            _ => Affine3A::IDENTITY,
        }
    }

    /// Makes `map` follow the graph's estimates of the poses now, in place: completes the
    /// re-integration in progress (what is pending of it), then re-integrates, at once, what
    /// a later correction moved further (the end of a scan; every correction when the
    /// per-keyframe budget is 0). Returns what [`LoopClosure::keyframe_follow`] does. Nothing
    /// moves when loop closure stopped (the store is gone).
    pub fn follow(&mut self, map: &mut TsdfMap, frame: usize) -> Result<(Affine3A, Vec<Affine3A>)> {
        self.follow_now(map, frame, true)
    }

    fn follow_now(&mut self, map: &mut TsdfMap, frame: usize, at_end: bool) -> Result<(Affine3A, Vec<Affine3A>)> {
        let mut corrected_from_old = Affine3A::IDENTITY;
        if self.behind {
            // A correction came after the shadow's start: one re-integration from the live
            // map (which holds every frame where the map says) covers both, for less work
            // than completing the shadow and then rebuilding what the later correction moved.
            self.shadow = None;
        } else if let Some((c, _)) = self.advance(map, frame, None, at_end, true)? {
            corrected_from_old = c;
        }
        if self.behind && self.start(map, frame) {
            if let Some((c, _)) = self.advance(map, frame, None, at_end, true)? {
                corrected_from_old = c * corrected_from_old;
            }
        }
        Ok((corrected_from_old, self.estimates()))
    }

    /// The graph's estimate of every stored frame's pose: its keyframe's pose times its
    /// fixed offset (keyframes added since the last optimisation extend the corrected chain).
    fn estimates(&self) -> Vec<Affine3A> {
        self.frames.iter().map(|f| self.estimate(f)).collect()
    }

    fn estimate(&self, f: &StoredFrame) -> Affine3A {
        to_f32(self.graph.poses()[f.node] * f.node_from_camera)
    }
}

/// How far `a` to `b` moves a point 2 m in front of the camera, about: translation plus
/// twice the turn.
fn moved_by(a: &DAffine3, b: &DAffine3) -> f64 {
    let (t, r) = pose_distance(a, b);
    t + 2.0 * r
}

mod plan;
mod search;
mod shadow;

#[cfg(test)]
mod tests;
