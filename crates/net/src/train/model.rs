//! CBSCN in burn, for training: the blocks of [`crate::model`] with the same tensor names,
//! built on the engine's sparse convolution as a custom burn operation
//! ([`super::sparse_conv`]) and burn's differentiable tensor operations for everything else
//! (batch norm, ReLU, linear layers, the attention fusion, trilinear upsampling as a gather
//! of 8 coarse rows and a weighted sum, whose gradient burn computes as a scatter-add).
//!
//! Parameters are kept as flat named tensors (one per entry of
//! [`crate::model::tensor_specs`]), so [`BurnCbscn::to_weights`] and
//! [`BurnCbscn::from_weights`] are plain copies and the trained weights run unchanged in the
//! fused [`crate::Segmenter`] (the parity test checks that both forwards agree).
//!
//! Batch norm: in [`Mode::Train`] every batch norm normalises with the batch statistics and
//! updates its running mean and (unbiased) variance with the given momentum, as PyTorch does;
//! in [`Mode::Eval`] it uses the running statistics, as the fused inference does.

use std::collections::BTreeMap;
use std::sync::Arc;

use burn::tensor::activation::{relu, sigmoid};
use burn::tensor::{Device, Int, Tensor, TensorData};

use crate::config::NetConfig;
use crate::error::{NetError, Result};
use crate::geometry::NetGeometry;
use crate::model::{bn_names, tensor_specs};
use crate::train::sparse_conv::{sparse_conv, ConvLayer, ConvSite};
use crate::weights::{Tensor as WTensor, Weights};

/// Batch-norm behaviour of a forward pass.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Mode {
    /// Batch statistics; running statistics updated with this momentum (PyTorch's 0.1).
    Train {
        /// Weight of the new batch in the running averages.
        momentum: f32,
    },
    /// Running statistics (inference).
    Eval,
}

/// A trainable parameter: flat values and the shape of its [`crate::model`] entry.
#[derive(Debug, Clone)]
struct Param {
    value: Tensor<1>,
    shape: Vec<usize>,
}

/// CBSCN with burn tensors (see the module documentation).
#[derive(Debug, Clone)]
pub struct BurnCbscn {
    config: NetConfig,
    device: Device,
    params: BTreeMap<String, Param>,
    /// `running_mean` / `running_var` buffers by full name.
    running: BTreeMap<String, Vec<f32>>,
}

impl BurnCbscn {
    /// The network with `weights` (checked against `config`) on `device`; parameters
    /// require gradients when `device` is an autodiff device.
    ///
    /// # Errors
    /// The errors of [`Weights::check`].
    pub fn from_weights(weights: &Weights, config: &NetConfig, device: &Device) -> Result<Self> {
        weights.check(config)?;
        let mut params = BTreeMap::new();
        let mut running = BTreeMap::new();
        for spec in tensor_specs(config) {
            let data = weights.get(&spec.name)?;
            if spec.role.is_parameter() {
                let t = Tensor::<1>::from_data(TensorData::new(data.to_vec(), [data.len()]), device);
                let t = if device.is_autodiff() { t.require_grad() } else { t };
                params.insert(spec.name, Param { value: t, shape: spec.shape });
            } else {
                running.insert(spec.name, data.to_vec());
            }
        }
        Ok(Self { config: config.clone(), device: device.clone(), params, running })
    }

    /// The configuration.
    pub fn config(&self) -> &NetConfig {
        &self.config
    }

    /// The device of the parameters.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// Current parameters and running statistics as [`Weights`].
    pub fn to_weights(&self) -> Weights {
        let mut tensors = BTreeMap::new();
        for spec in tensor_specs(&self.config) {
            let data = if spec.role.is_parameter() {
                self.params.get(&spec.name).map(|p| tensor_values(p.value.clone())).unwrap_or_default()
            } else {
                self.running.get(&spec.name).cloned().unwrap_or_default()
            };
            tensors.insert(spec.name, WTensor { shape: spec.shape, data });
        }
        Weights::from_tensors(tensors)
    }

    /// Names of the trainable parameters, in a fixed (sorted) order.
    pub fn parameter_names(&self) -> Vec<String> {
        self.params.keys().cloned().collect()
    }

    /// The gradient of every parameter after `loss.backward()` (zeros for parameters that
    /// did not take part), by name.
    pub fn gradients(&self, grads: &burn::tensor::Gradients) -> BTreeMap<String, Vec<f32>> {
        self.params
            .iter()
            .map(|(name, p)| {
                let n: usize = p.shape.iter().product();
                let g = p.value.grad(grads).map(tensor_values).unwrap_or_else(|| vec![0.0; n]);
                (name.clone(), g)
            })
            .collect()
    }

    /// Replaces the values of every parameter (for an optimiser step), keeping gradients on.
    ///
    /// # Errors
    /// [`NetError::InvalidInput`] for a missing name or a wrong length.
    pub fn set_parameters(&mut self, values: &BTreeMap<String, Vec<f32>>) -> Result<()> {
        for (name, p) in &mut self.params {
            let v = values.get(name).ok_or_else(|| NetError::InvalidInput(format!("no value for `{name}`")))?;
            let n: usize = p.shape.iter().product();
            if v.len() != n {
                return Err(NetError::InvalidInput(format!("`{name}`: {} values, expected {n}", v.len())));
            }
            let t = Tensor::<1>::from_data(TensorData::new(v.clone(), [n]), &self.device);
            p.value = if self.device.is_autodiff() { t.require_grad() } else { t };
        }
        Ok(())
    }

    fn param(&self, name: &str) -> Result<Tensor<1>> {
        self.params
            .get(name)
            .map(|p| p.value.clone())
            .ok_or_else(|| NetError::MissingTensor { file: "<burn model>".into(), tensor: name.to_string() })
    }

    fn matrix(&self, name: &str, rows: usize, cols: usize) -> Result<Tensor<2>> {
        Ok(self.param(name)?.reshape([rows, cols]))
    }

    fn kernel(&self, name: &str) -> Result<Tensor<3>> {
        let p = self
            .params
            .get(name)
            .ok_or_else(|| NetError::MissingTensor { file: "<burn model>".into(), tensor: name.to_string() })?;
        let s = &p.shape;
        Ok(p.value.clone().reshape([s[0], s[1], s[2]]))
    }

    /// Batch norm and ReLU of `x` (`[n, c]`) with the parameters under `prefix`.
    fn bn_relu(&mut self, x: Tensor<2>, prefix: &str, mode: Mode) -> Result<Tensor<2>> {
        let [g, b, m, v] = bn_names(prefix);
        let c = x.dims()[1];
        let n = x.dims()[0];
        let gamma = self.param(&g)?.reshape([1, c]);
        let beta = self.param(&b)?.reshape([1, c]);
        let eps = self.config.bn_eps;
        let normalised = match mode {
            Mode::Train { momentum } if n > 0 => {
                let mean = x.clone().mean_dim(0);
                let centred = x - mean.clone();
                let var = centred.clone().powi_scalar(2).mean_dim(0);
                // Running statistics: detached values, unbiased variance.
                let (mv, vv) =
                    (tensor_values(mean.detach().reshape([c])), tensor_values(var.clone().detach().reshape([c])));
                let unbias = if n > 1 { n as f32 / (n - 1) as f32 } else { 1.0 };
                if let Some(rm) = self.running.get_mut(&m) {
                    rm.iter_mut().zip(&mv).for_each(|(r, x)| *r = (1.0 - momentum) * *r + momentum * x);
                }
                if let Some(rv) = self.running.get_mut(&v) {
                    rv.iter_mut().zip(&vv).for_each(|(r, x)| *r = (1.0 - momentum) * *r + momentum * x * unbias);
                }
                centred / (var + eps).sqrt()
            }
            _ => {
                let rm = self.running.get(&m).cloned().unwrap_or_else(|| vec![0.0; c]);
                let rv = self.running.get(&v).cloned().unwrap_or_else(|| vec![1.0; c]);
                let inv: Vec<f32> = rv.iter().map(|v| 1.0 / (v + eps).sqrt()).collect();
                let rm = Tensor::<2>::from_data(TensorData::new(rm, [1, c]), &self.device);
                let inv = Tensor::<2>::from_data(TensorData::new(inv, [1, c]), &self.device);
                (x - rm) * inv
            }
        };
        Ok(relu(normalised * gamma + beta))
    }

    /// `x + conv2(BN(conv1(BN(x))))` on the submanifold layer of `level`.
    fn res_block(&mut self, x: Tensor<2>, prefix: &str, layer: &ConvLayer, mode: Mode) -> Result<Tensor<2>> {
        let h = self.bn_relu(x.clone(), &format!("{prefix}.bn1"), mode)?;
        let h = sparse_conv(h, self.kernel(&format!("{prefix}.conv1.weight"))?, layer);
        let h = self.bn_relu(h, &format!("{prefix}.bn2"), mode)?;
        let h = sparse_conv(h, self.kernel(&format!("{prefix}.conv2.weight"))?, layer);
        Ok(x + h)
    }

    /// Class scores of every voxel of `geometry` (`features` in the order of
    /// `geometry.coords(0)`).
    ///
    /// # Shapes
    /// `features`: `[n, in_channels]`; result `[n, classes]`.
    ///
    /// # Errors
    /// [`NetError::InvalidInput`] for a geometry of another depth or mismatched features.
    pub fn forward(&mut self, geometry: &Arc<NetGeometry>, features: Tensor<2>, mode: Mode) -> Result<Tensor<2>> {
        let l = self.config.levels;
        let n = geometry.coords(0).len();
        if geometry.levels() != l || features.dims() != [n, self.config.in_channels] {
            return Err(NetError::InvalidInput(format!(
                "geometry of {} levels and features {:?} for {} voxels, network {}",
                geometry.levels(),
                features.dims(),
                n,
                self.config.summary()
            )));
        }
        let cfg = self.config.clone();
        let c = |i: usize| cfg.channels(i);
        let layer = |site: ConvSite| {
            ConvLayer::new(geometry.clone(), site)
                .ok_or_else(|| NetError::InvalidInput(format!("geometry has no layer {site:?}")))
        };
        let subm: Vec<ConvLayer> = (0..l).map(|i| layer(ConvSite::Submanifold(i))).collect::<Result<_>>()?;

        let x0 = sparse_conv(features, self.kernel("input.conv.weight")?, &subm[0]);
        let mut enc = vec![self.res_block(x0, "extract.0", &subm[0], mode)?];
        for i in 1..l {
            let h = self.bn_relu(enc[i - 1].clone(), &format!("down.{}.bn", i - 1), mode)?;
            let h =
                sparse_conv(h, self.kernel(&format!("down.{}.conv.weight", i - 1))?, &layer(ConvSite::Down(i - 1))?);
            enc.push(self.res_block(h, &format!("extract.{i}"), &subm[i], mode)?);
        }
        let mut dec: Vec<Option<Tensor<2>>> = vec![None; l];
        dec[l - 1] = enc.pop();
        for t in (0..l.saturating_sub(1)).rev() {
            let above = dec[t + 1].clone().ok_or_else(|| NetError::InvalidInput("missing decoder level".into()))?;
            let h = self.bn_relu(above, &format!("up.{t}.bn"), mode)?;
            let up = sparse_conv(h, self.kernel(&format!("up.{t}.conv.weight"))?, &layer(ConvSite::Up(t))?);
            let skip = enc[t].clone().matmul(self.matrix(&format!("up.{t}.skip.weight"), c(t), c(t))?);
            let mut d = self.res_block(up + skip, &format!("up.{t}"), &subm[t], mode)?;
            for (j, dj) in dec.iter().enumerate().take(l.saturating_sub(1)).skip(t + 1) {
                let dj = dj.clone().ok_or_else(|| NetError::InvalidInput("missing decoder level".into()))?;
                let att =
                    sigmoid(dj.clone().matmul(self.matrix(&format!("fuse.{t}.{j}.attention.weight"), c(j), 1)?));
                let val = dj.matmul(self.matrix(&format!("fuse.{t}.{j}.value.weight"), c(j), c(t))?) * att;
                d = d + self.upsample(geometry, val, t, j)?;
            }
            dec[t] = Some(d);
        }
        let d0 = dec[0].take().ok_or_else(|| NetError::InvalidInput("missing decoder level".into()))?;
        let h = self.bn_relu(d0, "head.bn", mode)?;
        let k = self.config.classes;
        let bias = self.param("head.linear.bias")?.reshape([1, k]);
        Ok(h.matmul(self.matrix("head.linear.weight", c(0), k)?) + bias)
    }

    /// Trilinear upsampling of `values` (`[n_j, ch]`) from level `j` to level `t`: a gather
    /// of the 8 interpolation rows per fine voxel and their weighted sum.
    fn upsample(&self, geometry: &NetGeometry, values: Tensor<2>, t: usize, j: usize) -> Result<Tensor<2>> {
        let (rows, weights) = geometry
            .interpolation(t, j)
            .ok_or_else(|| NetError::InvalidInput(format!("no interpolation table from level {j} to {t}")))?;
        let n = rows.len() / 8;
        let ch = values.dims()[1];
        let idx = Tensor::<1, Int>::from_data(
            TensorData::new(rows.iter().map(|&r| i64::from(r)).collect::<Vec<_>>(), [rows.len()]),
            &self.device,
        );
        let w = Tensor::<3>::from_data(TensorData::new(weights.to_vec(), [n, 8, 1]), &self.device);
        let gathered = values.select(0, idx).reshape([n, 8, ch]);
        Ok((gathered * w).sum_dim(1).reshape([n, ch]))
    }
}

/// The `f32` values of a tensor (any device).
pub(crate) fn tensor_values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().convert::<f32>().try_into_vec::<f32>().unwrap_or_default()
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use semrecon_sparse::{ChunkConfig, Coord};

    use super::*;
    use crate::Segmenter;

    /// A random blob of surface-like voxels (a few slabs), Z-ordered by the engine later.
    fn random_room(seed: u64) -> (Vec<Coord>, Vec<f32>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut set = std::collections::BTreeSet::new();
        for x in 0..24 {
            for y in 0..20 {
                set.insert([x, y, 0, 0]);
                if rng.random_bool(0.3) {
                    set.insert([x, y, rng.random_range(1..12), 0]);
                }
            }
        }
        for z in 0..12 {
            for x in 0..24 {
                set.insert([x, 0, z, 0]);
            }
        }
        let coords: Vec<Coord> = set.into_iter().collect();
        let order = semrecon_sparse::morton::morton_order(&coords).unwrap();
        let coords: Vec<Coord> = order.iter().map(|&r| coords[r as usize]).collect();
        let feats = (0..coords.len() * 3).map(|_| rng.random_range(-1.0..1.0)).collect();
        (coords, feats)
    }

    #[test]
    fn eval_forward_matches_the_fused_segmenter_and_weights_round_trip() {
        let cfg = NetConfig::new("tiny", 3, 8, 0.05);
        for seed in 0..2 {
            let mut weights = Weights::random(&cfg, seed);
            weights.perturb_normalisation(seed + 10);
            let (coords, feats) = random_room(seed);
            let geo = Arc::new(NetGeometry::build(coords.clone(), &cfg, &ChunkConfig::default()).unwrap());
            for device in [Device::flex(), Device::flex().autodiff()] {
                let mut net = BurnCbscn::from_weights(&weights, &cfg, &device).unwrap();
                let x = Tensor::<2>::from_data(TensorData::new(feats.clone(), [coords.len(), 3]), &device);
                let ours = tensor_values(net.forward(&geo, x, Mode::Eval).unwrap());
                let exported = net.to_weights();
                assert_eq!(exported.tensors(), weights.tensors());
                let mut seg = Segmenter::new(exported, cfg.clone()).unwrap();
                let fused = seg.segment(&coords, &feats).unwrap();
                let worst = ours.iter().zip(&fused).map(|(a, b)| (a - b).abs() / (1.0 + b.abs())).fold(0.0, f32::max);
                assert!(worst < 1e-4, "seed {seed}: {worst}");
            }
        }
    }

    #[test]
    fn training_mode_updates_running_statistics() {
        let cfg = NetConfig::new("tiny", 3, 4, 0.05);
        let weights = Weights::random(&cfg, 1);
        let (coords, feats) = random_room(3);
        let geo = Arc::new(NetGeometry::build(coords.clone(), &cfg, &ChunkConfig::default()).unwrap());
        let device = Device::flex().autodiff();
        let mut net = BurnCbscn::from_weights(&weights, &cfg, &device).unwrap();
        let x = Tensor::<2>::from_data(TensorData::new(feats, [coords.len(), 3]), &device);
        let y = net.forward(&geo, x, Mode::Train { momentum: 0.1 }).unwrap();
        let grads = y.powi_scalar(2).mean().backward();
        let g = net.gradients(&grads);
        assert!(g["input.conv.weight"].iter().any(|v| *v != 0.0));
        assert!(g["fuse.0.1.attention.weight"].iter().any(|v| *v != 0.0));
        let after = net.to_weights();
        assert_ne!(
            after.get("extract.0.bn1.running_mean").unwrap(),
            weights.get("extract.0.bn1.running_mean").unwrap()
        );
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod timing {
    use std::time::Instant;

    use semrecon_sparse::ChunkConfig;

    use super::*;
    use crate::dataset::{load_sample, DataSource};

    /// Time of one training step of `s20` on a synthetic room against the time of its
    /// convolutions alone (engine kernels, forward + both gradients): the share of burn's
    /// other operations. Run with `cargo test --release --features train -- --ignored
    /// step_time_breakdown --nocapture`.
    #[test]
    #[ignore = "timing, prints numbers"]
    fn step_time_breakdown() {
        let cfg = NetConfig::s20();
        let room = &DataSource::parse("synth:5..6").unwrap().rooms().unwrap()[0];
        let s = load_sample(room, cfg.voxel_size, None, 0).unwrap();
        let n = s.len();
        let geo = Arc::new(NetGeometry::build(s.coords.clone(), &cfg, &ChunkConfig::default()).unwrap());
        let device = Device::flex().autodiff();
        let mut net = BurnCbscn::from_weights(&Weights::random(&cfg, 0), &cfg, &device).unwrap();
        let mut best = (f64::MAX, f64::MAX, f64::MAX);
        for _ in 0..3 {
            let t0 = Instant::now();
            let x = Tensor::<2>::from_data(TensorData::new(s.features.clone(), [n, 3]), &device);
            let y = net.forward(&geo, x, Mode::Train { momentum: 0.1 }).unwrap();
            let loss = y.powi_scalar(2).mean();
            let _ = tensor_values(loss.clone().detach());
            let t1 = Instant::now();
            let grads = loss.backward();
            let _ = net.gradients(&grads);
            let t2 = Instant::now();
            // The same convolutions on the engine alone.
            let mut conv = 0.0;
            for i in 0..cfg.levels {
                let c = cfg.channels(i);
                let rows = geo.coords(i).len();
                let x = vec![0.5f32; rows * c];
                let w = vec![0.01f32; 27 * c * c];
                let layer = geo.submanifold(i);
                let reps = if i + 1 < cfg.levels { 4.0 } else { 2.0 };
                let t = Instant::now();
                let y = layer.forward(&x, c, &w, c).unwrap();
                let _ = layer.backward_input(&y, c, &w, c).unwrap();
                let _ = layer.backward_weight(&x, c, &y, c).unwrap();
                conv += t.elapsed().as_secs_f64() * reps;
            }
            best.0 = best.0.min((t1 - t0).as_secs_f64());
            best.1 = best.1.min((t2 - t1).as_secs_f64());
            best.2 = best.2.min(conv);
        }
        println!(
            "s20, {n} voxels: forward {:.3} s, backward {:.3} s; 3x3x3 convolutions alone (engine, fwd+bwd) {:.3} s",
            best.0, best.1, best.2
        );
        // Single burn operations at level 0 (32 channels), forward + backward.
        let c = cfg.channels(0);
        let x = || Tensor::<2>::from_data(TensorData::new(vec![0.3f32; n * c], [n, c]), &device).require_grad();
        let t = Instant::now();
        let mut bn = BurnCbscn::from_weights(&Weights::random(&cfg, 0), &cfg, &device).unwrap();
        let y = bn.bn_relu(x(), "extract.0.bn1", Mode::Train { momentum: 0.1 }).unwrap();
        let _ = y.sum().backward();
        let t_bn = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let coarse = geo.coords(1).len();
        let v = Tensor::<2>::from_data(TensorData::new(vec![0.3f32; coarse * c], [coarse, c]), &device).require_grad();
        let y = net.upsample(&geo, v, 0, 1).unwrap();
        let _ = y.sum().backward();
        let t_up = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let w = Tensor::<2>::from_data(TensorData::new(vec![0.1f32; c * c], [c, c]), &device).require_grad();
        let _ = x().matmul(w).sum().backward();
        let t_mm = t.elapsed().as_secs_f64();
        println!(
            "burn ops at level 0 ([{n}, {c}]), fwd+bwd: batch norm + ReLU {t_bn:.3} s, trilinear upsampling (gather 8 rows + weighted sum) {t_up:.3} s, linear {c}x{c} {t_mm:.3} s"
        );
    }
}
