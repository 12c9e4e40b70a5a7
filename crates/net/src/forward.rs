//! The fused forward of CBSCN, written once for every engine: generic over
//! [`ResidentBackend`], so the CPU engine runs it on host vectors and the GPU engine on device
//! buffers, with no branch per device.
//!
//! Batch norm uses the running statistics folded into one scale and shift per channel
//! ([`Params::fold`], stored `[scale | shift]`), applied together with the ReLU inside the
//! convolution that reads it (fused by the chunked kernels, a separate pass for the rulebook),
//! and residual sums go into the second convolution's output. The cross-scale fusion's
//! attention gate, its trilinear interpolation (a weighted row gather) and the head's bias are
//! the engine's element-wise operations. Weights are the engine's tensors, made once per model
//! by the caller ([`Params::map`] with the engine's upload); activations live in a
//! [`Workspace`] of engine tensors that only grows; the input is uploaded once per call and
//! the result read back once: the logits, or only the labels ([`Readout`]).

use semrecon_sparse::ResidentBackend;

use crate::config::NetConfig;
use crate::error::{NetError, Result};
use crate::model::bn_names;
use crate::weights::Weights;

/// Batch norm with running statistics folded into `max(0, x * scale + shift)`.
///
/// # Shapes
/// Result `[2, c]`: the scales, then the shifts.
fn fold_bn(w: &Weights, prefix: &str, eps: f32) -> Result<Vec<f32>> {
    let [g, b, m, v] = bn_names(prefix);
    let (g, b, m, v) = (w.get(&g)?, w.get(&b)?, w.get(&m)?, w.get(&v)?);
    let scale: Vec<f32> = g.iter().zip(v).map(|(g, v)| g / (v + eps).sqrt()).collect();
    let shift: Vec<f32> = b.iter().zip(m).zip(&scale).map(|((b, m), s)| b - m * s).collect();
    Ok([scale, shift].concat())
}

/// `x + conv2(BN(conv1(BN(x))))`.
#[derive(Debug, Clone)]
pub(crate) struct ResBlock<T> {
    bn1: T,
    conv1: T,
    bn2: T,
    conv2: T,
}

impl ResBlock<Vec<f32>> {
    fn load(w: &Weights, prefix: &str, eps: f32) -> Result<Self> {
        Ok(Self {
            bn1: fold_bn(w, &format!("{prefix}.bn1"), eps)?,
            conv1: w.get(&format!("{prefix}.conv1.weight"))?.to_vec(),
            bn2: fold_bn(w, &format!("{prefix}.bn2"), eps)?,
            conv2: w.get(&format!("{prefix}.conv2.weight"))?.to_vec(),
        })
    }
}

impl<T> ResBlock<T> {
    fn map<U, E>(&self, f: &mut impl FnMut(&T) -> Result<U, E>) -> Result<ResBlock<U>, E> {
        Ok(ResBlock { bn1: f(&self.bn1)?, conv1: f(&self.conv1)?, bn2: f(&self.bn2)?, conv2: f(&self.conv2)? })
    }

    /// Applies the block to `x` in place; `a` is scratch.
    ///
    /// # Shapes
    /// `x`: `[n, c]` with `n` the rows of `conv`.
    fn run<B>(&self, engine: &B, conv: &B::Layer, x: &mut T, c: usize, a: &mut T) -> Result<()>
    where
        B: ResidentBackend<Tensor = T>,
        NetError: From<B::Error>,
    {
        engine.reserve(a, engine.layer_rows(conv).1 * c)?;
        engine.conv(conv, x, c, Some(&self.bn1), &self.conv1, c, a, false)?;
        engine.conv(conv, a, c, Some(&self.bn2), &self.conv2, c, x, true)?;
        Ok(())
    }
}

/// One decoder step: producing `D_t` from `D_(t+1)` and `E_t`.
#[derive(Debug, Clone)]
pub(crate) struct Up<T> {
    bn: T,
    conv: T,
    skip: T,
    block: ResBlock<T>,
}

/// Folded parameters of the whole network, as tensors of one engine (`Vec<f32>` on the host,
/// which is also the CPU engine's tensor).
#[derive(Debug, Clone)]
pub(crate) struct Params<T> {
    input: T,
    extract: Vec<ResBlock<T>>,
    /// `down[i]`: level `i` to `i + 1` (folded batch norm, weights).
    down: Vec<(T, T)>,
    /// `up[t]`: producing `D_t` from `D_(t+1)` and `E_t`.
    up: Vec<Up<T>>,
    /// `fuse[t][j - t - 1]`: `[C_j, C_t + 1]`, the value map `b` then the attention column `a`.
    fuse: Vec<Vec<T>>,
    head_bn: T,
    head_w: T,
    head_b: T,
}

impl Params<Vec<f32>> {
    /// Folds the batch norms of `w` and lays the fusion matrices out as the layers read them.
    ///
    /// # Errors
    /// Missing tensors.
    pub(crate) fn fold(w: &Weights, cfg: &NetConfig) -> Result<Self> {
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
                    Ok((fold_bn(w, &format!("down.{i}.bn"), eps)?, w.get(&format!("down.{i}.conv.weight"))?.to_vec()))
                })
                .collect::<Result<_>>()?,
            up: (0..l.saturating_sub(1))
                .map(|t| {
                    Ok(Up {
                        bn: fold_bn(w, &format!("up.{t}.bn"), eps)?,
                        conv: w.get(&format!("up.{t}.conv.weight"))?.to_vec(),
                        skip: w.get(&format!("up.{t}.skip.weight"))?.to_vec(),
                        block: ResBlock::load(w, &format!("up.{t}"), eps)?,
                    })
                })
                .collect::<Result<_>>()?,
            fuse,
            head_bn: fold_bn(w, "head.bn", eps)?,
            head_w: w.get("head.linear.weight")?.to_vec(),
            head_b: w.get("head.linear.bias")?.to_vec(),
        })
    }
}

impl Params<Vec<f32>> {
    /// The class head's folded batch norm: `(scale, shift)`, `[C_0]` each.
    pub(crate) fn head_bn_parts(&self) -> (&[f32], &[f32]) {
        self.head_bn.split_at(self.head_bn.len() / 2)
    }
}

impl<T> Params<T> {
    /// Every tensor through `f` (an engine's upload: the weights made resident once).
    pub(crate) fn map<U, E>(&self, f: &mut impl FnMut(&T) -> Result<U, E>) -> Result<Params<U>, E> {
        Ok(Params {
            input: f(&self.input)?,
            extract: self.extract.iter().map(|b| b.map(f)).collect::<Result<_, E>>()?,
            down: self.down.iter().map(|(bn, w)| Ok((f(bn)?, f(w)?))).collect::<Result<_, E>>()?,
            up: self
                .up
                .iter()
                .map(|u| Ok(Up { bn: f(&u.bn)?, conv: f(&u.conv)?, skip: f(&u.skip)?, block: u.block.map(f)? }))
                .collect::<Result<_, E>>()?,
            fuse: self
                .fuse
                .iter()
                .map(|per| per.iter().map(&mut *f).collect::<Result<_, E>>())
                .collect::<Result<_, E>>()?,
            head_bn: f(&self.head_bn)?,
            head_w: f(&self.head_w)?,
            head_b: f(&self.head_b)?,
        })
    }
}

/// Activation tensors of one engine, kept between calls and only grown, so repeated calls on
/// rooms of similar size allocate nothing per layer.
pub(crate) struct Workspace<T> {
    /// Encoder outputs `E_i` per level.
    enc: Vec<T>,
    /// Decoder outputs `D_t` per level.
    dec: Vec<T>,
    /// Residual blocks' scratch.
    a: T,
    /// Fusion values with their gate column.
    g: T,
    logits: T,
}

impl<T> Workspace<T> {
    /// Every tensor of the workspace.
    pub(crate) fn tensors(&self) -> impl Iterator<Item = &T> {
        self.enc.iter().chain(&self.dec).chain([&self.a, &self.g, &self.logits])
    }

    /// Empty tensors for a network of `levels` levels.
    ///
    /// # Errors
    /// The engine's (a lost device).
    pub(crate) fn new<B: ResidentBackend<Tensor = T>>(engine: &B, levels: usize) -> Result<Self, B::Error> {
        let empty = || engine.upload(&[]);
        Ok(Self {
            enc: (0..levels).map(|_| empty()).collect::<Result<_, _>>()?,
            dec: (0..levels).map(|_| empty()).collect::<Result<_, _>>()?,
            a: empty()?,
            g: empty()?,
            logits: empty()?,
        })
    }
}

/// The layers of one level on one engine.
pub(crate) struct LevelLayers<'a, L> {
    /// The 3x3x3 submanifold layer of the level.
    pub(crate) subm: &'a L,
    /// The pointwise layer (linear maps on the level's rows).
    pub(crate) point: &'a L,
    /// The strided layer to the next level and its transpose back.
    pub(crate) down: Option<(&'a L, &'a L)>,
}

/// What a forward reads back from the engine.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Readout {
    /// The class scores of every voxel.
    Logits,
    /// Only the class of every voxel (an argmax on the engine: `1 / classes` of the bytes).
    Labels,
    /// The class scores and the finest decoder features the head reads (before its batch
    /// norm), for a second head ([`crate::home_head`]).
    LogitsAndDecoder,
}

/// The result of a forward: the part [`Readout`] asked for, the other empty.
///
/// # Shapes
/// `logits`: `[n, classes]`; `labels`: `[n]`; `decoder`: `[n, C_0]`.
#[derive(Debug, Clone, Default)]
pub(crate) struct Scores {
    pub(crate) logits: Vec<f32>,
    pub(crate) labels: Vec<u32>,
    pub(crate) decoder: Vec<f32>,
}

/// The input of one forward on one engine: layers and interpolation tables per level, as the
/// engine holds them.
pub(crate) struct Prepared<'a, B: ResidentBackend> {
    pub(crate) levels: Vec<LevelLayers<'a, B::Layer>>,
    /// `interp[t][j - t - 1]`: trilinear interpolation from level `j` to level `t`.
    pub(crate) interp: Vec<Vec<&'a B::Gather>>,
    /// Voxels per level.
    pub(crate) rows: Vec<usize>,
}

/// The whole forward pass on `engine`: encoder, decoder with cross-scale fusion, head, and
/// one read-back.
///
/// # Shapes
/// `feats`: `[rows[0], in_channels]`; the result as [`Scores`].
///
/// # Errors
/// The engine's (short tensors, device errors).
pub(crate) fn forward<B>(
    engine: &B,
    geo: &Prepared<'_, B>,
    config: &NetConfig,
    p: &Params<B::Tensor>,
    ws: &mut Workspace<B::Tensor>,
    feats: &[f32],
    readout: Readout,
) -> Result<Scores>
where
    B: ResidentBackend,
    NetError: From<B::Error>,
{
    let l = config.levels;
    let levels = &geo.levels;
    let c = |i: usize| config.channels(i);
    let n = |i: usize| geo.rows[i];

    // Encoder.
    let input = engine.upload(feats)?;
    engine.reserve(&mut ws.enc[0], n(0) * c(0))?;
    engine.conv(levels[0].subm, &input, config.in_channels, None, &p.input, c(0), &mut ws.enc[0], false)?;
    p.extract[0].run(engine, levels[0].subm, &mut ws.enc[0], c(0), &mut ws.a)?;
    for i in 1..l {
        let (prev, rest) = ws.enc.split_at_mut(i);
        let (bn, w) = &p.down[i - 1];
        let e = &mut rest[0];
        engine.reserve(e, n(i) * c(i))?;
        if let Some((down, _)) = levels[i - 1].down {
            engine.conv(down, &prev[i - 1], c(i - 1), Some(bn), w, c(i), e, false)?;
        }
        p.extract[i].run(engine, levels[i].subm, e, c(i), &mut ws.a)?;
    }

    // Decoder, coarse to fine, with the cross-scale fusion.
    for t in (0..l.saturating_sub(1)).rev() {
        let up = &p.up[t];
        let (lower, higher) = ws.dec.split_at_mut(t + 1);
        let d = &mut lower[t];
        engine.reserve(d, n(t) * c(t))?;
        if let Some((_, tconv)) = levels[t].down {
            let src = if t + 1 == l - 1 { &ws.enc[l - 1] } else { &higher[0] };
            engine.conv(tconv, src, c(t + 1), Some(&up.bn), &up.conv, c(t), d, false)?;
        }
        // The skip connection, added to the upsampled features.
        engine.conv(levels[t].point, &ws.enc[t], c(t), None, &up.skip, c(t), d, true)?;
        up.block.run(engine, levels[t].subm, d, c(t), &mut ws.a)?;
        for (q, w) in p.fuse.get(t).into_iter().flatten().enumerate() {
            let j = t + 1 + q;
            engine.reserve(&mut ws.g, n(j) * (c(t) + 1))?;
            engine.conv(levels[j].point, &higher[j - t - 1], c(j), None, w, c(t) + 1, &mut ws.g, false)?;
            engine.gate(&mut ws.g, n(j), c(t))?;
            engine.gather_add(geo.interp[t][q], &ws.g, c(t) + 1, c(t), d)?;
        }
    }

    // Head.
    let d0 = if l == 1 { &ws.enc[0] } else { &ws.dec[0] };
    let k = config.classes;
    engine.reserve(&mut ws.logits, n(0) * k)?;
    engine.conv(levels[0].point, d0, c(0), Some(&p.head_bn), &p.head_w, k, &mut ws.logits, false)?;
    engine.add_bias(&mut ws.logits, n(0), &p.head_b, k)?;
    Ok(match readout {
        Readout::Logits => Scores { logits: engine.download(&ws.logits, n(0) * k)?, ..Scores::default() },
        Readout::Labels => Scores { labels: engine.argmax_rows(&ws.logits, n(0), k)?, ..Scores::default() },
        Readout::LogitsAndDecoder => Scores {
            logits: engine.download(&ws.logits, n(0) * k)?,
            labels: Vec::new(),
            decoder: engine.download(d0, n(0) * c(0))?,
        },
    })
}
