//! The engine's types in a build without the `gpu` feature: they cannot be constructed
//! ([`GpuEngine::new`] says how to build with the feature), so code written against them
//! compiles in every build and needs no conditional compilation of its own.

use std::convert::Infallible;
use std::sync::Arc;

use semrecon_sparse::{
    BnRelu, ChunkConfig, ChunkedConv, ConvAlgorithm, ConvBackend, Coord, GatherTable, MapKind, ResidentBackend,
};

use crate::error::{GpuError, Result};
use crate::host_level::HostLevel;
use crate::kernel_time::KernelTime;
use crate::transfers::TransferCounts;

/// No device: this build has no GPU engine.
#[derive(Debug)]
pub struct GpuContext {
    never: Infallible,
}

impl GpuContext {
    /// Always [`GpuError::NotBuilt`].
    ///
    /// # Errors
    /// Always.
    pub fn new() -> Result<Self> {
        Err(GpuError::NotBuilt)
    }

    /// Never called (no value exists).
    pub fn adapter_name(&self) -> String {
        match self.never {}
    }

    /// Never called (no value exists).
    pub fn is_software(&self) -> bool {
        match self.never {}
    }

    /// Never called (no value exists).
    pub fn max_buffer_bytes(&self) -> u64 {
        match self.never {}
    }

    /// Never called (no value exists).
    pub fn set_buffer_limit(&mut self, _bytes: u64) {
        match self.never {}
    }

    /// Never called (no value exists).
    pub fn destroy(&self) {
        match self.never {}
    }

    /// Never called (no value exists).
    pub fn profiling(&self) -> bool {
        match self.never {}
    }

    /// Never called (no value exists).
    pub fn kernel_times(&self) -> Vec<KernelTime> {
        match self.never {}
    }

    /// Never called (no value exists).
    pub fn dispatches(&self) -> (u64, f64) {
        match self.never {}
    }

    /// Never called (no value exists).
    pub fn transfers(&self) -> TransferCounts {
        match self.never {}
    }

    /// Never called (no value exists).
    ///
    /// # Errors
    /// Never.
    pub fn flush(&self) -> Result<()> {
        match self.never {}
    }
}

/// No tensors: this build has no GPU engine.
#[derive(Debug)]
pub struct GpuTensor {
    never: Infallible,
}

/// No gather tables: this build has no GPU engine.
#[derive(Debug)]
pub struct GpuGather {
    never: Infallible,
}

/// No hierarchies: this build has no GPU engine.
#[derive(Debug)]
pub struct DeviceHierarchy {
    /// Always empty (no level exists).
    pub levels: Vec<DeviceLevel>,
}

/// No hierarchy levels: this build has no GPU engine.
#[derive(Debug)]
pub struct DeviceLevel {
    /// Never populated (no value exists).
    pub subm: GpuLayer,
    /// Never populated (no value exists).
    pub point: GpuLayer,
    /// Never populated (no value exists).
    pub down: Option<(GpuLayer, GpuLayer)>,
    never: Infallible,
}

impl DeviceLevel {
    /// Never called (no value exists).
    pub fn rows(&self) -> usize {
        match self.never {}
    }

    /// Never called (no value exists).
    pub fn neighbour_pairs(&self) -> usize {
        match self.never {}
    }
}

impl GpuGather {
    /// Never called (no value exists).
    pub fn len(&self) -> usize {
        match self.never {}
    }

    /// Never called (no value exists).
    pub fn is_empty(&self) -> bool {
        match self.never {}
    }

    /// Never called (no value exists).
    pub fn per_row(&self) -> usize {
        match self.never {}
    }
}

/// No layers: this build has no GPU engine.
#[derive(Debug)]
pub struct GpuLayer {
    never: Infallible,
}

/// The GPU engine of a build without the `gpu` feature: cannot be constructed.
#[derive(Debug, Clone)]
pub struct GpuEngine {
    never: Arc<Infallible>,
}

impl GpuEngine {
    /// Always [`GpuError::NotBuilt`].
    ///
    /// # Errors
    /// Always.
    pub fn new(_algorithm: ConvAlgorithm) -> Result<Self> {
        Err(GpuError::NotBuilt)
    }

    /// Never called (no value exists).
    pub fn with_context(ctx: Arc<GpuContext>, _algorithm: ConvAlgorithm) -> Self {
        match ctx.never {}
    }

    /// Never called (no value exists).
    pub fn context(&self) -> &Arc<GpuContext> {
        match *self.never {}
    }

    /// Never called (no value exists).
    pub fn with_algorithm(&self, _algorithm: ConvAlgorithm) -> Self {
        match *self.never {}
    }

    /// Never called (no value exists).
    pub fn import(&self, _layer: &ChunkedConv) -> Result<GpuLayer> {
        match *self.never {}
    }

    /// Never called (no value exists).
    pub fn import_table(&self, _kind: MapKind, _n_in: usize, _table: &[u32]) -> Result<GpuLayer> {
        match *self.never {}
    }

    /// Never called (no value exists).
    pub fn with_chunk(&self, _chunk: ChunkConfig) -> Self {
        match *self.never {}
    }

    /// Never called (no value exists).
    pub fn with_tile(&self, _tile: Option<usize>) -> Result<Self> {
        match *self.never {}
    }

    /// Never called (no value exists).
    pub fn with_splits(&self, _splits: Option<u32>) -> Result<Self> {
        match *self.never {}
    }

    /// Never called (no value exists).
    pub fn build_hierarchy(&self, _coords: &[Coord], _levels: usize) -> Result<DeviceHierarchy> {
        match *self.never {}
    }

    /// Never called (no value exists).
    pub fn interpolation(&self, _h: &DeviceHierarchy, _t: usize, _j: usize) -> Result<GpuGather> {
        match *self.never {}
    }

    /// Never called (no value exists).
    pub fn download_level(&self, _h: &DeviceHierarchy, _i: usize) -> Result<HostLevel> {
        match *self.never {}
    }

    /// Never called (no value exists).
    pub fn download_gather(&self, _g: &GpuGather) -> Result<(Vec<u32>, Vec<f32>)> {
        match *self.never {}
    }
}

impl ConvBackend for GpuEngine {
    type Layer = GpuLayer;
    type Error = GpuError;

    fn name(&self) -> String {
        match *self.never {}
    }

    fn submanifold(&self, _: &[Coord], _: usize) -> Result<GpuLayer> {
        match *self.never {}
    }

    fn downsample(&self, _: &[Coord]) -> Result<(Vec<Coord>, GpuLayer)> {
        match *self.never {}
    }

    fn upsample(&self, _: &[Coord], _: &[Coord]) -> Result<GpuLayer> {
        match *self.never {}
    }

    fn layer_rows(&self, layer: &GpuLayer) -> (usize, usize) {
        match layer.never {}
    }

    fn forward_into(
        &self,
        _: &GpuLayer,
        _: &[f32],
        _: usize,
        _: Option<BnRelu<'_>>,
        _: &[f32],
        _: usize,
        _: &mut [f32],
        _: bool,
    ) -> Result<()> {
        match *self.never {}
    }

    fn backward_input(&self, _: &GpuLayer, _: &[f32], _: usize, _: &[f32], _: usize) -> Result<Vec<f32>> {
        match *self.never {}
    }

    fn backward_weight(&self, _: &GpuLayer, _: &[f32], _: usize, _: &[f32], _: usize) -> Result<Vec<f32>> {
        match *self.never {}
    }
}

impl ResidentBackend for GpuEngine {
    type Tensor = GpuTensor;
    type Gather = GpuGather;

    fn upload(&self, _: &[f32]) -> Result<GpuTensor> {
        match *self.never {}
    }

    fn download(&self, t: &GpuTensor, _: usize) -> Result<Vec<f32>> {
        match t.never {}
    }

    fn tensor_len(&self, t: &GpuTensor) -> usize {
        match t.never {}
    }

    fn reserve(&self, t: &mut GpuTensor, _: usize) -> Result<()> {
        match t.never {}
    }

    fn gather_table(&self, _: &GatherTable) -> Result<GpuGather> {
        match *self.never {}
    }

    fn conv(
        &self,
        layer: &GpuLayer,
        _: &GpuTensor,
        _: usize,
        _: Option<&GpuTensor>,
        _: &GpuTensor,
        _: usize,
        _: &mut GpuTensor,
        _: bool,
    ) -> Result<()> {
        match layer.never {}
    }

    fn gate(&self, g: &mut GpuTensor, _: usize, _: usize) -> Result<()> {
        match g.never {}
    }

    fn gather_add(&self, table: &GpuGather, _: &GpuTensor, _: usize, _: usize, _: &mut GpuTensor) -> Result<()> {
        match table.never {}
    }

    fn add_bias(&self, y: &mut GpuTensor, _: usize, _: &GpuTensor, _: usize) -> Result<()> {
        match y.never {}
    }

    fn argmax_rows(&self, scores: &GpuTensor, _: usize, _: usize) -> Result<Vec<u32>> {
        match scores.never {}
    }
}
