//! Training of CBSCN with burn (feature `train`): the sparse convolution as a custom burn
//! operation on the engine's kernels ([`sparse_conv`]), the network with the tensor names of
//! [`crate::model`] ([`model`]), and the training loop ([`trainer`]).

pub mod model;
pub mod sparse_conv;
pub mod trainer;

pub use model::{BurnCbscn, Mode};
pub use trainer::{train, Progress, TrainOptions, TrainState};
