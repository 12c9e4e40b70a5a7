//! Pose-graph optimisation: the keyframe poses that best agree with the relative motions
//! measured between them (odometry between consecutive keyframes, loop closures between a
//! keyframe and an earlier one seen again), so that the drift a loop reveals is spread along
//! the loop instead of leaving the same wall drawn twice.
//!
//! Each pose is `world_from_keyframe` in `f64`. An edge `(i, j)` measures
//! `i_from_j = Z`; its error is `e = (t, log R)` of `Z⁻¹ · Tᵢ⁻¹ · Tⱼ` (translation first,
//! then the rotation vector), weighed by the edge's 6x6 information matrix `Ω`
//! (`s = eᵀ Ω e`, a chi-square with 6 degrees of freedom when `Ω` is the true inverse
//! covariance). Poses are perturbed on the left in the world frame (`t ← t + δt`,
//! `R ← exp(δφ) R`), with analytic Jacobians (tested against finite differences). The first
//! pose is held fixed (the gauge).
//!
//! Levenberg-Marquardt on the normal equations, which are sparse: one 6x6 block per edge
//! end pair. They are solved by `nalgebra-sparse`'s Cholesky factorisation (symbolic pattern
//! once per optimisation, numeric per iteration). The crate was chosen over `faer` (and
//! `tiny-solver` / `factrs`, which build on it) for build cost: nalgebra is already in the
//! workspace and the sparse crate adds a few thousand lines, where faer adds a large generic
//! library to a two-core build. Its factorisation does no fill-reducing ordering, and in
//! capture order the loop edges fill the band between their ends (a 360-keyframe scan that
//! revisits its first lap: 0.6 s per optimisation), so the pose blocks are put in reverse
//! Cuthill-McKee order first (a breadth-first pass over the graph, written here; the same
//! graph then takes 15 ms; docs/loop_closure.md).
//!
//! Robustness against false loops, two layers: loop edges carry a Cauchy kernel
//! (`ρ(s) = c² ln(1 + s / c²)`, weights `1 / (1 + s / c²)` by iterative re-weighting), so
//! one wrong edge pulls with a bounded force; after convergence a loop edge whose chi-square
//! still exceeds [`PoseGraphConfig::outlier_chi2`] is switched off and the graph is
//! optimised again from its starting poses without it. Odometry edges are trusted (plain
//! least squares). A result with non-finite poses, or one that moves a keyframe further than
//! the configured bound, is refused and the poses stay as they were.

// Index loops mirror the matrix formulas they implement.
#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]

use std::collections::BTreeMap;

use glam::{DAffine3, DMat3, DQuat, DVec3};
use nalgebra::DMatrix;
use nalgebra_sparse::factorization::CscCholesky;
use nalgebra_sparse::CscMatrix;

/// A 6x6 matrix, row-major, translation rows and columns first.
pub type Mat6 = [[f64; 6]; 6];

/// What a pose-graph optimisation refuses.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PoseGraphError {
    /// An edge names a missing pose, joins a pose to itself, or has a non-finite
    /// measurement or information matrix.
    #[error("edge {index}: {message}")]
    InvalidEdge {
        /// Position of the edge.
        index: usize,
        /// What is wrong.
        message: String,
    },
    /// A pose given to the graph is not finite.
    #[error("pose {0} is not finite")]
    NonFinitePose(usize),
    /// The normal equations could not be factorised (an unconstrained pose).
    #[error("the normal equations are singular (a pose without edges?)")]
    Singular,
    /// The optimised poses are not finite or move a pose beyond the configured bound; the
    /// previous poses are kept.
    #[error("refused: pose {pose} would move {translation_m:.3} m and {rotation_deg:.1} degrees")]
    Refused {
        /// The pose that moved the most.
        pose: usize,
        /// How far, metres (NaN for a non-finite result).
        translation_m: f64,
        /// How much it turned, degrees.
        rotation_deg: f64,
    },
}

/// Which kind of measurement an edge is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EdgeKind {
    /// Between consecutive keyframes, from tracking: trusted.
    Odometry,
    /// Between a keyframe and an earlier one, from place recognition: robust kernel and
    /// outlier rejection.
    Loop,
}

/// One relative-pose measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseEdge {
    /// The pose the measurement is expressed in.
    pub from: usize,
    /// The pose measured.
    pub to: usize,
    /// The measured `from_from_to` transform.
    pub from_from_to: DAffine3,
    /// Inverse covariance of the error `(t, log R)`, translation first.
    pub information: Mat6,
    /// Odometry or loop.
    pub kind: EdgeKind,
}

/// Parameters of [`PoseGraph::optimise`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseGraphConfig {
    /// Most Levenberg-Marquardt iterations per solve.
    pub max_iterations: usize,
    /// Iterations stop once the largest update of a pose is below this (metres and
    /// radians together).
    pub converged_step: f64,
    /// Cauchy scale of loop edges, in units of the chi-square `s` (`c²`): an edge with
    /// `s = c²` weighs half. 0 turns the kernel off (plain least squares).
    pub loop_kernel_chi2: f64,
    /// After convergence a loop edge with a larger chi-square is rejected and the graph
    /// re-optimised without it (16.8: the 99 % quantile of a chi-square with 6 degrees of
    /// freedom). Infinity keeps every loop edge.
    pub outlier_chi2: f64,
    /// A result that moves any pose by more than this many metres is refused.
    pub max_translation_change: f64,
    /// A result that turns any pose by more than this many radians is refused.
    pub max_rotation_change: f64,
}

impl Default for PoseGraphConfig {
    fn default() -> Self {
        Self {
            max_iterations: 20,
            converged_step: 1e-7,
            loop_kernel_chi2: 16.8,
            outlier_chi2: 16.8,
            max_translation_change: 1.0,
            max_rotation_change: 30f64.to_radians(),
        }
    }
}

/// What one [`PoseGraph::optimise`] did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OptimisationReport {
    /// Levenberg-Marquardt iterations over all solves.
    pub iterations: usize,
    /// Solves (1, plus one after each round of rejections).
    pub solves: usize,
    /// Cost (sum of kernelised chi-squares) at the starting poses, all loop edges on.
    pub initial_cost: f64,
    /// Cost at the result, over the edges kept.
    pub final_cost: f64,
    /// Loop edges rejected by this call (positions in [`PoseGraph::edges`]).
    pub rejected: Vec<usize>,
    /// The largest move of a pose, metres, and the largest turn, radians.
    pub largest_change: (f64, f64),
}

/// Keyframe poses and the edges between them.
#[derive(Debug, Clone, Default)]
pub struct PoseGraph {
    poses: Vec<DAffine3>,
    edges: Vec<PoseEdge>,
    /// Per edge, whether a past optimisation rejected it.
    rejected: Vec<bool>,
}

/// `[v]×`, the cross-product matrix.
fn skew(v: DVec3) -> DMat3 {
    DMat3::from_cols(DVec3::new(0.0, v.z, -v.y), DVec3::new(-v.z, 0.0, v.x), DVec3::new(v.y, -v.x, 0.0))
}

/// The rotation vector of `r` (axis times angle, angle in 0..π).
pub fn rotation_log(r: DMat3) -> DVec3 {
    let q = DQuat::from_mat3(&r).normalize();
    // The shorter way round: q and -q are the same rotation.
    let q = if q.w < 0.0 { -q } else { q };
    let v = DVec3::new(q.x, q.y, q.z);
    let s = v.length();
    if s < 1e-12 {
        return 2.0 * v;
    }
    v * (2.0 * s.atan2(q.w) / s)
}

/// `exp([φ]×)`.
pub fn rotation_exp(phi: DVec3) -> DMat3 {
    DMat3::from_quat(DQuat::from_scaled_axis(phi))
}

/// Inverse right Jacobian of SO(3) at `phi`: `log(exp(φ) exp(w)) ≈ φ + Jr⁻¹(φ) w`.
fn right_jacobian_inverse(phi: DVec3) -> DMat3 {
    let theta = phi.length();
    let k = skew(phi);
    let c = if theta < 1e-6 {
        1.0 / 12.0 + theta * theta / 720.0
    } else {
        1.0 / (theta * theta) - (1.0 + theta.cos()) / (2.0 * theta * theta.sin())
    };
    DMat3::IDENTITY + 0.5 * k + c * (k * k)
}

/// The error `(t, log R)` of `Z⁻¹ Tᵢ⁻¹ Tⱼ`.
pub fn edge_error(world_from_i: &DAffine3, world_from_j: &DAffine3, i_from_j: &DAffine3) -> [f64; 6] {
    let e = i_from_j.inverse() * world_from_i.inverse() * *world_from_j;
    let r = rotation_log(e.matrix3);
    [e.translation.x, e.translation.y, e.translation.z, r.x, r.y, r.z]
}

/// The error and its Jacobians with respect to the left perturbations `(δt, δφ)` of pose
/// `i` and of pose `j` (see the module documentation).
fn edge_jacobians(ti: &DAffine3, tj: &DAffine3, z: &DAffine3) -> ([f64; 6], Mat6, Mat6) {
    let e = edge_error(ti, tj, z);
    let a = z.matrix3.transpose() * ti.matrix3.transpose();
    let d = tj.translation - ti.translation;
    let ad = a * skew(d);
    let jr = right_jacobian_inverse(DVec3::new(e[3], e[4], e[5])) * tj.matrix3.transpose();
    let mut ji = [[0.0; 6]; 6];
    let mut jj = [[0.0; 6]; 6];
    for r in 0..3 {
        for c in 0..3 {
            // glam matrices are column-major: m.col(c)[r] is row r, column c.
            ji[r][c] = -a.col(c)[r];
            ji[r][3 + c] = ad.col(c)[r];
            jj[r][c] = a.col(c)[r];
            ji[3 + r][3 + c] = -jr.col(c)[r];
            jj[3 + r][3 + c] = jr.col(c)[r];
        }
    }
    (e, ji, jj)
}

/// Applies the left perturbation `(δt, δφ)` to `pose`.
fn perturbed(pose: &DAffine3, delta: &[f64]) -> DAffine3 {
    let r = rotation_exp(DVec3::new(delta[3], delta[4], delta[5])) * pose.matrix3;
    // Re-orthonormalise: thousands of small products drift.
    let r = DMat3::from_quat(DQuat::from_mat3(&r).normalize());
    DAffine3 { matrix3: r, translation: pose.translation + DVec3::new(delta[0], delta[1], delta[2]) }
}

/// A sparse Cholesky factorisation, the block pattern it was analysed for and the block
/// order it uses.
struct Factorisation {
    pattern: Vec<(usize, usize)>,
    order: Vec<usize>,
    cholesky: CscCholesky<f64>,
}

/// The factorisation of the last solve, if any.
type Factor = Option<Factorisation>;

/// `eᵀ Ω e`.
fn chi2(e: &[f64; 6], omega: &Mat6) -> f64 {
    let mut s = 0.0;
    for r in 0..6 {
        for c in 0..6 {
            s += e[r] * omega[r][c] * e[c];
        }
    }
    s
}

/// The information of independent errors with standard deviations `sigma_t` (metres, per
/// translation axis) and `sigma_r` (radians, per rotation axis).
pub fn isotropic_information(sigma_t: f64, sigma_r: f64) -> Mat6 {
    let mut m = [[0.0; 6]; 6];
    for i in 0..3 {
        m[i][i] = 1.0 / (sigma_t * sigma_t);
        m[3 + i][3 + i] = 1.0 / (sigma_r * sigma_r);
    }
    m
}

/// Translation (metres) and rotation (radians) between two poses.
pub fn pose_distance(a: &DAffine3, b: &DAffine3) -> (f64, f64) {
    let t = (a.translation - b.translation).length();
    let r = rotation_log(a.matrix3.transpose() * b.matrix3).length();
    (t, r)
}

/// Normal equations of one linearisation: 6x6 blocks keyed by (row, column) of the free
/// poses (the upper triangle and the diagonal only) and the gradient.
struct NormalEquations {
    blocks: BTreeMap<(usize, usize), Mat6>,
    gradient: Vec<f64>,
}

impl PoseGraph {
    /// An empty graph.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a pose (normally the new keyframe's tracked pose); returns its index.
    ///
    /// # Errors
    /// [`PoseGraphError::NonFinitePose`] for a pose with a NaN or infinite entry.
    pub fn add_pose(&mut self, world_from_keyframe: DAffine3) -> Result<usize, PoseGraphError> {
        if !world_from_keyframe.is_finite() {
            return Err(PoseGraphError::NonFinitePose(self.poses.len()));
        }
        self.poses.push(world_from_keyframe);
        Ok(self.poses.len() - 1)
    }

    /// Adds an edge; returns its index.
    ///
    /// # Errors
    /// [`PoseGraphError::InvalidEdge`] for a missing or repeated pose, a non-finite
    /// measurement, or an information matrix that is not finite, symmetric and with a
    /// positive diagonal.
    pub fn add_edge(&mut self, edge: PoseEdge) -> Result<usize, PoseGraphError> {
        let index = self.edges.len();
        let bad = |message: String| Err(PoseGraphError::InvalidEdge { index, message });
        let n = self.poses.len();
        if edge.from >= n || edge.to >= n || edge.from == edge.to {
            return bad(format!("joins poses {} and {} of {n}", edge.from, edge.to));
        }
        if !edge.from_from_to.is_finite() {
            return bad("the measurement is not finite".into());
        }
        let m = &edge.information;
        let symmetric = (0..6).all(|r| (0..6).all(|c| m[r][c].is_finite() && m[r][c] == m[c][r]));
        if !symmetric || (0..6).any(|i| !(m[i][i] > 0.0)) {
            return bad("the information matrix is not finite, symmetric with a positive diagonal".into());
        }
        self.edges.push(edge);
        self.rejected.push(false);
        Ok(index)
    }

    /// The poses.
    pub fn poses(&self) -> &[DAffine3] {
        &self.poses
    }

    /// The edges, in the order they were added.
    pub fn edges(&self) -> &[PoseEdge] {
        &self.edges
    }

    /// Whether edge `i` was rejected as an outlier by an optimisation.
    pub fn is_rejected(&self, i: usize) -> bool {
        self.rejected.get(i).copied().unwrap_or(false)
    }

    /// Switches edge `i` off for good (a loop the caller no longer trusts).
    pub fn reject(&mut self, i: usize) {
        if let Some(r) = self.rejected.get_mut(i) {
            *r = true;
        }
    }

    /// Puts edge `i` back into the optimisation (a rejection later evidence overturns).
    pub fn restore(&mut self, i: usize) {
        if let Some(r) = self.rejected.get_mut(i) {
            *r = false;
        }
    }

    /// Multiplies the information of every edge of `kind` by `factor` (positive): a noise
    /// model found too confident for the data.
    pub fn scale_information(&mut self, kind: EdgeKind, factor: f64) {
        for e in self.edges.iter_mut().filter(|e| e.kind == kind) {
            for row in e.information.iter_mut() {
                for v in row.iter_mut() {
                    *v *= factor;
                }
            }
        }
    }

    /// Chi-square `eᵀ Ω e` of edge `i` at the current poses.
    pub fn edge_chi2(&self, i: usize) -> Option<f64> {
        let e = self.edges.get(i)?;
        Some(chi2(&edge_error(&self.poses[e.from], &self.poses[e.to], &e.from_from_to), &e.information))
    }

    /// Optimises every pose but the first; rejects loop edges that stay inconsistent (see
    /// the module documentation). On success the poses are replaced; on error they are as
    /// before.
    ///
    /// # Errors
    /// [`PoseGraphError::Singular`] when a pose is unconstrained; [`PoseGraphError::Refused`]
    /// when the result is not finite or moves a pose beyond the configured bounds.
    pub fn optimise(&mut self, config: &PoseGraphConfig) -> Result<OptimisationReport, PoseGraphError> {
        let start = self.poses.clone();
        let mut report = OptimisationReport::default();
        if self.poses.len() < 2 {
            return Ok(report);
        }
        let mut active: Vec<bool> = self.rejected.iter().map(|r| !r).collect();
        report.initial_cost = self.cost(&start, &active, config);
        let mut poses = start.clone();
        loop {
            poses.clone_from(&start);
            let (iterations, cost) = self.solve(&mut poses, &active, config)?;
            report.iterations += iterations;
            report.solves += 1;
            report.final_cost = cost;
            let mut worst: Option<(f64, usize)> = None;
            for (i, e) in self.edges.iter().enumerate() {
                if e.kind == EdgeKind::Loop && active[i] {
                    let s = chi2(&edge_error(&poses[e.from], &poses[e.to], &e.from_from_to), &e.information);
                    if s > config.outlier_chi2 && worst.is_none_or(|(w, _)| s > w) {
                        worst = Some((s, i));
                    }
                }
            }
            // One edge at a time, the worst first: a false loop can drag a true one past the
            // threshold while it is in the graph.
            match worst {
                Some((_, i)) => {
                    active[i] = false;
                    report.rejected.push(i);
                }
                None => break,
            }
        }
        // The largest move and turn, and the pose that moved the most (a NaN is refused).
        let (mut pose, mut t, mut r) = (0usize, 0.0f64, 0.0f64);
        for (i, (a, b)) in start.iter().zip(&poses).enumerate() {
            let (ti, ri) = pose_distance(a, b);
            if ti.is_nan() || ri.is_nan() {
                (pose, t, r) = (i, f64::NAN, f64::NAN);
                break;
            }
            if ti > t {
                (pose, t) = (i, ti);
            }
            r = r.max(ri);
        }
        if !(t <= config.max_translation_change && r <= config.max_rotation_change) {
            return Err(PoseGraphError::Refused { pose, translation_m: t, rotation_deg: r.to_degrees() });
        }
        report.largest_change = (t, r);
        for &i in &report.rejected {
            self.rejected[i] = true;
        }
        self.poses = poses;
        Ok(report)
    }

    /// Robust weight of an edge with chi-square `s`.
    fn weight(kind: EdgeKind, s: f64, config: &PoseGraphConfig) -> f64 {
        match kind {
            EdgeKind::Loop if config.loop_kernel_chi2 > 0.0 => 1.0 / (1.0 + s / config.loop_kernel_chi2),
            _ => 1.0,
        }
    }

    /// Kernelised cost of the active edges at `poses`.
    fn cost(&self, poses: &[DAffine3], active: &[bool], config: &PoseGraphConfig) -> f64 {
        self.edges
            .iter()
            .zip(active)
            .filter(|(_, a)| **a)
            .map(|(e, _)| {
                let s = chi2(&edge_error(&poses[e.from], &poses[e.to], &e.from_from_to), &e.information);
                match e.kind {
                    EdgeKind::Loop if config.loop_kernel_chi2 > 0.0 => {
                        config.loop_kernel_chi2 * (s / config.loop_kernel_chi2).ln_1p()
                    }
                    _ => s,
                }
            })
            .sum()
    }

    /// Linearises the active edges at `poses` (pose 0 fixed: free pose `p` is variable
    /// block `p - 1`).
    fn normal_equations(&self, poses: &[DAffine3], active: &[bool], config: &PoseGraphConfig) -> NormalEquations {
        let free = poses.len() - 1;
        let mut blocks: BTreeMap<(usize, usize), Mat6> = BTreeMap::new();
        let mut gradient = vec![0.0; 6 * free];
        for p in 0..free {
            blocks.insert((p, p), [[0.0; 6]; 6]);
        }
        for (edge, _) in self.edges.iter().zip(active).filter(|(_, a)| **a) {
            let (e, ji, jj) = edge_jacobians(&poses[edge.from], &poses[edge.to], &edge.from_from_to);
            let s = chi2(&e, &edge.information);
            let w = Self::weight(edge.kind, s, config);
            // w Ω J for both ends.
            let omega = &edge.information;
            let ends = [(edge.from, &ji), (edge.to, &jj)];
            let mut oj = [[[0.0; 6]; 6]; 2];
            for (k, (_, j)) in ends.iter().enumerate() {
                for r in 0..6 {
                    for c in 0..6 {
                        oj[k][r][c] = w * (0..6).map(|m| omega[r][m] * j[m][c]).sum::<f64>();
                    }
                }
            }
            for (pa, ja) in ends.iter() {
                if *pa == 0 {
                    continue;
                }
                let ra = pa - 1;
                for r in 0..6 {
                    gradient[6 * ra + r] +=
                        (0..6).map(|m| ja[m][r] * (0..6).map(|n| omega[m][n] * e[n]).sum::<f64>()).sum::<f64>() * w;
                }
                for (b, (pb, _)) in ends.iter().enumerate() {
                    if *pb == 0 || pb < pa {
                        continue;
                    }
                    let block = blocks.entry((ra, pb - 1)).or_insert([[0.0; 6]; 6]);
                    for r in 0..6 {
                        for c in 0..6 {
                            block[r][c] += (0..6).map(|m| ja[m][r] * oj[b][m][c]).sum::<f64>();
                        }
                    }
                }
            }
        }
        NormalEquations { blocks, gradient }
    }

    /// Levenberg-Marquardt from `poses` over the active edges; returns the iterations and
    /// the final cost.
    fn solve(
        &self,
        poses: &mut [DAffine3],
        active: &[bool],
        config: &PoseGraphConfig,
    ) -> Result<(usize, f64), PoseGraphError> {
        let mut lambda = 1e-6;
        let mut factor: Factor = None;
        let mut cost = self.cost(poses, active, config);
        let mut iterations = 0;
        while iterations < config.max_iterations {
            iterations += 1;
            let ne = self.normal_equations(poses, active, config);
            let mut accepted = false;
            let mut step = 0.0f64;
            for _ in 0..10 {
                let delta = solve_sparse(&ne, lambda, &mut factor)?;
                let candidate: Vec<DAffine3> = std::iter::once(poses[0])
                    .chain(poses[1..].iter().enumerate().map(|(p, pose)| perturbed(pose, &delta[6 * p..6 * p + 6])))
                    .collect();
                let new_cost = self.cost(&candidate, active, config);
                if new_cost.is_finite() && new_cost <= cost {
                    poses.copy_from_slice(&candidate);
                    step = delta.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                    cost = new_cost;
                    lambda = (lambda * 0.1).max(1e-12);
                    accepted = true;
                    break;
                }
                lambda *= 10.0;
            }
            if !accepted || step < config.converged_step {
                break;
            }
        }
        Ok((iterations, cost))
    }
}

/// Solves `(H + λ diag(H)) δ = -g` with the sparse Cholesky factorisation, reusing the
/// symbolic analysis of `factor` while the block pattern is the same.
fn solve_sparse(ne: &NormalEquations, lambda: f64, factor: &mut Factor) -> Result<Vec<f64>, PoseGraphError> {
    let n = ne.gradient.len();
    let pattern: Vec<(usize, usize)> = ne.blocks.keys().copied().collect();
    let reuse = matches!(factor, Some(f) if f.pattern == pattern);
    let order = match factor {
        Some(f) if reuse => std::mem::take(&mut f.order),
        _ => reverse_cuthill_mckee(n / 6, &pattern),
    };
    // Columns of the full symmetric matrix in the new block order: block (r, c) is H[r][c]
    // and, transposed, H[c][r].
    let mut by_column: Vec<Vec<(usize, bool, &Mat6)>> = vec![Vec::new(); n / 6];
    for (&(r, c), m) in &ne.blocks {
        let (nr, nc) = (order[r], order[c]);
        by_column[nc].push((nr, false, m));
        if r != c {
            by_column[nr].push((nc, true, m));
        }
    }
    let mut offsets = Vec::with_capacity(n + 1);
    let mut rows = Vec::new();
    let mut values = Vec::new();
    offsets.push(0);
    for (bc, col_blocks) in by_column.iter_mut().enumerate() {
        col_blocks.sort_by_key(|b| b.0);
        for k in 0..6 {
            for &(br, transposed, m) in col_blocks.iter() {
                for i in 0..6 {
                    let mut v = if transposed { m[k][i] } else { m[i][k] };
                    if br == bc && i == k {
                        // Marquardt damping, and a floor for rotations a graph leaves free.
                        v += lambda * v + 1e-12;
                    }
                    rows.push(6 * br + i);
                    values.push(v);
                }
            }
            offsets.push(rows.len());
        }
    }
    match factor {
        Some(f) if reuse => {
            f.order = order;
            f.cholesky.refactor(&values).map_err(|_| PoseGraphError::Singular)?;
        }
        _ => {
            let h = CscMatrix::try_from_csc_data(n, n, offsets, rows, values).map_err(|_| PoseGraphError::Singular)?;
            let cholesky = CscCholesky::factor(&h).map_err(|_| PoseGraphError::Singular)?;
            *factor = Some(Factorisation { pattern, order, cholesky });
        }
    }
    let Some(f) = factor.as_ref() else { return Err(PoseGraphError::Singular) };
    let mut b = DMatrix::<f64>::zeros(n, 1);
    for (p, &q) in f.order.iter().enumerate() {
        for i in 0..6 {
            b[6 * q + i] = -ne.gradient[6 * p + i];
        }
    }
    let x = f.cholesky.solve(&b);
    let delta: Vec<f64> = (0..n).map(|j| x[6 * f.order[j / 6] + j % 6]).collect();
    if delta.iter().all(|v| v.is_finite()) {
        Ok(delta)
    } else {
        Err(PoseGraphError::Singular)
    }
}

/// A fill-reducing order of the `n` pose blocks (reverse Cuthill-McKee: breadth first from
/// a least-connected pose, neighbours by increasing degree, then reversed): `order[p]` is
/// the new position of block `p`. Keyframes in capture order are banded except for the loop
/// edges, which in that order make the factor fill the whole band between a loop's ends (a
/// 360-keyframe scan revisiting its first lap: 0.6 s per optimisation); this order keeps a
/// revisited lap next to the lap it revisits. Ties go to the lower index (deterministic).
fn reverse_cuthill_mckee(n: usize, pattern: &[(usize, usize)]) -> Vec<usize> {
    let mut adjacent = vec![Vec::new(); n];
    for &(r, c) in pattern {
        if r != c {
            adjacent[r].push(c);
            adjacent[c].push(r);
        }
    }
    for a in &mut adjacent {
        a.sort_unstable();
        a.dedup();
    }
    let degree: Vec<usize> = adjacent.iter().map(Vec::len).collect();
    let mut visited = vec![false; n];
    let mut sequence = Vec::with_capacity(n);
    while sequence.len() < n {
        let Some(start) = (0..n).filter(|&p| !visited[p]).min_by_key(|&p| (degree[p], p)) else { break };
        visited[start] = true;
        let mut head = sequence.len();
        sequence.push(start);
        while head < sequence.len() {
            let p = sequence[head];
            head += 1;
            let mut next: Vec<usize> = adjacent[p].iter().copied().filter(|&q| !visited[q]).collect();
            next.sort_unstable_by_key(|&q| (degree[q], q));
            for q in next {
                visited[q] = true;
                sequence.push(q);
            }
        }
    }
    let mut order = vec![0; n];
    for (new, &old) in sequence.iter().rev().enumerate() {
        order[old] = new;
    }
    order
}

mod information;
pub use information::{adjoint, alignment_information, odometry_information, pull_back};

#[cfg(test)]
mod tests;
