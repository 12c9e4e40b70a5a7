//! The Replica layout of NICE-SLAM and its successors: `results/frameNNNNNN.jpg` and
//! `results/depthNNNNNN.png` (16-bit, `raw / scale` metres, scale 6553.5), `traj.txt` (one
//! row-major 4x4 `world_from_camera` per line, line N for frame N) and `cam_params.json`
//! (`camera: {w, h, fx, fy, cx, cy, scale}`) in the sequence folder or its parent. The path
//! may name the sequence folder or a folder holding exactly one sequence. Frames are the
//! image pairs that exist (samples often ship a few images with the full trajectory).

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use glam::Affine3A;

use crate::camera::Intrinsics;
use crate::datasets::{
    find_here_or_parent, list_files, load_color_registered, load_depth_checked, number_between, require_dir, validated,
};
use crate::error::{DataError, Result};
use crate::frame::{Frame, FrameSource};
use crate::trajectory::{read_text, Trajectory};

/// NICE-SLAM's Replica camera, used when no `cam_params.json` is found.
const DEFAULT_CAMERA: (u32, u32, [f32; 4], f32) = (1200, 680, [600.0, 600.0, 599.5, 339.5], 6553.5);

#[derive(Debug, Clone)]
struct Entry {
    number: u64,
    depth: PathBuf,
    color: PathBuf,
    pose: Option<Affine3A>,
}

/// A Replica (NICE-SLAM layout) sequence.
#[derive(Debug, Clone)]
pub struct Replica {
    dir: PathBuf,
    intrinsics: Intrinsics,
    units_per_metre: f32,
    frames: Vec<Entry>,
    has_ground_truth: bool,
}

impl Replica {
    /// Finds the sequence folder, indexes `results/`, reads `traj.txt` and `cam_params.json`.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let root = path.as_ref();
        const WHAT: &str = "a Replica sequence folder with results/frameNNNNNN.jpg, results/depthNNNNNN.png and traj.txt (or a folder holding one)";
        require_dir(root, WHAT)?;
        let dir = sequence_folder(root, WHAT)?;
        let results = dir.join("results");
        let names = list_files(&results)?;
        let set: HashSet<&str> = names.iter().map(String::as_str).collect();
        let mut numbers: Vec<(u64, &str)> = names
            .iter()
            .filter_map(|n| {
                let digits = n.strip_prefix("depth")?.strip_suffix(".png")?;
                Some((number_between(n, "depth", ".png")?, digits))
            })
            .collect();
        numbers.sort_unstable();
        numbers.dedup_by_key(|(n, _)| *n);
        let traj_path = dir.join("traj.txt");
        let traj = if traj_path.is_file() { Some(Trajectory::read_replica(&traj_path)?) } else { None };
        let mut frames = Vec::new();
        for (number, digits) in numbers {
            let Some(color) =
                ["jpg", "png"].iter().map(|e| format!("frame{digits}.{e}")).find(|n| set.contains(n.as_str()))
            else {
                continue;
            };
            let pose = match &traj {
                Some(t) => Some(*usize::try_from(number).ok().and_then(|i| t.poses.get(i)).ok_or_else(|| {
                    DataError::dataset(
                        &traj_path,
                        format!("{} poses, but results/ has frame {number}; expected a pose per frame", t.len()),
                    )
                })?),
                None => None,
            };
            frames.push(Entry {
                number,
                depth: results.join(format!("depth{digits}.png")),
                color: results.join(color),
                pose,
            });
        }
        if frames.is_empty() {
            return Err(DataError::dataset(
                &results,
                format!("no depthNNNNNN.png with a frameNNNNNN.jpg; expected {WHAT}"),
            ));
        }
        let (width, height, [fx, fy, cx, cy], units_per_metre) = match find_here_or_parent(&dir, "cam_params.json") {
            Some(p) => read_cam_params(&p)?,
            None => DEFAULT_CAMERA,
        };
        let intrinsics =
            Intrinsics::new(width, height, fx, fy, cx, cy).map_err(|e| DataError::dataset(&dir, e.to_string()))?;
        Ok(Self { dir, intrinsics, units_per_metre, frames, has_ground_truth: traj.is_some() })
    }

    /// The frame number (from the file name, which is also its line in `traj.txt`) of each
    /// frame, in order.
    pub fn frame_numbers(&self) -> Vec<u64> {
        self.frames.iter().map(|f| f.number).collect()
    }
}

/// `root` when it has `results/`, else its only subfolder that has one.
fn sequence_folder(root: &Path, what: &str) -> Result<PathBuf> {
    if root.join("results").is_dir() {
        return Ok(root.to_path_buf());
    }
    let entries = std::fs::read_dir(root).map_err(|e| DataError::io(root, e))?;
    let mut found: Vec<PathBuf> =
        entries.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.join("results").is_dir()).collect();
    found.sort();
    match found.len() {
        1 => Ok(found.remove(0)),
        0 => Err(DataError::dataset(root, format!("no results/ folder here or in a subfolder; expected {what}"))),
        n => {
            Err(DataError::dataset(root, format!("{n} subfolders have results/ ({}); name one of them", names(&found))))
        }
    }
}

fn names(paths: &[PathBuf]) -> String {
    paths.iter().filter_map(|p| p.file_name()).map(|n| n.to_string_lossy()).collect::<Vec<_>>().join(", ")
}

/// `(w, h, [fx, fy, cx, cy], scale)` from a NICE-SLAM `cam_params.json`.
fn read_cam_params(path: &Path) -> Result<(u32, u32, [f32; 4], f32)> {
    let value: serde_json::Value = serde_json::from_str(&read_text(path)?)
        .map_err(|e| DataError::parse(path, Some(e.line()), format!("invalid JSON: {e}")))?;
    let camera = value.get("camera").ok_or_else(|| DataError::parse(path, None, "no `camera` object"))?;
    let number = |key: &str| {
        camera
            .get(key)
            .and_then(|v| v.as_f64())
            .filter(|v| v.is_finite())
            .ok_or_else(|| DataError::parse(path, None, format!("`camera.{key}` missing or not a number")))
    };
    let size = |key: &str| {
        let v = number(key)?;
        if v >= 1.0 && v <= u32::MAX as f64 && v.fract() == 0.0 {
            Ok(v as u32)
        } else {
            Err(DataError::parse(path, None, format!("`camera.{key}` = {v} is not an image size")))
        }
    };
    let scale = match camera.get("scale") {
        None => DEFAULT_CAMERA.3,
        Some(_) => number("scale")? as f32,
    };
    if !scale.is_finite() || scale <= 0.0 {
        return Err(DataError::parse(path, None, format!("`camera.scale` = {scale} must be positive")));
    }
    let k = [number("fx")? as f32, number("fy")? as f32, number("cx")? as f32, number("cy")? as f32];
    Ok((size("w")?, size("h")?, k, scale))
}

impl FrameSource for Replica {
    fn name(&self) -> String {
        format!("replica:{}", self.dir.display())
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
        let depth = load_depth_checked(&entry.depth, self.units_per_metre, &[], &self.intrinsics)?;
        let color = load_color_registered(&entry.color, &self.intrinsics, None)?;
        let frame = Frame {
            index,
            timestamp: entry.number as f64 / 30.0,
            depth,
            color,
            intrinsics: self.intrinsics,
            world_from_camera: entry.pose,
            labels: None,
        };
        validated(frame, &entry.depth)
    }
}
