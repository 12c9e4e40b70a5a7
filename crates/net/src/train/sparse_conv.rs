//! The sparse convolution as one burn operation: a backend extension whose forward and
//! backward call the engine's chunked kernels ([`ChunkedConv::forward`],
//! [`ChunkedConv::backward_input`], [`ChunkedConv::backward_weight`]) on the CPU `Flex`
//! backend, with a hand-written `Backward` for `Autodiff<Flex>`. A loop of per-offset burn
//! gathers, matmuls and scatters would compute the same thing at a fraction of the speed and
//! with 27 graph nodes per layer.
//!
//! The layer geometry (kernel map and chunk plans) travels with the call as a [`ConvLayer`]:
//! a shared handle on the input's [`NetGeometry`] and the layer's place in it.

use std::sync::Arc;

use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::autodiff::Autodiff;
use burn::backend::flex::FlexTensor;
use burn::backend::tensor::FloatTensor;
use burn::backend::{backend_extension, Backend, Dispatch, Flex};
use burn::tensor::{Tensor, TensorData};
use semrecon_sparse::ChunkedConv;

use crate::geometry::NetGeometry;

/// Which convolution of a [`NetGeometry`] a layer uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ConvSite {
    /// The 3x3x3 submanifold convolution of a level.
    Submanifold(usize),
    /// The strided convolution from a level to the next coarser one.
    Down(usize),
    /// The transposed convolution from level `i + 1` back to level `i`.
    Up(usize),
}

/// A convolution's geometry, cheap to clone: the shared geometry of the input and the site.
#[derive(Clone)]
pub struct ConvLayer {
    geometry: Arc<NetGeometry>,
    site: ConvSite,
}

impl std::fmt::Debug for ConvLayer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "ConvLayer({:?})", self.site)
    }
}

impl ConvLayer {
    /// The layer at `site` of `geometry`; `None` when the geometry has no such layer.
    pub fn new(geometry: Arc<NetGeometry>, site: ConvSite) -> Option<Self> {
        let ok = match site {
            ConvSite::Submanifold(i) => i < geometry.levels(),
            ConvSite::Down(i) | ConvSite::Up(i) => i < geometry.levels() && geometry.down(i).is_some(),
        };
        ok.then_some(Self { geometry, site })
    }

    /// The engine's layer.
    pub fn conv(&self) -> &ChunkedConv {
        let g = &self.geometry;
        let layer = match self.site {
            ConvSite::Submanifold(i) => Some(g.submanifold(i)),
            ConvSite::Down(i) => g.down(i),
            ConvSite::Up(i) => g.up(i),
        };
        // `new` checked that the site exists.
        layer.unwrap_or_else(|| unreachable!("ConvLayer site checked at construction"))
    }
}

/// The custom operation: `y = conv(x, w)` over a sparse layer.
#[backend_extension(Autodiff, Flex)]
pub trait SparseConvBackend: Backend {
    /// # Shapes
    /// `x`: `[n_in, c_in]`; `w`: `[K^3, c_in, c_out]`; result `[n_out, c_out]`.
    fn sparse_conv(x: FloatTensor<Self>, w: FloatTensor<Self>, layer: ConvLayer) -> FloatTensor<Self>;
}

/// Runs `f` on the `f32` values of `t` (copied only when not contiguous).
fn with_values<R>(t: &FlexTensor, f: impl FnOnce(&[f32]) -> R) -> R {
    match t.as_slice::<f32>() {
        Some(s) => f(s),
        None => {
            let c = t.to_contiguous();
            match c.as_slice::<f32>() {
                Some(s) => f(s),
                None => f(&c.into_data().try_to_vec::<f32>().unwrap_or_default()),
            }
        }
    }
}

fn dims(t: &FlexTensor) -> Vec<usize> {
    t.layout().shape().to_vec()
}

fn flex(values: Vec<f32>, shape: Vec<usize>) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(values, shape))
}

fn forward_values(x: &FlexTensor, w: &FlexTensor, layer: &ConvLayer) -> FlexTensor {
    let (xs, ws) = (dims(x), dims(w));
    let (c_in, c_out) = (ws[1], ws[2]);
    debug_assert_eq!(xs[1], c_in);
    let conv = layer.conv();
    let y = with_values(x, |xv| with_values(w, |wv| conv.forward(xv, c_in, wv, c_out)));
    // Shapes are set by the model from the configuration, never by user data.
    let y = y.unwrap_or_else(|e| panic!("sparse convolution {layer:?}: {e}"));
    flex(y, vec![conv.map().n_out(), c_out])
}

impl SparseConvBackend for Flex {
    fn sparse_conv(x: FloatTensor<Self>, w: FloatTensor<Self>, layer: ConvLayer) -> FloatTensor<Self> {
        forward_values(&x, &w, &layer)
    }
}

#[derive(Debug)]
struct SparseConvBackward;

impl Backward<Flex, 2> for SparseConvBackward {
    type State = (FlexTensor, FlexTensor, ConvLayer);

    fn backward(self, ops: Ops<Self::State, 2>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let [node_x, node_w] = ops.parents;
        let dy = grads.consume::<Flex>(&ops.node);
        let (x, w, layer) = ops.state;
        let ws = dims(&w);
        let (c_in, c_out) = (ws[1], ws[2]);
        let conv = layer.conv();
        if let Some(node) = node_x {
            let dx = with_values(&dy, |dyv| with_values(&w, |wv| conv.backward_input(dyv, c_out, wv, c_in)))
                .unwrap_or_else(|e| panic!("sparse convolution input gradient {layer:?}: {e}"));
            grads.register::<Flex>(node.id, flex(dx, vec![conv.map().n_in(), c_in]));
        }
        if let Some(node) = node_w {
            let dw = with_values(&x, |xv| with_values(&dy, |dyv| conv.backward_weight(xv, c_in, dyv, c_out)))
                .unwrap_or_else(|e| panic!("sparse convolution weight gradient {layer:?}: {e}"));
            grads.register::<Flex>(node.id, flex(dw, ws));
        }
    }
}

impl<C: CheckpointStrategy> SparseConvBackend for Autodiff<Flex, C> {
    fn sparse_conv(x: FloatTensor<Self>, w: FloatTensor<Self>, layer: ConvLayer) -> FloatTensor<Self> {
        match SparseConvBackward.prepare::<C>([x.node(), w.node()]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let (xp, wp) = (x.primitive().clone(), w.primitive().clone());
                let y = forward_values(&xp, &wp, &layer);
                prep.finish((xp, wp, layer), y)
            }
            OpsKind::UnTracked(prep) => {
                let y = forward_values(x.primitive(), w.primitive(), &layer);
                prep.finish(y)
            }
        }
    }
}

/// `y = conv(x, w)` on the layer's kernel map, differentiable in `x` and `w`.
///
/// # Shapes
/// `x`: `[n_in, c_in]`; `w`: `[K^3, c_in, c_out]`; result `[n_out, c_out]`.
pub fn sparse_conv(x: Tensor<2>, w: Tensor<3>, layer: &ConvLayer) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as SparseConvBackend>::sparse_conv(
        x.into_dispatch(),
        w.into_dispatch(),
        layer.clone(),
    ))
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use burn::tensor::Device;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use semrecon_sparse::{ChunkConfig, Coord};

    use super::*;
    use crate::config::NetConfig;

    fn random_coords(n: usize, seed: u64) -> Vec<Coord> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut set = std::collections::BTreeSet::new();
        while set.len() < n {
            set.insert([rng.random_range(0..6), rng.random_range(0..6), rng.random_range(0..4), 0]);
        }
        set.into_iter().collect()
    }

    fn values(t: Tensor<2>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().unwrap()
    }

    /// Loss `sum(y * r)` for a fixed random `r`, so every output element matters.
    fn loss(x: &[f32], w: &[f32], layer: &ConvLayer, ci: usize, co: usize, r: &[f32]) -> f64 {
        let y = layer.conv().forward(x, ci, w, co).unwrap();
        y.iter().zip(r).map(|(a, b)| f64::from(*a) * f64::from(*b)).sum()
    }

    #[test]
    fn gradients_match_finite_differences() {
        let coords = random_coords(60, 3);
        let cfg = NetConfig::new("t", 2, 2, 0.05);
        let geo = Arc::new(NetGeometry::build(coords, &cfg, &ChunkConfig::default()).unwrap());
        let device = Device::flex().autodiff();
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for site in [ConvSite::Submanifold(0), ConvSite::Down(0), ConvSite::Up(0)] {
            let layer = ConvLayer::new(geo.clone(), site).unwrap();
            let (ci, co) = (3usize, 4usize);
            let (n_in, n_out, kv) =
                (layer.conv().map().n_in(), layer.conv().map().n_out(), layer.conv().map().kernel_volume());
            let xv: Vec<f32> = (0..n_in * ci).map(|_| rng.random_range(-1.0..1.0)).collect();
            let wv: Vec<f32> = (0..kv * ci * co).map(|_| rng.random_range(-1.0..1.0)).collect();
            let r: Vec<f32> = (0..n_out * co).map(|_| rng.random_range(-1.0..1.0)).collect();
            let x = Tensor::<2>::from_data(TensorData::new(xv.clone(), [n_in, ci]), &device).require_grad();
            let w = Tensor::<3>::from_data(TensorData::new(wv.clone(), [kv, ci, co]), &device).require_grad();
            let rt = Tensor::<2>::from_data(TensorData::new(r.clone(), [n_out, co]), &device);
            let y = sparse_conv(x.clone(), w.clone(), &layer);
            assert_eq!(values(y.clone()), layer.conv().forward(&xv, ci, &wv, co).unwrap());
            let grads = (y * rt).sum().backward();
            let gx = x.grad(&grads).unwrap().into_data().try_to_vec::<f32>().unwrap();
            let gw = w.grad(&grads).unwrap().into_data().try_to_vec::<f32>().unwrap();
            let h = 1e-2f32;
            let check = |g: &[f32], which: usize| {
                for idx in (0..g.len()).step_by(g.len() / 23 + 1) {
                    let (mut xp, mut wp) = (xv.clone(), wv.clone());
                    let (mut xm, mut wm) = (xv.clone(), wv.clone());
                    if which == 0 {
                        xp[idx] += h;
                        xm[idx] -= h;
                    } else {
                        wp[idx] += h;
                        wm[idx] -= h;
                    }
                    let fd = (loss(&xp, &wp, &layer, ci, co, &r) - loss(&xm, &wm, &layer, ci, co, &r))
                        / (2.0 * f64::from(h));
                    assert!(
                        (fd - f64::from(g[idx])).abs() < 1e-2 * (1.0 + fd.abs()),
                        "{site:?} {which} {idx}: {fd} vs {}",
                        g[idx]
                    );
                }
            };
            check(&gx, 0);
            check(&gw, 1);
        }
    }
}
