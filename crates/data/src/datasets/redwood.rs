//! The Redwood / Open3D RGB-D layout: `color/*.jpg|png` and `depth/*.png|pgm` (16-bit
//! millimetres) paired in sorted order, an optional `trajectory.log` of ground-truth
//! `world_from_camera` poses (one per frame, in order), and intrinsics from an Open3D
//! `PinholeCameraIntrinsic` JSON in the folder or its parent (PrimeSense defaults otherwise).

use std::path::{Path, PathBuf};

use glam::Affine3A;

use crate::camera::Intrinsics;
use crate::datasets::{
    image_size, list_files, load_color_registered, load_depth_checked, read_open3d_intrinsics, require_dir, validated,
};
use crate::depth_image::check_size;
use crate::error::{DataError, Result};
use crate::frame::{Frame, FrameSource};
use crate::trajectory::Trajectory;

/// Millimetres.
const DEPTH_UNITS_PER_METRE: f32 = 1000.0;
/// PrimeSense / Kinect v1 intrinsics Open3D uses by default.
const DEFAULT_K: [f32; 4] = [525.0, 525.0, 319.5, 239.5];

/// A Redwood / Open3D RGB-D folder.
#[derive(Debug, Clone)]
pub struct Redwood {
    dir: PathBuf,
    intrinsics: Intrinsics,
    depth: Vec<PathBuf>,
    color: Vec<PathBuf>,
    poses: Option<Vec<Affine3A>>,
}

impl Redwood {
    /// Indexes `color/` and `depth/`, reads `trajectory.log` and the intrinsics JSON.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let dir = path.as_ref().to_path_buf();
        const WHAT: &str = "a Redwood/Open3D folder with color/ (jpg or png) and depth/ (16-bit png)";
        require_dir(&dir, WHAT)?;
        for sub in ["color", "depth"] {
            if !dir.join(sub).is_dir() {
                return Err(DataError::dataset(&dir, format!("no {sub}/ folder; expected {WHAT}")));
            }
        }
        let color = images_in(&dir.join("color"), &["jpg", "jpeg", "png"])?;
        let depth = images_in(&dir.join("depth"), &["png", "pgm"])?;
        if depth.is_empty() {
            return Err(DataError::dataset(&dir, format!("depth/ has no .png or .pgm image; expected {WHAT}")));
        }
        if color.len() != depth.len() {
            return Err(DataError::dataset(
                &dir,
                format!("color/ has {} images but depth/ has {}; they pair in sorted order", color.len(), depth.len()),
            ));
        }
        let log = dir.join("trajectory.log");
        let poses = if log.is_file() {
            let t = Trajectory::read_log(&log)?;
            if t.len() < depth.len() {
                return Err(DataError::dataset(
                    &log,
                    format!("{} poses for {} frames; expected one pose per frame", t.len(), depth.len()),
                ));
            }
            Some(t.poses)
        } else {
            None
        };
        let (width, height) = image_size(&depth[0])?;
        let intrinsics = match find_open3d_intrinsics(&dir)? {
            Some((k, json)) => {
                check_size(&depth[0], width, height, &k)
                    .map_err(|e| DataError::dataset(&json, format!("intrinsics do not fit the depth images: {e}")))?;
                k
            }
            None => {
                let [fx, fy, cx, cy] = DEFAULT_K;
                Intrinsics::new(width, height, fx, fy, cx, cy).map_err(|e| DataError::dataset(&dir, e.to_string()))?
            }
        };
        Ok(Self { dir, intrinsics, depth, color, poses })
    }
}

/// Image files of `dir` with one of `extensions`, in natural order (numbers compared as
/// numbers, so `2.png` comes before `10.png`).
fn images_in(dir: &Path, extensions: &[&str]) -> Result<Vec<PathBuf>> {
    let mut names: Vec<String> = list_files(dir)?
        .into_iter()
        .filter(|n| n.rsplit_once('.').is_some_and(|(_, ext)| extensions.iter().any(|e| ext.eq_ignore_ascii_case(e))))
        .collect();
    names.sort_by_key(|n| {
        let stem = n.rsplit_once('.').map_or(n.as_str(), |(s, _)| s);
        (stem.parse::<u64>().unwrap_or(u64::MAX), n.clone())
    });
    Ok(names.into_iter().map(|n| dir.join(n)).collect())
}

/// The first Open3D intrinsics JSON (sorted by name) in `dir`, then in its parent.
fn find_open3d_intrinsics(dir: &Path) -> Result<Option<(Intrinsics, PathBuf)>> {
    for folder in std::iter::once(dir).chain(dir.parent()) {
        let Ok(names) = list_files(folder) else { continue };
        for name in names.iter().filter(|n| n.to_ascii_lowercase().ends_with(".json")) {
            let path = folder.join(name);
            if let Some(k) = read_open3d_intrinsics(&path)? {
                return Ok(Some((k, path)));
            }
        }
    }
    Ok(None)
}

impl FrameSource for Redwood {
    fn name(&self) -> String {
        format!("redwood:{}", self.dir.display())
    }

    fn len(&self) -> usize {
        self.depth.len()
    }

    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    fn has_ground_truth(&self) -> bool {
        self.poses.is_some()
    }

    fn frame(&self, index: usize) -> Result<Frame> {
        let (Some(depth_path), Some(color_path)) = (self.depth.get(index), self.color.get(index)) else {
            return Err(DataError::InvalidArgument(format!(
                "frame {index} of {} frames in {}",
                self.depth.len(),
                self.name()
            )));
        };
        let depth = load_depth_checked(depth_path, DEPTH_UNITS_PER_METRE, &[], &self.intrinsics)?;
        let color = load_color_registered(color_path, &self.intrinsics, None)?;
        let frame = Frame {
            index,
            timestamp: index as f64 / 30.0,
            depth,
            color,
            intrinsics: self.intrinsics,
            world_from_camera: self.poses.as_ref().and_then(|p| p.get(index).copied()),
            labels: None,
        };
        validated(frame, depth_path)
    }
}
