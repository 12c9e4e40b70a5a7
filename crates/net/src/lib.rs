//! CBSCN, the semantic segmentation network of semrecon (MISSION.md section 3): a sparse
//! voxel U-Net with residual blocks and cross-scale fusion with spatial attention, labelling
//! every voxel of a room with one of 13 classes.
//!
//! - [`config`]: named configurations (`s20`, `s50`, `live`) and configuration files;
//! - [`model`]: the architecture as named tensors, parameter and FLOP counts;
//! - [`weights`]: named tensors, safetensors files with `f16` storage, seeded initialisation;
//! - [`geometry`]: kernel maps, chunk plans and interpolation tables of one input;
//! - [`metrics`]: confusion matrix, per-class IoU, mIoU, accuracy;
//! - [`inference`]: inference on the sparse engines ([`Segmenter`]), on the CPU or, with the
//!   cargo feature `gpu`, on the GPU engine ([`Device`]); the fused forward itself is one,
//!   generic over the engine's tensors (`forward`, private);
//! - [`reference`](mod@reference): a plain, unfused forward, the oracle of the tests;
//! - [`surface`]: coloured, labelled point samples of a mesh surface (network input);
//! - [`sample`]: voxelised, labelled rooms ([`VoxelSample`]), the unit of training and evaluation;
//! - [`dataset`]: data sources (`synth:`, `s3dis:`, `scannet:`, `ply:`), loading and augmentation;
//! - [`shipped`]: the shipped default model and the checked loading of model files;
//! - [`structure`]: room structure after the network (segment votes, floor and ceiling
//!   planes);
//! - [`tta`]: test-time augmentation ([`Tta`]), the network averaged over turned and
//!   mirrored copies of a room;
//! - `train` (cargo feature `train`): training with burn (custom sparse-convolution operation,
//!   the network in burn, the training loop); see docs/model.md.
//!
//! ```
//! use semrecon_net::{NetConfig, Segmenter, Weights};
//!
//! let config = NetConfig::new("tiny", 3, 4, 0.05);
//! let mut net = Segmenter::new(Weights::random(&config, 1), config)?;
//! let points = [[0.0, 0.0, 0.0], [0.06, 0.0, 0.0], [0.06, 0.05, 0.0]];
//! let colors = [[200, 10, 10], [10, 200, 10], [10, 10, 200]];
//! let labels = net.segment_points(&points, &colors)?;
//! assert_eq!(labels.len(), 3);
//! # Ok::<(), semrecon_net::NetError>(())
//! ```
#![warn(missing_docs)]

pub mod augment;
pub mod camera_colours;
pub mod config;
pub mod dataset;
pub mod error;
mod forward;
pub mod geometry;
pub mod home_head;
pub mod home_head_training;
pub mod inference;
pub mod metrics;
pub mod model;
pub mod reference;
pub mod repaint;
pub mod sample;
pub mod scan_imitation;
pub mod shipped;
pub mod structure;
pub mod surface;
mod table_geometry;
#[cfg(feature = "train")]
pub mod train;
pub mod tta;
pub mod weights;

pub use config::NetConfig;
pub use error::{NetError, Result};
pub use geometry::NetGeometry;
pub use inference::{color_features, ConvKernel, Device, GpuGeometry, PointScores, Segmenter, Timing};
pub use metrics::ConfusionMatrix;
pub use model::{forward_flops, parameter_count, LevelStats};
pub use sample::VoxelSample;
pub use tta::{GridSymmetry, Tta, TtaMean};
pub use weights::{Tensor, Weights};
