//! Loop detection on a rendered scan that returns to its start: true revisits accepted with
//! the drift measured, unrelated views and look-alike places elsewhere rejected.

use super::*;
use semrecon_data::datasets::{synthetic_scan, SyntheticScanConfig};
use semrecon_data::FrameSource;

/// Keyframes every 10 frames of a 300-frame rendered scan (seed 1), with their true poses.
fn scan_keyframes() -> Vec<(Frame, DAffine3)> {
    let mut config = SyntheticScanConfig::new(1);
    config.frames = 300;
    let (_, scan) = synthetic_scan(&config).expect("scan");
    (0..30)
        .map(|k| {
            let f = scan.frame(10 * k).expect("frame");
            let pose = f.world_from_camera.map(|p| p.as_daffine3()).expect("rendered frames have poses");
            (f, pose)
        })
        .collect()
}

/// `pose` after drift that grows along the scan: `k` keyframes in, 2 mm and 0.03 degree per
/// keyframe (6 cm and 0.9 degree by the end, several times what tracking drifts on such a
/// scan), the turn about the camera.
fn drifted(k: usize, pose: &DAffine3) -> DAffine3 {
    let k = k as f64;
    let turn = DAffine3 { matrix3: rotation_exp(DVec3::new(0.0, 0.0005 * k, 0.0)), translation: DVec3::ZERO };
    DAffine3::from_translation(DVec3::new(0.0015 * k, -0.0012 * k, 0.0006 * k)) * *pose * turn
}

#[test]
fn a_revisit_with_drift_is_accepted_and_the_alignment_recovers_the_truth() {
    let keyframes = scan_keyframes();
    let mut detector = LoopDetector::new(LoopConfig::default());
    let truth: Vec<DAffine3> = keyframes.iter().map(|(_, p)| *p).collect();
    let drifted: Vec<DAffine3> = truth.iter().enumerate().map(|(k, p)| drifted(k, p)).collect();
    for (f, _) in &keyframes {
        detector.add(f);
    }
    let last = keyframes.len() - 1;
    let verdicts = detector.detect(last, &drifted);
    let accepted: Vec<&LoopVerdict> = verdicts.iter().filter(|v| v.accepted()).collect();
    assert!(!accepted.is_empty(), "no loop accepted: {verdicts:#?}");
    for v in accepted {
        assert!(v.old + detector.config().min_keyframe_gap <= last);
        let true_relative = truth[v.old].inverse() * truth[last];
        let predicted = drifted[v.old].inverse() * drifted[last];
        let (t_err, r_err) = pose_distance(&v.old_from_new, &true_relative);
        let (t_drift, _) = pose_distance(&predicted, &true_relative);
        eprintln!(
            "keyframes {} -> {last}: alignment off the truth by {:.2} mm, {:.3} deg (drift {:.1} mm)",
            v.old,
            t_err * 1e3,
            r_err.to_degrees(),
            t_drift * 1e3
        );
        assert!(t_err < 0.01 && r_err < 0.01, "alignment off the truth by {t_err} m, {r_err} rad");
        assert!(t_err < t_drift / 3.0, "the alignment removes the drift: {t_err} against {t_drift}");
    }
}

#[test]
fn a_look_alike_place_far_away_is_not_a_candidate() {
    let keyframes = scan_keyframes();
    let mut detector = LoopDetector::new(LoopConfig::default());
    // A twin room 4 m to the side: the same views, poses 4 m apart.
    let twin = DAffine3::from_translation(DVec3::new(4.0, 0.0, 0.0));
    let mut poses = Vec::new();
    for (k, (f, p)) in keyframes.iter().enumerate().take(15) {
        detector.add(f);
        poses.push(if k < 12 { *p } else { twin * *p });
    }
    // Keyframe 0 seen again in the twin room.
    detector.add(&keyframes[0].0);
    poses.push(twin * keyframes[0].1);
    let verdicts = detector.detect(15, &poses);
    assert!(verdicts.is_empty(), "{verdicts:#?}");
}

#[test]
fn an_unrelated_view_at_the_predicted_place_is_rejected() {
    let keyframes = scan_keyframes();
    let mut detector = LoopDetector::new(LoopConfig::default());
    for (f, _) in &keyframes {
        detector.add(f);
    }
    // Keyframe 15 looks elsewhere in the room; claim it stands where keyframe 0 stood.
    let v = detector.verify(0, 15, DAffine3::IDENTITY).expect("both keyframes exist");
    assert!(!v.accepted(), "{v:#?}");
    // And the true pair is accepted from its true relative pose.
    let truth = keyframes[0].1.inverse() * keyframes[29].1;
    assert!(detector.verify(0, 29, truth).is_some_and(|v| v.accepted()));
    // Missing keyframes and non-finite predictions give no verdict, not a panic.
    assert!(detector.verify(0, 99, truth).is_none());
    let nan = DAffine3::from_translation(DVec3::new(f64::NAN, 0.0, 0.0));
    assert!(detector.verify(0, 29, nan).is_none());
}

#[test]
fn downscaled_depth_means_agreeing_pixels_and_rejects_sparse_blocks() {
    let mut block = vec![1.0, 1.01, 1.0, 3.0];
    // 3.0 is past the band of the median: the mean of the other three.
    assert!((agreeing_mean(&mut block, 4) - 1.003_333).abs() < 1e-5);
    let mut sparse = vec![1.0];
    assert_eq!(agreeing_mean(&mut sparse, 4), 0.0);
    // A plane facing the camera gives normals along -z.
    let k = Intrinsics::new(16, 12, 14.0, 14.0, 7.5, 5.5).expect("camera");
    let level = level_from_depth(k, &vec![2.0; 16 * 12]);
    let n = level.normals[5 * 16 + 8];
    assert!((n - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-5, "{n}");
    assert!(level.normals[0].is_nan(), "borders have no normal");
}
