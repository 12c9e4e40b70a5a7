//! Measuring a camera's radial depth bias from its frames: the largest plane of a frame, fitted
//! together with the bowl the bias bends it into, then a robust average over many frames.
//!
//! A plane's inverse depth is linear in the pixel coordinates (`1/z = a x + b y + c` for a
//! pinhole camera), and the bias is not: measured inverse depth is `p (1 - k ρ²)` to first
//! order, `p` the plane. So per frame: RANSAC finds the plane that holds the most sampled
//! pixels (points chosen by the plane's depth, not their own: a cut on measured depth drops
//! one side of the noise and bends the fit), then a least-squares fit of `(a, b, c, k)` on its
//! inliers away from the rim of their region (where a floor meets a wall or a box stands on
//! it, other surfaces pass through the band: session 40's estimates fell 5-10 % short with
//! them), refitted within three robust sigma. A frame counts only when its plane covers a
//! good part of the image and a spread of radii (a small patch cannot tell a bowl from a
//! tilt). Session 26 found single frames biased (+1.5 % on a far wall seen obliquely, for a
//! true +0.5 %), so the calibration is the median of the frames' estimates, and a camera whose
//! frames disagree beyond [`EstimateConfig::max_spread`] is refused: its depth error is not
//! one radial term (7-Scenes' frames swing by ±3 %), and a wrong correction is worse than none.
//!
//! Written here rather than taken from a crate: a four-parameter fit whose residual is in
//! inverse depth, with the bias's column built from the plane itself, is not a stock RANSAC
//! model.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::DepthCalibration;
use crate::{FrameSource, Result};

/// How frames are sampled and which estimates count.
#[derive(Debug, Clone, PartialEq)]
pub struct EstimateConfig {
    /// Every this many pixels along x and y is sampled.
    pub pixel_step: usize,
    /// Depths (of the plane) considered, metres: near the sensor's minimum range the noise
    /// model changes, far away the noise swamps a bias of a fraction of a percent.
    pub depth_range: (f64, f64),
    /// RANSAC: plane hypotheses per frame.
    pub hypotheses: usize,
    /// RANSAC: a pixel is on the plane within this relative inverse-depth difference (wide
    /// enough to keep the bowl, 0.5 % at the corners, with the noise).
    pub inlier_tolerance: f64,
    /// A frame counts when its plane holds at least this share of the valid samples.
    pub min_plane_fraction: f64,
    /// ... and its inliers' ρ² have at least this standard deviation.
    pub min_radius_spread: f64,
    /// ... and the fit's standard error of `k` is at most this.
    pub max_standard_error: f64,
    /// Fewest frames that must count.
    pub min_frames: usize,
    /// The frames' estimates may disagree by at most this robust spread (1.4826 × MAD).
    pub max_spread: f64,
    /// A pixel enters the fit only when every sampled pixel within this many samples of it
    /// is on the plane too (0: no such test): the rim of a plane's region is where other
    /// surfaces pass within the band (the floor where it meets a wall, a box's foot), and
    /// they sit mostly at large radii, where they pull the bowl flat.
    pub rim_samples: usize,
}

impl Default for EstimateConfig {
    fn default() -> Self {
        Self {
            pixel_step: 4,
            depth_range: (0.5, 3.5),
            hypotheses: 150,
            inlier_tolerance: 0.015,
            min_plane_fraction: 0.3,
            min_radius_spread: 0.08,
            max_standard_error: 0.001,
            min_frames: 5,
            max_spread: 0.002,
            rim_samples: 2,
        }
    }
}

/// One frame's estimate.
#[derive(Debug, Clone, PartialEq)]
pub struct PlaneEstimate {
    /// The frame's index.
    pub frame: usize,
    /// The radial coefficient `k` the frame's plane gives.
    pub radial: f64,
    /// Its standard error (from the fit's residuals).
    pub standard_error: f64,
    /// Share of the valid samples on the plane (its rim included).
    pub plane_fraction: f64,
    /// Standard deviation of the inliers' ρ².
    pub radius_spread: f64,
}

impl PlaneEstimate {
    /// Whether the estimate counts under `config`.
    pub fn counts(&self, config: &EstimateConfig) -> bool {
        self.plane_fraction >= config.min_plane_fraction
            && self.radius_spread >= config.min_radius_spread
            && self.standard_error <= config.max_standard_error
    }
}

/// A sampled pixel: normalised image coordinates (x, y over the half diagonal), ρ², and
/// measured inverse depth.
#[derive(Clone, Copy)]
struct Sample {
    x: f64,
    y: f64,
    rho2: f64,
    w: f64,
    /// Index in the grid of sampled pixels.
    cell: usize,
}

/// The largest plane of one depth image (metres, row-major, 0 = missing) and the radial
/// coefficient fitted with it; `None` when no plane holds enough pixels to fit.
pub fn estimate_frame(
    depth: &[f32],
    width: u32,
    height: u32,
    frame: usize,
    config: &EstimateConfig,
) -> Option<PlaneEstimate> {
    let (w, h) = (width as usize, height as usize);
    if depth.len() != w * h || w < 2 || h < 2 {
        return None;
    }
    let (cx, cy) = ((w as f64 - 1.0) * 0.5, (h as f64 - 1.0) * 0.5);
    let half_diagonal = (cx * cx + cy * cy).sqrt();
    let (near, far) = config.depth_range;
    let step = config.pixel_step.max(1);
    let (grid_w, grid_h) = (w.div_ceil(step), h.div_ceil(step));
    let mut samples = Vec::with_capacity(grid_w * grid_h);
    for (gy, py) in (0..h).step_by(step).enumerate() {
        for (gx, px) in (0..w).step_by(step).enumerate() {
            let d = depth[py * w + px] as f64;
            // Measured depth is only a loose gate here (the plane's depth decides below).
            if d.is_finite() && d > 0.5 * near && d < 1.5 * far {
                let (x, y) = ((px as f64 - cx) / half_diagonal, (py as f64 - cy) / half_diagonal);
                samples.push(Sample { x, y, rho2: x * x + y * y, w: 1.0 / d, cell: gy * grid_w + gx });
            }
        }
    }
    if samples.len() < 100 {
        return None;
    }
    let in_range = |p: f64| p > 1.0 / far && p < 1.0 / near;

    // RANSAC on the plane alone (the bowl is within the tolerance).
    let mut rng = ChaCha8Rng::seed_from_u64(0x5eed_0000 + frame as u64);
    let mut best: Option<([f64; 3], usize)> = None;
    for _ in 0..config.hypotheses {
        let picks = [0, 1, 2].map(|_| samples[rng.random_range(0..samples.len())]);
        let Some(plane) = plane_through(&picks) else { continue };
        let count = samples
            .iter()
            .filter(|s| {
                let p = plane[0] * s.x + plane[1] * s.y + plane[2];
                in_range(p) && (s.w - p).abs() <= config.inlier_tolerance * p
            })
            .count();
        if best.is_none_or(|(_, n)| count > n) {
            best = Some((plane, count));
        }
    }
    let (plane, _) = best?;

    // Least squares of (a, b, c, k): w = p - k ρ² p, the bias's column from the previous
    // plane; inliers first by the RANSAC tolerance, then within three robust sigma.
    let mut model = [plane[0], plane[1], plane[2], 0.0];
    let mut bound: Option<f64> = None;
    let mut fit = None;
    for _ in 0..4 {
        let predict = |m: &[f64; 4], s: &Sample| {
            let p = m[0] * s.x + m[1] * s.y + m[2];
            (p, p - m[3] * s.rho2 * p)
        };
        let on_plane: Vec<bool> = samples
            .iter()
            .map(|s| {
                let (p, q) = predict(&model, s);
                in_range(p)
                    && match bound {
                        None => (s.w - q).abs() <= config.inlier_tolerance * p,
                        Some(b) => (s.w - q).abs() <= b,
                    }
            })
            .collect();
        let on_count = on_plane.iter().filter(|&&o| o).count();
        let interior = interior_cells(&samples, &on_plane, grid_w, grid_h, config.rim_samples);
        let inliers: Vec<(Sample, f64)> = samples
            .iter()
            .zip(&on_plane)
            .filter(|&(s, &on)| on && interior[s.cell])
            .map(|(s, _)| (*s, predict(&model, s).0))
            .collect();
        if inliers.len() < 50 {
            return None;
        }
        let mut ata = [[0.0f64; 4]; 4];
        let mut atb = [0.0f64; 4];
        for (s, p) in &inliers {
            let row = [s.x, s.y, 1.0, -s.rho2 * p];
            for i in 0..4 {
                atb[i] += row[i] * s.w;
                for j in 0..4 {
                    ata[i][j] += row[i] * row[j];
                }
            }
        }
        let solution = solve4(ata, atb)?;
        let residuals: Vec<f64> = inliers
            .iter()
            .map(|(s, p)| s.w - (solution[0] * s.x + solution[1] * s.y + solution[2] - solution[3] * s.rho2 * p))
            .collect();
        let sigma = robust_sigma(&residuals).max(1e-12);
        bound = Some(3.0 * sigma);
        model = solution;
        // The variance of k: sigma² (AᵀA)⁻¹ at (3, 3), from a unit right-hand side.
        let unit_k = solve4(ata, [0.0, 0.0, 0.0, 1.0])?;
        let n = inliers.len() as f64;
        let mean_rho2 = inliers.iter().map(|(s, _)| s.rho2).sum::<f64>() / n;
        let var_rho2 = inliers.iter().map(|(s, _)| (s.rho2 - mean_rho2).powi(2)).sum::<f64>() / n;
        fit = Some(PlaneEstimate {
            frame,
            radial: solution[3],
            standard_error: sigma * unit_k[3].max(0.0).sqrt(),
            plane_fraction: on_count as f64 / samples.len() as f64,
            radius_spread: var_rho2.sqrt(),
        });
    }
    fit
}

/// Which cells of the `grid_w` x `grid_h` sample grid lie `radius` cells or more inside the
/// region of samples on the plane: a cell counts when every cell within `radius` (a square)
/// holds a sample on the plane. Two passes of running counts (rows, then columns), so the
/// cost does not grow with the radius.
fn interior_cells(samples: &[Sample], on_plane: &[bool], grid_w: usize, grid_h: usize, radius: usize) -> Vec<bool> {
    let mut on = vec![false; grid_w * grid_h];
    for (s, &o) in samples.iter().zip(on_plane) {
        on[s.cell] = o;
    }
    if radius == 0 {
        return on;
    }
    // A window of 2r + 1 cells along a line is full when every cell of it inside the image
    // is on: the image's border is no rim of the plane, and its corners carry most of the bowl.
    let full_along = |values: &[bool]| -> Vec<bool> {
        let n = values.len();
        let mut prefix = vec![0usize; n + 1];
        for (i, &v) in values.iter().enumerate() {
            prefix[i + 1] = prefix[i] + usize::from(v);
        }
        (0..n)
            .map(|i| {
                let (lo, hi) = (i.saturating_sub(radius), (i + radius + 1).min(n));
                prefix[hi] - prefix[lo] == hi - lo
            })
            .collect()
    };
    let mut rows = vec![false; grid_w * grid_h];
    for y in 0..grid_h {
        let line = full_along(&on[y * grid_w..(y + 1) * grid_w]);
        rows[y * grid_w..(y + 1) * grid_w].copy_from_slice(&line);
    }
    let mut out = vec![false; grid_w * grid_h];
    for x in 0..grid_w {
        let column: Vec<bool> = (0..grid_h).map(|y| rows[y * grid_w + x]).collect();
        for (y, full) in full_along(&column).into_iter().enumerate() {
            out[y * grid_w + x] = full;
        }
    }
    out
}

/// What [`calibrate`] found: the calibration, or why there is none, with every frame's
/// estimate.
#[derive(Debug, Clone)]
pub struct CalibrationOutcome {
    /// The calibration, or why the frames do not give one.
    pub calibration: std::result::Result<DepthCalibration, String>,
    /// Every frame's estimate, counted or not.
    pub estimates: Vec<PlaneEstimate>,
    /// The median of the counted estimates, or `None`.
    pub radial: Option<f64>,
    /// Robust spread of the counted estimates.
    pub spread: f64,
    /// Frames that counted.
    pub frames_used: usize,
}

/// Estimates `source`'s radial depth bias from every `every`-th frame of `frames`: the
/// calibration, or why the frames do not give one (too few planes, or estimates that
/// disagree: a depth error one radial term does not describe). Errors: a frame that cannot
/// be read.
pub fn calibrate(
    source: &dyn FrameSource,
    frames: std::ops::Range<usize>,
    every: usize,
    config: &EstimateConfig,
) -> Result<CalibrationOutcome> {
    let k = source.intrinsics();
    let indices: Vec<usize> = frames.step_by(every.max(1)).collect();
    let estimates: Vec<PlaneEstimate> = {
        use rayon::prelude::*;
        let per_frame: Vec<Result<Option<PlaneEstimate>>> = indices
            .par_iter()
            .map(|&i| {
                let frame = source.frame(i)?;
                Ok(estimate_frame(&frame.depth, frame.intrinsics.width, frame.intrinsics.height, i, config))
            })
            .collect();
        let mut out = Vec::new();
        for e in per_frame {
            out.extend(e?);
        }
        out
    };
    // Each frame weighs by its fit's precision (1 / standard error²): a plane that fills the
    // view face on measures the bowl three times better than a far wall seen obliquely, whose
    // estimates also run high (synth:1:noisy: +1.2-1.8 % at 0.10 % error against +0.37-0.49 %
    // at 0.03 %, for a true +0.5 %).
    let mut counted: Vec<(f64, f64)> = estimates
        .iter()
        .filter(|e| e.counts(config))
        .map(|e| (e.radial, 1.0 / e.standard_error.max(1e-6).powi(2)))
        .collect();
    let frames_used = counted.len();
    let radial = weighted_median(&mut counted);
    let spread = radial.map_or(0.0, |m| {
        let mut deviations: Vec<(f64, f64)> = counted.iter().map(|&(k, w)| ((k - m).abs(), w)).collect();
        1.4826 * weighted_median(&mut deviations).unwrap_or(0.0)
    });
    let calibration = if frames_used < config.min_frames {
        Err(format!(
            "{frames_used} of {} frames show a plane large enough to measure the depth bias on \
             (at least {} needed): scan a wall or floor face on",
            indices.len(),
            config.min_frames
        ))
    } else if spread > config.max_spread {
        Err(format!(
            "the frames' estimates disagree (median {:+.3} %, spread {:.3} % over {frames_used} frames, \
             at most {:.3} % allowed): this camera's depth error is not one radial term",
            100.0 * radial.unwrap_or(0.0),
            100.0 * spread,
            100.0 * config.max_spread
        ))
    } else {
        Ok(DepthCalibration::new(radial.unwrap_or(0.0), k.width, k.height, source.name(), frames_used, spread))
    };
    Ok(CalibrationOutcome { calibration, estimates, radial, spread, frames_used })
}

/// The median of `values` (sorted in place), `None` when empty.
fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    Some(if n % 2 == 1 { values[n / 2] } else { 0.5 * (values[n / 2 - 1] + values[n / 2]) })
}

/// The weighted median of `(value, weight)` pairs (sorted in place): the smallest value whose
/// cumulative weight reaches half the total; `None` when empty.
fn weighted_median(values: &mut [(f64, f64)]) -> Option<f64> {
    values.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = values.iter().map(|v| v.1).sum();
    let mut cumulative = 0.0;
    for &(value, weight) in values.iter() {
        cumulative += weight;
        if cumulative >= 0.5 * total {
            return Some(value);
        }
    }
    values.last().map(|v| v.0)
}

/// 1.4826 × the median absolute value: a standard deviation that ignores outliers.
fn robust_sigma(residuals: &[f64]) -> f64 {
    let mut abs: Vec<f64> = residuals.iter().map(|r| r.abs()).collect();
    1.4826 * median(&mut abs).unwrap_or(0.0)
}

/// The plane `w = a x + b y + c` through three samples; `None` when they are (nearly) on a line.
fn plane_through(s: &[Sample; 3]) -> Option<[f64; 3]> {
    let (u1, v1) = (s[1].x - s[0].x, s[1].y - s[0].y);
    let (u2, v2) = (s[2].x - s[0].x, s[2].y - s[0].y);
    let det = u1 * v2 - u2 * v1;
    // Twice the triangle's area in normalised coordinates: under about 0.1 % of the image.
    if det.abs() < 1e-3 {
        return None;
    }
    let (w1, w2) = (s[1].w - s[0].w, s[2].w - s[0].w);
    let a = (w1 * v2 - w2 * v1) / det;
    let b = (u1 * w2 - u2 * w1) / det;
    Some([a, b, s[0].w - a * s[0].x - b * s[0].y])
}

/// Solves the symmetric 4x4 system `m x = r` by Gaussian elimination with partial pivoting;
/// `None` when it is singular. (Four unknowns: a dense solver crate would be more code to call.)
fn solve4(mut m: [[f64; 4]; 4], mut r: [f64; 4]) -> Option<[f64; 4]> {
    let scale = m.iter().flatten().fold(0.0f64, |a, v| a.max(v.abs()));
    if scale == 0.0 || !scale.is_finite() {
        return None;
    }
    for col in 0..4 {
        let pivot = (col..4).max_by(|&a, &b| m[a][col].abs().total_cmp(&m[b][col].abs()))?;
        if m[pivot][col].abs() <= 1e-14 * scale {
            return None;
        }
        m.swap(col, pivot);
        r.swap(col, pivot);
        for row in col + 1..4 {
            let f = m[row][col] / m[col][col];
            let pivot_row = m[col];
            for (value, above) in m[row].iter_mut().zip(pivot_row).skip(col) {
                *value -= f * above;
            }
            r[row] -= f * r[col];
        }
    }
    let mut x = [0.0; 4];
    for row in (0..4).rev() {
        let s: f64 = (row + 1..4).map(|k| m[row][k] * x[k]).sum();
        x[row] = (r[row] - s) / m[row][row];
    }
    Some(x)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand_distr::{Distribution, Normal};

    /// A 160x120 depth image whose true depth at pixel (x, y) is `scene(x, y, ray)` (`ray` the
    /// pixel's ray at z = 1), seen through a bias of `radial` and relative noise `noise`.
    fn rendered(radial: f64, noise: f64, seed: u64, scene: impl Fn(usize, usize, [f64; 3]) -> f64) -> Vec<f32> {
        let (w, h) = (160usize, 120usize);
        let (fx, cx, cy) = (140.0, 79.5, 59.5);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let gauss = Normal::new(0.0, 1.0).expect("a valid distribution");
        let mut depth = vec![0.0f32; w * h];
        for y in 0..h {
            for x in 0..w {
                let z = scene(x, y, [(x as f64 - cx) / fx, (y as f64 - cy) / fx, 1.0]);
                let factor = DepthCalibration::factor(radial, x, y, w as u32, h as u32);
                depth[y * w + x] = (z * factor * (1.0 + noise * gauss.sample(&mut rng))) as f32;
            }
        }
        depth
    }

    /// A wall (plane `n·X = 2` in the camera frame) with a box in front covering part of it.
    fn wall(radial: f64, noise: f64, tilt: f64, seed: u64) -> Vec<f32> {
        let n = [tilt.sin(), 0.2 * tilt.cos(), tilt.cos()];
        rendered(radial, noise, seed, |x, y, ray| {
            if (60..100).contains(&x) && (70..110).contains(&y) {
                1.2 // the box
            } else {
                2.0 / (n[0] * ray[0] + n[1] * ray[1] + n[2] * ray[2])
            }
        })
    }

    #[test]
    fn a_walls_bowl_gives_the_radial_coefficient() {
        let config = EstimateConfig { pixel_step: 2, ..EstimateConfig::default() };
        for (radial, tilt) in [(0.005, 0.0), (0.005, 0.5), (-0.004, 0.3), (0.0, 0.2), (0.01, -0.6)] {
            let depth = wall(radial, 0.002, tilt, 7);
            let e = estimate_frame(&depth, 160, 120, 0, &config).expect("a plane");
            assert!(e.counts(&config), "{e:?}");
            assert!((e.radial - radial).abs() < 0.0006, "true {radial}, tilt {tilt}: {e:?}");
            assert!(e.standard_error < 0.0006, "{e:?}");
        }
    }

    #[test]
    fn a_frame_without_a_plane_gives_nothing_that_counts() {
        // Depth that is no plane: a random scatter.
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let depth: Vec<f32> = (0..160 * 120).map(|_| rng.random_range(0.6..3.0)).collect();
        let config = EstimateConfig::default();
        assert!(estimate_frame(&depth, 160, 120, 0, &config).is_none_or(|e| !e.counts(&config)));
        assert!(estimate_frame(&[], 0, 0, 0, &config).is_none());
        assert!(estimate_frame(&vec![0.0; 160 * 120], 160, 120, 0, &config).is_none());
    }

    /// A wall 2 m ahead, face on, and the floor 0.5 m below the camera meeting it in the
    /// image's lower quarter.
    fn wall_and_floor(radial: f64, noise: f64, seed: u64) -> Vec<f32> {
        rendered(radial, noise, seed, |_, _, ray| if ray[1] > 0.0 { (0.5 / ray[1]).min(2.0) } else { 2.0 })
    }

    #[test]
    fn a_wall_meeting_the_floor_gives_the_radial_coefficient() {
        // Two surfaces crossing in the image: the floor's last centimetres before the wall lie
        // within the band of the wall's plane, along the wall's foot.
        let config = EstimateConfig { pixel_step: 2, ..EstimateConfig::default() };
        let mut mean = 0.0;
        for seed in 0..4 {
            let depth = wall_and_floor(0.005, 0.004, seed);
            let e = estimate_frame(&depth, 160, 120, 0, &config).expect("a plane");
            assert!(e.counts(&config), "{e:?}");
            mean += e.radial / 4.0;
        }
        assert!((mean - 0.005).abs() < 0.0003, "{mean}");
    }

    #[test]
    fn interior_cells_leave_out_the_rim_but_not_the_image_border() {
        // A 6x5 grid whose right two columns are off the plane.
        let (gw, gh) = (6, 5);
        let samples: Vec<Sample> =
            (0..gw * gh).map(|cell| Sample { x: 0.0, y: 0.0, rho2: 0.0, w: 1.0, cell }).collect();
        let on: Vec<bool> = (0..gw * gh).map(|c| c % gw < 4).collect();
        let interior = interior_cells(&samples, &on, gw, gh, 1);
        for y in 0..gh {
            let row: Vec<bool> = (0..gw).map(|x| interior[y * gw + x]).collect();
            // Columns 0-2 are interior (the image's left border is no rim), 3 touches the
            // off columns, 4-5 are off.
            assert_eq!(row, [true, true, true, false, false, false], "row {y}");
        }
        assert_eq!(interior_cells(&samples, &on, gw, gh, 0), on);
    }

    #[test]
    fn the_weighted_median_follows_the_weights() {
        assert_eq!(weighted_median(&mut []), None);
        assert_eq!(weighted_median(&mut [(3.0, 1.0), (1.0, 1.0), (2.0, 1.0)]), Some(2.0));
        assert_eq!(weighted_median(&mut [(3.0, 10.0), (1.0, 1.0), (2.0, 1.0)]), Some(3.0));
        assert_eq!(weighted_median(&mut [(5.0, 1.0), (0.4, 9.0), (0.5, 9.0)]), Some(0.5));
    }

    #[test]
    fn the_solver_matches_a_known_system() {
        let m = [[4.0, 1.0, 0.5, 0.2], [1.0, 3.0, 0.3, 0.1], [0.5, 0.3, 2.0, 0.4], [0.2, 0.1, 0.4, 1.5]];
        let x = [1.0, -2.0, 0.5, 3.0];
        let r: [f64; 4] = std::array::from_fn(|i| (0..4).map(|j| m[i][j] * x[j]).sum());
        let got = solve4(m, r).expect("a regular system");
        for i in 0..4 {
            assert!((got[i] - x[i]).abs() < 1e-12);
        }
        assert!(solve4([[0.0; 4]; 4], [1.0; 4]).is_none());
    }
}
