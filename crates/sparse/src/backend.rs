//! One kernel interface for every sparse-convolution engine: [`ConvBackend`].
//!
//! The CPU engine ([`CpuEngine`], this crate) and the GPU engine (crate `semrecon-gpu`) both
//! implement it, and one shared test suite (`backend_tests`, cargo feature `test-suite`)
//! checks any implementation against the plain [`reference`](crate::reference) kernels. Code
//! above the engines (the network, the benchmarks) is written once against the trait, never
//! with a branch per device: a new engine only has to pass the suite.
//!
//! Layers are prepared once per voxel set ([`ConvBackend::submanifold`],
//! [`ConvBackend::downsample`], [`ConvBackend::upsample`]) and then run any number of times
//! with different weights and channel counts, as the network does per level. Feature and
//! weight buffers cross the interface as host slices in the layouts of the rest of the crate
//! (rows x channels, weights `[K^3, c_in, c_out]`), so every engine is checked on exactly the
//! same data; an engine keeps its own device copies of layer geometry between calls.

use crate::chunked::{ChunkConfig, ChunkedConv};
use crate::error::{Result, SparseError};
use crate::kernel_map::{check_weights, KernelMap};
use crate::key::Coord;
use crate::rulebook;
use crate::tensor::check_rows;

/// Which algorithm an engine runs its convolutions with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ConvAlgorithm {
    /// The adaptive chunk-based kernel (the paper's Algorithm 2): the fast path.
    #[default]
    Chunked,
    /// Gather-GEMM-scatter per kernel offset (the paper's Algorithm 1): the baseline.
    Rulebook,
}

impl ConvAlgorithm {
    /// Lower-case name (`chunked`, `rulebook`) for tables and logs.
    pub fn name(self) -> &'static str {
        match self {
            Self::Chunked => "chunked",
            Self::Rulebook => "rulebook",
        }
    }
}

/// A folded batch norm and ReLU applied to a convolution's input: `max(0, x * scale + shift)`
/// per channel.
///
/// # Shapes
/// `scale`, `shift`: `[c_in]`.
#[derive(Debug, Clone, Copy)]
pub struct BnRelu<'a> {
    /// Per-channel factor.
    pub scale: &'a [f32],
    /// Per-channel offset.
    pub shift: &'a [f32],
}

/// A sparse-convolution engine: prepares layer geometry and runs the three passes of a layer.
///
/// Every method checks its buffers and returns an error on mismatched shapes; none panics on
/// caller data. Results must match the [`reference`](crate::reference) kernels to 1e-4 of the
/// output's largest magnitude (the shared suite's tolerance).
pub trait ConvBackend {
    /// A prepared layer: kernel map and whatever the engine derives from it (chunk plans,
    /// device buffers).
    type Layer;
    /// The engine's error; every [`SparseError`] converts into it.
    type Error: std::error::Error + From<SparseError> + Send + Sync + 'static;

    /// A short name for logs and tables, such as `cpu-chunked`.
    fn name(&self) -> String;

    /// The submanifold layer of a voxel set with an odd `kernel_size` (output set = input set).
    ///
    /// # Errors
    /// Even or too large kernels, coordinates out of range, duplicate coordinates.
    fn submanifold(&self, coords: &[Coord], kernel_size: usize) -> Result<Self::Layer, Self::Error>;

    /// The coarse set `{floor(u / 2)}` of `fine` (Z-order when `fine` is) and the strided layer
    /// (K = 2, stride 2) from `fine` to it.
    ///
    /// # Errors
    /// Coordinates out of range, duplicates.
    fn downsample(&self, fine: &[Coord]) -> Result<(Vec<Coord>, Self::Layer), Self::Error>;

    /// The transposed layer (K = 2, stride 2) from `coarse` back to `fine`.
    ///
    /// # Errors
    /// A fine voxel whose parent is not in `coarse`, range errors, duplicates.
    fn upsample(&self, coarse: &[Coord], fine: &[Coord]) -> Result<Self::Layer, Self::Error>;

    /// Rows of a layer's input and output sets.
    fn layer_rows(&self, layer: &Self::Layer) -> (usize, usize);

    /// Forward pass: `y = conv(bn_relu(x), w)`, or with `accumulate` `y += ...` (a residual
    /// sum); `bn` `None` reads `x` as it is.
    ///
    /// # Shapes
    /// `x`: `[n_in, c_in]`; `w`: `[K^3, c_in, c_out]`; `y`: `[n_out, c_out]`.
    ///
    /// # Errors
    /// Mismatched buffers; device errors of the engine.
    #[allow(clippy::too_many_arguments)]
    fn forward_into(
        &self,
        layer: &Self::Layer,
        x: &[f32],
        c_in: usize,
        bn: Option<BnRelu<'_>>,
        w: &[f32],
        c_out: usize,
        y: &mut [f32],
        accumulate: bool,
    ) -> Result<(), Self::Error>;

    /// Forward pass into a new buffer.
    ///
    /// # Shapes
    /// `x`: `[n_in, c_in]`; `w`: `[K^3, c_in, c_out]`; result `[n_out, c_out]`.
    ///
    /// # Errors
    /// As [`Self::forward_into`].
    fn forward(
        &self,
        layer: &Self::Layer,
        x: &[f32],
        c_in: usize,
        w: &[f32],
        c_out: usize,
    ) -> Result<Vec<f32>, Self::Error> {
        let mut y = vec![0f32; self.layer_rows(layer).1 * c_out];
        self.forward_into(layer, x, c_in, None, w, c_out, &mut y, false)?;
        Ok(y)
    }

    /// Input gradient.
    ///
    /// # Shapes
    /// `dy`: `[n_out, c_out]`; `w`: `[K^3, c_in, c_out]`; result `[n_in, c_in]`.
    ///
    /// # Errors
    /// As [`Self::forward_into`].
    fn backward_input(
        &self,
        layer: &Self::Layer,
        dy: &[f32],
        c_out: usize,
        w: &[f32],
        c_in: usize,
    ) -> Result<Vec<f32>, Self::Error>;

    /// Weight gradient.
    ///
    /// # Shapes
    /// `x`: `[n_in, c_in]`; `dy`: `[n_out, c_out]`; result `[K^3, c_in, c_out]`.
    ///
    /// # Errors
    /// As [`Self::forward_into`].
    fn backward_weight(
        &self,
        layer: &Self::Layer,
        x: &[f32],
        c_in: usize,
        dy: &[f32],
        c_out: usize,
    ) -> Result<Vec<f32>, Self::Error>;
}

/// Checks the buffers of a forward call against a layer of `kv` offsets and `(n_in, n_out)`
/// rows; shared by every engine so that all report the same errors.
///
/// # Errors
/// [`SparseError::FeatureShape`] / [`SparseError::WeightShape`].
#[allow(clippy::too_many_arguments)]
pub fn check_forward(
    kv: usize,
    rows: (usize, usize),
    x: &[f32],
    c_in: usize,
    bn: Option<BnRelu<'_>>,
    w: &[f32],
    c_out: usize,
    y: &[f32],
) -> Result<()> {
    check_rows("x", x, rows.0, c_in)?;
    check_weights(w, kv, c_in, c_out)?;
    check_rows("y", y, rows.1, c_out)?;
    if let Some(bn) = bn {
        check_rows("scale", bn.scale, 1, c_in)?;
        check_rows("shift", bn.shift, 1, c_in)?;
    }
    Ok(())
}

/// The CPU engine: [`ChunkedConv`] layers run with the chunked or the rulebook kernels.
#[derive(Debug, Clone, Copy, Default)]
pub struct CpuEngine {
    /// The algorithm of every convolution.
    pub algorithm: ConvAlgorithm,
    /// How outputs are cut into chunks.
    pub chunk: ChunkConfig,
}

impl CpuEngine {
    /// The engine running `algorithm` with the default chunk configuration.
    pub fn new(algorithm: ConvAlgorithm) -> Self {
        Self { algorithm, chunk: ChunkConfig::default() }
    }
}

impl ConvBackend for CpuEngine {
    type Layer = ChunkedConv;
    type Error = SparseError;

    fn name(&self) -> String {
        format!("cpu-{}", self.algorithm.name())
    }

    fn submanifold(&self, coords: &[Coord], kernel_size: usize) -> Result<ChunkedConv> {
        ChunkedConv::submanifold(coords, kernel_size, &self.chunk)
    }

    fn downsample(&self, fine: &[Coord]) -> Result<(Vec<Coord>, ChunkedConv)> {
        let (coarse, map) = KernelMap::downsample(fine)?;
        let layer = ChunkedConv::new(map, fine, &coarse, &self.chunk)?;
        Ok((coarse, layer))
    }

    fn upsample(&self, coarse: &[Coord], fine: &[Coord]) -> Result<ChunkedConv> {
        ChunkedConv::new(KernelMap::upsample(coarse, fine)?, coarse, fine, &self.chunk)
    }

    fn layer_rows(&self, layer: &ChunkedConv) -> (usize, usize) {
        (layer.n_in(), layer.n_out())
    }

    fn forward_into(
        &self,
        layer: &ChunkedConv,
        x: &[f32],
        c_in: usize,
        bn: Option<BnRelu<'_>>,
        w: &[f32],
        c_out: usize,
        y: &mut [f32],
        accumulate: bool,
    ) -> Result<()> {
        let kv = layer.forward_plan().kernel_volume();
        check_forward(kv, (layer.n_in(), layer.n_out()), x, c_in, bn, w, c_out, y)?;
        match (self.algorithm, bn) {
            (ConvAlgorithm::Chunked, Some(bn)) => {
                layer.forward_bn_relu_into(x, c_in, bn.scale, bn.shift, w, c_out, y, accumulate)
            }
            (ConvAlgorithm::Chunked, None) if !accumulate => layer.forward_into(x, c_in, w, c_out, y),
            (ConvAlgorithm::Chunked, None) => {
                // A residual sum without a batch norm (no fused form: the fused read applies
                // a ReLU): a plain forward into scratch, then the sum.
                with_scratch(y.len(), |t| {
                    layer.forward_into(x, c_in, w, c_out, t)?;
                    y.iter_mut().zip(t.iter()).for_each(|(a, b)| *a += b);
                    Ok(())
                })
            }
            (ConvAlgorithm::Rulebook, _) => {
                // The standard algorithm: the batch norm is a separate pass before the gather.
                with_buffer(&NORMALISED, |normalised| {
                    let src = match bn {
                        Some(bn) => {
                            apply_bn_relu_into(x, bn, normalised);
                            &normalised[..]
                        }
                        None => x,
                    };
                    if accumulate {
                        with_scratch(y.len(), |t| {
                            rulebook::forward_into(layer.map(), src, c_in, w, c_out, t)?;
                            y.iter_mut().zip(t.iter()).for_each(|(a, b)| *a += b);
                            Ok(())
                        })
                    } else {
                        rulebook::forward_into(layer.map(), src, c_in, w, c_out, y)
                    }
                })
            }
        }
    }

    fn backward_input(
        &self,
        layer: &ChunkedConv,
        dy: &[f32],
        c_out: usize,
        w: &[f32],
        c_in: usize,
    ) -> Result<Vec<f32>> {
        match self.algorithm {
            ConvAlgorithm::Chunked => layer.backward_input(dy, c_out, w, c_in),
            ConvAlgorithm::Rulebook => rulebook::backward_input(layer.map(), dy, c_out, w, c_in),
        }
    }

    fn backward_weight(
        &self,
        layer: &ChunkedConv,
        x: &[f32],
        c_in: usize,
        dy: &[f32],
        c_out: usize,
    ) -> Result<Vec<f32>> {
        match self.algorithm {
            ConvAlgorithm::Chunked => layer.backward_weight(x, c_in, dy, c_out),
            ConvAlgorithm::Rulebook => rulebook::backward_weight(layer.map(), x, c_in, dy, c_out),
        }
    }
}

thread_local! {
    /// The normalised input of the rulebook path, kept between calls: a fresh buffer per
    /// layer costs page faults the baseline should not pay.
    static NORMALISED: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
    /// Products before a residual sum, kept between calls for the same reason.
    static SCRATCH: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Runs `f` with this thread's buffer `key`, taken out for the call: a nested call on the same
/// thread (rayon runs other jobs while it waits) gets an empty buffer instead of a conflict.
fn with_buffer<R>(
    key: &'static std::thread::LocalKey<std::cell::RefCell<Vec<f32>>>,
    f: impl FnOnce(&mut Vec<f32>) -> R,
) -> R {
    let mut v = key.with(|c| std::mem::take(&mut *c.borrow_mut()));
    let r = f(&mut v);
    key.with(|c| *c.borrow_mut() = v);
    r
}

/// Runs `f` with this thread's scratch buffer cut to `len` values.
fn with_scratch<R>(len: usize, f: impl FnOnce(&mut [f32]) -> R) -> R {
    with_buffer(&SCRATCH, |s| {
        if s.len() < len {
            s.resize(len, 0.0);
        }
        f(&mut s[..len])
    })
}

/// `max(0, x * scale + shift)` per row into a new buffer (the separate normalisation pass).
///
/// # Shapes
/// `x`: `[n, c]` with `c = bn.scale.len()`; result the same.
pub fn apply_bn_relu(x: &[f32], bn: BnRelu<'_>) -> Vec<f32> {
    let mut out = Vec::new();
    apply_bn_relu_into(x, bn, &mut out);
    out
}

/// [`apply_bn_relu`] into `out` (resized to `x`), rows in parallel.
fn apply_bn_relu_into(x: &[f32], bn: BnRelu<'_>, out: &mut Vec<f32>) {
    use rayon::prelude::*;
    let c = bn.scale.len().max(1);
    out.resize(x.len(), 0.0);
    out.par_chunks_mut(c * 256).zip(x.par_chunks(c * 256)).for_each(|(d, s)| {
        for (dr, sr) in d.chunks_mut(c).zip(s.chunks(c)) {
            for (((v, x), s), b) in dr.iter_mut().zip(sr).zip(bn.scale).zip(bn.shift) {
                *v = (x * s + b).max(0.0);
            }
        }
    });
}
