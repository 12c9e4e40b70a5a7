//! The fused CPU forward of CBSCN on the sparse engine, for the live path (no training
//! framework involved).
//!
//! Per input, the [`NetGeometry`] is built once (kernel maps and chunk plans per level, shared
//! by every layer of the level, and the fusion's interpolation tables). Batch norm uses the
//! running statistics folded into one scale and shift per channel, applied together with the
//! ReLU: with the chunked kernels inside the convolution's gather (and residual sums inside
//! its output), with the rulebook kernels in a separate pass as the standard algorithm does. Activation buffers live in a workspace that only grows, so repeated
//! calls on rooms of similar size allocate nothing per layer.
//!
//! Voxels are processed in Z-order (the layout the chunked kernel is fastest with); inputs in
//! any other order are permuted on the way in and the logits back on the way out. Every step
//! is deterministic: the same bits for any number of rayon threads.

use std::time::{Duration, Instant};

use rayon::prelude::*;
use semrecon_gpu::{GpuEngine, GpuLayer};
use semrecon_sparse::morton::morton_order;
use semrecon_sparse::{voxelize, BnRelu, ChunkConfig, ChunkedConv, ConvAlgorithm, ConvBackend, Coord, CpuEngine};

use crate::config::NetConfig;
use crate::error::{NetError, Result};
use crate::geometry::{Interp, NetGeometry};
use crate::model::{bn_names, LevelStats};
use crate::weights::Weights;

/// Rows per parallel task in the element-wise passes.
const ROWS_PER_TASK: usize = 256;

/// Input features of colours: `c / 127.5 - 1` per channel (RGB in `[-1, 1]`), the
/// preprocessing every trainer and caller of the network must share.
///
/// # Shapes
/// Result `[n, 3]` row-major.
pub fn color_features(colors: &[[u8; 3]]) -> Vec<f32> {
    colors.iter().flat_map(|c| c.map(|v| f32::from(v) / 127.5 - 1.0)).collect()
}

/// Which engine kernel runs the convolutions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ConvKernel {
    /// The adaptive chunk-based kernel (the fast path).
    #[default]
    Chunked,
    /// The gather-GEMM-scatter baseline on the same kernel maps (for comparisons).
    Rulebook,
}

/// Batch norm with running statistics, folded: `y = max(0, x * scale + shift)`.
#[derive(Debug, Clone)]
struct Affine {
    scale: Vec<f32>,
    shift: Vec<f32>,
}

impl Affine {
    fn fold(w: &Weights, prefix: &str, eps: f32) -> Result<Self> {
        let [g, b, m, v] = bn_names(prefix);
        let (g, b, m, v) = (w.get(&g)?, w.get(&b)?, w.get(&m)?, w.get(&v)?);
        let scale: Vec<f32> = g.iter().zip(v).map(|(g, v)| g / (v + eps).sqrt()).collect();
        let shift = b.iter().zip(m).zip(&scale).map(|((b, m), s)| b - m * s).collect();
        Ok(Self { scale, shift })
    }

    /// The folded batch norm as the engines take it.
    fn bn(&self) -> BnRelu<'_> {
        BnRelu { scale: &self.scale, shift: &self.shift }
    }
}

/// `x + conv2(BN(conv1(BN(x))))`.
#[derive(Debug, Clone)]
struct ResBlock {
    bn1: Affine,
    conv1: Vec<f32>,
    bn2: Affine,
    conv2: Vec<f32>,
}

impl ResBlock {
    fn load(w: &Weights, prefix: &str, eps: f32) -> Result<Self> {
        Ok(Self {
            bn1: Affine::fold(w, &format!("{prefix}.bn1"), eps)?,
            conv1: w.get(&format!("{prefix}.conv1.weight"))?.to_vec(),
            bn2: Affine::fold(w, &format!("{prefix}.bn2"), eps)?,
            conv2: w.get(&format!("{prefix}.conv2.weight"))?.to_vec(),
        })
    }

    /// Applies the block to `x` (`[n, c]`) in place; `a` is scratch. Both batch norms go
    /// into the convolutions' reads (fused by the chunked kernels, a separate pass for the
    /// rulebook), the residual sum into the second convolution's output.
    fn run<B: ConvBackend>(&self, engine: &B, conv: &B::Layer, x: &mut [f32], c: usize, a: &mut Vec<f32>) -> Result<()>
    where
        NetError: From<B::Error>,
    {
        let a = sized(a, x.len());
        engine.forward_into(conv, x, c, Some(self.bn1.bn()), &self.conv1, c, a, false)?;
        engine.forward_into(conv, a, c, Some(self.bn2.bn()), &self.conv2, c, x, true)?;
        Ok(())
    }
}

/// Folded parameters of the whole network.
#[derive(Debug, Clone)]
struct Params {
    input: Vec<f32>,
    extract: Vec<ResBlock>,
    /// `down[i]`: level `i` to `i + 1`.
    down: Vec<(Affine, Vec<f32>)>,
    /// `up[t]`: producing `D_t` from `D_(t+1)` and `E_t`.
    up: Vec<Up>,
    /// `fuse[t][j - t - 1]`: `[C_j, C_t + 1]`, the value map `b` then the attention column `a`.
    fuse: Vec<Vec<Vec<f32>>>,
    head_bn: Affine,
    head_w: Vec<f32>,
    head_b: Vec<f32>,
}

#[derive(Debug, Clone)]
struct Up {
    bn: Affine,
    conv: Vec<f32>,
    skip: Vec<f32>,
    block: ResBlock,
}

impl Params {
    fn fold(w: &Weights, cfg: &NetConfig) -> Result<Self> {
        let l = cfg.levels;
        let eps = cfg.bn_eps;
        let mut fuse = Vec::new();
        for t in 0..l.saturating_sub(2) {
            let ct = cfg.channels(t);
            let mut per = Vec::new();
            for j in t + 1..=l - 2 {
                let a = w.get(&format!("fuse.{t}.{j}.attention.weight"))?;
                let b = w.get(&format!("fuse.{t}.{j}.value.weight"))?;
                let mut m = Vec::with_capacity(cfg.channels(j) * (ct + 1));
                for r in 0..cfg.channels(j) {
                    m.extend_from_slice(&b[r * ct..(r + 1) * ct]);
                    m.push(a[r]);
                }
                per.push(m);
            }
            fuse.push(per);
        }
        Ok(Self {
            input: w.get("input.conv.weight")?.to_vec(),
            extract: (0..l).map(|i| ResBlock::load(w, &format!("extract.{i}"), eps)).collect::<Result<_>>()?,
            down: (0..l.saturating_sub(1))
                .map(|i| {
                    Ok((
                        Affine::fold(w, &format!("down.{i}.bn"), eps)?,
                        w.get(&format!("down.{i}.conv.weight"))?.to_vec(),
                    ))
                })
                .collect::<Result<_>>()?,
            up: (0..l.saturating_sub(1))
                .map(|t| {
                    Ok(Up {
                        bn: Affine::fold(w, &format!("up.{t}.bn"), eps)?,
                        conv: w.get(&format!("up.{t}.conv.weight"))?.to_vec(),
                        skip: w.get(&format!("up.{t}.skip.weight"))?.to_vec(),
                        block: ResBlock::load(w, &format!("up.{t}"), eps)?,
                    })
                })
                .collect::<Result<_>>()?,
            fuse,
            head_bn: Affine::fold(w, "head.bn", eps)?,
            head_w: w.get("head.linear.weight")?.to_vec(),
            head_b: w.get("head.linear.bias")?.to_vec(),
        })
    }
}

/// `d[u] += sum_q w[u, q] g[row[u, q], ..c]` with `g` rows of `stride` values.
fn interp_add(ip: &Interp, g: &[f32], stride: usize, c: usize, d: &mut [f32]) {
    d.par_chunks_mut(c * ROWS_PER_TASK).enumerate().for_each(|(blk, dd)| {
        for (r, drow) in dd.chunks_exact_mut(c).enumerate() {
            let u = blk * ROWS_PER_TASK + r;
            for q in 0..8 {
                let w = ip.weights[u * 8 + q];
                if w == 0.0 {
                    continue;
                }
                let s = ip.rows[u * 8 + q] as usize * stride;
                for (dv, &gv) in drow.iter_mut().zip(&g[s..s + c]) {
                    *dv += w * gv;
                }
            }
        }
    });
}

/// `g[r, ..c] *= sigmoid(g[r, c])` for rows of `c + 1` values.
fn gate(g: &mut [f32], c: usize) {
    g.par_chunks_mut((c + 1) * ROWS_PER_TASK).for_each(|blk| {
        for row in blk.chunks_exact_mut(c + 1) {
            let s = 1.0 / (1.0 + (-row[c]).exp());
            for v in &mut row[..c] {
                *v *= s;
            }
        }
    });
}

/// The first `len` values of a buffer that only grows.
fn sized(v: &mut Vec<f32>, len: usize) -> &mut [f32] {
    if v.len() < len {
        v.resize(len, 0.0);
    }
    &mut v[..len]
}

/// Activation buffers kept between calls.
#[derive(Default)]
struct Workspace {
    enc: Vec<Vec<f32>>,
    dec: Vec<Vec<f32>>,
    a: Vec<f32>,
    g: Vec<f32>,
}

/// Wall time of the two phases of the last call.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Timing {
    /// Kernel maps, chunk plans and interpolation tables.
    pub geometry: Duration,
    /// The layers.
    pub forward: Duration,
}

/// A voxelised point cloud with the network's scores ([`Segmenter::segment_points_scores`]).
///
/// # Shapes
/// `coords`: `[v]`; `features`: `[v, 3]`; `logits`: `[v, classes]`; `point_to_voxel`: `[n]`
/// rows of `coords`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointScores {
    /// The voxels (Z-order, batch 0).
    pub coords: Vec<Coord>,
    /// Mean colour features of each voxel ([`color_features`]).
    pub features: Vec<f32>,
    /// Class scores of each voxel.
    pub logits: Vec<f32>,
    /// The voxel of every input point.
    pub point_to_voxel: Vec<u32>,
}

/// The network ready for inference: folded weights, a chunk configuration and a workspace.
pub struct Segmenter {
    config: NetConfig,
    params: Params,
    chunk: ChunkConfig,
    kernel: ConvKernel,
    ws: Workspace,
    device: Device,
    stats: Vec<LevelStats>,
    timing: Timing,
}

impl std::fmt::Debug for Segmenter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Segmenter").field("config", &self.config).finish_non_exhaustive()
    }
}

impl Segmenter {
    /// Checks `weights` against `config` and folds batch norms.
    ///
    /// # Errors
    /// Invalid configurations, and the errors of [`Weights::check`] naming the tensor.
    pub fn new(weights: Weights, config: NetConfig) -> Result<Self> {
        config.validate()?;
        weights.check(&config)?;
        let params = Params::fold(&weights, &config)?;
        Ok(Self {
            config,
            params,
            chunk: ChunkConfig::default(),
            kernel: ConvKernel::Chunked,
            ws: Workspace::default(),
            device: Device::Cpu,
            stats: Vec::new(),
            timing: Timing::default(),
        })
    }

    /// Runs the convolutions with `kernel` from now on (the chunked one by default).
    pub fn set_kernel(&mut self, kernel: ConvKernel) {
        self.kernel = kernel;
    }

    /// Runs the convolutions on `device` from now on (the CPU by default); the weights and
    /// results are the same, within 1e-4 relative (summation order).
    pub fn set_device(&mut self, device: Device) {
        self.device = device;
    }

    /// Where the convolutions run.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// The configuration.
    pub fn config(&self) -> &NetConfig {
        &self.config
    }

    /// Voxels and neighbour pairs per level of the last input (for FLOP counts).
    pub fn level_stats(&self) -> &[LevelStats] {
        &self.stats
    }

    /// Time spent in the phases of the last call.
    pub fn last_timing(&self) -> Timing {
        self.timing
    }

    /// Class scores of every voxel.
    ///
    /// # Shapes
    /// `coords`: `[n]` distinct voxels (any order); `features`: `[n, in_channels]`;
    /// result `[n, classes]` in the order of `coords`.
    ///
    /// # Errors
    /// [`NetError::InvalidInput`] for mismatched features; duplicate or out-of-range
    /// coordinates as [`NetError::Sparse`]. An empty input gives an empty output.
    pub fn segment(&mut self, coords: &[Coord], features: &[f32]) -> Result<Vec<f32>> {
        let cin = self.config.in_channels;
        if features.len() != coords.len() * cin {
            return Err(NetError::InvalidInput(format!(
                "{} feature values for {} voxels of {cin} channels",
                features.len(),
                coords.len()
            )));
        }
        let order = morton_order(coords)?;
        let identity = order.iter().enumerate().all(|(i, &o)| o as usize == i);
        if identity {
            return self.forward_sorted(coords.to_vec(), features);
        }
        let sorted: Vec<Coord> = order.iter().map(|&r| coords[r as usize]).collect();
        let mut feats = Vec::with_capacity(features.len());
        for &r in &order {
            feats.extend_from_slice(&features[r as usize * cin..(r as usize + 1) * cin]);
        }
        let logits = self.forward_sorted(sorted, &feats)?;
        let k = self.config.classes;
        let mut out = vec![0f32; logits.len()];
        for (i, &r) in order.iter().enumerate() {
            out[r as usize * k..(r as usize + 1) * k].copy_from_slice(&logits[i * k..(i + 1) * k]);
        }
        Ok(out)
    }

    /// Voxelises a coloured point cloud at the configuration's voxel size and returns the
    /// class (the highest score) of every point's voxel.
    ///
    /// # Shapes
    /// `points`: `[n]` metres; `colors`: `[n]`; result `[n]` class ids.
    ///
    /// # Errors
    /// [`NetError::InvalidInput`] when the lengths differ or the network does not take RGB
    /// (`in_channels != 3`); voxelisation errors (non-finite points) as [`NetError::Sparse`].
    pub fn segment_points(&mut self, points: &[[f32; 3]], colors: &[[u8; 3]]) -> Result<Vec<u8>> {
        // `segment_points_scores` checks the inputs.
        let scores = self.segment_points_scores(points, colors)?;
        let voxel_class = argmax_rows(&scores.logits, self.config.classes);
        Ok(scores.point_to_voxel.iter().map(|&r| voxel_class[r as usize]).collect())
    }

    /// Voxelises a coloured point cloud at the configuration's voxel size and returns the
    /// voxels with the network's class scores (logits; [`crate::structure::softmax_rows`]
    /// makes probabilities of them) and the voxel of every point: what
    /// [`segment_points`](Self::segment_points) takes its argmax of, for callers that refine
    /// the labels ([`crate::structure`]) or average several passes.
    ///
    /// # Shapes
    /// `points`: `[n]` metres; `colors`: `[n]`; the result's `coords`: `[v]` (Z-order),
    /// `features`: `[v, 3]`, `logits`: `[v, classes]`, `point_to_voxel`: `[n]`.
    ///
    /// # Errors
    /// As [`segment_points`](Self::segment_points).
    pub fn segment_points_scores(&mut self, points: &[[f32; 3]], colors: &[[u8; 3]]) -> Result<PointScores> {
        if points.len() != colors.len() {
            return Err(NetError::InvalidInput(format!("{} points but {} colours", points.len(), colors.len())));
        }
        if self.config.in_channels != 3 {
            return Err(NetError::InvalidInput(format!(
                "configuration {} takes {} input channels, not RGB",
                self.config.name, self.config.in_channels
            )));
        }
        let v = voxelize(points, &color_features(colors), 3, self.config.voxel_size, 0)?;
        let (coords, features) = v.tensor.into_parts();
        let logits = self.forward_sorted(coords.clone(), &features)?;
        Ok(PointScores { coords, features, logits, point_to_voxel: v.point_to_voxel })
    }

    /// Class scores of the voxels of a prebuilt geometry (for callers that keep the geometry
    /// of a map between calls, or share it with training).
    ///
    /// # Shapes
    /// `features`: `[n, in_channels]` in the order of `geometry.coords(0)`; result
    /// `[n, classes]` in the same order.
    ///
    /// # Errors
    /// [`NetError::InvalidInput`] when the geometry has another number of levels or the
    /// features do not match.
    pub fn segment_geometry(&mut self, geometry: &NetGeometry, features: &[f32]) -> Result<Vec<f32>> {
        if geometry.levels() != self.config.levels {
            return Err(NetError::InvalidInput(format!(
                "geometry of {} levels for a network of {}",
                geometry.levels(),
                self.config.levels
            )));
        }
        let n = geometry.coords(0).len();
        if features.len() != n * self.config.in_channels {
            return Err(NetError::InvalidInput(format!(
                "{} feature values for {n} voxels of {} channels",
                features.len(),
                self.config.in_channels
            )));
        }
        let t = Instant::now();
        let mut logits = vec![0f32; n * self.config.classes];
        if n > 0 {
            self.run_layers(geometry, features, &mut logits)?;
        }
        self.timing = Timing { geometry: Duration::ZERO, forward: t.elapsed() };
        self.stats = geometry.stats();
        Ok(logits)
    }

    /// The forward pass on Z-ordered voxels.
    fn forward_sorted(&mut self, coords: Vec<Coord>, feats: &[f32]) -> Result<Vec<f32>> {
        let k = self.config.classes;
        if coords.is_empty() {
            self.stats.clear();
            return Ok(Vec::new());
        }
        let t0 = Instant::now();
        let geo = NetGeometry::build(coords, &self.config, &self.chunk)?;
        if self.kernel == ConvKernel::Rulebook {
            geo.build_maps();
        }
        let t1 = Instant::now();
        let mut logits = vec![0f32; geo.levels[0].coords.len() * k];
        self.run_layers(&geo, feats, &mut logits)?;
        self.timing = Timing { geometry: t1 - t0, forward: t1.elapsed() };
        self.stats = geo.stats();
        Ok(logits)
    }

    /// The layers on the chosen device: the CPU engine reads the geometry's layers in place,
    /// the GPU engine gets them uploaded once per call (every layer of a level then shares
    /// them). The layer code itself is one, generic over the engine.
    fn run_layers(&mut self, geo: &NetGeometry, feats: &[f32], logits: &mut [f32]) -> Result<()> {
        let algorithm = match self.kernel {
            ConvKernel::Chunked => ConvAlgorithm::Chunked,
            ConvKernel::Rulebook => ConvAlgorithm::Rulebook,
        };
        let Self { config, params, ws, device, chunk, .. } = self;
        match device {
            Device::Cpu => {
                let engine = CpuEngine { algorithm, chunk: *chunk };
                let levels: Vec<LevelLayers<'_, ChunkedConv>> = geo
                    .levels
                    .iter()
                    .map(|l| LevelLayers { subm: &l.subm, point: &l.point, down: l.down.as_ref().map(|(d, u)| (d, u)) })
                    .collect();
                forward_layers(&engine, &levels, geo, config, params, ws, feats, logits)
            }
            Device::Gpu(gpu) => {
                let engine = gpu.with_algorithm(algorithm);
                let mut owned = Vec::with_capacity(geo.levels.len());
                for l in &geo.levels {
                    let down = match &l.down {
                        Some((d, u)) => Some((engine.import(d)?, engine.import(u)?)),
                        None => None,
                    };
                    owned.push((engine.import(&l.subm)?, engine.import(&l.point)?, down));
                }
                let levels: Vec<LevelLayers<'_, GpuLayer>> = owned
                    .iter()
                    .map(|(subm, point, down)| LevelLayers { subm, point, down: down.as_ref().map(|(d, u)| (d, u)) })
                    .collect();
                forward_layers(&engine, &levels, geo, config, params, ws, feats, logits)
            }
        }
    }
}

/// Where the network's convolutions run.
#[derive(Debug, Clone, Default)]
pub enum Device {
    /// The CPU engine (the default).
    #[default]
    Cpu,
    /// The GPU engine (crate `semrecon-gpu`, built with the cargo feature `gpu`).
    Gpu(GpuEngine),
}

impl Device {
    /// `cpu`, or `gpu (adapter name)`.
    pub fn describe(&self) -> String {
        match self {
            Self::Cpu => "cpu".into(),
            Self::Gpu(g) => format!("gpu ({})", g.context().adapter_name()),
        }
    }
}

/// The layers of one level on one engine.
struct LevelLayers<'a, L> {
    subm: &'a L,
    point: &'a L,
    /// The strided layer to the next level and its transpose back.
    down: Option<(&'a L, &'a L)>,
}

/// The whole forward pass on `engine`: encoder, decoder with cross-scale fusion, head. The
/// element-wise steps (attention gates, interpolation, bias) run on the host.
#[allow(clippy::too_many_arguments)]
fn forward_layers<B: ConvBackend>(
    engine: &B,
    levels: &[LevelLayers<'_, B::Layer>],
    geo: &NetGeometry,
    config: &NetConfig,
    p: &Params,
    ws: &mut Workspace,
    feats: &[f32],
    logits: &mut [f32],
) -> Result<()>
where
    NetError: From<B::Error>,
{
    let l = config.levels;
    let c = |i: usize| config.channels(i);
    let n = |i: usize| geo.levels[i].coords.len();
    ws.enc.resize_with(l, Vec::new);
    ws.dec.resize_with(l, Vec::new);

    // Encoder.
    {
        let e0 = sized(&mut ws.enc[0], n(0) * c(0));
        engine.forward_into(levels[0].subm, feats, config.in_channels, None, &p.input, c(0), e0, false)?;
        p.extract[0].run(engine, levels[0].subm, e0, c(0), &mut ws.a)?;
    }
    for i in 1..l {
        let (prev, rest) = ws.enc.split_at_mut(i);
        let (bn, w) = &p.down[i - 1];
        let e = sized(&mut rest[0], n(i) * c(i));
        if let Some((down, _)) = levels[i - 1].down {
            let x = &prev[i - 1][..n(i - 1) * c(i - 1)];
            engine.forward_into(down, x, c(i - 1), Some(bn.bn()), w, c(i), e, false)?;
        }
        p.extract[i].run(engine, levels[i].subm, e, c(i), &mut ws.a)?;
    }

    // Decoder, coarse to fine, with the cross-scale fusion.
    for t in (0..l.saturating_sub(1)).rev() {
        let up = &p.up[t];
        let (lower, higher) = ws.dec.split_at_mut(t + 1);
        let d = sized(&mut lower[t], n(t) * c(t));
        if let Some((_, tconv)) = levels[t].down {
            let src: &[f32] = if t + 1 == l - 1 { &ws.enc[l - 1] } else { &higher[0] };
            let x = &src[..n(t + 1) * c(t + 1)];
            engine.forward_into(tconv, x, c(t + 1), Some(up.bn.bn()), &up.conv, c(t), d, false)?;
        }
        // The skip connection, added to the upsampled features.
        engine.forward_into(levels[t].point, &ws.enc[t][..n(t) * c(t)], c(t), None, &up.skip, c(t), d, true)?;
        up.block.run(engine, levels[t].subm, d, c(t), &mut ws.a)?;
        for (q, w) in p.fuse.get(t).into_iter().flatten().enumerate() {
            let j = t + 1 + q;
            let dj = &higher[j - t - 1][..n(j) * c(j)];
            let g = sized(&mut ws.g, n(j) * (c(t) + 1));
            engine.forward_into(levels[j].point, dj, c(j), None, w, c(t) + 1, g, false)?;
            gate(g, c(t));
            interp_add(&geo.interp[t][q], g, c(t) + 1, c(t), d);
        }
    }

    // Head.
    let d0: &[f32] = if l == 1 { &ws.enc[0] } else { &ws.dec[0] };
    let x = &d0[..n(0) * c(0)];
    engine.forward_into(levels[0].point, x, c(0), Some(p.head_bn.bn()), &p.head_w, config.classes, logits, false)?;
    let k = config.classes;
    logits.par_chunks_mut(k * ROWS_PER_TASK).for_each(|blk| {
        for row in blk.chunks_exact_mut(k) {
            row.iter_mut().zip(&p.head_b).for_each(|(v, b)| *v += b);
        }
    });
    Ok(())
}

/// The index of the largest score of every row of `k` scores (the first on ties): the class
/// of each voxel from its logits.
///
/// # Shapes
/// `scores`: rows x `k`, row-major; the result has one entry per row.
pub(crate) fn argmax_rows(scores: &[f32], k: usize) -> Vec<u8> {
    scores
        .chunks_exact(k.max(1))
        .map(|row| {
            let mut best = 0;
            for (c, &s) in row.iter().enumerate() {
                if s > row[best] {
                    best = c;
                }
            }
            best as u8
        })
        .collect()
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::geometry::{interp_table, neighbour_table};
    use semrecon_sparse::KernelMap;

    /// Two coarse voxels (values 1 and 3 along x) interpolated to the fine voxels below
    /// them: by hand, factor 2 gives 1, 1.5, 2.5, 3 and factor 4 gives 1, 1, 1.25, 1.75,
    /// 2.25, 2.75, 3, 3 (the outer voxels see only one coarse voxel after renormalisation).
    #[test]
    fn trilinear_matches_the_hand_computed_case() {
        let coarse: Vec<Coord> = vec![[0, 0, 0, 0], [1, 0, 0, 0]];
        let values = [1.0f32, 3.0];
        let nbr = neighbour_table(&KernelMap::submanifold(&coarse, 3).unwrap());
        for (shift, expected) in
            [(1u32, vec![1.0, 1.5, 2.5, 3.0]), (2, vec![1.0, 1.0, 1.25, 1.75, 2.25, 2.75, 3.0, 3.0])]
        {
            let fine: Vec<Coord> = (0..expected.len() as i32).map(|x| [x, 1, 0, 0]).collect();
            let anc: Vec<u32> = fine.iter().map(|c| (c[0] >> shift) as u32).collect();
            let ip = interp_table(&fine, &anc, &nbr, shift);
            let mut d = vec![0f32; fine.len()];
            interp_add(&ip, &values, 1, 1, &mut d);
            for (got, want) in d.iter().zip(&expected) {
                assert!((got - want).abs() < 1e-6, "shift {shift}: {d:?} vs {expected:?}");
            }
        }
    }
}
