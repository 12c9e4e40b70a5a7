//! Trajectory error metrics as the TUM RGB-D benchmark defines them and `evo` computes them.
//!
//! Estimated poses are matched to ground-truth poses by timestamp, the estimated positions
//! are brought onto the ground truth by the rigid transform (rotation and translation, no
//! scale: depth cameras measure metric scale) that minimises the squared position error
//! (Horn / Umeyama closed form via an SVD), and then:
//! - ATE (absolute trajectory error): the distances between matched positions after the
//!   alignment; RMSE, mean, median and maximum;
//! - RPE (relative pose error) over `delta` seconds: for every matched pose and the matched
//!   pose `delta` seconds later, the motion between them in the estimate compared with the
//!   same motion in the ground truth; translation RMSE and rotation RMSE, divided by `delta`
//!   so that they read per second. RPE ignores the global alignment, so it measures drift.
//!
//! All arithmetic is in f64: positions of long trajectories in f32 lose the tenths of a
//! millimetre that good trackers are compared on.

use glam::{Affine3A, DAffine3, DMat3, DVec3};
use nalgebra::Matrix3;
use semrecon_data::trajectory::associate;
use semrecon_data::Trajectory;
use serde::Serialize;

use crate::error::{EvalError, Result};

/// Settings of [`evaluate_trajectory`].
#[derive(Debug, Clone, PartialEq)]
pub struct TrajectoryEvalConfig {
    /// Largest time difference, seconds, at which an estimated and a ground-truth pose are
    /// taken as the same instant (the TUM tools use 0.02 s).
    pub max_time_difference_s: f64,
    /// Time between the two poses of an RPE pair, seconds (1 s: drift per second).
    pub rpe_delta_s: f64,
}

impl Default for TrajectoryEvalConfig {
    fn default() -> Self {
        Self { max_time_difference_s: 0.02, rpe_delta_s: 1.0 }
    }
}

/// Errors of an estimated trajectory against the ground truth.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrajectoryErrors {
    /// Matched (estimated, ground-truth) pose pairs used for ATE.
    pub pairs: usize,
    /// Root mean square of the position errors after alignment, metres.
    pub ate_rmse_m: f64,
    /// Mean position error after alignment, metres.
    pub ate_mean_m: f64,
    /// Median position error after alignment, metres.
    pub ate_median_m: f64,
    /// Largest position error after alignment, metres.
    pub ate_max_m: f64,
    /// Pose pairs `rpe_delta_s` apart used for RPE (0 when the trajectory is shorter).
    pub rpe_pairs: usize,
    /// RMSE of the relative translation error over `rpe_delta_s`, divided by it: metres per
    /// second (`None` without RPE pairs).
    pub rpe_trans_m_per_s: Option<f64>,
    /// RMSE of the relative rotation error angle, degrees per second (`None` without pairs).
    pub rpe_rot_deg_per_s: Option<f64>,
    /// The alignment found, `gt_world_from_est_world`, as a row-major 3x4 matrix.
    pub gt_from_est: [[f64; 4]; 3],
}

impl TrajectoryErrors {
    /// [`TrajectoryErrors::gt_from_est`] as a transform: what moves anything built in the
    /// estimate's world (a map, a mesh) where the ATE's alignment puts the trajectory.
    pub fn gt_from_est_transform(&self) -> DAffine3 {
        let m = &self.gt_from_est;
        let column = |c: usize| DVec3::new(m[0][c], m[1][c], m[2][c]);
        DAffine3::from_cols(column(0), column(1), column(2), column(3))
    }
}

/// The rigid transform `gt_from_est` minimising `sum |gt_i - (R est_i + t)|^2` (no scale).
///
/// Closed form (Horn 1987 / Umeyama 1991): with the centred point sets, the SVD of the
/// cross-covariance `U D Vᵀ` gives `R = U S Vᵀ`, `S = diag(1, 1, ±1)` chosen so that `R` is a
/// rotation and not a reflection, and `t = mean(gt) - R mean(est)`.
///
/// # Shapes
/// `gt` and `est` have the same length (at least 3 points, not all on one line, for a
/// unique answer; fewer or collinear points still give a minimiser).
pub fn align_rigid(gt: &[DVec3], est: &[DVec3]) -> Result<DAffine3> {
    if gt.len() != est.len() || gt.is_empty() {
        return Err(EvalError::InvalidArgument(format!(
            "alignment needs two equally long non-empty point lists, got {} and {}",
            gt.len(),
            est.len()
        )));
    }
    let n = gt.len() as f64;
    let mean_gt = gt.iter().copied().sum::<DVec3>() / n;
    let mean_est = est.iter().copied().sum::<DVec3>() / n;
    let mut cov = Matrix3::<f64>::zeros();
    for (g, e) in gt.iter().zip(est) {
        let (g, e) = (*g - mean_gt, *e - mean_est);
        for r in 0..3 {
            for c in 0..3 {
                cov[(r, c)] += g[r] * e[c];
            }
        }
    }
    cov /= n;
    let svd = cov.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(EvalError::InvalidArgument("the SVD of the alignment did not converge".into()));
    };
    let mut s = Matrix3::<f64>::identity();
    if u.determinant() * v_t.determinant() < 0.0 {
        s[(2, 2)] = -1.0;
    }
    let r = u * s * v_t;
    let rotation = DMat3::from_cols(
        DVec3::new(r[(0, 0)], r[(1, 0)], r[(2, 0)]),
        DVec3::new(r[(0, 1)], r[(1, 1)], r[(2, 1)]),
        DVec3::new(r[(0, 2)], r[(1, 2)], r[(2, 2)]),
    );
    let translation = mean_gt - rotation * mean_est;
    Ok(DAffine3::from_mat3_translation(rotation, translation))
}

/// ATE and RPE of `est` against `gt` (see the module documentation).
///
/// Every estimated pose is matched to the ground-truth pose nearest in time within
/// `config.max_time_difference_s`; unmatched estimated poses are ignored. Fails when fewer
/// than 3 poses match.
pub fn evaluate_trajectory(
    gt: &Trajectory,
    est: &Trajectory,
    config: &TrajectoryEvalConfig,
) -> Result<TrajectoryErrors> {
    if !(config.max_time_difference_s >= 0.0 && config.max_time_difference_s.is_finite()) {
        return Err(EvalError::InvalidArgument(format!(
            "the association tolerance must be a finite non-negative time, got {}",
            config.max_time_difference_s
        )));
    }
    if !(config.rpe_delta_s > 0.0 && config.rpe_delta_s.is_finite()) {
        return Err(EvalError::InvalidArgument(format!(
            "the RPE interval must be a positive time, got {}",
            config.rpe_delta_s
        )));
    }
    let matches = associate(&est.timestamps, &gt.timestamps, config.max_time_difference_s);
    // (time, gt pose, est pose), sorted by time so that RPE can look `delta` ahead.
    let mut pairs: Vec<(f64, DAffine3, DAffine3)> = matches
        .iter()
        .enumerate()
        .filter_map(|(e, g)| g.map(|g| (gt.timestamps[g], to_f64(&gt.poses[g]), to_f64(&est.poses[e]))))
        .collect();
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    const NEEDED: usize = 3;
    if pairs.len() < NEEDED {
        return Err(EvalError::TooFewMatches {
            matched: pairs.len(),
            estimated: est.len(),
            needed: NEEDED,
            max_difference_s: config.max_time_difference_s,
        });
    }

    let gt_positions: Vec<DVec3> = pairs.iter().map(|p| p.1.translation).collect();
    let est_positions: Vec<DVec3> = pairs.iter().map(|p| p.2.translation).collect();
    let gt_from_est = align_rigid(&gt_positions, &est_positions)?;
    let ate: Vec<f64> = gt_positions
        .iter()
        .zip(&est_positions)
        .map(|(g, e)| (*g - gt_from_est.transform_point3(*e)).length())
        .collect();
    let (ate_rmse_m, ate_mean_m, ate_median_m, ate_max_m) = summary(&ate);

    let (trans, rot) = relative_errors(&pairs, config.rpe_delta_s);
    let per_second = |errors: &[f64]| (!errors.is_empty()).then(|| rms(errors) / config.rpe_delta_s);
    let m = gt_from_est.matrix3;
    let t = gt_from_est.translation;
    Ok(TrajectoryErrors {
        pairs: pairs.len(),
        ate_rmse_m,
        ate_mean_m,
        ate_median_m,
        ate_max_m,
        rpe_pairs: trans.len(),
        rpe_trans_m_per_s: per_second(&trans),
        rpe_rot_deg_per_s: per_second(&rot),
        gt_from_est: [
            [m.x_axis.x, m.y_axis.x, m.z_axis.x, t.x],
            [m.x_axis.y, m.y_axis.y, m.z_axis.y, t.y],
            [m.x_axis.z, m.y_axis.z, m.z_axis.z, t.z],
        ],
    })
}

/// Translation (metres) and rotation (degrees) errors of every RPE pair: each pose and the
/// later pose nearest in time to it plus `delta`, if that one is within 5% of `delta` and
/// within 0.6 median pose intervals of the target (the TUM tool's pairing, with a tolerance so
/// that a gap in the trajectory or its end gives no pair rather than a wrong interval). Every pose starts a pair, as with
/// `evo_rpe --all_pairs`.
///
/// # Shapes
/// `pairs` is sorted by time; both outputs have one entry per RPE pair.
fn relative_errors(pairs: &[(f64, DAffine3, DAffine3)], delta: f64) -> (Vec<f64>, Vec<f64>) {
    let mut steps: Vec<f64> = pairs.windows(2).map(|w| w[1].0 - w[0].0).collect();
    steps.sort_by(f64::total_cmp);
    let median_step = steps.get(steps.len() / 2).copied().unwrap_or(0.0);
    let tolerance = (0.05 * delta).min(0.6 * median_step);
    let mut trans = Vec::new();
    let mut rot = Vec::new();
    for (i, (t0, gt0, est0)) in pairs.iter().enumerate() {
        let target = t0 + delta;
        let after = pairs.partition_point(|p| p.0 < target);
        let nearest = [after.checked_sub(1), Some(after)]
            .into_iter()
            .flatten()
            .filter(|&j| j > i && j < pairs.len())
            .min_by(|&a, &b| (pairs[a].0 - target).abs().total_cmp(&(pairs[b].0 - target).abs()));
        let Some(j) = nearest.filter(|&j| (pairs[j].0 - target).abs() <= tolerance) else {
            continue;
        };
        let (_, gt1, est1) = &pairs[j];
        let gt_motion = gt0.inverse() * *gt1;
        let est_motion = est0.inverse() * *est1;
        let error = gt_motion.inverse() * est_motion;
        trans.push(error.translation.length());
        rot.push(rotation_angle(error.matrix3).to_degrees());
    }
    (trans, rot)
}

/// Angle of a rotation matrix in radians, accurate near 0 and near pi (atan2 of the sine
/// and cosine parts rather than acos of the trace).
fn rotation_angle(r: DMat3) -> f64 {
    let cos = (r.x_axis.x + r.y_axis.y + r.z_axis.z - 1.0) / 2.0;
    let axis = DVec3::new(r.y_axis.z - r.z_axis.y, r.z_axis.x - r.x_axis.z, r.x_axis.y - r.y_axis.x);
    (axis.length() / 2.0).atan2(cos)
}

fn to_f64(pose: &Affine3A) -> DAffine3 {
    let m = pose.matrix3;
    DAffine3::from_mat3_translation(
        DMat3::from_cols(m.x_axis.as_dvec3(), m.y_axis.as_dvec3(), m.z_axis.as_dvec3()),
        pose.translation.as_dvec3(),
    )
}

fn rms(values: &[f64]) -> f64 {
    (values.iter().map(|v| v * v).sum::<f64>() / values.len() as f64).sqrt()
}

/// RMSE, mean, median (mean of the two middle values for an even count) and maximum of a
/// non-empty list.
pub(crate) fn summary(values: &[f64]) -> (f64, f64, f64, f64) {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    let median = if n % 2 == 1 { sorted[n / 2] } else { 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]) };
    let mean = sorted.iter().sum::<f64>() / n as f64;
    (rms(&sorted), mean, median, sorted[n - 1])
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Quat, Vec3};
    use proptest::prelude::*;

    /// A wandering handheld-like trajectory: 30 Hz, `n` poses.
    fn wander(n: usize) -> Trajectory {
        let mut t = Trajectory::default();
        for i in 0..n {
            let s = i as f32 / 30.0;
            let p = Vec3::new(s.sin() * 1.5, (0.7 * s).cos(), 1.2 + 0.2 * (1.3 * s).sin());
            let q = Quat::from_euler(glam::EulerRot::ZYX, 0.5 * s, 0.2 * (0.9 * s).sin(), 0.1 * s.cos());
            t.push(f64::from(i as u32) / 30.0, Affine3A::from_rotation_translation(q, p));
        }
        t
    }

    fn transformed(t: &Trajectory, world: Affine3A) -> Trajectory {
        Trajectory { timestamps: t.timestamps.clone(), poses: t.poses.iter().map(|p| world * *p).collect() }
    }

    #[test]
    fn rigidly_moved_copy_has_no_error() {
        let gt = wander(120);
        let world = Affine3A::from_rotation_translation(
            Quat::from_rotation_z(2.0) * Quat::from_rotation_x(0.4),
            Vec3::new(3.0, -1.0, 0.5),
        );
        let e =
            evaluate_trajectory(&gt, &transformed(&gt, world), &TrajectoryEvalConfig::default()).expect("evaluates");
        assert_eq!(e.pairs, 120);
        assert!(e.ate_rmse_m < 1e-5 && e.ate_max_m < 2e-5, "{e:?}");
        assert_eq!(e.rpe_pairs, 120 - 30);
        assert!(e.rpe_trans_m_per_s.expect("pairs") < 1e-5 && e.rpe_rot_deg_per_s.expect("pairs") < 1e-3, "{e:?}");
        // The alignment found is the inverse of the transform applied.
        let inv = world.inverse();
        assert!((e.gt_from_est[0][3] - f64::from(inv.translation.x)).abs() < 1e-5);
        // As a transform it takes the moved trajectory back onto the original.
        let back = e.gt_from_est_transform();
        for (g, m) in gt.poses.iter().zip(&transformed(&gt, world).poses) {
            let moved = back.transform_point3(Vec3::from(m.translation).as_dvec3());
            assert!((moved - Vec3::from(g.translation).as_dvec3()).length() < 1e-4, "{moved} against {g:?}");
        }
    }

    #[test]
    fn saddle_noise_cannot_be_aligned_away() {
        // Corners of a square, the estimate pushed up and down in a checkerboard pattern:
        // no rotation or translation reduces that, so every error is exactly d.
        let d = 0.01f32;
        let mut gt = Trajectory::default();
        let mut est = Trajectory::default();
        for (i, (x, y)) in [(1.0f32, 1.0f32), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)].into_iter().enumerate() {
            let p = Vec3::new(x, y, 0.0);
            gt.push(i as f64, Affine3A::from_translation(p));
            est.push(i as f64, Affine3A::from_translation(p + Vec3::Z * d * x * y));
        }
        let e = evaluate_trajectory(&gt, &est, &TrajectoryEvalConfig::default()).expect("evaluates");
        for v in [e.ate_rmse_m, e.ate_mean_m, e.ate_median_m, e.ate_max_m] {
            assert!((v - f64::from(d)).abs() < 1e-6, "{e:?}");
        }
    }

    #[test]
    fn ate_statistics_of_known_errors() {
        let (rmse, mean, median, max) = summary(&[0.3, 0.1, 0.2, 0.4]);
        assert!((rmse - 0.075f64.sqrt()).abs() < 1e-12);
        assert!((mean - 0.25).abs() < 1e-12 && (median - 0.25).abs() < 1e-12 && max == 0.4);
    }

    #[test]
    fn rpe_measures_speed_and_spin_errors_per_second() {
        // Ground truth moves at 1 m/s along x; the estimate at 1.1 m/s: 0.1 m per second.
        let mut gt = Trajectory::default();
        let mut est = Trajectory::default();
        for i in 0..31 {
            let s = i as f32 / 10.0;
            gt.push(f64::from(s), Affine3A::from_translation(Vec3::X * s));
            est.push(f64::from(s), Affine3A::from_translation(Vec3::X * 1.1 * s));
        }
        let e = evaluate_trajectory(&gt, &est, &TrajectoryEvalConfig::default()).expect("evaluates");
        assert_eq!(e.rpe_pairs, 21);
        assert!((e.rpe_trans_m_per_s.expect("pairs") - 0.1).abs() < 1e-5, "{e:?}");
        assert!(e.rpe_rot_deg_per_s.expect("pairs") < 1e-4);

        // Standing still, the estimate spinning at 2 degrees per second about z.
        let mut gt = Trajectory::default();
        let mut est = Trajectory::default();
        for i in 0..31 {
            let s = i as f32 / 10.0;
            gt.push(f64::from(s), Affine3A::IDENTITY);
            est.push(f64::from(s), Affine3A::from_quat(Quat::from_rotation_z((2.0 * s).to_radians())));
        }
        let e = evaluate_trajectory(&gt, &est, &TrajectoryEvalConfig::default()).expect("evaluates");
        assert!((e.rpe_rot_deg_per_s.expect("pairs") - 2.0).abs() < 1e-3, "{e:?}");
        assert!(e.rpe_trans_m_per_s.expect("pairs") < 1e-6);
    }

    #[test]
    fn unmatched_and_short_inputs_are_errors_not_panics() {
        let gt = wander(10);
        let mut est = wander(10);
        for t in &mut est.timestamps {
            *t += 5.0;
        }
        let err = evaluate_trajectory(&gt, &est, &TrajectoryEvalConfig::default()).expect_err("no overlap");
        assert!(err.to_string().contains("only 0 of 10"), "{err}");
        let err =
            evaluate_trajectory(&gt, &Trajectory::default(), &TrajectoryEvalConfig::default()).expect_err("empty");
        assert!(matches!(err, EvalError::TooFewMatches { .. }));
        let bad = TrajectoryEvalConfig { rpe_delta_s: 0.0, ..Default::default() };
        assert!(evaluate_trajectory(&gt, &gt, &bad).is_err());
        // Shorter than the RPE interval: ATE only.
        let e = evaluate_trajectory(&gt, &gt, &TrajectoryEvalConfig::default()).expect("evaluates");
        assert_eq!((e.rpe_pairs, e.rpe_trans_m_per_s), (0, None));
    }

    #[test]
    fn rotation_angle_is_accurate_at_both_ends() {
        for a in [1e-7, 0.3, 3.0, std::f64::consts::PI - 1e-6] {
            let r = DMat3::from_axis_angle(DVec3::new(1.0, 2.0, -0.5).normalize(), a);
            assert!((rotation_angle(r) - a).abs() < 1e-9, "{a}");
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]

        #[test]
        fn alignment_recovers_any_rigid_transform(
            ax in -1.0f64..1.0, ay in -1.0f64..1.0, az in -1.0f64..1.0, angle in -3.1f64..3.1,
            tx in -10.0f64..10.0, ty in -10.0f64..10.0, tz in -10.0f64..10.0,
            seed in 0u64..1000,
        ) {
            let axis = DVec3::new(ax, ay, az);
            prop_assume!(axis.length() > 0.1);
            let truth = DAffine3::from_mat3_translation(DMat3::from_axis_angle(axis.normalize(), angle), DVec3::new(tx, ty, tz));
            let est: Vec<DVec3> = (0..20u64)
                .map(|i| {
                    let h = |k: u64| (((seed * 31 + i * 7 + k) * 2_654_435_761) % 1000) as f64 / 500.0 - 1.0;
                    DVec3::new(h(1), h(2), h(3)) * 3.0
                })
                .collect();
            let gt: Vec<DVec3> = est.iter().map(|p| truth.transform_point3(*p)).collect();
            let found = align_rigid(&gt, &est).expect("aligns");
            prop_assert!(found.matrix3.abs_diff_eq(truth.matrix3, 1e-8));
            prop_assert!(found.translation.abs_diff_eq(truth.translation, 1e-7));
            prop_assert!((found.matrix3.determinant() - 1.0).abs() < 1e-9);
        }

        #[test]
        fn alignment_is_optimal_under_noise(
            seed in 0u64..1000, angle in -0.05f64..0.05, shift in -0.05f64..0.05,
        ) {
            let est: Vec<DVec3> = (0..15u64)
                .map(|i| {
                    let h = |k: u64| (((seed * 17 + i * 13 + k) * 2_654_435_761) % 1000) as f64 / 500.0 - 1.0;
                    DVec3::new(h(1), h(2), h(3))
                })
                .collect();
            let gt: Vec<DVec3> = est
                .iter()
                .enumerate()
                .map(|(i, p)| *p + DVec3::new(0.01 * ((i * 7 % 5) as f64 - 2.0), 0.02 * ((i % 3) as f64 - 1.0), 0.005))
                .collect();
            let cost = |a: &DAffine3| gt.iter().zip(&est).map(|(g, e)| (*g - a.transform_point3(*e)).length_squared()).sum::<f64>();
            let best = align_rigid(&gt, &est).expect("aligns");
            let nudged = DAffine3::from_rotation_z(angle) * DAffine3::from_translation(DVec3::splat(shift)) * best;
            prop_assert!(cost(&best) <= cost(&nudged) + 1e-12);
            prop_assert!(cost(&best) <= cost(&DAffine3::IDENTITY) + 1e-12);
        }
    }
}
