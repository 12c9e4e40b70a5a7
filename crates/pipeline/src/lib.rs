//! The live semantic pipeline of semrecon (MISSION.md section 1): a front end that tracks and
//! fuses every RGB-D frame into a TSDF map, and a back end thread that, at keyframes, labels
//! the changed part of the map's surface with the CBSCN network at 5 cm and accumulates class
//! probabilities per cell, so that the mesh's labels settle as the scan goes on.
//!
//! ```text
//! Frame --push_frame--> tracking --> fusion --(keyframe)--> meshing (within a budget)
//!                                                  \--> surface cells (5 cm, changed chunks)
//!                                                        --> up estimate, tile selection
//!                                                        --> back end: network --> labels
//! mesh() = marching-cubes mesh + class of each vertex's cell
//! ```
//!
//! - [`Pipeline`]: the API (`new`, `push_frame`, `pose`, `trajectory`, `mesh`, `timings`,
//!   `finish`);
//! - [`config`]: [`PipelineConfig`], [`SemanticConfig`], full or incremental semantics;
//! - [`gravity`]: the up direction from the map's horizontal planes and the cameras;
//! - [`semantic_map`]: surface cells and accumulated labels;
//! - [`surface_cells`]: the map's surface points read from the TSDF chunks (the zero crossings
//!   the mesher meshes), so that labels do not wait for the mesh;
//! - [`label_islands`]: specks of a class merged into their surroundings;
//! - [`live`]: the feed from a live camera, a one-frame mailbox that drops and counts frames
//!   arriving while the pipeline is busy;
//! - [`loop_closure`]: loops found at keyframes, the pose graph optimised, the map re-fused
//!   where frames moved;
//! - [`timing`]: per-stage statistics.
//!
//! ```
//! use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
//! use semrecon_data::FrameSource;
//! use semrecon_net::{NetConfig, Segmenter, Weights};
//! use semrecon_pipeline::{Pipeline, PipelineConfig, PoseMode};
//!
//! let mut scan = SyntheticScanConfig::new(1);
//! scan.frames = 4;
//! scan.intrinsics = scan.intrinsics.scaled(160, 120);
//! let (_room, frames) = synthetic_scan(&scan)?;
//! let net_config = NetConfig::new("tiny", 3, 4, 0.05);
//! let net = Segmenter::new(Weights::random(&net_config, 1), net_config)?;
//! let mut config = PipelineConfig { poses: PoseMode::GroundTruth, keyframe_every: 2, ..PipelineConfig::default() };
//! config.tsdf.voxel_size = 0.02;
//! config.tsdf.truncation_voxels = 4.0;
//! let mut pipeline = Pipeline::new(config, frames.intrinsics(), Some(net))?;
//! for i in 0..frames.len() {
//!     pipeline.push_frame(&frames.frame(i)?)?;
//! }
//! let mesh = pipeline.finish()?;
//! assert_eq!(mesh.vertex_labels.len(), mesh.positions.len());
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
#![warn(missing_docs)]

mod backend;
pub mod config;
pub mod error;
mod freed_memory;
pub mod gravity;
pub mod label_islands;
pub mod label_store;
pub mod live;
pub mod loop_closure;
mod pipeline;
pub mod semantic_map;
pub mod surface_cells;
pub mod timing;

pub use config::{MapMemoryConfig, PipelineConfig, PoseMode, SemanticConfig, SemanticMode, DEFAULT_MESH_BUDGET};
pub use error::{PipelineError, Result};
pub use gravity::{UpEstimate, UpSource};
pub use live::{FeedStats, LiveFeed, LiveFrame};
pub use loop_closure::{CorrectionRecord, LoopClosureConfig, LoopClosureReport, LoopRecord, ReintegrationRecord};
pub use pipeline::{FrameResult, FrameStatus, Pipeline, SemanticPass, FRONT_END_STAGES};
pub use timing::{StageSummary, StageTimes};
