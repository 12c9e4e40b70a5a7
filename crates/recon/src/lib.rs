//! Dense geometric reconstruction for semrecon: a voxel-hashed truncated signed-distance
//! (TSDF) map at millimetre resolution, projective fusion of RGB-D frames into it, and
//! incremental marching cubes that turns it into a coloured triangle mesh.
//!
//! ```text
//! Frame + world_from_camera --TsdfMap::integrate--> TsdfMap --IncrementalMesher::update--> LabeledMesh
//! Frame + TsdfMap --Tracker::track--> world_from_camera (or lost: do not fuse)
//! lost Frame + TsdfMap + KeyframeIndex --Tracker::relocalise--> world_from_camera (or still lost)
//! TsdfMap + pose --raycast--> ModelView (vertex, normal, colour maps)
//! ```
//!
//! Conventions follow `semrecon_data`: metres, world frame z up, camera x right / y down /
//! z forward, poses as `world_from_camera`. Everything is deterministic: the same inputs give
//! the same bits for any rayon thread count (on one build: enabling FMA/AVX with
//! `target-cpu` may change the last bits).
//!
//! Memory: a chunk costs [`TsdfMap::bytes_per_chunk`] bytes (4096 for its 512 voxels of 8
//! bytes, the rest for its record, with up to 8 runs of the frames that touched it inline,
//! and its hash entry) while plain; [`TsdfMap::compact`] packs chunks fusion has left alone
//! (about 1 KB on the demo, lossless) and, past [`TsdfMap::set_memory_budget`], spills the
//! coldest to a file ([`TsdfMap::memory`] says where the bytes are). Revisiting a surface adds no chunks and no bytes. An [`IncrementalMesher`] with a
//! non-zero [`RemeshTolerance`] adds a 2112-byte snapshot per chunk with both signs.
#![warn(missing_docs)]

pub mod cache_hint;
mod cube_cases;
pub mod error;
pub mod fusion;
pub mod grouped_fusion;
mod linalg;
pub mod loop_detection;
pub mod map;
pub mod marching_cubes;
pub mod pose_graph;
pub mod raycast;
pub mod relocalisation;
pub mod tracking;

pub use error::{ReconError, Result};
pub use fusion::{depth_weight, IntegrationStats};
pub use grouped_fusion::{averaged_frame, AveragedFrame, GroupedFusion, GroupingStats};
pub use loop_detection::{LoopConfig, LoopDetector, LoopRejection, LoopVerdict};
pub use map::{
    Chunk, ChunkKey, Compaction, MapMemory, PackError, SpillError, SpillFile, TsdfConfig, TsdfMap, Voxel, CHUNK_SIDE,
    CHUNK_VOXELS,
};
pub use marching_cubes::{
    extract_mesh, extract_mesh_with, mesh_chunk, mesh_chunk_with, ChunkMesh, IncrementalMesher, MeshConfig,
    MeshStoreMemory, MeshingStats, RemeshTolerance,
};
pub use pose_graph::{EdgeKind, PoseEdge, PoseGraph, PoseGraphConfig, PoseGraphError};
pub use raycast::{raycast, ModelView};
pub use relocalisation::KeyframeIndex;
pub use tracking::{ate_rmse, Keyframe, LostReason, Tracker, TrackerConfig, TrackingResult, TrackingStatus};
