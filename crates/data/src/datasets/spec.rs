//! `KIND:PATH` dataset specifications (`7scenes:/data/redkitchen`, `tum:...`, `redwood:...`,
//! `scannet:...`, `replica:...`, `oni:FILE`, `bag:FILE`, and the generated scenes `synth:SEED`,
//! `synth-loop:SEED`, `synth-flat:SEED` with their options, see [`SyntheticSource`]) as typed
//! on the command line, and the one function that opens any of them as a boxed
//! [`FrameSource`].

use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;

use crate::datasets::synthetic_source::{SyntheticScene, SyntheticSource};
use crate::datasets::{Oni, RealSenseBag, Redwood, Replica, ScanNet, SevenScenes, Tum, TumCamera};
use crate::error::{DataError, Result};
use crate::frame::FrameSource;

/// The accepted kinds, for error messages.
const KINDS: &str = "7scenes:PATH, tum:PATH (tum-fr1/fr2/fr3/default:PATH names the camera), redwood:PATH, scannet:PATH, replica:PATH, oni:FILE, bag:FILE, \
                     synth:SEED, synth-loop:SEED, synth-flat:SEED (options :noisy, :SECONDSs)";

/// Which dataset reader to use on which folder (or which synthetic scene).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DatasetSpec {
    /// A 7-Scenes / SUN3D folder.
    SevenScenes(PathBuf),
    /// A TUM RGB-D folder, and its camera when the specification names it (`tum-fr2:PATH`;
    /// `None`: from the folder name).
    Tum(PathBuf, Option<TumCamera>),
    /// A Redwood / Open3D folder.
    Redwood(PathBuf),
    /// A ScanNet export folder.
    ScanNet(PathBuf),
    /// A Replica (NICE-SLAM layout) sequence or its parent.
    Replica(PathBuf),
    /// An OpenNI `.oni` recording (needs OpenNI2 at run time).
    Oni(PathBuf),
    /// A RealSense `.bag` recording (ROS 1 bag).
    Bag(PathBuf),
    /// A generated scene (a room, two rooms, a flat), rendered, from a seed and options.
    Synth(SyntheticSource),
}

impl FromStr for DatasetSpec {
    type Err = DataError;

    fn from_str(s: &str) -> Result<Self> {
        let Some((kind, rest)) = s.split_once(':') else {
            return Err(DataError::dataset(
                s,
                format!("not a KIND:PATH dataset specification; expected one of {KINDS}"),
            ));
        };
        if rest.is_empty() {
            return Err(DataError::dataset(s, format!("nothing after `{kind}:`; expected one of {KINDS}")));
        }
        let path = || PathBuf::from(rest);
        Ok(match kind.to_ascii_lowercase().as_str() {
            "7scenes" => Self::SevenScenes(path()),
            "tum" => Self::Tum(path(), None),
            "tum-fr1" => Self::Tum(path(), Some(TumCamera::Freiburg1)),
            "tum-fr2" => Self::Tum(path(), Some(TumCamera::Freiburg2)),
            "tum-fr3" => Self::Tum(path(), Some(TumCamera::Freiburg3)),
            "tum-default" => Self::Tum(path(), Some(TumCamera::Default)),
            "redwood" => Self::Redwood(path()),
            "scannet" => Self::ScanNet(path()),
            "replica" => Self::Replica(path()),
            "oni" => Self::Oni(path()),
            "bag" => Self::Bag(path()),
            other => match SyntheticScene::from_kind(other) {
                Some(scene) => {
                    Self::Synth(SyntheticSource::parse(scene, rest).map_err(|why| DataError::dataset(s, why))?)
                }
                None => {
                    return Err(DataError::dataset(
                        s,
                        format!("unknown dataset kind `{kind}`; expected one of {KINDS}"),
                    ))
                }
            },
        })
    }
}

impl fmt::Display for DatasetSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::SevenScenes(p) => write!(f, "7scenes:{}", p.display()),
            Self::Tum(p, camera) => {
                let kind = match camera {
                    None => "tum",
                    Some(TumCamera::Freiburg1) => "tum-fr1",
                    Some(TumCamera::Freiburg2) => "tum-fr2",
                    Some(TumCamera::Freiburg3) => "tum-fr3",
                    Some(TumCamera::Default) => "tum-default",
                };
                write!(f, "{kind}:{}", p.display())
            }
            Self::Redwood(p) => write!(f, "redwood:{}", p.display()),
            Self::ScanNet(p) => write!(f, "scannet:{}", p.display()),
            Self::Replica(p) => write!(f, "replica:{}", p.display()),
            Self::Oni(p) => write!(f, "oni:{}", p.display()),
            Self::Bag(p) => write!(f, "bag:{}", p.display()),
            Self::Synth(source) => write!(f, "{source}"),
        }
    }
}

/// Opens the source a specification names.
pub fn open_dataset(spec: &DatasetSpec) -> Result<Box<dyn FrameSource>> {
    Ok(match spec {
        DatasetSpec::SevenScenes(p) => Box::new(SevenScenes::open(p)?),
        DatasetSpec::Tum(p, camera) => Box::new(Tum::open_with_camera(p, *camera)?),
        DatasetSpec::Redwood(p) => Box::new(Redwood::open(p)?),
        DatasetSpec::ScanNet(p) => Box::new(ScanNet::open(p)?),
        DatasetSpec::Replica(p) => Box::new(Replica::open(p)?),
        DatasetSpec::Oni(p) => Box::new(Oni::open(p)?),
        DatasetSpec::Bag(p) => Box::new(RealSenseBag::open(p)?),
        DatasetSpec::Synth(source) => Box::new(source.open()?.1),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_parse_and_print_back() {
        for s in [
            "7scenes:/a/b",
            "tum:x",
            "tum-fr1:x",
            "tum-fr2:/t/desk",
            "tum-fr3:x",
            "tum-default:x",
            "redwood:../r",
            "scannet:s",
            "replica:C:/w",
            "oni:a.oni",
            "bag:/r/b.bag",
            "synth:42",
            "synth-loop:3:noisy",
            "synth-flat:1:600s",
        ] {
            let spec: DatasetSpec = s.parse().expect("valid");
            assert_eq!(spec.to_string(), s);
        }
        assert_eq!("replica:C:/w".parse::<DatasetSpec>().ok(), Some(DatasetSpec::Replica("C:/w".into())));
    }

    #[test]
    fn bad_specs_list_the_kinds() {
        for s in ["kinect:/x", "/just/a/path", "tum:", "synth:-1", "synth-flat:2:loud", "synth-loop:x"] {
            let e = s.parse::<DatasetSpec>().expect_err(s).to_string();
            assert!(e.contains(s), "{e}");
        }
        let e = "kinect:/x".parse::<DatasetSpec>().expect_err("unknown").to_string();
        assert!(
            e.contains("unknown dataset kind `kinect`") && e.contains("7scenes:PATH") && e.contains("synth:SEED"),
            "{e}"
        );
    }

    #[test]
    fn synth_opens_a_rendered_scan() {
        let source = open_dataset(&DatasetSpec::Synth(SyntheticSource::room(1))).expect("synth source");
        assert_eq!(source.name(), "synth:1");
        assert!(source.has_ground_truth() && !source.is_empty());
    }
}
