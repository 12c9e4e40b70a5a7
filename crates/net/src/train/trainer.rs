//! The training loop: batches of augmented rooms prepared on a loader thread while the step
//! runs, masked cross-entropy (unlabelled voxels ignored, optional class weights), Adam with
//! a warm-up and cosine learning-rate schedule over a step count or a time budget, periodic
//! validation with the fused [`Segmenter`] (mIoU overall and per room group), atomic
//! checkpoints and a JSON-lines log, all resumable.
//!
//! Output folder:
//!
//! | file | content |
//! |---|---|
//! | `last.safetensors` | latest weights (f16, [`Weights::save`]) |
//! | `best.safetensors` | weights with the best validation mIoU so far |
//! | `state.json` | step, seed, elapsed time, best mIoU, learning rate ([`TrainState`]) |
//! | `adam.bin` | Adam moments (f32, little-endian), for an exact resume |
//! | `log.jsonl` | one JSON object per logged step and per validation |
//!
//! Determinism: the room order of epoch `e` is a permutation seeded by `(seed, e)`, the
//! augmentation of each sample by `(seed, e, position)` ([`sample_seed`]), and the engine's
//! kernels give the same bits for any thread count, so a run and its resume see the same data.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, Receiver};
use std::sync::Arc;
use std::time::{Duration, Instant};

use burn::tensor::activation::log_softmax;
use burn::tensor::{Device, Int, Tensor, TensorData};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use semrecon_data::atomic_file::write_atomic;
use semrecon_data::class::UNLABELED;
use semrecon_data::LabeledPointCloud;
use semrecon_sparse::ChunkConfig;
use serde::{Deserialize, Serialize};

use crate::config::NetConfig;
use crate::dataset::{load_cloud, load_sample, sample_seed, Augment, RoomRef};
use crate::error::{NetError, Result};
use crate::geometry::NetGeometry;
use crate::inference::argmax_rows;
use crate::metrics::ConfusionMatrix;
use crate::sample::VoxelSample;
use crate::train::model::{tensor_values, BurnCbscn, Mode};
use crate::weights::Weights;
use crate::Segmenter;

/// Everything a training run needs.
#[derive(Debug, Clone)]
pub struct TrainOptions {
    /// Network configuration.
    pub config: NetConfig,
    /// Training rooms.
    pub train_rooms: Vec<RoomRef>,
    /// Validation rooms (not augmented).
    pub val_rooms: Vec<RoomRef>,
    /// Output folder (created).
    pub out: PathBuf,
    /// Number of optimiser steps (the schedule's length unless `time_budget` ends it first).
    pub steps: u64,
    /// Wall-clock budget: the schedule ends (and training stops) at whichever of `steps` and
    /// the budget comes first; resumed runs count the time already spent.
    pub time_budget: Option<Duration>,
    /// Rooms per step.
    pub batch: usize,
    /// Peak learning rate.
    pub lr: f32,
    /// Final learning rate as a fraction of the peak (cosine schedule).
    pub lr_final_fraction: f32,
    /// Steps of linear warm-up.
    pub warmup_steps: u64,
    /// Decoupled weight decay (AdamW), per unit learning rate.
    pub weight_decay: f32,
    /// Batch-norm momentum.
    pub bn_momentum: f32,
    /// Seed of initialisation, room order and augmentation.
    pub seed: u64,
    /// Augmentation of training samples.
    pub augment: Augment,
    /// Samples larger than this many voxels are cut to the voxels nearest (horizontally) to
    /// a random voxel (bounds the step time and memory).
    pub max_voxels: usize,
    /// Per-class loss weights (`classes` values) or `None` for uniform.
    pub class_weights: Option<Vec<f32>>,
    /// Validate every this many steps (and at the end).
    pub val_every_steps: u64,
    /// Validate also when this much time has passed since the last validation.
    pub val_every: Duration,
    /// Checkpoint every this many steps.
    pub checkpoint_every_steps: u64,
    /// Checkpoint also when this much time has passed since the last one.
    pub checkpoint_every: Duration,
    /// Continue from the checkpoint in `out`.
    pub resume: bool,
    /// Weights to start from when not resuming (fine-tuning a shipped model); `None`: the
    /// seeded random initialisation. The optimiser starts afresh either way.
    pub init: Option<PathBuf>,
}

impl TrainOptions {
    /// Defaults of the recipe in docs/model.md for `config`, rooms and output folder.
    pub fn new(config: NetConfig, train_rooms: Vec<RoomRef>, val_rooms: Vec<RoomRef>, out: PathBuf) -> Self {
        Self {
            config,
            train_rooms,
            val_rooms,
            out,
            steps: 10_000,
            time_budget: None,
            batch: 2,
            lr: 1e-3,
            lr_final_fraction: 0.02,
            warmup_steps: 50,
            weight_decay: 1e-4,
            bn_momentum: 0.1,
            seed: 0,
            augment: Augment::training(),
            max_voxels: 60_000,
            class_weights: None,
            val_every_steps: 500,
            val_every: Duration::from_secs(600),
            checkpoint_every_steps: 200,
            checkpoint_every: Duration::from_secs(300),
            resume: false,
            init: None,
        }
    }
}

/// The resumable state of a run (`state.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainState {
    /// Optimiser steps done.
    pub step: u64,
    /// Samples consumed (position in the epoch stream).
    pub samples: u64,
    /// Run seed.
    pub seed: u64,
    /// Training seconds spent so far (over all sessions).
    pub elapsed_secs: f64,
    /// Best validation mIoU so far (0..1), `None` before the first validation.
    pub best_miou: Option<f64>,
    /// Step of the best validation.
    pub best_step: Option<u64>,
    /// Configuration summary, for people reading the file.
    pub config: String,
}

/// What the caller sees after every step (for progress bars).
#[derive(Debug, Clone, Default)]
pub struct Progress {
    /// Steps done.
    pub step: u64,
    /// Planned steps.
    pub steps: u64,
    /// Loss of this step.
    pub loss: f32,
    /// Running mean loss (exponential, ~50 steps).
    pub mean_loss: f32,
    /// Learning rate of this step.
    pub lr: f32,
    /// Rooms per second over the session.
    pub rooms_per_s: f64,
    /// Seconds per step over the session.
    pub secs_per_step: f64,
    /// Latest validation mIoU (0..1).
    pub val_miou: Option<f64>,
    /// Training seconds so far.
    pub elapsed_secs: f64,
    /// A line worth printing (validation results, checkpoints), if any.
    pub message: Option<String>,
}

/// Validation result.
#[derive(Debug, Clone)]
pub struct Validation {
    /// Confusion over all validation rooms.
    pub total: ConfusionMatrix,
    /// Confusion per room group (style), sorted by name.
    pub groups: BTreeMap<String, ConfusionMatrix>,
}

/// The learning rate of `step`: linear warm-up, then cosine from `lr` to
/// `lr * final_fraction` as `fraction` (of steps or of time, whichever is further) goes 0 to 1.
pub fn learning_rate(lr: f32, final_fraction: f32, warmup_steps: u64, step: u64, fraction: f64) -> f32 {
    let warm = if warmup_steps > 0 { ((step + 1) as f32 / warmup_steps as f32).min(1.0) } else { 1.0 };
    let f = fraction.clamp(0.0, 1.0) as f32;
    let cos = 0.5 * (1.0 + (std::f32::consts::PI * f).cos());
    warm * lr * (final_fraction + (1.0 - final_fraction) * cos)
}

/// Adam with decoupled weight decay on named flat parameters.
#[derive(Debug, Clone)]
pub struct Adam {
    beta1: f32,
    beta2: f32,
    eps: f32,
    t: u64,
    m: BTreeMap<String, Vec<f32>>,
    v: BTreeMap<String, Vec<f32>>,
}

impl Adam {
    /// Fresh moments for `params` (betas 0.9 / 0.999, eps 1e-8).
    pub fn new(params: &BTreeMap<String, Vec<f32>>) -> Self {
        let zeros: BTreeMap<String, Vec<f32>> = params.iter().map(|(k, v)| (k.clone(), vec![0.0; v.len()])).collect();
        Self { beta1: 0.9, beta2: 0.999, eps: 1e-8, t: 0, m: zeros.clone(), v: zeros }
    }

    /// One update of `params` with `grads` at learning rate `lr`; weight decay applies to
    /// matrices and kernels only (names ending in `.weight` outside batch norms).
    pub fn step(
        &mut self,
        params: &mut BTreeMap<String, Vec<f32>>,
        grads: &BTreeMap<String, Vec<f32>>,
        lr: f32,
        decay: f32,
    ) {
        self.t += 1;
        let (b1, b2) = (self.beta1, self.beta2);
        let c1 = 1.0 - b1.powi(self.t.min(i32::MAX as u64) as i32);
        let c2 = 1.0 - b2.powi(self.t.min(i32::MAX as u64) as i32);
        for (name, p) in params.iter_mut() {
            let (Some(g), Some(m), Some(v)) = (grads.get(name), self.m.get_mut(name), self.v.get_mut(name)) else {
                continue;
            };
            let decays = name.ends_with(".weight") && !name.contains(".bn");
            for i in 0..p.len() {
                let gi = g[i];
                m[i] = b1 * m[i] + (1.0 - b1) * gi;
                v[i] = b2 * v[i] + (1.0 - b2) * gi * gi;
                let update = (m[i] / c1) / ((v[i] / c2).sqrt() + self.eps);
                if decays {
                    p[i] -= lr * decay * p[i];
                }
                p[i] -= lr * update;
            }
        }
    }

    /// The moments as bytes: `t` (u64), then per parameter (sorted) its m and v values.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = self.t.to_le_bytes().to_vec();
        for (m, v) in self.m.values().zip(self.v.values()) {
            out.extend((m.len() as u64).to_le_bytes());
            for x in m.iter().chain(v) {
                out.extend(x.to_le_bytes());
            }
        }
        out
    }

    /// Restores moments written by [`Self::to_bytes`] for the same parameters.
    ///
    /// # Errors
    /// [`NetError::WeightFile`] naming `path` when the sizes do not match.
    pub fn load_bytes(&mut self, bytes: &[u8], path: &Path) -> Result<()> {
        let bad = |m: &str| NetError::WeightFile { file: path.display().to_string(), message: m.to_string() };
        let mut pos = 0usize;
        let mut take = |n: usize| -> Result<&[u8]> {
            let s = bytes.get(pos..pos + n).ok_or_else(|| bad("truncated optimiser state"))?;
            pos += n;
            Ok(s)
        };
        let u64_at = |s: &[u8]| s.try_into().map(u64::from_le_bytes).map_err(|_| bad("truncated optimiser state"));
        let t = u64_at(take(8)?)?;
        let mut m = self.m.clone();
        let mut v = self.v.clone();
        for (mm, vv) in m.values_mut().zip(v.values_mut()) {
            let n = u64_at(take(8)?)? as usize;
            if n != mm.len() {
                return Err(bad("optimiser state of another configuration"));
            }
            let raw = take(8 * n)?;
            for (i, c) in raw.chunks_exact(4).enumerate() {
                let x = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
                if i < n {
                    mm[i] = x;
                } else {
                    vv[i - n] = x;
                }
            }
        }
        self.t = t;
        self.m = m;
        self.v = v;
        Ok(())
    }
}

/// Data sets of at most this many rooms keep their point clouds in memory between epochs.
const CACHED_ROOMS: usize = 16;

/// One prepared batch: merged geometry, features and labels.
struct Batch {
    geometry: Arc<NetGeometry>,
    features: Vec<f32>,
    labels: Vec<u8>,
    rooms: usize,
    /// Sample stream position after this batch.
    samples_after: u64,
}

/// Cuts `s` to the `max` voxels nearest (horizontal Chebyshev distance) to a random voxel,
/// keeping their order.
fn limit_voxels(s: VoxelSample, max: usize, rng: &mut ChaCha8Rng) -> VoxelSample {
    if s.len() <= max || max == 0 {
        return s;
    }
    let c = s.coords[rng.random_range(0..s.len())];
    let mut d: Vec<i32> = s.coords.iter().map(|v| (v[0] - c[0]).abs().max((v[1] - c[1]).abs())).collect();
    let mut sorted = d.clone();
    let (_, &mut radius, _) = sorted.select_nth_unstable(max - 1);
    // Voxels strictly inside the radius, then ties up to `max`.
    let mut budget = max - d.iter().filter(|&&x| x < radius).count();
    let keep: Vec<bool> = d
        .iter_mut()
        .map(|x| {
            if *x < radius {
                true
            } else if *x == radius && budget > 0 {
                budget -= 1;
                true
            } else {
                false
            }
        })
        .collect();
    let ch = s.channels;
    let mut out = VoxelSample { channels: ch, ..Default::default() };
    for (i, k) in keep.iter().enumerate() {
        if *k {
            out.coords.push(s.coords[i]);
            out.features.extend_from_slice(&s.features[i * ch..(i + 1) * ch]);
            out.labels.push(s.labels[i]);
        }
    }
    out
}

/// Merges samples into one input with batch indices `0..k` in the coordinates.
fn merge(samples: Vec<VoxelSample>, config: &NetConfig) -> Result<(Arc<NetGeometry>, Vec<f32>, Vec<u8>)> {
    let mut coords = Vec::new();
    let mut features = Vec::new();
    let mut labels = Vec::new();
    for (b, s) in samples.into_iter().enumerate() {
        coords.extend(s.coords.iter().map(|c| [c[0], c[1], c[2], b as i32]));
        features.extend(s.features);
        labels.extend(s.labels);
    }
    let geometry = NetGeometry::build(coords, config, &ChunkConfig::default())?;
    Ok((Arc::new(geometry), features, labels))
}

/// The training sample stream: position `p` is room `perm_e[p % n]` of epoch `e = p / n`.
fn room_at(rooms: usize, seed: u64, position: u64) -> (u64, usize) {
    let n = rooms as u64;
    let epoch = position / n;
    let mut perm: Vec<usize> = (0..rooms).collect();
    perm.shuffle(&mut ChaCha8Rng::seed_from_u64(seed ^ epoch.wrapping_mul(0xA24B_AED4_963E_E407)));
    (epoch, perm[(position % n) as usize])
}

/// Starts the loader thread at sample position `start`.
fn spawn_loader(opts: &TrainOptions, start: u64) -> Receiver<Result<Batch>> {
    let (tx, rx) = sync_channel::<Result<Batch>>(2);
    let rooms = opts.train_rooms.clone();
    let config = opts.config.clone();
    let augment = opts.augment.clone();
    let (seed, batch, max_voxels) = (opts.seed, opts.batch.max(1), opts.max_voxels);
    std::thread::spawn(move || {
        let mut position = start;
        let mut cache: std::collections::HashMap<usize, LabeledPointCloud> = std::collections::HashMap::new();
        loop {
            let mut samples = Vec::with_capacity(batch);
            let mut attempts = 0;
            while samples.len() < batch && attempts < batch * 20 {
                attempts += 1;
                let n = rooms.len() as u64;
                let (epoch, room) = room_at(rooms.len(), seed, position);
                let s_seed = sample_seed(seed, epoch, position % n);
                position += 1;
                let loaded = if rooms.len() <= CACHED_ROOMS {
                    // Few rooms (tests, fine-tuning on a handful of scans): keep their clouds.
                    let cloud = match cache.get(&room) {
                        Some(c) => Ok(c),
                        None => load_cloud(&rooms[room], config.voxel_size, room as u64)
                            .map(|c| &*cache.entry(room).or_insert(c)),
                    };
                    cloud.and_then(|c| {
                        let mut c = c.clone();
                        augment.apply(&mut c, s_seed);
                        VoxelSample::from_cloud(&c, config.voxel_size)
                    })
                } else {
                    load_sample(&rooms[room], config.voxel_size, Some(&augment), s_seed)
                };
                let sample = match loaded {
                    Ok(s) => s,
                    Err(e) => {
                        if tx.send(Err(e)).is_err() {
                            return;
                        }
                        continue;
                    }
                };
                let mut rng = ChaCha8Rng::seed_from_u64(s_seed ^ 0x11);
                let sample = limit_voxels(sample, max_voxels, &mut rng);
                // Samples without labelled voxels teach nothing (a crop of empty space).
                if sample.labels.iter().filter(|&&l| l != UNLABELED).count() >= 16 {
                    samples.push(sample);
                }
            }
            let rooms_in = samples.len();
            let result = if samples.is_empty() {
                Err(NetError::InvalidInput("the training data gave no labelled voxels".into()))
            } else {
                merge(samples, &config).map(|(geometry, features, labels)| Batch {
                    geometry,
                    features,
                    labels,
                    rooms: rooms_in,
                    samples_after: position,
                })
            };
            if tx.send(result).is_err() {
                return;
            }
        }
    });
    rx
}

/// Masked, optionally class-weighted cross-entropy of `logits` (`[n, k]`) against `labels`.
/// Returns `None` when no voxel is labelled.
fn cross_entropy(
    logits: Tensor<2>,
    labels: &[u8],
    class_weights: Option<&[f32]>,
    device: &Device,
) -> Option<Tensor<1>> {
    let k = logits.dims()[1];
    let rows: Vec<i64> = labels.iter().enumerate().filter(|(_, &l)| (l as usize) < k).map(|(i, _)| i as i64).collect();
    if rows.is_empty() {
        return None;
    }
    let m = rows.len();
    let targets: Vec<i64> = rows.iter().map(|&r| i64::from(labels[r as usize])).collect();
    let weights: Vec<f32> =
        targets.iter().map(|&t| class_weights.and_then(|w| w.get(t as usize).copied()).unwrap_or(1.0)).collect();
    let total: f32 = weights.iter().sum::<f32>().max(1e-12);
    let idx = Tensor::<1, Int>::from_data(TensorData::new(rows, [m]), device);
    let tgt = Tensor::<2, Int>::from_data(TensorData::new(targets, [m, 1]), device);
    let w = Tensor::<2>::from_data(TensorData::new(weights, [m, 1]), device);
    let logp = log_softmax(logits.select(0, idx), 1).gather(1, tgt);
    Some((logp * w).sum().neg() / total)
}

/// Validation on `samples` with the fused forward.
///
/// # Errors
/// Those of [`Segmenter`].
pub fn validate(weights: &Weights, config: &NetConfig, samples: &[(String, VoxelSample)]) -> Result<Validation> {
    let mut seg = Segmenter::new(weights.clone(), config.clone())?;
    let mut total = ConfusionMatrix::new(config.classes);
    let mut groups: BTreeMap<String, ConfusionMatrix> = BTreeMap::new();
    for (group, s) in samples {
        let logits = seg.segment(&s.coords, &s.features)?;
        let pred = argmax_rows(&logits, config.classes);
        total.add(&s.labels, &pred);
        groups.entry(group.clone()).or_insert_with(|| ConfusionMatrix::new(config.classes)).add(&s.labels, &pred);
    }
    Ok(Validation { total, groups })
}

fn write_json(path: &Path, value: &impl Serialize) -> Result<()> {
    let text = serde_json::to_string_pretty(value).map_err(|e| NetError::InvalidInput(e.to_string()))?;
    write_atomic(path, text.as_bytes())?;
    Ok(())
}

struct Log {
    file: std::fs::File,
    path: PathBuf,
}

impl Log {
    fn open(path: PathBuf) -> Result<Self> {
        let file =
            std::fs::OpenOptions::new().create(true).append(true).open(&path).map_err(|e| NetError::io(&path, e))?;
        Ok(Self { file, path })
    }

    fn write(&mut self, value: serde_json::Value) -> Result<()> {
        writeln!(self.file, "{value}").map_err(|e| NetError::io(&self.path, e))
    }
}

/// Runs training as configured, calling `progress` after every step; returns the final state.
///
/// # Errors
/// Unreadable data, an unwritable output folder, a checkpoint of another configuration on
/// resume (naming what differs).
pub fn train(opts: &TrainOptions, progress: &mut dyn FnMut(&Progress)) -> Result<TrainState> {
    let config = &opts.config;
    config.validate()?;
    if opts.train_rooms.is_empty() {
        return Err(NetError::InvalidInput("no training rooms".into()));
    }
    if let Some(w) = &opts.class_weights {
        if w.len() != config.classes {
            return Err(NetError::InvalidInput(format!("{} class weights for {} classes", w.len(), config.classes)));
        }
    }
    std::fs::create_dir_all(&opts.out).map_err(|e| NetError::io(&opts.out, e))?;
    let last_path = opts.out.join("last.safetensors");
    let best_path = opts.out.join("best.safetensors");
    let state_path = opts.out.join("state.json");
    let adam_path = opts.out.join("adam.bin");

    let (weights, mut state) = if opts.resume && last_path.exists() {
        let w = Weights::load(&last_path, config)?;
        let text = std::fs::read_to_string(&state_path).map_err(|e| NetError::io(&state_path, e))?;
        let s: TrainState = serde_json::from_str(&text)
            .map_err(|e| NetError::WeightFile { file: state_path.display().to_string(), message: e.to_string() })?;
        (w, s)
    } else {
        let initial = match &opts.init {
            Some(path) => Weights::load(path, config)?,
            None => Weights::random(config, opts.seed),
        };
        (
            initial,
            TrainState {
                step: 0,
                samples: 0,
                seed: opts.seed,
                elapsed_secs: 0.0,
                best_miou: None,
                best_step: None,
                config: config.summary(),
            },
        )
    };
    let device = Device::flex().autodiff();
    let mut net = BurnCbscn::from_weights(&weights, config, &device)?;
    let mut values: BTreeMap<String, Vec<f32>> = net
        .parameter_names()
        .into_iter()
        .map(|n| weights.get(&n).map(|v| (n.clone(), v.to_vec())))
        .collect::<Result<_>>()?;
    let mut adam = Adam::new(&values);
    if opts.resume && adam_path.exists() {
        let bytes = std::fs::read(&adam_path).map_err(|e| NetError::io(&adam_path, e))?;
        adam.load_bytes(&bytes, &adam_path)?;
    }
    let mut log = Log::open(opts.out.join("log.jsonl"))?;

    // Validation samples are prepared once, without augmentation.
    let val_samples: Vec<(String, VoxelSample)> = opts
        .val_rooms
        .iter()
        .enumerate()
        .map(|(i, r)| load_sample(r, config.voxel_size, None, i as u64).map(|s| (r.group.clone(), s)))
        .collect::<Result<_>>()?;

    let rx = spawn_loader(opts, state.samples);
    let session = Instant::now();
    let base_elapsed = state.elapsed_secs;
    let (mut last_val, mut last_ckpt) = (Instant::now(), Instant::now());
    // A validation triggered by time is not repeated by the step rule a few steps later.
    let mut last_val_step = state.step;
    let (mut rooms_done, mut steps_done) = (0u64, 0u64);
    let mut mean_loss: Option<f32> = None;
    let mut val_miou = state.best_miou;
    let fraction = |step: u64, elapsed: f64| {
        let by_steps = step as f64 / opts.steps.max(1) as f64;
        let by_time = opts.time_budget.map_or(0.0, |b| elapsed / b.as_secs_f64().max(1e-9));
        by_steps.max(by_time)
    };

    let save = |net: &BurnCbscn, state: &TrainState, adam: &Adam| -> Result<()> {
        net.to_weights().save(&last_path, config)?;
        write_atomic(&adam_path, &adam.to_bytes())?;
        write_json(&state_path, state)
    };

    loop {
        let elapsed = base_elapsed + session.elapsed().as_secs_f64();
        if state.step >= opts.steps || fraction(state.step, elapsed) >= 1.0 {
            break;
        }
        let batch = rx.recv().map_err(|_| NetError::InvalidInput("the data loader stopped".into()))??;
        let lr = learning_rate(
            opts.lr,
            opts.lr_final_fraction,
            opts.warmup_steps,
            state.step,
            fraction(state.step, elapsed),
        );
        let n = batch.labels.len();
        let x = Tensor::<2>::from_data(TensorData::new(batch.features, [n, config.in_channels]), &device);
        let logits = net.forward(&batch.geometry, x, Mode::Train { momentum: opts.bn_momentum })?;
        let Some(loss) = cross_entropy(logits, &batch.labels, opts.class_weights.as_deref(), &device) else {
            state.samples = batch.samples_after;
            continue;
        };
        let grads = loss.backward();
        let loss_value = tensor_values(loss.detach()).first().copied().unwrap_or(f32::NAN);
        if !loss_value.is_finite() {
            return Err(NetError::InvalidInput(format!("the loss became {loss_value} at step {}", state.step)));
        }
        let g = net.gradients(&grads);
        drop(grads);
        adam.step(&mut values, &g, lr, opts.weight_decay);
        net.set_parameters(&values)?;
        state.step += 1;
        state.samples = batch.samples_after;
        rooms_done += batch.rooms as u64;
        steps_done += 1;
        mean_loss = Some(mean_loss.map_or(loss_value, |m| 0.98 * m + 0.02 * loss_value));
        let secs = session.elapsed().as_secs_f64();
        state.elapsed_secs = base_elapsed + secs;
        let mut message = None;

        let finished = state.step >= opts.steps || fraction(state.step, state.elapsed_secs) >= 1.0;
        if !val_samples.is_empty()
            && ((state.step % opts.val_every_steps.max(1) == 0
                && state.step - last_val_step >= opts.val_every_steps.max(2) / 2)
                || last_val.elapsed() >= opts.val_every
                || finished)
        {
            // Validate what is shipped: the weights as they are after the f16 round trip.
            let w = net.to_weights().rounded_to_f16();
            let v = validate(&w, config, &val_samples)?;
            let miou = v.total.miou();
            val_miou = Some(miou);
            let per_group: BTreeMap<&str, f64> = v.groups.iter().map(|(k, c)| (k.as_str(), c.miou())).collect();
            let per_class: Vec<Option<f64>> = v.total.iou();
            log.write(serde_json::json!({
                "step": state.step, "elapsed_secs": state.elapsed_secs, "val_miou": miou,
                "val_accuracy": v.total.accuracy(), "val_groups": per_group, "val_class_iou": per_class,
            }))?;
            if state.best_miou.is_none_or(|b| miou > b) {
                state.best_miou = Some(miou);
                state.best_step = Some(state.step);
                w.save(&best_path, config)?;
                // The state on disk must name the best weights it sits next to.
                save(&net, &state, &adam)?;
                last_ckpt = Instant::now();
            }
            let groups: Vec<String> = per_group.iter().map(|(k, m)| format!("{k} {:.1}", m * 100.0)).collect();
            message = Some(format!(
                "step {}: validation mIoU {:.1} % (accuracy {:.1} %; {})",
                state.step,
                miou * 100.0,
                v.total.accuracy() * 100.0,
                groups.join(", ")
            ));
            last_val = Instant::now();
            last_val_step = state.step;
        }
        if state.step % 10 == 0 || steps_done <= 5 {
            log.write(serde_json::json!({
                "step": state.step, "loss": loss_value, "mean_loss": mean_loss, "lr": lr, "voxels": n,
                "rooms": batch.rooms, "elapsed_secs": state.elapsed_secs,
                "rooms_per_s": rooms_done as f64 / secs.max(1e-9), "secs_per_step": secs / steps_done as f64,
            }))?;
        }
        if state.step % opts.checkpoint_every_steps.max(1) == 0
            || last_ckpt.elapsed() >= opts.checkpoint_every
            || finished
        {
            save(&net, &state, &adam)?;
            last_ckpt = Instant::now();
        }
        progress(&Progress {
            step: state.step,
            steps: opts.steps,
            loss: loss_value,
            mean_loss: mean_loss.unwrap_or(loss_value),
            lr,
            rooms_per_s: rooms_done as f64 / secs.max(1e-9),
            secs_per_step: secs / steps_done as f64,
            val_miou,
            elapsed_secs: state.elapsed_secs,
            message,
        });
    }
    save(&net, &state, &adam)?;
    Ok(state)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn schedule_warms_up_and_decays() {
        assert!(learning_rate(1.0, 0.1, 10, 0, 0.0) < 0.2);
        assert!((learning_rate(1.0, 0.1, 10, 20, 0.0) - 1.0).abs() < 1e-6);
        assert!((learning_rate(1.0, 0.1, 10, 20, 1.0) - 0.1).abs() < 1e-6);
    }

    #[test]
    fn room_order_is_a_seeded_permutation_per_epoch() {
        let a: Vec<usize> = (0..5).map(|p| room_at(5, 1, p).1).collect();
        let mut s = a.clone();
        s.sort_unstable();
        assert_eq!(s, vec![0, 1, 2, 3, 4]);
        assert_eq!(room_at(5, 1, 7).0, 1);
    }

    #[test]
    fn voxel_limit_keeps_a_compact_region_in_order() {
        let coords: Vec<_> = (0..100).flat_map(|x| (0..10).map(move |y| [x, y, 0, 0])).collect();
        let n = coords.len();
        let s = VoxelSample { coords, features: vec![0.0; n * 3], channels: 3, labels: vec![1; n] };
        let cut = limit_voxels(s, 200, &mut ChaCha8Rng::seed_from_u64(3));
        assert_eq!(cut.len(), 200);
        assert!(cut.coords.windows(2).all(|w| w[0] < w[1]));
    }
}
