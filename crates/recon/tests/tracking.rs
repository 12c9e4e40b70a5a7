//! Ray-casting and frame-to-model tracking on rendered synthetic scans: accuracy against the
//! ground-truth trajectory, lost-frame handling, determinism across thread counts.

use glam::{Affine3A, Vec3};
use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
use semrecon_data::{Frame, FrameSource, SensorModel};
use semrecon_recon::{
    raycast, Tracker, TrackerConfig, TrackingStatus, TsdfConfig, TsdfMap,
};

/// `frames` frames of synthetic scan `seed` at 320x240.
fn scan(seed: u64, frames: usize, ideal: bool) -> Vec<Frame> {
    let mut config = SyntheticScanConfig::new(seed);
    config.frames = frames;
    config.intrinsics = config.intrinsics.scaled(320, 240);
    if ideal {
        config.sensor = SensorModel::ideal();
    }
    let (_room, scan) = synthetic_scan(&config).expect("synthetic scan");
    (0..scan.len())
        .map(|i| scan.frame(i).expect("rendered frame"))
        .collect()
}

fn gt(f: &Frame) -> Affine3A {
    f.world_from_camera.expect("synthetic frames have ground truth")
}

#[test]
fn raycast_reproduces_the_fused_depth() {
    let frames = scan(3, 1, true);
    let f = &frames[0];
    let mut map = TsdfMap::new(TsdfConfig::default()).expect("config");
    map.integrate(f, gt(f)).expect("fusion");
    let t = std::time::Instant::now();
    let view = raycast(&map, f.intrinsics, gt(f), 0.1, 5.0, None);
    eprintln!("raycast {:?}", t.elapsed());
    let k2 = f.intrinsics.scaled(160, 120);
    let t = std::time::Instant::now();
    let v2 = raycast(&map, k2, gt(f), 0.1, 5.0, None);
    eprintln!("raycast 160 {:?} valid {}", t.elapsed(), v2.valid_count());
    let hint: Vec<f32> = (0..120usize).flat_map(|y| (0..160usize).map(move |x| (x, y))).map(|(x, y)| f.depth[2 * y * 320 + 2 * x]).collect();
    let t = std::time::Instant::now();
    let v3 = raycast(&map, k2, gt(f), 0.1, 5.0, Some(&hint));
    eprintln!("raycast 160 hint {:?} valid {}", t.elapsed(), v3.valid_count());
    let (mut n, mut close, mut both) = (0, 0, 0);
    for (d, v) in f.depth.iter().zip(&view.vertices) {
        if *d > 0.0 {
            n += 1;
        }
        if *d > 0.0 && v.z > 0.0 {
            both += 1;
            if (d - v.z).abs() < 0.005 {
                close += 1;
            }
        }
    }
    eprintln!("valid {n}, both {both}, within 5 mm {close}");
    assert!(both as f32 > 0.9 * n as f32, "{both} of {n} pixels hit");
    assert!(close as f32 > 0.95 * both as f32, "{close} of {both} within 5 mm");
}

/// Tracks and fuses `frames` from the first ground-truth pose; returns the estimated poses
/// (None for lost frames) and the map.
fn track_and_fuse(frames: &[Frame], config: TrackerConfig) -> (Vec<Option<Affine3A>>, TsdfMap) {
    let mut map = TsdfMap::new(TsdfConfig::default()).expect("config");
    let mut tracker = Tracker::with_initial_pose(config, gt(&frames[0])).expect("tracker");
    let mut poses = Vec::new();
    for f in frames {
        let r = tracker.track(f, &map).expect("valid frame");
        eprintln!("{}: {:?} inl {:.3} res {:.4} cond {:.2e} ray {:.1} ms total {:.1} err {:.4}", f.index, r.status, r.inlier_ratio, r.residual_rms, r.condition, r.raycast_ms, r.total_ms, (Vec3::from(r.world_from_camera.translation) - Vec3::from(gt(f).translation)).length());
        if r.should_fuse() {
            map.integrate(f, r.world_from_camera).expect("fusion");
            poses.push(Some(r.world_from_camera));
        } else {
            poses.push(None);
        }
    }
    (poses, map)
}

/// RMS translation error against ground truth over the tracked frames (first pose aligned
/// by construction: tracking starts at the true first pose).
fn ate(frames: &[Frame], poses: &[Option<Affine3A>]) -> f32 {
    let errs: Vec<f32> = frames
        .iter()
        .zip(poses)
        .filter_map(|(f, p)| {
            p.map(|p| (Vec3::from(p.translation) - Vec3::from(gt(f).translation)).length_squared())
        })
        .collect();
    (errs.iter().sum::<f32>() / errs.len() as f32).sqrt()
}

#[test]
fn ideal_sensor_tracks_below_a_centimetre() {
    let frames = scan(3, 40, true);
    let (poses, _map) = track_and_fuse(&frames, TrackerConfig::default());
    let lost = poses.iter().filter(|p| p.is_none()).count();
    let e = ate(&frames, &poses);
    eprintln!("ideal: ATE {:.2} mm, {lost} lost", e * 1e3);
    assert_eq!(lost, 0);
    assert!(e < 0.01, "ATE {e} m");
}
