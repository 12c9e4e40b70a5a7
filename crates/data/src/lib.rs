//! Data for semrecon: the semantic classes, cameras and frames, every file format the
//! system reads or writes (PLY, TUM trajectories, S3DIS rooms, ScanNet labelled meshes),
//! readers for the common RGB-D dataset layouts behind one [`FrameSource`] trait, a
//! procedural generator of labelled indoor rooms, a z-buffer RGB-D renderer with a
//! Kinect-like sensor model, and live cameras: OpenNI2 devices and recordings (the library
//! loaded at run time), RealSense recordings, and any source replayed in real time
//! ([`live`]).
//!
//! Conventions: metres; world frame z up with the floor at z = 0; camera frame x right,
//! y down, z forward (the pinhole convention of every dataset read here); poses are
//! `world_from_camera` rigid transforms.
#![warn(missing_docs)]

pub mod atomic_file;
pub mod camera;
pub mod class;
pub mod datasets;
pub mod depth_calibration;
pub mod depth_image;
pub mod error;
pub mod frame;
pub mod home_class;
pub mod library;
pub mod live;
pub mod mesh;
pub mod openni;
pub mod ply;
pub mod point_cloud;
pub mod render;
pub mod ros_messages;
pub mod s3dis;
pub mod scan_path;
pub mod scannet_mesh;
pub mod sensor;
pub mod shared_data;
pub mod synth;
pub mod trajectory;

pub use camera::Intrinsics;
pub use class::SemanticClass;
pub use datasets::{open_dataset, DatasetSpec};
pub use error::{DataError, Result};
pub use frame::{Frame, FrameSource};
pub use home_class::{HomeClass, LabelSet};
pub use mesh::LabeledMesh;
pub use ply::{
    read_ply, read_ply_with_gravity, write_ply, write_ply_recoloured, write_ply_with_gravity, MeshGravity, PlyEncoding,
};
pub use point_cloud::LabeledPointCloud;
pub use render::{PreparedMesh, RenderOutput, RenderedScan, Renderer};
pub use scan_path::{RoomLayout, ScanPlan};
pub use sensor::SensorModel;
pub use trajectory::Trajectory;
