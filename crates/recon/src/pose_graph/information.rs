//! A loop edge's information from the alignment that measured it, instead of one isotropic
//! constant: a loop seen along a corridor constrains the motion along it little, and the
//! point-to-plane alignment's Gauss-Newton Hessian `JᵀJ` says so.
//!
//! The alignment perturbs `old_from_new = Z` on the left in the old keyframe's frame
//! (`t ← exp(δφ) t + δt`, `R ← exp(δφ) R`); the graph's edge error is `(t, log R)` of
//! `Z⁻¹ · Tᵢ⁻¹ · Tⱼ`, which near zero is `e = −M δ` with
//! `M⁻¹ = N = [[R, [t]ₓ R], [0, R]]` (`R`, `t` of `Z`). A quadratic `δᵀ H δ` is therefore
//! `eᵀ Nᵀ H N e` in the edge's terms.
//!
//! Scale: `H` sums thousands of block-mean points as if their errors were independent; they
//! are not (the block means, the sensor's calibration, the surfaces' own shape), and taken at
//! face value it would claim micrometres. Its shape is kept and its size set so that the
//! best-constrained translation direction has the standard deviation the isotropic model
//! gives every direction: the loops that were trusted stay as trusted where they are well
//! constrained, and weakly constrained directions get less weight.

use glam::{DAffine3, DMat3, DVec3};

use super::{skew, Mat6};

/// The information of a loop edge `i_from_j = z` measured by an alignment whose Gauss-Newton
/// Hessian (left perturbation `(δt, δφ)` of `z`, translation first) is `h`, scaled so that the
/// best-constrained translation direction has standard deviation `sigma_t` metres; `None`
/// when `h` has no translation information or is not finite. A tiny isotropic floor (1 m, 1
/// radian) keeps the result positive definite.
pub fn alignment_information(z: &DAffine3, h: &Mat6, sigma_t: f64) -> Option<Mat6> {
    if !(h.iter().flatten().all(|v| v.is_finite()) && sigma_t.is_finite() && sigma_t > 0.0) {
        return None;
    }
    let htt = DMat3::from_cols_array_2d(&[
        [h[0][0], h[1][0], h[2][0]],
        [h[0][1], h[1][1], h[2][1]],
        [h[0][2], h[1][2], h[2][2]],
    ]);
    let largest = largest_eigenvalue(htt);
    if !(largest.is_finite() && largest > 0.0) {
        return None;
    }
    let scale = 1.0 / (sigma_t * sigma_t * largest);
    // N = Ad(z) = [[R, [t]x R], [0, R]]: the form in the edge's terms is Nᵀ h N.
    let mut out = pull_back(h, &adjoint(z));
    // Scaled, with the floor (pull_back's result is exactly symmetric; so is a scaling).
    for (a, row) in out.iter_mut().enumerate() {
        for v in row.iter_mut() {
            *v *= scale;
        }
        row[a] += 1.0;
    }
    Some(out)
}

/// The adjoint of `t` on twists `ξ = (δt, δφ)` (translation first, the left-perturbation
/// model `x ← x + δφ × x + δt`): `t · exp(ξ) · t⁻¹ = exp(Ad(t) ξ)`, so that
/// `Ad(t) = [[R, [t]ₓ R], [0, R]]`.
pub fn adjoint(t: &DAffine3) -> Mat6 {
    let r = t.matrix3;
    let tr = skew(t.translation) * r;
    let mut a = [[0.0; 6]; 6];
    for row in 0..3 {
        for col in 0..3 {
            // glam matrices are column-major: m.col(c)[r] is row r, column c.
            a[row][col] = r.col(col)[row];
            a[row][3 + col] = tr.col(col)[row];
            a[3 + row][3 + col] = r.col(col)[row];
        }
    }
    a
}

/// `aᵀ h a`: the quadratic form `h` on twists `ζ` seen in twists `ξ` with `ζ = a ξ`.
pub fn pull_back(h: &Mat6, a: &Mat6) -> Mat6 {
    let mut ha = [[0.0; 6]; 6];
    for r in 0..6 {
        for c in 0..6 {
            ha[r][c] = (0..6).map(|k| h[r][k] * a[k][c]).sum();
        }
    }
    let mut out = [[0.0; 6]; 6];
    for r in 0..6 {
        for c in 0..6 {
            out[r][c] = (0..6).map(|k| a[k][r] * ha[k][c]).sum();
        }
    }
    // Exactly symmetric: the graph checks its information matrices.
    for r in 0..6 {
        for c in 0..r {
            let m = 0.5 * (out[r][c] + out[c][r]);
            out[r][c] = m;
            out[c][r] = m;
        }
    }
    out
}

/// The information of an odometry edge `i_from_j` from the normal matrix `h` of the tracking
/// that measured keyframe `j` against the map: `h` is a right perturbation `(δt, δφ)` of
/// `j`'s pose in its own camera frame (`T ← T · exp(δ)`, as
/// [`crate::TrackingResult::camera_hessian`]), which is a right perturbation of `i_from_j`
/// too, and the edge error `log(z⁻¹ Tᵢ⁻¹ Tⱼ)` is one: the form carries over unchanged. Scaled
/// like [`alignment_information`] (the best-constrained translation gets `sigma_t`); `None`
/// when `h` carries no translation information.
pub fn odometry_information(h: &Mat6, sigma_t: f64) -> Option<Mat6> {
    alignment_information(&DAffine3::IDENTITY, h, sigma_t)
}

/// The largest eigenvalue of a symmetric positive semi-definite 3x3 matrix, by power
/// iteration from the diagonal's largest column (enough here: only the scale depends on it).
fn largest_eigenvalue(m: DMat3) -> f64 {
    let cols = [m.x_axis, m.y_axis, m.z_axis];
    let mut v = cols.iter().copied().fold(DVec3::ZERO, |a, c| if c.length() > a.length() { c } else { a });
    if v.length() == 0.0 {
        return 0.0;
    }
    for _ in 0..50 {
        let w = m * v;
        let len = w.length();
        if len == 0.0 {
            return 0.0;
        }
        v = w / len;
    }
    v.dot(m * v)
}

#[cfg(test)]
mod tests {
    use glam::{DAffine3, DMat3, DVec3};

    use super::*;
    use crate::pose_graph::{edge_error, rotation_exp};

    /// The quadratic form in the edge's terms equals the alignment's in its own, for a small
    /// perturbation of the measurement.
    #[test]
    fn the_information_carries_the_hessian_into_the_edge_error() {
        let z = DAffine3 { matrix3: rotation_exp(DVec3::new(0.2, -0.4, 0.3)), translation: DVec3::new(0.5, -0.2, 1.1) };
        // A Hessian with a weak direction (translation along x) and coupling.
        let mut h = [[0.0; 6]; 6];
        let rows: [[f64; 6]; 7] = [
            [0.1, 1.0, 0.0, 0.3, 0.0, 0.2],
            [0.0, 0.5, 1.0, 0.0, 0.4, 0.0],
            [0.05, 0.0, 0.8, 0.1, 0.0, 0.9],
            [0.0, 0.7, 0.2, 1.0, 0.0, 0.0],
            [0.02, 0.0, 0.0, 0.0, 1.0, 0.3],
            [0.0, 0.2, 0.3, 0.5, 0.2, 1.0],
            [0.3, 0.1, 0.1, 0.0, 0.0, 0.1],
        ];
        for j in rows {
            for a in 0..6 {
                for b in 0..6 {
                    h[a][b] += j[a] * j[b];
                }
            }
        }
        let info = alignment_information(&z, &h, 0.004).expect("information");
        let scale = 1.0
            / (0.004f64.powi(2)
                * largest_eigenvalue(DMat3::from_cols_array_2d(&[
                    [h[0][0], h[1][0], h[2][0]],
                    [h[0][1], h[1][1], h[2][1]],
                    [h[0][2], h[1][2], h[2][2]],
                ])));
        // Poses with Ti = I, Tj = Z' = exp(δ) Z: the edge error of measuring Z for them.
        let delta = [1e-4, -2e-4, 0.5e-4, 1e-4, 0.3e-4, -1e-4];
        let step = DAffine3 {
            matrix3: rotation_exp(DVec3::new(delta[3], delta[4], delta[5])),
            translation: DVec3::new(delta[0], delta[1], delta[2]),
        };
        let moved = step * z;
        let e = edge_error(&DAffine3::IDENTITY, &moved, &z);
        // The error of the measurement z against the truth `moved` is the alignment's
        // perturbation back: -δ, so both forms must agree.
        let q_edge: f64 = (0..6)
            .map(|a| (0..6).map(|b| e[a] * (info[a][b] - if a == b { 1.0 } else { 0.0 }) * e[b]).sum::<f64>())
            .sum();
        let q_align: f64 =
            scale * (0..6).map(|a| (0..6).map(|b| delta[a] * h[a][b] * delta[b]).sum::<f64>()).sum::<f64>();
        assert!((q_edge - q_align).abs() <= 1e-3 * q_align, "{q_edge} against {q_align}");
    }

    #[test]
    fn a_hessian_without_translation_information_gives_none() {
        let mut h = [[0.0; 6]; 6];
        h[4][4] = 1.0;
        assert!(alignment_information(&DAffine3::IDENTITY, &h, 0.004).is_none());
        h[0][0] = f64::NAN;
        assert!(alignment_information(&DAffine3::IDENTITY, &h, 0.004).is_none());
    }
}
