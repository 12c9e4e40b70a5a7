//! Readers for the common RGB-D dataset layouts (7-Scenes/SUN3D, TUM RGB-D, Redwood/Open3D,
//! ScanNet exports, Replica/NICE-SLAM) and camera recordings (OpenNI `.oni`, RealSense `.bag`),
//! each a [`FrameSource`](crate::FrameSource), and the `KIND:PATH` specification that picks one
//! from the command line.
//!
//! Readers index the files when opened (cheap: directory listings and one image header) and
//! decode a frame only when asked for it, so that opening a long sequence is instant and a
//! reader thread can stream frames. Layout problems are reported at open time, naming what
//! was expected; problems with one frame's files are reported by `frame(i)`, naming the file.

pub mod oni;
pub mod realsense_bag;
pub mod redwood;
pub mod replica;
pub mod scannet;
pub mod seven_scenes;
pub mod spec;
pub mod synthetic;
pub mod synthetic_flat;
pub mod synthetic_source;
pub mod tum;

pub use oni::Oni;
pub use realsense_bag::RealSenseBag;
pub use redwood::Redwood;
pub use replica::Replica;
pub use scannet::ScanNet;
pub use seven_scenes::{SevenScenes, SevenScenesWriter};
pub use spec::{open_dataset, DatasetSpec};
pub use synthetic::{synthetic_scan, synthetic_scan_of, SyntheticScanConfig};
pub use synthetic_flat::{flat_layout, flat_scan_plan, synthetic_flat_scan};
pub use synthetic_source::{SyntheticScene, SyntheticSource};
pub use tum::{Tum, TumCamera};

use std::path::{Path, PathBuf};

use crate::camera::Intrinsics;
use crate::depth_image::{check_size, load_color, load_depth, register_color};
use crate::error::{DataError, Result};
use crate::frame::{Frame, FrameSource};

/// Entry `index` of a reader's frame list, or the error every reader gives for an index past
/// its end.
pub(crate) fn frame_entry<'a, T>(frames: &'a [T], index: usize, source: &dyn FrameSource) -> Result<&'a T> {
    frames.get(index).ok_or_else(|| {
        DataError::InvalidArgument(format!("frame {index} of {} frames in {}", frames.len(), source.name()))
    })
}

/// Fails with a dataset error unless `dir` is an existing folder.
pub(crate) fn require_dir(dir: &Path, what: &str) -> Result<()> {
    if dir.is_dir() {
        Ok(())
    } else if dir.exists() {
        Err(DataError::dataset(dir, format!("not a folder; expected {what}")))
    } else {
        Err(DataError::dataset(dir, format!("folder does not exist; expected {what}")))
    }
}

/// Names of the plain files in `dir`, sorted (names that are not UTF-8 are skipped: no
/// dataset layout uses them).
pub(crate) fn list_files(dir: &Path) -> Result<Vec<String>> {
    let entries = std::fs::read_dir(dir).map_err(|e| DataError::io(dir, e))?;
    let mut names = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| DataError::io(dir, e))?;
        let is_file = entry.file_type().map(|t| t.is_file() || t.is_symlink()).unwrap_or(false);
        if let (true, Some(name)) = (is_file, entry.file_name().to_str()) {
            names.push(name.to_owned());
        }
    }
    names.sort();
    Ok(names)
}

/// The number in `name` between `prefix` and `suffix` (digits only).
pub(crate) fn number_between(name: &str, prefix: &str, suffix: &str) -> Option<u64> {
    let digits = name.strip_prefix(prefix)?.strip_suffix(suffix)?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok()
}

/// `dir/name` if it exists, else `dir/../name` if that exists.
pub(crate) fn find_here_or_parent(dir: &Path, name: &str) -> Option<PathBuf> {
    let here = dir.join(name);
    if here.is_file() {
        return Some(here);
    }
    let parent = dir.parent()?.join(name);
    parent.is_file().then_some(parent)
}

/// Width and height of an image from its header, without decoding it.
pub(crate) fn image_size(path: &Path) -> Result<(u32, u32)> {
    image::ImageReader::open(path)
        .map_err(|e| DataError::io(path, e))?
        .with_guessed_format()
        .map_err(|e| DataError::io(path, e))?
        .into_dimensions()
        .map_err(|e| DataError::image(path, format!("cannot read the image header: {e}")))
}

/// Loads a depth image in metres and checks it against the source's intrinsics.
pub(crate) fn load_depth_checked(
    path: &Path,
    units_per_metre: f32,
    invalid: &[u16],
    intrinsics: &Intrinsics,
) -> Result<Vec<f32>> {
    let d = load_depth(path, units_per_metre, invalid)?;
    check_size(path, d.width, d.height, intrinsics)?;
    Ok(d.depth)
}

/// Loads a colour image and registers it to the depth grid (`color_intrinsics` without a
/// size: the size is taken from the image).
pub(crate) fn load_color_registered(
    path: &Path,
    intrinsics: &Intrinsics,
    color_fx_fy_cx_cy: Option<[f32; 4]>,
) -> Result<Vec<[u8; 3]>> {
    let c = load_color(path)?;
    let ck = match color_fx_fy_cx_cy {
        Some([fx, fy, cx, cy]) => Some(
            Intrinsics::new(c.width, c.height, fx, fy, cx, cy)
                .map_err(|e| DataError::image(path, format!("colour intrinsics: {e}")))?,
        ),
        None => None,
    };
    Ok(register_color(&c, intrinsics, ck.as_ref()))
}

/// Runs [`Frame::validate`], turning a failure into an error naming `path`.
pub(crate) fn validated(frame: Frame, path: &Path) -> Result<Frame> {
    frame.validate().map_err(|m| DataError::dataset(path, format!("frame {}: {m}", frame.index)))?;
    Ok(frame)
}

/// Reads an Open3D `PinholeCameraIntrinsic` JSON (`width`, `height`, `intrinsic_matrix` as
/// 9 column-major values). `Ok(None)` when the file is JSON but not such an object.
pub(crate) fn read_open3d_intrinsics(path: &Path) -> Result<Option<Intrinsics>> {
    let text = crate::trajectory::read_text(path)?;
    let value: serde_json::Value = match serde_json::from_str(&text) {
        Ok(v) => v,
        // Unrelated broken JSON next to a dataset is none of our business; a broken camera
        // file is.
        Err(_) if !text.contains("intrinsic_matrix") => return Ok(None),
        Err(e) => return Err(DataError::parse(path, Some(e.line()), format!("invalid JSON: {e}"))),
    };
    let Some(matrix) = value.get("intrinsic_matrix") else {
        return Ok(None);
    };
    let m: Vec<f64> = matrix.as_array().map(|a| a.iter().filter_map(|v| v.as_f64()).collect()).unwrap_or_default();
    if m.len() != 9 {
        return Err(DataError::parse(path, None, "`intrinsic_matrix` must be an array of 9 numbers"));
    }
    let dim = |key: &str| {
        value
            .get(key)
            .and_then(|v| v.as_u64())
            .and_then(|v| u32::try_from(v).ok())
            .ok_or_else(|| DataError::parse(path, None, format!("missing or invalid `{key}`")))
    };
    // Column-major: [fx 0 0, 0 fy 0, cx cy 1].
    let k = Intrinsics::new(dim("width")?, dim("height")?, m[0] as f32, m[4] as f32, m[6] as f32, m[7] as f32)
        .map_err(|e| DataError::parse(path, None, e.to_string()))?;
    Ok(Some(k))
}

/// Reads a 3x3 (or 4x4) intrinsics matrix text file: `fx 0 cx / 0 fy cy / 0 0 1`; returns
/// `[fx, fy, cx, cy]`.
pub(crate) fn read_intrinsics_matrix(path: &Path, size: usize) -> Result<[f32; 4]> {
    let text = crate::trajectory::read_text(path)?;
    let m = crate::trajectory::parse_matrix(&text, path, size, size)?;
    let k = [m[0][0] as f32, m[1][1] as f32, m[0][2] as f32, m[1][2] as f32];
    if !(k[0] > 0.0 && k[1] > 0.0) {
        return Err(DataError::parse(path, Some(1), "focal lengths must be positive"));
    }
    Ok(k)
}
