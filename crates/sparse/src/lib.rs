//! Sparse 3D convolution on the CPU: the semantic network's core.
//!
//! A [`SparseTensor`] holds active voxels (`[x, y, z, batch]`) and row-major `f32` features.
//! A [`KernelMap`] lists, per kernel offset, which input row feeds which output row; it is
//! built once per level from coordinates ([`KernelMap::submanifold`],
//! [`KernelMap::downsample`], [`KernelMap::upsample`]) and shared by every layer, by the
//! backward pass and by every kernel. Three kernels compute forward, input-gradient and
//! weight-gradient passes with weights laid out `[K^3, c_in, c_out]`:
//!
//! - [`reference`]: plain loops, the oracle of the tests;
//! - [`rulebook`]: the gather-GEMM-scatter baseline (the paper's Algorithm 1);
//! - [`chunked`]: the adaptive chunk-based kernel (Algorithm 2 for CPU caches), the fast path.
//!
//! All kernels are deterministic: the same bits for any number of rayon threads.
#![warn(missing_docs)]

pub mod bench;
pub mod chunked;
pub mod error;
mod gemm;
pub mod hash_map;
pub mod kernel_map;
pub mod key;
pub mod morton;
pub mod reference;
pub mod rulebook;
mod scatter;
pub mod tensor;
pub mod voxelize;

pub use chunked::{ChunkConfig, ChunkPlan, ChunkPlanArrays, ChunkedConv};
pub use error::{Result, SparseError};
pub use gemm::{simd_level, SimdLevel};
pub use hash_map::{KeyHasher, VoxelHashMap};
pub use kernel_map::{KernelMap, MapKind};
pub use key::Coord;
pub use tensor::SparseTensor;
pub use voxelize::{voxelize, Voxelization};
