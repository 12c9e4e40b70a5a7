//! The TUM RGB-D layout: `rgb.txt` and `depth.txt` list `timestamp filename` (paths relative
//! to the folder), `groundtruth.txt` (optional) is a TUM trajectory at about 100 Hz. Depth
//! images drive: each depth image is a frame when an RGB image lies within 0.02 s of it
//! (the tolerance of TUM's own `associate.py`); its ground-truth pose is interpolated between
//! the bracketing samples, or taken from the nearest sample within 0.02 s. Depth is 16-bit
//! in units of 1/5000 m. Intrinsics follow the Freiburg camera named in the folder name
//! (`freiburg2` as in TUM's own folder names), or the camera the caller names
//! ([`Tum::open_with_camera`]; `tum-fr2:PATH` on the command line): TUM's depth is registered
//! to colour with the Kinect's factory calibration, and TUM advises its default intrinsics for
//! it, so which one fits a recording is for the user to say (on our 50 frames of fr2/desk the
//! defaults track better: 8.4 against 9.2 mm, docs/loop_closure.md).

use std::path::{Path, PathBuf};

use glam::Affine3A;

use crate::camera::Intrinsics;
use crate::datasets::{image_size, load_color_registered, load_depth_checked, require_dir, validated};
use crate::error::{DataError, Result};
use crate::frame::{Frame, FrameSource};
use crate::trajectory::{associate, read_text, Trajectory};

/// TUM depth units.
const DEPTH_UNITS_PER_METRE: f32 = 5000.0;
/// Largest time difference between a depth image and its RGB image or nearest GT pose.
const MAX_DIFFERENCE_S: f64 = 0.02;
/// Largest gap between two ground-truth samples that a pose is interpolated across.
const MAX_INTERPOLATION_GAP_S: f64 = 0.1;

#[derive(Debug, Clone)]
struct Entry {
    timestamp: f64,
    depth: PathBuf,
    color: PathBuf,
    pose: Option<Affine3A>,
}

/// A TUM RGB-D sequence folder.
#[derive(Debug, Clone)]
pub struct Tum {
    dir: PathBuf,
    intrinsics: Intrinsics,
    frames: Vec<Entry>,
    has_ground_truth: bool,
}

/// The camera of a TUM recording, for its intrinsics.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TumCamera {
    /// The Freiburg 1 rig's Kinect (calibrated colour intrinsics).
    Freiburg1,
    /// The Freiburg 2 rig's Kinect.
    Freiburg2,
    /// The Freiburg 3 rig's Asus Xtion.
    Freiburg3,
    /// TUM's defaults for any of them (525, 525, 319.5, 239.5).
    Default,
}

impl TumCamera {
    /// `fx fy cx cy`.
    pub fn intrinsics(self) -> [f32; 4] {
        match self {
            Self::Freiburg1 => [517.3, 516.5, 318.6, 255.3],
            Self::Freiburg2 => [520.9, 521.0, 325.1, 249.7],
            Self::Freiburg3 => [535.4, 539.2, 320.1, 247.6],
            Self::Default => [525.0, 525.0, 319.5, 239.5],
        }
    }

    /// The camera a TUM folder name names (`freiburg1/2/3`), else the defaults.
    pub fn from_folder(dir: &Path) -> Self {
        let name = std::fs::canonicalize(dir)
            .ok()
            .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .or_else(|| dir.file_name().map(|n| n.to_string_lossy().into_owned()))
            .unwrap_or_default()
            .to_ascii_lowercase();
        if name.contains("freiburg1") {
            Self::Freiburg1
        } else if name.contains("freiburg2") {
            Self::Freiburg2
        } else if name.contains("freiburg3") {
            Self::Freiburg3
        } else {
            Self::Default
        }
    }
}

impl Tum {
    /// Reads `rgb.txt`, `depth.txt` and (when present) `groundtruth.txt` and associates them;
    /// the camera from the folder name ([`TumCamera::from_folder`]).
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        Self::open_with_camera(path, None)
    }

    /// [`Tum::open`] with the camera given (`None`: from the folder name).
    pub fn open_with_camera(path: impl AsRef<Path>, camera: Option<TumCamera>) -> Result<Self> {
        let dir = path.as_ref().to_path_buf();
        const WHAT: &str = "a TUM RGB-D folder with rgb.txt, depth.txt and optionally groundtruth.txt";
        require_dir(&dir, WHAT)?;
        for list in ["rgb.txt", "depth.txt"] {
            if !dir.join(list).is_file() {
                return Err(DataError::dataset(&dir, format!("no {list}; expected {WHAT}")));
            }
        }
        let rgb = read_list(&dir.join("rgb.txt"))?;
        let depth = read_list(&dir.join("depth.txt"))?;
        let gt_path = dir.join("groundtruth.txt");
        let gt = if gt_path.is_file() { Some(Trajectory::read_tum(&gt_path)?) } else { None };
        let rgb_times: Vec<f64> = rgb.iter().map(|(t, _)| *t).collect();
        let depth_times: Vec<f64> = depth.iter().map(|(t, _)| *t).collect();
        let matches = associate(&depth_times, &rgb_times, MAX_DIFFERENCE_S);
        let mut frames: Vec<Entry> = depth
            .iter()
            .zip(matches)
            .filter_map(|((t, d), m)| {
                let color = &rgb[m?].1;
                Some(Entry {
                    timestamp: *t,
                    depth: dir.join(d),
                    color: dir.join(color),
                    pose: gt.as_ref().and_then(|g| g.pose_at(*t, MAX_INTERPOLATION_GAP_S, MAX_DIFFERENCE_S)),
                })
            })
            .collect();
        frames.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
        if frames.is_empty() {
            return Err(DataError::dataset(
                &dir,
                format!(
                    "no depth image of depth.txt ({} entries) has an RGB image of rgb.txt ({} entries) within {MAX_DIFFERENCE_S} s",
                    depth.len(),
                    rgb.len()
                ),
            ));
        }
        let (width, height) = image_size(&frames[0].depth)?;
        let [fx, fy, cx, cy] = camera.unwrap_or_else(|| TumCamera::from_folder(&dir)).intrinsics();
        let intrinsics =
            Intrinsics::new(width, height, fx, fy, cx, cy).map_err(|e| DataError::dataset(&dir, e.to_string()))?;
        let has_ground_truth = gt.is_some_and(|g| !g.is_empty());
        Ok(Self { dir, intrinsics, frames, has_ground_truth })
    }
}

/// Parses an `rgb.txt` / `depth.txt` list: `timestamp filename` per line, `#` comments.
fn read_list(path: &Path) -> Result<Vec<(f64, String)>> {
    parse_list(&read_text(path)?, path)
}

/// Parses list text; `path` only names the source in errors.
pub(crate) fn parse_list(text: &str, path: &Path) -> Result<Vec<(f64, String)>> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split_whitespace().collect();
        if fields.len() != 2 {
            return Err(DataError::parse(
                path,
                Some(i + 1),
                format!("expected `timestamp filename`, found {} fields", fields.len()),
            ));
        }
        let t: f64 = fields[0]
            .parse()
            .map_err(|_| DataError::parse(path, Some(i + 1), format!("`{}` is not a timestamp", fields[0])))?;
        if !t.is_finite() {
            return Err(DataError::parse(path, Some(i + 1), format!("non-finite timestamp {t}")));
        }
        out.push((t, fields[1].to_owned()));
    }
    Ok(out)
}

impl FrameSource for Tum {
    fn name(&self) -> String {
        format!("tum:{}", self.dir.display())
    }

    fn len(&self) -> usize {
        self.frames.len()
    }

    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    fn has_ground_truth(&self) -> bool {
        self.has_ground_truth
    }

    fn frame(&self, index: usize) -> Result<Frame> {
        let entry = super::frame_entry(&self.frames, index, self)?;
        let depth = load_depth_checked(&entry.depth, DEPTH_UNITS_PER_METRE, &[], &self.intrinsics)?;
        let color = load_color_registered(&entry.color, &self.intrinsics, None)?;
        let frame = Frame {
            index,
            timestamp: entry.timestamp,
            depth,
            color,
            intrinsics: self.intrinsics,
            world_from_camera: entry.pose,
            labels: None,
        };
        validated(frame, &entry.depth)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lists_parse_and_name_bad_lines() {
        let p = Path::new("rgb.txt");
        let l = parse_list("# c\n1.5 rgb/a.png\n\n2 rgb/b.png\n", p).expect("valid");
        assert_eq!(l, vec![(1.5, "rgb/a.png".to_owned()), (2.0, "rgb/b.png".to_owned())]);
        let e = parse_list("1.5\n", p).expect_err("short");
        assert!(e.to_string().contains("rgb.txt:1"), "{e}");
        let e = parse_list("x a\n", p).expect_err("word");
        assert!(e.to_string().contains("not a timestamp"), "{e}");
        let e = parse_list("\ninf a\n", p).expect_err("inf");
        assert!(e.to_string().contains("rgb.txt:2"), "{e}");
    }

    #[test]
    fn freiburg_cameras_follow_the_folder_name() {
        let of = |p: &str| TumCamera::from_folder(Path::new(p)).intrinsics();
        assert_eq!(of("/x/rgbd_dataset_freiburg2_desk")[0], 520.9);
        assert_eq!(of("/x/rgbd_dataset_freiburg3_office")[1], 539.2);
        assert_eq!(of("/x/mine")[0], 525.0);
    }
}
