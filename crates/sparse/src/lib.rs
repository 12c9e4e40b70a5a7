//! Sparse 3D convolution on the CPU: the semantic network's core.
//!
//! A [`SparseTensor`] holds active voxels (`[x, y, z, batch]`) and row-major `f32` features.
//! A [`KernelMap`] lists, per kernel offset, which input row feeds which output row; it is
//! built once per level from coordinates ([`KernelMap::submanifold`],
//! [`KernelMap::downsample`], [`KernelMap::upsample`]) and shared by every layer, by the
//! backward pass and by every kernel. Three kernels compute forward, input-gradient and
//! weight-gradient passes with weights laid out `[K^3, c_in, c_out]`:
//!
//! - [`reference`](mod@reference): plain loops, the oracle of the tests;
//! - [`rulebook`]: the gather-GEMM-scatter baseline (the paper's Algorithm 1);
//! - [`chunked`]: the adaptive chunk-based kernel (Algorithm 2 for CPU caches), the fast path.
//!
//! [`ConvBackend`] is the one kernel interface of every engine: [`CpuEngine`] here, the GPU
//! engine in crate `semrecon-gpu`; the shared suite `backend_tests` (cargo feature
//! `test-suite`) holds each to the reference. [`ResidentBackend`] extends it with tensors the
//! engine owns (host vectors on the CPU, device buffers on a GPU) and the element-wise steps
//! of a network ([`elementwise`]), so that a whole network runs without leaving the device;
//! `resident_tests` is its shared suite.
//!
//! All kernels are deterministic: the same bits for any number of rayon threads.
//!
//! ```
//! use semrecon_sparse::{voxelize, ChunkConfig, ChunkedConv, KernelMap};
//!
//! // Points with RGB features, voxelised at 5 cm (voxels come out in Z-order).
//! let points = [[0.0, 0.0, 0.0], [0.06, 0.0, 0.0], [0.06, 0.05, 0.0]];
//! let rgb = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
//! let v = voxelize(&points, &rgb, 3, 0.05, 0)?;
//! let coords = v.tensor.coords();
//!
//! // One map and plan per level, shared by every 3x3x3 layer of that level.
//! let map = KernelMap::submanifold(coords, 3)?;
//! let conv = ChunkedConv::new(map, coords, coords, &ChunkConfig::default())?;
//! let w = vec![0.1f32; 27 * 3 * 8]; // [K^3, c_in, c_out]
//! let y = conv.forward(v.tensor.features(), 3, &w, 8)?;
//! assert_eq!(y.len(), coords.len() * 8);
//!
//! // Strided down to the coarser level and the transposed layer back up.
//! let (coarse, down_map) = KernelMap::downsample(coords)?;
//! let down = ChunkedConv::new(down_map, coords, &coarse, &ChunkConfig::default())?;
//! let up = down.transposed().expect("strided layers have a transpose");
//! assert_eq!(up.map().n_out(), coords.len());
//! # Ok::<(), semrecon_sparse::SparseError>(())
//! ```
#![warn(missing_docs)]

pub mod backend;
#[cfg(any(test, feature = "test-suite"))]
pub mod backend_tests;
pub mod bench;
mod block_index;
pub mod chunked;
pub mod elementwise;
pub mod error;
mod gemm;
pub mod hash_map;
pub mod kernel_map;
pub mod key;
pub mod morton;
pub mod reference;
pub mod resident;
#[cfg(any(test, feature = "test-suite"))]
pub mod resident_tests;
pub mod rulebook;
mod scatter;
pub mod tensor;
pub mod voxelize;

pub use backend::{BnRelu, ConvAlgorithm, ConvBackend, CpuEngine};
pub use chunked::{ChunkConfig, ChunkPlan, ChunkPlanArrays, ChunkedConv};
pub use elementwise::GatherTable;
pub use error::{Result, SparseError};
pub use gemm::{simd_level, SimdLevel};
pub use hash_map::{KeyHasher, VoxelHashMap};
pub use kernel_map::{KernelMap, MapKind};
pub use key::Coord;
pub use resident::ResidentBackend;
pub use tensor::SparseTensor;
pub use voxelize::{voxelize, Voxelization};

#[cfg(test)]
mod cpu_suite {
    //! The shared backend suite on the CPU engine, both algorithms.
    mod chunked {
        crate::backend_test_suite!(Some(crate::CpuEngine::new(crate::ConvAlgorithm::Chunked)));
    }
    mod rulebook {
        crate::backend_test_suite!(Some(crate::CpuEngine::new(crate::ConvAlgorithm::Rulebook)));
    }
    mod resident_chunked {
        crate::resident_test_suite!(Some(crate::CpuEngine::new(crate::ConvAlgorithm::Chunked)));
    }
    mod resident_rulebook {
        crate::resident_test_suite!(Some(crate::CpuEngine::new(crate::ConvAlgorithm::Rulebook)));
    }
}
