//! The generated scenes as command-line sources: `synth:SEED` (one room, 10 s),
//! `synth-loop:SEED` (two rooms joined by a doorway, a 60 s loop round both and back through
//! the doorway: a loop for loop closure) and `synth-flat:SEED` (a five-room flat of about
//! 80 m^2, a 5 min walk through every room and back), each rendered on the fly with exact
//! ground truth. Options follow the seed after more colons, in any order:
//!
//! - `noisy`: the uncalibrated sensor ([`SensorModel::kinect_uncalibrated`]), whose
//!   systematic depth bias makes tracking drift by centimetres a minute, as on real scans;
//! - `SECONDSs` (`90s`, `600s`): the length of the scan in whole seconds, at 30 fps.
//!
//! E.g. `synth-loop:3:noisy`, `synth-flat:1:600s`, `synth:7:noisy:60s`.

use std::fmt;

use crate::error::Result;
use crate::mesh::LabeledMesh;
use crate::render::RenderedScan;
use crate::sensor::SensorModel;
use crate::synth::{generate_flat, generate_room, FlatConfig, FlatKind, RoomConfig};

use super::synthetic::{synthetic_scan, SyntheticScanConfig};
use super::synthetic_flat::synthetic_flat_scan;

/// Which generated scene a source scans.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SyntheticScene {
    /// One room (`synth:`), the walk a loop round its middle.
    Room,
    /// Two rooms joined by a doorway (`synth-loop:`), the walk round one, through the
    /// doorway, round the other and back.
    TwoRooms,
    /// A five-room flat (`synth-flat:`), the walk through every room and back.
    Flat,
}

impl SyntheticScene {
    /// The source kind on the command line.
    pub fn kind(self) -> &'static str {
        match self {
            Self::Room => "synth",
            Self::TwoRooms => "synth-loop",
            Self::Flat => "synth-flat",
        }
    }

    /// Length of the scan when the source does not give one, seconds.
    pub fn default_seconds(self) -> f64 {
        match self {
            Self::Room => SyntheticScanConfig::DEFAULT_FRAMES as f64 / 30.0,
            Self::TwoRooms => 60.0,
            Self::Flat => 300.0,
        }
    }

    /// The scene of a source kind (`synth`, `synth-loop`, `synth-flat`), if it is one.
    pub fn from_kind(kind: &str) -> Option<Self> {
        [Self::Room, Self::TwoRooms, Self::Flat].into_iter().find(|s| s.kind() == kind)
    }
}

/// A generated-scene source: scene, seed and options (see the module documentation).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SyntheticSource {
    /// What is scanned.
    pub scene: SyntheticScene,
    /// Seed of the scene, the walk and the sensor noise.
    pub seed: u64,
    /// Whether the sensor is the uncalibrated, drifting one.
    pub noisy: bool,
    /// Length of the scan, whole seconds; `None` = [`SyntheticScene::default_seconds`].
    pub seconds: Option<u32>,
}

/// Frame rate of every generated scan, Hz.
const FRAME_RATE: f64 = 30.0;

/// Longest scan a source may ask for, seconds (an hour: 108,000 poses).
const MAX_SECONDS: u32 = 3600;

impl SyntheticSource {
    /// `synth:SEED`: one room, 10 s, the Kinect-like sensor.
    pub fn room(seed: u64) -> Self {
        Self { scene: SyntheticScene::Room, seed, noisy: false, seconds: None }
    }

    /// Parses what follows `KIND:` (`SEED[:OPTION]...`) for `scene`; the error says what is
    /// wrong without the source's name.
    pub fn parse(scene: SyntheticScene, rest: &str) -> std::result::Result<Self, String> {
        let mut parts = rest.split(':');
        let seed_text = parts.next().unwrap_or_default().trim();
        let kind = scene.kind();
        let seed = seed_text
            .parse()
            .map_err(|_| format!("`{seed_text}` is not a seed (a non-negative integer) for {kind}:SEED"))?;
        let mut source = Self { scene, seed, noisy: false, seconds: None };
        for option in parts {
            let option = option.trim();
            if option == "noisy" {
                source.noisy = true;
            } else if let Some(number) = option.strip_suffix('s') {
                let seconds: u32 =
                    number.parse().map_err(|_| format!("`{option}` is not a length in whole seconds like 60s"))?;
                if !(1..=MAX_SECONDS).contains(&seconds) {
                    return Err(format!("length `{option}` must be between 1 s and {MAX_SECONDS} s"));
                }
                source.seconds = Some(seconds);
            } else {
                return Err(format!("unknown option `{option}` (expected `noisy` or a length like `60s`)"));
            }
        }
        Ok(source)
    }

    /// Frames of the scan (30 per second).
    pub fn frames(&self) -> usize {
        (self.seconds.map_or(self.scene.default_seconds(), f64::from) * FRAME_RATE).round() as usize
    }

    /// The scan's configuration: frames, the VGA Kinect-like camera, the sensor (seeded with
    /// the seed; uncalibrated when `noisy`).
    pub fn config(&self) -> SyntheticScanConfig {
        let mut config = SyntheticScanConfig::new(self.seed);
        config.frames = self.frames();
        config.frame_rate = FRAME_RATE;
        if self.noisy {
            config.sensor = SensorModel::kinect_uncalibrated().with_seed(self.seed);
        }
        config
    }

    /// Generates the scene and renders the scan: the scene's labelled mesh (the ground
    /// truth) and the frames.
    pub fn open(&self) -> Result<(LabeledMesh, RenderedScan)> {
        let config = self.config();
        let name = self.to_string();
        match self.scene {
            SyntheticScene::Room => {
                let (room, scan) = synthetic_scan(&config)?;
                Ok((room.mesh, scan.renamed(name)))
            }
            SyntheticScene::TwoRooms | SyntheticScene::Flat => {
                let (flat, scan) = synthetic_flat_scan(&self.flat_config(), &config, name)?;
                Ok((flat.mesh, scan))
            }
        }
    }

    /// The scene's labelled mesh alone (no rendering): the ground truth a reconstruction
    /// of the scan is measured against.
    pub fn ground_truth(&self) -> Result<LabeledMesh> {
        Ok(match self.scene {
            SyntheticScene::Room => generate_room(&RoomConfig { seed: self.seed, style: None }).mesh,
            SyntheticScene::TwoRooms | SyntheticScene::Flat => generate_flat(&self.flat_config())?.mesh,
        })
    }

    fn flat_config(&self) -> FlatConfig {
        let kind = if self.scene == SyntheticScene::Flat { FlatKind::Home } else { FlatKind::TwoRooms };
        FlatConfig { seed: self.seed, kind }
    }
}

impl fmt::Display for SyntheticSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.scene.kind(), self.seed)?;
        if self.noisy {
            f.write_str(":noisy")?;
        }
        if let Some(s) = self.seconds {
            write!(f, ":{s}s")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::FrameSource;

    #[test]
    fn sources_parse_and_print_back() {
        for (kind, rest, scene) in [
            ("synth", "3", SyntheticScene::Room),
            ("synth-loop", "4:noisy", SyntheticScene::TwoRooms),
            ("synth-flat", "1:noisy:600s", SyntheticScene::Flat),
            ("synth", "7:90s", SyntheticScene::Room),
        ] {
            assert_eq!(SyntheticScene::from_kind(kind), Some(scene));
            let s = SyntheticSource::parse(scene, rest).expect(rest);
            assert_eq!(s.to_string(), format!("{kind}:{rest}"));
        }
        let s = SyntheticSource::parse(SyntheticScene::Flat, "2:30s:noisy").expect("any order");
        assert!(s.noisy && s.seconds == Some(30) && s.frames() == 900);
        assert_eq!(SyntheticSource::parse(SyntheticScene::TwoRooms, "2").expect("loop").frames(), 1800);
        assert_eq!(SyntheticSource::room(2).frames(), 300);
        assert_eq!(SyntheticSource::parse(SyntheticScene::Flat, "2").expect("flat").frames(), 9000);
    }

    #[test]
    fn bad_sources_say_what_is_wrong() {
        for (rest, says) in [
            ("x", "not a seed"),
            ("-1", "not a seed"),
            ("", "not a seed"),
            ("1:loud", "unknown option `loud`"),
            ("1:", "unknown option ``"),
            ("1:abcs", "not a length"),
            ("1:0s", "between"),
            ("1:99999s", "between"),
            ("1:NaNs", "not a length"),
            ("1:2.5s", "not a length"),
        ] {
            let e = SyntheticSource::parse(SyntheticScene::TwoRooms, rest).expect_err(rest);
            assert!(e.contains(says), "{rest}: {e}");
        }
    }

    #[test]
    fn the_noisy_option_changes_the_frames_deterministically() {
        let open = |noisy: bool| {
            let source = SyntheticSource { scene: SyntheticScene::TwoRooms, seed: 2, noisy, seconds: Some(1) };
            let (_, scan) = source.open().expect("scan");
            scan.frame(3).expect("frame")
        };
        let (a, b, calm) = (open(true), open(true), open(false));
        assert_eq!(a.depth, b.depth);
        assert_ne!(a.depth, calm.depth);
        assert_eq!(a.world_from_camera, calm.world_from_camera, "the walk does not depend on the sensor");
    }
}
