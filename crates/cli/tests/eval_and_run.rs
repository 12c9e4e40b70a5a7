//! End-to-end tests of `semrecon run` and `semrecon eval` through the built binary: outputs
//! written and well-formed, numbers right on hand-made inputs, bad input reported as an error
//! (exit code 1 and a message), never a panic.

mod common;

use std::path::{Path, PathBuf};
use std::process::Output;

use glam::{Affine3A, Quat, Vec3};
use semrecon_data::{write_ply, LabeledMesh, PlyEncoding, Trajectory};

use common::{s, semrecon};

fn stdout_json(out: &Output) -> serde_json::Value {
    assert!(out.status.success(), "failed: {}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("JSON on stdout")
}

fn assert_clean_failure(out: &Output, needle: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(stderr.contains(needle), "expected `{needle}` in: {stderr}");
}

/// `semrecon run --dataset DATASET ARGS.. --out OUT_DIR`, which must succeed.
fn run_ok(dataset: &str, args: &[&str], out_dir: &Path) -> Output {
    let mut all = vec!["run", "--dataset", dataset];
    all.extend_from_slice(args);
    all.extend(["--out", s(out_dir)]);
    let out = semrecon(&all);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    out
}

/// A `frames`-frame 64x48 dataset in the 7-Scenes layout, written by `semrecon synth` to
/// `dir/scan`.
fn tiny_seven_scenes(dir: &Path, frames: usize) -> PathBuf {
    let scan = dir.join("scan");
    let out = semrecon(&["synth", "--out", s(&scan), "--frames", &frames.to_string(), "--size", "64x48"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    scan
}

/// The `report.json` that `semrecon run` wrote to `out_dir`.
fn read_report(out_dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out_dir.join("report.json")).expect("report")).expect("JSON")
}

#[test]
fn run_reconstructs_a_few_synthetic_frames() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out_dir = dir.path().join("out");
    let out = run_ok("synth:3", &["--frames", "0..5", "--voxel", "0.02", "--keyframe-every", "2"], &out_dir);
    let table = String::from_utf8_lossy(&out.stdout);
    assert!(table.contains("fusion") && table.contains("meshing"), "{table}");

    let report = read_report(&out_dir);
    assert_eq!(report["frames"], 5);
    assert_eq!(report["lost_frames"], 0);
    assert!(report["colour_fallback_frames"].as_u64().is_some_and(|n| n <= 5), "{report}");
    assert!(report["realtime_factor"].as_f64().expect("number") > 0.0);
    assert!(report["chunks"].as_u64().expect("number") > 0);
    assert!(report["memory_mb"].as_f64().expect("number") > 0.0);
    for stage in ["tracking", "fusion", "meshing", "semantic"] {
        for key in ["median_ms", "p95_ms", "max_ms"] {
            assert!(report["stages"][stage][key].is_number(), "{stage}.{key} in {report}");
        }
    }
    // Keyframes at 2 and 4 fused frames; the final update is a stage of its own.
    assert_eq!(report["stages"]["meshing"]["count"], 2);
    assert_eq!(report["stages"]["final meshing"]["count"], 1);
    // With semantics too keyframes re-mesh within the budget: the labels read the map.
    assert_eq!(report["mesh_budget"], semrecon_pipeline::DEFAULT_MESH_BUDGET);
    assert!(report["mesh_pending_chunks"]["max"].is_u64(), "{report}");
    // Tracked poses (started at the first ground-truth pose) stay within millimetres.
    let ate = report["ate_rmse_m"].as_f64().expect("synthetic data has ground truth");
    assert!(ate < 0.005, "ATE {ate} m");
    assert_eq!(report["poses"], "tracking (frame-to-model ICP)");

    let trajectory = Trajectory::read_tum(out_dir.join("trajectory.txt")).expect("TUM trajectory");
    assert_eq!(trajectory.len(), 5);
    let mesh = semrecon_data::read_ply(out_dir.join("mesh.ply")).expect("mesh");
    assert!(mesh.triangle_count() > 100, "{} triangles", mesh.triangle_count());
    let header = std::fs::read(out_dir.join("mesh.ply")).expect("bytes");
    assert!(header.windows(20).any(|w| w == b"binary_little_endian"));
    assert_eq!(mesh.vertex_labels.len(), mesh.vertex_count(), "labelled vertices");
    assert!(out_dir.join("semantic.ply").is_file());
    // synth: datasets carry their labelled room, so the labels are scored.
    assert!(report["miou"].is_number(), "{report}");
    assert!(report["mesh_accuracy_mm"].as_f64().expect("accuracy") < 20.0, "{report}");
    // 5 frames lie nearly on a line, about which the trajectory's alignment could turn the
    // mesh anyhow: no aligned accuracy.
    assert!(report["mesh_accuracy_aligned_mm"].is_null(), "{report}");
    assert!(report["semantic_passes"].as_u64().expect("passes") >= 2, "{report}");
    assert_eq!(report["realtime"], false);
}

/// The written meshes record the map frame's up direction (the dataset's gravity file, else
/// estimated), so that physics, the viewer and `snapshot` pull balls the right way in frames
/// that are not z up (7-Scenes' world is nearly y down).
#[test]
fn run_records_the_up_direction_in_its_meshes() {
    let dir = tempfile::tempdir().expect("temp dir");
    let scan = tiny_seven_scenes(dir.path(), 6);
    // A gravity file (7-Scenes' convention: the direction of gravity in the poses' world).
    std::fs::write(scan.join("gravity-direction.txt"), "0.0 0.6 -0.8\n").expect("gravity");
    let given = dir.path().join("given");
    run_ok(&format!("7scenes:{}", s(&scan)), &["--voxel", "0.02"], &given);
    for name in ["mesh.ply", "semantic.ply"] {
        let (_, gravity) = semrecon_data::read_ply_with_gravity(given.join(name)).expect("mesh");
        let gravity = gravity.expect("gravity");
        assert!((gravity.up - glam::Vec3::new(0.0, -0.6, 0.8)).length() < 1e-5, "{name}: {}", gravity.up);
        assert!(gravity.floor_height.is_some_and(f32::is_finite), "{name}: {gravity:?}");
    }
    // Without semantics (no estimate from the passes) and without a gravity file: estimated
    // from the mesh and the cameras, the generated room's +z (160x120: at 64x48 the floor
    // and table tops give too few horizontal vertices, and the cameras' prior stays).
    let scan = dir.path().join("larger");
    let out = semrecon(&["synth", "--out", s(&scan), "--frames", "10", "--size", "160x120"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let estimated = dir.path().join("estimated");
    run_ok(&format!("7scenes:{}", s(&scan)), &["--voxel", "0.02", "--semantics", "off"], &estimated);
    let (_, gravity) = semrecon_data::read_ply_with_gravity(estimated.join("mesh.ply")).expect("mesh");
    let gravity = gravity.expect("gravity");
    assert!(gravity.up.angle_between(glam::Vec3::Z).to_degrees() < 2.0, "{}", gravity.up);
    // The generated room's floor is at z = 0.
    let floor = gravity.floor_height.expect("a floor");
    assert!(floor.abs() < 0.05, "floor at {floor} m");
}

/// `--max-memory` spills packed chunks (during the scan past the budget, at its end all of
/// them) and changes no output byte of packing alone, and with
/// `--packed-distance-step 0` none of the plain map's; a budget below the chunks in view is
/// raised and said so in report.json; the spill file does not outlive the run.
#[test]
fn run_within_a_memory_budget_writes_the_same_mesh() {
    let dir = tempfile::tempdir().expect("temp dir");
    let common = ["--frames", "0..12", "--voxel", "0.02", "--keyframe-every", "3", "--semantics", "off"];
    let [plain, packed, budget, exact] = ["plain", "packed", "budget", "exact"].map(|n| dir.path().join(n));
    run_ok("synth:3", &[&common[..], &["--cold-after", "0"]].concat(), &plain);
    run_ok("synth:3", &[&common[..], &["--cold-after", "1"]].concat(), &packed);
    let out = run_ok("synth:3", &[&common[..], &["--cold-after", "1", "--max-memory", "1K"]].concat(), &budget);
    let exact_args = ["--cold-after", "1", "--max-memory", "1K", "--packed-distance-step", "0"];
    run_ok("synth:3", &[&common[..], &exact_args].concat(), &exact);
    let read = |d: &Path, f: &str| std::fs::read(d.join(f)).expect("output");
    for (a, b) in [(&packed, &budget), (&plain, &exact)] {
        assert!(read(a, "mesh.ply") == read(b, "mesh.ply"), "same mesh bytes: {a:?} {b:?}");
        assert!(read(a, "trajectory.txt") == read(b, "trajectory.txt"), "same trajectory: {a:?} {b:?}");
    }
    let report = read_report(&budget);
    let m = &report["map_memory"];
    assert_eq!(m["budget_bytes"], 1024, "{m}");
    assert!(m["budget_raised_to"].as_u64().is_some_and(|r| r > 1024), "{m}");
    assert!(m["surface_m2"].as_f64().is_some_and(|a| a > 0.1) && m["bytes_per_m2"].is_number(), "{m}");
    assert!(m["packed_chunks"].as_u64().unwrap_or(0) + m["spilled_chunks"].as_u64().unwrap_or(0) > 0, "{m}");
    // At the end the whole packed map went to the spill file, before the mesh was assembled.
    let (before, after) = (m["bytes_in_memory"].as_u64(), m["bytes_in_memory_after_finish"].as_u64());
    assert!(before.zip(after).is_some_and(|(b, a)| a <= b), "{m}");
    assert_eq!(read_report(&plain)["map_memory"]["packed_chunks"], 0);
    assert!(read_report(&plain)["map_memory"]["bytes_in_memory_after_finish"].is_null());
    assert!(String::from_utf8_lossy(&out.stdout).contains("raised to"), "summary line");
    let left: Vec<_> = std::fs::read_dir(&budget).expect("dir").flatten().map(|e| e.file_name()).collect();
    assert!(!left.iter().any(|n| n.to_string_lossy().ends_with(".spill")), "{left:?}");
}

#[test]
fn run_in_real_time_keeps_every_frame_and_reports_the_lag() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out_dir = dir.path().join("out");
    let out = run_ok(
        "synth:2",
        &["--frames", "0..6", "--voxel", "0.02", "--keyframe-every", "2", "--realtime", "--semantics", "full"],
        &out_dir,
    );
    let report = read_report(&out_dir);
    assert_eq!(report["realtime"], true);
    assert_eq!((report["frames"].as_u64(), report["fused_frames"].as_u64()), (Some(6), Some(6)));
    assert!(report["max_lag_s"].as_f64().expect("lag") >= 0.0);
    // Frames come at 30 fps: 6 frames take at least 5/30 s.
    assert!(report["wall_s"].as_f64().expect("wall") >= 5.0 / 30.0);
    assert!(String::from_utf8_lossy(&out.stdout).contains("fell behind"));
}

#[test]
fn run_model_and_semantics_options() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out_dir = dir.path().join("out");
    let bad = dir.path().join("weights.safetensors");
    std::fs::write(&bad, b"not weights").expect("write");
    let out = semrecon(&["run", "--dataset", "synth:1", "--frames", "0..2", "--model", s(&bad), "--out", s(&out_dir)]);
    assert_clean_failure(&out, "weights.safetensors");
    run_ok(
        "synth:1",
        &["--frames", "0..3", "--voxel", "0.02", "--semantics", "off", "--keyframe-every", "1"],
        &out_dir,
    );
    let report = read_report(&out_dir);
    assert_eq!(report["semantic_passes"], 0);
    assert_eq!(report["stages"]["semantic"]["count"], 0);
    // Without semantics as well, unless told otherwise.
    assert_eq!(report["mesh_budget"], semrecon_pipeline::DEFAULT_MESH_BUDGET);
    assert!(report["mesh_pending_chunks"]["max"].is_u64(), "{report}");
    run_ok("synth:1", &["--frames", "0..3", "--voxel", "0.02", "--semantics", "off", "--mesh-budget", "0"], &out_dir);
    assert!(read_report(&out_dir)["mesh_budget"].is_null());
}

#[test]
fn run_stops_cleanly_when_the_dataset_ends_early() {
    // 34 frames, of which the last 31 cannot be read: the run stops after 30 failures in a row
    // and still writes valid outputs of the first three frames.
    let dir = tempfile::tempdir().expect("temp dir");
    let scan = tiny_seven_scenes(dir.path(), 34);
    for i in 3..34 {
        std::fs::write(scan.join(format!("frame-{i:06}.depth.png")), b"truncated").expect("corrupt");
    }
    let out_dir = dir.path().join("out");
    let dataset = format!("7scenes:{}", s(&scan));
    let out = run_ok(&dataset, &["--poses", "ground-truth", "--voxel", "0.05", "--keyframe-every", "2"], &out_dir);
    assert!(String::from_utf8_lossy(&out.stdout).contains("ended early"), "{}", String::from_utf8_lossy(&out.stdout));
    let report = read_report(&out_dir);
    assert_eq!(report["stopped_early_at"], 33);
    assert_eq!((report["fused_frames"].as_u64(), report["failed_loads"].as_u64()), (Some(3), Some(30)));
    assert_eq!(Trajectory::read_tum(out_dir.join("trajectory.txt")).expect("TUM").len(), 3);
    let mesh = semrecon_data::read_ply(out_dir.join("mesh.ply")).expect("mesh");
    mesh.validate().expect("valid mesh");
}

#[test]
fn run_rejects_bad_input_cleanly() {
    let dir = tempfile::tempdir().expect("temp dir");
    let out_dir = dir.path().join("out");
    let missing = dir.path().join("nothing-here");
    let out = semrecon(&["run", "--dataset", &format!("7scenes:{}", s(&missing)), "--out", s(&out_dir)]);
    assert_clean_failure(&out, "nothing-here");
    let out = semrecon(&["run", "--dataset", "synth:1", "--frames", "400..500", "--out", s(&out_dir)]);
    assert_clean_failure(&out, "selects no frame");
    let out = semrecon(&["run", "--dataset", "synth:1", "--frames", "5..5", "--out", s(&out_dir)]);
    assert!(!out.status.success());
    let out = semrecon(&["run", "--dataset", "synth:1", "--frames", "0..2", "--voxel=-1", "--out", s(&out_dir)]);
    assert_clean_failure(&out, "voxel");
    // A loop-closure option without loop closure would be silently ignored: refused instead
    // (`run` closes loops unless told not to; `demo` only when told to).
    let args = ["run", "--dataset", "synth:1", "--no-loop-closure", "--odometry-information-from-tracking"];
    let out = semrecon(&[&args[..], &["--out", s(&out_dir)]].concat());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "a usage error: {stderr}");
    assert!(stderr.contains("--no-loop-closure"), "{stderr}");
    let out = semrecon(&["demo", "--frame-store", "1G", "--out", s(&out_dir)]);
    assert_clean_failure(&out, "--loop-closure");
    assert!(!out_dir.join("report.json").exists());
}

#[test]
fn run_skips_frames_that_fail_to_load() {
    // A tiny 7-Scenes layout dataset with one frame's depth image corrupted.
    let dir = tempfile::tempdir().expect("temp dir");
    let scan = tiny_seven_scenes(dir.path(), 6);
    std::fs::write(scan.join("frame-000002.depth.png"), b"not a png").expect("corrupt a frame");
    let out_dir = dir.path().join("out");
    // 64x48 frames are too small to track: this test is about skipping bad frames.
    let dataset = format!("7scenes:{}", s(&scan));
    let out = run_ok(&dataset, &["--poses", "ground-truth", "--voxel", "0.05"], &out_dir);
    assert!(String::from_utf8_lossy(&out.stderr).contains("frame 2 skipped"));
    let report = read_report(&out_dir);
    assert_eq!((report["frames"].as_u64(), report["lost_frames"].as_u64()), (Some(6), Some(1)));
    assert_eq!(Trajectory::read_tum(out_dir.join("trajectory.txt")).expect("TUM").len(), 5);
}

#[test]
fn eval_traj_reports_known_errors() {
    let dir = tempfile::tempdir().expect("temp dir");
    let mut gt = Trajectory::default();
    let mut est = Trajectory::default();
    // Square corners pushed up and down in a checkerboard: 1 cm that no alignment removes,
    // the estimate also moved rigidly. 30 Hz over 2 s, so RPE has 1 s pairs.
    let world = Affine3A::from_rotation_translation(Quat::from_rotation_z(0.5), Vec3::new(2.0, 0.0, -1.0));
    for i in 0..60 {
        let corner = [(1.0f32, 1.0f32), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)][i % 4];
        let p = Vec3::new(corner.0, corner.1, 0.0) * (1.0 + (i / 4) as f32);
        let t = i as f64 / 30.0;
        gt.push(t, Affine3A::from_translation(p));
        est.push(t, world * Affine3A::from_translation(p + Vec3::Z * 0.01 * corner.0 * corner.1));
    }
    let (gt_path, est_path) = (dir.path().join("gt.txt"), dir.path().join("est.txt"));
    gt.write_tum(&gt_path).expect("write");
    est.write_tum(&est_path).expect("write");
    let json_path = dir.path().join("traj.json");
    let out = semrecon(&["eval", "traj", "--gt", s(&gt_path), "--est", s(&est_path), "--json", "--out", s(&json_path)]);
    let r = stdout_json(&out);
    assert_eq!(r["pairs"], 60);
    for key in ["ate_rmse_m", "ate_mean_m", "ate_median_m"] {
        assert!((r[key].as_f64().expect("number") - 0.01).abs() < 1e-5, "{key}: {r}");
    }
    assert!(r["rpe_trans_m_per_s"].is_number() && r["rpe_rot_deg_per_s"].is_number(), "{r}");
    assert_eq!(r["rpe_pairs"], 30);
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json_path).expect("file")).expect("JSON");
    assert_eq!(written, r);

    let table = semrecon(&["eval", "traj", "--gt", s(&gt_path), "--est", s(&est_path)]);
    assert!(String::from_utf8_lossy(&table.stdout).contains("ATE rmse"));

    let garbage = dir.path().join("garbage.txt");
    std::fs::write(&garbage, "0 1 2\n").expect("write");
    assert_clean_failure(&semrecon(&["eval", "traj", "--gt", s(&gt_path), "--est", s(&garbage)]), "garbage.txt:1");
    let shifted = dir.path().join("shifted.txt");
    let mut late = est.clone();
    late.timestamps.iter_mut().for_each(|t| *t += 100.0);
    late.write_tum(&shifted).expect("write");
    assert_clean_failure(&semrecon(&["eval", "traj", "--gt", s(&gt_path), "--est", s(&shifted)]), "only 0 of 60");
}

/// An `n` x `n`-cell square of side 0.5 m at height `z`.
fn plane(n: u32, z: f32) -> LabeledMesh {
    let mut m = LabeledMesh::default();
    for j in 0..=n {
        for i in 0..=n {
            m.positions.push(Vec3::new(0.5 * i as f32 / n as f32, 0.5 * j as f32 / n as f32, z));
            m.colors.push([128; 3]);
        }
    }
    let v = |i: u32, j: u32| j * (n + 1) + i;
    for j in 0..n {
        for i in 0..n {
            m.triangles.push([v(i, j), v(i + 1, j), v(i + 1, j + 1)]);
            m.triangles.push([v(i, j), v(i + 1, j + 1), v(i, j + 1)]);
        }
    }
    m
}

#[test]
fn eval_mesh_reports_known_errors() {
    let dir = tempfile::tempdir().expect("temp dir");
    let (gt_path, est_path) = (dir.path().join("gt.ply"), dir.path().join("est.ply"));
    write_ply(&gt_path, &plane(5, 0.0), PlyEncoding::BinaryLittleEndian).expect("write");
    write_ply(&est_path, &plane(7, 0.015), PlyEncoding::Ascii).expect("write");
    let out = semrecon(&["eval", "mesh", "--gt", s(&gt_path), "--est", s(&est_path), "--json", "--spacing", "0.005"]);
    let r = stdout_json(&out);
    for key in ["accuracy_mean_m", "accuracy_median_m", "completeness_mean_m", "completeness_median_m"] {
        assert!((r[key].as_f64().expect("number") - 0.015).abs() < 1e-5, "{key}: {r}");
    }
    assert_eq!(
        (r["fscore_1cm"].as_f64(), r["fscore_2cm"].as_f64(), r["fscore_5cm"].as_f64()),
        (Some(0.0), Some(1.0), Some(1.0))
    );
    assert_eq!(r["precision_2cm"], 1.0);
    assert_eq!(r["recall_5cm"], 1.0);

    let table = semrecon(&["eval", "mesh", "--gt", s(&gt_path), "--est", s(&est_path)]);
    assert!(String::from_utf8_lossy(&table.stdout).contains("completeness"));

    let missing = dir.path().join("missing.ply");
    assert_clean_failure(&semrecon(&["eval", "mesh", "--gt", s(&gt_path), "--est", s(&missing)]), "missing.ply");
    let empty = dir.path().join("empty.ply");
    write_ply(&empty, &LabeledMesh::default(), PlyEncoding::Ascii).expect("write");
    assert_clean_failure(&semrecon(&["eval", "mesh", "--gt", s(&gt_path), "--est", s(&empty)]), "no vertices");
}

#[test]
fn a_depth_calibration_is_measured_on_one_scan_and_corrects_another() {
    let dir = tempfile::tempdir().expect("temp dir");
    let calibration = dir.path().join("camera.json");
    // The uncalibrated generated sensor: depth 0.5 % too far in the image corners.
    let out =
        semrecon(&["calibrate-depth", "--dataset", "synth:1:noisy", "--frames", "120..250", "--out", s(&calibration)]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&calibration).expect("written")).expect("JSON");
    let radial = file["radial"].as_f64().expect("radial");
    assert!((0.004..0.006).contains(&radial), "{file}");
    let calibration_arg = s(&calibration);
    let out_dir = dir.path().join("out");
    run_ok(
        "synth:1:noisy",
        &["--frames", "0..3", "--semantics", "off", "--depth-calibration", calibration_arg],
        &out_dir,
    );

    // Another camera's image size, a broken file, a missing one, a scan without planes.
    let tiny = tiny_seven_scenes(dir.path(), 2);
    let tiny_spec = format!("7scenes:{}", s(&tiny));
    let run_with = |file: &str| {
        semrecon(&["run", "--dataset", &tiny_spec, "--depth-calibration", file, "--out", s(&dir.path().join("x"))])
    };
    assert_clean_failure(&run_with(calibration_arg), "640x480");
    let broken = dir.path().join("broken.json");
    std::fs::write(&broken, "{\"format\": \"semrecon-depth-calibration\"").expect("write");
    assert_clean_failure(&run_with(s(&broken)), "broken.json");
    assert_clean_failure(&run_with("/no/such/camera.json"), "/no/such/camera.json");
    let refused = dir.path().join("refused.json");
    let out = semrecon(&["calibrate-depth", "--dataset", &tiny_spec, "--out", s(&refused)]);
    assert_clean_failure(&out, "no calibration written");
    assert!(!refused.exists());
}
