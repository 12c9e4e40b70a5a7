//! Tests of the pose graph against plain references: finite differences for the Jacobians,
//! a dense Cholesky for the sparse solve, known true poses for whole optimisations.

use super::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random_pose(rng: &mut ChaCha8Rng, t: f64, r: f64) -> DAffine3 {
    let v = |rng: &mut ChaCha8Rng, s: f64| {
        DVec3::new(rng.random_range(-s..s), rng.random_range(-s..s), rng.random_range(-s..s))
    };
    DAffine3 { matrix3: rotation_exp(v(rng, r)), translation: v(rng, t) }
}

#[test]
fn rotation_log_inverts_exp_on_random_vectors() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for _ in 0..200 {
        let axis = DVec3::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        let phi = axis.normalize_or_zero() * rng.random_range(0.0..3.1);
        let back = rotation_log(rotation_exp(phi));
        assert!((back - phi).length() < 1e-9, "{phi} -> {back}");
    }
    assert_eq!(rotation_log(DMat3::IDENTITY), DVec3::ZERO);
}

#[test]
fn analytic_jacobians_match_finite_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    for _ in 0..50 {
        let ti = random_pose(&mut rng, 2.0, 1.5);
        let tj = random_pose(&mut rng, 2.0, 1.5);
        // A measurement near the truth, as in an optimisation, and a far one.
        let near = ti.inverse() * tj * random_pose(&mut rng, 0.05, 0.05);
        let far = random_pose(&mut rng, 1.0, 1.0);
        for z in [near, far] {
            let (_, ji, jj) = edge_jacobians(&ti, &tj, &z);
            let h = 1e-6;
            for k in 0..6 {
                let mut d = [0.0; 6];
                d[k] = h;
                let mut m = [0.0; 6];
                m[k] = -h;
                let num_i: Vec<f64> = edge_error(&perturbed(&ti, &d), &tj, &z)
                    .iter()
                    .zip(edge_error(&perturbed(&ti, &m), &tj, &z))
                    .map(|(a, b)| (a - b) / (2.0 * h))
                    .collect();
                let num_j: Vec<f64> = edge_error(&ti, &perturbed(&tj, &d), &z)
                    .iter()
                    .zip(edge_error(&ti, &perturbed(&tj, &m), &z))
                    .map(|(a, b)| (a - b) / (2.0 * h))
                    .collect();
                for r in 0..6 {
                    assert!((ji[r][k] - num_i[r]).abs() < 1e-5, "d e{r} / d xi_i{k}: {} vs {}", ji[r][k], num_i[r]);
                    assert!((jj[r][k] - num_j[r]).abs() < 1e-5, "d e{r} / d xi_j{k}: {} vs {}", jj[r][k], num_j[r]);
                }
            }
        }
    }
}

/// A ring of `n` true poses of radius 2 m, looking along the ring.
fn ring(n: usize) -> Vec<DAffine3> {
    (0..n)
        .map(|i| {
            let a = i as f64 / n as f64 * std::f64::consts::TAU;
            DAffine3 {
                matrix3: rotation_exp(DVec3::new(0.0, 0.0, a)),
                translation: DVec3::new(2.0 * a.cos(), 2.0 * a.sin(), 0.1 * (3.0 * a).sin()),
            }
        })
        .collect()
}

/// Odometry with noise and a bias (drift), composed into starting poses; a graph with the
/// odometry edges.
fn drifting_graph(truth: &[DAffine3], seed: u64) -> PoseGraph {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let bias = DAffine3 {
        matrix3: rotation_exp(DVec3::new(0.0002, -0.0003, 0.0005)),
        translation: DVec3::new(0.001, -0.0005, 0.0003),
    };
    let mut g = PoseGraph::new();
    let mut pose = truth[0];
    g.add_pose(pose).expect("finite");
    for i in 1..truth.len() {
        let z = truth[i - 1].inverse() * truth[i] * bias * random_pose(&mut rng, 0.004, 0.004);
        pose *= z;
        g.add_pose(pose).expect("finite");
        g.add_edge(PoseEdge {
            from: i - 1,
            to: i,
            from_from_to: z,
            information: isotropic_information(0.005, 0.005),
            kind: EdgeKind::Odometry,
        })
        .expect("valid");
    }
    g
}

fn loop_edge(truth: &[DAffine3], from: usize, to: usize, offset: DAffine3) -> PoseEdge {
    PoseEdge {
        from,
        to,
        from_from_to: truth[from].inverse() * truth[to] * offset,
        information: isotropic_information(0.002, 0.002),
        kind: EdgeKind::Loop,
    }
}

fn ate(poses: &[DAffine3], truth: &[DAffine3]) -> f64 {
    (poses.iter().zip(truth).map(|(a, b)| (a.translation - b.translation).length_squared()).sum::<f64>()
        / poses.len() as f64)
        .sqrt()
}

#[test]
fn sparse_solve_matches_a_dense_cholesky_on_random_graphs() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for seed in 0..5 {
        let truth = ring(30);
        let mut g = drifting_graph(&truth, seed);
        for _ in 0..6 {
            let a = rng.random_range(0..25);
            let b = rng.random_range(a + 2..30);
            g.add_edge(loop_edge(&truth, b, a, random_pose(&mut rng, 0.01, 0.01))).expect("valid");
        }
        let active = vec![true; g.edges.len()];
        let config = PoseGraphConfig::default();
        let ne = g.normal_equations(&g.poses, &active, &config);
        let lambda = 1e-3;
        let sparse = solve_sparse(&ne, lambda, &mut None).expect("solvable");
        // Dense reference: the same damped matrix, full, through nalgebra's dense Cholesky.
        let n = ne.gradient.len();
        let mut h = DMatrix::<f64>::zeros(n, n);
        for (&(r, c), m) in &ne.blocks {
            for i in 0..6 {
                for k in 0..6 {
                    h[(6 * r + i, 6 * c + k)] = m[i][k];
                    h[(6 * c + k, 6 * r + i)] = m[i][k];
                }
            }
        }
        for i in 0..n {
            h[(i, i)] += lambda * h[(i, i)] + 1e-12;
        }
        let b = DMatrix::from_iterator(n, 1, ne.gradient.iter().map(|v| -v));
        let dense = h.cholesky().expect("positive definite").solve(&b);
        let scale = dense.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        for (s, d) in sparse.iter().zip(dense.iter()) {
            assert!((s - d).abs() <= 1e-9 * scale.max(1.0), "{s} vs {d}");
        }
    }
}

#[test]
fn a_closed_loop_removes_drift_and_converges() {
    let mut ratios = Vec::new();
    for seed in 0..5 {
        let truth = ring(40);
        let mut g = drifting_graph(&truth, seed);
        let before = ate(g.poses(), &truth);
        g.add_edge(loop_edge(&truth, 39, 0, DAffine3::IDENTITY)).expect("valid");
        g.add_edge(loop_edge(&truth, 38, 1, DAffine3::IDENTITY)).expect("valid");
        let report = g.optimise(&PoseGraphConfig::default()).expect("optimised");
        let after = ate(g.poses(), &truth);
        assert!(report.rejected.is_empty(), "true loops kept: {report:?}");
        // Converged: the gradient at the result is negligible.
        let active = vec![true; g.edges.len()];
        let ne = g.normal_equations(g.poses(), &active, &PoseGraphConfig::default());
        let grad = ne.gradient.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(grad < 1e-3, "gradient {grad}");

        assert!(after < before, "seed {seed}: ATE {before} -> {after}");
        ratios.push(after / before);
        assert!(report.final_cost < report.initial_cost);
    }
}

#[test]
fn a_false_loop_is_rejected_and_leaves_the_result_as_without_it() {
    let truth = ring(40);
    let mut clean = drifting_graph(&truth, 7);
    clean.add_edge(loop_edge(&truth, 39, 0, DAffine3::IDENTITY)).expect("valid");
    let mut dirty = clean.clone();
    // Keyframes 10 and 30 are 4 m apart; the false edge says 20 cm.
    let false_edge = PoseEdge {
        from: 10,
        to: 30,
        from_from_to: DAffine3::from_translation(DVec3::new(0.2, 0.0, 0.0)),
        information: isotropic_information(0.002, 0.002),
        kind: EdgeKind::Loop,
    };
    let index = dirty.add_edge(false_edge).expect("valid");
    clean.optimise(&PoseGraphConfig::default()).expect("optimised");
    let report = dirty.optimise(&PoseGraphConfig::default()).expect("optimised");
    assert_eq!(report.rejected, vec![index]);
    assert!(dirty.is_rejected(index));
    for (a, b) in clean.poses().iter().zip(dirty.poses()) {
        let (t, r) = pose_distance(a, b);
        assert!(t < 1e-6 && r < 1e-6, "{t} m, {r} rad");
    }
}

#[test]
fn the_kernel_alone_bounds_how_far_a_forced_false_loop_bends_the_map() {
    let truth = ring(40);
    let mut base = drifting_graph(&truth, 9);
    base.add_edge(loop_edge(&truth, 39, 0, DAffine3::IDENTITY)).expect("valid");
    // A false loop: keyframe 20 said to be 30 cm from where it is. (A 10 cm error is within
    // what fifteen odometry edges of 5 mm can absorb: the kernel rightly lets it bend them.)
    let false_edge = loop_edge(&truth, 5, 20, DAffine3::from_translation(DVec3::new(0.3, 0.0, 0.0)));
    let forced = PoseGraphConfig { outlier_chi2: f64::INFINITY, ..PoseGraphConfig::default() };
    let plain = PoseGraphConfig { loop_kernel_chi2: 0.0, ..forced };
    let mut clean = base.clone();
    clean.optimise(&forced).expect("optimised");
    let moved = |config: &PoseGraphConfig| {
        let mut g = base.clone();
        g.add_edge(false_edge).expect("valid");
        g.optimise(config).expect("optimised");
        g.poses().iter().zip(clean.poses()).map(|(a, b)| pose_distance(a, b).0).fold(0.0f64, f64::max)
    };
    let (robust, least_squares) = (moved(&forced), moved(&plain));
    assert!(least_squares > 0.1, "least squares bends the map: {least_squares} m");
    assert!(robust < least_squares / 4.0, "Cauchy {robust} m against least squares {least_squares} m");
}

#[test]
fn bad_input_is_refused_and_the_poses_are_kept() {
    let mut g = PoseGraph::new();
    let nan = DAffine3::from_translation(DVec3::new(f64::NAN, 0.0, 0.0));
    assert_eq!(g.add_pose(nan), Err(PoseGraphError::NonFinitePose(0)));
    g.add_pose(DAffine3::IDENTITY).expect("finite");
    g.add_pose(DAffine3::IDENTITY).expect("finite");
    let edge = |z: DAffine3, information: Mat6| PoseEdge {
        from: 0,
        to: 1,
        from_from_to: z,
        information,
        kind: EdgeKind::Odometry,
    };
    let info = isotropic_information(0.01, 0.01);
    assert!(g.add_edge(PoseEdge { to: 2, ..edge(DAffine3::IDENTITY, info) }).is_err());
    assert!(g.add_edge(edge(nan, info)).is_err());
    let mut asymmetric = info;
    asymmetric[0][1] = 1.0;
    assert!(g.add_edge(edge(DAffine3::IDENTITY, asymmetric)).is_err());
    // A measurement 5 m away moves pose 1 beyond the 1 m bound: refused, poses kept.
    g.add_edge(edge(DAffine3::from_translation(DVec3::new(5.0, 0.0, 0.0)), info)).expect("valid");
    let err = g.optimise(&PoseGraphConfig::default()).expect_err("refused");
    assert!(matches!(err, PoseGraphError::Refused { pose: 1, .. }), "{err}");
    assert_eq!(g.poses()[1], DAffine3::IDENTITY);
    // A pose without any edge stays where it is.
    let mut g = PoseGraph::new();
    for _ in 0..3 {
        g.add_pose(DAffine3::from_translation(DVec3::X)).expect("finite");
    }
    g.add_edge(PoseEdge { to: 1, ..edge(DAffine3::IDENTITY, info) }).expect("valid");
    g.optimise(&PoseGraphConfig::default()).expect("optimised");
    assert_eq!(g.poses()[2], DAffine3::from_translation(DVec3::X));
}

#[test]
fn the_block_order_is_a_permutation_and_narrows_a_revisited_ring() {
    // Two laps of 40 poses, the second seeing the first: in capture order the loop edges
    // span 40 blocks; reordered, every edge spans a few (5 here).
    let n = 80;
    let mut pattern: Vec<(usize, usize)> = (0..n).map(|p| (p, p)).collect();
    pattern.extend((1..n).map(|p| (p - 1, p)));
    pattern.extend((40..n).map(|p| (p - 40, p)));
    let order = reverse_cuthill_mckee(n, &pattern);
    let mut seen = order.clone();
    seen.sort_unstable();
    assert_eq!(seen, (0..n).collect::<Vec<_>>());
    let band = pattern.iter().map(|&(r, c)| order[r].abs_diff(order[c])).max().unwrap_or(0);
    assert!(band <= 6, "bandwidth {band}");
}

#[test]
fn restored_edges_and_scaled_information_change_what_the_optimiser_sees() {
    let truth = ring(20);
    let mut g = drifting_graph(&truth, 3);
    let e = g.add_edge(loop_edge(&truth, 19, 0, DAffine3::IDENTITY)).expect("valid");
    let odometry = (0..g.edges().len()).find(|&i| g.edges()[i].kind == EdgeKind::Odometry).expect("odometry");
    let before = g.edge_chi2(odometry).expect("edge");
    // A quarter of the information: a quarter of the chi-square, and only odometry's.
    let loop_before = g.edge_chi2(e).expect("edge");
    g.scale_information(EdgeKind::Odometry, 0.25);
    assert!((g.edge_chi2(odometry).expect("edge") - 0.25 * before).abs() <= 1e-12 * before.max(1.0));
    assert_eq!(g.edge_chi2(e), Some(loop_before));
    g.reject(e);
    assert!(g.is_rejected(e));
    g.restore(e);
    assert!(!g.is_rejected(e));
    // Out-of-range indices are ignored, not a panic.
    g.restore(999);
    assert!(!g.is_rejected(999));
}
