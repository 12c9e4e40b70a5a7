//! The shipped default model and the loading of model files by users: `semrecon segment`,
//! `semrecon eval seg` and the demo run the trained `s20` network without flags, so its file
//! must be found both from a source checkout and from an installed binary, and every way a
//! user's file can be wrong (missing, truncated, another configuration) must say what is
//! wrong rather than produce labels from garbage.
//!
//! The default file is found in this order: the path in `SEMRECON_MODEL`; `models/s20.safetensors`
//! next to the executable (an installed copy); the repository's
//! `crates/net/models/s20.safetensors` (the path known at compile time).

use std::path::{Path, PathBuf};

use crate::config::NetConfig;
use crate::error::{NetError, Result};
use crate::inference::Segmenter;
use crate::weights::Weights;

/// Environment variable naming a model file that replaces the shipped one.
pub const MODEL_ENV: &str = "SEMRECON_MODEL";

/// Path of the shipped model relative to the executable's folder or to the crate.
pub const MODEL_RELATIVE_PATH: &str = "models/s20.safetensors";

/// The shipped model in the source tree (known at compile time).
const SOURCE_TREE_MODEL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/models/s20.safetensors");

/// Where the default model is looked for: `SEMRECON_MODEL` when set (even if the file is
/// absent, so that a typo is reported rather than silently replaced); else
/// `models/s20.safetensors` next to the executable when that file exists; else the source
/// tree's `crates/net/models/s20.safetensors`.
pub fn default_model_path() -> PathBuf {
    if let Some(p) = std::env::var_os(MODEL_ENV).filter(|p| !p.is_empty()) {
        return PathBuf::from(p);
    }
    if let Some(dir) = std::env::current_exe().ok().and_then(|e| e.parent().map(Path::to_path_buf)) {
        let beside = dir.join(MODEL_RELATIVE_PATH);
        if beside.is_file() {
            return beside;
        }
    }
    PathBuf::from(SOURCE_TREE_MODEL)
}

/// The network of [`default_model_path`], ready for inference.
///
/// # Errors
/// [`NetError::Io`] (kind `NotFound`) saying how to get a model when there is no file;
/// otherwise the errors of [`load`].
pub fn load_default() -> Result<Segmenter> {
    let path = default_model_path();
    if !path.is_file() {
        return Err(NetError::io(
            &path,
            std::io::Error::new(
                std::io::ErrorKind::NotFound,
                format!(
                    "no shipped model at {}: train one with `semrecon train` or pass --model \
                     (or set {MODEL_ENV})",
                    path.display()
                ),
            ),
        ));
    }
    load(&path, None)
}

/// A model file ready for inference, with the configuration stored in it, or `config` when
/// the file has none. With both, they must describe the same network.
///
/// # Errors
/// [`NetError::Io`] for unreadable files; [`NetError::WeightFile`] for truncated or corrupt
/// files (with the size the header describes and the size found), and for files with no
/// stored configuration when `config` is `None`; [`NetError::ConfigMismatch`] naming the
/// fields that differ; the tensor errors of [`Weights::load`].
pub fn load(path: &Path, config: Option<&NetConfig>) -> Result<Segmenter> {
    let stored = Weights::read_config(path).map_err(|e| explain_truncation(path, e))?;
    let config = match (stored, config) {
        (Some(saved), Some(wanted)) => {
            if !saved.same_shape(wanted) {
                return Err(NetError::ConfigMismatch {
                    file: path.display().to_string(),
                    saved: saved.summary(),
                    wanted: format!(
                        "{} (they differ in {}; file first)",
                        wanted.summary(),
                        config_differences(&saved, wanted)
                    ),
                });
            }
            // The file's own values (name, epsilon) are those it was trained with.
            saved
        }
        (Some(saved), None) => saved,
        (None, Some(wanted)) => wanted.clone(),
        (None, None) => {
            return Err(NetError::WeightFile {
                file: path.display().to_string(),
                message: "no configuration is stored in the file: pass the configuration it was trained with \
                          (--config s20|s50|live|FILE)"
                    .to_string(),
            })
        }
    };
    config.validate()?;
    let weights = Weights::load(path, &config).map_err(|e| explain_truncation(path, e))?;
    Segmenter::new(weights, config)
}

/// The fields in which two configurations differ, as `levels 5 vs 7, width 32 vs 16`
/// (first value: `a`'s).
pub fn config_differences(a: &NetConfig, b: &NetConfig) -> String {
    let mut d = Vec::new();
    let mut field = |name: &str, x: String, y: String| {
        if x != y {
            d.push(format!("{name} {x} vs {y}"));
        }
    };
    field("levels", a.levels.to_string(), b.levels.to_string());
    field("width", a.width.to_string(), b.width.to_string());
    field("in_channels", a.in_channels.to_string(), b.in_channels.to_string());
    field("classes", a.classes.to_string(), b.classes.to_string());
    field("voxel_size", a.voxel_size.to_string(), b.voxel_size.to_string());
    if d.is_empty() {
        "nothing".to_string()
    } else {
        d.join(", ")
    }
}

/// Replaces the safetensors library's message for a short file ("incomplete buffer") by the
/// sizes involved: how many bytes the header describes and how many the file has.
fn explain_truncation(path: &Path, err: NetError) -> NetError {
    let NetError::WeightFile { file, message } = err else { return err };
    let Ok(len) = std::fs::metadata(path).map(|m| m.len()) else {
        return NetError::WeightFile { file, message };
    };
    match described_size(path) {
        Some(expected) if expected > len => NetError::WeightFile {
            file,
            message: format!(
                "truncated: the file has {len} bytes but its header describes {expected} ({} missing)",
                expected - len
            ),
        },
        _ if len < 8 => NetError::WeightFile {
            file,
            message: format!("truncated: {len} bytes, not even the 8-byte header length of a safetensors file"),
        },
        _ => NetError::WeightFile { file, message },
    }
}

/// The total size a safetensors file's header describes: 8 bytes of header length, the
/// header, and the end of the furthest tensor; `None` when the header cannot be read.
fn described_size(path: &Path) -> Option<u64> {
    use std::io::Read;
    let mut f = std::fs::File::open(path).ok()?;
    let mut n = [0u8; 8];
    f.read_exact(&mut n).ok()?;
    let header_len = u64::from_le_bytes(n);
    let file_len = f.metadata().ok()?.len();
    if header_len > file_len.saturating_sub(8) {
        return Some(8 + header_len);
    }
    let mut header = vec![0u8; usize::try_from(header_len).ok()?];
    f.read_exact(&mut header).ok()?;
    let json: serde_json::Value = serde_json::from_slice(&header).ok()?;
    let data_end = json
        .as_object()?
        .iter()
        .filter(|(k, _)| k.as_str() != "__metadata__")
        .filter_map(|(_, v)| v.get("data_offsets")?.get(1)?.as_u64())
        .max()
        .unwrap_or(0);
    Some(8 + header_len + data_end)
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn tiny() -> NetConfig {
        NetConfig::new("tiny", 3, 4, 0.05)
    }

    #[test]
    fn a_saved_model_loads_with_its_stored_configuration() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.safetensors");
        Weights::random(&tiny(), 3).save(&path, &tiny()).unwrap();
        let mut net = load(&path, None).unwrap();
        assert_eq!(net.config(), &tiny());
        let labels = net.segment_points(&[[0.0, 0.0, 0.0], [0.06, 0.0, 0.0]], &[[9, 9, 9], [200, 0, 0]]).unwrap();
        assert_eq!(labels.len(), 2);
        assert!(load(&path, Some(&tiny())).is_ok());
    }

    #[test]
    fn another_configuration_is_named_field_by_field() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.safetensors");
        Weights::random(&tiny(), 3).save(&path, &tiny()).unwrap();
        let other = NetConfig::new("other", 4, 8, 0.05);
        let e = load(&path, Some(&other)).unwrap_err().to_string();
        assert!(e.contains("m.safetensors") && e.contains("levels 3 vs 4") && e.contains("width 4 vs 8"), "{e}");
        // Weights::load alone also refuses, naming both configurations.
        let e = Weights::load(&path, &other).unwrap_err().to_string();
        assert!(e.contains("L=3, M=4") && e.contains("L=4, M=8"), "{e}");
    }

    #[test]
    fn a_file_without_configuration_is_checked_tensor_by_tensor() {
        use safetensors::tensor::{Dtype, TensorView};
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bare.safetensors");
        // Tensors of `tiny` written without metadata (as a foreign exporter would).
        let w = Weights::random(&tiny(), 1);
        let bytes: Vec<(String, Vec<u8>, Vec<usize>)> = w
            .tensors()
            .iter()
            .map(|(n, t)| (n.clone(), t.data.iter().flat_map(|v| v.to_le_bytes()).collect(), t.shape.clone()))
            .collect();
        let views: Vec<(String, TensorView)> =
            bytes.iter().map(|(n, b, s)| (n.clone(), TensorView::new(Dtype::F32, s.clone(), b).unwrap())).collect();
        std::fs::write(&path, safetensors::tensor::serialize(views, None).unwrap()).unwrap();
        let e = load(&path, None).unwrap_err().to_string();
        assert!(e.contains("no configuration is stored") && e.contains("--config"), "{e}");
        assert!(load(&path, Some(&tiny())).is_ok());
        let e = load(&path, Some(&NetConfig::new("wide", 3, 8, 0.05))).unwrap_err().to_string();
        assert!(e.contains("bare.safetensors") && e.contains("shape") && e.contains("input.conv.weight"), "{e}");
    }

    #[test]
    fn a_truncated_file_says_how_much_is_missing() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.safetensors");
        Weights::random(&tiny(), 3).save(&path, &tiny()).unwrap();
        let full = std::fs::read(&path).unwrap();
        for keep in [full.len() - 100, 200, 5] {
            std::fs::write(&path, &full[..keep]).unwrap();
            let e = load(&path, None).unwrap_err().to_string();
            assert!(e.contains("m.safetensors") && e.contains("truncated"), "{keep}: {e}");
            if keep > 8 {
                assert!(e.contains(&format!("has {keep} bytes")), "{e}");
            }
        }
        std::fs::write(&path, &full[..full.len() - 100]).unwrap();
        let e = load(&path, None).unwrap_err().to_string();
        assert!(e.contains(&format!("describes {}", full.len())) && e.contains("100 missing"), "{e}");
    }

    /// The repository's model, once trained: `s20`, f16 throughout, at most 20 MB, loadable.
    #[test]
    fn the_shipped_model_is_a_small_f16_s20() {
        let path = Path::new(SOURCE_TREE_MODEL);
        if !path.is_file() {
            eprintln!("skipped: no shipped model at {} yet", path.display());
            return;
        }
        let bytes = std::fs::read(path).unwrap();
        assert!(bytes.len() <= 20_000_000, "{} bytes", bytes.len());
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        for (name, view) in st.tensors() {
            assert_eq!(view.dtype(), safetensors::Dtype::F16, "{name}");
        }
        let net = load(path, Some(&NetConfig::s20())).unwrap();
        assert!(net.config().same_shape(&NetConfig::s20()));
    }

    #[test]
    fn the_default_path_follows_the_environment() {
        // One test touches the variable, so no other test of this process races with it.
        std::env::set_var(MODEL_ENV, "/nonexistent/semrecon-model.safetensors");
        assert_eq!(default_model_path(), PathBuf::from("/nonexistent/semrecon-model.safetensors"));
        let e = load_default().unwrap_err().to_string();
        assert!(e.contains("no shipped model at /nonexistent/semrecon-model.safetensors"), "{e}");
        assert!(e.contains("semrecon train") && e.contains("--model"), "{e}");
        std::env::remove_var(MODEL_ENV);
        assert!(default_model_path().ends_with("models/s20.safetensors"));
    }
}
