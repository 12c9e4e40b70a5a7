//! Network configurations: depth, width, input channels, classes and voxel size of a CBSCN.
//! The named ones (`s20`, `s50`, `live`) are the paper's two networks and a lighter one for
//! the live system; any other is a JSON or TOML file with the same fields, so that a user can
//! train a variant without touching code. The configuration also travels inside every weight
//! file, which is how a checkpoint of another configuration is recognised.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{NetError, Result};

/// Shape of a CBSCN (see [`crate::model`] for the architecture).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NetConfig {
    /// Name, for messages and file metadata.
    pub name: String,
    /// Number of U-Net levels `L` (level 0 is the finest); `L - 1` strided downscales.
    pub levels: usize,
    /// Width `M`: level `i` has `M (i + 1)` channels.
    pub width: usize,
    /// Input feature channels per voxel (3: RGB, see [`crate::inference::color_features`]).
    pub in_channels: usize,
    /// Output classes (13: the S3DIS set in MISSION.md's order).
    pub classes: usize,
    /// Edge of the finest voxels, metres.
    pub voxel_size: f32,
    /// Batch-norm epsilon.
    #[serde(default = "default_bn_eps")]
    pub bn_eps: f32,
}

fn default_bn_eps() -> f32 {
    1e-4
}

/// Names accepted by [`NetConfig::named`].
pub const NAMED_CONFIGS: [&str; 3] = ["s20", "s50", "live"];

impl NetConfig {
    /// A configuration with the defaults for classes (13), input (RGB) and epsilon.
    pub fn new(name: &str, levels: usize, width: usize, voxel_size: f32) -> Self {
        Self {
            name: name.to_string(),
            levels,
            width,
            in_channels: 3,
            classes: 13,
            voxel_size,
            bn_eps: default_bn_eps(),
        }
    }

    /// The paper's scale-20 network: 5 cm voxels, `L = 5`, `M = 32`.
    pub fn s20() -> Self {
        Self::new("s20", 5, 32, 0.05)
    }

    /// The paper's scale-50 network: 2 cm voxels, `L = 7`, `M = 32`.
    pub fn s50() -> Self {
        Self::new("s50", 7, 32, 0.02)
    }

    /// A lighter network for the live path: 5 cm voxels, `L = 5`, `M = 16` (a quarter of the
    /// convolution FLOPs of `s20`).
    pub fn live() -> Self {
        Self::new("live", 5, 16, 0.05)
    }

    /// A named configuration (`s20`, `s50`, `live`).
    pub fn named(name: &str) -> Option<Self> {
        match name {
            "s20" => Some(Self::s20()),
            "s50" => Some(Self::s50()),
            "live" => Some(Self::live()),
            _ => None,
        }
    }

    /// A named configuration, or else a JSON (`.json`) or TOML (any other extension) file.
    ///
    /// # Errors
    /// [`NetError::Config`] for an unknown name that is not a file, unreadable or invalid files.
    pub fn from_name_or_file(spec: &str) -> Result<Self> {
        if let Some(c) = Self::named(spec) {
            return Ok(c);
        }
        let path = Path::new(spec);
        if !path.exists() {
            return Err(NetError::Config {
                source_name: spec.to_string(),
                message: format!("neither a named configuration ({}) nor an existing file", NAMED_CONFIGS.join(", ")),
            });
        }
        Self::load(path)
    }

    /// Reads a configuration file: JSON for `.json`, TOML otherwise.
    ///
    /// # Errors
    /// [`NetError::Io`] when unreadable, [`NetError::Config`] for syntax errors, unknown or
    /// missing fields and invalid values.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| NetError::io(path, e))?;
        let cfg_err = |message: String| NetError::Config { source_name: path.display().to_string(), message };
        let config: Self = if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("json")) {
            serde_json::from_str(&text).map_err(|e| cfg_err(e.to_string()))?
        } else {
            toml::from_str(&text).map_err(|e| cfg_err(e.to_string()))?
        };
        config.validate().map_err(|e| cfg_err(e.to_string()))?;
        Ok(config)
    }

    /// The configuration as JSON (the form stored in weight files).
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).unwrap_or_default()
    }

    /// Checks value ranges.
    ///
    /// # Errors
    /// [`NetError::Config`] naming the bad field.
    pub fn validate(&self) -> Result<()> {
        let bad = |message: String| Err(NetError::Config { source_name: self.name.clone(), message });
        if !(1..=12).contains(&self.levels) {
            return bad(format!("levels = {} (must be 1..=12)", self.levels));
        }
        if !(1..=1024).contains(&self.width) {
            return bad(format!("width = {} (must be 1..=1024)", self.width));
        }
        if self.in_channels == 0 || self.classes == 0 {
            return bad("in_channels and classes must be positive".to_string());
        }
        if !(self.voxel_size.is_finite() && self.voxel_size > 0.0) {
            return bad(format!("voxel_size = {} (must be positive)", self.voxel_size));
        }
        if !(self.bn_eps.is_finite() && self.bn_eps > 0.0) {
            return bad(format!("bn_eps = {} (must be positive)", self.bn_eps));
        }
        Ok(())
    }

    /// Channels of level `i`: `M (i + 1)`.
    pub fn channels(&self, level: usize) -> usize {
        self.width * (level + 1)
    }

    /// One-line summary (`s20: L=5, M=32, in 3, 13 classes, 0.05 m`) for messages.
    pub fn summary(&self) -> String {
        format!(
            "{}: L={}, M={}, in {}, {} classes, {} m",
            self.name, self.levels, self.width, self.in_channels, self.classes, self.voxel_size
        )
    }

    /// Whether two configurations describe the same tensors and preprocessing (the name is
    /// ignored).
    pub fn same_shape(&self, other: &Self) -> bool {
        self.levels == other.levels
            && self.width == other.width
            && self.in_channels == other.in_channels
            && self.classes == other.classes
            && self.voxel_size == other.voxel_size
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn named_configs_and_files_load() {
        for n in NAMED_CONFIGS {
            let c = NetConfig::named(n).unwrap();
            c.validate().unwrap();
            assert_eq!(c.classes, 13);
        }
        let dir = tempfile::tempdir().unwrap();
        let json = dir.path().join("c.json");
        std::fs::write(&json, NetConfig::s50().to_json()).unwrap();
        assert_eq!(NetConfig::load(&json).unwrap(), NetConfig::s50());
        let tomlp = dir.path().join("c.toml");
        std::fs::write(
            &tomlp,
            "name = \"tiny\"\nlevels = 3\nwidth = 8\nin_channels = 3\nclasses = 13\nvoxel_size = 0.1\n",
        )
        .unwrap();
        let t = NetConfig::from_name_or_file(tomlp.to_str().unwrap()).unwrap();
        assert_eq!((t.levels, t.width, t.bn_eps), (3, 8, 1e-4));
        std::fs::write(
            &tomlp,
            "name = \"x\"\nlevels = 0\nwidth = 8\nin_channels = 3\nclasses = 13\nvoxel_size = 0.1\n",
        )
        .unwrap();
        let e = NetConfig::load(&tomlp).unwrap_err().to_string();
        assert!(e.contains("levels") && e.contains("c.toml"), "{e}");
        assert!(NetConfig::from_name_or_file("nope").is_err());
    }
}
