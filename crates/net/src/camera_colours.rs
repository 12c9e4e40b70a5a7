//! Colours as a consumer RGB-D camera records them, painted over a generated room.
//!
//! Generated rooms are lit evenly and their colours are the palette's, white-balanced and
//! well exposed. Real scans are not: the three ScanNet homes in `../shared/data` have a
//! median brightness (max channel) of 84-137 of 255 and a warm cast (mean red 97-131 against
//! blue 66-86, tungsten light and auto white balance), and every real map bakes its lighting
//! into the colours: bright by a window, dark under a table or in a corner. A network that
//! learnt "pale and even is wall" calls a dim wall door and a warm one sofa. This
//! augmentation draws, per sample, a white-balance cast (mostly warm), an exposure gain and a
//! gamma, a saturation change, and a slow multiplicative lighting field over space, so that
//! colour stops being a reliable cue on its own and geometry has to carry the label. The
//! labels are untouched.

use glam::Vec3;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use semrecon_data::LabeledPointCloud;

/// Spacing of the lighting field's control grid, metres: light varies over a room, not
/// over a chair.
const LIGHT_SPACING: f32 = 1.5;

/// One draw of the camera's colour response (see the module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct CameraColours {
    /// Per-channel gains (white balance), red and blue around green = 1.
    pub white_balance: [f32; 3],
    /// Exposure gain on linear-ish values.
    pub exposure: f32,
    /// Gamma applied to 0..1 values (`> 1` darkens mid-tones).
    pub gamma: f32,
    /// Saturation scale (`< 1` towards grey).
    pub saturation: f32,
    /// Amplitude of the lighting field (a factor in `[1 - a, 1 + a]`).
    pub light_amplitude: f32,
}

impl CameraColours {
    /// Draws a response: warm casts twice as often as cool ones, exposure 0.55-1.15,
    /// gamma 0.8-1.5, saturation 0.6-1.3, lighting amplitude 0-0.35.
    pub fn draw(rng: &mut ChaCha8Rng) -> Self {
        let warmth: f32 =
            if rng.random_bool(2.0 / 3.0) { rng.random_range(0.0..0.35) } else { rng.random_range(-0.15..0.0) };
        Self {
            white_balance: [1.0 + warmth, 1.0, 1.0 - warmth * 0.9],
            exposure: rng.random_range(0.55..1.15),
            gamma: rng.random_range(0.8..1.5),
            saturation: rng.random_range(0.6..1.3),
            light_amplitude: rng.random_range(0.0..0.35),
        }
    }

    /// The colour of one point under this response, with `light` the lighting factor there.
    pub fn apply_one(&self, c: [u8; 3], light: f32) -> [u8; 3] {
        let v: [f32; 3] = std::array::from_fn(|k| f32::from(c[k]) / 255.0);
        let grey = (v[0] + v[1] + v[2]) / 3.0;
        std::array::from_fn(|k| {
            let saturated = grey + (v[k] - grey) * self.saturation;
            let lit = (saturated * self.white_balance[k] * self.exposure * light).clamp(0.0, 1.0);
            (lit.powf(self.gamma) * 255.0).round().clamp(0.0, 255.0) as u8
        })
    }
}

/// Repaints `cloud` as a camera with a random response in a randomly lit room would record it.
pub fn apply_camera_colours(cloud: &mut LabeledPointCloud, rng: &mut ChaCha8Rng) {
    if cloud.is_empty() {
        return;
    }
    let response = CameraColours::draw(rng);
    let field = LightField::new(&cloud.positions, response.light_amplitude, rng);
    for (c, p) in cloud.colors.iter_mut().zip(&cloud.positions) {
        *c = response.apply_one(*c, field.factor(*p));
    }
}

/// A smooth random scalar field: trilinear interpolation of random values on a coarse grid.
struct LightField {
    lo: Vec3,
    dims: [usize; 3],
    values: Vec<f32>,
}

impl LightField {
    fn new(points: &[Vec3], amplitude: f32, rng: &mut ChaCha8Rng) -> Self {
        let (lo, hi) =
            points.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(l, h), p| (l.min(*p), h.max(*p)));
        let dims = ((hi - lo) / LIGHT_SPACING).to_array().map(|e| e.max(0.0).ceil() as usize + 2);
        let values = (0..dims[0] * dims[1] * dims[2])
            .map(|_| if amplitude > 0.0 { 1.0 + rng.random_range(-amplitude..=amplitude) } else { 1.0 })
            .collect();
        Self { lo, dims, values }
    }

    fn factor(&self, p: Vec3) -> f32 {
        let g = ((p - self.lo) / LIGHT_SPACING).max(Vec3::ZERO).to_array();
        let i: [usize; 3] = std::array::from_fn(|a| (g[a].floor() as usize).min(self.dims[a] - 2));
        let f: [f32; 3] = std::array::from_fn(|a| (g[a] - i[a] as f32).clamp(0.0, 1.0));
        let mut sum = 0.0;
        for corner in 0..8 {
            let mut w = 1.0;
            let mut idx = [0usize; 3];
            for a in 0..3 {
                let up = (corner >> a) & 1 == 1;
                idx[a] = i[a] + usize::from(up);
                w *= if up { f[a] } else { 1.0 - f[a] };
            }
            sum += w * self.values[(idx[2] * self.dims[1] + idx[1]) * self.dims[0] + idx[0]];
        }
        sum
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn identity_response_keeps_colours_and_labels_never_change() {
        let identity =
            CameraColours { white_balance: [1.0; 3], exposure: 1.0, gamma: 1.0, saturation: 1.0, light_amplitude: 0.0 };
        for c in [[0u8, 0, 0], [255, 255, 255], [12, 200, 90]] {
            assert_eq!(identity.apply_one(c, 1.0), c);
        }
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut cloud = LabeledPointCloud::default();
        for i in 0..500 {
            let t = i as f32 * 0.02;
            cloud.positions.push(Vec3::new(t, (t * 3.0).sin(), t * 0.3));
            cloud.colors.push([200, 180, 160]);
            cloud.labels.push((i % 13) as u8);
        }
        let labels = cloud.labels.clone();
        apply_camera_colours(&mut cloud, &mut rng);
        assert_eq!(cloud.labels, labels);
        assert!(cloud.colors.iter().any(|c| *c != [200, 180, 160]));
    }

    #[test]
    fn light_field_is_smooth_and_within_its_amplitude() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let pts: Vec<Vec3> = (0..100).map(|i| Vec3::new(i as f32 * 0.05, 0.0, 1.0)).collect();
        let field = LightField::new(&pts, 0.3, &mut rng);
        let mut last = field.factor(pts[0]);
        for p in &pts {
            let f = field.factor(*p);
            assert!((0.7 - 1e-5..=1.3 + 1e-5).contains(&f), "{f}");
            // 5 cm steps over a 1.5 m grid: at most 0.6 * 0.05 / 1.5 = 0.02 apart.
            assert!((f - last).abs() <= 0.021, "{f} {last}");
            last = f;
        }
    }
}
