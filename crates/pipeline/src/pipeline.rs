//! [`Pipeline`]: the live system of MISSION.md section 1 behind one object. Every frame is
//! tracked and fused on the caller's thread (the front end); every `keyframe_every` fused
//! frames the mesh is brought up to date (within [`PipelineConfig::mesh_budget`]) and the
//! surface of the chunks that changed, read from the TSDF (not the mesh, which may lag under
//! the budget), is handed to the semantic back end (its own thread, see [`crate::backend`]), whose class probabilities
//! are accumulated per 5 cm cell and read by [`Pipeline::mesh`]. When tracking, keyframes
//! also look for loops and correct the poses, and the map follows the correction (see
//! [`crate::loop_closure`]; on the front end, before the keyframe's meshing).
//!
//! Timing rules: without `realtime`, the front end waits at each keyframe for the previous
//! keyframe's labels before it snapshots the map again, so every pass sees the same map and
//! results are applied at the same frames whatever the machine's speed: the output is
//! deterministic. With `realtime`, keyframes that find the back end busy are skipped (the next
//! pass then covers their changes too) and results are applied as soon as they arrive.

use std::collections::BTreeSet;
use std::time::Instant;

use glam::{Affine3A, Vec3};
use semrecon_data::{class::UNLABELED, Frame, Intrinsics, LabeledMesh, SemanticClass, Trajectory};
use semrecon_net::Segmenter;
use semrecon_recon::{
    GroupedFusion, IncrementalMesher, KeyframeIndex, LostReason, MapMemory, MeshStoreMemory, RemeshTolerance, Tracker,
    TrackerConfig, TrackingResult, TrackingStatus, TsdfMap,
};
use serde::Serialize;

use crate::backend::{Backend, Job, JobResult};
use crate::config::{PipelineConfig, PoseMode, SemanticMode};
use crate::error::{PipelineError, Result};
use crate::gravity::{camera_up_prior, estimate_up, given_up, UpEstimate};
use crate::label_store::LabelStore;
use crate::loop_closure::{LoopClosure, LoopClosureReport, PoseUpdate};
use crate::semantic_map::{SurfaceCells, CLASSES};
use crate::surface_cells::SurfaceRule;
use crate::timing::StageTimes;

/// Keyframes tried per relocalisation; each costs about one tracking call with a ray-cast.
const RELOCALISATION_ATTEMPTS: usize = 2;
/// Relocalisation is tried on the first lost frame and then on every this many: a lost
/// streak lasts until the camera returns near a keyframe, and trying on every frame would
/// triple the cost of each lost frame for a recovery a frame or two earlier.
const RELOCALISATION_EVERY: usize = 3;

/// Stages the front end runs, and its waits for the back end (their sum is
/// [`Pipeline::front_end_seconds`]).
pub const FRONT_END_STAGES: [&str; 10] = [
    "tracking",
    "fusion",
    "map compaction",
    "loop closure",
    "map re-integration",
    "final map re-integration",
    "meshing",
    "final meshing",
    "semantic snapshot",
    "semantic wait",
];

/// After a loop search was taken back: its back-end time joins the timings, and the
/// trajectory takes the correction it found (every fused frame's corrected pose); the map is
/// then behind it.
fn adopt_search(
    lc: &mut LoopClosure,
    update: Option<PoseUpdate>,
    trajectory: &mut Trajectory,
    times: &mut StageTimes,
    warnings: &mut Vec<String>,
) {
    if let Some((ms, cpu_ms)) = lc.take_search_ms() {
        times.record_ms("global pose optimisation", ms);
        if let Some(cpu_ms) = cpu_ms {
            times.record_ms("global pose optimisation, CPU time (back end)", cpu_ms);
        }
    }
    let Some(update) = update else { return };
    if update.poses.len() == trajectory.poses.len() {
        lc.record_correction(update.record);
        trajectory.poses = update.poses;
    } else {
        // Cannot happen while the store and the trajectory grow together.
        warnings.push("loop closure: frame store out of step with the trajectory; correction skipped".into());
    }
}

/// What happened to one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FrameStatus {
    /// The first fused frame: its pose is the initial pose.
    Initialized,
    /// Tracked (or given a ground-truth pose) and fused.
    Fused,
    /// Tracking from the last pose failed, and relocalisation from a keyframe that looks
    /// like the frame recovered the pose; fused.
    Relocalised,
    /// Tracking failed: the frame was not fused (the map is unchanged).
    Lost(LostReason),
    /// Ground-truth mode and the frame has no pose: not fused.
    NoPose,
}

/// The outcome of [`Pipeline::push_frame`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameResult {
    /// The frame's index in its source.
    pub index: usize,
    /// Fused, lost, ...
    pub status: FrameStatus,
    /// The frame's `world_from_camera` when fused; `None` otherwise.
    pub pose: Option<Affine3A>,
    /// Whether this frame was a keyframe (mesh updated, semantics considered).
    pub keyframe: bool,
    /// Whether a semantic pass was started at this frame.
    pub semantic_pass: bool,
    /// What the tracker measured of the frame (conditioning, departure from the motion
    /// prediction, inliers): `None` with ground-truth poses. For diagnosing where a scan
    /// drifted (`semrecon run` writes it to `tracking.csv`).
    pub tracking: Option<TrackingResult>,
}

/// One semantic pass, for reports and benchmarks.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SemanticPass {
    /// Frame index the snapshot was taken at.
    pub frame: usize,
    /// Cells with surface in the whole map at that time.
    pub map_cells: usize,
    /// Cells given to the network (changed tiles and their context).
    pub input_cells: usize,
    /// Cells whose labels were written back.
    pub updated_cells: usize,
    /// Voxels of the network's input (cells merged in the gravity-aligned grid).
    pub network_voxels: usize,
    /// Front-end time of the snapshot (surface extraction, up estimate, selection), ms.
    pub snapshot_ms: f64,
    /// Back-end time (voxelising, network, softmax), ms.
    pub network_ms: f64,
    /// Whether the pass labelled every cell again, its result replacing every label made
    /// before, because the up direction moved (see `RELABEL_ANGLE_DEG`).
    pub relabelled: bool,
}

/// An up direction that moves by more than this many degrees between passes invalidates the
/// labels made so far (see `Pipeline::start_pass`). Estimates from the map's planes move by
/// 0.1-3 degrees from pass to pass; a first estimate from a pitched camera alone was 37-50
/// degrees off on three of the demo's first ten seeds.
const RELABEL_ANGLE_DEG: f32 = 10.0;

/// Semantic state: surface cells, labels, the back end.
struct Semantics {
    cells: SurfaceCells,
    labels: LabelStore,
    backend: Backend,
    /// Snapshot record of the job in flight.
    in_flight: Option<SemanticPass>,
    passes: Vec<SemanticPass>,
    skipped: usize,
    up: Option<UpEstimate>,
    /// The labels are from another frame until a relabelling pass lands.
    relabel_pending: bool,
    /// Whether the map changed since the last snapshot.
    stale: bool,
    /// The next snapshot reads every changed chunk still waiting for its turn (the scan's
    /// last passes).
    flush: bool,
}

/// The live pipeline. See the module documentation.
pub struct Pipeline {
    config: PipelineConfig,
    intrinsics: Intrinsics,
    map: TsdfMap,
    mesher: IncrementalMesher,
    tracker: Option<Tracker>,
    /// Keyframe thumbnails for relocalisation after a lost frame.
    keyframe_index: KeyframeIndex,
    relocalised: usize,
    /// Frames the tracker aligned again with colour (depth alone left them poorly
    /// conditioned).
    colour_fallbacks: usize,
    /// Consecutive lost frames so far.
    lost_streak: usize,
    trajectory: Trajectory,
    times: StageTimes,
    fused: usize,
    meshed_at: usize,
    /// Chunks the mesh budget left waiting after the keyframes' meshing: (keyframes, sum,
    /// largest).
    pending_after_keyframes: (usize, usize, usize),
    frames: usize,
    lost: usize,
    last_pose: Option<Affine3A>,
    /// Index of the last fused frame (the clock of map compaction).
    last_fused_index: usize,
    semantics: Option<Semantics>,
    /// Keyframe graph, loop detection and the frame store (tracking with loop closure on).
    loop_closure: Option<LoopClosure>,
    /// Fusion of far chunks from groups of frames ([`TsdfConfig::far_group_beyond_m`]); with
    /// loop closure, flushed before a re-integration and bypassed while one runs (its shadow
    /// follows frames fused whole).
    grouped: GroupedFusion,
    warnings: Vec<String>,
    /// The live mesh's store as it was when [`Pipeline::finish`] took the whole mesh from it,
    /// while the emptied store has not been refilled: [`Pipeline::mesh`] then meshes the map
    /// afresh.
    handed_over: Option<MeshStoreMemory>,
    /// The semantic map's heap bytes when [`Pipeline::finish`] released its surface cells.
    semantic_bytes_at_finish: Option<usize>,
    /// The map's memory at the end of the scan, before [`Pipeline::finish`] spilled it (with
    /// a budget) for the final mesh's assembly.
    map_memory_at_finish: Option<MapMemory>,
}

impl std::fmt::Debug for Pipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pipeline").field("frames", &self.frames).field("fused", &self.fused).finish_non_exhaustive()
    }
}

impl Pipeline {
    /// A pipeline for frames of camera `intrinsics`; `net` labels the map (without one, the
    /// mesh stays unlabelled and no back end runs).
    ///
    /// # Errors
    /// An invalid configuration; a network that does not output the 13 classes.
    pub fn new(config: PipelineConfig, intrinsics: Intrinsics, net: Option<Segmenter>) -> Result<Self> {
        config.validate()?;
        let mut map = TsdfMap::new(config.tsdf)?;
        if let Some(budget) = config.memory.budget_bytes {
            let path = config
                .memory
                .spill_path
                .clone()
                .unwrap_or_else(|| std::env::temp_dir().join(format!("semrecon-map-{}.spill", std::process::id())));
            map.set_memory_budget(budget, &path).map_err(semrecon_recon::ReconError::from)?;
        }
        let semantics = match net {
            None => None,
            Some(net) => {
                let c = net.config();
                if c.classes != CLASSES {
                    return Err(PipelineError::InvalidConfig(format!(
                        "network {} outputs {} classes, the pipeline labels {CLASSES}",
                        c.name, c.classes
                    )));
                }
                if c.in_channels != 3 {
                    return Err(PipelineError::InvalidConfig(format!(
                        "network {} takes {} input channels, the pipeline gives RGB",
                        c.name, c.in_channels
                    )));
                }
                let cells = SurfaceCells::new(c.voxel_size, SurfaceRule::new(&config.tsdf, &config.mesh))
                    .with_refresh_every(config.semantics.surface_refresh_keyframes);
                Some(Semantics {
                    cells,
                    labels: LabelStore::new(island_cells(config.semantics.min_island_m2, c.voxel_size))
                        .with_segment_vote(config.semantics.segment_vote),
                    backend: Backend::start(net)?,
                    in_flight: None,
                    passes: Vec::new(),
                    skipped: 0,
                    up: None,
                    relabel_pending: false,
                    stale: false,
                    flush: false,
                })
            }
        };
        let mesher =
            IncrementalMesher::with_config(config.mesh, RemeshTolerance::EXACT)?.with_budget(config.mesh_budget);
        let loop_closure = (config.poses == PoseMode::Track && config.loop_closure.enabled)
            .then(|| LoopClosure::new(config.loop_closure.clone(), intrinsics));
        let grouped = GroupedFusion::new(config.tsdf.far_group_beyond_m, config.tsdf.far_group_frames);
        Ok(Self {
            config,
            intrinsics,
            map,
            mesher,
            tracker: None,
            keyframe_index: KeyframeIndex::new(),
            relocalised: 0,
            colour_fallbacks: 0,
            lost_streak: 0,
            trajectory: Trajectory::default(),
            times: StageTimes::default(),
            fused: 0,
            meshed_at: 0,
            pending_after_keyframes: (0, 0, 0),
            frames: 0,
            lost: 0,
            last_pose: None,
            last_fused_index: 0,
            semantics,
            loop_closure,
            grouped,
            warnings: Vec::new(),
            handed_over: None,
            semantic_bytes_at_finish: None,
            map_memory_at_finish: None,
        })
    }

    /// Tracks and fuses one frame; at keyframes updates the mesh and starts a semantic pass.
    ///
    /// Frames must come in capture order. A frame that cannot be tracked is reported in the
    /// result and leaves the map unchanged; the pipeline goes on with the next.
    ///
    /// # Errors
    /// [`PipelineError::InvalidFrame`] when the frame's buffers do not match the camera (the
    /// frame is skipped, nothing changes). Failures of the semantic back end are not errors
    /// of the frame: they are collected in [`Pipeline::warnings`].
    pub fn push_frame(&mut self, frame: &Frame) -> Result<FrameResult> {
        let k = &self.intrinsics;
        if frame.intrinsics.width != k.width || frame.intrinsics.height != k.height {
            return Err(PipelineError::InvalidFrame {
                index: frame.index,
                message: format!(
                    "{}x{} frame for a {}x{} camera",
                    frame.intrinsics.width, frame.intrinsics.height, k.width, k.height
                ),
            });
        }
        frame.validate().map_err(|message| PipelineError::InvalidFrame { index: frame.index, message })?;
        // A stream that goes on after `finish`: the semantic map is live again.
        self.semantic_bytes_at_finish = None;
        self.map_memory_at_finish = None;
        self.frames += 1;
        if self.config.semantics.realtime {
            self.poll_semantics();
        }
        let t = Instant::now();
        // What the tracker measured of this frame (its conditioning and normal matrix), for
        // the odometry edges of loop closure.
        let mut tracking: Option<TrackingResult> = None;
        let (status, pose) = match self.config.poses {
            PoseMode::GroundTruth => match frame.world_from_camera {
                Some(p) => (if self.fused == 0 { FrameStatus::Initialized } else { FrameStatus::Fused }, Some(p)),
                None => (FrameStatus::NoPose, None),
            },
            PoseMode::Track => {
                let tracker = match &mut self.tracker {
                    Some(t) => t,
                    None => {
                        let start = self.config.initial_pose.or(frame.world_from_camera).unwrap_or(Affine3A::IDENTITY);
                        let config = TrackerConfig {
                            keyframe_interval: self.config.keyframe_every,
                            ..self.config.tracker.clone()
                        };
                        self.tracker.insert(Tracker::with_initial_pose(config, start)?)
                    }
                };
                let mut r = tracker.track(frame, &self.map)?;
                let mut relocalised = false;
                if matches!(r.status, TrackingStatus::Lost(reason) if reason != LostReason::NoDepth) {
                    // A small pose jump (within what the bound allowed before session 39) is
                    // an alignment that disagrees with the motion more than a camera that is
                    // lost: the next frame, predicted at rest under a wider bound, usually
                    // tracks, where a keyframe's pose is a coarser start (a generated loop,
                    // `synth-loop:3:noisy`, relocalised 10 cm off, six frames in a row, where
                    // tracking had it within 3 cm a frame later: ATE 88.5 mm against 143.3).
                    let small_jump = r.status == TrackingStatus::Lost(LostReason::PoseJump)
                        && r.departure_m <= TrackerConfig::WIDE_JUMP_FRAMES * tracker.config().max_translation_jump;
                    let wait = usize::from(small_jump);
                    let attempt =
                        self.lost_streak >= wait && (self.lost_streak - wait).is_multiple_of(RELOCALISATION_EVERY);
                    self.lost_streak += 1;
                    if attempt {
                        if let Some(recovered) =
                            tracker.relocalise(frame, &self.map, &self.keyframe_index, RELOCALISATION_ATTEMPTS)?
                        {
                            r = recovered;
                            relocalised = true;
                            self.relocalised += 1;
                        }
                    }
                }
                if r.keyframe {
                    self.keyframe_index.add(frame, r.world_from_camera);
                }
                self.colour_fallbacks += usize::from(r.colour_fallback);
                tracking = Some(r);
                match r.status {
                    TrackingStatus::Lost(reason) => (FrameStatus::Lost(reason), None),
                    TrackingStatus::Initialized => (FrameStatus::Initialized, Some(r.world_from_camera)),
                    TrackingStatus::Tracked => {
                        self.lost_streak = 0;
                        let status = if relocalised { FrameStatus::Relocalised } else { FrameStatus::Fused };
                        (status, Some(r.world_from_camera))
                    }
                }
            }
        };
        self.times.record("tracking", t.elapsed());
        let mut result =
            FrameResult { index: frame.index, status, pose: None, keyframe: false, semantic_pass: false, tracking };
        let Some(pose) = pose else {
            self.lost += 1;
            return Ok(result);
        };
        let t = Instant::now();
        match &mut self.loop_closure {
            // A re-integration in progress copies the chunks the frame changes, first, and
            // the frame is fused whole (the group was flushed when the re-integration began).
            Some(lc) if lc.is_rebuilding() => {
                lc.fuse_live(&mut self.map, frame, pose)?;
            }
            lc => {
                self.grouped.integrate(&mut self.map, frame, pose)?;
                if let Some(lc) = lc {
                    lc.count_live(self.grouped.last_selection());
                }
            }
        }
        self.times.record("fusion", t.elapsed());
        self.last_fused_index = frame.index;
        self.compact_map(frame.index);
        self.trajectory.push(frame.timestamp, pose);
        self.last_pose = Some(pose);
        self.fused += 1;
        result.pose = Some(pose);
        if let Some(s) = &mut self.semantics {
            s.stale = true;
        }
        let keyframe = self.fused.is_multiple_of(self.config.keyframe_every);
        let relocalised = result.status == FrameStatus::Relocalised;
        self.global_optimisation(
            frame,
            pose,
            keyframe,
            tracking.map(|r| (r.condition, r.camera_hessian)),
            relocalised,
        )?;
        if keyframe {
            result.keyframe = true;
            self.remesh();
            result.semantic_pass = self.keyframe_semantics(frame.index)?;
        }
        Ok(result)
    }

    /// Loop closure for a fused frame: stores it, and at keyframes looks for loops and
    /// applies a correction of the poses to the trajectory, the tracker and the map.
    fn global_optimisation(
        &mut self,
        frame: &Frame,
        pose: Affine3A,
        keyframe: bool,
        tracking: Option<(f64, [[f64; 6]; 6])>,
        relocalised: bool,
    ) -> Result<()> {
        let Some(lc) = &mut self.loop_closure else { return Ok(()) };
        // The front end's part ("loop closure"): the frame's copy in the store; at a keyframe
        // also the previous keyframe's search taken back from its thread (a wait only when
        // it still runs), the correction it found, and this keyframe's search handed over.
        // The search's own time is the back end's ("global pose optimisation").
        let t = Instant::now();
        lc.add_frame_tracked(frame, pose, keyframe, tracking, relocalised)?;
        if !keyframe {
            self.times.record("loop closure", t.elapsed());
            if lc.is_rebuilding() {
                // The re-integration in progress goes on at every frame; it swaps at keyframes.
                let t = Instant::now();
                lc.frame_follow(&mut self.map, frame.index)?;
                self.times.record("map re-integration", t.elapsed());
            }
            return Ok(());
        }
        let update = lc.close_loops(frame.index, &mut self.warnings);
        adopt_search(lc, update, &mut self.trajectory, &mut self.times, &mut self.warnings);
        self.times.record("loop closure", t.elapsed());
        let t = Instant::now();
        let rebuilding = lc.is_rebuilding();
        if lc.starts_following() && self.grouped.is_holding() {
            // A re-integration starts now: the map it copies and plans from holds every fused
            // frame, and frames fuse whole (through its shadow) until it swaps. Not before it
            // is due (a correction waiting for the end of the scan keeps the grouping).
            self.grouped.flush(&mut self.map)?;
        }
        let followed = lc.keyframe_follow(&mut self.map, frame.index)?;
        if rebuilding || lc.is_rebuilding() || followed.is_some() {
            // Per keyframe: the share of a re-integration it did (spread over keyframes).
            self.times.record("map re-integration", t.elapsed());
        }
        if let Some(followed) = followed {
            self.adopt_follow(followed);
        }
        Ok(())
    }

    /// Makes the map follow the corrected trajectory now (re-fusing where frames moved).
    fn follow_poses(&mut self, frame: usize) -> Result<()> {
        let Some(lc) = &mut self.loop_closure else { return Ok(()) };
        // The last keyframe's search first: its correction is part of what the map follows.
        let t = Instant::now();
        let update = lc.finish_search(frame, &mut self.warnings);
        adopt_search(lc, update, &mut self.trajectory, &mut self.times, &mut self.warnings);
        self.times.record("loop closure", t.elapsed());
        if !lc.is_behind() {
            return Ok(());
        }
        let t = Instant::now();
        let followed = lc.follow(&mut self.map, frame)?;
        // Apart from the keyframes' shares: what was still pending at the end of the scan.
        self.times.record("final map re-integration", t.elapsed());
        self.adopt_follow(followed);
        Ok(())
    }

    /// After the map followed a correction: the trajectory takes the estimates, and the
    /// tracker, which works in the map, moves with the last frame.
    fn adopt_follow(&mut self, (corrected_from_old, estimates): (Affine3A, Vec<Affine3A>)) {
        if estimates.len() == self.trajectory.poses.len() {
            self.trajectory.poses = estimates;
        }
        if let Some(tracker) = &mut self.tracker {
            tracker.correct(corrected_from_old);
        }
        if let Some(p) = self.last_pose.as_mut() {
            *p = corrected_from_old * *p;
        }
        if let Some(s) = &mut self.semantics {
            s.stale = true;
        }
    }

    /// Every few fused frames: packs the chunks fusion left alone and keeps the
    /// map within its memory budget; the map's warnings (budget raised, spill file failed)
    /// join the pipeline's, the latest of each kind kept.
    fn compact_map(&mut self, frame: usize) {
        let m = &self.config.memory;
        if m.cold_after_frames == 0 || !self.fused.is_multiple_of(m.compact_every) {
            return;
        }
        let t = Instant::now();
        let out = self.map.compact(frame.min(u32::MAX as usize) as u32, m.cold_after_frames);
        self.times.record("map compaction", t.elapsed());
        self.add_map_warnings(out.warnings);
    }

    /// Adds the map's warnings to the pipeline's; a budget raised again as the view grows
    /// stays one warning, with the latest figure.
    fn add_map_warnings(&mut self, warnings: Vec<String>) {
        const RAISED: &str = "map memory budget";
        for w in warnings {
            match self.warnings.iter_mut().find(|old| w.starts_with(RAISED) && old.starts_with(RAISED)) {
                Some(old) => *old = w,
                None => self.warnings.push(w),
            }
        }
    }

    fn remesh(&mut self) {
        let t = Instant::now();
        // After `finish` took the store: the whole map at once, not a budget's worth of it.
        let stats = if self.handed_over.take().is_some() {
            self.mesher.update_all(&self.map)
        } else {
            self.mesher.update(&self.map)
        };
        self.times.record("meshing", t.elapsed());
        let (n, sum, max) = self.pending_after_keyframes;
        self.pending_after_keyframes = (n + 1, sum + stats.pending_chunks, max.max(stats.pending_chunks));
        self.meshed_at = self.fused;
    }

    /// At a keyframe: collects the previous pass (waiting for it unless real-time) and starts
    /// a new one. Returns whether one was started.
    fn keyframe_semantics(&mut self, frame: usize) -> Result<bool> {
        let Some(s) = &mut self.semantics else { return Ok(false) };
        if s.in_flight.is_some() {
            if self.config.semantics.realtime {
                s.skipped += 1;
                return Ok(false);
            }
            let t = Instant::now();
            let r = s.backend.wait();
            self.times.record("semantic wait", t.elapsed());
            self.apply(r);
        }
        self.start_pass(frame)
    }

    /// Snapshots the changed surface and hands it to the back end; false when nothing changed.
    fn start_pass(&mut self, frame: usize) -> Result<bool> {
        let Some(s) = &mut self.semantics else { return Ok(false) };
        if !s.stale {
            return Ok(false);
        }
        let t = Instant::now();
        // Straight from the map's changed chunks: the mesh may lag them under a budget.
        let flush = std::mem::take(&mut s.flush);
        let changed = s.cells.update_with(&self.map, flush);
        s.stale = false;
        if changed.is_empty() || s.cells.is_empty() {
            return Ok(false);
        }
        let samples = s.cells.samples();
        let cameras: Vec<Vec3> = self.trajectory.poses.iter().map(|p| Vec3::from(p.translation)).collect();
        let up = match self.config.semantics.up {
            Some(u) => given_up(&samples, u, &cameras),
            None => {
                let prior = camera_up_prior(&self.trajectory.poses).unwrap_or(Vec3::Z);
                estimate_up(&samples, prior, &cameras)
            }
        };
        // Labels made in a frame tilted away from this one (an early estimate from a camera
        // pitched at the floor, before the planes were found) are the network's view of a
        // tilted room: this pass labels every cell in the new frame, and its result replaces
        // them all when it lands (until then the old labels stay on show).
        s.relabel_pending |= s.up.is_some_and(|u| u.up.dot(up.up) < RELABEL_ANGLE_DEG.to_radians().cos());
        let relabel = s.relabel_pending;
        s.up = Some(up);
        let tile_cells = ((self.config.semantics.tile_m / s.cells.cell_size()).round() as i32).max(1);
        let changed_cells = s.cells.take_changed_cells(self.config.semantics.min_cell_change);
        let cells = &s.cells;
        s.labels.retain(|k| cells.contains(k));
        let selected = match self.config.semantics.mode {
            SemanticMode::Incremental { context_m } if !relabel => {
                if changed_cells.is_empty() {
                    self.times.record("semantic snapshot", t.elapsed());
                    return Ok(false);
                }
                let tiles: BTreeSet<(i32, i32, i32)> = s.cells.tiles_of_cells(&changed_cells, tile_cells);
                let tile_m = tile_cells as f32 * s.cells.cell_size();
                s.cells.select(Some(&tiles), tile_cells, (context_m / tile_m).ceil() as i32)
            }
            SemanticMode::Full | SemanticMode::Incremental { .. } => s.cells.select(None, tile_cells, 0),
        };
        let job = Job {
            keys: selected.iter().map(|(c, _)| c.key).collect(),
            positions: selected.iter().map(|(c, _)| c.position).collect(),
            colors: selected.iter().map(|(c, _)| c.color).collect(),
            update: selected.iter().map(|(_, u)| *u).collect(),
            aligned_from_map: up.aligned_from_map(),
        };
        let record = SemanticPass {
            frame,
            map_cells: s.cells.len(),
            input_cells: job.keys.len(),
            updated_cells: job.update.iter().filter(|u| **u).count(),
            network_voxels: 0,
            snapshot_ms: t.elapsed().as_secs_f64() * 1e3,
            network_ms: 0.0,
            relabelled: relabel,
        };
        if let Err(e) = s.backend.submit(job) {
            // The back end is gone (its thread panicked): go on without semantics.
            self.warnings.push(format!("semantics stopped at frame {frame}: {e}"));
            self.semantics = None;
            return Ok(false);
        }
        s.in_flight = Some(record);
        self.times.record_ms("semantic snapshot", record.snapshot_ms);
        Ok(true)
    }

    /// Applies a finished pass (or records its failure).
    fn apply(&mut self, r: Result<JobResult>) {
        let Some(s) = &mut self.semantics else { return };
        let Some(mut record) = s.in_flight.take() else { return };
        match r {
            Ok(r) => {
                // A pass is started only when none is in flight, so nothing older than a
                // relabelling pass can land after it.
                if record.relabelled {
                    s.labels.retain(|_| false);
                    s.relabel_pending = false;
                }
                s.labels.accumulate(&r.keys, &r.probs, &r.colors);
                record.network_voxels = r.network_voxels;
                record.network_ms = r.total_ms;
                s.passes.push(record);
                self.times.record_ms("semantic", r.total_ms);
            }
            Err(e) => self.warnings.push(format!("semantic pass of frame {} failed: {e}", record.frame)),
        }
    }

    fn poll_semantics(&mut self) {
        let Some(s) = &self.semantics else { return };
        if s.in_flight.is_none() {
            return;
        }
        if let Some(r) = s.backend.poll() {
            self.apply(r);
        }
    }

    /// Ends the stream: waits for the pass in flight, runs a last pass over what changed
    /// since, brings the mesh up to date and returns the labelled mesh. The live mesh's
    /// memory goes into the returned mesh (a whole home's live mesh is half a gigabyte):
    /// [`Pipeline::mesh`] meshes the map afresh after this, until the next keyframe.
    ///
    /// # Errors
    /// None at present (failures of the back end are [`Pipeline::warnings`]); the `Result`
    /// leaves room for outputs that can fail.
    pub fn finish(&mut self) -> Result<LabeledMesh> {
        // Frames of an unfinished group: their far chunks, before the last mesh and labels.
        if self.grouped.is_holding() {
            let t = Instant::now();
            let flushed = self.grouped.flush(&mut self.map)?;
            self.times.record("fusion", t.elapsed());
            if flushed.updated_voxels > 0 {
                self.meshed_at = usize::MAX;
                if let Some(s) = &mut self.semantics {
                    s.stale = true;
                }
            }
        }
        if self.loop_closure.is_some() {
            self.follow_poses(self.frames.saturating_sub(1))?;
        }
        if self.meshed_at != self.fused || self.mesher.pending_chunks() > 0 {
            let t = Instant::now();
            self.mesher.update_all(&self.map);
            self.handed_over = None;
            // Apart from the keyframes' "meshing": a one-off catch-up without the budget. The
            // surface cells read the map, not the mesh, so this changes no label.
            self.times.record("final meshing", t.elapsed());
            self.meshed_at = self.fused;
        }
        if let Some(s) = &mut self.semantics {
            if s.cells.has_pending() {
                s.flush = true;
                s.stale = true;
            }
        }
        for _ in 0..2 {
            if let Some(s) = &self.semantics {
                if s.in_flight.is_some() {
                    let t = Instant::now();
                    let r = s.backend.wait();
                    self.times.record("semantic wait", t.elapsed());
                    self.apply(r);
                }
            }
            let frame = self.frames.saturating_sub(1);
            if !self.start_pass(frame)? {
                break;
            }
        }
        if self.config.memory.cold_after_frames > 0 {
            // The readers are done: the map goes back to its compact form (no unpacked
            // copies kept for readers that will not come, then a compaction at the last
            // frame, which then sees only what the map itself holds). Before the mesh is
            // assembled, which reads no voxel: the final meshing unpacked every chunk it
            // re-meshed, hundreds of megabytes that would otherwise sit beside the mesh.
            let t = Instant::now();
            let last = self.last_fused_index.min(u32::MAX as usize) as u32;
            self.map.release_caches();
            let mut out = self.map.compact(last, self.config.memory.cold_after_frames);
            // With a budget, the whole packed map goes to the spill file, not only what is
            // over the budget: nothing reads it while the mesh is assembled, whose peak would
            // otherwise hold the map and the whole mesh at once (a home: 0.65 + 0.9 GB). A
            // scan that goes on reads the chunks back as the camera meets them.
            self.map_memory_at_finish = Some(self.map.memory());
            let spilled = self.map.spill_packed();
            out.warnings.extend(spilled.warnings);
            if spilled.spilled > 0 {
                crate::freed_memory::return_to_os();
            }
            self.times.record("map compaction", t.elapsed());
            self.add_map_warnings(out.warnings);
        }
        // The labels are made: the cells' classes are settled (the vote's working memory,
        // a hundred megabytes for a whole home, is freed before the mesh is assembled, not
        // beside it), and the surface cells' sums (about as much) are not needed beside the
        // final mesh; a later keyframe reads them back from the map.
        if let Some(s) = &self.semantics {
            s.labels.settle();
        }
        self.semantic_bytes_at_finish = self.semantic_map_bytes();
        // The network's work buffers too (tens of megabytes after a whole home's passes).
        let released = self.semantics.as_mut().map(|s| {
            s.cells.release();
            s.backend.release_workspace()
        });
        if let Some(Err(e)) = released {
            self.warnings.push(format!("semantic back end: {e}"));
        }
        // The whole mesh takes the live mesh's memory: each chunk mesh is freed once copied,
        // and the freed pages go back to the system as they add up, so that a whole home's
        // peak holds one of the two (half a gigabyte packed, nearly one whole), not both.
        self.handed_over = Some(self.mesher.memory());
        let mesh = self.mesher.take_mesh(|_| crate::freed_memory::return_to_os());
        self.meshed_at = usize::MAX;
        Ok(self.labelled(mesh))
    }

    /// Loop closure's account: loops tried (accepted and rejected, with their frames and
    /// residuals) and corrections applied; `None` when it is off (ground-truth poses,
    /// [`crate::LoopClosureConfig::enabled`] false).
    pub fn loop_closure(&self) -> Option<LoopClosureReport> {
        self.loop_closure.as_ref().map(LoopClosure::report)
    }

    /// Poses of the fused frames as tracked, before any loop-closure correction (`None`
    /// when loop closure is off: then [`Pipeline::trajectory`] is that).
    pub fn tracked_trajectory(&self) -> Option<&Trajectory> {
        self.loop_closure.as_ref().map(LoopClosure::tracked)
    }

    /// The pose of the last fused frame (`None` before the first).
    pub fn pose(&self) -> Option<Affine3A> {
        self.last_pose
    }

    /// Poses of the fused frames.
    pub fn trajectory(&self) -> &Trajectory {
        &self.trajectory
    }

    /// The mesh as of the last keyframe, with per-vertex classes ([`UNLABELED`] where no pass
    /// reached yet) and observed colours. Each vertex takes the class of its 5 cm cell, else of
    /// the neighbouring cell with the most evidence: under a mesh budget a vertex may stand where
    /// the surface was keyframes ago, while the cells follow the map.
    ///
    /// After [`Pipeline::finish`], which hands the live mesh's memory over to the mesh it
    /// returns, the map is meshed afresh (until the next keyframe refills the live mesh).
    pub fn mesh(&self) -> LabeledMesh {
        let mesh = if self.handed_over.is_some() {
            let mut afresh = self.mesher.clone();
            afresh.update_all(&self.map);
            afresh.mesh()
        } else {
            self.mesher.mesh()
        };
        self.labelled(mesh)
    }

    /// `mesh` with the class of each vertex (see [`Pipeline::mesh`]).
    fn labelled(&self, mut mesh: LabeledMesh) -> LabeledMesh {
        mesh.vertex_labels = match &self.semantics {
            Some(s) => mesh.positions.iter().map(|p| s.labels.label_near(s.cells.cell_of_point(*p))).collect(),
            None => vec![UNLABELED; mesh.positions.len()],
        };
        mesh
    }

    /// The class at map point `p` (the class of its 5 cm cell), `None` when unlabelled.
    pub fn label_at(&self, p: Vec3) -> Option<SemanticClass> {
        let s = self.semantics.as_ref()?;
        SemanticClass::from_id(s.labels.label(s.cells.cell_of_point(p)))
    }

    /// Per-stage timings: `tracking` and `fusion` per frame, `meshing` and `semantic snapshot`
    /// per keyframe (front end), `semantic` per pass (back end), `semantic wait` where the
    /// front end waited for the back end.
    pub fn timings(&self) -> &StageTimes {
        &self.times
    }

    /// Seconds the front end spent in [`FRONT_END_STAGES`] (what a real-time factor divides):
    /// its own work and, without `realtime`, its waits for a semantic pass still running at
    /// the next keyframe, so that the factor also says whether semantics keep up.
    pub fn front_end_seconds(&self) -> f64 {
        FRONT_END_STAGES.iter().filter_map(|s| self.times.summary(s)).map(|s| s.total_ms).sum::<f64>() / 1e3
    }

    /// The TSDF map.
    pub fn map(&self) -> &TsdfMap {
        &self.map
    }

    /// Heap bytes of the live mesh's chunk store (beside the map's [`TsdfMap::memory`]).
    /// After [`Pipeline::finish`]: as it was when the final mesh took it over.
    pub fn mesh_store_memory(&self) -> MeshStoreMemory {
        self.handed_over.unwrap_or_else(|| self.mesher.memory())
    }

    /// Where the map's bytes are ([`TsdfMap::memory`]). After [`Pipeline::finish`]: as they
    /// were at the end of the scan, before a memory budget sent the whole packed map to the
    /// spill file for the final mesh's assembly ([`TsdfMap::spill_packed`]; the map itself
    /// then says what is in memory now).
    pub fn map_memory(&self) -> MapMemory {
        self.map_memory_at_finish.unwrap_or_else(|| self.map.memory())
    }

    /// Heap bytes of the semantic map beside the TSDF map: the surface cells with their
    /// per-chunk sums and the labels' evidence (`None` with semantics off). The network's
    /// weights and work buffers are not counted.
    ///
    /// After [`Pipeline::finish`], which releases the surface cells: as they were then.
    pub fn semantic_map_bytes(&self) -> Option<usize> {
        self.semantic_bytes_at_finish
            .or_else(|| self.semantics.as_ref().map(|s| s.cells.heap_bytes() + s.labels.heap_bytes()))
    }

    /// How far the live mesh lagged under [`crate::PipelineConfig::mesh_budget`]: the chunks
    /// left waiting after each keyframe's meshing, as (mean, largest); `None` before the first
    /// keyframe. Always (0, 0) without a budget.
    pub fn mesh_lag(&self) -> Option<(f64, usize)> {
        let (n, sum, max) = self.pending_after_keyframes;
        (n > 0).then(|| (sum as f64 / n as f64, max))
    }

    /// Frames pushed (valid ones), fused, and not fused (lost or without pose).
    pub fn frame_counts(&self) -> (usize, usize, usize) {
        (self.frames, self.fused, self.lost)
    }

    /// Frames whose pose relocalisation recovered after tracking failed (they are fused and
    /// counted in [`Pipeline::frame_counts`]'s fused frames).
    pub fn relocalised_frames(&self) -> usize {
        self.relocalised
    }

    /// Frames the tracker aligned a second time with its colour term because depth alone
    /// left the alignment poorly conditioned (a bare wall, a door, a corridor:
    /// `TrackerConfig::degenerate_photometric_weight`), tracked or not.
    pub fn colour_fallback_frames(&self) -> usize {
        self.colour_fallbacks
    }

    /// Semantic passes applied so far, in order.
    pub fn semantic_passes(&self) -> &[SemanticPass] {
        self.semantics.as_ref().map_or(&[], |s| s.passes.as_slice())
    }

    /// Semantic passes that labelled every cell again because the up direction moved
    /// (see [`SemanticPass::relabelled`]).
    pub fn relabelled_passes(&self) -> usize {
        self.semantic_passes().iter().filter(|p| p.relabelled).count()
    }

    /// Keyframes skipped because the back end was busy (real-time mode).
    pub fn skipped_keyframes(&self) -> usize {
        self.semantics.as_ref().map_or(0, |s| s.skipped)
    }

    /// The up direction and floor used by the last pass.
    pub fn up(&self) -> Option<UpEstimate> {
        self.semantics.as_ref().and_then(|s| s.up)
    }

    /// Labelled 5 cm cells and their classes, in (z, y, x) order.
    pub fn cell_labels(&self) -> Vec<(glam::IVec3, u8)> {
        self.semantics.as_ref().map_or_else(Vec::new, |s| s.labels.labels())
    }

    /// Whether a network labels the map.
    pub fn has_semantics(&self) -> bool {
        self.semantics.is_some()
    }

    /// Problems that did not stop the pipeline (failed semantic passes).
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// The configuration.
    pub fn config(&self) -> &PipelineConfig {
        &self.config
    }
}

/// Cells of side `cell_m` in `area_m2` (rounded to nearest; 0 for no area).
fn island_cells(area_m2: f32, cell_m: f32) -> usize {
    (area_m2 / (cell_m * cell_m)).round() as usize
}
