//! A minimal reader of the 7-Scenes layout for tests and the benchmark (the project's real
//! dataset readers live in `semrecon-data`): 16-bit depth PNG in millimetres (0 and 65535
//! invalid), colour JPEG/PNG, 4x4 row-major camera-to-world pose; fx = fy = 585, cx = 320,
//! cy = 240.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use glam::{Affine3A, Mat4};
use semrecon_data::{Frame, Intrinsics};

/// `<workspace>/../shared/data/7scenes-redkitchen`, when present.
pub fn redkitchen() -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/7scenes-redkitchen");
    dir.is_dir().then_some(dir)
}

/// One 7-Scenes frame with its reference pose.
pub fn read_frame(dir: &Path, index: usize) -> Result<(Frame, Affine3A), String> {
    let k = Intrinsics::new(640, 480, 585.0, 585.0, 320.0, 240.0).map_err(|e| e.to_string())?;
    let stem = dir.join(format!("frame-{index:06}"));
    let depth_path = stem.with_extension("depth.png");
    let depth_img = image::open(&depth_path).map_err(|e| format!("{}: {e}", depth_path.display()))?.into_luma16();
    if depth_img.dimensions() != (k.width, k.height) {
        return Err(format!("{}: size {:?}, expected 640x480", depth_path.display(), depth_img.dimensions()));
    }
    let depth: Vec<f32> =
        depth_img.as_raw().iter().map(|&mm| if mm == 0 || mm == u16::MAX { 0.0 } else { mm as f32 * 1e-3 }).collect();
    let color = ["color.png", "color.jpg"]
        .iter()
        .map(|ext| stem.with_extension(ext))
        .find(|p| p.exists())
        .and_then(|p| image::open(&p).ok())
        .map(|img| img.resize_exact(k.width, k.height, image::imageops::FilterType::Triangle).into_rgb8())
        .map(|img| img.pixels().map(|p| p.0).collect())
        .unwrap_or_else(|| vec![[128, 128, 128]; k.pixel_count()]);
    let pose_path = stem.with_extension("pose.txt");
    let text = std::fs::read_to_string(&pose_path).map_err(|e| format!("{}: {e}", pose_path.display()))?;
    let values: Vec<f32> = text
        .split_whitespace()
        .map(|t| t.parse::<f32>().map_err(|e| format!("{}: {e}", pose_path.display())))
        .collect::<Result<_, _>>()?;
    if values.len() != 16 {
        return Err(format!("{}: {} numbers, expected 16", pose_path.display(), values.len()));
    }
    // Row-major in the file; glam is column-major.
    let m = Mat4::from_cols_slice(&values).transpose();
    let pose = Affine3A::from_mat4(m);
    let frame = Frame {
        index,
        timestamp: index as f64 / 30.0,
        depth,
        color,
        intrinsics: k,
        world_from_camera: Some(pose),
        labels: None,
    };
    Ok((frame, pose))
}
