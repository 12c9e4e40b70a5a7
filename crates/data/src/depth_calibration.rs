//! A depth camera's radial depth bias, measured once per camera and divided out of every frame.
//!
//! Structured-light cameras (Kinect v1, Xtion, many RealSense units) read a flat wall face on
//! as a shallow bowl: depth in the image corners is a fraction of a percent too far, by an
//! amount fixed for the unit (Smisek et al. 2011, Herrera et al. 2012, Teichman et al. 2013).
//! Frame-to-model tracking absorbs a little of that bend at every step, and the error builds
//! up into drift that no rigid pose correction (loop closure included) can undo, since each
//! view of the map is bent differently. The fix real systems use is a per-camera calibration,
//! not a per-scan one: measure the bias on a scan with large flat surfaces in view, store it,
//! and correct every later frame of that camera. An online estimate from the scan being
//! reconstructed was tried (session 26, docs/benchmarks_log.md, "Self-calibrating a radial
//! depth bias") and swung by several percent on 7-Scenes, where real depth bends in ways one
//! radial term does not describe; a calibration refuses such a camera instead of guessing
//! ([`estimate`]).
//!
//! The model: measured depth = true depth × (1 + `radial` ρ²), ρ the pixel's distance from
//! the image centre over the half diagonal (1 in the corners). The image centre, not the
//! principal point: the centre of the bias is the sensor's, and the principal point is not
//! known better than the centre for the cameras this is for. [`DepthCalibration::correct`]
//! divides the factor out.

pub mod estimate;

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::live::{CameraEvent, LiveCamera};
use crate::{DataError, Frame, FrameSource, Intrinsics, Result};

/// The `format` tag every calibration file carries.
pub const FORMAT: &str = "semrecon-depth-calibration";
/// Largest radial coefficient a file may hold: 5 % in the corners, ten times what
/// uncalibrated structured-light cameras show; beyond it the file is not a calibration.
pub const MAX_RADIAL: f64 = 0.05;

/// One camera's depth calibration, as stored in its JSON file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DepthCalibration {
    /// Always [`FORMAT`].
    pub format: String,
    /// File version (1).
    pub version: u32,
    /// Relative depth error in the image corners (measured = true × (1 + radial ρ²)).
    pub radial: f64,
    /// Width of the depth images it was measured on, pixels.
    pub width: u32,
    /// Height of the depth images it was measured on, pixels.
    pub height: u32,
    /// The source it was measured on (`synth:1:noisy`, `tum:/path`).
    pub measured_on: String,
    /// Frames whose largest plane gave an estimate.
    pub frames_used: usize,
    /// Robust spread of the frames' estimates (1.4826 × median absolute deviation).
    pub spread: f64,
}

impl DepthCalibration {
    /// A calibration of `radial` for `width` x `height` depth images.
    pub fn new(radial: f64, width: u32, height: u32, measured_on: String, frames_used: usize, spread: f64) -> Self {
        Self { format: FORMAT.into(), version: 1, radial, width, height, measured_on, frames_used, spread }
    }

    /// Reads and checks a calibration file; errors name the file and what is wrong.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|e| DataError::io(path, e))?;
        let calibration: Self = serde_json::from_str(&text)
            .map_err(|e| DataError::parse(path, Some(e.line()), format!("not a depth calibration: {e}")))?;
        calibration.check().map_err(|message| DataError::parse(path, None, message))?;
        Ok(calibration)
    }

    /// Writes the calibration as JSON (to a temporary file, then renamed).
    pub fn save(&self, path: &Path) -> Result<()> {
        let mut text = serde_json::to_string_pretty(self)
            .map_err(|e| DataError::parse(path, None, format!("cannot serialise: {e}")))?;
        text.push('\n');
        crate::atomic_file::write_atomic(path, text.as_bytes())
    }

    /// What is wrong with the fields, if anything.
    fn check(&self) -> std::result::Result<(), String> {
        if self.format != FORMAT {
            return Err(format!("format is {:?}, not {FORMAT:?}", self.format));
        }
        if self.version != 1 {
            return Err(format!("version {} (this build reads version 1)", self.version));
        }
        if !(self.radial.is_finite() && self.radial.abs() <= MAX_RADIAL) {
            return Err(format!("radial coefficient {} is not a finite number within ±{MAX_RADIAL}", self.radial));
        }
        if self.width == 0 || self.height == 0 {
            return Err(format!("image size {}x{} is empty", self.width, self.height));
        }
        Ok(())
    }

    /// Errors unless the camera `name` with intrinsics `k` gives images of the calibrated size.
    pub fn check_size(&self, name: &str, k: Intrinsics) -> Result<()> {
        if k.width == self.width && k.height == self.height {
            return Ok(());
        }
        Err(DataError::InvalidArgument(format!(
            "the depth calibration (measured on {}) is for {}x{} depth images, {name} has {}x{}",
            self.measured_on, self.width, self.height, k.width, k.height
        )))
    }

    /// The factor measured depth carries at pixel `(x, y)` of a `width` x `height` image:
    /// `1 + radial ρ²`.
    pub fn factor(radial: f64, x: usize, y: usize, width: u32, height: u32) -> f64 {
        let (cx, cy) = ((width as f64 - 1.0) * 0.5, (height as f64 - 1.0) * 0.5);
        let corner_sq = (cx * cx + cy * cy).max(1.0);
        let (dx, dy) = (x as f64 - cx, y as f64 - cy);
        1.0 + radial * (dx * dx + dy * dy) / corner_sq
    }

    /// Per pixel, row-major, the reciprocal of [`DepthCalibration::factor`]: what a measured
    /// depth is multiplied by.
    pub fn correction_image(&self) -> Vec<f32> {
        let (w, h) = (self.width as usize, self.height as usize);
        (0..w * h).map(|i| (1.0 / Self::factor(self.radial, i % w, i / w, self.width, self.height)) as f32).collect()
    }

    /// Divides the bias out of `frame`'s depth. Errors when the frame is not of the
    /// calibrated size.
    pub fn correct(&self, frame: &mut Frame) -> Result<()> {
        self.correct_with(&self.correction_image(), frame)
    }

    fn correct_with(&self, image: &[f32], frame: &mut Frame) -> Result<()> {
        if frame.depth.len() != image.len()
            || frame.intrinsics.width != self.width
            || frame.intrinsics.height != self.height
        {
            return Err(DataError::InvalidArgument(format!(
                "the depth calibration is for {}x{} images, frame {} is {}x{}",
                self.width, self.height, frame.index, frame.intrinsics.width, frame.intrinsics.height
            )));
        }
        for (d, c) in frame.depth.iter_mut().zip(image) {
            *d *= c;
        }
        Ok(())
    }
}

/// A calibration with its per-pixel correction image, for one camera's stream: what both
/// wrappers below apply to every frame.
struct Corrector {
    calibration: DepthCalibration,
    image: Vec<f32>,
}

impl Corrector {
    /// Errors when the camera `name` with intrinsics `k` is not of the calibrated size.
    fn new(calibration: DepthCalibration, name: &str, k: Intrinsics) -> Result<Self> {
        calibration.check_size(name, k)?;
        let image = calibration.correction_image();
        Ok(Self { calibration, image })
    }

    fn apply(&self, frame: &mut Frame) -> Result<()> {
        self.calibration.correct_with(&self.image, frame)
    }

    /// The source's notes with one saying what the correction does.
    fn notes(&self, mut notes: Vec<String>) -> Vec<String> {
        notes.push(format!(
            "depth divided by 1 + {:.5} r^2 (calibration measured on {})",
            self.calibration.radial, self.calibration.measured_on
        ));
        notes
    }
}

/// A frame source whose depth goes through a [`DepthCalibration`].
pub struct CalibratedSource {
    inner: Box<dyn FrameSource>,
    corrector: Corrector,
}

impl CalibratedSource {
    /// Wraps `inner`; errors when its images are not of the calibrated size.
    pub fn new(inner: Box<dyn FrameSource>, calibration: DepthCalibration) -> Result<Self> {
        let corrector = Corrector::new(calibration, &inner.name(), inner.intrinsics())?;
        Ok(Self { inner, corrector })
    }
}

impl FrameSource for CalibratedSource {
    fn name(&self) -> String {
        self.inner.name()
    }
    fn len(&self) -> usize {
        self.inner.len()
    }
    fn intrinsics(&self) -> Intrinsics {
        self.inner.intrinsics()
    }
    fn has_ground_truth(&self) -> bool {
        self.inner.has_ground_truth()
    }
    fn color_registered(&self) -> bool {
        self.inner.color_registered()
    }
    fn frame_rate(&self) -> f64 {
        self.inner.frame_rate()
    }
    fn frame(&self, index: usize) -> Result<Frame> {
        let mut frame = self.inner.frame(index)?;
        self.corrector.apply(&mut frame)?;
        Ok(frame)
    }
    fn notes(&self) -> Vec<String> {
        self.corrector.notes(self.inner.notes())
    }
}

/// A live camera whose depth goes through a [`DepthCalibration`].
pub struct CalibratedCamera {
    inner: Box<dyn LiveCamera>,
    corrector: Corrector,
}

impl CalibratedCamera {
    /// Wraps `inner`; errors when its images are not of the calibrated size.
    pub fn new(inner: Box<dyn LiveCamera>, calibration: DepthCalibration) -> Result<Self> {
        let corrector = Corrector::new(calibration, &inner.name(), inner.intrinsics())?;
        Ok(Self { inner, corrector })
    }
}

impl LiveCamera for CalibratedCamera {
    fn name(&self) -> String {
        self.inner.name()
    }
    fn intrinsics(&self) -> Intrinsics {
        self.inner.intrinsics()
    }
    fn frame_rate(&self) -> f64 {
        self.inner.frame_rate()
    }
    fn expected_frames(&self) -> Option<usize> {
        self.inner.expected_frames()
    }
    fn notes(&self) -> Vec<String> {
        self.corrector.notes(self.inner.notes())
    }
    fn next_event(&mut self) -> CameraEvent {
        match self.inner.next_event() {
            CameraEvent::Frame(mut frame) => match self.corrector.apply(&mut frame) {
                Ok(()) => CameraEvent::Frame(frame),
                // A frame of another size than the stream's: skipped, as a damaged one is.
                Err(e) => CameraEvent::Skipped(e.to_string()),
            },
            other => other,
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::sensor::{DepthBias, SensorModel};
    use crate::RenderOutput;

    #[test]
    fn the_correction_undoes_the_generated_sensors_bias() {
        // A flat wall at 2 m rendered through a bias-only sensor, then corrected.
        let k = Intrinsics { width: 64, height: 48, fx: 50.0, fy: 50.0, cx: 31.5, cy: 23.5 };
        let n = 64 * 48;
        let mut out = RenderOutput {
            width: 64,
            height: 48,
            depth: vec![2.0; n],
            color: vec![[0; 3]; n],
            labels: vec![0; n],
            incidence: vec![1.0; n],
        };
        let model = SensorModel { depth_bias: Some(DepthBias { scale: 1.0, radial: 0.005 }), ..SensorModel::ideal() };
        model.apply(&mut out, 0);
        let measured = out.depth;
        assert!(measured.iter().any(|d| (d - 2.0).abs() > 0.005), "the bias is there");
        let calibration = DepthCalibration::new(0.005, 64, 48, "test".into(), 1, 0.0);
        let mut frame = Frame::from_depth(k, measured);
        calibration.correct(&mut frame).unwrap();
        for d in &frame.depth {
            assert!((d - 2.0).abs() < 1e-5, "{d}");
        }
    }

    #[test]
    fn a_frame_of_another_size_is_refused() {
        let k = Intrinsics { width: 32, height: 24, fx: 25.0, fy: 25.0, cx: 15.5, cy: 11.5 };
        let calibration = DepthCalibration::new(0.005, 64, 48, "test".into(), 1, 0.0);
        let mut frame = Frame::from_depth(k, vec![1.0; 32 * 24]);
        let e = calibration.correct(&mut frame).unwrap_err().to_string();
        assert!(e.contains("64x48") && e.contains("32x24"), "{e}");
    }

    #[test]
    fn files_round_trip_and_bad_files_name_the_problem() {
        let dir = std::env::temp_dir().join(format!("semrecon-depth-cal-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("camera.json");
        let calibration = DepthCalibration::new(0.0049, 640, 480, "synth:1:noisy".into(), 27, 0.0003);
        calibration.save(&path).unwrap();
        assert_eq!(DepthCalibration::load(&path).unwrap(), calibration);

        let cases = [
            ("{", "not a depth calibration"),
            (
                r#"{"format":"x","version":1,"radial":0.0,"width":1,"height":1,"measured_on":"","frames_used":0,"spread":0}"#,
                "format",
            ),
            (
                r#"{"format":"semrecon-depth-calibration","version":2,"radial":0.0,"width":1,"height":1,"measured_on":"","frames_used":0,"spread":0}"#,
                "version 2",
            ),
            (
                r#"{"format":"semrecon-depth-calibration","version":1,"radial":0.5,"width":1,"height":1,"measured_on":"","frames_used":0,"spread":0}"#,
                "radial",
            ),
            (
                r#"{"format":"semrecon-depth-calibration","version":1,"radial":0.0,"width":0,"height":1,"measured_on":"","frames_used":0,"spread":0}"#,
                "empty",
            ),
        ];
        for (text, expected) in cases {
            std::fs::write(&path, text).unwrap();
            let e = DepthCalibration::load(&path).unwrap_err().to_string();
            assert!(e.contains("camera.json") && e.contains(expected), "{text}: {e}");
        }
        let e = DepthCalibration::load(&dir.join("missing.json")).unwrap_err().to_string();
        assert!(e.contains("missing.json"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
