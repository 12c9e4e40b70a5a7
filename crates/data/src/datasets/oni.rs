//! `oni:FILE`: an OpenNI `.oni` recording as a dataset, frame by frame without dropping any
//! (the recording plays on demand, one frame per read), through [`crate::openni`]. Live
//! (`semrecon live --oni`), [`crate::live::Replay`] delivers it at its recorded times.
//!
//! OpenNI reads a recording forwards only: frames are read in order, a frame behind the last
//! one read reopens the recording, and a frame ahead skips the ones between. Each frame is the
//! depth frame with the colour frame that arrived last before it.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use crate::camera::Intrinsics;
use crate::error::{DataError, Result};
use crate::frame::{Frame, FrameSource};
use crate::openni::{OniCamera, OpenNiError};

/// An OpenNI recording read as a dataset.
#[derive(Debug)]
pub struct Oni {
    path: PathBuf,
    intrinsics: Intrinsics,
    frames: usize,
    frame_rate: f64,
    notes: Vec<String>,
    /// The open recording; `None` after a failure (the next read reopens it).
    camera: Mutex<Option<OniCamera>>,
}

impl Oni {
    /// Opens `path` (OpenNI2 must be installed: the error says how otherwise).
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        if !path.is_file() {
            return Err(DataError::dataset(
                &path,
                if path.exists() { "not a file; expected an OpenNI .oni recording" } else { "file does not exist" },
            ));
        }
        let camera = OniCamera::open_recording(&path)?;
        let frames = camera.recorded_frames().unwrap_or(0);
        let mut notes = camera.notes();
        notes.insert(0, format!("depth units {} m", camera.depth_unit_m()));
        Ok(Self {
            intrinsics: camera.intrinsics(),
            frame_rate: camera.frame_rate(),
            frames,
            notes,
            camera: Mutex::new(Some(camera)),
            path,
        })
    }

    fn read(&self, index: usize) -> std::result::Result<Frame, OpenNiError> {
        let mut guard = self.camera.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        if guard.as_ref().is_none_or(|c| c.frames_read() > index) {
            *guard = None;
            *guard = Some(OniCamera::open_recording(&self.path)?);
        }
        let Some(camera) = guard.as_mut() else {
            return Err(OpenNiError::Device { name: self.path.display().to_string(), message: "not open".into() });
        };
        loop {
            let before = camera.frames_read();
            match camera.next_frame() {
                Ok(Some(frame)) if frame.index == index => return Ok(frame),
                Ok(Some(_)) => continue,
                Ok(None) => {
                    return Err(OpenNiError::Device {
                        name: self.path.display().to_string(),
                        message: format!("the recording ended before frame {index}"),
                    })
                }
                Err(e) => {
                    // A damaged frame is consumed and the recording reads on (one before the
                    // frame wanted is passed over); anything else (the recording stopped
                    // delivering) starts afresh at the next read.
                    let consumed = camera.frames_read() > before;
                    if consumed && before < index {
                        continue;
                    }
                    if !consumed {
                        *guard = None;
                    }
                    return Err(e);
                }
            }
        }
    }
}

impl FrameSource for Oni {
    fn name(&self) -> String {
        format!("oni:{}", self.path.display())
    }

    fn len(&self) -> usize {
        self.frames
    }

    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    fn has_ground_truth(&self) -> bool {
        false
    }

    fn frame_rate(&self) -> f64 {
        self.frame_rate
    }

    fn frame(&self, index: usize) -> Result<Frame> {
        if index >= self.frames {
            return Err(DataError::InvalidArgument(format!(
                "frame {index} of {} frames in {}",
                self.frames,
                self.name()
            )));
        }
        Ok(self.read(index)?)
    }

    fn notes(&self) -> Vec<String> {
        self.notes.clone()
    }
}
