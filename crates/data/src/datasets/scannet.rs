//! The ScanNet export layout (what ScanNet's `SensReader` writes): `color/N.jpg` (1296x968),
//! `depth/N.png` (640x480, 16-bit millimetres), `pose/N.txt` (4x4 `world_from_camera`;
//! `-inf` where ScanNet's tracker lost the camera), and `intrinsic/intrinsic_depth.txt` /
//! `intrinsic_color.txt` (4x4). The colour camera is registered to the depth camera (same
//! centre and orientation), so colour is resampled onto the depth grid through the two
//! intrinsics.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use crate::camera::Intrinsics;
use crate::datasets::{
    image_size, list_files, load_color_registered, load_depth_checked, number_between, read_intrinsics_matrix,
    require_dir, validated,
};
use crate::error::{DataError, Result};
use crate::frame::{Frame, FrameSource};
use crate::trajectory::read_pose_matrix;

/// Millimetres.
const DEPTH_UNITS_PER_METRE: f32 = 1000.0;

#[derive(Debug, Clone)]
struct Entry {
    number: u64,
    depth: PathBuf,
    color: PathBuf,
    pose: Option<PathBuf>,
}

/// A ScanNet scene export folder.
#[derive(Debug, Clone)]
pub struct ScanNet {
    dir: PathBuf,
    intrinsics: Intrinsics,
    color_k: Option<[f32; 4]>,
    frames: Vec<Entry>,
    has_ground_truth: bool,
}

impl ScanNet {
    /// Indexes `depth/`, `color/`, `pose/` and reads `intrinsic/`.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let dir = path.as_ref().to_path_buf();
        const WHAT: &str =
            "a ScanNet export with color/N.jpg, depth/N.png, pose/N.txt and intrinsic/intrinsic_depth.txt";
        require_dir(&dir, WHAT)?;
        for sub in ["color", "depth"] {
            if !dir.join(sub).is_dir() {
                return Err(DataError::dataset(&dir, format!("no {sub}/ folder; expected {WHAT}")));
            }
        }
        let depth_k_path = dir.join("intrinsic").join("intrinsic_depth.txt");
        if !depth_k_path.is_file() {
            return Err(DataError::dataset(&dir, format!("no intrinsic/intrinsic_depth.txt; expected {WHAT}")));
        }
        let [fx, fy, cx, cy] = read_intrinsics_matrix(&depth_k_path, 4)?;
        let color_k_path = dir.join("intrinsic").join("intrinsic_color.txt");
        let color_k = if color_k_path.is_file() { Some(read_intrinsics_matrix(&color_k_path, 4)?) } else { None };

        let color_names = list_files(&dir.join("color"))?;
        let color_set: HashSet<&str> = color_names.iter().map(String::as_str).collect();
        let pose_dir = dir.join("pose");
        let pose_names = if pose_dir.is_dir() { list_files(&pose_dir)? } else { Vec::new() };
        let pose_set: HashSet<&str> = pose_names.iter().map(String::as_str).collect();
        let mut numbers: Vec<u64> =
            list_files(&dir.join("depth"))?.iter().filter_map(|n| number_between(n, "", ".png")).collect();
        numbers.sort_unstable();
        numbers.dedup();
        if numbers.is_empty() {
            return Err(DataError::dataset(&dir, format!("depth/ has no N.png image; expected {WHAT}")));
        }
        let mut frames = Vec::with_capacity(numbers.len());
        for number in numbers {
            let color = [format!("{number}.jpg"), format!("{number}.png")]
                .into_iter()
                .find(|n| color_set.contains(n.as_str()))
                .ok_or_else(|| {
                    DataError::dataset(&dir, format!("depth/{number}.png has no color/{number}.jpg or .png"))
                })?;
            let pose_name = format!("{number}.txt");
            frames.push(Entry {
                number,
                depth: dir.join("depth").join(format!("{number}.png")),
                color: dir.join("color").join(color),
                pose: pose_set.contains(pose_name.as_str()).then(|| pose_dir.join(&pose_name)),
            });
        }
        let has_ground_truth = frames.iter().all(|f| f.pose.is_some());
        let (width, height) = image_size(&frames[0].depth)?;
        let intrinsics = Intrinsics::new(width, height, fx, fy, cx, cy)
            .map_err(|e| DataError::dataset(&depth_k_path, e.to_string()))?;
        Ok(Self { dir, intrinsics, color_k, frames, has_ground_truth })
    }
}

impl FrameSource for ScanNet {
    fn name(&self) -> String {
        format!("scannet:{}", self.dir.display())
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
        let color = load_color_registered(&entry.color, &self.intrinsics, self.color_k)?;
        let world_from_camera = match &entry.pose {
            Some(p) => read_pose_matrix(p)?,
            None => None,
        };
        let frame = Frame {
            index,
            timestamp: entry.number as f64 / 30.0,
            depth,
            color,
            intrinsics: self.intrinsics,
            world_from_camera,
            labels: None,
        };
        validated(frame, &entry.depth)
    }
}
