//! One RGB-D frame and the [`FrameSource`] trait every dataset reader (and the renderer)
//! implements, so that the reconstruction and the CLI never care where frames come from.

use glam::Affine3A;

use crate::camera::Intrinsics;

/// One RGB-D frame at the depth camera's resolution.
///
/// # Shapes
/// `depth`, `color` and (when present) `labels` are row-major, `width * height` long,
/// with `width`/`height` from `intrinsics`.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Index of the frame in its source (0-based).
    pub index: usize,
    /// Capture time in seconds (from the dataset, or `index / 30` when it has none).
    pub timestamp: f64,
    /// Depth along the optical axis in metres; 0 marks a missing measurement.
    pub depth: Vec<f32>,
    /// Colour registered to the depth image (resampled by the reader where the colour camera
    /// has another resolution).
    pub color: Vec<[u8; 3]>,
    /// Camera intrinsics of `depth`.
    pub intrinsics: Intrinsics,
    /// Ground-truth `world_from_camera` pose, when the dataset has one.
    pub world_from_camera: Option<Affine3A>,
    /// Per-pixel class ids (rendered data only; [`crate::class::UNLABELED`] where nothing).
    pub labels: Option<Vec<u8>>,
}

impl Frame {
    /// A frame with depth only (no colour, pose or labels), index 0 at time 0: what a
    /// depth-only sensor gives, and what geometric tests need.
    ///
    /// # Shapes
    /// `depth`: `height * width` metres, row-major.
    pub fn from_depth(intrinsics: Intrinsics, depth: Vec<f32>) -> Self {
        Self { index: 0, timestamp: 0.0, depth, color: Vec::new(), intrinsics, world_from_camera: None, labels: None }
    }

    /// Checks that the buffers match the intrinsics' size and that depth and pose are
    /// finite; readers call this so that downstream code can index without checks.
    pub fn validate(&self) -> Result<(), String> {
        let n = self.intrinsics.pixel_count();
        if self.depth.len() != n {
            return Err(format!("depth has {} pixels, expected {n}", self.depth.len()));
        }
        if self.color.len() != n {
            return Err(format!("colour has {} pixels, expected {n}", self.color.len()));
        }
        if let Some(l) = &self.labels {
            if l.len() != n {
                return Err(format!("labels have {} pixels, expected {n}", l.len()));
            }
        }
        // A branch-free scan per block (vectorised) before the exact search: `position` alone
        // does not vectorise and cost a millisecond a frame at 640x480.
        let is_distance = |d: &f32| (0.0..f32::INFINITY).contains(d);
        const BLOCK: usize = 1024;
        for (b, block) in self.depth.chunks(BLOCK).enumerate() {
            if !block.iter().fold(true, |ok, d| ok & is_distance(d)) {
                let i = b * BLOCK + block.iter().position(|d| !is_distance(d)).unwrap_or(0);
                return Err(format!("depth pixel {i} is {} (not a distance)", self.depth[i]));
            }
        }
        if let Some(pose) = &self.world_from_camera {
            if !pose.is_finite() {
                return Err("ground-truth pose is not finite".into());
            }
        }
        Ok(())
    }

    /// Smallest and largest valid depth in metres; `None` when no pixel is valid.
    pub fn depth_range(&self) -> Option<(f32, f32)> {
        self.depth.iter().filter(|d| **d > 0.0).fold(None, |acc, &d| match acc {
            None => Some((d, d)),
            Some((lo, hi)) => Some((lo.min(d), hi.max(d))),
        })
    }
}

/// A sequence of RGB-D frames with one camera.
///
/// Random access by index so that evaluations can sub-sample and the live pipeline can
/// read ahead; `Send + Sync` so that a reader thread can own it.
pub trait FrameSource: Send + Sync {
    /// A short description (`7scenes:/path`, `synth:3`).
    fn name(&self) -> String;
    /// Number of frames.
    fn len(&self) -> usize;
    /// Whether the source has no frame.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Intrinsics of the depth images (every frame has the same).
    fn intrinsics(&self) -> Intrinsics;
    /// Whether frames carry ground-truth poses.
    fn has_ground_truth(&self) -> bool;
    /// Whether each frame's colour is registered to its depth (the same camera, or resampled
    /// onto the depth grid through both cameras' intrinsics), so that a pixel's colour and
    /// depth see the same point: what the tracker's colour term needs. True unless the
    /// format is known to pair them loosely (7-Scenes).
    fn color_registered(&self) -> bool {
        true
    }
    /// Nominal frame rate in Hz (30 where the dataset does not say).
    fn frame_rate(&self) -> f64 {
        30.0
    }
    /// Loads frame `index`; errors name the file and what is wrong with it.
    fn frame(&self, index: usize) -> crate::Result<Frame>;
    /// What else a user should know about the source (depth units, how colour is registered,
    /// the library that reads it), one line each; `semrecon info` prints them.
    fn notes(&self) -> Vec<String> {
        Vec::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(depth: Vec<f32>, width: u32, height: u32) -> Frame {
        let k = Intrinsics { width, height, fx: 100.0, fy: 100.0, cx: 50.0, cy: 40.0 };
        let n = depth.len();
        Frame { color: vec![[0; 3]; n], ..Frame::from_depth(k, depth) }
    }

    /// The blockwise scan reports the same first bad pixel as a plain search.
    #[test]
    fn validate_names_the_first_pixel_that_is_not_a_distance() {
        let (w, h) = (100u32, 80u32);
        let n = (w * h) as usize;
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY, -0.5, -1e-30] {
            for at in [0, 1023, 1024, 5000, n - 1] {
                let mut depth: Vec<f32> = (0..n).map(|i| (i % 7) as f32 * 0.5).collect();
                depth[at] = bad;
                if at + 3 < n {
                    depth[at + 3] = f32::NAN;
                }
                let err = frame(depth, w, h).validate().expect_err("bad depth");
                assert!(err.starts_with(&format!("depth pixel {at} is ")), "{err}");
            }
        }
        let ok: Vec<f32> = (0..n).map(|i| if i % 3 == 0 { 0.0 } else { i as f32 }).collect();
        assert_eq!(frame(ok, w, h).validate(), Ok(()));
        let mut neg_zero = vec![1.0f32; n];
        neg_zero[17] = -0.0;
        assert_eq!(frame(neg_zero, w, h).validate(), Ok(()), "-0 is 0: a missing measurement");
    }
}
