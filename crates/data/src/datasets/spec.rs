//! `KIND:PATH` dataset specifications (`7scenes:/data/redkitchen`, `tum:...`, `redwood:...`,
//! `scannet:...`, `replica:...`, `oni:FILE`, `bag:FILE`, and the generated scenes `synth:SEED`,
//! `synth-loop:SEED`, `synth-flat:SEED` with their options, see [`SyntheticSource`]) as typed
//! on the command line, and the one function that opens any of them as a boxed
//! [`FrameSource`]. A bare path (no kind) is read by the kind its files show (see
//! [`DatasetSpec::detect`]): the layouts differ enough that a user should not have to name it.

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
        let Some((kind, rest)) = s.split_once(':').filter(|(kind, _)| is_kind(kind)) else {
            if std::path::Path::new(s).exists() {
                return Self::detect(s);
            }
            if let Some((kind, _)) = s.split_once(':') {
                return Err(DataError::dataset(s, format!("unknown dataset kind `{kind}`; expected one of {KINDS}")));
            }
            return Err(DataError::dataset(
                s,
                format!("no such file or folder, and not a KIND:PATH dataset specification; expected a dataset folder or one of {KINDS}"),
            ));
        };
        if rest.is_empty() {
            return Err(DataError::dataset(s, format!("nothing after `{kind}:`; expected one of {KINDS}")));
        }
        if let Some(spec) = recorded(kind, PathBuf::from(rest)) {
            return Ok(spec);
        }
        match SyntheticScene::from_kind(&kind.to_ascii_lowercase()) {
            Some(scene) => {
                Ok(Self::Synth(SyntheticSource::parse(scene, rest).map_err(|why| DataError::dataset(s, why))?))
            }
            None => Err(DataError::dataset(s, format!("unknown dataset kind `{kind}`; expected one of {KINDS}"))),
        }
    }
}

/// The recorded dataset of `kind` (the part before the first `:`, any case) at `path`;
/// `None` for a generated scene's kind or an unknown one.
fn recorded(kind: &str, path: PathBuf) -> Option<DatasetSpec> {
    Some(match kind.to_ascii_lowercase().as_str() {
        "7scenes" => DatasetSpec::SevenScenes(path),
        "tum" => DatasetSpec::Tum(path, None),
        "tum-fr1" => DatasetSpec::Tum(path, Some(TumCamera::Freiburg1)),
        "tum-fr2" => DatasetSpec::Tum(path, Some(TumCamera::Freiburg2)),
        "tum-fr3" => DatasetSpec::Tum(path, Some(TumCamera::Freiburg3)),
        "tum-default" => DatasetSpec::Tum(path, Some(TumCamera::Default)),
        "redwood" => DatasetSpec::Redwood(path),
        "scannet" => DatasetSpec::ScanNet(path),
        "replica" => DatasetSpec::Replica(path),
        "oni" => DatasetSpec::Oni(path),
        "bag" => DatasetSpec::Bag(path),
        _ => return None,
    })
}

/// The kinds a specification may start with: the recorded ones and the generated scenes.
fn is_kind(kind: &str) -> bool {
    recorded(kind, PathBuf::new()).is_some() || SyntheticScene::from_kind(&kind.to_ascii_lowercase()).is_some()
}

impl DatasetSpec {
    /// The folder or file of a recorded dataset (`None` for a generated scene).
    pub fn path(&self) -> Option<&std::path::Path> {
        match self {
            Self::SevenScenes(p)
            | Self::Tum(p, _)
            | Self::Redwood(p)
            | Self::ScanNet(p)
            | Self::Replica(p)
            | Self::Oni(p)
            | Self::Bag(p) => Some(p),
            Self::Synth(_) => None,
        }
    }

    /// The reader for an existing file or folder `path` given without a kind, from what it
    /// holds: `.oni` and `.bag` files by their extension; folders with `rgb.txt` and
    /// `depth.txt` (TUM), `results/` and `traj.txt` in them or in one sub-folder (Replica),
    /// `color/`, `depth/`, `pose/` and `intrinsic/` (ScanNet), `color/` and `depth/`
    /// (Redwood / Open3D), or `frame-N.depth.png` files (7-Scenes, SUN3D). The TUM camera
    /// then comes from the folder's name, as with `tum:`.
    ///
    /// # Errors
    /// A path that matches none of them: the error lists what was looked for and says to
    /// name the kind.
    pub fn detect(path: impl AsRef<std::path::Path>) -> Result<Self> {
        let path = path.as_ref();
        let p = path.to_path_buf();
        if path.is_file() {
            let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
            return match ext.as_deref() {
                Some("oni") => Ok(Self::Oni(p)),
                Some("bag") => Ok(Self::Bag(p)),
                _ => Err(DataError::dataset(
                    path,
                    format!(
                        "a file that is not an .oni or .bag recording; expected a dataset folder or one of {KINDS}"
                    ),
                )),
            };
        }
        let has = |name: &str| path.join(name).exists();
        let is_replica = |dir: &std::path::Path| dir.join("results").is_dir() && dir.join("traj.txt").is_file();
        if has("rgb.txt") && has("depth.txt") {
            return Ok(Self::Tum(p, None));
        }
        if has("color") && has("depth") && has("pose") && has("intrinsic") {
            return Ok(Self::ScanNet(p));
        }
        if has("color") && has("depth") {
            return Ok(Self::Redwood(p));
        }
        let entries: Vec<std::fs::DirEntry> = match std::fs::read_dir(path) {
            Ok(entries) => entries.filter_map(std::result::Result::ok).collect(),
            Err(e) => return Err(DataError::io(path, e)),
        };
        if is_replica(path) || entries.iter().any(|e| is_replica(&e.path())) {
            return Ok(Self::Replica(p));
        }
        let frame_files = entries.iter().any(|e| {
            let name = e.file_name();
            let name = name.to_string_lossy();
            name.starts_with("frame-") && name.ends_with(".depth.png")
        });
        if frame_files {
            return Ok(Self::SevenScenes(p));
        }
        Err(DataError::dataset(
            path,
            format!(
                "cannot tell the dataset kind from the folder's files (looked for rgb.txt + depth.txt, results/ + traj.txt, \
                 color/ + depth/, frame-N.depth.png); name it: one of {KINDS}"
            ),
        ))
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
        for s in ["kinect:/x", "/just/a/path", "tum:", "synth:-1", "synth-flat:2:loud", "synth-loop:x", "C:/no/such"] {
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
    fn a_bare_path_is_read_by_the_kind_its_files_show() {
        let dir = tempfile::tempdir().expect("tempdir");
        let make = |name: &str, files: &[&str], dirs: &[&str]| {
            let d = dir.path().join(name);
            std::fs::create_dir_all(&d).expect("mkdir");
            for sub in dirs {
                std::fs::create_dir_all(d.join(sub)).expect("mkdir");
            }
            for f in files {
                std::fs::write(d.join(f), b"").expect("write");
            }
            d
        };
        let parse = |p: &std::path::Path| p.to_string_lossy().parse::<DatasetSpec>();
        let tum = make("rgbd_dataset_freiburg2_desk", &["rgb.txt", "depth.txt"], &["rgb", "depth"]);
        assert_eq!(parse(&tum).ok(), Some(DatasetSpec::Tum(tum.clone(), None)));
        let scannet = make("scene0001_00", &[], &["color", "depth", "pose", "intrinsic"]);
        assert_eq!(parse(&scannet).ok(), Some(DatasetSpec::ScanNet(scannet.clone())));
        let redwood = make("living_room", &["trajectory.log"], &["color", "depth"]);
        assert_eq!(parse(&redwood).ok(), Some(DatasetSpec::Redwood(redwood.clone())));
        let replica = make("replica/office0", &["traj.txt"], &["results"]);
        assert_eq!(parse(&replica).ok(), Some(DatasetSpec::Replica(replica.clone())));
        let parent = dir.path().join("replica");
        assert_eq!(parse(&parent).ok(), Some(DatasetSpec::Replica(parent.clone())));
        let seven = make("redkitchen", &["frame-000000.depth.png", "frame-000000.color.png"], &[]);
        assert_eq!(parse(&seven).ok(), Some(DatasetSpec::SevenScenes(seven.clone())));
        let oni = dir.path().join("take.ONI");
        std::fs::write(&oni, b"").expect("write");
        assert_eq!(parse(&oni).ok(), Some(DatasetSpec::Oni(oni.clone())));
        // Nothing recognisable: the error names the folder and says to name the kind.
        let other = make("holiday_photos", &["a.jpg"], &[]);
        let e = parse(&other).expect_err("unknown layout").to_string();
        assert!(e.contains("holiday_photos") && e.contains("name it") && e.contains("7scenes:PATH"), "{e}");
        let e = parse(&other.join("a.jpg")).expect_err("a photo").to_string();
        assert!(e.contains("a.jpg") && e.contains(".oni"), "{e}");
        // A kind still wins over a path that happens to exist.
        assert_eq!(format!("redwood:{}", tum.display()).parse::<DatasetSpec>().ok(), Some(DatasetSpec::Redwood(tum)));
    }

    #[test]
    fn synth_opens_a_rendered_scan() {
        let source = open_dataset(&DatasetSpec::Synth(SyntheticSource::room(1))).expect("synth source");
        assert_eq!(source.name(), "synth:1");
        assert!(source.has_ground_truth() && !source.is_empty());
    }
}
