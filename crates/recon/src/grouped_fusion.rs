//! Fusing far surfaces from groups of consecutive frames: one voxel pass for a few frames'
//! depth, with the noise averaging of all of them.
//!
//! Why: fusion's cost is the voxels in the truncation band of the surface in view, and far
//! away, where the band is widest and a pixel is already wider than a voxel, most of them lie
//! (80 % of the demo's updates come from surfaces 2.5-4 m away; docs/fusion.md). Fusing far
//! chunks from every second frame only halves that work but loses the averaging of half the
//! observations, which the far surfaces need most (mesh accuracy 1.48 -> 2.0 mm on the demo,
//! docs/benchmarks_log.md, "Session 26"). Here every frame fuses its near chunks at once; the
//! first frames of a group are held, and the last averages the held frames' depth into its
//! own, pixel by pixel ([`grouped_depth`]), and fuses its far chunks from that average at the
//! group's weight. Inside the band a voxel's signed distance is linear in the depth along the
//! ray, so the average of n depths weighing n is the same update as the n depths one after
//! the other, up to how well the warp finds each held frame's depth on the new pixel's ray.
//!
//! The warp: a pixel of the last frame, back-projected at its depth, is moved into a held
//! camera and projected there; the held depth is interpolated bilinearly at that position
//! over the neighbours that are valid and within the band of the predicted depth (so no
//! average straddles an edge) and its point is moved back. That point lies on the held
//! camera's ray, off the new ray by the depth disagreement times the parallax between frames
//! tens of milliseconds apart (hundredths of a millimetre at 3 m), so its depth along the new
//! camera's axis is the held frame's observation for that pixel. Pixels without a partner in
//! every held frame are left out of the far pass (occlusion edges, newly seen borders, flying
//! pixels at depth edges): a far surface loses one group's observation there.
//!
//! Near chunks are fused from every frame as before, so close-range detail and the tracker's
//! model are unchanged. Everything is per pixel and per chunk in a fixed order: the same bits
//! for any thread count. A far pass records every frame of its group in the chunks it
//! changes, so that loop closure's re-integration re-fuses them all where a correction moves
//! the chunk. With loop closure the pipeline flushes the group before a re-integration starts
//! and fuses frames whole while it runs (docs/loop_closure.md, "Session 43").

use glam::{Affine3A, Vec3};
use rayon::prelude::*;
use semrecon_data::{Frame, Intrinsics};

use crate::error::Result;
use crate::fusion::IntegrationStats;
use crate::map::{depth_noise, ChunkKey, TsdfConfig, TsdfMap, CHUNK_SIDE};

/// Largest gap in frame indices between consecutive frames of a group: a stream that skipped
/// frames (a lost frame, a subsampled clip) groups across a short gap, not across seconds.
const MAX_GROUP_GAP: usize = 3;

/// Fusion that groups consecutive frames for the chunks beyond a distance (see the module).
#[derive(Debug)]
pub struct GroupedFusion {
    beyond_m: f32,
    frames: usize,
    held: Vec<Held>,
    stats: GroupingStats,
    /// Chunks the last frame's view selected, near and far.
    last_selection: usize,
}

/// A frame of a group before its last: fused near, waiting to be fused far.
#[derive(Debug)]
struct Held {
    index: usize,
    depth: Vec<f32>,
    intrinsics: Intrinsics,
    world_from_camera: Affine3A,
    /// Colour, for fusing it alone if the group is broken off.
    color: Vec<[u8; 3]>,
    timestamp: f64,
    /// Its far chunks that the map already held: what it fuses alone if the group is broken
    /// off.
    far: Vec<ChunkKey>,
}

impl Held {
    /// The held frame as a frame (its buffers moved out; [`Held::restore`] puts them back).
    fn frame(&mut self) -> Frame {
        Frame {
            index: self.index,
            timestamp: self.timestamp,
            depth: std::mem::take(&mut self.depth),
            color: std::mem::take(&mut self.color),
            intrinsics: self.intrinsics,
            world_from_camera: None,
            labels: None,
        }
    }

    /// Takes back the buffers [`Held::frame`] moved out.
    fn restore(&mut self, frame: Frame) {
        self.depth = frame.depth;
        self.color = frame.color;
    }
}

/// What the grouping did over a scan.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GroupingStats {
    /// Far passes fused from a whole group.
    pub groups: usize,
    /// Pixels of the groups' last frames that found a partner in every held frame.
    pub paired_pixels: usize,
    /// Pixels of the groups' last frames that could reach a far chunk.
    pub candidate_pixels: usize,
    /// Held frames fused alone (a group broken off by a gap, the end of the scan).
    pub flushed_frames: usize,
}

impl GroupedFusion {
    /// Groups `frames` consecutive frames (2 to 8) for chunks whose centre lies more than
    /// `beyond_m` metres along the camera's axis; `beyond_m` 0 (or not positive and finite),
    /// or `frames` below 2, fuses every frame whole, as [`TsdfMap::integrate`] does.
    pub fn new(beyond_m: f32, frames: usize) -> Self {
        let on = beyond_m.is_finite() && beyond_m > 0.0 && frames >= 2;
        Self {
            beyond_m: if on { beyond_m } else { 0.0 },
            frames: if on { frames.min(8) } else { 1 },
            held: Vec::new(),
            stats: GroupingStats::default(),
            last_selection: 0,
        }
    }

    /// Chunks the last integrated frame's view selected, near and far (what fusing it whole
    /// would have visited), whatever part of them it fused now.
    pub fn last_selection(&self) -> usize {
        self.last_selection
    }

    /// For a map's configuration ([`crate::TsdfConfig::far_group_beyond_m`],
    /// [`crate::TsdfConfig::far_group_frames`]).
    pub fn for_map(map: &TsdfMap) -> Self {
        Self::new(map.config().far_group_beyond_m, map.config().far_group_frames)
    }

    /// Whether frames are grouped at all.
    pub fn is_on(&self) -> bool {
        self.frames >= 2
    }

    /// What the grouping did so far.
    pub fn stats(&self) -> GroupingStats {
        self.stats
    }

    /// Fuses `frame` seen from `world_from_camera`: near chunks now; far chunks now from the
    /// average over the group when it is the group's last frame, otherwise later.
    ///
    /// # Errors
    /// What [`TsdfMap::select_chunks`] and [`TsdfMap::integrate_chunks`] return (a frame whose
    /// buffers do not match its intrinsics, a non-finite pose).
    pub fn integrate(
        &mut self,
        map: &mut TsdfMap,
        frame: &Frame,
        world_from_camera: Affine3A,
    ) -> Result<IntegrationStats> {
        if !self.is_on() {
            let stats = map.integrate(frame, world_from_camera)?;
            self.last_selection = stats.visited_chunks;
            return Ok(stats);
        }
        let keys = map.select_chunks(frame, world_from_camera)?;
        self.last_selection = keys.len();
        let (near, far) = split_by_depth(map, &keys, world_from_camera, self.beyond_m);
        let mut stats = IntegrationStats::default();
        // A group broken by a gap in the stream, or by another camera, is fused frame by frame.
        if let Some(last) = self.held.last() {
            let gap = frame.index.wrapping_sub(last.index);
            if !(1..=MAX_GROUP_GAP).contains(&gap) || last.intrinsics != frame.intrinsics {
                stats += self.flush(map)?;
            }
        }
        if self.held.len() + 1 < self.frames {
            // Far chunks the map does not hold yet are fused at once with the near ones: a
            // surface seen for the first time (the whole view at the start of a scan, when
            // everything may be far) is in the tracker's model for the next frame. The
            // group's pass adds them again (one observation counted twice, where a surface
            // is new).
            let (new, far): (Vec<ChunkKey>, Vec<ChunkKey>) = far.into_iter().partition(|k| map.chunk(*k).is_none());
            let now: Vec<ChunkKey> = if new.is_empty() { near } else { near.into_iter().chain(new).collect() };
            stats += map.integrate_chunks(frame, world_from_camera, &now)?;
            self.held.push(Held {
                index: frame.index,
                depth: frame.depth.clone(),
                intrinsics: frame.intrinsics,
                world_from_camera,
                color: frame.color.clone(),
                timestamp: frame.timestamp,
                far,
            });
            return Ok(stats);
        }
        stats += map.integrate_chunks(frame, world_from_camera, &near)?;
        let mut held = std::mem::take(&mut self.held);
        // Far chunks a held frame saw that the last frame does not (the edge of a panning
        // view) would get nothing from the average: each held frame fuses those alone.
        let last: std::collections::HashSet<ChunkKey> = far.iter().copied().collect();
        for h in &mut held {
            let missing: Vec<ChunkKey> = h.far.iter().copied().filter(|k| !last.contains(k)).collect();
            if !missing.is_empty() {
                let frame = h.frame();
                stats += map.integrate_chunks(&frame, h.world_from_camera, &missing)?;
                h.restore(frame);
            }
        }
        if far.is_empty() {
            return Ok(stats);
        }
        let config = *map.config();
        let truncation = config.truncation();
        // A pixel nearer than this reaches no far voxel: every far chunk's voxels lie behind
        // its surface by more than the band (or the clamp behind it).
        let reach = CHUNK_SIDE as f32 * config.voxel_size;
        let from_depth = self.beyond_m - reach - config.behind_band * truncation;
        let others: Vec<(&[f32], Affine3A)> = held.iter().map(|h| (h.depth.as_slice(), h.world_from_camera)).collect();
        let averaged = averaged_frame(&config, frame, world_from_camera, &others, from_depth, others.len());
        self.stats.groups += 1;
        self.stats.paired_pixels += averaged.paired;
        self.stats.candidate_pixels += averaged.candidates;
        // The chunks record the whole group: a re-integration re-fuses every frame of it.
        let first = held.first().map_or(frame.index, |h| h.index);
        stats += map.integrate_chunks_weighted(
            &averaged.frame,
            world_from_camera,
            &far,
            self.frames as f32,
            first..=frame.index,
        )?;
        Ok(stats)
    }

    /// Fuses the held frames' far chunks one by one (the end of a scan, a group broken off):
    /// no observation is lost.
    ///
    /// # Errors
    /// What [`TsdfMap::integrate_chunks`] returns.
    pub fn flush(&mut self, map: &mut TsdfMap) -> Result<IntegrationStats> {
        let mut stats = IntegrationStats::default();
        for mut held in std::mem::take(&mut self.held) {
            self.stats.flushed_frames += 1;
            if held.far.is_empty() {
                continue;
            }
            let pose = held.world_from_camera;
            let far = std::mem::take(&mut held.far);
            stats += map.integrate_chunks(&held.frame(), pose, &far)?;
        }
        Ok(stats)
    }

    /// Whether frames are held, their far chunks not fused yet.
    pub fn is_holding(&self) -> bool {
        !self.held.is_empty()
    }
}

/// A frame whose depth is averaged with other frames' ([`averaged_frame`]).
#[derive(Debug, Clone)]
pub struct AveragedFrame {
    /// The frame, its depth replaced by the average (0 where a pixel is left out).
    pub frame: Frame,
    /// Pixels that found a partner in every other frame (the averaged ones).
    pub paired: usize,
    /// Valid pixels from the given depth on.
    pub candidates: usize,
}

/// `frame`'s depth averaged, pixel by pixel, with `others`' observations of the same surface
/// points ([`grouped_depth`], with the sensor's noise as the tolerance and the map's depth
/// range): one image that, fused at the frames' count as its weight, gives the update of all
/// of them. `others` holds each other frame's depth (same intrinsics as `frame`) and
/// `world_from_camera`; pixels nearer than `from_depth` are left out.
///
/// # Shapes
/// Every depth `height * width` metres of `frame.intrinsics`, row-major.
pub fn averaged_frame(
    config: &TsdfConfig,
    frame: &Frame,
    world_from_camera: Affine3A,
    others: &[(&[f32], Affine3A)],
    from_depth: f32,
    min_partners: usize,
) -> AveragedFrame {
    let camera_from_world = world_from_camera.inverse();
    let others: Vec<(&[f32], Affine3A)> =
        others.iter().map(|&(depth, world_from_other)| (depth, camera_from_world * world_from_other)).collect();
    let (depth, paired, candidates) = grouped_depth(
        &frame.depth,
        &others,
        &frame.intrinsics,
        // Two observations of one surface differ by the noise of both, sqrt(2) sigma:
        // 4.5 sigma keeps all but a few in ten thousand of them (the band, capped at the
        // truncation, would drop a fifth far away), and still parts surfaces that are
        // decimetres apart at 4 m.
        |z| (4.5 * depth_noise(z)).max(2.0 * config.voxel_size),
        (config.min_depth, config.max_depth),
        from_depth,
        min_partners,
    );
    let frame = Frame {
        index: frame.index,
        timestamp: frame.timestamp,
        depth,
        color: frame.color.clone(),
        intrinsics: frame.intrinsics,
        world_from_camera: frame.world_from_camera,
        labels: None,
    };
    AveragedFrame { frame, paired, candidates }
}

/// `keys` split into chunks whose centre is at most `beyond_m` along the camera's axis and
/// those beyond, each in the given order.
fn split_by_depth(
    map: &TsdfMap,
    keys: &[ChunkKey],
    world_from_camera: Affine3A,
    beyond_m: f32,
) -> (Vec<ChunkKey>, Vec<ChunkKey>) {
    let camera_from_world = world_from_camera.inverse();
    let voxel = map.config().voxel_size;
    let half = (CHUNK_SIDE as f32 - 1.0) / 2.0;
    keys.iter().partition(|key| {
        let centre = (key.as_vec3() * CHUNK_SIDE as f32 + Vec3::splat(half)) * voxel;
        camera_from_world.transform_point3(centre).z <= beyond_m
    })
}

/// The depth of `current` averaged, pixel by pixel, with each of `others`' observations of
/// the same surface point (see the module's text); 0 where some other frame has no partner,
/// and for pixels nearer than `from_depth` (left out). Returns the image, the number of
/// averaged pixels and the number of valid pixels from `from_depth` on.
///
/// `others` holds each other frame's depth and `current_from_other`, which moves points from
/// its camera into the current one; all share the intrinsics `k`. `tolerance(z)` is the most
/// two depths of one surface at depth `z` may differ by (the sensor's noise); depths outside
/// `range` (min, max metres) are invalid. An other depth is interpolated bilinearly over those
/// of the four neighbours that are valid and within the tolerance of the predicted depth,
/// when they carry at least a quarter of the weight: a sensor's scattered dropouts would
/// otherwise leave a fifth of the pixels unpaired.
///
/// `min_partners` is how many of the other frames must pair a pixel for it to be kept
/// (`others.len()` or more: every one); a kept pixel is averaged over the frames that pair
/// it. The paired count returned is of pixels averaged with every other frame.
///
/// # Shapes
/// `current` and every other depth: `height * width` metres, row-major, of `k`'s size; the
/// result the same.
pub fn grouped_depth(
    current: &[f32],
    others: &[(&[f32], Affine3A)],
    k: &Intrinsics,
    tolerance: impl Fn(f32) -> f32 + Sync,
    range: (f32, f32),
    from_depth: f32,
    min_partners: usize,
) -> (Vec<f32>, usize, usize) {
    grouped_depth_with(current, others, k, tolerance, range, from_depth, min_partners.min(others.len()), true)
}

/// [`grouped_depth`], eight pixels at a time (`lanes`) or one by one: the same
/// operations in the same order either way (tested bit for bit).
#[allow(clippy::too_many_arguments)]
fn grouped_depth_with(
    current: &[f32],
    others: &[(&[f32], Affine3A)],
    k: &Intrinsics,
    tolerance: impl Fn(f32) -> f32 + Sync,
    range: (f32, f32),
    from_depth: f32,
    min_partners: usize,
    lanes: bool,
) -> (Vec<f32>, usize, usize) {
    let (w, h) = (k.width as usize, k.height as usize);
    let g = Geometry {
        k: *k,
        w,
        h,
        inv_fx: 1.0 / k.fx,
        inv_fy: 1.0 / k.fy,
        range,
        from: from_depth.max(range.0),
        min_partners,
    };
    let warps: Vec<Warp> = others
        .iter()
        .map(|&(depth, current_from_other)| {
            let other_from_current = current_from_other.inverse();
            let back = current_from_other.matrix3;
            Warp {
                depth,
                rotation: other_from_current.matrix3,
                translation: Vec3::from(other_from_current.translation),
                step_u: Vec3::from(other_from_current.matrix3.x_axis) * g.inv_fx,
                back_z: Vec3::new(back.x_axis.z, back.y_axis.z, back.z_axis.z),
                back_tz: current_from_other.translation.z,
            }
        })
        .collect();
    let mut out = vec![0.0f32; w * h];
    let (paired, candidates) = out
        .par_chunks_mut(w)
        .enumerate()
        .map(|(v, row)| {
            let row_rays: Vec<Vec3> = warps
                .iter()
                .map(|wp| {
                    Vec3::from(wp.rotation * glam::Vec3A::new(-k.cx * g.inv_fx, (v as f32 - k.cy) * g.inv_fy, 1.0))
                })
                .collect();
            let depth_row = &current[v * w..(v + 1) * w];
            let (mut n, mut c) = (0, 0);
            let mut u = 0;
            if lanes {
                while u + 8 <= w {
                    let (pn, pc) =
                        pixels8(&g, &warps, &row_rays, &tolerance, u, &depth_row[u..u + 8], &mut row[u..u + 8]);
                    n += pn;
                    c += pc;
                    u += 8;
                }
            }
            for u in u..w {
                let d = depth_row[u];
                if !(d >= g.from && d <= range.1) {
                    continue;
                }
                c += 1;
                if let Some((sum, count)) = pixel(&g, &warps, &row_rays, &tolerance, u, d) {
                    // Far grouping averages only pixels every held frame saw: filling the
                    // others with the frames that did, at the group's weight, cost 0.2-0.5 mm
                    // of mesh accuracy on rendered scans for under a point of completeness
                    // (docs/fusion.md).
                    row[u] = sum * (1.0 / count);
                    n += (count as usize == warps.len() + 1) as usize;
                }
            }
            (n, c)
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    (out, paired, candidates)
}

/// The camera and the depth range, for the per-pixel work.
struct Geometry {
    k: Intrinsics,
    w: usize,
    h: usize,
    inv_fx: f32,
    inv_fy: f32,
    range: (f32, f32),
    /// Pixels nearer than this are left out.
    from: f32,
    /// Other frames that must pair a pixel for it to be kept.
    min_partners: usize,
}

/// One other frame, seen from the current camera: a current pixel's point seen from it is
/// `d * (R ray(u, v)) + t`, with `ray(u, v)` linear in `u` along a row; of the point brought
/// back only the depth along the current camera's axis is needed.
struct Warp<'a> {
    depth: &'a [f32],
    rotation: glam::Mat3A,
    translation: Vec3,
    step_u: Vec3,
    back_z: Vec3,
    back_tz: f32,
}

/// The sum of pixel `u`'s depth `d` and the other frames' depths of the same surface point,
/// with their count (`d` included), or `None` where fewer than `g.min_partners` other frames
/// have a partner for it.
fn pixel(
    g: &Geometry,
    warps: &[Warp],
    row_rays: &[Vec3],
    tolerance: &impl Fn(f32) -> f32,
    u: usize,
    d: f32,
) -> Option<(f32, f32)> {
    let (w, k) = (g.w, &g.k);
    let valid = |z: f32| z >= g.range.0 && z <= g.range.1;
    let (mut sum, mut count) = (d, 1.0f32);
    let mut missed = 0;
    for (wp, row_ray) in warps.iter().zip(row_rays) {
        let partner = (|| {
            let seen = (*row_ray + wp.step_u * u as f32) * d + wp.translation;
            if !valid(seen.z) {
                return None;
            }
            let inv_z = 1.0 / seen.z;
            let (px, py) = (k.fx * seen.x * inv_z + k.cx, k.fy * seen.y * inv_z + k.cy);
            // Truncation is the floor for the non-negative coordinates kept (the baseline
            // target has no rounding instruction: `floor` is a call).
            if !(px >= 0.0 && py >= 0.0 && px < (w - 1) as f32 && py < (g.h - 1) as f32) {
                return None;
            }
            let (iu, iv) = (px as usize, py as usize);
            let (a, b) = (px - iu as f32, py - iv as f32);
            let tol = tolerance(seen.z);
            let i = iv * w + iu;
            let corners = [
                (wp.depth[i], (1.0 - a) * (1.0 - b)),
                (wp.depth[i + 1], a * (1.0 - b)),
                (wp.depth[i + w], (1.0 - a) * b),
                (wp.depth[i + w + 1], a * b),
            ];
            // Corners on another surface (across an edge) are left out.
            let (mut acc, mut weight) = (0.0f32, 0.0f32);
            for (z, wz) in corners {
                if valid(z) && (z - seen.z).abs() <= tol {
                    acc += z * wz;
                    weight += wz;
                }
            }
            if weight < 0.25 {
                return None;
            }
            let held = acc / weight;
            let ray = Vec3::new((px - k.cx) * g.inv_fx, (py - k.cy) * g.inv_fy, 1.0);
            let back = held * wp.back_z.dot(ray) + wp.back_tz;
            valid(back).then_some(back)
        })();
        match partner {
            Some(back) => {
                sum += back;
                count += 1.0;
            }
            None => {
                missed += 1;
                if warps.len() - missed < g.min_partners {
                    return None;
                }
            }
        }
    }
    Some((sum, count))
}

/// [`pixel`] for the eight pixels from `u0` (`depth`, `out`: eight each), lane by lane the
/// same operations (no fused multiply-add), so the same bits; returns the pixels averaged
/// with every other frame and the candidates. The warp was a tenth of grouped fusion's time
/// one pixel at a time.
#[allow(clippy::too_many_arguments)]
fn pixels8(
    g: &Geometry,
    warps: &[Warp],
    row_rays: &[Vec3],
    tolerance: &impl Fn(f32) -> f32,
    u0: usize,
    depth: &[f32],
    out: &mut [f32],
) -> (usize, usize) {
    use wide::f32x8;
    let splat = f32x8::splat;
    let (zero, one) = (splat(0.0), splat(1.0));
    let (r0, r1) = (splat(g.range.0), splat(g.range.1));
    let d = f32x8::new(std::array::from_fn(|l| depth[l]));
    let candidate = d.simd_ge(splat(g.from)) & d.simd_le(r1);
    let candidates = candidate.to_bitmask().count_ones() as usize;
    if candidates == 0 {
        return (0, 0);
    }
    let uf = f32x8::new(std::array::from_fn(|l| (u0 + l) as f32));
    let (k, w) = (&g.k, g.w);
    let (wl, hl) = (splat((w - 1) as f32), splat((g.h - 1) as f32));
    // Every other frame must pair a lane: a lane out stays out (and the lanes stop early).
    let all = g.min_partners >= warps.len();
    let mut alive = candidate;
    let (mut sum, mut count) = (d, one);
    for (wp, rr) in warps.iter().zip(row_rays) {
        let mut ok = alive;
        let sx = (splat(rr.x) + splat(wp.step_u.x) * uf) * d + splat(wp.translation.x);
        let sy = (splat(rr.y) + splat(wp.step_u.y) * uf) * d + splat(wp.translation.y);
        let sz = (splat(rr.z) + splat(wp.step_u.z) * uf) * d + splat(wp.translation.z);
        ok &= sz.simd_ge(r0) & sz.simd_le(r1);
        let inv_z = one / sz;
        let px = splat(k.fx) * sx * inv_z + splat(k.cx);
        let py = splat(k.fy) * sy * inv_z + splat(k.cy);
        ok &= px.simd_ge(zero) & py.simd_ge(zero) & px.simd_lt(wl) & py.simd_lt(hl);
        if ok.to_bitmask() == 0 {
            if all {
                alive = ok;
                break;
            }
            continue;
        }
        // Lanes out keep harmless coordinates (pixel 0).
        let (pxs, pys) = (ok.select(px, zero), ok.select(py, zero));
        let (iu, iv) = (pxs.fast_trunc_int(), pys.fast_trunc_int());
        let (a, b) = (pxs - iu.round_float(), pys - iv.round_float());
        let szs = sz.to_array();
        let tol = f32x8::new(std::array::from_fn(|l| tolerance(szs[l])));
        let (iu, iv) = (iu.to_array(), iv.to_array());
        let index: [usize; 8] = std::array::from_fn(|l| iv[l] as usize * w + iu[l] as usize);
        let corner = |offset: usize| f32x8::new(std::array::from_fn(|l| wp.depth[index[l] + offset]));
        let corners = [
            (corner(0), (one - a) * (one - b)),
            (corner(1), a * (one - b)),
            (corner(w), (one - a) * b),
            (corner(w + 1), a * b),
        ];
        let (mut acc, mut weight) = (zero, zero);
        for (z, wz) in corners {
            let near = z.simd_ge(r0) & z.simd_le(r1) & (z - sz).abs().simd_le(tol);
            acc = near.select(acc + z * wz, acc);
            weight = near.select(weight + wz, weight);
        }
        ok &= weight.simd_ge(splat(0.25));
        let held = acc / weight;
        let rx = (px - splat(k.cx)) * splat(g.inv_fx);
        let ry = (py - splat(k.cy)) * splat(g.inv_fy);
        let dot = splat(wp.back_z.x) * rx + splat(wp.back_z.y) * ry + splat(wp.back_z.z) * one;
        let back = held * dot + splat(wp.back_tz);
        ok &= back.simd_ge(r0) & back.simd_le(r1);
        sum = ok.select(sum + back, sum);
        count = ok.select(count + one, count);
        if all {
            alive = ok;
        }
    }
    let kept = if all { alive } else { candidate & count.simd_ge(splat((g.min_partners + 1) as f32)) };
    let full = count.simd_eq(splat((warps.len() + 1) as f32)) & kept;
    let bits = kept.to_bitmask();
    let averaged = (sum * (one / count)).to_array();
    for (l, o) in out.iter_mut().enumerate() {
        if bits & (1 << l) != 0 {
            *o = averaged[l];
        }
    }
    (full.to_bitmask().count_ones() as usize, candidates)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::TsdfConfig;

    fn intrinsics() -> Intrinsics {
        Intrinsics::new(64, 48, 50.0, 50.0, 31.5, 23.5).expect("intrinsics")
    }

    /// Depth of the plane `n · x = c` (camera frame) on every pixel's ray.
    fn plane_depth(k: &Intrinsics, n: Vec3, c: f32) -> Vec<f32> {
        let mut out = Vec::new();
        for v in 0..k.height {
            for u in 0..k.width {
                let ray = k.unproject(u as f32, v as f32, 1.0);
                out.push(c / n.dot(ray));
            }
        }
        out
    }

    /// A slanted plane seen from two poses: the previous frame's depth, warped onto the
    /// current pixels, equals the current depth wherever both see it, so the average is the
    /// current depth; pixels that leave the previous view are left out.
    #[test]
    fn a_plane_seen_twice_averages_to_its_own_depth() {
        let k = intrinsics();
        let n = Vec3::new(0.3, -0.2, 1.0).normalize();
        let world_plane_c = 3.0;
        let previous_from_world = Affine3A::IDENTITY;
        let current_from_world = Affine3A::from_rotation_translation(
            glam::Quat::from_rotation_y(0.03) * glam::Quat::from_rotation_x(-0.02),
            Vec3::new(0.04, -0.01, 0.02),
        );
        // The plane in each camera: n_c = R n, c_c = c + n_c · t.
        let in_camera = |t: Affine3A| {
            let nc = t.transform_vector3(n);
            (nc, world_plane_c + nc.dot(Vec3::from(t.translation)))
        };
        let (np, cp) = in_camera(previous_from_world);
        let (nc, cc) = in_camera(current_from_world);
        let previous = plane_depth(&k, np, cp);
        let current = plane_depth(&k, nc, cc);
        let current_from_previous = current_from_world * previous_from_world.inverse();
        let (avg, paired, _) =
            grouped_depth(&current, &[(&previous, current_from_previous)], &k, |_| 0.05, (0.1, 10.0), 0.0, 1);
        assert!(paired > k.pixel_count() * 3 / 4, "{paired} of {} paired", k.pixel_count());
        let mut worst = 0.0f32;
        for (a, c) in avg.iter().zip(&current) {
            if *a > 0.0 {
                worst = worst.max((a - c).abs());
            }
        }
        // Bilinear interpolation of 1/(n·ray) is not exact: well under a millimetre here.
        assert!(worst < 5e-4, "worst difference {worst} m");
    }

    /// Noise averages: two independent noisy copies of a wall average to about half the
    /// variance, and a depth edge is never averaged across.
    #[test]
    fn noise_averages_and_edges_are_left_out() {
        let k = intrinsics();
        let n = k.pixel_count();
        let mut state = 12345u64;
        let mut noise = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * 0.02
        };
        // A wall at 3 m with a box at 1.5 m in the left quarter.
        let truth: Vec<f32> = (0..n).map(|i| if i % 64 < 16 { 1.5 } else { 3.0 }).collect();
        let a: Vec<f32> = truth.iter().map(|t| t + noise()).collect();
        let b: Vec<f32> = truth.iter().map(|t| t + noise()).collect();
        let (avg, _, _) = grouped_depth(&a, &[(&b, Affine3A::IDENTITY)], &k, |_| 0.1, (0.1, 10.0), 0.0, 1);
        let err = |img: &[f32]| {
            let e: Vec<f32> =
                img.iter().zip(&truth).filter(|(v, _)| **v > 0.0).map(|(v, t)| (v - t) * (v - t)).collect();
            e.iter().sum::<f32>() / e.len() as f32
        };
        assert!(err(&avg) < 0.75 * err(&a), "{} against {}", err(&avg), err(&a));
        // Pixels next to the edge (whose bilinear neighbours straddle it) are never averaged
        // into a value between the two surfaces.
        for (v, t) in avg.iter().zip(&truth) {
            assert!(*v == 0.0 || (v - t).abs() < 0.03, "{v} averaged across the edge (truth {t})");
        }
    }

    /// A chunk's key and its voxels' distance, weight and colour.
    type ChunkVoxels = (ChunkKey, Vec<(f32, f32, [u8; 3])>);

    /// The eight-lane warp against the one-pixel warp, bit for bit, on random depth (walls at
    /// random depths with noise, dropouts, edges, pixels out of range) and random small motions
    /// with one and two other frames; image widths that leave a tail of pixels.
    #[test]
    fn eight_lanes_equal_one_pixel_at_a_time() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut rand = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        for (trial, width) in [(0, 64usize), (1, 61), (2, 37), (3, 64)] {
            let k = Intrinsics::new(width as u32, 40, 45.0, 45.0, width as f32 / 2.0 - 0.5, 19.5).expect("intrinsics");
            let n = k.pixel_count();
            let base = 0.5 + 4.0 * rand();
            let image = |r: &mut dyn FnMut() -> f32| -> Vec<f32> {
                (0..n)
                    .map(|i| {
                        let x = r();
                        if x < 0.08 {
                            0.0
                        } else if x < 0.1 {
                            9.0
                        } else if (i % width) < width / 3 {
                            base * 0.6 + 0.02 * r()
                        } else {
                            base + 0.03 * r()
                        }
                    })
                    .collect()
            };
            let current = image(&mut rand);
            let a = image(&mut rand);
            let b = image(&mut rand);
            let pose = |r: &mut dyn FnMut() -> f32| {
                Affine3A::from_rotation_translation(
                    glam::Quat::from_rotation_y(0.04 * (r() - 0.5)) * glam::Quat::from_rotation_x(0.04 * (r() - 0.5)),
                    Vec3::new(0.05 * (r() - 0.5), 0.05 * (r() - 0.5), 0.05 * (r() - 0.5)),
                )
            };
            let (pa, pb) = (pose(&mut rand), pose(&mut rand));
            let others: Vec<(&[f32], Affine3A)> =
                if trial % 2 == 0 { vec![(&a, pa), (&b, pb)] } else { vec![(&a, pa)] };
            let tolerance = |z: f32| 0.01 + 0.02 * z * z;
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            let from = 0.3 * trial as f32;
            let mut kept_before = usize::MAX;
            for need in (0..=others.len()).rev() {
                let lanes = grouped_depth_with(&current, &others, &k, tolerance, (0.1, 5.0), from, need, true);
                let single = grouped_depth_with(&current, &others, &k, tolerance, (0.1, 5.0), from, need, false);
                assert!(lanes.1 > 0, "trial {trial}, {need} partners: nothing averaged");
                assert_eq!((lanes.1, lanes.2), (single.1, single.2), "trial {trial}, {need} partners");
                assert_eq!(bits(&lanes.0), bits(&single.0), "trial {trial}, {need} partners");
                // Fewer partners needed keep more pixels; every partner needed is `grouped_depth`.
                let kept = lanes.0.iter().filter(|d| **d > 0.0).count();
                if need == others.len() {
                    let full = grouped_depth(&current, &others, &k, tolerance, (0.1, 5.0), from, usize::MAX);
                    assert_eq!(bits(&full.0), bits(&lanes.0), "trial {trial}");
                    assert_eq!(kept, full.1, "trial {trial}");
                } else {
                    assert!(kept > kept_before, "trial {trial}, {need} partners: {kept} kept");
                }
                if need == 0 {
                    assert_eq!(kept, lanes.2, "trial {trial}: every candidate kept with no partner needed");
                }
                kept_before = kept;
            }
        }
    }

    /// Every chunk's key and voxels, in key order.
    fn voxels(map: &TsdfMap) -> Vec<ChunkVoxels> {
        map.sorted_keys()
            .into_iter()
            .filter_map(|key| {
                map.chunk(key).map(|c| (key, c.voxels().map(|v| (v.tsdf(), v.weight(), v.color())).collect()))
            })
            .collect()
    }

    /// With pairing off the map is exactly what `TsdfMap::integrate` builds; with it on, a
    /// held frame's far chunks are fused by `flush`.
    #[test]
    fn off_is_plain_fusion_and_a_held_frame_is_flushed() {
        let k = intrinsics();
        let config = TsdfConfig { voxel_size: 0.02, ..TsdfConfig::default() };
        let depth: Vec<f32> = (0..k.pixel_count()).map(|i| if i % 64 < 32 { 1.0 } else { 3.0 }).collect();
        let frame = Frame { color: vec![[100, 120, 140]; k.pixel_count()], ..Frame::from_depth(k, depth) };
        let pose = Affine3A::IDENTITY;
        let mut plain = TsdfMap::new(config).expect("map");
        plain.integrate(&frame, pose).expect("fusion");
        let mut off = TsdfMap::new(config).expect("map");
        GroupedFusion::new(0.0, 2).integrate(&mut off, &frame, pose).expect("fusion");
        assert_eq!(voxels(&off), voxels(&plain));

        let mut paired = TsdfMap::new(config).expect("map");
        let mut fusion = GroupedFusion::new(2.0, 2);
        fusion.integrate(&mut paired, &frame, pose).expect("fusion");
        assert!(fusion.is_holding());
        // A first frame's far surface is new: fused at once, so the tracker sees it.
        assert_eq!(paired.chunk_count(), plain.chunk_count());
        assert_eq!(voxels(&paired), voxels(&plain));
        // A second frame from elsewhere (a gap in the stream) breaks the group off: the held
        // frame has nothing left to fuse, the new one is held with its far chunks waiting.
        let later = Frame { index: 10, ..frame.clone() };
        fusion.integrate(&mut paired, &later, pose).expect("fusion");
        assert!(fusion.is_holding());
        assert_eq!(fusion.stats().flushed_frames, 1);
        let mut twice = TsdfMap::new(*paired.config()).expect("map");
        twice.integrate(&frame, pose).expect("fusion");
        let near_only = voxels(&paired);
        fusion.flush(&mut paired).expect("flush");
        assert!(!fusion.is_holding());
        twice.integrate(&later, pose).expect("fusion");
        assert_ne!(near_only, voxels(&twice), "the far wall waited");
        assert_eq!(voxels(&paired), voxels(&twice), "flushed, the map is the two frames fused whole");
    }
}
