//! The map's parameters ([`TsdfConfig`]) and the sensor noise model the fusion band follows:
//! what a caller sets, with the ranges [`TsdfConfig::validate`] enforces, and the derived
//! quantities (band per depth, colour band, the packed distances' coding) that fusion, meshing
//! and packing read.

use super::{compressed, CHUNK_SIDE, TSDF_SCALE, WEIGHT_SCALE};
use crate::error::{ReconError, Result};

/// Parameters of the map and of fusion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TsdfConfig {
    /// Voxel edge length in metres (2 mm to 5 cm).
    pub voxel_size: f32,
    /// Truncation distance in voxels (at least 1; about 4 is usual): the widest band, and the
    /// unit of the stored distances. With a depth-dependent band (below) it is the band far
    /// away, where the sensor noise is largest.
    pub truncation_voxels: f32,
    /// Depth-dependent band: at measured depth `z` the band is
    /// `clamp(truncation_noise_factor * sigma(z) / voxel_size, min_truncation_voxels,
    /// truncation_voxels)` voxels, with `sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2` m the axial noise of a Kinect
    /// (Nguyen, Izadi and Lovell 2012). Near surfaces then get a narrow band, which fusion and
    /// meshing pay for per voxel, and far, noisy ones the full width, which averaging needs
    /// (a band narrower than the noise clips it one-sidedly and biases the surface). 0 turns
    /// this off: a fixed band of `truncation_voxels` everywhere (0 to 100).
    pub truncation_noise_factor: f32,
    /// Narrowest band in voxels (at least 1); at or above `truncation_voxels` the band is
    /// fixed. Tracking errors of a few millimetres also need a margin, hence 4 voxels.
    pub min_truncation_voxels: f32,
    /// Weight cap of a voxel (at most 255): the map keeps adapting once a voxel reaches it.
    pub max_weight: f32,
    /// Depths below this many metres are ignored.
    pub min_depth: f32,
    /// Depths above this many metres are ignored (sensor noise grows with the square of depth).
    pub max_depth: f32,
    /// Chunk selection back-projects every `selection_stride`-th pixel in both directions.
    pub selection_stride: usize,
    /// Colour is fused from every `color_every`-th frame (by frame index, 1 to 64), and from
    /// any frame into voxels with fewer than 16 colour observations. Colour noise is small
    /// next to depth noise, so a few observations a second keep the mean colour, while
    /// blending every voxel of the band every frame was about a fifth of fusion's time
    /// (docs/fusion.md).
    pub color_every: usize,
    /// Colour is blended only into voxels whose distance to the measured surface is below
    /// this many voxels (0.5 to 64; at or above the band: the whole band, as before issue
    /// 20). Meshing and the semantic surface cells read colour only at zero crossings, from
    /// the two voxels of a crossed edge, so colour further out is never read, yet packed
    /// chunks stored it. 4, the narrowest band: near surfaces are coloured over their whole
    /// band as before, far ones, whose band widens to average noisier distances, within 4
    /// voxels only. Narrower colour bands leave some crossings of surfaces seen only at
    /// grazing angles (where the distance along the optical axis overstates the distance to
    /// the surface) with two uncoloured ends, black vertices: 0.25 % of the demo's at 2
    /// voxels, 0.05 % at 3, 0.007 % at 4 (docs/benchmarks_log.md, "A compact voxel and
    /// denser packing").
    pub color_band_voxels: f32,
    /// Packed (cold) chunks store the distances of voxels at least
    /// [`TsdfConfig::packed_exact_band_voxels`] from the surface in steps of this many voxels
    /// (0: every distance exact, as fusion left it). Meshing, the raycast and the labels read
    /// distances only near zero crossings; far out in the band the finest steps spend bits
    /// on sensor noise. 0.2 voxels (1 mm at 5 mm) takes the demo's packed map from 2.88 to
    /// 2.50 MB per m² of surface (docs/benchmarks_log.md, "Session 22"). Plain chunks and
    /// the spill file are unaffected: a chunk changes only when it is packed. 0 to 1.
    pub packed_far_step_voxels: f32,
    /// Distances nearer to zero than this many voxels are always packed exactly (2 to 64).
    pub packed_exact_band_voxels: f32,
    /// An observation up to this many bands behind a voxel is clamped to one band behind;
    /// beyond it the voxel is left alone (1 to 4). At 1 (the default) the clamp is one-sided:
    /// a measurement more than a band in front of a voxel counts as one band, one more than a
    /// band behind is skipped, so the sensor's noise averages one-sidedly at the surface and
    /// pushes it away from the camera, the more so the narrower the band is against the
    /// noise. 1.5 treats both sides alike for all but the outermost noise: mesh accuracy on
    /// rendered scans 1.61 -> 1.50 mm (synth:1) and 1.53 -> 1.31 mm (synth:2), ATE on synth:2
    /// 1.62 -> 0.86 mm, the same fusion time; but demo seed 16, which faces a bare wall,
    /// then drifts (ATE 2.8 -> 18.8 mm, mIoU 94.8 -> 19.8 %), so it is not the default
    /// (docs/benchmarks_log.md, "Both sides of the band alike"). Voxels further behind than
    /// one band are updated only in the chunks the band selects, and keep negative
    /// distances there, which meshing never crosses.
    pub behind_band: f32,
    /// Chunks whose centre lies more than this many metres along the camera's axis are fused
    /// from groups of [`TsdfConfig::far_group_frames`] consecutive frames, one pass for the
    /// group at its weight, the frames' depths averaged pixel by pixel
    /// ([`crate::GroupedFusion`]; used by the pipeline and the benchmarks, not by
    /// [`crate::TsdfMap::integrate`], which fuses every frame whole). 0: off.
    pub far_group_beyond_m: f32,
    /// Frames in a group of [`TsdfConfig::far_group_beyond_m`] (2 to 8).
    pub far_group_frames: usize,
}

impl Default for TsdfConfig {
    fn default() -> Self {
        Self {
            voxel_size: 0.005,
            truncation_voxels: 4.0,
            truncation_noise_factor: 3.0,
            min_truncation_voxels: 4.0,
            max_weight: 64.0,
            min_depth: 0.1,
            max_depth: 5.0,
            selection_stride: 2,
            color_every: 3,
            color_band_voxels: 4.0,
            packed_far_step_voxels: 0.2,
            packed_exact_band_voxels: 3.0,
            behind_band: 1.0,
            far_group_beyond_m: 2.0,
            far_group_frames: 4,
        }
    }
}

impl TsdfConfig {
    /// The default configuration at another voxel size.
    pub fn with_voxel_size(voxel_size: f32) -> Result<Self> {
        let c = Self { voxel_size, ..Self::default() };
        c.validate()?;
        Ok(c)
    }

    /// Checks every field against its documented range.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(ReconError::InvalidConfig(m));
        if !(0.002..=0.05).contains(&self.voxel_size) {
            return bad(format!("voxel size {} m is outside 0.002..0.05 m", self.voxel_size));
        }
        if !(1.0..=64.0).contains(&self.truncation_voxels) {
            return bad(format!("truncation {} voxels is outside 1..64", self.truncation_voxels));
        }
        if !(0.0..=100.0).contains(&self.truncation_noise_factor) {
            return bad(format!("truncation noise factor {} is outside 0..100", self.truncation_noise_factor));
        }
        if !(1.0..=64.0).contains(&self.min_truncation_voxels) {
            return bad(format!("narrowest truncation {} voxels is outside 1..64", self.min_truncation_voxels));
        }
        if !(1.0 / WEIGHT_SCALE..=255.0).contains(&self.max_weight) {
            return bad(format!("weight cap {} is outside 1/{WEIGHT_SCALE}..255", self.max_weight));
        }
        if !(self.min_depth >= 0.0 && self.min_depth < self.max_depth && self.max_depth.is_finite()) {
            return bad(format!("depth range {}..{} m is empty or not finite", self.min_depth, self.max_depth));
        }
        if !(1..=64).contains(&self.selection_stride) {
            return bad(format!("selection stride {} is outside 1..64", self.selection_stride));
        }
        if !(0.5..=64.0).contains(&self.color_band_voxels) {
            return bad(format!("colour band {} voxels is outside 0.5..64", self.color_band_voxels));
        }
        if !(0.0..=1.0).contains(&self.packed_far_step_voxels) {
            return bad(format!("packed distance step {} voxels is outside 0..1", self.packed_far_step_voxels));
        }
        if !(2.0..=64.0).contains(&self.packed_exact_band_voxels) {
            return bad(format!("exact packed band {} voxels is outside 2..64", self.packed_exact_band_voxels));
        }
        if !(1.0..=4.0).contains(&self.behind_band) {
            return bad(format!("behind band {} is outside 1..4", self.behind_band));
        }
        if !(self.far_group_beyond_m == 0.0 || (0.3..=20.0).contains(&self.far_group_beyond_m)) {
            return bad(format!("far group distance {} m is neither 0 nor in 0.3..20 m", self.far_group_beyond_m));
        }
        if !(2..=8).contains(&self.far_group_frames) {
            return bad(format!("far group of {} frames is outside 2..8", self.far_group_frames));
        }
        if !(1..=64).contains(&self.color_every) {
            return bad(format!("colour rate 1/{} is outside 1/1..1/64", self.color_every));
        }
        Ok(())
    }

    /// Truncation distance in metres: the widest band, and the unit of [`Voxel::tsdf`](super::Voxel::tsdf).
    pub fn truncation(&self) -> f32 {
        self.voxel_size * self.truncation_voxels
    }

    /// Half-width of the truncation band for a measured depth of `depth` metres, in metres
    /// (see [`TsdfConfig::truncation_noise_factor`]).
    pub fn band(&self, depth: f32) -> f32 {
        self.band_model().relative(depth) * self.truncation()
    }

    /// Narrowest band in voxels: the band's width where the sensor is most precise.
    pub fn narrowest_band_voxels(&self) -> f32 {
        self.band_model().min_relative * self.truncation_voxels
    }

    pub(crate) fn band_model(&self) -> BandModel {
        let k = self.truncation_noise_factor / self.truncation();
        let min_relative = if self.truncation_noise_factor > 0.0 {
            (self.min_truncation_voxels / self.truncation_voxels).min(1.0)
        } else {
            1.0
        };
        BandModel { constant: k * NOISE_CONSTANT, quadratic: k * NOISE_QUADRATIC, min_relative }
    }

    /// How packed chunks code distances (see [`TsdfConfig::packed_far_step_voxels`]), in
    /// stored units.
    pub(crate) fn distance_coding(&self) -> compressed::DistanceCoding {
        let unit = TSDF_SCALE / self.truncation_voxels;
        let step = (self.packed_far_step_voxels * unit).round();
        if step < 2.0 {
            return compressed::DistanceCoding::EXACT;
        }
        compressed::DistanceCoding {
            exact_below: (self.packed_exact_band_voxels * unit).round().min(u16::MAX as f32) as u16,
            far_step: step as u16,
        }
    }

    /// Half-width of the colour band in truncation units (the unit of stored distances).
    pub(crate) fn color_band(&self) -> f32 {
        self.color_band_voxels / self.truncation_voxels
    }

    /// Whether frame `index` is a colour frame (see [`TsdfConfig::color_every`]).
    pub fn is_color_frame(&self, index: usize) -> bool {
        index.is_multiple_of(self.color_every.max(1))
    }

    /// Chunk edge length in metres.
    pub fn chunk_size(&self) -> f32 {
        self.voxel_size * CHUNK_SIDE as f32
    }
}

/// Colour observations a voxel takes from every frame before [`TsdfConfig::color_every`]
/// thins them: a surface seen only briefly still gets a well-averaged colour.
pub(crate) const COLOR_WARMUP: u8 = 16;

/// Kinect axial noise `sigma(z) = NOISE_CONSTANT + NOISE_QUADRATIC (z - NOISE_OFFSET)^2`
/// metres (Nguyen, Izadi and Lovell 2012, for 10-60 degree surfaces).
const NOISE_CONSTANT: f32 = 0.0012;
const NOISE_QUADRATIC: f32 = 0.0019;
pub(crate) const NOISE_OFFSET: f32 = 0.4;

/// The Kinect axial noise `sigma(z)` above, metres at depth `depth` metres.
#[inline]
pub(crate) fn depth_noise(depth: f32) -> f32 {
    let e = depth - NOISE_OFFSET;
    NOISE_CONSTANT + NOISE_QUADRATIC * (e * e)
}

/// The band of [`TsdfConfig::band`] in units of the truncation distance:
/// `clamp(constant + quadratic (z - 0.4)^2, min_relative, 1)`. Fusion evaluates this exact
/// expression in SIMD lanes, so selection, integration and tests agree bit for bit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BandModel {
    pub(crate) constant: f32,
    pub(crate) quadratic: f32,
    pub(crate) min_relative: f32,
}

impl BandModel {
    /// Band half-width at measured depth `depth`, in truncation units (in `min_relative..=1`).
    #[inline]
    pub(crate) fn relative(&self, depth: f32) -> f32 {
        let e = depth - NOISE_OFFSET;
        (self.constant + self.quadratic * (e * e)).max(self.min_relative).min(1.0)
    }
}
