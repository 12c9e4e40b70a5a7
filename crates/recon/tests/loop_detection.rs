//! Loop verification on real Kinect data (7-Scenes redkitchen, skipped when the data is
//! absent): keyframes 100 frames apart that see the same place, aligned from their reference
//! relative pose and from one perturbed by the drift tracking has.

#[path = "common/seven_scenes.rs"]
mod seven_scenes;

use glam::{Affine3A, DAffine3, DVec3};
use semrecon_data::{open_dataset, DatasetSpec};
use semrecon_recon::pose_graph::{pose_distance, rotation_exp};
use semrecon_recon::{LoopConfig, LoopDetector};

/// A detector holding every tenth of redkitchen's first 500 frames, and their reference poses.
fn redkitchen_keyframes(dir: &std::path::Path, config: LoopConfig) -> (LoopDetector, Vec<DAffine3>) {
    let mut detector = LoopDetector::new(config);
    let mut poses = Vec::new();
    for i in (0..500).step_by(10) {
        let (frame, pose) = seven_scenes::read_frame(dir, i).expect("frame");
        detector.add(&frame);
        poses.push(d(pose));
    }
    (detector, poses)
}

/// Drift after a long walk, applied to a keyframe's pose: 35 cm and 8 degrees.
fn large_drift() -> DAffine3 {
    DAffine3 { matrix3: rotation_exp(DVec3::new(0.05, 0.12, -0.06)), translation: DVec3::new(0.25, -0.2, 0.15) }
}

fn d(p: Affine3A) -> DAffine3 {
    p.as_daffine3()
}

#[test]
fn redkitchen_revisits_align_the_same_from_a_drifted_start() {
    let Some(dir) = seven_scenes::redkitchen() else {
        eprintln!("skipped: ../shared/data/7scenes-redkitchen is absent");
        return;
    };
    let (detector, poses) = redkitchen_keyframes(&dir, LoopConfig::default());
    // Drift of the size 7-Scenes tracking has: 2 cm and 1 degree.
    let drift =
        DAffine3 { matrix3: rotation_exp(DVec3::new(0.0, 0.017, 0.0)), translation: DVec3::new(0.015, -0.01, 0.008) };
    let mut errors = Vec::new();
    for new in 10..poses.len() {
        let old = new - 10;
        let truth = poses[old].inverse() * poses[new];
        let (Some(from_truth), Some(from_drift)) =
            (detector.verify(old, new, truth), detector.verify(old, new, truth * drift))
        else {
            continue;
        };
        if from_truth.accepted() && from_drift.accepted() {
            let (t, r) = pose_distance(&from_drift.old_from_new, &truth);
            let (dt, _) = pose_distance(&from_drift.old_from_new, &from_truth.old_from_new);
            errors.push((dt, t, r.to_degrees(), old * 10, new * 10, from_drift.residual_rms));
        }
    }
    errors.sort_by(|a, b| a.0.total_cmp(&b.0));
    for e in &errors {
        eprintln!(
            "{:>4} -> {:>4}: {:.2} mm between the two starts; {:.1} mm, {:.2} deg from the reference; residual {:.1} mm",
            e.3,
            e.4,
            e.0 * 1e3,
            e.1 * 1e3,
            e.2,
            e.5 * 1e3
        );
    }
    let median = |i: usize| {
        let mut v: Vec<f64> = errors.iter().map(|e| if i == 0 { e.0 } else { e.1 }).collect();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
    };
    eprintln!(
        "{} of {} pairs accepted from both starts; median {:.2} mm apart, {:.1} mm from the reference",
        errors.len(),
        poses.len() - 10,
        median(0) * 1e3,
        median(1) * 1e3
    );
    // The alignment's own minimum does not depend on the start (2 cm / 1 degree away). The
    // reference poses (KinectFusion's) are not the yardstick at this precision: tracking
    // differs from them by 47 mm median over the same 100-frame gaps, and this alignment by
    // about as much (docs/loop_closure.md), while on rendered scans it recovers the truth to
    // under a millimetre (the unit tests).
    // 11 of 40 since the basin test (18 before it: the other 7 ended 1.7-10 mm apart from
    // starts 2 cm apart along their weakest direction).
    assert!(errors.len() >= 8, "{} accepted", errors.len());
    assert!(median(0) < 0.003, "median {} m between the starts", median(0));
    assert!(median(1) < 0.08, "median {} m from the reference", median(1));
}

/// Two keyframes of a generated two-room loop whose views pin every motion but one only
/// weakly (a wall seen nearly along itself): aligned from their true relative pose, the ICP
/// slides 15 mm along that direction and every other test passes. The basin test sees that
/// it ends elsewhere when started 2 cm either side, and rejects it; a neighbouring keyframe
/// pair of the same place, well pinned, stays accepted and exact. (In a whole run the slide
/// became a "correction" that took the trajectory from 1.4 to 7.5 mm ATE.)
#[test]
fn a_loop_that_slides_along_its_weak_direction_is_rejected() {
    let spec: DatasetSpec = "synth-loop:2".parse().expect("spec");
    let source = open_dataset(&spec).expect("generated");
    let verdict = |new: usize, old: usize, config: LoopConfig| {
        let mut detector = LoopDetector::new(config);
        let mut poses = Vec::new();
        for i in [old, new] {
            let frame = source.frame(i).expect("frame");
            poses.push(frame.world_from_camera.expect("truth").as_daffine3());
            detector.add(&frame);
        }
        let truth = poses[0].inverse() * poses[1];
        let v = detector.verify(0, 1, truth).expect("verdict");
        (v, pose_distance(&v.old_from_new, &truth).0)
    };
    let no_basin = LoopConfig { basin_shift: 0.0, ..LoopConfig::default() };
    let (v, error) = verdict(1019, 729, no_basin);
    assert!(v.accepted() && error > 0.01, "without the test: {:?}, {error} m", v.rejection);
    let (v, _) = verdict(1019, 729, LoopConfig::default());
    assert_eq!(v.rejection, Some(semrecon_recon::LoopRejection::Ambiguous));
    let (v, error) = verdict(1029, 729, LoopConfig::default());
    assert!(v.accepted() && error < 0.001, "{:?}, {error} m", v.rejection);
}

/// A view seen again after a long walk, on real frames with colour registered to depth (TUM
/// fr2/desk, motion-capture poses; skipped when absent): keyframes 30 frames apart, the new
/// one's pose drifted by 35 cm and 8 degrees, beyond the loop ICP's basin. The pose-based
/// candidates fail, and the feature path (BRIEF matches and RANSAC, then the same ICP and
/// tests) finds the loop at the alignment the undrifted start gives.
#[test]
fn desk_views_are_found_by_features_after_large_drift() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/tum-fr2-desk-50");
    if !dir.is_dir() {
        eprintln!("skipped: ../shared/data/tum-fr2-desk-50 is absent");
        return;
    }
    let source = open_dataset(&DatasetSpec::Tum(dir, None)).expect("TUM frames");
    let config = LoopConfig { min_keyframe_gap: 10, ..LoopConfig::default() };
    let mut detector = LoopDetector::new(config);
    let mut poses = Vec::new();
    for i in (0..source.len()).step_by(2) {
        let frame = source.frame(i).expect("frame");
        poses.push(d(frame.world_from_camera.expect("motion capture")));
        detector.add(&frame);
    }
    let drift = large_drift();
    let (mut found, mut tried) = (0, 0);
    for new in 15..poses.len() {
        let old = new - 15;
        let truth = poses[old].inverse() * poses[new];
        // Pairs the ICP accepts from the motion-capture start: the place is seen again.
        let Some(reference) = detector.verify(old, new, truth).filter(|v| v.accepted()) else { continue };
        tried += 1;
        // From the drifted start the ICP alone fails.
        assert!(!detector.verify(old, new, truth * drift).is_some_and(|v| v.accepted()), "{new}: ICP from 35 cm off");
        // A twin of the place 4 m away (the same views, poses metres apart) is no loop:
        // features match it, the correction bound refuses it.
        let mut twin = poses.clone();
        twin[new] = DAffine3::from_translation(DVec3::new(4.0, 0.0, 0.0)) * poses[new];
        assert!(detector.detect(new, &twin).iter().all(|v| !v.accepted()), "{new}: a loop with a twin 4 m away");
        let mut drifted = poses.clone();
        drifted[new] = poses[new] * drift;
        let verdicts = detector.detect(new, &drifted);
        let Some(v) = verdicts.iter().find(|v| v.accepted()) else { continue };
        found += 1;
        assert!(v.feature_inliers > 0, "{new}: accepted without features from 35 cm off: {v:?}");
        // The loop's correction is the drift put in, and its alignment agrees with the
        // reference start's (when it found the same keyframe) or with motion capture.
        let truth_v = poses[v.old].inverse() * poses[new];
        let (t, r) = pose_distance(&v.old_from_new, &truth_v);
        let apart = if v.old == old { pose_distance(&v.old_from_new, &reference.old_from_new).0 } else { f64::NAN };
        eprintln!(
            "frame {:>2} -> {:>2}: {} feature inliers, correction {:.0} mm; {:.1} mm / {:.2} deg from motion capture, {:.2} mm from the undrifted alignment",
            2 * v.old,
            2 * new,
            v.feature_inliers,
            v.correction.0 * 1e3,
            t * 1e3,
            r.to_degrees(),
            apart * 1e3
        );
        assert!(t < 0.03 && r.to_degrees() < 2.0, "{new}: {t} m, {r} rad from motion capture");
        assert!(apart.is_nan() || apart <= 0.003, "{new}: {apart} m from the undrifted alignment");
    }
    eprintln!("{found} of {tried} views found again from 35 cm of drift");
    assert!(tried >= 5 && found * 10 >= tried * 8, "{found} of {tried}");
}

/// The same on 7-Scenes, whose colour is not registered to its depth (the colour camera sits
/// beside the depth camera with another field of view, and the reader only resamples it): a
/// corner's depth is read at the wrong place, centimetres to decimetres off, so RANSAC finds
/// only 12-17 agreeing matches where TUM's registered frames give 70-115 (12 loops over 40
/// drifted keyframes), but none falsely: every loop found corrects the drift put in.
#[test]
fn redkitchen_loops_from_features_correct_the_drift_they_were_given() {
    let Some(dir) = seven_scenes::redkitchen() else {
        eprintln!("skipped: ../shared/data/7scenes-redkitchen is absent");
        return;
    };
    let (detector, poses) = redkitchen_keyframes(&dir, LoopConfig { min_keyframe_gap: 10, ..LoopConfig::default() });
    let drift = large_drift();
    let mut found = 0;
    for new in 10..poses.len() {
        let mut drifted = poses.clone();
        drifted[new] = poses[new] * drift;
        for v in detector.detect(new, &drifted).iter().filter(|v| v.accepted()) {
            found += 1;
            eprintln!(
                "{:>4} -> {:>4}: {} feature inliers, correction {:.0} mm",
                v.frames.0,
                v.frames.1,
                v.feature_inliers,
                v.correction.0 * 1e3
            );
            // The reference poses are themselves a few centimetres off over such gaps.
            assert!((v.correction.0 - drift.translation.length()).abs() < 0.1, "{v:?}");
        }
    }
    eprintln!("{found} loops found from 35 cm of drift");
}
