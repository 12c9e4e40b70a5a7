//! Weights of a CBSCN: named `f32` tensors in memory, stored as safetensors with `f16` values
//! (half the size; the network's accuracy does not notice the rounding) and the
//! configuration as JSON in the file's metadata. Loading checks every tensor against
//! [`crate::model::tensor_specs`] and names the file and tensor on any mismatch, so a
//! truncated download or a checkpoint of another configuration fails clearly instead of
//! producing garbage labels. Random He initialisation (seeded) serves tests and training.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use half::f16;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal, Uniform};
use safetensors::tensor::{Dtype, SafeTensors, TensorView};

use crate::config::NetConfig;
use crate::error::{NetError, Result};
use crate::model::{tensor_specs, TensorRole};

/// Metadata key under which the configuration JSON is stored.
pub const CONFIG_METADATA_KEY: &str = "semrecon.config";

/// A dense tensor: shape and row-major values.
#[derive(Debug, Clone, PartialEq)]
pub struct Tensor {
    /// Shape.
    pub shape: Vec<usize>,
    /// Values, row-major, `shape.iter().product()` of them.
    pub data: Vec<f32>,
}

/// Named tensors of one network (see [`crate::model`] for names and shapes).
#[derive(Debug, Clone, PartialEq)]
pub struct Weights {
    tensors: BTreeMap<String, Tensor>,
    /// Where the weights came from (a file path, or `<memory>`), for error messages.
    source: String,
}

impl Weights {
    /// Weights from named tensors (checked against a configuration by [`Self::check`]).
    pub fn from_tensors(tensors: BTreeMap<String, Tensor>) -> Self {
        Self { tensors, source: "<memory>".to_string() }
    }

    /// Seeded He (Kaiming normal, `std = sqrt(2 / fan_in)`) initialisation of every weight;
    /// biases and BN shifts zero, BN scales and running variances one, running means zero:
    /// the state a training run starts from.
    pub fn random(config: &NetConfig, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut tensors = BTreeMap::new();
        for spec in tensor_specs(config) {
            let n = spec.numel();
            let data = match spec.role {
                TensorRole::Weight { fan_in } => {
                    let std = (2.0 / fan_in.max(1) as f32).sqrt();
                    match Normal::new(0.0f32, std) {
                        Ok(d) => (0..n).map(|_| d.sample(&mut rng)).collect(),
                        Err(_) => vec![0.0; n],
                    }
                }
                TensorRole::BnWeight | TensorRole::RunningVar => vec![1.0; n],
                TensorRole::Bias | TensorRole::BnBias | TensorRole::RunningMean => vec![0.0; n],
            };
            tensors.insert(spec.name, Tensor { shape: spec.shape, data });
        }
        Self::from_tensors(tensors)
    }

    /// Gives every batch norm and bias random values like those of a trained network (scale
    /// in [0.5, 1.5], shift and mean in [-0.2, 0.2], variance in [0.5, 2]), so that tests
    /// exercise the folding of batch norm and the biases.
    pub fn perturb_normalisation(&mut self, seed: u64) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (Ok(scale), Ok(shift), Ok(var)) =
            (Uniform::new(0.5f32, 1.5), Uniform::new(-0.2f32, 0.2), Uniform::new(0.5f32, 2.0))
        else {
            return;
        };
        for (name, t) in &mut self.tensors {
            let dist = if name.ends_with("running_var") {
                &var
            } else if name.ends_with(".bias") || name.ends_with("running_mean") {
                &shift
            } else if name.contains(".bn") && name.ends_with(".weight") {
                &scale
            } else {
                continue;
            };
            for v in &mut t.data {
                *v = dist.sample(&mut rng);
            }
        }
    }

    /// Where the weights came from (a file path or `<memory>`).
    pub fn source(&self) -> &str {
        &self.source
    }

    /// All tensors by name.
    pub fn tensors(&self) -> &BTreeMap<String, Tensor> {
        &self.tensors
    }

    /// Mutable tensors (for a trainer writing updated values back).
    pub fn tensors_mut(&mut self) -> &mut BTreeMap<String, Tensor> {
        &mut self.tensors
    }

    /// The values of tensor `name`.
    ///
    /// # Errors
    /// [`NetError::MissingTensor`] naming the source.
    pub fn get(&self, name: &str) -> Result<&[f32]> {
        self.tensors
            .get(name)
            .map(|t| t.data.as_slice())
            .ok_or_else(|| NetError::MissingTensor { file: self.source.clone(), tensor: name.to_string() })
    }

    /// Checks that the tensors are exactly those of `config` with the right shapes.
    ///
    /// # Errors
    /// [`NetError::MissingTensor`], [`NetError::TensorShape`], [`NetError::UnexpectedTensor`].
    pub fn check(&self, config: &NetConfig) -> Result<()> {
        let specs = tensor_specs(config);
        for spec in &specs {
            let t = self
                .tensors
                .get(&spec.name)
                .ok_or_else(|| NetError::MissingTensor { file: self.source.clone(), tensor: spec.name.clone() })?;
            if t.shape != spec.shape || t.data.len() != spec.numel() {
                return Err(NetError::TensorShape {
                    file: self.source.clone(),
                    tensor: spec.name.clone(),
                    expected: spec.shape.clone(),
                    got: t.shape.clone(),
                });
            }
        }
        if self.tensors.len() != specs.len() {
            let known: std::collections::HashSet<&str> = specs.iter().map(|s| s.name.as_str()).collect();
            if let Some(extra) = self.tensors.keys().find(|k| !known.contains(k.as_str()) && !is_optional_head(k)) {
                return Err(NetError::UnexpectedTensor { file: self.source.clone(), tensor: extra.clone() });
            }
        }
        Ok(())
    }

    /// The values as they will be after an `f16` round trip (what [`Self::save`] stores).
    pub fn rounded_to_f16(&self) -> Self {
        let mut w = self.clone();
        for t in w.tensors.values_mut() {
            for v in &mut t.data {
                *v = f16::from_f32(*v).to_f32();
            }
        }
        w
    }

    /// Writes a safetensors file with `f16` values and `config` in the metadata, atomically
    /// (temporary file in the same folder, then rename).
    ///
    /// # Errors
    /// [`NetError::Io`] on write failures, the errors of [`Self::check`] when the weights do
    /// not match `config`.
    pub fn save(&self, path: &Path, config: &NetConfig) -> Result<()> {
        self.check(config)?;
        let bytes: Vec<(String, Vec<u8>, Vec<usize>)> = self
            .tensors
            .iter()
            .map(|(name, t)| {
                let mut b = Vec::with_capacity(t.data.len() * 2);
                for &v in &t.data {
                    b.extend_from_slice(&f16::from_f32(v).to_le_bytes());
                }
                (name.clone(), b, t.shape.clone())
            })
            .collect();
        let file_err = |message: String| NetError::WeightFile { file: path.display().to_string(), message };
        let views = bytes
            .iter()
            .map(|(name, b, shape)| {
                TensorView::new(Dtype::F16, shape.clone(), b)
                    .map(|v| (name.clone(), v))
                    .map_err(|e| file_err(format!("tensor `{name}`: {e}")))
            })
            .collect::<Result<Vec<_>>>()?;
        let metadata = HashMap::from([(CONFIG_METADATA_KEY.to_string(), config.to_json())]);
        let data = safetensors::tensor::serialize(views, Some(metadata)).map_err(|e| file_err(e.to_string()))?;
        let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "weights".into());
        let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
        std::fs::write(&tmp, &data).map_err(|e| NetError::io(&tmp, e))?;
        std::fs::rename(&tmp, path).map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            NetError::io(path, e)
        })
    }

    /// The configuration stored in a weight file's metadata, if any.
    ///
    /// # Errors
    /// [`NetError::Io`], [`NetError::WeightFile`] for unreadable or invalid files.
    pub fn read_config(path: &Path) -> Result<Option<NetConfig>> {
        let bytes = std::fs::read(path).map_err(|e| NetError::io(path, e))?;
        stored_config(path, &bytes)
    }

    /// Reads a weight file (`f16` or `f32` tensors) for `config`: the stored configuration
    /// (when present) must have the same shape, and every tensor must be present with the
    /// right shape, no other tensor allowed.
    ///
    /// # Errors
    /// [`NetError::Io`]; [`NetError::WeightFile`] for a truncated or corrupt file;
    /// [`NetError::ConfigMismatch`]; [`NetError::MissingTensor`], [`NetError::TensorShape`],
    /// [`NetError::TensorDtype`], [`NetError::UnexpectedTensor`] naming file and tensor.
    pub fn load(path: &Path, config: &NetConfig) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| NetError::io(path, e))?;
        let file = path.display().to_string();
        if let Some(saved) = stored_config(path, &bytes)? {
            if !saved.same_shape(config) {
                return Err(NetError::ConfigMismatch { file, saved: saved.summary(), wanted: config.summary() });
            }
        }
        let st = SafeTensors::deserialize(&bytes)
            .map_err(|e| NetError::WeightFile { file: file.clone(), message: e.to_string() })?;
        let mut tensors = BTreeMap::new();
        for spec in tensor_specs(config) {
            let view = st
                .tensor(&spec.name)
                .map_err(|_| NetError::MissingTensor { file: file.clone(), tensor: spec.name.clone() })?;
            if view.shape() != spec.shape.as_slice() {
                return Err(NetError::TensorShape {
                    file,
                    tensor: spec.name,
                    expected: spec.shape,
                    got: view.shape().to_vec(),
                });
            }
            let data = tensor_values(&file, &spec.name, view.dtype(), view.data())?;
            tensors.insert(spec.name, Tensor { shape: spec.shape, data });
        }
        // The optional second head (`crate::home_head`), whatever its shapes: the head checks
        // them when it is built.
        let mut optional: Vec<&str> = st.names().into_iter().filter(|n| is_optional_head(n)).collect();
        optional.sort_unstable();
        for name in optional {
            let view = st
                .tensor(name)
                .map_err(|e| NetError::WeightFile { file: file.clone(), message: format!("tensor `{name}`: {e}") })?;
            let data = tensor_values(&file, name, view.dtype(), view.data())?;
            tensors.insert(name.to_string(), Tensor { shape: view.shape().to_vec(), data });
        }
        if st.len() != tensors.len() {
            if let Some(extra) = st.names().into_iter().find(|n| !tensors.contains_key(*n)) {
                return Err(NetError::UnexpectedTensor { file, tensor: extra.to_string() });
            }
        }
        Ok(Self { tensors, source: file })
    }
}

/// Whether `name` belongs to an optional head that a weights file may carry beside the
/// network's own tensors (the home head, `crate::home_head`).
fn is_optional_head(name: &str) -> bool {
    name.starts_with(crate::home_head::HOME_HEAD_PREFIX)
}

/// A tensor's values as `f32` from its raw little-endian `f16` or `f32` bytes.
fn tensor_values(file: &str, name: &str, dtype: Dtype, raw: &[u8]) -> Result<Vec<f32>> {
    Ok(match dtype {
        Dtype::F16 => raw.chunks_exact(2).map(|b| f16::from_le_bytes([b[0], b[1]]).to_f32()).collect(),
        Dtype::F32 => raw.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect(),
        other => {
            return Err(NetError::TensorDtype {
                file: file.to_string(),
                tensor: name.to_string(),
                dtype: format!("{other:?}"),
            })
        }
    })
}

/// The configuration in the metadata of the safetensors `bytes` read from `path`.
fn stored_config(path: &Path, bytes: &[u8]) -> Result<Option<NetConfig>> {
    let file_err = |message: String| NetError::WeightFile { file: path.display().to_string(), message };
    let (_, meta) = SafeTensors::read_metadata(bytes).map_err(|e| file_err(e.to_string()))?;
    let Some(json) = meta.metadata().as_ref().and_then(|m| m.get(CONFIG_METADATA_KEY)) else {
        return Ok(None);
    };
    let cfg: NetConfig = serde_json::from_str(json).map_err(|e| file_err(format!("stored configuration: {e}")))?;
    Ok(Some(cfg))
}
