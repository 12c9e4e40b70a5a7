//! Tests of the tracker: synthetic motions recovered, the fast paths against the scalar
//! definitions, losses and relocalisation.

use super::*;

/// `J^T J` and `J^T r` of `rows` random Jacobian rows, each with its component along
/// `null` removed when given (so that motion along `null` is unconstrained).
fn normal_system(seed: u64, rows: usize, null: Option<[f64; 6]>) -> ([[f64; 6]; 6], [f64; 6]) {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let (mut h, mut g) = ([[0.0f64; 6]; 6], [0.0f64; 6]);
    for _ in 0..rows {
        let mut j: [f64; 6] = std::array::from_fn(|k| rng.random_range(-1.0..1.0) * if k < 3 { 0.5 } else { 2.0 });
        if let Some(u) = null {
            let along: f64 = j.iter().zip(&u).map(|(a, b)| a * b).sum();
            j.iter_mut().zip(&u).for_each(|(a, b)| *a -= along * b);
        }
        let r: f64 = rng.random_range(-0.01..0.01);
        for a in 0..6 {
            for b in 0..6 {
                h[a][b] += j[a] * j[b];
            }
            g[a] += j[a] * r;
        }
    }
    (h, g)
}

#[test]
fn a_well_conditioned_step_is_the_plain_solve() {
    let c = TrackerConfig::default();
    for seed in 0..20 {
        let (h, g) = normal_system(seed, 50, None);
        assert_eq!(gauss_newton_step(&h, &g, &c), cholesky_solve(&h, &g), "seed {seed}");
    }
}

#[test]
fn a_degenerate_step_solves_the_constrained_part_and_leaves_the_rest() {
    let c = TrackerConfig::default();
    for seed in 0..20u64 {
        // A unit direction mixing rotation and translation, unconstrained by every row.
        let raw: [f64; 6] = std::array::from_fn(|k| ((seed as f64 + 1.0) * (k as f64 + 0.7)).sin());
        let norm = raw.iter().map(|v| v * v).sum::<f64>().sqrt();
        let u = raw.map(|v| v / norm);
        let (h, g) = normal_system(seed, 50, Some(u));
        assert_eq!(conditioning(&h, c.min_condition).1, 5, "seed {seed}");
        let xi = gauss_newton_step(&h, &g, &c).expect("a step");
        // The system is consistent (g lies in the range of h): the step solves it...
        let hx: [f64; 6] = std::array::from_fn(|a| (0..6).map(|b| h[a][b] * xi[b]).sum());
        let scale = g.iter().map(|v| v.abs()).fold(0.0, f64::max);
        for a in 0..6 {
            assert!((hx[a] - g[a]).abs() < 1e-6 * scale, "seed {seed}: {hx:?} against {g:?}");
        }
        // ...with nothing along the unconstrained direction in the scaled metric
        // (`D^-1 xi` orthogonal to the null vector `D^-1 u` of `D h D`).
        let d: [f64; 6] = std::array::from_fn(|i| 1.0 / h[i][i].sqrt());
        let along: f64 = (0..6).map(|i| (xi[i] / d[i]) * (u[i] / d[i])).sum();
        let size: f64 = (0..6).map(|i| (xi[i] / d[i]).powi(2)).sum::<f64>().sqrt();
        assert!(along.abs() <= 1e-6 * size.max(1e-12), "seed {seed}: {along} of {size}");
    }
}

/// A pinned direction of translation ends where it is pinned, and the rest of the step is
/// the solve of the system with that direction fixed: for a pin along the vertical (the
/// twist's entry 4), the 5x5 system without its row and column, with the fixed step's pull
/// moved to the right-hand side.
#[test]
fn a_pinned_step_keeps_its_direction_and_solves_the_rest() {
    let c = TrackerConfig::default();
    for seed in 0..20u64 {
        let (h, g) = normal_system(seed, 50, None);
        let t = Vec3::new(0.01, -0.02 + 0.001 * seed as f32, 0.005);
        let pin = Pin { direction: Vec3::Y, at: 0.003 };
        let (mut hp, mut gp) = (h, g);
        pin_translation(&mut hp, &mut gp, &[pin], t);
        let xi = gauss_newton_step(&hp, &gp, &c).expect("a step");
        let fixed = f64::from(pin.at - t.y);
        let scale = xi.iter().chain(&[fixed]).map(|v| v.abs()).fold(0.0, f64::max);
        assert!((xi[4] - fixed).abs() < 1e-4 * scale, "seed {seed}: {} against {fixed}", xi[4]);
        let free = [0usize, 1, 2, 3, 5];
        let reduced: [[f64; 5]; 5] = std::array::from_fn(|a| std::array::from_fn(|b| h[free[a]][free[b]]));
        let rhs: [f64; 5] = std::array::from_fn(|a| g[free[a]] - h[free[a]][4] * fixed);
        let expected = cholesky_solve(&reduced, &rhs).expect("the reduced system is positive definite");
        for (a, &i) in free.iter().enumerate() {
            assert!(
                (xi[i] - expected[a]).abs() < 1e-3 * scale,
                "seed {seed}: entry {i}: {} against {}",
                xi[i],
                expected[a]
            );
        }
        // No pins: the plain step.
        let (mut h0, mut g0) = (h, g);
        pin_translation(&mut h0, &mut g0, &[], t);
        assert_eq!((h0, g0), (h, g));
    }
}

#[test]
fn horn_alignment_removes_a_rigid_motion() {
    let pts: Vec<Vec3> = (0..20)
        .map(|i| {
            let t = i as f32 * 0.3;
            Vec3::new(t.sin(), t.cos() * 0.5, 0.1 * t)
        })
        .collect();
    let m = Affine3A::from_rotation_translation(
        Quat::from_euler(glam::EulerRot::XYZ, 0.3, -0.7, 1.2),
        Vec3::new(1.0, -2.0, 0.5),
    );
    let moved: Vec<Vec3> = pts.iter().map(|p| m.transform_point3(*p)).collect();
    let e = ate_rmse(&moved, &pts).expect("enough points");
    assert!(e < 1e-5, "{e}");
    let mut noisy = moved.clone();
    noisy[3].x += 0.1;
    let e = ate_rmse(&noisy, &pts).expect("enough points");
    assert!(e > 0.01 && e < 0.1 / (20f64).sqrt() + 1e-3, "{e}");
}

#[test]
fn pyramid_averages_only_agreeing_depths() {
    let k = Intrinsics::new(8, 8, 10.0, 10.0, 3.5, 3.5).expect("camera");
    let mut depth = vec![1.0f32; 64];
    depth[0] = 3.0; // an outlier in the first 2x2 block
    depth[9] = f32::NAN;
    let frame = Frame {
        index: 0,
        timestamp: 0.0,
        depth,
        color: vec![[10, 20, 30]; 64],
        intrinsics: k,
        world_from_camera: None,
        labels: None,
    };
    let p = build_pyramid(&frame, &TrackerConfig::default());
    assert_eq!(p[1].k.width, 4);
    assert_eq!(p[1].depth[0], 1.0);
    assert_eq!(p[0].depth[9], 0.0);
    assert_eq!(p[2].depth.len(), 4);
}

#[test]
fn simd_row_sums_match_the_plain_f64_accumulation() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let (mut plain, mut simd) = (Normals::ZERO, Normals::ZERO);
    let mut sums = RowSums::ZERO;
    for i in 0..20_000 {
        // Jacobians as the association forms them: lever arms of metres, unit normals.
        let j: [f32; 6] = std::array::from_fn(|k| rng.random_range(-1.0..1.0) * if k < 3 { 3.0 } else { 1.0 });
        let r: f32 = rng.random_range(-0.01..0.01);
        let w: f32 = rng.random_range(0.1..1.0);
        plain.add(j.map(|v| v as f64), r as f64, w as f64);
        sums.add(j, r, w);
        if i % 320 == 319 {
            sums.flush(&mut simd);
        }
    }
    sums.flush(&mut simd);
    for a in 0..6 {
        for b in a..6 {
            let (p, s) = (plain.h[a][b], simd.h[a][b]);
            assert!((p - s).abs() <= 1e-5 * plain.h[a][a].max(plain.h[b][b]), "h[{a}][{b}]: {p} vs {s}");
        }
        // The gradient sums signed terms that cancel: compare with the scale of its terms.
        let scale = (plain.h[a][a] * 0.01f64.powi(2) * 20_000.0).sqrt();
        assert!((plain.g[a] - simd.g[a]).abs() <= 1e-4 * scale, "g[{a}]: {} vs {}", plain.g[a], simd.g[a]);
    }
}

#[test]
fn block_depth_matches_the_sorted_median_rule() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    for _ in 0..5000 {
        // Invalid, close and outlying depths, repeats included.
        let block: [f32; 4] = std::array::from_fn(|_| match rng.random_range(0..4) {
            0 => 0.0,
            1 => 2.0,
            2 => 2.0 + rng.random_range(-0.05..0.05),
            _ => rng.random_range(0.5..4.0),
        });
        let mut valid: Vec<f32> = block.iter().copied().filter(|&d| d > 0.0).collect();
        valid.sort_by(f32::total_cmp);
        let want = if valid.is_empty() {
            0.0
        } else {
            let median = valid[(valid.len() - 1) / 2];
            let kept: Vec<f32> = valid.into_iter().filter(|d| (d - median).abs() <= 0.03 * median).collect();
            kept.iter().fold(0.0f32, |s, d| s + d) / kept.len() as f32
        };
        assert_eq!(block_depth(block).to_bits(), want.to_bits(), "{block:?}");
    }
}

#[test]
fn block_depth_rows_match_block_by_block() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    // Odd and even widths, rows past the edge, invalid, close and outlying depths.
    for pw in [1usize, 7, 16, 33, 64, 161] {
        let row = |rng: &mut rand_chacha::ChaCha8Rng| -> Vec<f32> {
            (0..pw)
                .map(|_| match rng.random_range(0..4) {
                    0 => 0.0,
                    1 => 2.0,
                    2 => 2.0 + rng.random_range(-0.05..0.05),
                    _ => rng.random_range(0.5..4.0),
                })
                .collect()
        };
        for missing_row in [false, true] {
            let (r0, r1) = (row(&mut rng), if missing_row { Vec::new() } else { row(&mut rng) });
            let w = (pw / 2).max(1);
            let mut got = vec![-1.0f32; w];
            block_depth_row(&r0, &r1, &mut got);
            let at = |r: &[f32], sx: usize| r.get(sx).copied().unwrap_or(0.0);
            for (x, g) in got.iter().enumerate() {
                let want = block_depth([at(&r0, 2 * x), at(&r0, 2 * x + 1), at(&r1, 2 * x), at(&r1, 2 * x + 1)]);
                assert_eq!(g.to_bits(), want.to_bits(), "width {pw}, block {x}");
            }
        }
    }
}

#[test]
fn lane_normals_match_the_pixel_rule() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(13);
    // Widths with and without a scalar tail; bumps, holes and depth edges.
    for w in [3usize, 10, 37, 64] {
        let h = 9;
        let k = Intrinsics::new(w as u32, h as u32, 30.0, 31.0, w as f32 / 2.0, 4.0).expect("camera");
        let depth: Vec<f32> = (0..w * h)
            .map(|i| match rng.random_range(0..10) {
                0 => 0.0,
                1 => rng.random_range(0.5..4.0),
                _ => 1.5 + 0.01 * (i % w) as f32 + rng.random_range(-0.004..0.004),
            })
            .collect();
        let level = make_level(k, depth, true);
        let (mut set, mut zero) = (0, 0);
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                let want = pixel_normal(&level.vertices, w, y * w + x);
                let got = level.normals[y * w + x];
                assert_eq!(got.to_array().map(f32::to_bits), want.to_array().map(f32::to_bits), "{x}, {y}");
                if want == Vec3::ZERO {
                    zero += 1;
                } else {
                    set += 1;
                }
            }
        }
        assert!(w < 10 || (set > 0 && zero > 0), "{set} {zero}");
    }
}

#[test]
fn sort4_sorts_like_the_library() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    for _ in 0..1000 {
        let n = rng.random_range(0..=4);
        let mut v = [f32::INFINITY; 4];
        for d in v.iter_mut().take(n) {
            // Repeated values too.
            *d = rng.random_range(0..6) as f32 * 0.5;
        }
        let mut want = v;
        want.sort_by(f32::total_cmp);
        sort4(&mut v);
        assert_eq!(v, want);
    }
}

/// The per-frame share of a motion over several frames, applied that many times, gives the
/// motion back (within a micrometre and ten microradians, f32 rounding); over one frame it
/// is the motion itself, bit for bit.
#[test]
fn a_motion_over_frames_splits_into_equal_steps() {
    let motion = Affine3A::from_rotation_translation(
        Quat::from_axis_angle(Vec3::new(0.2, -0.9, 0.4).normalize(), 0.05),
        Vec3::new(0.031, -0.012, 0.046),
    );
    assert_eq!(per_frame(motion, 1), motion);
    for frames in [2, 3, 7] {
        let step = per_frame(motion, frames);
        let mut total = Affine3A::IDENTITY;
        for _ in 0..frames {
            total *= step;
        }
        let apart = motion.inverse() * total;
        let moved = Vec3::from(apart.translation).length();
        let turned = Quat::from_mat3a(&apart.matrix3).to_axis_angle().1;
        let turned = turned.min(std::f32::consts::TAU - turned);
        assert!(moved < 1e-6 && turned < 1e-5, "{frames} frames: {moved} m, {turned} rad apart");
    }
}

#[test]
fn exp_of_a_small_twist_matches_its_linearisation() {
    let xi = [1e-4, -2e-4, 3e-4, 1e-3, 0.0, -1e-3];
    let t = se3_exp(xi);
    let q = Vec3::new(0.3, -0.2, 1.5);
    let lin = q + Vec3::new(1e-4, -2e-4, 3e-4).cross(q) + Vec3::new(1e-3, 0.0, -1e-3);
    assert!((t.transform_point3(q) - lin).length() < 1e-6);
}

#[test]
fn lazy_finest_level_equals_the_materialised_one() {
    // A tilted, bumpy plane; the model is the frame's own half-resolution level.
    let c = TrackerConfig { fine_stride: 1, ..TrackerConfig::default() };
    let (pyramid, model) = bumpy_plane(&c);
    let (k, l1) = (pyramid[0].k, &pyramid[1]);
    // The materialised level 0: its vertices, and level 1's own normals per 2x2 block.
    let mut eager = make_level(k, pyramid[0].depth.clone(), false);
    for (i, n) in eager.normals.iter_mut().enumerate() {
        let (x, y) = (i % 64, i / 64);
        let ci = (y / 2).min(23) * 32 + (x / 2).min(31);
        let d = eager.depth[i];
        if d > 0.0 && (d - l1.depth[ci]).abs() <= 0.05 * d {
            *n = l1.own_normals[ci];
        }
    }
    let motion = se3_exp([0.001, -0.002, 0.0005, 0.002, 0.001, -0.003]);
    for stride in [1, 2] {
        let lazy = normal_equations(&pyramid[0], Some(l1), &model, &motion, 0.05, stride, &c);
        let full = normal_equations(&eager, None, &model, &motion, 0.05, stride, &c);
        assert!(lazy.inliers > 100);
        assert_eq!((lazy.h, lazy.g, lazy.inliers, lazy.sampled), (full.h, full.g, full.inliers, full.sampled));
    }
}

/// The level-1 model and pyramid of a tilted, bumpy plane (shared by the association
/// tests).
fn bumpy_plane(c: &TrackerConfig) -> (Vec<Level>, Model) {
    let k = Intrinsics::new(64, 48, 60.0, 60.0, 31.5, 23.5).expect("camera");
    let depth: Vec<f32> =
        (0..64 * 48).map(|i| 1.0 + 0.004 * (i % 64) as f32 + 0.01 * ((i / 64) as f32 * 0.7).sin()).collect();
    let pyramid = build_pyramid(&Frame::from_depth(k, depth), c);
    let l1 = &pyramid[1];
    let view = ModelView {
        intrinsics: l1.k,
        world_from_camera: Affine3A::IDENTITY,
        vertices: l1.vertices.clone(),
        normals: l1.normals.clone(),
        colors: vec![[0; 3]; l1.vertices.len()],
    };
    (pyramid, Model { view: Arc::new(view), intensity: Vec::new(), gradient: Vec::new() })
}

fn normals_key(n: &Normals) -> ([[f64; 6]; 6], [f64; 6], f64, f64, [u64; 4]) {
    (n.h, n.g, n.sq_residual, n.sq_normalised, [n.inliers, n.far, n.turned, n.sampled])
}

#[test]
fn lane_association_matches_the_scalar_path() {
    // A tight distance and angle gate, so that both rejections occur.
    let c = TrackerConfig { fine_stride: 1, max_normal_angle: 10f32.to_radians(), ..TrackerConfig::default() };
    let (pyramid, model) = bumpy_plane(&c);
    let motion = se3_exp([0.001, -0.002, 0.0005, 0.002, 0.001, -0.003]);
    let mut totals = (0, 0, 0);
    for (level, stride, max_distance) in
        [(0, 1, 0.012), (0, 1, 0.03), (0, 2, 0.03), (0, 3, 0.03), (1, 1, 0.04), (2, 1, 0.08)]
    {
        let data = &pyramid[level];
        let scalar = normal_equations(data, pyramid.get(level + 1), &model, &motion, max_distance, stride, &c);
        let lanes =
            LevelPoints::new(data, pyramid.get(level + 1), stride).normal_equations(&model, &motion, max_distance, &c);
        let counts = |n: &Normals| (n.inliers, n.far, n.turned, n.sampled);
        assert_eq!(counts(&lanes), counts(&scalar), "level {level} stride {stride}");
        totals.0 += scalar.inliers;
        totals.1 += scalar.far;
        totals.2 += scalar.turned;
        for a in 0..6 {
            let scale = scalar.h[a][a].max(1e-30);
            for b in a..6 {
                let tol = 1e-5 * scalar.h[a][a].max(scalar.h[b][b]);
                assert!((lanes.h[a][b] - scalar.h[a][b]).abs() <= tol, "h[{a}][{b}] at level {level}");
            }
            let g_tol = 1e-4 * (scale * scalar.sq_residual).sqrt();
            assert!((lanes.g[a] - scalar.g[a]).abs() <= g_tol, "g[{a}] at level {level}");
        }
        assert!((lanes.sq_residual - scalar.sq_residual).abs() <= 1e-12 * scalar.sq_residual);
        assert!((lanes.sq_normalised - scalar.sq_normalised).abs() <= 1e-12 * scalar.sq_normalised);
    }
    assert!(totals.0 > 2000 && totals.1 > 100 && totals.2 > 100, "{totals:?}");
}

#[test]
fn avx2_lanes_give_the_portable_bits() {
    #[cfg(target_arch = "x86_64")]
    if avx2_available() {
        // Tight and loose gates (far and turned pairs), and a motion that moves part of
        // the frame off the model's image.
        let (mut far, mut turned, mut off) = (0, 0, 0);
        for (angle, max_distance, xi) in [
            (45f32, 0.01, [0.001, -0.002, 0.0005, 0.002, 0.001, -0.003]),
            (10.0, 0.03, [0.001, -0.002, 0.0005, 0.002, 0.001, -0.003]),
            (45.0, 0.05, [0.02, -0.1, 0.01, 0.3, 0.04, -0.02]),
        ] {
            let c = TrackerConfig { fine_stride: 1, max_normal_angle: angle.to_radians(), ..TrackerConfig::default() };
            let (pyramid, model) = bumpy_plane(&c);
            let step = StepParams::new(&model, &se3_exp(xi), max_distance, &c);
            assert!(step.gather_safe());
            for level in 0..3 {
                let points = LevelPoints::new(&pyramid[level], pyramid.get(level + 1), 1);
                for b in &points.blocks {
                    let portable = block_sums_lanes(b, &step);
                    // SAFETY: checked above; blocks are padded to whole lanes.
                    let avx2 = unsafe { avx2::block_sums(b, &step) };
                    assert_eq!(normals_key(&portable), normals_key(&avx2));
                    far += avx2.far;
                    turned += avx2.turned;
                    off += b.len as u64 - (avx2.inliers + avx2.far + avx2.turned);
                }
            }
        }
        assert!(far > 100 && turned > 100 && off > 100, "{far} {turned} {off}");
    }
}

#[test]
fn ray_table_unprojects_like_the_camera() {
    let k = Intrinsics::new(640, 480, 525.0, 523.5, 319.5, 239.25).expect("camera");
    let rays = RayTable::new(k);
    for (i, d) in [0.31f32, 1.0, 2.75, 4.9].into_iter().enumerate() {
        for y in (i..480).step_by(7) {
            for x in (i..640).step_by(5) {
                assert_eq!(rays.unproject(x, y, d), k.unproject(x as f32, y as f32, d));
            }
        }
    }
}

/// The camera-frame normal matrix gives the same quadratic form as the alignment's own for
/// the same small motion of the pose, expressed either way (random poses and forms).
#[test]
fn the_camera_frame_hessian_is_the_same_form_in_the_camera_frame() {
    use crate::pose_graph::{rotation_exp, rotation_log};
    use glam::{DAffine3, DVec3};
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    for seed in 0..20 {
        let (h, _) = normal_system(seed, 40, None);
        let axis = Vec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        let estimate = Affine3A::from_rotation_translation(
            Quat::from_scaled_axis(axis),
            Vec3::new(rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0)),
        );
        let hc = camera_hessian(&h, estimate);
        let e = estimate.as_daffine3();
        // A right perturbation (δt, δφ) in the camera's frame...
        let d: [f64; 6] = std::array::from_fn(|_| rng.random_range(-1e-4..1e-4));
        let moved = e * DAffine3 {
            matrix3: rotation_exp(DVec3::new(d[3], d[4], d[5])),
            translation: DVec3::new(d[0], d[1], d[2]),
        };
        // ... is the left twist (ω, υ) of the reference frame that the alignment's sums use.
        let left = moved * e.inverse();
        let w = rotation_log(left.matrix3);
        let xi = [w.x, w.y, w.z, left.translation.x, left.translation.y, left.translation.z];
        let form = |h: &[[f64; 6]; 6], v: &[f64; 6]| -> f64 {
            (0..6).map(|a| (0..6).map(|b| v[a] * h[a][b] * v[b]).sum::<f64>()).sum()
        };
        let (expected, got) = (form(&h, &xi), form(&hc, &d));
        assert!((expected - got).abs() <= 1e-3 * expected.abs(), "seed {seed}: {expected} vs {got}");
    }
}

/// The translation's uncertainty against its definition by the Schur complement: with
/// rotation left free, the translation's information is `S = H_tt - H_tr H_rr⁻¹ H_rt`, and
/// its worst standard deviation `sigma / sqrt(smallest eigenvalue of S)` (the smallest by
/// bisection on the characteristic polynomial's sign through a plain 3x3 determinant).
#[test]
fn translation_sigma_matches_the_schur_complement() {
    fn det3(m: &[[f64; 3]; 3]) -> f64 {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    }
    fn inverse3(m: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
        let d = det3(m);
        std::array::from_fn(|i| {
            std::array::from_fn(|j| {
                let (r, c) = ([(j + 1) % 3, (j + 2) % 3], [(i + 1) % 3, (i + 2) % 3]);
                (m[r[0]][c[0]] * m[r[1]][c[1]] - m[r[0]][c[1]] * m[r[1]][c[0]]) / d
            })
        })
    }
    for seed in 0..6 {
        // Seeds 3-5: translation along one axis barely seen.
        let null = (seed >= 3).then_some([0.0, 1.0, 0.0, 0.0, 0.0, 0.0]);
        let (mut h, _) = normal_system(seed, 200, null);
        h[1][1] += 1e-3;
        let block =
            |r: usize, c: usize| -> [[f64; 3]; 3] { std::array::from_fn(|i| std::array::from_fn(|j| h[r + i][c + j])) };
        let (tt, tr, rr) = (block(0, 0), block(0, 3), block(3, 3));
        let rr_inv = inverse3(&rr);
        let s: [[f64; 3]; 3] = std::array::from_fn(|i| {
            std::array::from_fn(|j| {
                tt[i][j] - (0..3).map(|a| (0..3).map(|b| tr[i][a] * rr_inv[a][b] * tr[j][b]).sum::<f64>()).sum::<f64>()
            })
        });
        // Smallest eigenvalue: the first root of det(S - x I) from 0 up.
        let shifted =
            |x: f64| det3(&std::array::from_fn(|i| std::array::from_fn(|j| s[i][j] - if i == j { x } else { 0.0 })));
        let (mut lo, mut hi) = (0.0, (0..3).map(|i| s[i][i]).fold(f64::INFINITY, f64::min));
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if shifted(mid) > 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let expected = 0.004 / lo.sqrt();
        let got = translation_sigma(&h, 0.004);
        assert!((got - expected).abs() <= 1e-6 * expected, "seed {seed}: {got} vs {expected}");
        if seed >= 3 {
            assert!(got > 0.004 / 0.1, "seed {seed}: the unseen axis is {got} uncertain");
        }
    }
    assert!(translation_sigma(&[[0.0; 6]; 6], 0.004).is_infinite());
}

/// The colour fallback's departure trigger must be positive (infinity turns it off).
#[test]
fn the_fallback_departure_and_the_support_check_are_validated() {
    assert!(TrackerConfig::default().validate().is_ok());
    let off = TrackerConfig { degenerate_departure: f32::INFINITY, ..TrackerConfig::default() };
    assert!(off.validate().is_ok());
    for bad in [
        TrackerConfig { degenerate_departure: -0.01, ..TrackerConfig::default() },
        TrackerConfig { degenerate_departure: f32::NAN, ..TrackerConfig::default() },
    ] {
        let e = bad.validate().expect_err("refused").to_string();
        assert!(e.contains("degenerate_"), "{e}");
    }
    let off = TrackerConfig { min_support: 0.0, ..TrackerConfig::default() };
    assert!(off.validate().is_ok());
    for bad in [
        TrackerConfig { min_support: -0.1, ..TrackerConfig::default() },
        TrackerConfig { min_support: f32::NAN, ..TrackerConfig::default() },
        TrackerConfig { support_tilt: 0.0, ..TrackerConfig::default() },
        TrackerConfig { support_tilt: 1.5, ..TrackerConfig::default() },
    ] {
        let e = bad.validate().expect_err("refused").to_string();
        assert!(e.contains("support"), "{e}");
    }
}
