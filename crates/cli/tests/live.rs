//! `semrecon live`: the simulated camera (a rendered scan delivered at 30 fps on a timer) with
//! frames dropped while the pipeline is busy and none waiting longer than about one frame
//! period; Ctrl-C mid-stream still writes valid outputs; the two real recordings (skipped when
//! `../shared/data` or OpenNI2 is absent); and bad cameras, which are clear errors.

mod common;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{s, semrecon, stderr, stdout};

fn report(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("report.json")).expect("report.json");
    serde_json::from_str(&text).expect("report JSON")
}

fn count(r: &serde_json::Value, key: &str) -> u64 {
    r[key].as_u64().unwrap_or_else(|| panic!("no `{key}` in {r}"))
}

/// The outputs of `run` are there and readable, and the counts add up.
fn check_outputs(dir: &Path) -> serde_json::Value {
    let r = report(dir);
    let mesh = semrecon_data::read_ply(dir.join("mesh.ply")).expect("mesh.ply");
    assert_eq!(mesh.vertex_labels.len(), mesh.positions.len());
    semrecon_data::read_ply(dir.join("semantic.ply")).expect("semantic.ply");
    let trajectory = semrecon_data::Trajectory::read_tum(dir.join("trajectory.txt")).expect("trajectory");
    assert_eq!(trajectory.len() as u64, count(&r, "fused_frames"), "a pose for each fused frame");
    assert_eq!(count(&r, "frames_taken") + count(&r, "dropped_frames"), count(&r, "frames_in"), "{r}");
    assert!(count(&r, "fused_frames") + count(&r, "lost_frames") <= count(&r, "frames_taken"), "{r}");
    r
}

fn shared(rel: &str) -> Option<PathBuf> {
    semrecon_data::shared_data::shared_data_path(rel)
}

/// The `.oni` recording when both it and OpenNI2 are here.
fn oni_recording() -> Option<PathBuf> {
    let path = shared("live-recordings/kinect1-12-frames.oni")?;
    match semrecon_data::openni::availability() {
        Ok(_) => Some(path),
        Err(e) => {
            println!("skipping: {e}");
            None
        }
    }
}

#[test]
fn the_simulated_camera_runs_in_real_time_dropping_what_the_pipeline_cannot_take() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("out");
    let o = semrecon(&[
        "live",
        "--synth",
        "4",
        "--max-frames",
        "45",
        "--voxel",
        "0.02",
        "--semantics",
        "off",
        "--out",
        s(&out),
    ]);
    assert!(o.status.success(), "{}\n{}", stdout(&o), stderr(&o));
    let r = check_outputs(&out);
    assert_eq!(count(&r, "frames_in"), 45);
    assert_eq!(r["stopped_by"], "max_frames");
    assert!(count(&r, "fused_frames") > 5, "{r}");
    let period = r["frame_period_ms"].as_f64().expect("period");
    assert!((period - 33.33).abs() < 0.1, "30 fps: {period}");
    // No frame waits for the pipeline longer than about one frame period (a newer frame
    // replaces it), with a period's slack for a loaded machine's scheduling: a frame kept
    // for three periods fails.
    let max_wait = r["max_wait_ms"].as_f64().expect("max wait");
    assert!(max_wait <= 2.0 * period + 20.0, "a frame waited {max_wait} ms: {r}");
    assert!(r["realtime_factor"].as_f64().is_some_and(|f| f > 0.0), "{r}");
    assert!(r["ate_rmse_m"].as_f64().is_some_and(|a| a < 0.05), "tracking follows the simulated camera: {r}");
    assert!(stdout(&o).contains("finished (--max-frames reached): frames in 45"), "{}", stdout(&o));
}

/// Ctrl-C mid-stream: the session finishes with what it has and its outputs are valid.
#[test]
fn ctrl_c_mid_stream_writes_valid_outputs() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("out");
    let mut child = Command::new(env!("CARGO_BIN_EXE_semrecon"))
        .args([
            "live",
            "--synth",
            "5",
            "--max-frames",
            "150",
            "--voxel",
            "0.02",
            "--semantics",
            "off",
            "--out",
            s(&out),
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start semrecon live");
    let stdout_pipe = child.stdout.take().expect("stdout");
    let (tx, rx) = std::sync::mpsc::channel();
    let reader = std::thread::spawn(move || {
        let mut all = String::new();
        for line in BufReader::new(stdout_pipe).lines().map_while(Result::ok) {
            if line.contains("Ctrl-C finishes") {
                let _ = tx.send(());
            }
            all.push_str(&line);
            all.push('\n');
        }
        all
    });
    rx.recv_timeout(Duration::from_secs(120)).expect("the session starts");
    // About 1.5 s of the 5 s stream.
    std::thread::sleep(Duration::from_millis(1500));
    let killed = Command::new("kill").args(["-INT", &child.id().to_string()]).status().expect("kill");
    assert!(killed.success());
    let started = Instant::now();
    let status = child.wait().expect("wait");
    let printed = reader.join().expect("reader");
    assert!(status.success(), "{printed}");
    assert!(started.elapsed() < Duration::from_secs(60), "finishing took {:?}", started.elapsed());
    assert!(printed.contains("finished (Ctrl-C)"), "{printed}");
    let r = check_outputs(&out);
    assert_eq!(r["stopped_by"], "interrupted");
    assert!(count(&r, "frames_in") < 150, "stopped mid-stream: {r}");
}

#[test]
fn the_kinect_recording_runs_live_and_as_a_dataset() {
    let Some(oni) = oni_recording() else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let live = dir.path().join("live");
    let o = semrecon(&["live", "--oni", s(&oni), "--voxel", "0.02", "--semantics", "off", "--out", s(&live)]);
    assert!(o.status.success(), "{}\n{}", stdout(&o), stderr(&o));
    let r = check_outputs(&live);
    assert_eq!(count(&r, "frames_in"), 12);
    assert_eq!(r["stopped_by"], "end_of_stream");
    assert!(count(&r, "fused_frames") >= 2, "{r}");
    let run = dir.path().join("run");
    let o = semrecon(&[
        "run",
        "--dataset",
        &format!("oni:{}", oni.display()),
        "--voxel",
        "0.02",
        "--semantics",
        "off",
        "--out",
        s(&run),
    ]);
    assert!(o.status.success(), "{}\n{}", stdout(&o), stderr(&o));
    let r = report(&run);
    assert_eq!((count(&r, "frames"), count(&r, "fused_frames")), (12, 12), "no frame dropped as a dataset: {r}");
    let o = semrecon(&["info", "--dataset", &format!("oni:{}", oni.display())]);
    assert!(stdout(&o).contains("frames       12") && stdout(&o).contains("depth units 0.001 m"), "{}", stdout(&o));
}

#[test]
fn the_realsense_recording_runs_live() {
    let Some(bag) = shared("live-recordings/realsense-d435-3-frames.bag") else { return };
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("out");
    let o = semrecon(&["live", "--bag", s(&bag), "--voxel", "0.02", "--semantics", "off", "--out", s(&out)]);
    assert!(o.status.success(), "{}\n{}", stdout(&o), stderr(&o));
    let r = check_outputs(&out);
    assert_eq!(count(&r, "frames_in"), 2);
    assert_eq!(r["stopped_by"], "end_of_stream");
    let o = semrecon(&["info", "--dataset", &format!("bag:{}", bag.display()), "--json"]);
    let info: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("info JSON");
    assert_eq!((info["frames"].as_u64(), info["width"].as_u64()), (Some(2), Some(640)));
}

#[test]
fn bad_cameras_are_clear_errors() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("out");
    let missing = dir.path().join("nothing.bag");
    let o = semrecon(&["live", "--bag", s(&missing), "--out", s(&out)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("nothing.bag: file does not exist"), "{}", stderr(&o));
    let o = semrecon(&["live", "--out", s(&out)]);
    assert!(!o.status.success(), "a camera is required");
    // A truncated recording.
    if let Some(bag) = shared("live-recordings/realsense-d435-3-frames.bag") {
        let bytes = std::fs::read(&bag).expect("bag");
        let cut = dir.path().join("cut.bag");
        std::fs::write(&cut, &bytes[..bytes.len() / 3]).expect("write");
        let o = semrecon(&["run", "--dataset", &format!("bag:{}", cut.display()), "--out", s(&out)]);
        assert!(!o.status.success());
        assert!(stderr(&o).contains("cut.bag: truncated"), "{}", stderr(&o));
        assert!(!stderr(&o).contains("panicked"), "{}", stderr(&o));
    }
    // OpenNI2 missing (the library looked for where there is none): how to install it.
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_semrecon"));
    cmd.env(semrecon_data::openni::LIBRARY_ENV, dir.path().join("libOpenNI2.so.0"));
    let oni = shared("live-recordings/kinect1-12-frames.oni").unwrap_or_else(|| dir.path().join("x.oni"));
    if !oni.exists() {
        std::fs::write(&oni, b"NI10 and more").expect("write");
    }
    let o = cmd.args(["live", "--oni", s(&oni), "--out", s(&out)]).output().expect("run");
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("OpenNI2 is not available") && e.contains("apt-get install libopenni2-0"), "{e}");
}
