//! What `semrecon demo` and `semrecon run` share around the live [`Pipeline`]: their options
//! (map, poses, semantics, network), loading the network, the outputs (`mesh.ply` with a
//! `label` property, `semantic.ply` in class colours, `trajectory.txt`) and the semantic score
//! against a labelled ground truth.
//!
//! The pipeline time (what the real-time factor divides by) counts the front end's stages
//! (tracking, fusion, meshing, the semantic snapshot) and its waits for a semantic pass still
//! running at the next keyframe; the network runs in the back end thread beside it and is
//! reported on its own line. Producing the input (decoding files,
//! simulating the sensor) is timed but left out, as a camera delivers it.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use glam::Vec3;
use rayon::prelude::*;
use semrecon_data::class::UNLABELED;
use semrecon_data::{write_ply_recoloured, LabeledMesh, MeshGravity, PlyEncoding, SemanticClass, Trajectory};
use semrecon_eval::{evaluate_trajectory, TrajectoryEvalConfig};
use semrecon_eval::{MeshEvalConfig, SurfaceIndex, SurfaceLabeler};
use semrecon_net::{shipped, ConfusionMatrix, NetConfig, Segmenter, Weights};
use semrecon_pipeline::{LoopClosureConfig, Pipeline, PipelineConfig, SemanticMode, UpEstimate, DEFAULT_MESH_BUDGET};
use semrecon_recon::{MeshConfig, TrackerConfig, TsdfConfig};

use crate::live_view::LiveView;

/// Options of the dense-geometry loop, shared by `run` and `demo`.
#[derive(clap::Args)]
pub struct ReconArgs {
    /// TSDF voxel size in metres.
    #[arg(long, default_value_t = 0.005)]
    pub voxel: f32,
    /// Re-mesh and start a semantic pass every this many fused frames (a keyframe).
    #[arg(long, default_value_t = 10)]
    pub keyframe_every: usize,
    /// TSDF truncation in voxels, the band far away (about 10 suits noisy depth sensors at 5 mm
    /// voxels); nearer surfaces get a narrower band that follows the sensor noise, down to 4.
    #[arg(long, default_value_t = 10.0)]
    pub truncation: f32,
    /// Farthest depth fused into the map, metres: beyond it a pixel only helps tracking.
    /// Fusion's work grows with the square of the range (the surface a frame sees), while a
    /// Kinect-like sensor's noise at 4-5 m is 3-4 cm.
    #[arg(long, default_value_t = TsdfConfig::default().max_depth)]
    pub max_depth: f32,
    /// Smallest fusion weight of a voxel that meshing counts as observed (one observation at
    /// depth d weighs 1/d^2, at most 4): lighter voxels, seen once or twice from far away or
    /// grazed at depth edges, stay holes instead of surfaces centimetres off; 0 meshes every
    /// observed voxel.
    #[arg(long, default_value_t = MeshConfig::RECOMMENDED.min_weight)]
    pub min_mesh_weight: f32,
    /// Connected pieces of the output mesh with fewer triangles than this are dropped (specks
    /// of noise floating in free space); 0 keeps everything.
    #[arg(long, default_value_t = MeshConfig::RECOMMENDED.min_component_triangles)]
    pub min_mesh_piece: usize,
    /// Most 8x8x8-voxel chunks a keyframe re-meshes: newly seen surface first, then the chunks
    /// waiting longest, the rest at later keyframes (the written mesh is always complete); 0
    /// re-meshes every changed chunk at every keyframe. Default: 3072 (16-20 ms at 5 mm on two
    /// cores); labels do not depend on it (the network reads the map, not the mesh).
    #[arg(long)]
    pub mesh_budget: Option<usize>,
    /// Weight of the tracker's photometric term (colour intensity 0..1 against metres of
    /// point-to-plane distance); 0 tracks on depth alone. Only for colour registered to depth
    /// (synthetic scans, Replica), not 7-Scenes.
    #[arg(long, default_value_t = 0.0)]
    pub photometric_weight: f32,
    /// Weight of the photometric term for frames whose depth alone leaves the alignment
    /// poorly conditioned (a bare wall, a door, a corridor): only those frames are aligned
    /// again with colour, so they alone pay for it; 0 tracks on depth alone. Default: 0.1
    /// where colour is registered to depth (generated scans, Replica, TUM, ScanNet, live
    /// cameras), 0 for 7-Scenes, whose colour is not (docs/benchmarks_log.md, "Session 34").
    #[arg(long)]
    pub degenerate_photometric_weight: Option<f32>,
    /// Smallest fraction of the surface in view that must lean (by 17 degrees) towards a
    /// direction of translation for depth to hold the camera along it. Views below it (a wall
    /// and a door with no floor, ceiling or shelf in sight leave the height unheld) are
    /// aligned again with colour, or, without colour, keep the camera where it was along that
    /// direction; 0 turns the check off (docs/benchmarks_log.md, "Session 42").
    #[arg(long, default_value_t = 0.02)]
    pub min_support: f32,
    /// Where poses come from: tracking, or the dataset's ground truth.
    #[arg(long, value_enum, default_value_t = PoseMode::Track)]
    pub poses: PoseMode,
    /// Close loops: find revisited places at keyframes, optimise the pose graph and re-fuse
    /// the map's chunks that a correction moves by more than half a voxel. On by default in
    /// `run`; `demo` and `live` close loops only with this flag (a correction's re-fusion
    /// costs much of the real-time factor when the map follows it live, docs/loop_closure.md).
    #[arg(long, conflicts_with = "no_loop_closure")]
    pub loop_closure: bool,
    /// No loop closure: the trajectory as tracked and the map as fused (`run` closes loops by
    /// default; this is the comparison).
    #[arg(long)]
    pub no_loop_closure: bool,
    /// With loop closure: when the map follows the corrected poses. `live`: during the scan
    /// (the corrected chunks re-fused in a shadow, a bounded amount a keyframe, swapped in
    /// when complete), for a live view and AR on the corrected map; `end`: once, when the scan
    /// ends (the trajectory is corrected at once either way), for the least work. Default:
    /// `end` in `run` (7-Scenes with semantics: RTF 1.59 against 1.13 with `live`, 2.0 without
    /// loop closure), `live` in `demo` and `live`.
    #[arg(long, value_enum, conflicts_with = "no_loop_closure")]
    pub map_follows: Option<MapFollows>,
    /// Fusion clamps a depth measured up to this many bands behind a voxel to one band behind
    /// (1, the default: such depths are skipped). 1.5 treats the sensor's noise alike on both
    /// sides of the surface: 7-14 % better mesh accuracy on rendered scans, but a scan facing
    /// a bare wall may drift (docs/fusion.md, "Both sides of the band").
    #[arg(long, default_value_t = 1.0)]
    pub behind_band: f32,
    /// Chunks more than this many metres from the camera (along its axis) are fused once per
    /// group of `--far-group-frames` consecutive frames, from the frames' depths averaged
    /// pixel by pixel: the same noise averaging for a fraction of the work. 0: every frame
    /// whole. With `--loop-closure`, frames fuse whole while a re-integration runs (docs/fusion.md, "Far surfaces from groups of frames").
    #[arg(long, default_value_t = TsdfConfig::default().far_group_beyond_m)]
    pub far_group_beyond: f32,
    /// Frames in a group of `--far-group-beyond` (2 to 8; 4 since session 33, 3 before: 3-4 %
    /// faster on the demo at the same accuracy, 0.1-0.35 points of completeness).
    #[arg(long, default_value_t = TsdfConfig::default().far_group_frames)]
    pub far_group_frames: usize,
    /// With loop closure: re-fuse runs of up to this many consecutive stored frames as one,
    /// their depths averaged onto the run's middle frame and weighing as much as the run
    /// (4 by default; 1: every frame, exact). Cuts a re-integration's work 2-3 times at the
    /// same or better mesh accuracy, for 2-3 % of completeness (docs/loop_closure.md).
    #[arg(long, conflicts_with = "no_loop_closure")]
    pub reintegration_stride: Option<usize>,
    /// With loop closure: weigh loop edges by the shape of the loop alignment's Hessian
    /// (J^T J of the point-to-plane ICP) instead of one isotropic standard deviation (4 mm,
    /// 0.17 degree). Off by default: it closed less drift on rendered loops
    /// (docs/loop_closure.md).
    #[arg(long, conflicts_with = "no_loop_closure")]
    pub loop_information_from_alignment: bool,
    /// With loop closure: odometry edges take their information's shape from the tracking
    /// between their keyframes (the worst-conditioned frame's normal matrix), so that a stretch
    /// where depth barely constrained some motion takes more of a loop's correction.
    #[arg(long, conflicts_with = "no_loop_closure")]
    pub odometry_information_from_tracking: bool,
    /// With loop closure: a loop edge's standard deviations grow in proportion to its
    /// alignment's RMS residual past this many millimetres (default 3; 0: the same for every
    /// loop).
    #[arg(long, conflicts_with = "no_loop_closure")]
    pub loop_residual_reference_mm: Option<f64>,
    /// With loop closure: the map follows a correction only in chunks that a frame's pose
    /// change moves by more than this many voxels (default 0.5).
    #[arg(long, conflicts_with = "no_loop_closure")]
    pub min_chunk_move_voxels: Option<f32>,
    /// With loop closure: memory for the frames it keeps to re-fuse the map, e.g. 8G (default
    /// 2G: 1,365 frames at 640x480, 45 s at 30 Hz). Past it the store keeps every second
    /// frame, then every fourth, ...: loop closure goes on over any length of scan, and the
    /// map follows a correction from the frames kept (report.json: `store_stride`).
    #[arg(long, conflicts_with = "no_loop_closure", value_parser = crate::cli_values::parse_bytes)]
    pub frame_store: Option<usize>,
    /// Memory the TSDF map may use, e.g. 512M or 2G: past it the coldest chunks (packed, far
    /// from the camera) are written to a spill file in the output folder and read back when
    /// the camera returns; the output is the same. At the end of the scan every packed chunk
    /// goes to the spill file, so that the map does not sit beside the final mesh. A budget
    /// below what the chunks near the camera need is raised, with a warning, and report.json
    /// says so. The rest of the process comes on top of it: the live mesh, and at the end the
    /// whole mesh, and the semantic map (report.json's `process_memory` says what the live
    /// mesh, the semantic map and the resident peak were). A generated 5-minute home of five
    /// rooms peaks at 1.94-1.96 GB with 700M and semantics. Default: no budget.
    #[arg(long, value_parser = crate::cli_values::parse_bytes)]
    pub max_memory: Option<usize>,
    /// Chunks that no frame changed for this many frames are packed in memory (lossless but
    /// for distances far from the surface, see `--packed-distance-step`); 0 keeps every chunk
    /// plain (4 KiB each). Default: 30 with
    /// `--max-memory`, else 0: a packed chunk takes about 1 KB, so packing saves a third of
    /// a room scan's map at its end (the view stays plain) and three quarters of what the
    /// camera left, for compaction every 10th frame (about 17 ms on the demo) and slower
    /// final meshing (docs/benchmarks_log.md, "A compact voxel and denser packing").
    #[arg(long)]
    pub cold_after: Option<u32>,
    /// Packed chunks keep distances more than 3 voxels from the surface in steps of this many
    /// voxels (0 to 1; 0: exactly, and packing and spilling then change no output bit).
    /// Meshing, tracking and the labels read distances near the surface; 0.2 makes a packed
    /// chunk about 15 % smaller (docs/benchmarks_log.md, "Session 22").
    #[arg(long, default_value_t = semrecon_recon::TsdfConfig::default().packed_far_step_voxels)]
    pub packed_distance_step: f32,
}

/// When the map follows loop closure's corrections (`--map-follows`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum MapFollows {
    /// During the scan, every few keyframes.
    Live,
    /// Once, when the scan ends.
    End,
}

/// Where the pose of each frame comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum PoseMode {
    /// Frame-to-model ICP tracking (the live system).
    Track,
    /// The dataset's ground-truth poses (to judge fusion and meshing alone).
    GroundTruth,
}

impl PoseMode {
    /// What the report says the poses come from.
    pub fn describe(self) -> &'static str {
        match self {
            Self::Track => "tracking (frame-to-model ICP)",
            Self::GroundTruth => "ground truth",
        }
    }
}

/// Options of the semantic back end, shared by `run` and `demo`.
#[derive(clap::Args)]
pub struct SemanticArgs {
    /// Network weights (safetensors written by training; the configuration stored in the file
    /// is used, s20 when it has none). Default: the shipped model (`SEMRECON_MODEL` or
    /// crates/net/models/s20.safetensors); where that file is missing, an untrained s20
    /// network with random weights runs and the run says so: timings are real, labels are not.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Semantic passes: incremental (changed tiles plus context), full (the whole map each
    /// keyframe), or off.
    #[arg(long, value_enum, default_value_t = SemanticsMode::Incremental)]
    pub semantics: SemanticsMode,
    /// Context around the changed tiles in incremental passes, metres.
    #[arg(long, default_value_t = 1.0)]
    pub context: f32,
    /// Connected pieces of one class smaller than this many square metres take the class
    /// around them (specks of a wrong class at boundaries and in clutter); 0 keeps them.
    #[arg(long, default_value_t = 0.06)]
    pub min_label_island: f32,
    /// Labels voted over geometric segments of the map (normals and colour), as `semrecon
    /// segment --structure segments`: a class bleeding from an object onto the even surface
    /// beside it goes back to that surface's own; `none`: each 5 cm cell its own class.
    #[arg(long, value_enum, default_value_t = LiveStructure::Segments)]
    pub structure: LiveStructure,
    /// A changed chunk whose surface the labels already know is re-read for them at one
    /// keyframe in this many (new surface at once, everything at the end); 1: every changed
    /// chunk at every keyframe.
    #[arg(long, default_value_t = semrecon_pipeline::SemanticConfig::default().surface_refresh_keyframes)]
    pub surface_refresh: u32,
}

/// `--structure` of the live map's labels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LiveStructure {
    /// Each cell its own class.
    None,
    /// Each geometric segment one class.
    Segments,
}

/// `--semantics`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum SemanticsMode {
    /// Only the changed part of the map and its context.
    Incremental,
    /// The whole map at every keyframe.
    Full,
    /// No network.
    Off,
}

/// The pipeline configuration of the options; `up` is the map's up direction when known;
/// `color_registered`: whether the source's colour is registered to its depth (which sets
/// the colour fallback's default weight); `closes_loops`: whether the command closes loops
/// without `--loop-closure` (and lets the map follow at the end of the scan).
pub fn pipeline_config(
    recon: &ReconArgs,
    semantics: &SemanticArgs,
    realtime: bool,
    up: Option<Vec3>,
    color_registered: bool,
    closes_loops: bool,
) -> anyhow::Result<PipelineConfig> {
    anyhow::ensure!(recon.keyframe_every > 0, "--keyframe-every must be at least 1");
    let mut tsdf = TsdfConfig::with_voxel_size(recon.voxel).with_context(|| format!("voxel size {} m", recon.voxel))?;
    tsdf.truncation_voxels = recon.truncation;
    tsdf.max_depth = recon.max_depth;
    tsdf.behind_band = recon.behind_band;
    tsdf.far_group_beyond_m = recon.far_group_beyond;
    tsdf.far_group_frames = recon.far_group_frames;
    tsdf.validate().with_context(|| {
        format!(
            "truncation of {} voxels, fused depth up to {} m, far groups of {} frames beyond {} m",
            recon.truncation, recon.max_depth, recon.far_group_frames, recon.far_group_beyond
        )
    })?;
    // The same budget with semantics: the network reads the map's chunks, not the mesh.
    let default_mesh_budget = DEFAULT_MESH_BUDGET;
    let mut config = PipelineConfig {
        tsdf,
        mesh: MeshConfig { min_weight: recon.min_mesh_weight, min_component_triangles: recon.min_mesh_piece },
        mesh_budget: std::num::NonZeroUsize::new(recon.mesh_budget.unwrap_or(default_mesh_budget)),
        tracker: TrackerConfig {
            keyframe_interval: recon.keyframe_every,
            photometric_weight: recon.photometric_weight,
            degenerate_photometric_weight: recon
                .degenerate_photometric_weight
                .unwrap_or_else(|| TrackerConfig::colour_fallback_weight(color_registered)),
            min_support: recon.min_support,
            ..TrackerConfig::default()
        },
        poses: match recon.poses {
            PoseMode::Track => semrecon_pipeline::PoseMode::Track,
            PoseMode::GroundTruth => semrecon_pipeline::PoseMode::GroundTruth,
        },
        initial_pose: None,
        keyframe_every: recon.keyframe_every,
        ..PipelineConfig::default()
    };
    config.semantics.mode = match semantics.semantics {
        SemanticsMode::Full => SemanticMode::Full,
        _ => SemanticMode::Incremental { context_m: semantics.context },
    };
    config.semantics.realtime = realtime;
    config.semantics.up = up;
    config.semantics.min_island_m2 = semantics.min_label_island;
    config.semantics.segment_vote = semantics.structure == LiveStructure::Segments;
    anyhow::ensure!(semantics.surface_refresh > 0, "--surface-refresh must be at least 1");
    config.semantics.surface_refresh_keyframes = semantics.surface_refresh;
    config.loop_closure.enabled = loop_closure_on(recon, closes_loops)?;
    let follows = recon.map_follows.unwrap_or(if closes_loops { MapFollows::End } else { MapFollows::Live });
    if follows == MapFollows::End {
        // Never during the scan: `finish` brings the map to the final poses.
        config.loop_closure.follow_every = LoopClosureConfig::FOLLOW_AT_END;
    }
    if let Some(bytes) = recon.frame_store {
        config.loop_closure.frame_store_mb = bytes.div_ceil(1 << 20);
    }
    config.loop_closure.loop_information_from_alignment = recon.loop_information_from_alignment;
    config.loop_closure.odometry_information_from_tracking = recon.odometry_information_from_tracking;
    if let Some(mm) = recon.loop_residual_reference_mm {
        config.loop_closure.loop_residual_reference = mm * 1e-3;
    }
    if let Some(v) = recon.min_chunk_move_voxels {
        config.loop_closure.min_chunk_move_voxels = v;
    }
    if let Some(stride) = recon.reintegration_stride {
        config.loop_closure.reintegration_stride = stride;
    }
    config.memory.cold_after_frames = recon.cold_after.unwrap_or(if recon.max_memory.is_some() {
        semrecon_pipeline::MapMemoryConfig::default().cold_after_frames
    } else {
        0
    });
    config.memory.budget_bytes = recon.max_memory;
    config.tsdf.packed_far_step_voxels = recon.packed_distance_step;
    config.validate().context("pipeline options")?;
    Ok(config)
}

/// Whether loop closure runs: asked for (`--loop-closure`), or by the command's default
/// (`closes_loops`) unless `--no-loop-closure`. A memory budget turns the default off (with a
/// note: the re-integration cannot read spilled chunks yet); loop-closure options with loop
/// closure off are refused rather than ignored.
fn loop_closure_on(recon: &ReconArgs, closes_loops: bool) -> anyhow::Result<bool> {
    let mut on = recon.loop_closure || (closes_loops && !recon.no_loop_closure);
    if on && !recon.loop_closure && recon.max_memory.is_some() {
        println!("note: no loop closure under --max-memory (its re-fusion cannot read spilled chunks yet)");
        on = false;
    }
    let options = [
        (recon.reintegration_stride.is_some(), "--reintegration-stride"),
        (recon.loop_information_from_alignment, "--loop-information-from-alignment"),
        (recon.odometry_information_from_tracking, "--odometry-information-from-tracking"),
        (recon.loop_residual_reference_mm.is_some(), "--loop-residual-reference-mm"),
        (recon.min_chunk_move_voxels.is_some(), "--min-chunk-move-voxels"),
        (recon.frame_store.is_some(), "--frame-store"),
        (recon.map_follows.is_some(), "--map-follows"),
    ];
    if let Some((_, name)) = options.iter().find(|(given, _)| *given).filter(|_| !on) {
        anyhow::bail!("{name} is a loop-closure option, and loop closure is off here: add --loop-closure");
    }
    Ok(on)
}

/// Puts the map's spill file (used only under `--max-memory`) in the output folder `out`, as
/// a hidden temporary named after the process (deleted when the map is).
pub fn spill_in(config: &mut PipelineConfig, out: &Path) {
    config.memory.spill_path = Some(out.join(format!(".semrecon-map-{}.spill", std::process::id())));
}

/// The network of `--model` (or the shipped model, or an untrained s20 when that is missing), `None` with `--semantics off`; with a
/// sentence saying which.
/// The network runs on `device` (`live` passes the CPU: its `--device` names a camera).
pub fn load_network(
    args: &SemanticArgs,
    device: &crate::device::DeviceArgs,
) -> anyhow::Result<(Option<Segmenter>, String)> {
    if args.semantics == SemanticsMode::Off {
        return Ok((None, "off".into()));
    }
    let (net, summary) = load_network_on_cpu(args)?;
    let Some(mut net) = net else { return Ok((None, summary)) };
    let device = device.network_device()?;
    let summary = format!("{summary} on {}", device.describe());
    net.set_device(device);
    Ok((Some(net), summary))
}

/// [`load_network`] before the device is chosen.
fn load_network_on_cpu(args: &SemanticArgs) -> anyhow::Result<(Option<Segmenter>, String)> {
    match &args.model {
        Some(path) => {
            let net = shipped::load(path, None).with_context(|| format!("loading the model {}", path.display()))?;
            let summary = format!("{} ({})", path.display(), net.config().summary());
            Ok((Some(net), summary))
        }
        None => {
            let path = shipped::default_model_path();
            if path.is_file() {
                let net = shipped::load(&path, None)
                    .with_context(|| format!("loading the shipped model {}", path.display()))?;
                let summary = format!("shipped {} ({})", path.display(), net.config().summary());
                return Ok((Some(net), summary));
            }
            let config = NetConfig::s20();
            let net = Segmenter::new(Weights::random(&config, 1), config.clone())?;
            Ok((
                Some(net),
                format!(
                    "untrained {} with random weights: no model at {} (labels meaningless; pass --model)",
                    config.name,
                    path.display()
                ),
            ))
        }
    }
}

/// The class colour of every vertex of `mesh` ([`UNLABELED`] and unknown ids grey; all grey
/// when the mesh has no vertex labels).
pub fn class_colors(mesh: &LabeledMesh) -> Vec<[u8; 3]> {
    if mesh.vertex_labels.len() != mesh.positions.len() {
        return vec![[160, 160, 160]; mesh.positions.len()];
    }
    mesh.vertex_labels
        .iter()
        .map(|&l| SemanticClass::from_id(l).map_or([160, 160, 160], SemanticClass::color))
        .collect()
}

/// Creates the output folder `dir` before any work starts, so that a wrong path fails at once
/// instead of after a whole run.
pub fn prepare_output_dir(dir: &Path) -> anyhow::Result<()> {
    anyhow::ensure!(!dir.exists() || dir.is_dir(), "output folder {}: exists and is not a folder", dir.display());
    std::fs::create_dir_all(dir).with_context(|| format!("creating the output folder {}", dir.display()))
}

/// Most warnings a run or live session prints; the rest are counted.
pub const MAX_WARNINGS: usize = 10;

/// Ends a `run` or `live` session alike: finishes the pipeline (the final meshing and
/// semantics), shows the final mesh in the live viewer, prints the pipeline's warnings and
/// how many of the session's `warnings` were not shown, and writes the outputs to `out`.
/// Returns the mesh and the wall time since `start`, taken before the outputs are written.
pub fn finish_session(
    pipeline: &mut Pipeline,
    live: Option<&mut LiveView>,
    start: Instant,
    warnings: usize,
    out: &Path,
) -> anyhow::Result<(LabeledMesh, f64)> {
    let mesh = pipeline.finish()?;
    let wall_s = start.elapsed().as_secs_f64();
    let gravity = output_gravity(pipeline, &mesh);
    if let Some(live) = live {
        if let Err(why) = live.push(pipeline.frame_counts().1, &mesh, pipeline.trajectory(), gravity) {
            eprintln!("warning: {why}");
        }
    }
    for w in pipeline.warnings() {
        eprintln!("warning: {w}");
    }
    if warnings > MAX_WARNINGS {
        eprintln!("warning: {} more warnings not shown", warnings - MAX_WARNINGS);
    }
    write_outputs(out, &mesh, pipeline.trajectory(), gravity)?;
    Ok((mesh, wall_s))
}

/// The gravity recorded in the written meshes: the pipeline's up and floor (a dataset's
/// gravity file, or the semantic passes' estimate), else estimated from the mesh and the
/// cameras, so that physics, the viewer and `snapshot` know where gravity points in the map
/// frame and where the floor lies under the scan's holes.
pub fn output_gravity(pipeline: &Pipeline, mesh: &LabeledMesh) -> Option<MeshGravity> {
    pipeline
        .up()
        .or_else(|| semrecon_pipeline::gravity::mesh_up(&mesh.positions, &mesh.normals, &pipeline.trajectory().poses))
        .map(mesh_gravity)
}

/// An up estimate as recorded in a mesh file.
fn mesh_gravity(u: UpEstimate) -> MeshGravity {
    MeshGravity { up: u.up, floor_height: Some(u.floor_height) }
}

/// Writes `dir/mesh.ply` (observed colours and a vertex `label`), `dir/semantic.ply` (class
/// colours) and `dir/trajectory.txt` (TUM) into `dir`, which [`prepare_output_dir`] made
/// before the run. Both meshes record `gravity` (the map frame's up and floor) when known.
pub fn write_outputs(
    dir: &Path,
    mesh: &LabeledMesh,
    trajectory: &Trajectory,
    gravity: Option<MeshGravity>,
) -> anyhow::Result<()> {
    // Both files straight from the mesh, in blocks of rows: a whole home's mesh is a gigabyte.
    let colors = class_colors(mesh);
    write_ply_recoloured(
        dir.join("mesh.ply"),
        dir.join("semantic.ply"),
        mesh,
        &colors,
        PlyEncoding::BinaryLittleEndian,
        gravity,
    )?;
    trajectory.write_tum(dir.join("trajectory.txt"))?;
    Ok(())
}

/// mIoU of the mesh's vertex labels against the class of the nearest ground-truth surface
/// (within 5 cm; further vertices have no true class and are not counted). Unlabelled vertices
/// count as wrong. `None` when no vertex has a true class.
pub fn semantic_score(gt: &LabeledMesh, mesh: &LabeledMesh) -> anyhow::Result<Option<(f64, ConfusionMatrix)>> {
    if mesh.positions.is_empty() || mesh.vertex_labels.len() != mesh.positions.len() {
        return Ok(None);
    }
    let labeler = SurfaceLabeler::new(gt, 0.05).context("indexing the ground-truth mesh")?;
    let truth = labeler.labels(&mesh.positions);
    let mut cm = ConfusionMatrix::new(SemanticClass::COUNT);
    cm.add(&truth, &mesh.vertex_labels);
    Ok((cm.total() > 0).then(|| (cm.miou(), cm)))
}

/// Mean distance from the mesh's vertices to the ground-truth surface, millimetres (a quick
/// accuracy for `run`: `evaluate_mesh` samples both surfaces both ways and costs seconds more).
/// `None` for a mesh without vertices.
pub fn vertex_accuracy_mm(gt: &LabeledMesh, mesh: &LabeledMesh) -> anyhow::Result<Option<f64>> {
    if mesh.positions.is_empty() {
        return Ok(None);
    }
    let config = MeshEvalConfig { sample_spacing_m: 0.01, ..MeshEvalConfig::default() };
    let index = SurfaceIndex::new(gt, &config, "ground-truth").context("indexing the ground-truth mesh")?;
    let sum: f64 = mesh.positions.par_iter().map(|p| f64::from(index.nearest_triangle(*p).0)).sum();
    Ok(Some(sum / mesh.positions.len() as f64 * 1e3))
}

/// [`vertex_accuracy_mm`] of `mesh` moved by `gt_from_est` (the ATE's alignment,
/// [`semrecon_eval::TrajectoryErrors::gt_from_est_transform`]): the mesh's accuracy with
/// the trajectory's rigid alignment taken out, as the ATE takes it out of the positions. A
/// tracked map is rigidly off by what its first frames' small errors set (0.1-0.2 degrees on
/// the generated loops, 5-10 mm at the far walls), which the plain accuracy counts as error
/// everywhere.
///
/// `None` for a trajectory within [`MIN_ALIGNMENT_SPREAD_M`] of a line: the alignment's turn
/// about that line is then set by noise (a 5-frame run moved its mesh by a metre).
pub fn aligned_vertex_accuracy_mm(
    gt: &LabeledMesh,
    mesh: &LabeledMesh,
    trajectory: &[Vec3],
    gt_from_est: glam::DAffine3,
) -> anyhow::Result<Option<f64>> {
    if off_line_spread_m(trajectory) < MIN_ALIGNMENT_SPREAD_M {
        return Ok(None);
    }
    anyhow::ensure!(gt_from_est.is_finite(), "the trajectory's alignment is not finite");
    let positions = mesh.positions.iter().map(|p| gt_from_est.transform_point3(p.as_dvec3()).as_vec3()).collect();
    vertex_accuracy_mm(gt, &LabeledMesh { positions, ..LabeledMesh::default() })
}

/// Least root-mean-square distance of a trajectory's positions from the line that fits them
/// for [`aligned_vertex_accuracy_mm`]: 0.25 m, a room's walk (the generated loops: metres).
pub const MIN_ALIGNMENT_SPREAD_M: f64 = 0.25;

/// Root-mean-square distance of `points` from the line that fits them best: the square root
/// of their covariance's trace less its largest eigenvalue (by power iteration; a 3x3
/// matrix needs no library).
fn off_line_spread_m(points: &[Vec3]) -> f64 {
    if points.len() < 3 {
        return 0.0;
    }
    let n = points.len() as f64;
    let mean = points.iter().fold(glam::DVec3::ZERO, |a, p| a + p.as_dvec3()) / n;
    let mut covariance = glam::DMat3::ZERO;
    for p in points {
        let d = p.as_dvec3() - mean;
        covariance += glam::DMat3::from_cols(d * d.x, d * d.y, d * d.z) / n;
    }
    let trace = covariance.x_axis.x + covariance.y_axis.y + covariance.z_axis.z;
    let mut v = glam::DVec3::ONE.normalize();
    for _ in 0..100 {
        let next = covariance * v;
        if next.length() == 0.0 {
            return 0.0;
        }
        v = next.normalize();
    }
    let largest = v.dot(covariance * v);
    (trace - largest).max(0.0).sqrt()
}

/// The up direction of a dataset's world frame when the dataset says it: a 7-Scenes style
/// `gravity-direction.txt` (three numbers, the direction of gravity in the world frame of the
/// poses) in the folder. `None` when there is no such file; an error when it is unreadable.
pub fn dataset_up(folder: Option<&Path>) -> anyhow::Result<Option<Vec3>> {
    let Some(path) = folder.map(|f| f.join("gravity-direction.txt")).filter(|p| p.is_file()) else {
        return Ok(None);
    };
    let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let v: Vec<f32> = text
        .split_whitespace()
        .map(|t| t.parse::<f32>().with_context(|| format!("{}: `{t}` is not a number", path.display())))
        .collect::<anyhow::Result<_>>()?;
    anyhow::ensure!(v.len() == 3, "{}: expected 3 numbers (a direction), found {}", path.display(), v.len());
    let g = Vec3::new(v[0], v[1], v[2]);
    anyhow::ensure!(g.is_finite() && g.length() > 1e-6, "{}: the direction is zero or not finite", path.display());
    Ok(Some(-g.normalize()))
}

/// Share of labelled vertices, for messages.
pub fn labelled_share(mesh: &LabeledMesh) -> f64 {
    if mesh.vertex_labels.is_empty() {
        return 0.0;
    }
    mesh.vertex_labels.iter().filter(|&&l| l != UNLABELED).count() as f64 / mesh.vertex_labels.len() as f64
}

/// The `loop_closure` object of `report.json`: loops tried (frame pairs, residuals, accepted
/// or why not), corrections applied, the trajectory before and after optimisation
/// (`[t, x, y, z, qx, qy, qz, qw]` rows, `world_from_camera`), and with a ground truth the ATE
/// of both. `null` when loop closure was off.
pub fn loop_closure_json(pipeline: &Pipeline, gt: Option<&Trajectory>) -> serde_json::Value {
    let (Some(report), Some(before)) = (pipeline.loop_closure(), pipeline.tracked_trajectory()) else {
        return serde_json::Value::Null;
    };
    let rows = |t: &Trajectory| -> Vec<[f64; 8]> {
        t.timestamps
            .iter()
            .zip(&t.poses)
            .map(|(&time, p)| {
                let (_, q, x) = p.to_scale_rotation_translation();
                [time, x.x as f64, x.y as f64, x.z as f64, q.x as f64, q.y as f64, q.z as f64, q.w as f64]
            })
            .collect()
    };
    let ate = |t: &Trajectory| {
        gt.filter(|g| !g.is_empty() && !t.is_empty())
            .and_then(|g| evaluate_trajectory(g, t, &TrajectoryEvalConfig::default()).ok())
            .map(|e| e.ate_rmse_m)
    };
    let accepted = report.loops.iter().filter(|l| l.accepted).count();
    serde_json::json!({
        "keyframes": report.keyframes,
        "stopped": report.stopped,
        "loops_accepted": accepted,
        "loops_rejected": report.loops.len() - accepted,
        "loops": report.loops,
        "corrections": report.corrections,
        "reintegrations": report.reintegrations,
        "skipped_reintegrations": report.skipped_reintegrations,
        "odometry_scale": report.odometry_scale,
        "stored_frames": report.stored_frames,
        "frame_store_mb": report.frame_store_bytes as f64 / 1e6,
        "store_stride": report.store_stride,
        // The map follows the corrections live, or once at the end (`--map-follows`).
        "map_follows": if pipeline.config().loop_closure.follows_at_end() { "end" } else { "live" },
        "ate_rmse_before_m": ate(before),
        "ate_rmse_after_m": ate(pipeline.trajectory()),
        "trajectory_before": rows(before),
        "trajectory_after": rows(pipeline.trajectory()),
    })
}

/// One line on loop closure from [`loop_closure_json`]'s object.
pub fn loop_closure_summary(json: &serde_json::Value) -> String {
    if json.is_null() {
        return "loop closure: off (`run` closes loops unless --no-loop-closure; `demo` and `live` with --loop-closure)".into();
    }
    let mm = |k: &str| json[k].as_f64().map_or("n/a".to_string(), |v| format!("{:.1} mm", v * 1e3));
    format!(
        "loop closure: {} keyframes, {} loops accepted, {} rejected, {} pose corrections, {} map re-integrations (the map following {}); ATE {} as tracked, {} after{}",
        json["keyframes"],
        json["loops_accepted"],
        json["loops_rejected"],
        json["corrections"].as_array().map_or(0, Vec::len),
        json["reintegrations"].as_array().map_or(0, Vec::len),
        if json["map_follows"] == "end" { "at the end" } else { "live" },
        mm("ate_rmse_before_m"),
        mm("ate_rmse_after_m"),
        json["stopped"].as_str().map_or(String::new(), |s| format!(" ({s})"))
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_trajectorys_spread_off_its_line() {
        let line: Vec<Vec3> = (0..20).map(|i| Vec3::new(0.1 * i as f32, 0.05 * i as f32, 1.0)).collect();
        assert!(off_line_spread_m(&line) < 1e-6);
        // A circle of radius r: the mean squared distance from a diameter is r² / 2.
        let circle: Vec<Vec3> = (0..360)
            .map(|i| {
                let a = (i as f32).to_radians();
                Vec3::new(2.0 * a.cos(), 1.5, 2.0 * a.sin())
            })
            .collect();
        assert!((off_line_spread_m(&circle) - 2.0 / 2f64.sqrt()).abs() < 1e-4);
        assert_eq!(off_line_spread_m(&line[..2]), 0.0);
    }

    /// A mesh that is the true surface moved rigidly: off by centimetres as it lies, exact once
    /// the alignment is undone; a trajectory along a line gives no aligned figure.
    #[test]
    fn the_aligned_accuracy_takes_out_a_rigid_offset() {
        // A floor and a wall, two triangles each.
        let truth = LabeledMesh {
            positions: vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(4.0, 0.0, 0.0),
                Vec3::new(4.0, 4.0, 0.0),
                Vec3::new(0.0, 4.0, 0.0),
                Vec3::new(0.0, 4.0, 3.0),
                Vec3::new(4.0, 4.0, 3.0),
            ],
            colors: vec![[200; 3]; 6],
            triangles: vec![[0, 1, 2], [0, 2, 3], [3, 2, 5], [3, 5, 4]],
            ..LabeledMesh::default()
        };
        let est_from_gt = glam::DAffine3::from_rotation_translation(
            glam::DQuat::from_rotation_x(0.01),
            glam::DVec3::new(0.0, -0.02, 0.03),
        );
        let moved = LabeledMesh {
            positions: truth.positions.iter().map(|p| est_from_gt.transform_point3(p.as_dvec3()).as_vec3()).collect(),
            ..truth.clone()
        };
        let gt_from_est = est_from_gt.inverse();
        let walk: Vec<Vec3> =
            (0..40).map(|i| Vec3::new(2.0 + (i as f32 * 0.3).cos(), 2.0 + (i as f32 * 0.3).sin(), 1.5)).collect();
        let plain = vertex_accuracy_mm(&truth, &moved).expect("accuracy").expect("vertices");
        let aligned =
            aligned_vertex_accuracy_mm(&truth, &moved, &walk, gt_from_est).expect("accuracy").expect("spread");
        assert!(plain > 10.0 && aligned < 0.01, "plain {plain} mm, aligned {aligned} mm");
        let line: Vec<Vec3> = (0..40).map(|i| Vec3::new(0.01 * i as f32, 2.0, 1.5)).collect();
        assert_eq!(aligned_vertex_accuracy_mm(&truth, &moved, &line, gt_from_est).expect("accuracy"), None);
    }

    #[derive(clap::Parser)]
    struct Options {
        #[command(flatten)]
        recon: ReconArgs,
        #[command(flatten)]
        semantics: SemanticArgs,
    }

    /// The colour fallback's weight: 0.1 by default where colour is registered to depth, 0
    /// where it is not (7-Scenes), and what the user gives either way.
    #[test]
    fn the_colour_fallback_follows_the_sources_registration_unless_given() {
        use clap::Parser;
        let weight = |args: &[&str], registered: bool| {
            let o = Options::parse_from(std::iter::once("semrecon").chain(args.iter().copied()));
            pipeline_config(&o.recon, &o.semantics, false, None, registered, false)
                .expect("config")
                .tracker
                .degenerate_photometric_weight
        };
        assert_eq!(weight(&[], true), 0.1);
        assert_eq!(weight(&[], false), 0.0);
        assert_eq!(weight(&["--degenerate-photometric-weight", "0.3"], false), 0.3);
        assert_eq!(weight(&["--degenerate-photometric-weight", "0"], true), 0.0);
    }

    /// `run` closes loops by default and lets the map follow at the end; `demo` and `live`
    /// only with `--loop-closure`, the map following live; `--no-loop-closure` and a memory
    /// budget turn the default off; a loop-closure option with loop closure off is refused.
    #[test]
    fn loop_closure_defaults_depend_on_the_command() {
        use clap::Parser;
        let config = |args: &[&str], closes_loops: bool| {
            let o = Options::parse_from(std::iter::once("semrecon").chain(args.iter().copied()));
            pipeline_config(&o.recon, &o.semantics, false, None, true, closes_loops)
                .map(|c| (c.loop_closure.enabled, c.loop_closure.follow_every))
        };
        let end = LoopClosureConfig::FOLLOW_AT_END;
        let live = LoopClosureConfig::default().follow_every;
        assert_eq!(config(&[], true).expect("run"), (true, end));
        assert!(!config(&["--no-loop-closure"], true).expect("run").0);
        assert_eq!(config(&["--map-follows", "live"], true).expect("run"), (true, live));
        assert!(!config(&["--max-memory", "1G"], true).expect("run").0);
        assert!(!config(&[], false).expect("demo").0);
        assert_eq!(config(&["--loop-closure"], false).expect("demo"), (true, live));
        assert_eq!(config(&["--loop-closure", "--map-follows", "end"], false).expect("demo"), (true, end));
        let refused = config(&["--frame-store", "1G"], false).expect_err("no loop closure in demo");
        assert!(refused.to_string().contains("--loop-closure"), "{refused}");
        assert!(config(&["--loop-closure", "--max-memory", "1G"], true).is_err());
        assert!(Options::try_parse_from(["semrecon", "--no-loop-closure", "--frame-store", "1G"]).is_err());
        assert!(Options::try_parse_from(["semrecon", "--no-loop-closure", "--loop-closure"]).is_err());
    }
}
