//! Inference with CBSCN on the sparse engines, for the live path (no training framework
//! involved): [`Segmenter`], on the CPU or the GPU ([`Device`]).
//!
//! Per input, the [`NetGeometry`] is built once on the host (kernel maps and chunk plans per
//! level, shared by every layer of the level, and the fusion's interpolation tables). The
//! layers run in [`crate::forward`], one forward generic over the engine's
//! [`ResidentBackend`]: this module only picks the engine and hands it its tensors. The CPU
//! engine's tensors are the host parameters and a host workspace; the GPU engine's weights are
//! uploaded on its first call and kept until the device changes, its activations stay on the
//! device, and each call uploads the input and the geometry and reads back the logits (or, for
//! [`Segmenter::segment_points`], only the labels).
//!
//! Voxels are processed in Z-order (the layout the chunked kernel is fastest with); inputs in
//! any other order are permuted on the way in and the logits back on the way out. Every step
//! is deterministic: the same bits for any number of rayon threads.

use std::time::{Duration, Instant};

use semrecon_gpu::{GpuEngine, GpuGather, GpuLayer, GpuTensor};
use semrecon_sparse::morton::morton_order;
use semrecon_sparse::{
    voxelize, ChunkConfig, ConvAlgorithm, Coord, CpuEngine, GatherTable, MapKind, ResidentBackend, Voxelization,
};

use crate::config::NetConfig;
use crate::error::{NetError, Result};
use crate::forward::{forward, LevelLayers, Params, Prepared, Readout, Scores, Workspace};
use crate::geometry::NetGeometry;
use crate::home_head::{HomeHead, HOME_HEAD_PREFIX};
use crate::model::LevelStats;
use crate::table_geometry::TableGeometry;
use crate::weights::Weights;

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

/// Where the GPU path builds an input's geometry (kernel maps, strided tables, interpolation
/// tables).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum GpuGeometry {
    /// On the device (`semrecon_gpu::DeviceHierarchy`): only the coordinates go up. The
    /// default for the chunked kernel.
    #[default]
    Device,
    /// Neighbour tables on the host ([`TableGeometry`]), uploaded per call: what the rulebook
    /// kernel always uses (it needs pair lists), and a comparison for benchmarks.
    Host,
}

/// Wall time of the two phases of the last call.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Timing {
    /// Kernel maps, chunk plans and interpolation tables (on the GPU with
    /// [`GpuGeometry::Device`]: the coordinates' upload and the device's build, waited for).
    pub geometry: Duration,
    /// The layers.
    pub forward: Duration,
    /// Of `forward`: the geometry prepared for and copied to the device (maps, plans and
    /// tables uploaded); zero on the CPU, which reads the geometry in place.
    pub upload: Duration,
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
    /// The activations the class head reads (after its batch norm and ReLU), `[v, C_0]`,
    /// for the second head ([`crate::home_head`]); empty unless asked for
    /// ([`Segmenter::segment_points_with_features`]).
    pub head_features: Vec<f32>,
}

/// The network ready for inference: folded weights, a chunk configuration and the engines'
/// workspaces.
pub struct Segmenter {
    config: NetConfig,
    /// Folded weights on the host: the CPU engine's tensors, and what the GPU's come from.
    params: Params<Vec<f32>>,
    chunk: ChunkConfig,
    kernel: ConvKernel,
    /// The CPU engine's activations (made on its first call).
    cpu_ws: Option<Workspace<Vec<f32>>>,
    device: Device,
    /// Weights and activations on the GPU of `device` (made on its first call, dropped when
    /// the device changes).
    gpu: Option<Resident<GpuTensor>>,
    gpu_geometry: GpuGeometry,
    stats: Vec<LevelStats>,
    timing: Timing,
    /// The second label set's head, when the weights file has one.
    home_head: Option<HomeHead>,
}

/// The network's tensors on one device: weights uploaded once, activations kept.
struct Resident<T> {
    params: Params<T>,
    ws: Workspace<T>,
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
        let home_head = HomeHead::from_weights(&weights)?;
        if let Some(h) = &home_head {
            let want = HomeHead::input_width(config.channels(0), config.classes);
            if h.inputs() != want {
                return Err(NetError::TensorShape {
                    file: weights.source().to_string(),
                    tensor: format!("{HOME_HEAD_PREFIX}hidden.weight"),
                    expected: vec![want, h.hidden()],
                    got: vec![h.inputs(), h.hidden()],
                });
            }
        }
        Ok(Self {
            config,
            params,
            home_head,
            chunk: ChunkConfig::default(),
            kernel: ConvKernel::Chunked,
            cpu_ws: None,
            device: Device::Cpu,
            gpu: None,
            gpu_geometry: GpuGeometry::Device,
            stats: Vec::new(),
            timing: Timing::default(),
        })
    }

    /// The home head ([`crate::home_head`]: ScanNet's 20 classes and the ceiling) stored with
    /// the weights, if any.
    pub fn home_head(&self) -> Option<&HomeHead> {
        self.home_head.as_ref()
    }

    /// Sets or removes the home head (training it, comparing heads).
    pub fn set_home_head(&mut self, head: Option<HomeHead>) {
        self.home_head = head;
    }

    /// Frees the CPU engine's work buffers (activations of the largest input so far, which only
    /// grow: tens of megabytes after a whole home's passes) while no input is coming; the next
    /// call allocates them again. Outputs do not change.
    pub fn release_workspace(&mut self) {
        self.cpu_ws = None;
    }

    /// Heap bytes of the CPU engine's work buffers.
    pub fn workspace_bytes(&self) -> usize {
        self.cpu_ws.as_ref().map_or(0, |ws| ws.tensors().map(|t| t.capacity() * std::mem::size_of::<f32>()).sum())
    }

    /// Runs the convolutions with `kernel` from now on (the chunked one by default).
    pub fn set_kernel(&mut self, kernel: ConvKernel) {
        self.kernel = kernel;
    }

    /// Cuts the chunked kernels' outputs into chunks of this shape from now on (default
    /// [`ChunkConfig::default`], sized for CPU caches). Outputs are the same within summation
    /// order; only the speed changes.
    pub fn set_chunk(&mut self, chunk: ChunkConfig) {
        self.chunk = chunk;
    }

    /// Runs the network on `device` from now on (the CPU by default); the weights and
    /// results are the same, within 1e-4 relative (summation order). A GPU gets the weights
    /// on its first call and keeps them until the device changes again.
    pub fn set_device(&mut self, device: Device) {
        self.device = device;
        self.gpu = None;
    }

    /// Where the GPU path builds each input's geometry from now on (on the device by default;
    /// the rulebook kernel always builds it on the host). Outputs are the same within 1e-6
    /// relative (the interpolation weights' rounding).
    pub fn set_gpu_geometry(&mut self, geometry: GpuGeometry) {
        self.gpu_geometry = geometry;
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
            return Ok(self.forward_sorted(coords.to_vec(), features, Readout::Logits)?.logits);
        }
        let sorted: Vec<Coord> = order.iter().map(|&r| coords[r as usize]).collect();
        let mut feats = Vec::with_capacity(features.len());
        for &r in &order {
            feats.extend_from_slice(&features[r as usize * cin..(r as usize + 1) * cin]);
        }
        let logits = self.forward_sorted(sorted, &feats, Readout::Logits)?.logits;
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
        let v = self.voxelize_points(points, colors)?;
        let (coords, features) = v.tensor.into_parts();
        // Only the labels come back from the engine (an argmax where the logits are).
        let voxel_class = self.forward_sorted(coords, &features, Readout::Labels)?.labels;
        // Labels are bytes throughout the pipeline, as `argmax_rows` makes them.
        Ok(v.point_to_voxel.iter().map(|&r| voxel_class[r as usize] as u8).collect())
    }

    /// The voxels of a coloured point cloud at the configuration's voxel size.
    fn voxelize_points(&self, points: &[[f32; 3]], colors: &[[u8; 3]]) -> Result<Voxelization> {
        if points.len() != colors.len() {
            return Err(NetError::InvalidInput(format!("{} points but {} colours", points.len(), colors.len())));
        }
        if self.config.in_channels != 3 {
            return Err(NetError::InvalidInput(format!(
                "configuration {} takes {} input channels, not RGB",
                self.config.name, self.config.in_channels
            )));
        }
        Ok(voxelize(points, &color_features(colors), 3, self.config.voxel_size, 0)?)
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
        let v = self.voxelize_points(points, colors)?;
        let (coords, features) = v.tensor.into_parts();
        let logits = self.forward_sorted(coords.clone(), &features, Readout::Logits)?.logits;
        Ok(PointScores { coords, features, logits, point_to_voxel: v.point_to_voxel, head_features: Vec::new() })
    }

    /// [`segment_points_scores`](Self::segment_points_scores), also reading back what the
    /// class head sees of each voxel (`head_features`): the input of a second head.
    ///
    /// # Shapes
    /// As [`segment_points_scores`](Self::segment_points_scores); `head_features`:
    /// `[v, C_0]`.
    ///
    /// # Errors
    /// As [`segment_points`](Self::segment_points).
    pub fn segment_points_with_features(&mut self, points: &[[f32; 3]], colors: &[[u8; 3]]) -> Result<PointScores> {
        let v = self.voxelize_points(points, colors)?;
        let (coords, features) = v.tensor.into_parts();
        let scores = self.forward_sorted(coords.clone(), &features, Readout::LogitsAndDecoder)?;
        let head_features = self.head_activations(&scores.decoder);
        Ok(PointScores { coords, features, logits: scores.logits, point_to_voxel: v.point_to_voxel, head_features })
    }

    /// `relu(bn(x))` of the class head's folded batch norm, row by row.
    ///
    /// # Shapes
    /// `decoder`: `[v, C_0]`; result `[v, C_0]`.
    fn head_activations(&self, decoder: &[f32]) -> Vec<f32> {
        let (scale, shift) = self.params.head_bn_parts();
        let c = scale.len();
        decoder.iter().enumerate().map(|(i, &x)| (x * scale[i % c] + shift[i % c]).max(0.0)).collect()
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
        let (logits, upload) = if n > 0 {
            let (scores, upload) = self.run_layers(geometry, features, Readout::Logits)?;
            (scores.logits, upload)
        } else {
            (Vec::new(), Duration::ZERO)
        };
        self.timing = Timing { geometry: Duration::ZERO, forward: t.elapsed(), upload };
        self.stats = geometry.stats();
        Ok(logits)
    }

    /// The forward pass on Z-ordered voxels.
    fn forward_sorted(&mut self, coords: Vec<Coord>, feats: &[f32], readout: Readout) -> Result<Scores> {
        if coords.is_empty() {
            self.stats.clear();
            return Ok(Scores::default());
        }
        let t0 = Instant::now();
        if let Device::Gpu(engine) = &self.device {
            let engine = engine.clone();
            if self.kernel == ConvKernel::Chunked && self.gpu_geometry == GpuGeometry::Device {
                return self.run_device_geometry(&engine, &coords, feats, readout, t0);
            }
            // The GPU's kernels walk rows in Z-order themselves: tables, no chunk plans.
            let geo = TableGeometry::build(coords, &self.config)?;
            let t1 = Instant::now();
            let (scores, upload) = self.run_table_layers(&engine, &geo, feats, readout)?;
            self.timing = Timing { geometry: t1 - t0, forward: t1.elapsed(), upload };
            self.stats = geo.stats();
            return Ok(scores);
        }
        let geo = NetGeometry::build(coords, &self.config, &self.chunk)?;
        if self.kernel == ConvKernel::Rulebook {
            geo.build_maps();
        }
        let t1 = Instant::now();
        let (scores, upload) = self.run_layers(&geo, feats, readout)?;
        self.timing = Timing { geometry: t1 - t0, forward: t1.elapsed(), upload };
        self.stats = geo.stats();
        Ok(scores)
    }

    /// The engines' algorithm of the chosen kernel.
    fn algorithm(&self) -> ConvAlgorithm {
        match self.kernel {
            ConvKernel::Chunked => ConvAlgorithm::Chunked,
            ConvKernel::Rulebook => ConvAlgorithm::Rulebook,
        }
    }

    /// The layers on the chosen engine, with its tensors: the CPU engine reads the host
    /// parameters and the geometry's layers in place; the GPU engine gets the weights on its
    /// first call (kept), the geometry uploaded per call (every layer of a level then shares
    /// it). The forward itself is one, generic over the engine. Also returns the time spent
    /// uploading the geometry.
    fn run_layers(&mut self, geo: &NetGeometry, feats: &[f32], readout: Readout) -> Result<(Scores, Duration)> {
        let algorithm = self.algorithm();
        let Self { config, params, cpu_ws, device, gpu, chunk, .. } = self;
        let rows: Vec<usize> = geo.levels.iter().map(|l| l.coords.len()).collect();
        match device {
            Device::Cpu => {
                let engine = CpuEngine { algorithm, chunk: *chunk };
                let ws = match cpu_ws {
                    Some(ws) => ws,
                    None => cpu_ws.insert(Workspace::new(&engine, config.levels)?),
                };
                let levels = geo
                    .levels
                    .iter()
                    .map(|l| LevelLayers { subm: &l.subm, point: &l.point, down: l.down.as_ref().map(|(d, u)| (d, u)) })
                    .collect();
                let interp = geo.interp.iter().map(|per| per.iter().collect()).collect();
                let prepared = Prepared::<CpuEngine> { levels, interp, rows };
                Ok((forward(&engine, &prepared, config, params, ws, feats, readout)?, Duration::ZERO))
            }
            Device::Gpu(device) => {
                let engine = device.with_algorithm(algorithm);
                let resident = gpu_resident(gpu, &engine, config, params)?;
                let t = Instant::now();
                let mut owned = Vec::with_capacity(geo.levels.len());
                for l in &geo.levels {
                    let down = match &l.down {
                        Some((d, u)) => Some((engine.import(d)?, engine.import(u)?)),
                        None => None,
                    };
                    owned.push((engine.import(&l.subm)?, engine.import(&l.point)?, down));
                }
                gpu_forward(&engine, &owned, &geo.interp, rows, t, config, resident, feats, readout)
            }
        }
    }
}

impl Segmenter {
    /// The layers on the GPU engine from a [`TableGeometry`]: the weights on the device (kept
    /// between calls), the tables uploaded per call, one forward. Also returns the time spent
    /// uploading the geometry.
    fn run_table_layers(
        &mut self,
        device: &GpuEngine,
        geo: &TableGeometry,
        feats: &[f32],
        readout: Readout,
    ) -> Result<(Scores, Duration)> {
        let engine = device.with_algorithm(self.algorithm());
        let Self { config, params, gpu, .. } = self;
        let resident = gpu_resident(gpu, &engine, config, params)?;
        let t = Instant::now();
        let sub = MapKind::Submanifold { kernel_size: 3 };
        let point = MapKind::Submanifold { kernel_size: 1 };
        let mut owned = Vec::with_capacity(geo.levels.len());
        for (i, l) in geo.levels.iter().enumerate() {
            let n = l.coords.len();
            let identity: Vec<u32> = (0..n as u32).collect();
            let down = match &l.down {
                Some((d, u)) => {
                    let n_next = geo.levels.get(i + 1).map_or(0, |next| next.coords.len());
                    Some((engine.import_table(MapKind::Down, n, d)?, engine.import_table(MapKind::Up, n_next, u)?))
                }
                None => None,
            };
            owned.push((engine.import_table(sub, n, &l.subm)?, engine.import_table(point, n, &identity)?, down));
        }
        let rows = geo.levels.iter().map(|l| l.coords.len()).collect();
        gpu_forward(&engine, &owned, &geo.interp, rows, t, config, resident, feats, readout)
    }
}

impl Segmenter {
    /// The chunked forward on the GPU with the geometry built on the device: the coordinates
    /// go up, the levels and interpolation tables are made there, the weights are resident.
    fn run_device_geometry(
        &mut self,
        device: &GpuEngine,
        coords: &[Coord],
        feats: &[f32],
        readout: Readout,
        t0: Instant,
    ) -> Result<Scores> {
        let engine = device.with_algorithm(ConvAlgorithm::Chunked);
        let Self { config, params, gpu, .. } = self;
        let resident = gpu_resident(gpu, &engine, config, params)?;
        let l = config.levels;
        let h = engine.build_hierarchy(coords, l)?;
        // The fusion's tables: level j onto level t, t < j <= L - 2 (as `interpolation_tables`).
        let mut tables = Vec::new();
        for t in 0..l.saturating_sub(2) {
            tables.push(
                (t + 1..=l - 2).map(|j| engine.interpolation(&h, t, j)).collect::<std::result::Result<Vec<_>, _>>()?,
            );
        }
        let t1 = Instant::now();
        let levels = h
            .levels
            .iter()
            .map(|v| LevelLayers { subm: &v.subm, point: &v.point, down: v.down.as_ref().map(|(d, u)| (d, u)) })
            .collect();
        let interp = tables.iter().map(|per| per.iter().collect()).collect();
        let rows = h.levels.iter().map(|v| v.rows()).collect();
        let prepared = Prepared::<GpuEngine> { levels, interp, rows };
        let scores = forward(&engine, &prepared, config, &resident.params, &mut resident.ws, feats, readout)?;
        self.timing = Timing { geometry: t1 - t0, forward: t1.elapsed(), upload: Duration::ZERO };
        self.stats =
            h.levels.iter().map(|v| LevelStats { voxels: v.rows(), neighbour_pairs: v.neighbour_pairs() }).collect();
        Ok(scores)
    }
}

/// One level's layers on the GPU: submanifold, pointwise, and the strided pair to the next.
type GpuLevel = (GpuLayer, GpuLayer, Option<(GpuLayer, GpuLayer)>);

/// The network's weights and workspace on the GPU of `engine`: uploaded on the first call,
/// kept until the device changes.
fn gpu_resident<'a>(
    gpu: &'a mut Option<Resident<GpuTensor>>,
    engine: &GpuEngine,
    config: &NetConfig,
    params: &Params<Vec<f32>>,
) -> Result<&'a mut Resident<GpuTensor>> {
    Ok(match gpu {
        Some(r) => r,
        None => gpu.insert(Resident {
            params: params.map(&mut |t| engine.upload(t))?,
            ws: Workspace::new(engine, config.levels)?,
        }),
    })
}

/// The forward on the GPU over layers already uploaded (since `t`): uploads the interpolation
/// tables, then runs; returns the scores and the geometry's upload time (from `t`).
#[allow(clippy::too_many_arguments)]
fn gpu_forward(
    engine: &GpuEngine,
    owned: &[GpuLevel],
    interp: &[Vec<GatherTable>],
    rows: Vec<usize>,
    t: Instant,
    config: &NetConfig,
    resident: &mut Resident<GpuTensor>,
    feats: &[f32],
    readout: Readout,
) -> Result<(Scores, Duration)> {
    let tables: Vec<Vec<GpuGather>> = interp
        .iter()
        .map(|per| per.iter().map(|t: &GatherTable| engine.gather_table(t)).collect())
        .collect::<std::result::Result<_, _>>()?;
    let levels = owned
        .iter()
        .map(|(subm, point, down)| LevelLayers { subm, point, down: down.as_ref().map(|(d, u)| (d, u)) })
        .collect();
    let interp = tables.iter().map(|per| per.iter().collect()).collect();
    let upload = t.elapsed();
    let prepared = Prepared::<GpuEngine> { levels, interp, rows };
    Ok((forward(engine, &prepared, config, &resident.params, &mut resident.ws, feats, readout)?, upload))
}

/// Where the network runs.
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

/// The index of the largest score of every row of `k` scores (the first on ties): the class
/// of each voxel from its logits.
///
/// # Shapes
/// `scores`: rows x `k`, row-major; the result has one entry per row.
pub(crate) fn argmax_rows(scores: &[f32], k: usize) -> Vec<u8> {
    semrecon_sparse::elementwise::argmax_rows(scores, k).into_iter().map(|c| c as u8).collect()
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
            let ip = interp_table(&fine, &anc, &nbr, shift).unwrap();
            let mut d = vec![0f32; fine.len()];
            semrecon_sparse::elementwise::gather_add(&ip, &values, 1, 1, &mut d).unwrap();
            for (got, want) in d.iter().zip(&expected) {
                assert!((got - want).abs() < 1e-6, "shift {shift}: {d:?} vs {expected:?}");
            }
        }
    }
}
