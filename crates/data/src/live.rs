//! Live cameras: a [`LiveCamera`] delivers frames when they arrive, blocking until the next
//! one, as a camera does (where a [`FrameSource`] hands out any frame on request).
//!
//! - an OpenNI2 device ([`OpenNiLive`] over [`OniCamera`](crate::openni::OniCamera));
//! - [`Replay`]: any [`FrameSource`] delivered on a timer at its capture times (an `.oni` or
//!   RealSense `.bag` recording, a rendered synthetic scan: a simulated camera), never earlier, and late when
//!   producing a frame takes longer than its period, as a slow camera would be.
//!
//! What happens to frames that arrive while the consumer is busy is the consumer's business
//! (`semrecon_pipeline::live` drops them).

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use rayon::prelude::*;

use crate::camera::Intrinsics;
use crate::frame::{Frame, FrameSource};
use crate::openni::OniCamera;

/// What a camera delivers next.
#[derive(Debug)]
pub enum CameraEvent {
    /// A frame, just arrived.
    Frame(Frame),
    /// A frame that arrived damaged or could not be read: why (the stream goes on).
    Skipped(String),
    /// The stream is over: `None` at the end of a recording, `Some(why)` when the camera
    /// failed (unplugged, a recording cut short).
    Ended(Option<String>),
}

/// A source of frames in real time.
pub trait LiveCamera: Send {
    /// A short description (`oni:/path`, `openni:URI`, `synth:3`).
    fn name(&self) -> String;
    /// Intrinsics of the depth frames.
    fn intrinsics(&self) -> Intrinsics;
    /// Nominal frame rate, Hz.
    fn frame_rate(&self) -> f64;
    /// Frames the stream will deliver, where known (recordings).
    fn expected_frames(&self) -> Option<usize> {
        None
    }
    /// What a user should know about the source, one line each.
    fn notes(&self) -> Vec<String> {
        Vec::new()
    }
    /// Blocks until the next frame arrives (or the stream ends).
    fn next_event(&mut self) -> CameraEvent;
}

/// An OpenNI camera as a live source (a device; a recording opened this way would be read as
/// fast as the consumer reads: replay it with [`Replay`] over [`crate::datasets::Oni`]).
pub struct OpenNiLive {
    camera: OniCamera,
    label: String,
}

impl OpenNiLive {
    /// Wraps an open camera, described as `label` (`oni:FILE`, `openni:URI`).
    pub fn new(camera: OniCamera, label: impl Into<String>) -> Self {
        Self { camera, label: label.into() }
    }
}

impl LiveCamera for OpenNiLive {
    fn name(&self) -> String {
        self.label.clone()
    }

    fn intrinsics(&self) -> Intrinsics {
        self.camera.intrinsics()
    }

    fn frame_rate(&self) -> f64 {
        self.camera.frame_rate()
    }

    fn expected_frames(&self) -> Option<usize> {
        self.camera.recorded_frames()
    }

    fn notes(&self) -> Vec<String> {
        self.camera.notes()
    }

    fn next_event(&mut self) -> CameraEvent {
        match self.camera.next_frame() {
            Ok(Some(frame)) => CameraEvent::Frame(frame),
            Ok(None) => CameraEvent::Ended(None),
            Err(e) => CameraEvent::Ended(Some(e.to_string())),
        }
    }
}

/// Failed reads in a row after which a replayed source is taken to have ended early.
pub const MAX_FAILED_READS: usize = 30;

/// A [`FrameSource`] delivered in real time: frame `i` not before its capture time (its
/// timestamp after the first frame's; `i / frame_rate` where timestamps do not increase),
/// counted from the first call.
pub struct Replay {
    source: Box<dyn FrameSource>,
    next: usize,
    end: usize,
    start: Option<Instant>,
    first_timestamp: Option<f64>,
    last_due: Duration,
    failed_in_a_row: usize,
    speed: f64,
    /// Frames read beforehand by [`Replay::preload`] (or why they could not be).
    preloaded: Option<VecDeque<Result<Frame, String>>>,
}

impl Replay {
    /// Replays `source` at its capture rate.
    pub fn new(source: Box<dyn FrameSource>) -> Self {
        let end = source.len();
        Self {
            source,
            next: 0,
            end,
            start: None,
            first_timestamp: None,
            last_due: Duration::ZERO,
            failed_in_a_row: 0,
            speed: 1.0,
            preloaded: None,
        }
    }

    /// Reads every frame to replay into memory first (in parallel; ground-truth labels left
    /// out), so that producing a frame costs nothing during the replay: a camera that delivers
    /// exactly on time, whatever the source costs (a rendered scan). Memory: about 7 bytes a
    /// pixel a frame (2.2 MB at 640x480).
    pub fn preload(mut self) -> Self {
        let source = &self.source;
        let frames: Vec<Result<Frame, String>> = (0..self.end)
            .into_par_iter()
            .map(|i| source.frame(i).map(|f| Frame { labels: None, ..f }).map_err(|e| e.to_string()))
            .collect();
        self.preloaded = Some(frames.into());
        self
    }

    /// Replays only the first `frames` frames.
    pub fn limit(mut self, frames: usize) -> Self {
        self.end = self.end.min(frames);
        self
    }

    /// Replays at `speed` times the capture rate (2.0: twice as fast).
    pub fn speed(mut self, speed: f64) -> Self {
        if speed.is_finite() && speed > 0.0 {
            self.speed = speed;
        }
        self
    }

    /// When frame `index` with `timestamp` is due, after the first frame.
    fn due(&mut self, index: usize, timestamp: f64) -> Duration {
        let t0 = *self.first_timestamp.get_or_insert(timestamp);
        let by_rate = Duration::from_secs_f64(index as f64 / self.source.frame_rate().max(1e-3));
        let by_stamp = Duration::try_from_secs_f64(timestamp - t0).unwrap_or(by_rate);
        // Timestamps that go backwards or stall fall back to the nominal rate.
        let due = if by_stamp > self.last_due || index == 0 { by_stamp } else { by_rate.max(self.last_due) };
        self.last_due = due;
        due.div_f64(self.speed)
    }
}

impl LiveCamera for Replay {
    fn name(&self) -> String {
        self.source.name()
    }

    fn intrinsics(&self) -> Intrinsics {
        self.source.intrinsics()
    }

    fn frame_rate(&self) -> f64 {
        self.source.frame_rate() * self.speed
    }

    fn expected_frames(&self) -> Option<usize> {
        Some(self.end)
    }

    fn notes(&self) -> Vec<String> {
        self.source.notes()
    }

    fn next_event(&mut self) -> CameraEvent {
        if self.next >= self.end {
            return CameraEvent::Ended(None);
        }
        let index = self.next;
        self.next += 1;
        let start = *self.start.get_or_insert_with(Instant::now);
        let frame = match self.preloaded.as_mut() {
            Some(frames) => frames.pop_front().unwrap_or_else(|| Err("not preloaded".into())),
            None => self.source.frame(index).map_err(|e| e.to_string()),
        };
        match frame {
            Ok(frame) => {
                self.failed_in_a_row = 0;
                let due = start + self.due(index, frame.timestamp);
                if let Some(wait) = due.checked_duration_since(Instant::now()) {
                    std::thread::sleep(wait);
                }
                CameraEvent::Frame(frame)
            }
            Err(e) => {
                self.failed_in_a_row += 1;
                if self.failed_in_a_row >= MAX_FAILED_READS {
                    CameraEvent::Ended(Some(format!(
                        "{MAX_FAILED_READS} frames in a row failed to load, the last: {e}"
                    )))
                } else {
                    CameraEvent::Skipped(format!("frame {index}: {e}"))
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::datasets::{synthetic_scan, SyntheticScanConfig};

    #[test]
    fn a_replay_delivers_at_the_frame_rate_and_ends() {
        let mut config = SyntheticScanConfig::new(2);
        config.frames = 4;
        config.intrinsics = config.intrinsics.scaled(40, 30);
        config.frame_rate = 50.0;
        let (_, scan) = synthetic_scan(&config).expect("scan");
        let mut replay = Replay::new(Box::new(scan)).limit(3);
        let start = Instant::now();
        let mut times = Vec::new();
        while let CameraEvent::Frame(f) = replay.next_event() {
            times.push((f.index, start.elapsed()));
        }
        assert_eq!(times.iter().map(|t| t.0).collect::<Vec<_>>(), vec![0, 1, 2]);
        assert!(times[2].1 >= Duration::from_millis(40), "frame 2 is due 40 ms after frame 0: {times:?}");
        assert!(matches!(replay.next_event(), CameraEvent::Ended(None)));
    }
}
