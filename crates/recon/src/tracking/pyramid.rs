//! The frame's pyramid: depth halved per level by a robust block median, vertices, normals
//! (central differences, eight lanes at a time) and intensity with its gradient.

use super::*;

/// The depth pyramid with vertices, normals and intensity per level.
pub(super) fn build_pyramid(frame: &Frame, c: &TrackerConfig) -> Vec<Level> {
    let k0 = frame.intrinsics;
    // Filtered and counted in one pass, bands of rows in parallel (a plain loop per band,
    // which the compiler vectorises). A kept depth is positive: `-0.0` becomes `0.0`, which
    // every later test reads as missing all the same.
    let band = 16 * k0.width as usize;
    let mut depth0 = vec![0.0f32; frame.depth.len()];
    let valid0: usize = depth0
        .par_chunks_mut(band)
        .zip(frame.depth.par_chunks(band))
        .map(|(out, src)| {
            let mut valid = 0;
            for (o, &d) in out.iter_mut().zip(src) {
                // NaN fails every comparison, and the range is finite.
                let keep = (d > 0.0) & (d >= c.min_depth) & (d <= c.max_depth);
                *o = if keep { d } else { 0.0 };
                valid += keep as usize;
            }
            valid
        })
        .sum();
    // Level 0 takes its normals from level 1, and its vertices are one multiply-add away from
    // its depth: both are formed where association visits a pixel (a stride of them).
    let mut levels = vec![Level {
        k: k0,
        depth: depth0,
        vertices: Vec::new(),
        normals: Vec::new(),
        intensity: Vec::new(),
        valid: valid0,
        own_normals: Vec::new(),
    }];
    for _ in 1..LEVELS {
        let prev = levels.last().expect("level 0 exists");
        let (pw, ph) = (prev.k.width as usize, prev.k.height as usize);
        let (w, h) = ((pw / 2).max(1), (ph / 2).max(1));
        let k = prev.k.scaled(w as u32, h as u32);
        let mut depth = vec![0.0f32; w * h];
        depth.par_chunks_mut(w).enumerate().for_each(|(y, drow)| {
            // A row past the edge (odd heights) reads as invalid, as does a column.
            let src_row = |sy: usize| if sy < ph { &prev.depth[sy * pw..(sy + 1) * pw] } else { &[][..] };
            block_depth_row(src_row(2 * y), src_row(2 * y + 1), drow);
        });
        levels.push(make_level(k, depth, true));
    }
    // Normals of a level come from the next coarser level: neighbouring pixels of a noisy,
    // disparity-quantised depth image differ by about as much in depth as in position, so
    // their normals scatter by tens of degrees; the coarser level averages 2x2 blocks and
    // spans twice the baseline. Pixels whose depth disagrees with the coarse one (edges)
    // get none.
    for l in 1..LEVELS - 1 {
        let (fine, coarse) = levels.split_at_mut(l + 1);
        let (fine, coarse) = (&mut fine[l], &coarse[0]);
        let w = fine.k.width as usize;
        let fine_depth = &fine.depth;
        fine.own_normals = fine.normals.clone();
        fine.normals.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, n) in row.iter_mut().enumerate() {
                *n = coarse.normal_for_finer(&coarse.normals, x, y, fine_depth[y * w + x]).unwrap_or(Vec3::ZERO);
            }
        });
    }
    // Intensity only feeds the photometric term: empty at every level when it is off.
    if c.photometric_weight > 0.0 {
        add_intensity(&mut levels, frame);
    }
    levels
}

/// Fills every level's intensity: the frame's luma at level 0, then the mean of each 2x2
/// block of the level below (nothing for a frame without colour).
pub(super) fn add_intensity(levels: &mut [Level], frame: &Frame) {
    if frame.color.is_empty() || levels.is_empty() {
        return;
    }
    levels[0].intensity = frame.color.iter().map(|&c| luma(c)).collect();
    for l in 1..levels.len() {
        let (below, rest) = levels.split_at_mut(l);
        let (prev, level) = (&below[l - 1], &mut rest[0]);
        let (pw, ph) = (prev.k.width as usize, prev.k.height as usize);
        let w = level.k.width as usize;
        let mut intensity = vec![0.0f32; w * level.k.height as usize];
        intensity.par_chunks_mut(w).enumerate().for_each(|(y, irow)| {
            for (x, out) in irow.iter_mut().enumerate() {
                let (mut inten, mut m) = (0.0, 0);
                for (sx, sy) in [(2 * x, 2 * y), (2 * x + 1, 2 * y), (2 * x, 2 * y + 1), (2 * x + 1, 2 * y + 1)] {
                    if sx < pw && sy < ph {
                        inten += prev.intensity[sy * pw + sx];
                        m += 1;
                    }
                }
                if m > 0 {
                    *out = inten / m as f32;
                }
            }
        });
        level.intensity = intensity;
    }
}

/// The depth of a 2x2 block (0 = invalid in and out): the mean of its valid depths within
/// 3% of their median (the lower one of an even count), summed in ascending order.
#[inline]
pub(super) fn block_depth(block: [f32; 4]) -> f32 {
    let n = block.iter().filter(|&&d| d > 0.0).count();
    if n == 0 {
        return 0.0;
    }
    // Invalid depths sort last, past the `n` valid ones.
    let mut vals = block.map(|d| if d > 0.0 { d } else { f32::INFINITY });
    sort4(&mut vals);
    let median = vals[(n - 1) / 2];
    let (mut sum, mut cnt) = (0.0f32, 0u32);
    for (k, &d) in vals.iter().enumerate() {
        let keep = k < n && (d - median).abs() <= 0.03 * median;
        // Adding 0 to a positive sum leaves its bits: the same as skipping.
        sum += if keep { d } else { 0.0 };
        cnt += keep as u32;
    }
    sum / cnt as f32
}

/// One row of 2x2 block depths from two source rows (`out[x]` from columns `2x, 2x + 1`; a
/// missing row or column reads as invalid): [`block_depth`] eight blocks at a time where
/// all their columns exist, the same operations per lane (the same bits, tested), else
/// block by block.
pub(super) fn block_depth_row(r0: &[f32], r1: &[f32], out: &mut [f32]) {
    let full = if r0.len() == r1.len() { (r0.len() / 2).min(out.len()) / LANES * LANES } else { 0 };
    for (x8, o) in out[..full].chunks_exact_mut(LANES).enumerate() {
        let base = 2 * LANES * x8;
        let col = |r: &[f32], odd: usize| f32x8::new(std::array::from_fn(|l| r[base + 2 * l + odd]));
        o.copy_from_slice(&block_depth_lanes([col(r0, 0), col(r0, 1), col(r1, 0), col(r1, 1)]).to_array());
    }
    let at = |r: &[f32], sx: usize| r.get(sx).copied().unwrap_or(0.0);
    for (x, d) in out.iter_mut().enumerate().skip(full) {
        *d = block_depth([at(r0, 2 * x), at(r0, 2 * x + 1), at(r1, 2 * x), at(r1, 2 * x + 1)]);
    }
}

/// [`block_depth`] of eight blocks, one per lane (the four depths of block `l` in lane `l`
/// of `block[0..4]`): the same comparisons, selections and sums in the same order, without
/// the branches.
#[inline]
pub(super) fn block_depth_lanes(block: [f32x8; 4]) -> f32x8 {
    let (zero, one) = (f32x8::ZERO, f32x8::ONE);
    let valid = block.map(|d| d.simd_gt(zero));
    let n = valid.iter().fold(zero, |n, &m| n + m.select(one, zero));
    let mut v: [f32x8; 4] = std::array::from_fn(|k| valid[k].select(block[k], f32x8::splat(f32::INFINITY)));
    // `sort4`'s network; depths are never NaN and never -0, so min and max need no care.
    for (i, j) in [(0, 1), (2, 3), (0, 2), (1, 3), (1, 2)] {
        let (a, b) = (v[i], v[j]);
        v[i] = a.fast_min(b);
        v[j] = a.fast_max(b);
    }
    // The lower median: the second value of three or four, else the first.
    let median = n.simd_ge(f32x8::splat(3.0)).select(v[1], v[0]);
    let tolerance = f32x8::splat(0.03) * median;
    let (mut sum, mut count) = (zero, zero);
    for (k, &d) in v.iter().enumerate() {
        let keep = n.simd_gt(f32x8::splat(k as f32)) & (d - median).abs().simd_le(tolerance);
        sum += keep.select(d, zero);
        count += keep.select(one, zero);
    }
    n.simd_gt(zero).select(sum / count, zero)
}

/// Sorts four depths ascending with a five-comparison network (the pyramid's median of a
/// 2x2 block; a library sort is an out-of-line call per block). Depths are never NaN.
#[inline]
pub(super) fn sort4(v: &mut [f32; 4]) {
    let mut cmp = |i: usize, j: usize| {
        let (a, b) = (v[i], v[j]);
        v[i] = a.min(b);
        v[j] = a.max(b);
    };
    cmp(0, 1);
    cmp(2, 3);
    cmp(0, 2);
    cmp(1, 3);
    cmp(1, 2);
}

/// `(u - cx) / fx` per column and `(v - cy) / fy` per row: [`Intrinsics::unproject`] is
/// these times the depth, so the table gives its bits without its two divisions a pixel.
pub(super) struct RayTable {
    pub(super) x: Vec<f32>,
    pub(super) y: Vec<f32>,
}

impl RayTable {
    pub(super) fn new(k: Intrinsics) -> Self {
        Self {
            x: (0..k.width).map(|u| (u as f32 - k.cx) / k.fx).collect(),
            y: (0..k.height).map(|v| (v as f32 - k.cy) / k.fy).collect(),
        }
    }

    /// `k.unproject(x, y, d)`, bit for bit.
    #[inline]
    pub(super) fn unproject(&self, x: usize, y: usize, d: f32) -> Vec3 {
        Vec3::new(self.x[x] * d, self.y[y] * d, d)
    }
}

/// Vertices and normals of one level (intensity comes later, from [`add_intensity`]).
pub(super) fn make_level(k: Intrinsics, depth: Vec<f32>, with_normals: bool) -> Level {
    let (w, h) = (k.width as usize, k.height as usize);
    let mut vertices = vec![Vec3::ZERO; w * h];
    let rays = RayTable::new(k);
    vertices.par_chunks_mut(w).zip(depth.par_chunks(w)).enumerate().for_each(|(y, (row, drow))| {
        for (x, (p, &d)) in row.iter_mut().zip(drow).enumerate() {
            if d > 0.0 {
                *p = rays.unproject(x, y, d);
            }
        }
    });
    let mut normals = vec![Vec3::ZERO; w * h];
    normals.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        if !with_normals || y == 0 || y + 1 >= h {
            return;
        }
        let inner = w.saturating_sub(2);
        let lanes_end = 1 + inner / LANES * LANES;
        for x in (1..lanes_end).step_by(LANES) {
            row[x..x + LANES].copy_from_slice(&normals_lanes(&rays, &depth, w, x, y));
        }
        for x in lanes_end..w.saturating_sub(1) {
            row[x] = pixel_normal(&vertices, w, y * w + x);
        }
    });
    let valid = depth.iter().filter(|&&d| d > 0.0).count();
    Level { k, depth, vertices, normals, intensity: Vec::new(), valid, own_normals: Vec::new() }
}

/// The normal of inner pixel `i` of a level from its four neighbours' vertices (zero where
/// a neighbour is missing or more than 5% of the depth away: a depth edge), facing the
/// camera.
#[inline]
pub(super) fn pixel_normal(vertices: &[Vec3], w: usize, i: usize) -> Vec3 {
    let p = vertices[i];
    if p.z <= 0.0 {
        return Vec3::ZERO;
    }
    let (l, r, u, d) = (vertices[i - 1], vertices[i + 1], vertices[i - w], vertices[i + w]);
    let jump = 0.05 * p.z;
    if [l, r, u, d].iter().any(|q| q.z <= 0.0 || (q.z - p.z).abs() > jump) {
        return Vec3::ZERO;
    }
    let n = (d - u).cross(r - l);
    let len = n.length();
    if !(len > 0.0) {
        return Vec3::ZERO;
    }
    let n = n / len;
    if n.dot(p) > 0.0 {
        -n
    } else {
        n
    }
}

/// [`pixel_normal`] of the eight inner pixels `x..x + 8` of row `y`, one per lane, with the
/// vertices formed from the depths as [`RayTable::unproject`] forms them (contiguous loads
/// instead of interleaved vectors): the same operations in the same order, so the same
/// bits (tested).
#[inline]
pub(super) fn normals_lanes(rays: &RayTable, depth: &[f32], w: usize, x: usize, y: usize) -> [Vec3; LANES] {
    let load = |s: &[f32], at: usize| f32x8::new(std::array::from_fn(|l| s[at + l]));
    let i = y * w + x;
    let (dp, dl, dr, du, dd) =
        (load(depth, i), load(depth, i - 1), load(depth, i + 1), load(depth, i - w), load(depth, i + w));
    let (rx, rxl, rxr) = (load(&rays.x, x), load(&rays.x, x - 1), load(&rays.x, x + 1));
    let (ry, ryu, ryd) = (f32x8::splat(rays.y[y]), f32x8::splat(rays.y[y - 1]), f32x8::splat(rays.y[y + 1]));
    let zero = f32x8::ZERO;
    let jump = f32x8::splat(0.05) * dp;
    // Depths are never NaN: `!(a > b)` is `a <= b`.
    let mut ok = dp.simd_gt(zero);
    for q in [dl, dr, du, dd] {
        ok &= q.simd_gt(zero) & (q - dp).abs().simd_le(jump);
    }
    let p = [rx * dp, ry * dp, dp];
    let (l, r) = ([rxl * dl, ry * dl, dl], [rxr * dr, ry * dr, dr]);
    let (u, d) = ([rx * du, ryu * du, du], [rx * dd, ryd * dd, dd]);
    let a = [d[0] - u[0], d[1] - u[1], d[2] - u[2]];
    let b = [r[0] - l[0], r[1] - l[1], r[2] - l[2]];
    // glam's `cross`, `length`, division and `dot`, operation for operation.
    let n = [a[1] * b[2] - b[1] * a[2], a[2] * b[0] - b[2] * a[0], a[0] * b[1] - b[0] * a[1]];
    let len = ((n[0] * n[0] + n[1] * n[1]) + n[2] * n[2]).sqrt();
    ok &= len.simd_gt(zero);
    let n = n.map(|c| c / len);
    let flip = ((n[0] * p[0] + n[1] * p[1]) + n[2] * p[2]).simd_gt(zero);
    let n = n.map(|c| ok.select(flip.select(-c, c), zero).to_array());
    std::array::from_fn(|l| Vec3::new(n[0][l], n[1][l], n[2][l]))
}
