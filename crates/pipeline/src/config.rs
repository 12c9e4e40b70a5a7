//! Configuration of the live pipeline: the map, tracking, keyframes, and how semantics run.

use std::num::NonZeroUsize;
use std::path::PathBuf;

use glam::{Affine3A, Vec3};
use semrecon_recon::{MeshConfig, TrackerConfig, TsdfConfig};

use crate::error::{PipelineError, Result};
use crate::loop_closure::LoopClosureConfig;

/// A [`PipelineConfig::mesh_budget`] in chunks, what `semrecon run` uses with and without
/// semantics: 16-20 ms of meshing a keyframe on two cores at 5 mm on 7-Scenes, where a changed
/// chunk then waits about six keyframes (at most 12) for its refresh (docs/benchmarks_log.md,
/// "Meshing within a budget, session 10"). The semantic passes read the map's surface from the
/// TSDF chunks ([`crate::surface_cells`]), so the budget costs no labels ("Labels that do not
/// wait for the mesh").
pub const DEFAULT_MESH_BUDGET: usize = 3072;

/// Where the pose of each frame comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PoseMode {
    /// Frame-to-model ICP tracking (the live system).
    #[default]
    Track,
    /// The frames' ground-truth poses (to judge fusion and semantics alone).
    GroundTruth,
}

/// Which part of the map the network sees at a keyframe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SemanticMode {
    /// The whole map, every time (the paper's way; cost grows with the map).
    Full,
    /// Only the tiles changed since the last pass, with `context_m` metres of unchanged map
    /// around them as context; labels elsewhere are kept. The network's own receptive field
    /// (five levels, 3x3x3 convolutions at 80 cm voxels on the coarsest) spans several metres,
    /// so a bounded context changes labels a little (measured in the crate's tests and
    /// docs/benchmarks.md), in exchange for a cost that follows the camera, not the map.
    Incremental {
        /// Context around the changed tiles, metres (1 m by default).
        context_m: f32,
    },
}

impl Default for SemanticMode {
    fn default() -> Self {
        Self::Incremental { context_m: 1.0 }
    }
}

/// How semantics run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SemanticConfig {
    /// Full or incremental passes.
    pub mode: SemanticMode,
    /// Side of the tiles that changes are tracked in, metres (a multiple of the network's voxel
    /// is used: 0.5 m at 5 cm voxels).
    pub tile_m: f32,
    /// Incremental passes re-label a tile when one of its cells is new, lost its surface, or
    /// its number of surface points moved by more than this fraction since it was last
    /// labelled (0.25: re-observing a surface leaves its cells alone, filling a hole does not).
    pub min_cell_change: f32,
    /// Real-time mode: the front end never waits for the back end; a keyframe that finds the
    /// back end busy is skipped, and results are applied as they arrive. Off (the default), the
    /// front end waits at each keyframe for the previous keyframe's labels, so results do not
    /// depend on timing.
    pub realtime: bool,
    /// Up direction in the map frame when known (gravity sensor, a dataset's gravity file);
    /// estimated from the map otherwise.
    pub up: Option<Vec3>,
    /// Connected pieces of one class smaller than this, square metres of cells (0.06: about
    /// 25 cm square, 24 cells of 5 cm), take the class of the cells around them: specks of
    /// a class at boundaries and in clutter (see [`crate::label_islands`]). 0 keeps them.
    pub min_island_m2: f32,
    /// Whether the map's classes are voted over geometric segments of the labelled cells
    /// (normals and colour; [`crate::label_store`]), as `semrecon segment` does offline: a
    /// class that bleeds from an object onto the even surface beside it (a window's onto its
    /// wall) goes back to the surface's own. On by default: demo seeds 1-20 74.1 -> 77.7 %
    /// mean mIoU, pooled 84.2 -> 86.3 % (docs/model.md, "A segment vote in the live map").
    pub segment_vote: bool,
    /// A changed chunk whose surface the cells already hold is re-read at one keyframe in
    /// this many, staggered by chunk ([`crate::semantic_map::SurfaceCells::with_refresh_every`]);
    /// new surface is read at once, and the scan's last pass reads everything. 1: every
    /// changed chunk at every keyframe. Default 3: the demo's snapshot 45 -> 28 ms a keyframe
    /// and its front end 8.1 -> 7.7 s, 7-Scenes' snapshot 28 -> 17 ms, labels no worse (demo
    /// seeds 1-10: 73.5 -> 74.4 % mIoU; docs/benchmarks_log.md, "Staggered surface re-reads").
    pub surface_refresh_keyframes: u32,
}

impl Default for SemanticConfig {
    fn default() -> Self {
        Self {
            mode: SemanticMode::default(),
            tile_m: 0.5,
            min_cell_change: 0.25,
            realtime: false,
            up: None,
            min_island_m2: 0.06,
            segment_vote: true,
            surface_refresh_keyframes: 3,
        }
    }
}

/// How the map keeps its memory down ([`semrecon_recon::TsdfMap::compact`]): chunks that no
/// frame changed for a while are packed in memory, and past a budget the coldest are spilled
/// to a file. Packing keeps every voxel but the distances far from the surface exactly
/// ([`semrecon_recon::TsdfConfig::packed_far_step_voxels`]; 0 there: the output is the same
/// bits with any of these settings); spilling adds nothing to packing.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MapMemoryConfig {
    /// Chunks no fused frame changed for this many frames are packed (0: never pack). A
    /// second at 30 Hz: the chunks in view stay plain, so fusion does not unpack them again.
    pub cold_after_frames: u32,
    /// Compaction runs every this many fused frames (at least 1).
    pub compact_every: usize,
    /// Bytes the map may hold in memory; past it the coldest packed chunks go to the spill
    /// file (`None`: no budget, nothing spilled).
    pub budget_bytes: Option<usize>,
    /// The spill file (created new, deleted at the end); `None` puts it in the system's
    /// temporary folder.
    pub spill_path: Option<PathBuf>,
}

impl Default for MapMemoryConfig {
    fn default() -> Self {
        Self { cold_after_frames: 30, compact_every: 10, budget_bytes: None, spill_path: None }
    }
}

/// Everything [`crate::Pipeline::new`] needs besides the camera and the network.
#[derive(Debug, Clone, PartialEq)]
pub struct PipelineConfig {
    /// The TSDF map.
    pub tsdf: TsdfConfig,
    /// Meshing ([`MeshConfig::RECOMMENDED`] by default: voxels seen too little stay holes and
    /// specks of noise are dropped).
    pub mesh: MeshConfig,
    /// Most chunks a keyframe re-meshes ([`IncrementalMesher::with_budget`]: newly seen
    /// surface first, then the chunks due the longest); `None`, the default, re-meshes every
    /// changed chunk at every keyframe (see [`DEFAULT_MESH_BUDGET`]). Labels do not depend on
    /// it: the semantic passes read the map, not the mesh.
    /// [`crate::Pipeline::finish`] brings every chunk up to date either way.
    ///
    /// [`IncrementalMesher::with_budget`]: semrecon_recon::IncrementalMesher::with_budget
    pub mesh_budget: Option<NonZeroUsize>,
    /// The tracker (its keyframe interval is overridden by `keyframe_every`).
    pub tracker: TrackerConfig,
    /// Where poses come from.
    pub poses: PoseMode,
    /// The first frame's pose when tracking: `None` starts at the first frame's ground-truth
    /// pose when it has one (so that trajectories compare without alignment), else at the
    /// identity (the map frame is then the first camera's).
    pub initial_pose: Option<Affine3A>,
    /// A keyframe every this many fused frames: the mesh is brought up to date and a semantic
    /// pass is started.
    pub keyframe_every: usize,
    /// Semantics.
    pub semantics: SemanticConfig,
    /// Loop closure and global pose optimisation (tracking only: ground-truth poses need
    /// none).
    pub loop_closure: LoopClosureConfig,
    /// Packing cold chunks and the memory budget.
    pub memory: MapMemoryConfig,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self {
            tsdf: TsdfConfig { truncation_voxels: 10.0, ..TsdfConfig::default() },
            mesh: MeshConfig::RECOMMENDED,
            mesh_budget: None,
            tracker: TrackerConfig::default(),
            poses: PoseMode::Track,
            initial_pose: None,
            keyframe_every: 10,
            semantics: SemanticConfig::default(),
            loop_closure: LoopClosureConfig::default(),
            memory: MapMemoryConfig::default(),
        }
    }
}

impl PipelineConfig {
    /// Checks the ranges of every field.
    ///
    /// # Errors
    /// [`PipelineError::InvalidConfig`] naming the field, or the map's and tracker's own
    /// checks.
    pub fn validate(&self) -> Result<()> {
        self.tsdf.validate()?;
        self.mesh.validate()?;
        self.tracker.validate()?;
        self.loop_closure.validate()?;
        let bad = |m: String| Err(PipelineError::InvalidConfig(m));
        if self.keyframe_every == 0 {
            return bad("keyframe_every must be at least 1".into());
        }
        if self.memory.compact_every == 0 {
            return bad("memory.compact_every must be at least 1".into());
        }
        // A re-integration copies chunks into a shadow map that has no spill file, so it
        // cannot read a spilled chunk back: refused until the shadow can.
        if self.loop_closure.enabled && self.memory.budget_bytes.is_some() {
            return bad("loop closure with a memory budget is not supported yet (re-integration cannot read spilled chunks): drop --max-memory or --loop-closure".into());
        }
        let s = &self.semantics;
        if !(s.tile_m.is_finite() && (0.05..=10.0).contains(&s.tile_m)) {
            return bad(format!("semantic tile {} m is outside 0.05..10 m", s.tile_m));
        }
        if !(s.min_island_m2.is_finite() && (0.0..=100.0).contains(&s.min_island_m2)) {
            return bad(format!("smallest label island {} m^2 is outside 0..100 m^2", s.min_island_m2));
        }
        if !(s.min_cell_change.is_finite() && (0.0..=10.0).contains(&s.min_cell_change)) {
            return bad(format!("minimum cell change {} is outside 0..10", s.min_cell_change));
        }
        if let SemanticMode::Incremental { context_m } = s.mode {
            if !(context_m.is_finite() && (0.0..=100.0).contains(&context_m)) {
                return bad(format!("semantic context {context_m} m is outside 0..100 m"));
            }
        }
        if s.up.is_some_and(|u| !u.is_finite() || u.length() < 1e-6) {
            return bad("the given up direction is zero or not finite".into());
        }
        if self.initial_pose.is_some_and(|p| !p.is_finite()) {
            return bad("the initial pose is not finite".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod budget_tests {
    use super::*;

    /// Loop closure and a memory budget together are refused with a message, not run.
    #[test]
    fn loop_closure_with_a_memory_budget_is_refused() {
        let mut config = PipelineConfig::default();
        config.loop_closure.enabled = true;
        assert!(config.validate().is_ok());
        config.memory.budget_bytes = Some(1 << 30);
        let e = config.validate().expect_err("refused").to_string();
        assert!(e.contains("memory budget"), "{e}");
    }
}
