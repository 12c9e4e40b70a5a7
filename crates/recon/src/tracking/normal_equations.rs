//! One Gauss-Newton step of the tracker: the point-to-plane (and photometric) normal
//! equations summed in fixed row blocks (the same bits for any thread count), the robust
//! weights and the damped, conditioning-checked solve.

use super::*;

/// Normal equations of one Gauss-Newton step at `estimate` (`reference_from_current`: the model view's camera from the frame's).
/// Visits every `stride`-th pixel of every `stride`-th row. A level without vertices
/// (level 0) forms them from its depth and takes its normals from `coarse`, the next level.
#[allow(clippy::too_many_arguments)]
pub(super) fn normal_equations(
    data: &Level,
    coarse: Option<&Level>,
    model: &Model,
    estimate: &Affine3A,
    max_distance: f32,
    stride: usize,
    c: &TrackerConfig,
) -> Normals {
    let w = data.k.width as usize;
    let h = data.k.height as usize;
    let mk = model.view.intrinsics;
    let (mw, mh) = (mk.width as usize, mk.height as usize);
    let rot = Mat3::from(estimate.matrix3);
    let trans = Vec3::from(estimate.translation);
    let min_cos = c.max_normal_angle.cos();
    let max_d2 = max_distance * max_distance;
    let photometric = c.photometric_weight > 0.0 && !data.intensity.is_empty() && !model.intensity.is_empty();
    let lambda = c.photometric_weight;
    let rows: Vec<usize> = (0..h).step_by(stride).collect();
    let blocks: Vec<Normals> = rows
        .par_chunks(ROWS_PER_BLOCK)
        .map(|rows| {
            let mut acc = Normals::ZERO;
            let mut sums = RowSums::ZERO;
            for &y in rows {
                sums.flush(&mut acc);
                for x in (0..w).step_by(stride) {
                    let i = y * w + x;
                    let d = data.depth[i];
                    acc.sampled += (d > 0.0) as u64;
                    let (p_cur, n_cur) = if data.vertices.is_empty() {
                        // As `build_pyramid` does for level 1 from level 2.
                        let Some(n) = coarse.and_then(|c| c.normal_for_finer(&c.own_normals, x, y, d)) else {
                            continue;
                        };
                        (data.k.unproject(x as f32, y as f32, d), n)
                    } else {
                        (data.vertices[i], data.normals[i])
                    };
                    if n_cur == Vec3::ZERO {
                        continue;
                    }
                    let q = rot * p_cur + trans;
                    if q.z <= 0.0 {
                        continue;
                    }
                    let uv = mk.project(q);
                    // Nearest model pixel; truncation is floor on the non-negative range
                    // kept (`floor` is a library call on baseline x86-64).
                    let (fu, fv) = (uv.x + 0.5, uv.y + 0.5);
                    if !(fu >= 0.0 && fv >= 0.0 && fu < mw as f32 && fv < mh as f32) {
                        continue;
                    }
                    let mi = fv as usize * mw + fu as usize;
                    let mvtx = model.view.vertices[mi];
                    if mvtx.z <= 0.0 {
                        continue;
                    }
                    let mn = model.view.normals[mi];
                    let diff = q - mvtx;
                    if diff.length_squared() > max_d2 {
                        acc.far += 1;
                        continue;
                    }
                    if (rot * n_cur).dot(mn) < min_cos {
                        acc.turned += 1;
                        continue;
                    }
                    let r = mn.dot(diff);
                    // Depth noise grows about with the square of depth: residuals are
                    // measured in units of the noise at 1 m (Huber on the normalised
                    // residual, information weight 1/scale²). Far points then no longer
                    // dominate, which matters because fusion biases the model surface by
                    // a fraction of the noise where it nears the truncation distance.
                    let scale = mvtx.z.max(0.5) * mvtx.z.max(0.5);
                    let wgt = huber(r / scale, c.huber_geometric) / (scale * scale);
                    // The lever arm from the model point, not the measured one: the measured
                    // point's depth noise is in the residual too, and a Jacobian correlated
                    // with the residual biases the solution (by a few millimetres per frame
                    // at Kinect noise levels).
                    let qxn = mvtx.cross(mn);
                    sums.add([qxn.x, qxn.y, qxn.z, mn.x, mn.y, mn.z], r, wgt);
                    let (r, scale) = (r as f64, scale as f64);
                    acc.sq_residual += r * r;
                    acc.sq_normalised += (r / scale) * (r / scale);
                    acc.inliers += 1;
                    if photometric {
                        if let Some((rp, jp)) = photometric_term(model, uv, q, data.intensity[i]) {
                            let wp = lambda * huber(rp, c.huber_photometric);
                            sums.add(jp, rp, wp);
                        }
                    }
                }
            }
            sums.flush(&mut acc);
            acc
        })
        .collect();
    let mut total = Normals::ZERO;
    for b in &blocks {
        total.merge(b);
    }
    total
}

/// Lanes of the vectorised association (one AVX register of f32).
pub(super) const LANES: usize = 8;

/// The points of one pyramid level that association visits, gathered once per frame into
/// structure-of-arrays blocks: every pixel on the visited grid with a depth and a normal
/// (at the finest level formed from the depth and the next level, as [`normal_equations`]
/// does), in row-major order. The iterations of a level then run over dense lanes instead
/// of re-testing every pixel, and a block's eight lanes go through the same arithmetic
/// together.
pub(super) struct LevelPoints {
    pub(super) blocks: Vec<PointBlock>,
    /// Pixels with a valid depth among those visited (the overlap test's denominator).
    pub(super) sampled: u64,
}

/// The points of [`ROWS_PER_BLOCK`] visited rows.
///
/// # Shapes
/// `coords[0..3]` are the vertex x, y, z and `coords[3..6]` the normal x, y, z, each `len`
/// long, then zero-padded to a multiple of [`LANES`].
pub(super) struct PointBlock {
    pub(super) coords: [Vec<f32>; 6],
    pub(super) len: usize,
}

impl LevelPoints {
    /// Gathers the points of `data` on every `stride`-th pixel of every `stride`-th row; a
    /// level without vertices forms them from its depth and takes normals from `coarse`.
    pub(super) fn new(data: &Level, coarse: Option<&Level>, stride: usize) -> Self {
        let (w, h) = (data.k.width as usize, data.k.height as usize);
        let rows: Vec<usize> = (0..h).step_by(stride).collect();
        let rays = RayTable::new(data.k);
        let blocks: Vec<(PointBlock, u64)> = rows
            .par_chunks(ROWS_PER_BLOCK)
            .map(|rows| {
                // Written by index into zeroed buffers sized for every visited pixel (the
                // padding is then already zero), not pushed: six capacity checks a point.
                let capacity = (rows.len() * w.div_ceil(stride)).next_multiple_of(LANES);
                let mut coords: [Vec<f32>; 6] = std::array::from_fn(|_| vec![0.0; capacity]);
                let [cx, cy, cz, cnx, cny, cnz] = &mut coords;
                let (mut len, mut sampled) = (0usize, 0u64);
                for &y in rows {
                    let drow = &data.depth[y * w..(y + 1) * w];
                    for x in (0..w).step_by(stride) {
                        let d = drow[x];
                        sampled += (d > 0.0) as u64;
                        let (p, n) = if data.vertices.is_empty() {
                            let Some(n) = coarse.and_then(|c| c.normal_for_finer(&c.own_normals, x, y, d)) else {
                                continue;
                            };
                            (rays.unproject(x, y, d), n)
                        } else {
                            let i = y * w + x;
                            (data.vertices[i], data.normals[i])
                        };
                        if n == Vec3::ZERO {
                            continue;
                        }
                        (cx[len], cy[len], cz[len]) = (p.x, p.y, p.z);
                        (cnx[len], cny[len], cnz[len]) = (n.x, n.y, n.z);
                        len += 1;
                    }
                }
                for v in &mut coords {
                    v.truncate(len.next_multiple_of(LANES));
                }
                (PointBlock { coords, len }, sampled)
            })
            .collect();
        let sampled = blocks.iter().map(|b| b.1).sum();
        Self { blocks: blocks.into_iter().map(|b| b.0).collect(), sampled }
    }

    /// The normal equations of one Gauss-Newton step at `estimate`, as [`normal_equations`]
    /// forms them without the photometric term: the same pairs, residuals and weights
    /// (bit for bit), summed per lane in f32 within a block (as many terms per lane as a
    /// row of the scalar path sums), then in f64.
    pub(super) fn normal_equations(
        &self,
        model: &Model,
        estimate: &Affine3A,
        max_distance: f32,
        c: &TrackerConfig,
    ) -> Normals {
        let step = StepParams::new(model, estimate, max_distance, c);
        let blocks: Vec<Normals> = self.blocks.par_iter().map(|b| block_sums(b, &step)).collect();
        let mut total = Normals::ZERO;
        for b in &blocks {
            total.merge(b);
        }
        total.sampled = self.sampled;
        total
    }
}

/// What one association step needs, unpacked for the lanes.
pub(super) struct StepParams<'a> {
    /// Rotation columns and translation of `reference_from_current`.
    pub(super) rot: [[f32; 3]; 3],
    pub(super) trans: [f32; 3],
    pub(super) fx: f32,
    pub(super) fy: f32,
    pub(super) cx: f32,
    pub(super) cy: f32,
    pub(super) mw: usize,
    pub(super) mh: usize,
    pub(super) vertices: &'a [Vec3],
    pub(super) normals: &'a [Vec3],
    pub(super) max_d2: f32,
    pub(super) min_cos: f32,
    pub(super) huber: f32,
}

impl<'a> StepParams<'a> {
    pub(super) fn new(model: &'a Model, estimate: &Affine3A, max_distance: f32, c: &TrackerConfig) -> Self {
        let m = Mat3::from(estimate.matrix3);
        let k = model.view.intrinsics;
        Self {
            rot: [m.x_axis.to_array(), m.y_axis.to_array(), m.z_axis.to_array()],
            trans: Vec3::from(estimate.translation).to_array(),
            fx: k.fx,
            fy: k.fy,
            cx: k.cx,
            cy: k.cy,
            mw: k.width as usize,
            mh: k.height as usize,
            vertices: &model.view.vertices,
            normals: &model.view.normals,
            max_d2: max_distance * max_distance,
            min_cos: c.max_normal_angle.cos(),
            huber: c.huber_geometric,
        }
    }

    /// Whether the model buffers cover every pixel index association can form, with
    /// component offsets (`3 i + 2`) that fit an `i32` (what the AVX2 gathers rely on).
    #[cfg(target_arch = "x86_64")]
    pub(super) fn gather_safe(&self) -> bool {
        let pixels = self.mw * self.mh;
        self.vertices.len() >= pixels && self.normals.len() >= pixels && pixels <= (i32::MAX as usize) / 4
    }
}

/// [`block_sums_lanes`] in AVX2 intrinsics where the CPU has it (the same IEEE operations
/// in the same order, so both give the same bits), else the portable lanes.
pub(super) fn block_sums(b: &PointBlock, s: &StepParams) -> Normals {
    #[cfg(target_arch = "x86_64")]
    if avx2_available() && s.gather_safe() {
        // SAFETY: the CPU has AVX2 and FMA (checked at run time), the model buffers cover
        // its pixels with i32 indices (checked above), and blocks are padded to whole lanes.
        return unsafe { avx2::block_sums(b, s) };
    }
    block_sums_lanes(b, s)
}

/// Whether the CPU has AVX2 and FMA (`SEMRECON_TRACKING_SIMD=portable` says no).
#[cfg(target_arch = "x86_64")]
pub(super) fn avx2_available() -> bool {
    static AVX2: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *AVX2.get_or_init(|| {
        std::env::var("SEMRECON_TRACKING_SIMD").map_or(true, |v| v != "portable")
            && is_x86_feature_detected!("avx2")
            && is_x86_feature_detected!("fma")
    })
}

/// Per-lane sums of one block: the upper triangle of H (21, row by row) then g (6), the
/// squared residuals and the test counts, reduced to [`Normals`] in a fixed order.
pub(super) struct LaneSums {
    pub(super) sums: [[f32; LANES]; 27],
    pub(super) sq_res: [f64; LANES],
    pub(super) sq_norm: [f64; LANES],
    pub(super) inliers: [u32; LANES],
    pub(super) far: [u32; LANES],
    pub(super) turned: [u32; LANES],
}

impl LaneSums {
    pub(super) const ZERO: Self = Self {
        sums: [[0.0; LANES]; 27],
        sq_res: [0.0; LANES],
        sq_norm: [0.0; LANES],
        inliers: [0; LANES],
        far: [0; LANES],
        turned: [0; LANES],
    };

    pub(super) fn into_normals(self) -> Normals {
        let mut n = Normals::ZERO;
        let mut k = 0;
        for a in 0..6 {
            for bb in a..6 {
                n.h[a][bb] = self.sums[k].iter().fold(0.0f64, |acc, &v| acc + v as f64);
                k += 1;
            }
            n.g[a] = self.sums[21 + a].iter().fold(0.0f64, |acc, &v| acc + v as f64);
        }
        n.sq_residual = self.sq_res.iter().sum();
        n.sq_normalised = self.sq_norm.iter().sum();
        n.inliers = self.inliers.iter().map(|&v| v as u64).sum();
        n.far = self.far.iter().map(|&v| v as u64).sum();
        n.turned = self.turned.iter().map(|&v| v as u64).sum();
        n
    }
}

/// The association and normal-equation sums of one block, [`LANES`] points at a time.
/// Written as per-lane loops over fixed-size arrays, which the compiler turns into vector
/// instructions of whatever width the enclosing function is compiled for; a rejected lane
/// contributes exact zeros.
#[inline(always)]
pub(super) fn block_sums_lanes(b: &PointBlock, s: &StepParams) -> Normals {
    type L = [f32; LANES];
    let mut out = LaneSums::ZERO;
    let LaneSums { sums, sq_res, sq_norm, inliers, far, turned } = &mut out;
    let [r0, r1, r2] = s.rot;
    let t = s.trans;
    let (mwf, mhf) = (s.mw as f32, s.mh as f32);
    pub(super) fn lanes(v: &[f32]) -> impl Iterator<Item = [f32; LANES]> + '_ {
        v.chunks_exact(LANES).map(|c| std::array::from_fn(|l| c[l]))
    }
    let [px, py, pz, nx, ny, nz] = &b.coords;
    let points = lanes(px).zip(lanes(py)).zip(lanes(pz)).zip(lanes(nx)).zip(lanes(ny)).zip(lanes(nz));
    for (g, (((((px, py), pz), nx), ny), nz)) in (0..b.len).step_by(LANES).zip(points) {
        let (mut qx, mut qy, mut qz) = ([0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES]);
        let mut mi = [0usize; LANES];
        let mut ok = [false; LANES];
        for l in 0..LANES {
            // glam's `rot * p + trans`, operation for operation.
            qx[l] = ((r0[0] * px[l] + r1[0] * py[l]) + r2[0] * pz[l]) + t[0];
            qy[l] = ((r0[1] * px[l] + r1[1] * py[l]) + r2[1] * pz[l]) + t[1];
            qz[l] = ((r0[2] * px[l] + r1[2] * py[l]) + r2[2] * pz[l]) + t[2];
            let fu = s.fx * qx[l] / qz[l] + s.cx + 0.5;
            let fv = s.fy * qy[l] / qz[l] + s.cy + 0.5;
            ok[l] = g + l < b.len && qz[l] > 0.0 && fu >= 0.0 && fv >= 0.0 && fu < mwf && fv < mhf;
            mi[l] = if ok[l] { fv as i32 as usize * s.mw + fu as i32 as usize } else { 0 };
        }
        // The model pixels (a gather: scalar loads).
        let (mut mx, mut my, mut mz, mut mnx, mut mny, mut mnz) =
            ([0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES], [0.0f32; LANES]);
        for l in 0..LANES {
            let (v, n) = (s.vertices[mi[l]], s.normals[mi[l]]);
            (mx[l], my[l], mz[l], mnx[l], mny[l], mnz[l]) = (v.x, v.y, v.z, n.x, n.y, n.z);
        }
        let mut j: [L; 6] = [[0.0; LANES]; 6];
        let (mut r, mut wgt) = ([0.0f32; LANES], [0.0f32; LANES]);
        for l in 0..LANES {
            let on_model = ok[l] && mz[l] > 0.0;
            let (dx, dy, dz) = (qx[l] - mx[l], qy[l] - my[l], qz[l] - mz[l]);
            let is_far = on_model && (dx * dx + dy * dy) + dz * dz > s.max_d2;
            let near = on_model && !is_far;
            let nrx = (r0[0] * nx[l] + r1[0] * ny[l]) + r2[0] * nz[l];
            let nry = (r0[1] * nx[l] + r1[1] * ny[l]) + r2[1] * nz[l];
            let nrz = (r0[2] * nx[l] + r1[2] * ny[l]) + r2[2] * nz[l];
            let is_turned = near && (nrx * mnx[l] + nry * mny[l]) + nrz * mnz[l] < s.min_cos;
            let inlier = near && !is_turned;
            far[l] += is_far as u32;
            turned[l] += is_turned as u32;
            inliers[l] += inlier as u32;
            let res = (mnx[l] * dx + mny[l] * dy) + mnz[l] * dz;
            let z = mz[l].max(0.5);
            let scale = z * z;
            let a = (res / scale).abs();
            let hub = if a <= s.huber { 1.0 } else { s.huber / a };
            let w = hub / (scale * scale);
            // The lever arm from the model point (see `normal_equations`).
            let jac = [
                my[l] * mnz[l] - mny[l] * mz[l],
                mz[l] * mnx[l] - mnz[l] * mx[l],
                mx[l] * mny[l] - mnx[l] * my[l],
                mnx[l],
                mny[l],
                mnz[l],
            ];
            for (ja, v) in j.iter_mut().zip(jac) {
                ja[l] = if inlier { v } else { 0.0 };
            }
            r[l] = if inlier { res } else { 0.0 };
            wgt[l] = if inlier { w } else { 0.0 };
            let (rd, sd) = (r[l] as f64, if inlier { scale as f64 } else { 1.0 });
            sq_res[l] += rd * rd;
            sq_norm[l] += (rd / sd) * (rd / sd);
        }
        let mut k = 0;
        for a in 0..6 {
            let wa: L = std::array::from_fn(|l| wgt[l] * j[a][l]);
            for bb in a..6 {
                for l in 0..LANES {
                    sums[k][l] += wa[l] * j[bb][l];
                }
                k += 1;
            }
            for l in 0..LANES {
                sums[21 + a][l] += wa[l] * r[l];
            }
        }
    }
    out.into_normals()
}

/// Intensity residual `I_model(π(q)) - I_frame` and its Jacobian with respect to a left
/// twist `(ω, υ)` of `q`; `None` where the model has no gradient.
#[inline]
pub(super) fn photometric_term(model: &Model, uv: Vec2, q: Vec3, intensity: f32) -> Option<(f32, [f32; 6])> {
    let k = model.view.intrinsics;
    let w = k.width as usize;
    if !(uv.x >= 0.0 && uv.y >= 0.0) {
        return None;
    }
    let (x0, y0) = ((uv.x as u32) as f32, (uv.y as u32) as f32);
    if !(x0 + 1.0 < k.width as f32 && y0 + 1.0 < k.height as f32) {
        return None;
    }
    let (fx, fy) = (uv.x - x0, uv.y - y0);
    let i = y0 as usize * w + x0 as usize;
    let idx = [i, i + 1, i + w, i + w + 1];
    let wts = [(1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy];
    let (mut val, mut grad) = (0.0f32, Vec2::ZERO);
    for (&j, &wt) in idx.iter().zip(&wts) {
        val += wt * model.intensity[j];
        grad += wt * model.gradient[j];
    }
    if !(val.is_finite() && grad.is_finite()) {
        return None;
    }
    let inv_z = 1.0 / q.z;
    // dπ/dq transposed times the image gradient.
    let g = Vec3::new(
        grad.x * k.fx * inv_z,
        grad.y * k.fy * inv_z,
        -(grad.x * k.fx * q.x + grad.y * k.fy * q.y) * inv_z * inv_z,
    );
    let qxg = q.cross(g);
    Some((val - intensity, [qxg.x, qxg.y, qxg.z, g.x, g.y, g.z]))
}

/// Huber weight of residual `r` with threshold `delta`.
#[inline]
pub(super) fn huber(r: f32, delta: f32) -> f32 {
    let a = r.abs();
    if a <= delta {
        1.0
    } else {
        delta / a
    }
}

/// The normal matrix `h` of an alignment (left twists `(ω, υ)` of `reference_from_current`
/// in the reference frame, rotation first, as [`se3_exp`] applies them) as a right
/// perturbation `(δt, δφ)` of the pose in the current camera's frame, translation first:
/// `estimate · exp(ξ) = exp(Ad(estimate) ξ) · estimate`, so the form is pulled back through
/// the adjoint. The reference's own pose adds nothing: a right perturbation of
/// `reference · estimate` is one of `estimate`.
pub(super) fn camera_hessian(h: &[[f64; 6]; 6], estimate: Affine3A) -> [[f64; 6]; 6] {
    // Rotation-first to translation-first.
    const FROM: [usize; 6] = [3, 4, 5, 0, 1, 2];
    let mut left = [[0.0; 6]; 6];
    for (r, row) in left.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = h[FROM[r]][FROM[c]];
        }
    }
    crate::pose_graph::pull_back(&left, &crate::pose_graph::adjoint(&estimate.as_daffine3()))
}

/// `exp` of a left twist `(ω, υ)`: rotation by `ω`, then translation by `υ` (the first-order
/// model the Jacobians use).
pub(super) fn se3_exp(xi: [f64; 6]) -> Affine3A {
    let omega = Vec3::new(xi[0] as f32, xi[1] as f32, xi[2] as f32);
    let v = Vec3::new(xi[3] as f32, xi[4] as f32, xi[5] as f32);
    Affine3A::from_rotation_translation(Quat::from_scaled_axis(omega), v)
}

/// The same transform with its rotation re-orthonormalised (accumulated f32 products drift).
pub(super) fn orthonormalised(t: Affine3A) -> Affine3A {
    let q = Quat::from_mat3a(&t.matrix3).normalize();
    Affine3A::from_rotation_translation(q, t.translation.into())
}

/// Smallest over largest eigenvalue of `h` after scaling it to a unit diagonal, so that
/// rotation (m²) and translation (1) entries compare.
/// The Jacobi scaling of `h` (1 / sqrt of the diagonal; 0 where the diagonal is not
/// positive) and the eigen-decomposition of the scaled matrix (ascending eigenvalues,
/// eigenvectors as rows).
pub(super) type ScaledEigen = ([f64; 6], [f64; 6], [[f64; 6]; 6]);

pub(super) fn scaled_eigen(h: &[[f64; 6]; 6]) -> ScaledEigen {
    // A diagonal that is rounding noise (a perfect plane leaves exact zeros that come out
    // as 1e-20) would be scaled up into a direction that looks constrained.
    let floor = 1e-12 * (0..6).map(|i| h[i][i]).fold(0.0, f64::max);
    let d: [f64; 6] = std::array::from_fn(|i| if h[i][i] > floor { 1.0 / h[i][i].sqrt() } else { 0.0 });
    let s: [[f64; 6]; 6] = std::array::from_fn(|i| std::array::from_fn(|j| h[i][j] * d[i] * d[j]));
    let (vals, vecs) = symmetric_eigen(&s);
    (d, vals, vecs)
}

/// Smallest over largest eigenvalue of the scale-normalised `h` (0 when a direction has
/// no constraint at all), and how many eigenvalues are at least `min_condition` times the
/// largest: the motion directions the alignment constrains.
pub(crate) fn conditioning(h: &[[f64; 6]; 6], min_condition: f64) -> (f64, usize) {
    let (d, vals, _) = scaled_eigen(h);
    if !(vals[5] > 0.0) {
        return (0.0, 0);
    }
    let constrained = vals.iter().filter(|&&v| v >= min_condition * vals[5]).count();
    let unconstrained_axes = d.iter().filter(|&&v| v == 0.0).count();
    let cond = if unconstrained_axes > 0 { 0.0 } else { (vals[0] / vals[5]).max(0.0) };
    (cond, constrained.min(6 - unconstrained_axes))
}

/// The standard deviation of the alignment's translation along its least determined axis,
/// metres: `sigma² (h⁻¹)` restricted to translation (rotation left free, so a slide that a
/// turn could explain counts as undetermined), its largest eigenvalue, for residuals of RMS
/// `sigma`. Unlike a condition number this is absolute: it says whether the view holds the
/// camera's position to a millimetre or lets it slide by centimetres within the noise (a
/// wall and a ceiling meeting along the image's width hold nothing across it). A lower
/// bound: noise in the normals lends every axis some information. Infinite for a singular
/// `h`.
pub(crate) fn translation_sigma(h: &[[f64; 6]; 6], sigma: f64) -> f64 {
    let mut block = [[0.0f64; 3]; 3];
    for i in 0..3 {
        let mut unit = [0.0; 6];
        unit[i] = 1.0;
        let Some(column) = cholesky_solve(h, &unit) else { return f64::INFINITY };
        for j in 0..3 {
            block[j][i] = column[j];
        }
    }
    let (vals, _) = symmetric_eigen(&block);
    let largest = vals.iter().copied().fold(0.0f64, f64::max);
    if largest.is_finite() {
        sigma * largest.sqrt()
    } else {
        f64::INFINITY
    }
}

/// One Gauss-Newton step: solves `h xi = neg_g`. A well-conditioned system is solved
/// as it is; otherwise, when `config.min_constrained` allows it, only along the scaled
/// eigen-directions that are constrained (eigenvalue at least `min_condition` times the
/// largest), so the unconstrained ones stay where the estimate started: at the motion
/// prediction. `None` for a singular or non-finite system.
pub(super) fn gauss_newton_step(h: &[[f64; 6]; 6], neg_g: &[f64; 6], config: &TrackerConfig) -> Option<[f64; 6]> {
    if config.min_constrained >= 6 {
        return cholesky_solve(h, neg_g);
    }
    let (d, vals, vecs) = scaled_eigen(h);
    let well_conditioned = d.iter().all(|&v| v > 0.0) && vals[0] >= config.min_condition * vals[5];
    if well_conditioned || !(vals[5] > 0.0) {
        // The first keeps the same bits as a plain solve wherever nothing is degenerate.
        return cholesky_solve(h, neg_g);
    }
    // xi = D pinv(D h D) D neg_g, truncated to the constrained directions.
    let b: [f64; 6] = std::array::from_fn(|i| d[i] * neg_g[i]);
    let mut y = [0.0f64; 6];
    for (val, vec) in vals.iter().zip(&vecs) {
        if *val >= config.min_condition * vals[5] {
            let along = vec.iter().zip(&b).map(|(v, b)| v * b).sum::<f64>() / val;
            for (y, v) in y.iter_mut().zip(vec) {
                *y += along * v;
            }
        }
    }
    let xi: [f64; 6] = std::array::from_fn(|i| d[i] * y[i]);
    xi.iter().all(|v| v.is_finite()).then_some(xi)
}
