//! The live feed between a camera and the pipeline: the camera runs on its own thread and puts
//! each frame into a one-frame mailbox; the pipeline takes the newest frame when it is ready
//! for one. A frame that arrives while the previous one still waits replaces it: the older one
//! is dropped and counted. Nothing queues without bound, and no frame waits longer than the
//! camera takes to deliver the next one (one frame period).
//!
//! ```text
//! camera thread: next_event() --> [ mailbox: newest frame ] --> LiveFeed::next_timeout() --> pipeline
//!                                        \-- replaced: dropped += 1
//! ```

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use semrecon_data::live::{CameraEvent, LiveCamera};
use semrecon_data::Frame;

/// Counts of a live feed so far.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FeedStats {
    /// Frames the camera delivered.
    pub arrived: usize,
    /// Frames taken by the consumer.
    pub taken: usize,
    /// Frames replaced in the mailbox by a newer one before they were taken.
    pub dropped: usize,
    /// Frames the camera could not deliver (damaged, unreadable).
    pub skipped: usize,
    /// Longest a taken frame waited in the mailbox (at most about one frame period, save for
    /// the stream's last frame, which no newer frame replaces).
    pub max_wait: Duration,
    /// Whether the camera's stream is over.
    pub ended: bool,
    /// Why the stream ended early (camera failure), if it did.
    pub failure: Option<String>,
    /// The first few reasons frames were skipped.
    pub skip_reasons: Vec<String>,
}

/// A frame as taken from the feed.
#[derive(Debug)]
pub struct LiveFrame {
    /// The frame.
    pub frame: Frame,
    /// How long it waited in the mailbox.
    pub waited: Duration,
    /// When it arrived from the camera.
    pub arrived_at: Instant,
}

/// Skip reasons kept in [`FeedStats::skip_reasons`].
const KEPT_REASONS: usize = 10;

struct Shared {
    state: Mutex<State>,
    ready: Condvar,
    stop: AtomicBool,
}

#[derive(Default)]
struct State {
    mailbox: Option<(Frame, Instant)>,
    stats: FeedStats,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
    }
}

/// A camera running on its own thread, read through a one-frame mailbox.
pub struct LiveFeed {
    shared: Arc<Shared>,
    thread: Option<JoinHandle<()>>,
}

impl LiveFeed {
    /// Starts `camera` on its own thread.
    pub fn start(mut camera: Box<dyn LiveCamera>) -> Self {
        let shared = Arc::new(Shared {
            state: Mutex::new(State::default()),
            ready: Condvar::new(),
            stop: AtomicBool::new(false),
        });
        let producer = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("camera".into())
            .spawn(move || {
                while !producer.stop.load(Ordering::Relaxed) {
                    let event = camera.next_event();
                    let mut state = producer.lock();
                    match event {
                        CameraEvent::Frame(frame) => {
                            state.stats.arrived += 1;
                            if state.mailbox.replace((frame, Instant::now())).is_some() {
                                state.stats.dropped += 1;
                            }
                        }
                        CameraEvent::Skipped(why) => {
                            state.stats.skipped += 1;
                            if state.stats.skip_reasons.len() < KEPT_REASONS {
                                state.stats.skip_reasons.push(why);
                            }
                            continue;
                        }
                        CameraEvent::Ended(why) => {
                            state.stats.failure = why;
                            break;
                        }
                    }
                    drop(state);
                    producer.ready.notify_all();
                }
                producer.lock().stats.ended = true;
                producer.ready.notify_all();
                // The camera (and its device) closes here, on its own thread.
                drop(camera);
            })
            .ok();
        if thread.is_none() {
            let mut state = shared.lock();
            state.stats.ended = true;
            state.stats.failure = Some("cannot start the camera thread".into());
        }
        Self { shared, thread }
    }

    /// The newest frame, waiting up to `timeout` for one; `None` on timeout or when the stream
    /// is over and nothing is left (see [`LiveFeed::is_over`]).
    pub fn next_timeout(&self, timeout: Duration) -> Option<LiveFrame> {
        let deadline = Instant::now() + timeout;
        let mut state = self.shared.lock();
        loop {
            if let Some((frame, arrived_at)) = state.mailbox.take() {
                let waited = arrived_at.elapsed();
                state.stats.taken += 1;
                state.stats.max_wait = state.stats.max_wait.max(waited);
                return Some(LiveFrame { frame, waited, arrived_at });
            }
            let now = Instant::now();
            if state.stats.ended || now >= deadline {
                return None;
            }
            state = match self.shared.ready.wait_timeout(state, deadline - now) {
                Ok((guard, _)) => guard,
                Err(poisoned) => poisoned.into_inner().0,
            };
        }
    }

    /// Whether the stream is over and every delivered frame has been taken or dropped.
    pub fn is_over(&self) -> bool {
        let state = self.shared.lock();
        state.stats.ended && state.mailbox.is_none()
    }

    /// The counts so far.
    pub fn stats(&self) -> FeedStats {
        self.shared.lock().stats.clone()
    }

    /// Stops the camera: no frame is taken after this; a frame waiting in the mailbox counts as
    /// dropped. Waits for the camera thread to finish its current frame (at most the time a
    /// camera takes to deliver one, or its timeout).
    pub fn stop(mut self) -> FeedStats {
        self.shutdown();
        self.stats()
    }

    fn shutdown(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
        let mut state = self.shared.lock();
        if state.mailbox.take().is_some() {
            state.stats.dropped += 1;
        }
        state.stats.ended = true;
    }
}

impl Drop for LiveFeed {
    fn drop(&mut self) {
        self.shutdown();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use semrecon_data::Intrinsics;

    /// Delivers `n` tiny frames every `period`.
    struct Ticker {
        n: usize,
        i: usize,
        period: Duration,
        start: Option<Instant>,
    }

    impl LiveCamera for Ticker {
        fn name(&self) -> String {
            "ticker".into()
        }
        fn intrinsics(&self) -> Intrinsics {
            Intrinsics { width: 2, height: 2, fx: 1.0, fy: 1.0, cx: 0.5, cy: 0.5 }
        }
        fn frame_rate(&self) -> f64 {
            1.0 / self.period.as_secs_f64()
        }
        fn next_event(&mut self) -> CameraEvent {
            if self.i >= self.n {
                return CameraEvent::Ended(None);
            }
            let start = *self.start.get_or_insert_with(Instant::now);
            let due = start + self.period * self.i as u32;
            if let Some(w) = due.checked_duration_since(Instant::now()) {
                std::thread::sleep(w);
            }
            let mut frame = Frame::from_depth(self.intrinsics(), vec![1.0; 4]);
            frame.index = self.i;
            self.i += 1;
            CameraEvent::Frame(frame)
        }
    }

    #[test]
    fn a_slow_consumer_drops_frames_and_none_waits_longer_than_a_period() {
        let period = Duration::from_millis(10);
        let feed = LiveFeed::start(Box::new(Ticker { n: 40, i: 0, period, start: None }));
        let (mut taken, mut waits) = (Vec::new(), Vec::new());
        while !feed.is_over() {
            if let Some(f) = feed.next_timeout(Duration::from_millis(200)) {
                taken.push(f.frame.index);
                waits.push(f.waited);
                std::thread::sleep(Duration::from_millis(25));
            }
        }
        let stats = feed.stop();
        assert_eq!(stats.arrived, 40);
        assert_eq!(stats.taken + stats.dropped, 40, "{stats:?}");
        assert!(stats.dropped > 10, "a consumer 2.5x slower than the camera drops: {stats:?}");
        assert!(taken.windows(2).all(|w| w[0] < w[1]), "frames in order: {taken:?}");
        assert_eq!(taken.last(), Some(&39), "the newest frame is never lost at the end");
        // One period, with slack for a loaded machine's scheduling (39 ms was seen under a load
        // average of 10); a frame held until the consumer's 200 ms timeout would still fail.
        // The stream's last frame has no successor to replace it and waits for the consumer.
        let longest = waits[..waits.len() - 1].iter().max().copied().unwrap_or_default();
        assert!(longest <= period + Duration::from_millis(75), "{longest:?} {stats:?}");
    }

    #[test]
    fn stopping_mid_stream_ends_the_camera() {
        let feed = LiveFeed::start(Box::new(Ticker { n: 1000, i: 0, period: Duration::from_millis(5), start: None }));
        assert!(feed.next_timeout(Duration::from_secs(2)).is_some());
        let stats = feed.stop();
        assert!(stats.ended && stats.arrived < 1000 && stats.failure.is_none(), "{stats:?}");
    }
}
