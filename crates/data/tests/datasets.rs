//! Dataset readers on the shared real samples (skipped when absent) and on fixtures written
//! here, bad input of every kind, and property tests of the trajectory text parsers.

use std::path::{Path, PathBuf};

use glam::{Affine3A, Quat, Vec3};
use proptest::prelude::*;
use semrecon_data::datasets::{Redwood, Replica, ScanNet, SevenScenes, SevenScenesWriter, Tum};
use semrecon_data::depth_image::{write_color_png, write_depth_png, write_label_png};
use semrecon_data::trajectory::{parse_pose_matrix, read_pose_matrix};
use semrecon_data::{open_dataset, DataError, DatasetSpec, Frame, FrameSource, Intrinsics, Trajectory};

fn shared_data() -> Option<PathBuf> {
    semrecon_data::shared_data::shared_data_path("")
}

fn sample(rel: &str) -> Option<PathBuf> {
    let p = shared_data()?.join(rel);
    if p.exists() {
        Some(p)
    } else {
        println!("skipping: ../shared/data/{rel} not found");
        None
    }
}

/// Checks the invariants every reader promises and that the depth looks like a room.
fn check_frame(f: &Frame, source: &dyn FrameSource) {
    f.validate().expect("valid frame");
    assert_eq!(f.intrinsics, source.intrinsics());
    let valid = f.depth.iter().filter(|d| **d > 0.0).count();
    assert!(valid > f.depth.len() / 3, "only {valid} valid depth pixels");
    let (lo, hi) = f.depth_range().expect("some depth");
    assert!(lo > 0.05 && hi < 20.0, "depth range {lo}..{hi}");
    let distinct = f.color.iter().take(5000).collect::<std::collections::HashSet<_>>().len();
    assert!(distinct > 10, "colour looks blank");
}

fn assert_pose_eq(a: &Affine3A, b: &Affine3A, tol: f32) {
    assert!(a.abs_diff_eq(*b, tol), "{a:?} != {b:?}");
}

// ---------------------------------------------------------------- shared samples

/// Median |predicted - measured| depth (metres) when frame `a`'s depth is moved into frame
/// `b` with the ground-truth poses, and the number of pixels compared: checks the pose
/// convention (`world_from_camera`), the depth scale and the intrinsics together.
fn reprojection_error(a: &Frame, b: &Frame) -> (f32, usize) {
    let k = a.intrinsics;
    let b_from_a = b.world_from_camera.expect("pose").inverse() * a.world_from_camera.expect("pose");
    let mut errors = Vec::new();
    for v in (0..k.height).step_by(4) {
        for u in (0..k.width).step_by(4) {
            let z = a.depth[(v * k.width + u) as usize];
            if z <= 0.0 {
                continue;
            }
            let p = b_from_a.transform_point3(k.unproject(u as f32, v as f32, z));
            if p.z <= 0.1 {
                continue;
            }
            let uv = k.project(p).round();
            if uv.x < 0.0 || uv.y < 0.0 || uv.x >= k.width as f32 || uv.y >= k.height as f32 {
                continue;
            }
            let zb = b.depth[(uv.y as u32 * k.width + uv.x as u32) as usize];
            if zb > 0.0 {
                errors.push((zb - p.z).abs());
            }
        }
    }
    errors.sort_by(f32::total_cmp);
    (errors.get(errors.len() / 2).copied().unwrap_or(f32::INFINITY), errors.len())
}

#[test]
fn seven_scenes_redkitchen() {
    let Some(dir) = sample("7scenes-redkitchen") else { return };
    let src = SevenScenes::open(&dir).expect("open");
    assert_eq!(src.len(), 500);
    let k = src.intrinsics();
    assert_eq!((k.width, k.height, k.fx, k.fy, k.cx, k.cy), (640, 480, 585.0, 585.0, 320.0, 240.0));
    assert!(src.has_ground_truth());
    assert!(src.name().starts_with("7scenes:"));
    for i in [0, 250] {
        let f = src.frame(i).expect("frame");
        check_frame(&f, &src);
        assert_eq!(f.index, i);
        let file = dir.join(format!("frame-{i:06}.pose.txt"));
        let expected = read_pose_matrix(&file).expect("pose file").expect("valid pose");
        assert_pose_eq(&f.world_from_camera.expect("pose"), &expected, 1e-6);
    }
    // The camera moves over the sequence.
    let a = src.frame(0).expect("frame").world_from_camera.expect("pose");
    let b = src.frame(499).expect("frame").world_from_camera.expect("pose");
    assert!((a.translation - b.translation).length() > 0.1);
    let (err, n) = reprojection_error(&src.frame(0).expect("frame"), &src.frame(20).expect("frame"));
    println!("7-Scenes frames 0 -> 20: median depth disagreement {err} m over {n} pixels");
    assert!(err < 0.03 && n > 5000, "{err} m over {n} pixels");
}

#[test]
fn sun3d_sequence_with_gaps_and_parent_intrinsics() {
    let Some(dir) = sample("formats/sun3d-3dmatch/seq-01") else { return };
    let src = SevenScenes::open(&dir).expect("open");
    assert_eq!(src.frame_numbers(), vec![0, 1, 2, 116, 422]);
    let k = src.intrinsics();
    assert!((k.fx - 570.342_2).abs() < 1e-3 && k.cx == 320.0 && k.cy == 240.0, "{k:?}");
    let f = src.frame(3).expect("frame");
    check_frame(&f, &src);
    assert_eq!(f.index, 3);
    assert!((f.timestamp - 116.0 / 30.0).abs() < 1e-9);
    assert!(f.world_from_camera.is_some());
    let (err, n) = reprojection_error(&src.frame(0).expect("frame"), &src.frame(2).expect("frame"));
    println!("SUN3D frames 0 -> 2: median depth disagreement {err} m over {n} pixels");
    assert!(err < 0.03 && n > 5000, "{err} m over {n} pixels");
}

#[test]
fn redwood_icl_nuim() {
    let Some(dir) = sample("formats/icl-nuim-open3d/RGBD") else { return };
    let src = Redwood::open(&dir).expect("open");
    assert_eq!(src.len(), 5);
    let k = src.intrinsics();
    assert_eq!((k.width, k.height, k.fx, k.fy, k.cx, k.cy), (640, 480, 525.0, 525.0, 319.5, 239.5));
    assert!(src.has_ground_truth());
    let log = Trajectory::read_log(dir.join("trajectory.log")).expect("log");
    for i in [0, 4] {
        let f = src.frame(i).expect("frame");
        check_frame(&f, &src);
        assert_pose_eq(&f.world_from_camera.expect("pose"), &log.poses[i], 1e-6);
    }
    let (err, n) = reprojection_error(&src.frame(0).expect("frame"), &src.frame(4).expect("frame"));
    println!("ICL-NUIM frames 0 -> 4: median depth disagreement {err} m over {n} pixels");
    assert!(err < 0.03 && n > 5000, "{err} m over {n} pixels");
}

#[test]
fn replica_office0_from_sequence_or_parent() {
    let Some(parent) = sample("replica-office0") else { return };
    for dir in [parent.join("office0"), parent.clone()] {
        let src = Replica::open(&dir).expect("open");
        assert_eq!(src.len(), 4);
        assert_eq!(src.frame_numbers(), vec![0, 1, 2, 3]);
        let k = src.intrinsics();
        assert_eq!((k.width, k.height, k.fx, k.cx, k.cy), (1200, 680, 600.0, 599.5, 339.5));
        assert!(src.has_ground_truth());
    }
    let src = Replica::open(&parent).expect("open");
    let traj = Trajectory::read_replica(parent.join("office0/traj.txt")).expect("traj");
    assert_eq!(traj.len(), 2000);
    let f = src.frame(2).expect("frame");
    check_frame(&f, &src);
    assert_pose_eq(&f.world_from_camera.expect("pose"), &traj.poses[2], 1e-6);
    let (err, n) = reprojection_error(&src.frame(0).expect("frame"), &src.frame(3).expect("frame"));
    println!("Replica frames 0 -> 3: median depth disagreement {err} m over {n} pixels");
    assert!(err < 0.01 && n > 5000, "{err} m over {n} pixels");
}

#[test]
fn sixteen_bit_pgm_depth() {
    let Some(dir) = sample("formats") else { return };
    let d = semrecon_data::depth_image::load_depth(dir.join("kinect-slambook/depth/1.pgm"), 1000.0, &[]).expect("pgm");
    assert_eq!((d.width, d.height), (640, 480));
    let valid: Vec<f32> = d.depth.iter().copied().filter(|v| *v > 0.0).collect();
    let max = valid.iter().copied().fold(0.0f32, f32::max);
    assert!(valid.len() > 100_000 && max < 12.0, "{} valid, max {max}", valid.len());
    // NYU's PGM holds raw Kinect disparity rather than depth; it must still decode as 16-bit.
    let nyu = dir.join("icl-nuim-open3d/RGBD/other_formats/NYU_depth.pgm");
    let d = semrecon_data::depth_image::load_depth(nyu, 1.0, &[]).expect("pgm");
    assert_eq!(d.depth.len(), 640 * 480);
}

#[test]
fn open_dataset_dispatches_on_kind() {
    let Some(dir) = sample("formats/icl-nuim-open3d/RGBD") else { return };
    let spec: DatasetSpec = format!("redwood:{}", dir.display()).parse().expect("spec");
    let src = open_dataset(&spec).expect("open");
    assert_eq!(src.len(), 5);
    assert!(src.name().starts_with("redwood:"));
}

// ---------------------------------------------------------------- fixtures

/// A small synthetic frame: a tilted plane, a colour gradient, stripes of labels.
fn synthetic_frame(index: usize, k: Intrinsics) -> Frame {
    let (w, h) = (k.width as usize, k.height as usize);
    let depth = (0..w * h).map(|i| if i % 17 == 0 { 0.0 } else { 1.0 + (i % w) as f32 * 0.01 }).collect();
    let color = (0..w * h).map(|i| [(i % w * 4) as u8, (i / w * 4) as u8, index as u8]).collect();
    let labels = Some((0..w * h).map(|i| ((i / w) % 13) as u8).collect());
    let pose = Affine3A::from_rotation_translation(
        Quat::from_rotation_y(0.1 * index as f32),
        Vec3::new(index as f32, 0.5, 1.5),
    );
    Frame { index, timestamp: index as f64 / 30.0, depth, color, intrinsics: k, world_from_camera: Some(pose), labels }
}

#[test]
fn seven_scenes_writer_round_trip() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let k = Intrinsics::new(32, 24, 30.5, 31.25, 15.5, 11.75).expect("k");
    let writer = SevenScenesWriter::new(tmp.path().join("seq"), &k).expect("writer");
    let frames: Vec<Frame> = (0..3).map(|i| synthetic_frame(i, k)).collect();
    for f in &frames {
        writer.write_frame(f).expect("write");
    }
    let src = SevenScenes::open(tmp.path().join("seq")).expect("open");
    assert_eq!(src.len(), 3);
    assert_eq!(src.intrinsics(), k);
    assert!(src.has_ground_truth());
    // The layout carries no calibration between its colour and depth cameras.
    assert!(!src.color_registered());
    for f in &frames {
        let g = src.frame(f.index).expect("read");
        for (a, b) in f.depth.iter().zip(&g.depth) {
            assert!((a - b).abs() <= 0.0005 + 1e-6, "{a} vs {b}");
        }
        assert_eq!(g.color, f.color);
        assert_eq!(g.labels, f.labels);
        assert_pose_eq(&g.world_from_camera.expect("pose"), &f.world_from_camera.expect("pose"), 1e-6);
    }
    // A frame of another size is refused.
    let other = synthetic_frame(5, Intrinsics::new(8, 8, 8.0, 8.0, 4.0, 4.0).expect("k"));
    assert!(writer.write_frame(&other).is_err());
}

fn write_tum_images(dir: &Path, names: &[String], color_names: &[String]) {
    let other = shared_data().map(|d| d.join("formats/icl-nuim-open3d/RGBD/other_formats"));
    let real = other.filter(|o| o.join("TUM_depth.png").is_file() && o.join("TUM_color.png").is_file());
    for n in names {
        let path = dir.join(n);
        match &real {
            Some(o) => std::fs::copy(o.join("TUM_depth.png"), &path).map(|_| ()).expect("copy"),
            None => write_depth_png(&path, 64, 48, &vec![1.25; 64 * 48], 5000.0).expect("depth"),
        }
    }
    for n in color_names {
        let path = dir.join(n);
        match &real {
            Some(o) => std::fs::copy(o.join("TUM_color.png"), &path).map(|_| ()).expect("copy"),
            None => {
                let px: Vec<[u8; 3]> = (0..64 * 48).map(|i| [(i % 64) as u8, (i / 64) as u8, 7]).collect();
                write_color_png(&path, 64, 48, &px).expect("color")
            }
        }
    }
}

#[test]
fn tum_fixture_associates_by_timestamp() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path().join("rgbd_dataset_freiburg1_fixture");
    std::fs::create_dir_all(dir.join("rgb")).expect("mkdir");
    std::fs::create_dir_all(dir.join("depth")).expect("mkdir");
    let depth_t = [10.0, 10.1, 10.2, 10.3];
    // rgb lags 10 ms; none near 10.2 (that depth frame is dropped).
    let rgb_t = [10.01, 10.11, 10.25, 10.29];
    let dn: Vec<String> = depth_t.iter().map(|t| format!("depth/{t:.6}.png")).collect();
    let cn: Vec<String> = rgb_t.iter().map(|t| format!("rgb/{t:.6}.png")).collect();
    write_tum_images(&dir, &dn, &cn);
    let list = |ts: &[f64], ns: &[String]| {
        let mut s = String::from("# timestamp filename\n");
        for (t, n) in ts.iter().zip(ns) {
            s.push_str(&format!("{t:.6} {n}\n"));
        }
        s
    };
    std::fs::write(dir.join("depth.txt"), list(&depth_t, &dn)).expect("write");
    std::fs::write(dir.join("rgb.txt"), list(&rgb_t, &cn)).expect("write");
    // Ground truth every 50 ms moving along x at 1 m/s, but nothing after 10.16.
    let mut gt = Trajectory::default();
    for i in 0..=4 {
        let t = 9.96 + 0.05 * i as f64;
        gt.push(t, Affine3A::from_translation(Vec3::new(t as f32 - 10.0, 0.0, 0.0)));
    }
    gt.push(10.31, Affine3A::from_translation(Vec3::new(5.0, 0.0, 0.0)));
    gt.write_tum(dir.join("groundtruth.txt")).expect("gt");

    let src = Tum::open(&dir).expect("open");
    assert_eq!(src.len(), 3);
    assert!(src.has_ground_truth());
    let k = src.intrinsics();
    assert_eq!((k.fx, k.fy, k.cx, k.cy), (517.3, 516.5, 318.6, 255.3));
    let f = src.frame(1).expect("frame");
    f.validate().expect("valid");
    assert!((f.timestamp - 10.1).abs() < 1e-9);
    let x = f.world_from_camera.expect("interpolated pose").translation.x;
    assert!((x - 0.1).abs() < 1e-4, "{x}");
    // 10.3: the bracketing samples are 0.15 s apart, the nearest is 0.01 s away.
    let last = src.frame(2).expect("frame");
    assert!((last.timestamp - 10.3).abs() < 1e-9);
    assert_eq!(last.world_from_camera.map(|p| p.translation.x), Some(5.0));
    let d = f.depth.iter().copied().filter(|d| *d > 0.0).fold(0.0f32, f32::max);
    assert!(d > 0.2 && d < 13.2, "{d}");
}

fn write_matrix(path: &Path, rows: &[[f64; 4]]) {
    let text: String = rows.iter().map(|r| format!("{} {} {} {}\n", r[0], r[1], r[2], r[3])).collect();
    std::fs::write(path, text).expect("write");
}

#[test]
fn scannet_fixture_registers_colour_and_handles_lost_poses() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let dir = tmp.path();
    for sub in ["color", "depth", "pose", "intrinsic"] {
        std::fs::create_dir_all(dir.join(sub)).expect("mkdir");
    }
    // Depth 40x30 with f=36, colour 81x61 with f=60 (a wider, finer colour camera).
    write_matrix(
        &dir.join("intrinsic/intrinsic_depth.txt"),
        &[[36.0, 0.0, 19.5, 0.0], [0.0, 36.0, 14.5, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
    );
    write_matrix(
        &dir.join("intrinsic/intrinsic_color.txt"),
        &[[60.0, 0.0, 40.0, 0.0], [0.0, 60.0, 30.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
    );
    let (cw, ch) = (81usize, 61usize);
    let color: Vec<[u8; 3]> = (0..cw * ch).map(|i| [(i % cw) as u8, (i / cw) as u8, 200]).collect();
    for n in 0..2 {
        write_depth_png(dir.join(format!("depth/{n}.png")), 40, 30, &vec![2.0; 1200], 1000.0).expect("depth");
        write_color_png(dir.join(format!("color/{n}.png")), cw as u32, ch as u32, &color).expect("color");
    }
    write_matrix(
        &dir.join("pose/0.txt"),
        &[[1.0, 0.0, 0.0, 0.5], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
    );
    std::fs::write(dir.join("pose/1.txt"), "-inf -inf -inf -inf\n".repeat(4)).expect("write");

    let src = ScanNet::open(dir).expect("open");
    assert_eq!(src.len(), 2);
    assert!(src.has_ground_truth());
    let f0 = src.frame(0).expect("frame");
    f0.validate().expect("valid");
    assert_eq!(f0.world_from_camera.map(|p| p.translation.x), Some(0.5));
    assert!(src.frame(1).expect("frame").world_from_camera.is_none());
    // Depth pixel (u, v) sees colour pixel (60 (u - 19.5) / 36 + 40, 60 (v - 14.5) / 36 + 30).
    for (u, v) in [(0usize, 0usize), (19, 14), (39, 29), (7, 22)] {
        let uc = 60.0 * (u as f32 - 19.5) / 36.0 + 40.0;
        let vc = 60.0 * (v as f32 - 14.5) / 36.0 + 30.0;
        let px = f0.color[v * 40 + u];
        assert!((px[0] as f32 - uc).abs() <= 0.51 && (px[1] as f32 - vc).abs() <= 0.51, "{u},{v}: {px:?} vs {uc},{vc}");
        assert_eq!(px[2], 200);
    }
}

// ---------------------------------------------------------------- bad input

fn err_text<T>(r: Result<T, DataError>) -> String {
    match r {
        Ok(_) => panic!("expected an error"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn empty_or_missing_folders_say_what_was_expected() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let empty = tmp.path();
    let checks = [
        err_text(SevenScenes::open(empty)),
        err_text(Tum::open(empty)),
        err_text(Redwood::open(empty)),
        err_text(ScanNet::open(empty)),
        err_text(Replica::open(empty)),
    ];
    for e in &checks {
        assert!(e.contains("expected"), "{e}");
        assert!(e.contains(&empty.display().to_string()), "{e}");
    }
    let e = err_text(SevenScenes::open(empty.join("nope")));
    assert!(e.contains("does not exist"), "{e}");
    let e = err_text("nosuch:/x".parse::<DatasetSpec>());
    assert!(e.contains("unknown dataset kind") && e.contains("scannet:PATH"), "{e}");
}

/// A valid one-frame 7-Scenes folder of 16x12 images.
fn tiny_seven_scenes(dir: &Path) {
    let k = Intrinsics::new(16, 12, 20.0, 20.0, 7.5, 5.5).expect("k");
    let w = SevenScenesWriter::new(dir, &k).expect("writer");
    w.write_frame(&synthetic_frame(0, k)).expect("write");
}

#[test]
fn missing_colour_is_a_layout_error() {
    let tmp = tempfile::tempdir().expect("tempdir");
    tiny_seven_scenes(tmp.path());
    std::fs::remove_file(tmp.path().join("frame-000000.color.png")).expect("rm");
    let e = err_text(SevenScenes::open(tmp.path()));
    assert!(e.contains("frame-000000.color.png or frame-000000.color.jpg"), "{e}");
}

#[test]
fn corrupt_and_8_bit_depth_name_the_file() {
    let tmp = tempfile::tempdir().expect("tempdir");
    tiny_seven_scenes(tmp.path());
    let depth = tmp.path().join("frame-000000.depth.png");
    let bytes = std::fs::read(&depth).expect("read");
    std::fs::write(&depth, &bytes[..bytes.len() * 2 / 3]).expect("truncate");
    let src = SevenScenes::open(tmp.path()).expect("header still readable");
    let e = err_text(src.frame(0));
    assert!(e.contains("frame-000000.depth.png"), "{e}");

    write_label_png(&depth, 16, 12, &[9; 192]).expect("8-bit");
    let e = err_text(src.frame(0));
    assert!(e.contains("frame-000000.depth.png") && e.contains("8-bit PNG, expected 16-bit depth"), "{e}");

    std::fs::write(&depth, b"garbage").expect("write");
    let e = err_text(SevenScenes::open(tmp.path()));
    assert!(e.contains("frame-000000.depth.png"), "{e}");
}

#[test]
fn depth_size_must_match_the_intrinsics() {
    let tmp = tempfile::tempdir().expect("tempdir");
    tiny_seven_scenes(tmp.path());
    // A second frame of another size: the source takes its size from the first.
    let k = Intrinsics::new(10, 10, 20.0, 20.0, 5.0, 5.0).expect("k");
    let mut f = synthetic_frame(1, k);
    f.labels = None;
    let w = SevenScenesWriter::new(tmp.path().join("other"), &k).expect("writer");
    w.write_frame(&f).expect("write");
    for ext in ["depth.png", "color.png"] {
        std::fs::rename(
            tmp.path().join(format!("other/frame-000001.{ext}")),
            tmp.path().join(format!("frame-000001.{ext}")),
        )
        .expect("mv");
    }
    let src = SevenScenes::open(tmp.path()).expect("open");
    let e = err_text(src.frame(1));
    assert!(e.contains("frame-000001.depth.png") && e.contains("10x10") && e.contains("16x12"), "{e}");

    // Redwood: the JSON says 640x480 but the images are 16x12.
    let rw = tmp.path().join("redwood");
    std::fs::create_dir_all(rw.join("color")).expect("mkdir");
    std::fs::create_dir_all(rw.join("depth")).expect("mkdir");
    std::fs::copy(tmp.path().join("frame-000000.depth.png"), rw.join("depth/0.png")).expect("cp");
    std::fs::copy(tmp.path().join("frame-000000.color.png"), rw.join("color/0.png")).expect("cp");
    std::fs::write(
        rw.join("camera.json"),
        r#"{"width": 640, "height": 480, "intrinsic_matrix": [525, 0, 0, 0, 525, 0, 319.5, 239.5, 1]}"#,
    )
    .expect("json");
    let e = err_text(Redwood::open(&rw));
    assert!(e.contains("camera.json") && e.contains("16x12") && e.contains("640x480"), "{e}");
}

#[test]
fn bad_pose_lines_name_file_and_line() {
    let tmp = tempfile::tempdir().expect("tempdir");
    tiny_seven_scenes(tmp.path());
    let pose = tmp.path().join("frame-000000.pose.txt");
    std::fs::write(&pose, "1 0 0 0\n0 1 0 zero\n0 0 1 0\n0 0 0 1\n").expect("write");
    let src = SevenScenes::open(tmp.path()).expect("open");
    let e = err_text(src.frame(0));
    assert!(e.contains("frame-000000.pose.txt:2") && e.contains("`zero` is not a number"), "{e}");
    std::fs::write(&pose, "1 0 0 0\n0 1 0 0\n0 0 1 nan\n").expect("write");
    let e = err_text(src.frame(0));
    assert!(e.contains("frame-000000.pose.txt:3") && e.contains("non-finite"), "{e}");

    let log = tmp.path().join("trajectory.log");
    std::fs::write(&log, "0 0 1\n1 0 0 0\n0 1 0 0\n0 0 1 inf\n0 0 0 1\n").expect("write");
    let e = err_text(Trajectory::read_log(&log));
    assert!(e.contains("trajectory.log:4") && e.contains("non-finite"), "{e}");
    let traj = tmp.path().join("traj.txt");
    std::fs::write(&traj, "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n1 0 0 0 0 1 0 0 0 0 1 0 0 0 0\n").expect("write");
    let e = err_text(Trajectory::read_replica(&traj));
    assert!(e.contains("traj.txt:2") && e.contains("16 values"), "{e}");
    let tum = tmp.path().join("gt.txt");
    std::fs::write(&tum, "# x\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 0 1 9\n").expect("write");
    let e = err_text(Trajectory::read_tum(&tum));
    assert!(e.contains("gt.txt:3") && e.contains("8 fields"), "{e}");
}

// ---------------------------------------------------------------- properties

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn parsers_never_panic(text in "\\PC*") {
        let p = Path::new("fuzz.txt");
        let _ = Trajectory::parse_tum(&text, p);
        let _ = Trajectory::parse_log(&text, p);
        let _ = Trajectory::parse_replica(&text, p);
        let _ = parse_pose_matrix(&text, p);
    }

    #[test]
    fn numeric_garbage_never_panics(values in proptest::collection::vec(
        prop_oneof![any::<f64>(), Just(f64::INFINITY), Just(f64::NAN), -2.0..2.0f64], 0..40),
        width in 1usize..17)
    {
        let p = Path::new("fuzz.txt");
        let text: String = values
            .chunks(width)
            .map(|c| c.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(" ") + "\n")
            .collect();
        let _ = Trajectory::parse_tum(&text, p);
        let _ = Trajectory::parse_log(&text, p);
        let _ = Trajectory::parse_replica(&text, p);
        let _ = parse_pose_matrix(&text, p);
    }

    #[test]
    fn tum_round_trip(poses in proptest::collection::vec(
        (0.0..1e5f64, -50.0..50.0f32, -50.0..50.0f32, -50.0..50.0f32,
         -1.0..1.0f32, -1.0..1.0f32, -1.0..1.0f32, -1.0..1.0f32), 0..20))
    {
        let mut t = Trajectory::default();
        for (time, x, y, z, qx, qy, qz, qw) in poses {
            let q = Quat::from_xyzw(qx, qy, qz, qw);
            let q = if q.length() > 0.1 { q.normalize() } else { Quat::IDENTITY };
            t.push(time, Affine3A::from_rotation_translation(q, Vec3::new(x, y, z)));
        }
        let back = Trajectory::parse_tum(&t.to_tum_string(), Path::new("rt.txt")).expect("round trip");
        prop_assert_eq!(&back.timestamps, &t.timestamps);
        for (a, b) in back.poses.iter().zip(&t.poses) {
            prop_assert!(a.abs_diff_eq(*b, 1e-5), "{:?} vs {:?}", a, b);
        }
    }
}
