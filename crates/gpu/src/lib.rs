//! A portable GPU engine for semrecon's sparse convolutions: WGSL compute shaders on wgpu
//! (Vulkan), behind this crate's cargo feature `gpu`.
//!
//! [`GpuEngine`] implements `semrecon_sparse::ConvBackend`, the kernel trait the CPU engine
//! implements too, and passes the same shared suite (`semrecon_sparse::backend_tests`): the
//! chunk-based submanifold kernel (a chunk's input region and a weight tile in workgroup
//! memory), strided and transposed convolutions through the same kernel, the rulebook
//! (gather-GEMM-scatter) baseline, and both gradients. Submanifold kernel maps are built on
//! the device with a hash table; chunk plans come from the CPU planner (docs/gpu.md). A whole
//! voxel hierarchy (every level's tables, the strided layers, the interpolation between levels)
//! can be built on the device too ([`DeviceHierarchy`]), which is what the network's GPU path
//! uses.
//!
//! It also implements `semrecon_sparse::ResidentBackend`: tensors on the device
//! ([`GpuTensor`]), convolutions and the network's element-wise steps (attention gate,
//! weighted row gather, bias, argmax) run on them without copies, so a whole network forward
//! uploads its input once and reads back once; every transfer is counted
//! ([`GpuContext::transfers`]).
//!
//! Without the `gpu` feature nothing of wgpu is compiled: the engine's constructor returns
//! [`GpuError::NotBuilt`], so callers need no conditional code, and `cargo test --workspace`
//! stays free of wgpu.
//!
//! ```no_run
//! use semrecon_gpu::GpuEngine;
//! use semrecon_sparse::{ConvAlgorithm, ConvBackend};
//!
//! let gpu = GpuEngine::new(ConvAlgorithm::Chunked)?;
//! let coords = [[0, 0, 0, 0], [1, 0, 0, 0]];
//! let layer = gpu.submanifold(&coords, 3)?;
//! let y = gpu.forward(&layer, &[1.0, 2.0], 1, &vec![0.5; 27], 1)?;
//! assert_eq!(y, vec![1.5, 1.5]);
//! # Ok::<(), semrecon_gpu::GpuError>(())
//! ```
#![warn(missing_docs)]

#[cfg(feature = "gpu")]
mod context;
#[cfg(feature = "gpu")]
mod engine;
pub mod error;
#[cfg(feature = "gpu")]
mod hierarchy;
mod host_level;
mod kernel_time;
#[cfg(feature = "gpu")]
mod layer;
#[cfg(feature = "gpu")]
mod profile;
#[cfg(feature = "gpu")]
mod record;
#[cfg(feature = "gpu")]
mod resident;
#[cfg(not(feature = "gpu"))]
mod stub;
mod tile;
pub mod transfers;

#[cfg(feature = "gpu")]
pub use context::GpuContext;
#[cfg(feature = "gpu")]
pub use engine::GpuEngine;
pub use error::{GpuError, Result};
#[cfg(feature = "gpu")]
pub use hierarchy::{DeviceHierarchy, DeviceLevel};
pub use host_level::HostLevel;
pub use kernel_time::KernelTime;
#[cfg(feature = "gpu")]
pub use layer::GpuLayer;
#[cfg(feature = "gpu")]
pub use resident::{GpuGather, GpuTensor};
#[cfg(not(feature = "gpu"))]
pub use stub::{DeviceHierarchy, DeviceLevel, GpuContext, GpuEngine, GpuGather, GpuLayer, GpuTensor};
pub use tile::{TileShape, CHANNEL_STEP, CHUNKED_TILES};
pub use transfers::TransferCounts;

/// Whether this build has the GPU engine (the cargo feature `gpu`).
pub const BUILT: bool = cfg!(feature = "gpu");

/// An engine for the tests: `None`, after a message saying why, when no usable GPU exists
/// (or the crate was built without `gpu`), so that suites skip instead of failing.
pub fn test_engine(algorithm: semrecon_sparse::ConvAlgorithm) -> Option<GpuEngine> {
    match GpuEngine::new(algorithm) {
        Ok(e) => Some(e),
        Err(e) => {
            eprintln!("skipping a GPU test: {e}");
            None
        }
    }
}
