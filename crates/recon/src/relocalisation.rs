//! Relocalisation: getting a lost track back by recognising a place seen before.
//!
//! Frame-to-model tracking aligns each frame starting from the last good pose. Once it is
//! lost (a fast swing, a covered lens, a view with nothing the map knows), every later frame
//! starts from that stale pose, and the track only comes back if the camera happens to return
//! there. [`KeyframeIndex`] keeps a tiny thumbnail of every keyframe (depth and normalised
//! intensity, 40x30 block means, the idea of the keyframe-thumbnail relocalisers of
//! KinectFusion-style systems); [`Tracker::relocalise`] ranks them against a lost frame and
//! aligns the frame to the map from the best few keyframes' poses, accepting the first
//! alignment that passes the tracker's own quality checks. Thumbnails are written by hand
//! rather than with an image crate: they are block means with a validity rule, a few lines.

use glam::{Affine3A, Quat, Vec3};
use semrecon_data::Frame;

use crate::error::Result;
use crate::map::TsdfMap;
use crate::tracking::{Tracker, TrackingResult, TrackingStatus};

/// Thumbnail width and height in blocks.
const THUMB_W: usize = 40;
const THUMB_H: usize = 30;
/// A block is valid when at least this share of its pixels has depth.
const MIN_BLOCK_VALID: f32 = 0.5;
/// Two thumbnails are compared only where both have depth, and only when that is at least
/// this share of the blocks either has.
const MIN_OVERLAP: f32 = 0.5;
/// Depth difference that weighs as much as one standard deviation of intensity, metres.
const DEPTH_SCALE: f32 = 0.1;
/// Candidates closer than this to an already chosen one are skipped (metres, radians): the
/// alignment from either would end in the same place.
const DISTINCT_TRANSLATION: f32 = 0.05;
const DISTINCT_ROTATION: f32 = 0.09;

/// A keyframe's thumbnail and pose.
#[derive(Debug, Clone)]
pub(crate) struct Thumbnail {
    world_from_camera: Affine3A,
    /// Mean depth per block, metres; 0 where the block is invalid.
    depth: Vec<f32>,
    /// Mean intensity per block, zero mean and unit deviation over the valid blocks (so that
    /// exposure changes do not matter); 0 where the block is invalid or the frame has no
    /// colour.
    intensity: Vec<f32>,
}

impl Thumbnail {
    pub(crate) fn of(frame: &Frame, world_from_camera: Affine3A) -> Self {
        let (w, h) = (frame.intrinsics.width as usize, frame.intrinsics.height as usize);
        let mut depth_sum = vec![0.0f32; THUMB_W * THUMB_H];
        let mut luma_sum = vec![0.0f32; THUMB_W * THUMB_H];
        let mut valid = vec![0u32; THUMB_W * THUMB_H];
        let mut pixels = vec![0u32; THUMB_W * THUMB_H];
        let has_color = frame.color.len() == w * h;
        for v in 0..h {
            let row = (v * THUMB_H / h.max(1)) * THUMB_W;
            for u in 0..w {
                let b = row + u * THUMB_W / w.max(1);
                let i = v * w + u;
                pixels[b] += 1;
                let d = frame.depth.get(i).copied().unwrap_or(0.0);
                if d > 0.0 && d.is_finite() {
                    valid[b] += 1;
                    depth_sum[b] += d;
                    if has_color {
                        let [r, g, bl] = frame.color[i];
                        luma_sum[b] += 0.299 * r as f32 + 0.587 * g as f32 + 0.114 * bl as f32;
                    }
                }
            }
        }
        let mut depth = vec![0.0f32; THUMB_W * THUMB_H];
        let mut intensity = vec![0.0f32; THUMB_W * THUMB_H];
        for b in 0..depth.len() {
            if pixels[b] > 0 && valid[b] as f32 >= MIN_BLOCK_VALID * pixels[b] as f32 {
                depth[b] = depth_sum[b] / valid[b] as f32;
                intensity[b] = luma_sum[b] / valid[b] as f32;
            }
        }
        if has_color {
            let n = depth.iter().filter(|&&d| d > 0.0).count().max(1) as f32;
            let mean = depth.iter().zip(&intensity).filter(|(d, _)| **d > 0.0).map(|(_, i)| i).sum::<f32>() / n;
            let var =
                depth.iter().zip(&intensity).filter(|(d, _)| **d > 0.0).map(|(_, i)| (i - mean).powi(2)).sum::<f32>()
                    / n;
            let inv_std = if var > 1e-6 { 1.0 / var.sqrt() } else { 0.0 };
            for (i, d) in intensity.iter_mut().zip(&depth) {
                *i = if *d > 0.0 { (*i - mean) * inv_std } else { 0.0 };
            }
        } else {
            intensity.iter_mut().for_each(|i| *i = 0.0);
        }
        Self { world_from_camera, depth, intensity }
    }

    /// The block depths resampled (nearest block) to a `w` x `h` image, NaN where a block is
    /// invalid: a march-start bound for a ray-cast from this thumbnail's pose.
    fn depth_image(&self, w: usize, h: usize) -> Vec<f32> {
        (0..w * h)
            .map(|i| {
                let d = self.depth[((i / w) * THUMB_H / h.max(1)) * THUMB_W + (i % w) * THUMB_W / w.max(1)];
                if d > 0.0 {
                    d
                } else {
                    f32::NAN
                }
            })
            .collect()
    }

    /// Dissimilarity to `other` (mean over the blocks both have of the depth difference in
    /// units of [`DEPTH_SCALE`] plus the intensity difference); `None` when they share too
    /// few blocks.
    pub(crate) fn distance(&self, other: &Thumbnail) -> Option<f32> {
        let (mut both, mut either, mut sum) = (0u32, 0u32, 0.0f32);
        for b in 0..self.depth.len() {
            let (a, c) = (self.depth[b] > 0.0, other.depth[b] > 0.0);
            either += (a || c) as u32;
            if a && c {
                both += 1;
                sum += (self.depth[b] - other.depth[b]).abs() / DEPTH_SCALE
                    + (self.intensity[b] - other.intensity[b]).abs();
            }
        }
        (both > 0 && both as f32 >= MIN_OVERLAP * either as f32).then(|| sum / both as f32)
    }
}

/// Thumbnails of the keyframes, for [`Tracker::relocalise`].
///
/// About 10 KB per keyframe (a 1,000-frame scan with a keyframe every 10 frames: 1 MB).
#[derive(Debug, Clone, Default)]
pub struct KeyframeIndex {
    thumbnails: Vec<Thumbnail>,
}

impl KeyframeIndex {
    /// An empty index.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a tracked frame (normally each keyframe) at its pose.
    pub fn add(&mut self, frame: &Frame, world_from_camera: Affine3A) {
        self.thumbnails.push(Thumbnail::of(frame, world_from_camera));
    }

    /// Number of keyframes indexed.
    pub fn len(&self) -> usize {
        self.thumbnails.len()
    }

    /// Whether no keyframe is indexed.
    pub fn is_empty(&self) -> bool {
        self.thumbnails.is_empty()
    }

    /// Poses of up to `max` keyframes that look most like `frame`, best first, skipping
    /// poses within a few centimetres and degrees of a better one. Ties go to the earlier
    /// keyframe (deterministic).
    pub fn candidates(&self, frame: &Frame, max: usize) -> Vec<Affine3A> {
        self.ranked(frame, max).into_iter().map(|i| self.thumbnails[i].world_from_camera).collect()
    }

    /// Indices of the thumbnails [`KeyframeIndex::candidates`] returns.
    fn ranked(&self, frame: &Frame, max: usize) -> Vec<usize> {
        let query = Thumbnail::of(frame, Affine3A::IDENTITY);
        let mut scored: Vec<(f32, usize)> =
            self.thumbnails.iter().enumerate().filter_map(|(i, t)| query.distance(t).map(|d| (d, i))).collect();
        scored.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut chosen: Vec<usize> = Vec::new();
        for (_, i) in scored {
            if chosen.len() >= max {
                break;
            }
            let pose = self.thumbnails[i].world_from_camera;
            let distinct = chosen.iter().all(|&c| {
                let c = self.thumbnails[c].world_from_camera;
                let dt = (Vec3::from(c.translation) - Vec3::from(pose.translation)).length();
                let dr = Quat::from_mat3a(&(c.matrix3.transpose() * pose.matrix3)).to_axis_angle().1;
                let dr = dr.min(std::f32::consts::TAU - dr);
                dt > DISTINCT_TRANSLATION || dr > DISTINCT_ROTATION
            });
            if distinct {
                chosen.push(i);
            }
        }
        chosen
    }
}

impl Tracker {
    /// Tries to recover a lost track: aligns `frame` to `map` from the poses of the (up to)
    /// `attempts` keyframes of `index` that look most like it, and keeps the first alignment
    /// that passes the quality checks of [`Tracker::track`] (the pose-jump check then bounds
    /// the distance from that keyframe) and that depth alone conditions well (scaled
    /// condition at least [`crate::TrackerConfig::degenerate_condition`]). On success the tracker continues from the recovered
    /// pose and the result (status [`TrackingStatus::Tracked`]) says whether to fuse;
    /// otherwise the tracker is unchanged and `None` comes back.
    ///
    /// Each attempt ray-casts the map at a keyframe's pose (the march bounded by the
    /// keyframe's thumbnail depth), so this costs about `attempts` tracking calls: call it on
    /// lost frames only.
    ///
    /// # Errors
    /// As [`Tracker::track`]: a frame whose buffers do not match its camera.
    pub fn relocalise(
        &mut self,
        frame: &Frame,
        map: &TsdfMap,
        index: &KeyframeIndex,
        attempts: usize,
    ) -> Result<Option<TrackingResult>> {
        let downscale = self.config().model_downscale.max(1);
        let (w, h) = ((frame.intrinsics.width / downscale) as usize, (frame.intrinsics.height / downscale) as usize);
        for i in index.ranked(frame, attempts) {
            let keyframe = &index.thumbnails[i];
            let mut attempt = self.clone();
            attempt.restart_at(keyframe.world_from_camera, Some(keyframe.depth_image(w, h)));
            let result = attempt.track(frame, map)?;
            // Depth alone must pin the pose down: along a corridor or across a bare wall the
            // frame fits the map in many places, and the first keyframe tried would win (a
            // generated flat's hall: 5.1 m along the corridor, and the rest of the walk
            // fused there). Such a frame waits for a view with more to hold on to.
            let well_posed = !result.colour_fallback && result.condition >= self.config().degenerate_condition;
            if result.status == TrackingStatus::Tracked && well_posed {
                *self = attempt;
                return Ok(Some(result));
            }
        }
        Ok(None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use semrecon_data::Intrinsics;

    fn frame_with(depth: impl Fn(usize, usize) -> f32, luma: impl Fn(usize, usize) -> u8) -> Frame {
        let k = Intrinsics::new(80, 60, 70.0, 70.0, 39.5, 29.5).expect("camera");
        let mut f = Frame::from_depth(k, (0..80 * 60).map(|i| depth(i % 80, i / 80)).collect());
        f.color = (0..80 * 60).map(|i| [luma(i % 80, i / 80); 3]).collect();
        f
    }

    #[test]
    fn thumbnail_blocks_are_the_means_of_their_valid_pixels() {
        // 80x60 into 40x30: 2x2 blocks. One pixel of four missing keeps the block.
        let f = frame_with(|u, v| if u == 0 && v == 0 { 0.0 } else { 1.0 + 0.01 * (u / 2) as f32 }, |_, _| 0);
        let t = Thumbnail::of(&f, Affine3A::IDENTITY);
        assert!((t.depth[0] - 1.0).abs() < 1e-6);
        assert!((t.depth[7] - 1.07).abs() < 1e-5);
        let g = frame_with(|u, v| if u < 2 && v < 2 && (u + v) > 0 { 0.0 } else { 1.0 }, |_, _| 0);
        assert_eq!(Thumbnail::of(&g, Affine3A::IDENTITY).depth[0], 0.0, "3 of 4 missing: invalid");
    }

    #[test]
    fn the_most_similar_keyframe_comes_first_and_near_duplicates_are_skipped() {
        let ramp = |shift: f32| move |u: usize, v: usize| 1.0 + 0.02 * u as f32 + shift + 0.001 * v as f32;
        let stripes = |period: usize| move |u: usize, _v: usize| if (u / period).is_multiple_of(2) { 40 } else { 200 };
        let at = |x: f32| Affine3A::from_translation(Vec3::new(x, 0.0, 0.0));
        let mut index = KeyframeIndex::new();
        index.add(&frame_with(ramp(0.5), stripes(4)), at(0.0));
        index.add(&frame_with(ramp(0.0), stripes(8)), at(1.0));
        index.add(&frame_with(ramp(0.0), stripes(8)), at(1.01)); // a near duplicate
        index.add(&frame_with(ramp(0.02), stripes(8)), at(2.0));
        let query = frame_with(ramp(0.0), stripes(8));
        let c = index.candidates(&query, 3);
        let xs: Vec<f32> = c.iter().map(|p| p.translation.x).collect();
        assert_eq!(xs, vec![1.0, 2.0, 0.0]);
        // No shared depth: no candidate.
        assert!(index.candidates(&frame_with(|_, _| 0.0, |_, _| 0), 3).is_empty());
    }
}
