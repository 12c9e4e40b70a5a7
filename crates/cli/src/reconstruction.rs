//! The dense-geometry loop shared by `semrecon demo` and `semrecon run`: frames fused into a
//! TSDF map at their poses, the mesh brought up to date every keyframe, per-stage timings
//! kept, and the outputs (mesh, trajectory) written at the end.
//!
//! The pipeline time (what the real-time factor divides by) counts only the stages a live
//! system runs per frame (tracking, fusion, meshing); producing the input (decoding files,
//! simulating the sensor) is timed as its own stage but left out, as a camera delivers it.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::Context;
use glam::Affine3A;
use semrecon_data::{write_ply, Frame, LabeledMesh, PlyEncoding, Trajectory};
use semrecon_recon::{IncrementalMesher, Tracker, TrackerConfig, TrackingStatus, TsdfConfig, TsdfMap};

use crate::timing::StageTimes;

/// Map, mesher, trajectory and timings of one reconstruction.
pub struct Reconstruction {
    /// The TSDF map.
    pub map: TsdfMap,
    /// The incremental mesher (only dirty chunks are re-meshed).
    pub mesher: IncrementalMesher,
    /// Per-stage timings.
    pub times: StageTimes,
    /// The pose of every fused frame.
    pub trajectory: Trajectory,
    /// Seconds spent in pipeline stages (see the module documentation).
    pub pipeline_s: f64,
    keyframe_every: usize,
    fused: usize,
    meshed_at: usize,
}

impl Reconstruction {
    /// An empty map at `voxel` metres with a truncation of `truncation_voxels`, re-meshed
    /// every `keyframe_every` fused frames.
    pub fn new(voxel: f32, truncation_voxels: f32, keyframe_every: usize) -> anyhow::Result<Self> {
        anyhow::ensure!(keyframe_every > 0, "the keyframe interval must be at least 1 frame");
        let mut config = TsdfConfig::with_voxel_size(voxel).with_context(|| format!("voxel size {voxel} m"))?;
        config.truncation_voxels = truncation_voxels;
        config.validate().with_context(|| format!("truncation of {truncation_voxels} voxels"))?;
        Ok(Self {
            map: TsdfMap::new(config)?,
            mesher: IncrementalMesher::new(),
            times: StageTimes::default(),
            trajectory: Trajectory::default(),
            pipeline_s: 0.0,
            keyframe_every,
            fused: 0,
            meshed_at: 0,
        })
    }

    /// Records a pipeline stage's time (counted in [`Reconstruction::pipeline_s`]).
    pub fn record_pipeline(&mut self, stage: &str, elapsed: Duration) {
        self.times.record(stage, elapsed);
        self.pipeline_s += elapsed.as_secs_f64();
    }

    /// Fuses `frame` at `world_from_camera`, records the pose, and re-meshes when this frame
    /// completes a keyframe interval. On a fusion error the map is unchanged and nothing is
    /// recorded.
    pub fn add_frame(&mut self, frame: &Frame, world_from_camera: Affine3A) -> semrecon_recon::Result<()> {
        let t = Instant::now();
        self.map.integrate(frame, world_from_camera)?;
        self.record_pipeline("fusion", t.elapsed());
        self.trajectory.push(frame.timestamp, world_from_camera);
        self.fused += 1;
        if self.fused.is_multiple_of(self.keyframe_every) {
            self.remesh();
        }
        Ok(())
    }

    /// Frames fused so far.
    pub fn fused_frames(&self) -> usize {
        self.fused
    }

    /// Brings the mesh up to date (if anything was fused since the last keyframe) and
    /// returns it.
    pub fn finish(&mut self) -> LabeledMesh {
        if self.meshed_at != self.fused {
            self.remesh();
        }
        self.mesher.mesh()
    }

    fn remesh(&mut self) {
        let t = Instant::now();
        self.mesher.update(&self.map);
        self.record_pipeline("meshing", t.elapsed());
        self.meshed_at = self.fused;
    }

    /// Writes `dir/mesh.ply` (binary) and `dir/trajectory.txt` (TUM), creating `dir`.
    pub fn write_outputs(&self, dir: &Path, mesh: &LabeledMesh) -> anyhow::Result<()> {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        write_ply(dir.join("mesh.ply"), mesh, PlyEncoding::BinaryLittleEndian)?;
        self.trajectory.write_tum(dir.join("trajectory.txt"))?;
        Ok(())
    }
}

/// Options of the dense-geometry loop, shared by `run` and `demo`.
#[derive(clap::Args)]
pub struct ReconArgs {
    /// TSDF voxel size in metres.
    #[arg(long, default_value_t = 0.005)]
    pub voxel: f32,
    /// Re-mesh every this many fused frames (a keyframe).
    #[arg(long, default_value_t = 10)]
    pub keyframe_every: usize,
    /// TSDF truncation in voxels (about 10 suits noisy depth sensors at 5 mm voxels).
    #[arg(long, default_value_t = 10.0)]
    pub truncation: f32,
    /// Where poses come from: tracking, or the dataset's ground truth.
    #[arg(long, value_enum, default_value_t = PoseMode::Track)]
    pub poses: PoseMode,
}

/// Where the pose of each frame comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum PoseMode {
    /// Frame-to-model ICP tracking (the live system).
    Track,
    /// The dataset's ground-truth poses (to judge fusion and meshing alone).
    GroundTruth,
}

/// The per-frame pose estimator of `run` and `demo`.
pub enum PoseSource {
    /// Tracking against the map.
    Track(Box<Tracker>),
    /// Ground-truth poses from the frames.
    GroundTruth,
}

impl PoseSource {
    /// A source for `mode`; the tracker starts at `initial_pose` (the first frame's
    /// ground truth when there is one, so that trajectories compare without alignment;
    /// the identity otherwise).
    pub fn new(mode: PoseMode, initial_pose: Option<Affine3A>, keyframe_every: usize) -> anyhow::Result<Self> {
        Ok(match mode {
            PoseMode::GroundTruth => Self::GroundTruth,
            PoseMode::Track => {
                let config = TrackerConfig { keyframe_interval: keyframe_every, ..TrackerConfig::default() };
                Self::Track(Box::new(Tracker::with_initial_pose(config, initial_pose.unwrap_or(Affine3A::IDENTITY))?))
            }
        })
    }

    /// What the report says the poses come from.
    pub fn describe(&self) -> &'static str {
        match self {
            Self::Track(_) => "tracking (frame-to-model ICP)",
            Self::GroundTruth => "ground truth",
        }
    }

    /// The pose to fuse `frame` at, or why there is none (tracking lost, no ground truth).
    pub fn estimate(&mut self, frame: &Frame, map: &TsdfMap) -> Result<Affine3A, String> {
        match self {
            Self::GroundTruth => frame.world_from_camera.ok_or_else(|| "no ground-truth pose".to_string()),
            Self::Track(tracker) => {
                let result = tracker.track(frame, map).map_err(|e| e.to_string())?;
                match result.status {
                    TrackingStatus::Lost(reason) => Err(format!("tracking lost ({reason:?})")),
                    _ if result.should_fuse() => Ok(result.world_from_camera),
                    other => Err(format!("not fused ({other:?})")),
                }
            }
        }
    }
}
