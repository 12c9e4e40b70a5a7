//! The 7-Scenes / SUN3D (3DMatch) layout: one folder of `frame-NNNNNN.depth.png` (16-bit
//! millimetres; 0 and 65535 invalid), `frame-NNNNNN.color.png|jpg`, optional
//! `frame-NNNNNN.label.png` (8-bit class ids) and `frame-NNNNNN.pose.txt` (4x4
//! `world_from_camera`), with `camera-intrinsics.txt` (3x3 K) in the folder or its parent.
//! Frames are the depth files that exist, in order of their number (SUN3D samples skip
//! numbers). Also the writer of that layout, which is how semrecon exports rendered data.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use crate::atomic_file::write_atomic;
use crate::camera::Intrinsics;
use crate::datasets::{
    find_here_or_parent, image_size, list_files, load_color_registered, load_depth_checked, number_between,
    read_intrinsics_matrix, require_dir, validated,
};
use crate::depth_image::{check_size, load_labels, write_color_png, write_depth_png, write_label_png};
use crate::error::{DataError, Result};
use crate::frame::{Frame, FrameSource};
use crate::trajectory::{read_pose_matrix, write_pose_matrix};

/// Millimetres.
const DEPTH_UNITS_PER_METRE: f32 = 1000.0;
/// Raw depth values meaning "no measurement" besides 0.
const INVALID_DEPTH: [u16; 1] = [65535];
/// The 7-Scenes Kinect depth camera, used when no `camera-intrinsics.txt` is found.
const DEFAULT_K: [f32; 4] = [585.0, 585.0, 320.0, 240.0];

#[derive(Debug, Clone)]
struct Entry {
    number: u64,
    depth: PathBuf,
    color: PathBuf,
    label: Option<PathBuf>,
    pose: Option<PathBuf>,
}

/// A 7-Scenes / SUN3D sequence folder.
#[derive(Debug, Clone)]
pub struct SevenScenes {
    dir: PathBuf,
    intrinsics: Intrinsics,
    frames: Vec<Entry>,
    has_ground_truth: bool,
}

impl SevenScenes {
    /// Indexes the folder: every `frame-N.depth.png` with a colour image is a frame.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let dir = path.as_ref().to_path_buf();
        const WHAT: &str = "a 7-Scenes folder of frame-NNNNNN.depth.png / .color.{png,jpg} / .pose.txt";
        require_dir(&dir, WHAT)?;
        let names = list_files(&dir)?;
        let set: HashSet<&str> = names.iter().map(String::as_str).collect();
        // (number, stem) of every depth file, the stem spelled as in the folder.
        let mut stems: Vec<(u64, &str)> = names
            .iter()
            .filter_map(|n| {
                let stem = n.strip_suffix(".depth.png")?;
                Some((number_between(stem, "frame-", "")?, stem))
            })
            .collect();
        stems.sort_unstable();
        stems.dedup_by_key(|(n, _)| *n);
        if stems.is_empty() {
            return Err(DataError::dataset(&dir, format!("no frame-NNNNNN.depth.png files; expected {WHAT}")));
        }
        let mut frames = Vec::with_capacity(stems.len());
        for (number, stem) in stems {
            let color = [".color.png", ".color.jpg"]
                .iter()
                .map(|ext| format!("{stem}{ext}"))
                .find(|n| set.contains(n.as_str()))
                .ok_or_else(|| {
                    DataError::dataset(&dir, format!("{stem}.depth.png has no {stem}.color.png or {stem}.color.jpg"))
                })?;
            let optional = |ext: &str| {
                let n = format!("{stem}{ext}");
                set.contains(n.as_str()).then(|| dir.join(n))
            };
            frames.push(Entry {
                number,
                depth: dir.join(format!("{stem}.depth.png")),
                color: dir.join(color),
                label: optional(".label.png"),
                pose: optional(".pose.txt"),
            });
        }
        let has_ground_truth = frames.iter().all(|f| f.pose.is_some());
        let (width, height) = image_size(&frames[0].depth)?;
        let [fx, fy, cx, cy] = match find_here_or_parent(&dir, "camera-intrinsics.txt") {
            Some(p) => read_intrinsics_matrix(&p, 3)?,
            None => DEFAULT_K,
        };
        let intrinsics =
            Intrinsics::new(width, height, fx, fy, cx, cy).map_err(|e| DataError::dataset(&dir, e.to_string()))?;
        Ok(Self { dir, intrinsics, frames, has_ground_truth })
    }

    /// The frame number (from the file name) of each frame, in order.
    pub fn frame_numbers(&self) -> Vec<u64> {
        self.frames.iter().map(|f| f.number).collect()
    }
}

impl FrameSource for SevenScenes {
    fn name(&self) -> String {
        format!("7scenes:{}", self.dir.display())
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

    /// 7-Scenes pairs its Kinect's colour and depth without registering them (the layout
    /// carries no calibration between the two cameras): a colour term would pull the pose
    /// by the cameras' offset.
    fn color_registered(&self) -> bool {
        false
    }

    fn frame(&self, index: usize) -> Result<Frame> {
        let entry = super::frame_entry(&self.frames, index, self)?;
        let depth_path = &entry.depth;
        let depth = load_depth_checked(depth_path, DEPTH_UNITS_PER_METRE, &INVALID_DEPTH, &self.intrinsics)?;
        let color = load_color_registered(&entry.color, &self.intrinsics, None)?;
        let labels = match &entry.label {
            Some(p) => {
                let l = load_labels(p)?;
                check_size(p, l.width, l.height, &self.intrinsics)?;
                Some(l.labels)
            }
            None => None,
        };
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
            labels,
        };
        validated(frame, depth_path)
    }
}

/// Writes frames in the 7-Scenes layout (depth in millimetres, PNG colour, label PNG when a
/// frame has labels, `pose.txt` when it has a pose) plus `camera-intrinsics.txt`; files are
/// named by `Frame::index`.
#[derive(Debug, Clone)]
pub struct SevenScenesWriter {
    dir: PathBuf,
    intrinsics: Intrinsics,
}

impl SevenScenesWriter {
    /// Creates `dir` (and parents) and writes its `camera-intrinsics.txt`.
    pub fn new(dir: impl AsRef<Path>, intrinsics: &Intrinsics) -> Result<Self> {
        let dir = dir.as_ref().to_path_buf();
        std::fs::create_dir_all(&dir).map_err(|e| DataError::io(&dir, e))?;
        let k = intrinsics;
        let text = format!("{} 0 {}\n0 {} {}\n0 0 1\n", k.fx, k.cx, k.fy, k.cy);
        write_atomic(&dir.join("camera-intrinsics.txt"), text.as_bytes())?;
        Ok(Self { dir, intrinsics: *intrinsics })
    }

    /// Writes one frame's files (`frame-NNNNNN.*` with `NNNNNN = frame.index`). Depth beyond
    /// 65.534 m is written as invalid.
    pub fn write_frame(&self, frame: &Frame) -> Result<()> {
        let k = &self.intrinsics;
        if frame.intrinsics.width != k.width || frame.intrinsics.height != k.height {
            return Err(DataError::InvalidArgument(format!(
                "frame {} is {}x{}, but {} holds {}x{} images",
                frame.index,
                frame.intrinsics.width,
                frame.intrinsics.height,
                self.dir.display(),
                k.width,
                k.height
            )));
        }
        frame.validate().map_err(|m| DataError::InvalidArgument(format!("frame {}: {m}", frame.index)))?;
        let stem = self.dir.join(format!("frame-{:06}", frame.index));
        let path = |ext: &str| {
            let mut p = stem.clone().into_os_string();
            p.push(ext);
            PathBuf::from(p)
        };
        write_depth_png(path(".depth.png"), k.width, k.height, &frame.depth, DEPTH_UNITS_PER_METRE)?;
        write_color_png(path(".color.png"), k.width, k.height, &frame.color)?;
        if let Some(labels) = &frame.labels {
            write_label_png(path(".label.png"), k.width, k.height, labels)?;
        }
        if let Some(pose) = &frame.world_from_camera {
            write_pose_matrix(path(".pose.txt"), pose)?;
        }
        Ok(())
    }
}
