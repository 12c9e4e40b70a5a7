//! The camera recordings of `../shared/data/live-recordings` (skipped when absent; the OpenNI
//! ones also when OpenNI2 is not installed): a Kinect v1 `.oni` read through OpenNI2 and a
//! RealSense D435 `.bag`, as datasets and as live cameras; and bad recordings of every kind,
//! which must give an error naming the file and the problem, never a panic.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use semrecon_data::datasets::{Oni, RealSenseBag};
use semrecon_data::live::{CameraEvent, LiveCamera, Replay};
use semrecon_data::openni::{self, OniCamera};
use semrecon_data::{open_dataset, DatasetSpec, Frame, FrameSource};

const ONI: &str = "live-recordings/kinect1-12-frames.oni";
const BAG: &str = "live-recordings/realsense-d435-3-frames.bag";

fn recording(rel: &str) -> Option<PathBuf> {
    semrecon_data::shared_data::shared_data_path(rel)
}

/// The `.oni` recording when both it and OpenNI2 are here.
fn oni_recording() -> Option<PathBuf> {
    let path = recording(ONI)?;
    match openni::availability() {
        Ok(_) => Some(path),
        Err(e) => {
            println!("skipping: {e}");
            None
        }
    }
}

/// A frame that looks like a room seen by a real camera.
fn check_frame(f: &Frame, source: &dyn FrameSource) {
    f.validate().expect("valid frame");
    assert_eq!(f.intrinsics, source.intrinsics());
    let valid = f.depth.iter().filter(|d| **d > 0.0).count();
    assert!(valid > f.depth.len() / 3, "only {valid} valid depth pixels of {}", f.depth.len());
    let (lo, hi) = f.depth_range().expect("some depth");
    assert!(lo > 0.1 && hi < 10.0, "depth range {lo}..{hi}");
    let distinct = f.color.iter().step_by(7).collect::<std::collections::HashSet<_>>().len();
    assert!(distinct > 100, "colour looks blank ({distinct} colours)");
}

/// Every depth is a whole number of `unit` metres.
fn in_units(f: &Frame, unit: f32) -> bool {
    f.depth.iter().all(|&d| {
        let n = d / unit;
        (n - n.round()).abs() < 1e-3
    })
}

fn temp_copy(src: &Path, dir: &Path, name: &str, bytes: Option<usize>, patch: Option<(usize, usize)>) -> PathBuf {
    let mut data = std::fs::read(src).expect("read the recording");
    if let Some(n) = bytes {
        data.truncate(n);
    }
    if let Some((at, len)) = patch {
        let mut x: u32 = 12345;
        for b in &mut data[at..at + len] {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
            *b = (x >> 16) as u8;
        }
    }
    let path = dir.join(name);
    std::fs::write(&path, data).expect("write the copy");
    path
}

// ---------------------------------------------------------------- the Kinect .oni

#[test]
fn the_kinect_recording_reads_as_a_dataset() {
    let Some(path) = oni_recording() else { return };
    let oni = Oni::open(&path).expect("opens");
    assert_eq!(oni.len(), 12);
    assert_eq!(oni.frame_rate(), 30.0);
    let k = oni.intrinsics();
    assert_eq!((k.width, k.height), (640, 480));
    // The Kinect v1 depth camera: 58.1 x 45.3 degrees, fx = fy = 575.8.
    assert!((k.fx - 575.8).abs() < 0.5 && (k.fy - 575.8).abs() < 0.5, "{k:?}");
    assert!((k.cx - 319.5).abs() < 1e-3 && (k.cy - 239.5).abs() < 1e-3, "{k:?}");
    assert!(oni.notes().iter().any(|n| n == "depth units 0.001 m"), "{:?}", oni.notes());
    let frames: Vec<Frame> = (0..oni.len()).map(|i| oni.frame(i).expect("frame")).collect();
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f.index, i);
        check_frame(f, &oni);
        assert!(in_units(f, 0.001), "frame {i}: depth is not in millimetres");
    }
    // 30 fps: 33.3 ms apart, the first at 0 (timestamps start at the first depth frame).
    assert_eq!(frames[0].timestamp, 0.0);
    for w in frames.windows(2) {
        let dt = w[1].timestamp - w[0].timestamp;
        assert!((dt - 1.0 / 30.0).abs() < 0.002, "frames {} and {} are {dt} s apart", w[0].index, w[1].index);
    }
    assert!((frames[11].timestamp - 0.367).abs() < 0.003, "{}", frames[11].timestamp);
    // Reading backwards reopens the recording and gives the same frames.
    let again = oni.frame(3).expect("frame 3 again");
    assert_eq!(again.depth, frames[3].depth);
    assert_eq!(again.color, frames[3].color);
    assert!(oni.frame(12).is_err());
    // Through the KIND:PATH specification too.
    let spec: DatasetSpec = format!("oni:{}", path.display()).parse().expect("spec");
    assert_eq!(open_dataset(&spec).expect("opens").len(), 12);
}

/// The recording's streams share one timeline: reading depth alone to the end would leave no
/// colour. Read together, every depth frame has the colour frame recorded just before it.
#[test]
fn the_kinect_recording_replays_in_real_time_as_a_camera() {
    let Some(path) = oni_recording() else { return };
    assert!(OniCamera::open_recording(&path).expect("opens").has_color());
    let mut live = Replay::new(Box::new(Oni::open(&path).expect("opens")));
    assert_eq!(live.expected_frames(), Some(12));
    let start = Instant::now();
    let mut frames = Vec::new();
    loop {
        match live.next_event() {
            CameraEvent::Frame(f) => frames.push(f),
            CameraEvent::Skipped(why) => panic!("skipped: {why}"),
            CameraEvent::Ended(None) => break,
            CameraEvent::Ended(Some(why)) => panic!("failed: {why}"),
        }
    }
    let took = start.elapsed();
    assert_eq!(frames.len(), 12);
    // 12 frames at 30 fps span 0.37 s: played at the recorded times, not as fast as possible.
    assert!(took >= Duration::from_millis(300), "played in {took:?}");
    for f in &frames {
        let distinct = f.color.iter().step_by(7).collect::<std::collections::HashSet<_>>().len();
        assert!(distinct > 100, "frame {} has no colour", f.index);
    }
}

#[test]
fn bad_oni_files_are_named_errors() {
    let Some(path) = oni_recording() else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let size = std::fs::metadata(&path).expect("size").len() as usize;
    let cases = [
        (temp_copy(&path, dir.path(), "half.oni", Some(size / 2), None), "truncated"),
        (temp_copy(&path, dir.path(), "head.oni", Some(3), None), "shorter than its header"),
        (temp_copy(&path, dir.path(), "empty.oni", Some(0), None), "shorter than its header"),
        (dir.path().join("missing.oni"), "does not exist"),
    ];
    for (file, expected) in &cases {
        let e = Oni::open(file).expect_err("refused").to_string();
        assert!(e.contains(&file.display().to_string()) && e.contains(expected), "{file:?}: {e}");
    }
    std::fs::write(dir.path().join("text.oni"), "not a recording at all").expect("write");
    let e = Oni::open(dir.path().join("text.oni")).expect_err("refused").to_string();
    assert!(e.contains("no `NI10` header"), "{e}");
    // Damaged frame data inside a whole file: frames may be garbage, but reading never panics.
    let damaged = temp_copy(&path, dir.path(), "damaged.oni", None, Some((size / 2, 20_000)));
    if let Ok(oni) = Oni::open(&damaged) {
        for i in 0..oni.len() {
            let _ = oni.frame(i);
        }
    }
}

// ---------------------------------------------------------------- the RealSense .bag

#[test]
fn the_realsense_recording_reads_as_a_dataset() {
    let Some(path) = recording(BAG) else { return };
    let bag = RealSenseBag::open(&path).expect("opens");
    assert_eq!(bag.len(), 2, "two depth frames");
    assert_eq!(bag.depth_unit_m(), 0.001);
    assert_eq!(bag.frame_rate(), 6.0, "recorded at 6 fps (the stream's info)");
    let k = bag.intrinsics();
    assert_eq!((k.width, k.height), (640, 480));
    assert!((k.fx - 390.431).abs() < 0.01 && (k.fy - 390.431).abs() < 0.01, "{k:?}");
    assert!((k.cx - 331.388).abs() < 0.01 && (k.cy - 242.187).abs() < 0.01, "{k:?}");
    let ck = bag.color_intrinsics().expect("colour intrinsics");
    assert_eq!((ck.width, ck.height), (640, 480));
    assert!(ck.fx > 500.0, "the colour camera is narrower: {ck:?}");
    let frames: Vec<Frame> = (0..bag.len()).map(|i| bag.frame(i).expect("frame")).collect();
    for f in &frames {
        check_frame(f, &bag);
        assert!(in_units(f, 0.001));
    }
    assert_eq!(frames[0].timestamp, 0.0);
    let dt = frames[1].timestamp - frames[0].timestamp;
    assert!(dt > 0.0 && dt < 1.0, "frames {dt} s apart");
    // One colour frame, nearest to both depth frames.
    assert_eq!(frames[0].color, frames[1].color);
    assert!(bag.frame(2).is_err());
    let spec: DatasetSpec = format!("bag:{}", path.display()).parse().expect("spec");
    assert_eq!(open_dataset(&spec).expect("opens").len(), 2);
}

#[test]
fn the_realsense_recording_replays_at_its_capture_times() {
    let Some(path) = recording(BAG) else { return };
    let bag = RealSenseBag::open(&path).expect("opens");
    let dt = bag.frame(1).expect("frame").timestamp;
    let mut replay = Replay::new(Box::new(bag));
    let start = Instant::now();
    let mut n = 0;
    while let CameraEvent::Frame(_) = replay.next_event() {
        n += 1;
    }
    assert_eq!(n, 2);
    assert!(start.elapsed().as_secs_f64() >= dt * 0.95, "{:?} for frames {dt} s apart", start.elapsed());
}

#[test]
fn bad_bag_files_are_named_errors() {
    let Some(path) = recording(BAG) else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let size = std::fs::metadata(&path).expect("size").len() as usize;
    let cases = [
        (temp_copy(&path, dir.path(), "half.bag", Some(size / 2), None), "truncated"),
        (temp_copy(&path, dir.path(), "cut.bag", Some(size - 10), None), "cut short"),
        (temp_copy(&path, dir.path(), "head.bag", Some(20), None), "cut short"),
        (temp_copy(&path, dir.path(), "empty.bag", Some(0), None), "not a ROS bag"),
        (dir.path().join("missing.bag"), "does not exist"),
    ];
    for (file, expected) in &cases {
        let e = RealSenseBag::open(file).expect_err("refused").to_string();
        assert!(e.contains(&file.display().to_string()) && e.contains(expected), "{file:?}: {e}");
    }
    // Damage anywhere (header, chunks, index): an error or frames, never a panic.
    for at in [100, 5_000, size / 4, size / 2, size - 3_000] {
        let damaged = temp_copy(&path, dir.path(), "damaged.bag", None, Some((at, 2_000.min(size - at))));
        match RealSenseBag::open(&damaged) {
            Ok(bag) => {
                for i in 0..bag.len() {
                    if let Err(e) = bag.frame(i) {
                        assert!(e.to_string().contains("damaged.bag"), "{e}");
                    }
                }
            }
            Err(e) => assert!(e.to_string().contains("damaged.bag"), "damage at {at}: {e}"),
        }
    }
}
