//! A depth-sensor model applied to rendered frames, so that synthetic scans carry the
//! errors a structured-light camera (Kinect v1, PrimeSense, Structure Sensor) makes and
//! tracking and fusion are tested on realistic input rather than perfect depth.
//!
//! Modelled, after Nguyen, Izadi and Lovell (3DIMPVT 2012) and Khoshelham and Oude Elberink
//! (Sensors 2012): axial noise whose standard deviation grows with the square of the
//! distance, lateral jitter of a fraction of a pixel, quantisation in disparity (steps that
//! grow with z^2), missing depth where the surface is seen at a grazing angle and along
//! depth discontinuities (the projector's pattern is shadowed or smeared there), a working
//! range, and colour noise. Every random draw comes from a generator seeded by
//! (seed, frame index, image row), so the result is the same for any thread count and any
//! order of frames.

use rand::{Rng, RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::render::RenderOutput;

/// Axial (along the ray) depth noise: `sigma(z) = base + quadratic * (z - offset)^2` metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AxialNoise {
    /// Standard deviation at `z = offset`, metres.
    pub base: f32,
    /// Growth with the squared distance from `offset`, 1/metre.
    pub quadratic: f32,
    /// Distance of the smallest noise, metres.
    pub offset: f32,
}

impl AxialNoise {
    /// Standard deviation in metres at depth `z`.
    pub fn sigma(&self, z: f32) -> f32 {
        self.base + self.quadratic * (z - self.offset) * (z - self.offset)
    }
}

/// How measured depths are rounded.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Quantization {
    /// Depth kept as a float.
    None,
    /// Depth rounded to multiples of `metres` (a 16-bit millimetre image: 0.001).
    Step {
        /// Step in metres.
        metres: f32,
    },
    /// Structured light: disparity `d = focal_px * baseline_m / z` is rounded to
    /// `1 / subpixel` pixel, so depth steps are `z^2 / (focal_px * baseline_m * subpixel)`.
    Disparity {
        /// Focal length of the infrared camera, pixels.
        focal_px: f32,
        /// Projector-camera baseline, metres.
        baseline_m: f32,
        /// Disparity sub-pixel resolution (8 for the Kinect v1).
        subpixel: f32,
    },
}

/// Depth lost where the surface is seen at a grazing angle.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GrazingDropout {
    /// Incidence cosine below which depth is always missing.
    pub cos_missing: f32,
    /// Incidence cosine above which depth is always kept; in between, the chance of a
    /// missing pixel falls linearly.
    pub cos_kept: f32,
}

/// Depth lost next to depth discontinuities.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EdgeDropout {
    /// A 4-neighbour farther than `relative_jump * z` in depth (or without depth) marks an
    /// edge pixel.
    pub relative_jump: f32,
    /// Chance that an edge pixel loses its depth.
    pub probability: f32,
}

/// A systematic depth error of an uncalibrated sensor: every measured depth is multiplied by
/// `scale * (1 + radial * r^2)`, `r` the distance of the pixel from the image centre over
/// the half diagonal (1 in the corners). Structured-light cameras have both: a depth scale off
/// by up to a percent or two and a low-frequency bias that bends a flat wall into a shallow
/// bowl, largest towards the corners (Smisek, Jancosek and Pajdla 2011; Herrera, Kannala and
/// Heikkila 2012). Unlike the noise it is the same in every frame, so it does not average
/// out: each view sees the scene slightly differently bent, and the tracker drifts.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DepthBias {
    /// Factor on every depth (1 = exact).
    pub scale: f32,
    /// Relative depth error in the image corners (0 = none; positive: farther).
    pub radial: f32,
}

/// Depth-sensor model: configuration of the errors added to a rendered frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SensorModel {
    /// Seed of the noise; frames are seeded by (seed, frame index).
    pub seed: u64,
    /// Working range `(min, max)` in metres: depth outside is missing; `None` = unlimited.
    pub range: Option<(f32, f32)>,
    /// Axial depth noise; `None` = none.
    pub axial_noise: Option<AxialNoise>,
    /// Standard deviation of the lateral jitter in pixels (each pixel reads the depth of a
    /// neighbour offset by the rounded jitter); 0 = none.
    pub lateral_sigma_px: f32,
    /// Depth quantisation.
    pub quantization: Quantization,
    /// Missing depth at grazing angles; `None` = never.
    pub grazing_dropout: Option<GrazingDropout>,
    /// Missing depth at discontinuities; `None` = never.
    pub edge_dropout: Option<EdgeDropout>,
    /// Standard deviation of the colour noise per channel, in 0..255 units; 0 = none.
    pub color_sigma: f32,
    /// Systematic depth error (calibration); `None` = none.
    #[serde(default)]
    pub depth_bias: Option<DepthBias>,
}

impl Default for SensorModel {
    fn default() -> Self {
        Self::kinect()
    }
}

impl SensorModel {
    /// A Kinect v1-like sensor: range 0.4-4.5 m, `sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2`,
    /// 0.4 px lateral jitter, 1/8-pixel disparity steps (f = 580 px, baseline 7.5 cm),
    /// depth missing below 80 degrees of incidence and often between 70 and 80, and at half
    /// of the discontinuity pixels; colour noise of 2 levels.
    pub fn kinect() -> Self {
        Self {
            seed: 0,
            range: Some((0.4, 4.5)),
            axial_noise: Some(AxialNoise { base: 0.0012, quadratic: 0.0019, offset: 0.4 }),
            lateral_sigma_px: 0.4,
            quantization: Quantization::Disparity { focal_px: 580.0, baseline_m: 0.075, subpixel: 8.0 },
            grazing_dropout: Some(GrazingDropout { cos_missing: 0.17, cos_kept: 0.34 }),
            edge_dropout: Some(EdgeDropout { relative_jump: 0.05, probability: 0.5 }),
            color_sigma: 2.0,
            depth_bias: None,
        }
    }

    /// The Kinect-like sensor uncalibrated and noisier, so that frame-to-model tracking
    /// drifts as it does on real scans (a few centimetres a minute) rather than by
    /// millimetres: [`SensorModel::kinect`] with 1.5 times the axial noise and a radial depth
    /// bias of 0.5 % in the image corners ([`DepthBias`]). Zero-mean noise averages out in the
    /// map; a bias that depends on where in the image a surface is seen does not, and bends
    /// each view differently, which is what makes the tracker drift (the depth scale stays
    /// exact: a scale error changes the size of the map, not its consistency, and loop
    /// closure could not correct it).
    pub fn kinect_uncalibrated() -> Self {
        let mut model = Self::kinect();
        model.axial_noise =
            model.axial_noise.map(|a| AxialNoise { base: a.base * 1.5, quadratic: a.quadratic * 1.5, ..a });
        model.depth_bias = Some(DepthBias { scale: 1.0, radial: 0.005 });
        model
    }

    /// A perfect sensor: [`SensorModel::apply`] changes nothing.
    pub fn ideal() -> Self {
        Self {
            seed: 0,
            range: None,
            axial_noise: None,
            lateral_sigma_px: 0.0,
            quantization: Quantization::None,
            grazing_dropout: None,
            edge_dropout: None,
            color_sigma: 0.0,
            depth_bias: None,
        }
    }

    /// The same model with another seed.
    pub fn with_seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }

    /// Adds the sensor's errors to `out` (depth and colour; labels and incidence stay the
    /// rendered truth). Deterministic in (`self.seed`, `frame_index`).
    pub fn apply(&self, out: &mut RenderOutput, frame_index: usize) {
        let w = out.width as usize;
        let h = out.height as usize;
        if w == 0 || h == 0 || out.depth.len() != w * h {
            return;
        }
        let clean = out.depth.clone();
        let clean = &clean;
        let incidence = &out.incidence;
        let lateral = LateralTable::new(self.lateral_sigma_px);
        let lateral = &lateral;
        // Colour noise by table: the rounded offset for each Irwin-Hall sum of three 7-bit
        // uniforms (mean 190.5, standard deviation 64), an approximate normal bounded at
        // +-3 sigma, which is fine for colour.
        let color_noise: Option<Vec<i16>> = (self.color_sigma > 0.0).then(|| {
            (0..382)
                .map(|sum| ((sum as f32 - 190.5) / 64.0 * self.color_sigma).round().clamp(-255.0, 255.0) as i16)
                .collect()
        });
        let color_noise = &color_noise;
        // The bias's factor at (x, y), from the image centre's squared distance.
        let (cx, cy) = ((w as f32 - 1.0) * 0.5, (h as f32 - 1.0) * 0.5);
        let corner_sq = (cx * cx + cy * cy).max(1.0);
        let bias = |x: usize, y: usize| match self.depth_bias {
            Some(b) => {
                let (dx, dy) = (x as f32 - cx, y as f32 - cy);
                b.scale * (1.0 + b.radial * (dx * dx + dy * dy) / corner_sq)
            }
            None => 1.0,
        };
        out.depth.par_chunks_mut(w).zip(out.color.par_chunks_mut(w)).enumerate().for_each(|(y, (depth, color))| {
            let mut rng = PixelNoise::new(row_seed(self.seed, frame_index as u64, y as u64));
            let image = Image { depth: clean, incidence, w, h };
            for x in 0..w {
                depth[x] = self.measure(&image, lateral, x, y, &mut rng) * bias(x, y);
                if let Some(table) = &color_noise {
                    // One draw for the three channels, 21 bits each.
                    let bits = rng.next_u64();
                    for (ch, c) in color[x].iter_mut().enumerate() {
                        let b = bits >> (21 * ch);
                        let sum = (b & 0x7F) + ((b >> 7) & 0x7F) + ((b >> 14) & 0x7F);
                        *c = (i32::from(*c) + i32::from(table[sum as usize])).clamp(0, 255) as u8;
                    }
                }
            }
        });
    }

    /// The measured depth of pixel (x, y) given the clean depth image.
    fn measure(&self, image: &Image, lateral: &LateralTable, x: usize, y: usize, rng: &mut PixelNoise) -> f32 {
        let (w, h, clean) = (image.w, image.h, image.depth);
        // One draw, four 16-bit uniforms: lateral x and y, edge and grazing dropout.
        let bits = rng.next_u64();
        let uniform = |k: u32| ((bits >> (16 * k)) & 0xFFFF) as f32 * (1.0 / 65536.0);
        let (mut sx, mut sy) = (x, y);
        if self.lateral_sigma_px > 0.0 {
            sx = x.saturating_add_signed(lateral.offset(bits as u16)).min(w - 1);
            sy = y.saturating_add_signed(lateral.offset((bits >> 16) as u16)).min(h - 1);
        }
        let i = sy * w + sx;
        let mut z = clean[i];
        if z <= 0.0 {
            return 0.0;
        }
        let (u_edge, u_grazing) = (uniform(2), uniform(3));
        if let Some(e) = self.edge_dropout {
            let jump = e.relative_jump * z;
            let differs = |j: usize| clean[j] <= 0.0 || (clean[j] - z).abs() > jump;
            let edge = (sx > 0 && differs(i - 1))
                || (sx + 1 < w && differs(i + 1))
                || (sy > 0 && differs(i - w))
                || (sy + 1 < h && differs(i + w));
            if edge && u_edge < e.probability {
                return 0.0;
            }
        }
        if let Some(g) = self.grazing_dropout {
            let c = image.incidence.get(i).copied().unwrap_or(1.0);
            if c < g.cos_missing {
                return 0.0;
            }
            if c < g.cos_kept && u_grazing < (g.cos_kept - c) / (g.cos_kept - g.cos_missing) {
                return 0.0;
            }
        }
        if let Some(a) = self.axial_noise {
            let n: f32 = rng.sample(StandardNormal);
            z += n * a.sigma(z);
        }
        z = match self.quantization {
            Quantization::None => z,
            Quantization::Step { metres } if metres > 0.0 => round_half_up(z / metres) * metres,
            Quantization::Step { .. } => z,
            Quantization::Disparity { focal_px, baseline_m, subpixel } => {
                let fb = focal_px * baseline_m;
                let d = round_half_up(fb / z * subpixel) / subpixel;
                if d > 0.0 {
                    fb / d
                } else {
                    0.0
                }
            }
        };
        if let Some((lo, hi)) = self.range {
            if !(z >= lo && z <= hi) {
                return 0.0;
            }
        }
        if z.is_finite() && z > 0.0 {
            z
        } else {
            0.0
        }
    }
}

/// SplitMix64: the per-pixel random stream of one image row, seeded from ChaCha8 by
/// [`row_seed`]. Drawing every pixel's bits from ChaCha itself would cost more than the
/// rest of the model; noise only needs well-mixed, reproducible bits.
struct PixelNoise {
    state: u64,
}

impl PixelNoise {
    fn new(seed: u64) -> Self {
        Self { state: seed }
    }
}

impl RngCore for PixelNoise {
    #[inline]
    fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    #[inline]
    fn next_u32(&mut self) -> u32 {
        (self.next_u64() >> 32) as u32
    }

    fn fill_bytes(&mut self, dst: &mut [u8]) {
        for chunk in dst.chunks_mut(8) {
            let bytes = self.next_u64().to_le_bytes();
            chunk.copy_from_slice(&bytes[..chunk.len()]);
        }
    }
}

/// The clean rendered images a sensor reads from.
struct Image<'a> {
    depth: &'a [f32],
    incidence: &'a [f32],
    w: usize,
    h: usize,
}

/// Rounding of a non-negative value by a cast (`f32::round` is a libm call on baseline
/// x86-64); saturates for huge values.
#[inline]
fn round_half_up(v: f32) -> f32 {
    (v + 0.5) as u32 as f32
}

/// Lateral jitter as whole-pixel offsets: the normal N(0, sigma) rounded, drawn from a
/// 16-bit uniform by inverting its cumulative distribution.
struct LateralTable {
    /// `thresholds[k]` = P(offset <= k - 3) scaled to 65536, for offsets -3..=2.
    thresholds: [u32; 6],
    /// No jitter at all.
    off: bool,
}

impl LateralTable {
    fn new(sigma: f32) -> Self {
        let mut thresholds = [0u32; 6];
        for (k, t) in thresholds.iter_mut().enumerate() {
            let p = if sigma > 0.0 { normal_cdf((k as f64 - 3.0 + 0.5) / sigma as f64) } else { 0.0 };
            *t = (p * 65536.0) as u32;
        }
        Self { thresholds, off: sigma <= 0.0 }
    }

    #[inline]
    fn offset(&self, u: u16) -> isize {
        let u = u as u32;
        // Most pixels stay: test the middle interval first.
        if self.off || (u >= self.thresholds[2] && u < self.thresholds[3]) {
            return 0;
        }
        self.thresholds.iter().map(|&t| isize::from(u >= t)).sum::<isize>() - 3
    }
}

/// Standard normal cumulative distribution (Abramowitz and Stegun 7.1.26, error < 1.5e-7).
fn normal_cdf(x: f64) -> f64 {
    let z = x.abs() / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.3275911 * z);
    let poly = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429))));
    let erf = 1.0 - poly * (-z * z).exp();
    if x >= 0.0 {
        0.5 * (1.0 + erf)
    } else {
        0.5 * (1.0 - erf)
    }
}

/// Seed of one image row's noise: word `2 * row` of the ChaCha8 stream `frame` of `seed`
/// (random access, so rows can be processed in any order).
fn row_seed(seed: u64, frame: u64, row: u64) -> u64 {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(frame);
    rng.set_word_pos(2 * row as u128);
    rng.next_u64()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(w: u32, h: u32, z: f32, cos: f32) -> RenderOutput {
        let n = (w * h) as usize;
        RenderOutput {
            width: w,
            height: h,
            depth: vec![z; n],
            color: vec![[100, 150, 200]; n],
            labels: vec![2; n],
            incidence: vec![cos; n],
        }
    }

    #[test]
    fn depth_bias_bends_a_flat_wall_into_a_bowl() {
        let model = SensorModel { depth_bias: Some(DepthBias { scale: 1.01, radial: 0.02 }), ..SensorModel::ideal() };
        let mut out = flat(65, 49, 2.0, 1.0);
        model.apply(&mut out, 0);
        let at = |x: usize, y: usize| out.depth[y * 65 + x];
        assert!((at(32, 24) - 2.02).abs() < 1e-5, "centre {}", at(32, 24));
        assert!((at(0, 0) - 2.02 * 1.02).abs() < 1e-4, "corner {}", at(0, 0));
        assert!(at(16, 24) > at(32, 24) && at(16, 24) < at(0, 24));
        // The uncalibrated sensor differs from the calibrated one, deterministically.
        let mut a = flat(64, 48, 2.0, 0.9);
        let mut b = a.clone();
        let mut c = a.clone();
        SensorModel::kinect_uncalibrated().apply(&mut a, 2);
        SensorModel::kinect_uncalibrated().apply(&mut b, 2);
        SensorModel::kinect().apply(&mut c, 2);
        assert_eq!(a, b);
        assert_ne!(a.depth, c.depth);
    }

    #[test]
    fn ideal_sensor_changes_nothing() {
        let mut out = flat(16, 8, 2.0, 0.05);
        out.depth[5] = 0.0;
        let before = out.clone();
        SensorModel::ideal().apply(&mut out, 3);
        assert_eq!(out, before);
    }

    #[test]
    fn kinect_noise_is_deterministic_per_seed_and_frame() {
        let model = SensorModel::kinect().with_seed(9);
        let mut a = flat(64, 48, 2.0, 0.9);
        let mut b = a.clone();
        let mut c = a.clone();
        model.apply(&mut a, 4);
        model.apply(&mut b, 4);
        model.apply(&mut c, 5);
        assert_eq!(a, b);
        assert_ne!(a.depth, c.depth);
    }

    #[test]
    fn noise_is_the_same_for_any_thread_count() {
        let mut clean = flat(64, 48, 2.0, 0.3);
        for (i, d) in clean.depth.iter_mut().enumerate() {
            *d += (i % 7) as f32 * 0.2;
        }
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            let mut out = clean.clone();
            pool.install(|| SensorModel::kinect().apply(&mut out, 7));
            out
        };
        assert_eq!(run(1), run(3));
    }

    #[test]
    fn axial_noise_has_the_configured_spread() {
        let model = SensorModel {
            axial_noise: Some(AxialNoise { base: 0.0012, quadratic: 0.0019, offset: 0.4 }),
            ..SensorModel::ideal()
        };
        let z = 3.0;
        let mut out = flat(200, 100, z, 1.0);
        model.apply(&mut out, 0);
        let n = out.depth.len() as f32;
        let mean = out.depth.iter().sum::<f32>() / n;
        let std = (out.depth.iter().map(|d| (d - mean) * (d - mean)).sum::<f32>() / n).sqrt();
        let expected = 0.0012 + 0.0019 * (z - 0.4) * (z - 0.4);
        assert!((mean - z).abs() < 0.001, "mean {mean}");
        assert!((std / expected - 1.0).abs() < 0.05, "std {std}, expected {expected}");
    }

    #[test]
    fn disparity_quantisation_steps_grow_with_distance() {
        let model = SensorModel { quantization: SensorModel::kinect().quantization, ..SensorModel::ideal() };
        let levels = |z0: f32| {
            let mut out = flat(100, 1, z0, 1.0);
            for (i, d) in out.depth.iter_mut().enumerate() {
                *d = z0 + i as f32 * 0.0005;
            }
            model.apply(&mut out, 0);
            let mut v: Vec<u32> = out.depth.iter().map(|d| d.to_bits()).collect();
            v.dedup();
            v.len()
        };
        // 5 cm of depth: many steps at 1 m, few at 4 m.
        assert!(levels(1.0) > 3 * levels(4.0), "{} vs {}", levels(1.0), levels(4.0));
    }

    #[test]
    fn range_grazing_and_edges_remove_depth() {
        let model = SensorModel::kinect();
        let mut far = flat(32, 8, 5.0, 1.0);
        model.apply(&mut far, 0);
        assert!(far.depth.iter().all(|&d| d == 0.0), "beyond the range");
        let mut grazing = flat(32, 8, 2.0, 0.1);
        model.apply(&mut grazing, 0);
        assert!(grazing.depth.iter().all(|&d| d == 0.0), "grazing");
        // A step from 1 m to 2 m at column 16: about half of the pixels next to it vanish.
        let model = SensorModel { edge_dropout: SensorModel::kinect().edge_dropout, ..SensorModel::ideal() };
        let mut step = flat(32, 200, 1.0, 1.0);
        for row in step.depth.chunks_mut(32) {
            row[16..].fill(2.0);
        }
        model.apply(&mut step, 0);
        let missing_at_edge = step.depth.chunks(32).filter(|r| r[15] == 0.0).count();
        let missing_inside = step.depth.chunks(32).filter(|r| r[8] == 0.0).count();
        assert!((60..140).contains(&missing_at_edge), "{missing_at_edge} of 200 edge pixels missing");
        assert_eq!(missing_inside, 0);
    }

    #[test]
    fn lateral_jitter_moves_about_the_expected_share_of_pixels() {
        let table = LateralTable::new(0.4);
        let mut rng = PixelNoise::new(1);
        let n = 100_000;
        let moved = (0..n).filter(|_| table.offset(rng.next_u32() as u16) != 0).count() as f64 / n as f64;
        // P(|N(0, 0.4)| > 0.5) = 2 (1 - Phi(1.25)) = 0.211.
        assert!((moved - 0.211).abs() < 0.01, "{moved}");
        assert_eq!(LateralTable::new(0.0).offset(u16::MAX), 0);
        assert_eq!(LateralTable::new(0.0).offset(0), 0);
    }

    #[test]
    fn colour_noise_has_the_configured_spread() {
        let model = SensorModel { color_sigma: 3.0, ..SensorModel::ideal() };
        let mut out = flat(200, 100, 2.0, 1.0);
        model.apply(&mut out, 0);
        for ch in 0..3 {
            let v: Vec<f32> = out.color.iter().map(|c| c[ch] as f32).collect();
            let mean = v.iter().sum::<f32>() / v.len() as f32;
            let std = (v.iter().map(|x| (x - mean) * (x - mean)).sum::<f32>() / v.len() as f32).sqrt();
            let base = [100.0, 150.0, 200.0][ch];
            assert!((mean - base).abs() < 0.1, "channel {ch} mean {mean}");
            // Rounding to integers adds 1/12 of variance.
            assert!((std - (9.0f32 + 1.0 / 12.0).sqrt()).abs() < 0.1, "channel {ch} std {std}");
        }
    }

    #[test]
    fn config_round_trips_through_json() {
        let model = SensorModel::kinect().with_seed(5);
        let json = serde_json::to_string(&model).expect("serialise");
        let back: SensorModel = serde_json::from_str(&json).expect("parse");
        assert_eq!(back, model);
    }
}
