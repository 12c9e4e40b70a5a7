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
use semrecon_recon::{IncrementalMesher, TsdfConfig, TsdfMap};

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
    /// An empty map at `voxel` metres, re-meshed every `keyframe_every` fused frames.
    pub fn new(voxel: f32, keyframe_every: usize) -> anyhow::Result<Self> {
        anyhow::ensure!(
            keyframe_every > 0,
            "the keyframe interval must be at least 1 frame"
        );
        let config =
            TsdfConfig::with_voxel_size(voxel).with_context(|| format!("voxel size {voxel} m"))?;
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
    pub fn add_frame(
        &mut self,
        frame: &Frame,
        world_from_camera: Affine3A,
    ) -> semrecon_recon::Result<()> {
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
