//! The integration kernel in AVX-512 intrinsics, selected at run time where the CPU has
//! AVX-512F: the AVX2 kernel with two voxel rows (16 lanes) per register, comparisons into
//! mask registers instead of blends.
//!
//! Same two passes as the AVX2 kernel (project and gather every row pair, then update) and
//! the same arithmetic lane for lane (no fused multiply-add, same rounding), so all kernels
//! and the scalar specification `Voxel::fuse` give the same bits.
//!
//! Chunk selection's band walk is here too: the AVX2 walk with 16 sampled pixels per
//! register, so half as many walk steps per image row.

use std::arch::x86_64::*;
use std::mem::MaybeUninit;

use super::{Candidates, ChunkOutcome, FrameView, SelectionView, SELECTION_OFFSET};
use crate::map::{
    Chunk, ChunkKey, SignSummary, CHUNK_SIDE, COLOR_WARMUP, NOISE_OFFSET, RECIPROCALS, TSDF_SCALE, WEIGHT_SCALE,
};

/// The colour running mean's reciprocals, in memory for the gather.
static RECIPROCAL_TABLE: [u32; 256] = RECIPROCALS;

/// Rounds half away from zero like `map::round_half_away`: `trunc(|x| + 0.5)` with the sign
/// restored, the largest float below 0.5 rounding to 0. Inputs are far below 2^23.
#[inline(always)]
unsafe fn round_half_away(x: __m512) -> __m512 {
    // SAFETY: register-only intrinsics of the features the caller enables.
    unsafe {
        let sign = _mm512_set1_epi32(i32::MIN);
        let xi = _mm512_castps_si512(x);
        let abs = _mm512_castsi512_ps(_mm512_andnot_si512(sign, xi));
        let r =
            _mm512_roundscale_ps::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(_mm512_add_ps(abs, _mm512_set1_ps(0.5)));
        let halfish = _mm512_cmp_ps_mask::<_CMP_EQ_OQ>(abs, _mm512_set1_ps(0.5f32.next_down()));
        let r = _mm512_mask_mov_ps(r, halfish, _mm512_setzero_ps());
        _mm512_castsi512_ps(_mm512_or_si512(_mm512_castps_si512(r), _mm512_and_si512(sign, xi)))
    }
}

/// One colour channel of `map::blend_color` in 32-bit lanes: `((c n + o) recip + 2^15) >> 16`
/// (no overflow: at most `(255 * 255 + 255) * 65536 + 2^15 < 2^32`).
#[inline(always)]
unsafe fn blend_channel(c: __m512i, o: __m512i, count: __m512i, recip: __m512i) -> __m512i {
    // SAFETY: register-only intrinsics of the features the caller enables.
    unsafe {
        let sum = _mm512_add_epi32(_mm512_mullo_epi32(c, count), o);
        let c = _mm512_srli_epi32::<16>(_mm512_add_epi32(_mm512_mullo_epi32(sum, recip), _mm512_set1_epi32(1 << 15)));
        _mm512_and_si512(c, _mm512_set1_epi32(0xff))
    }
}

/// Lanes 0..8 `a`, lanes 8..16 `b`.
#[inline(always)]
unsafe fn pair(a: f32, b: f32) -> __m512 {
    // SAFETY: register-only intrinsics of the features the caller enables.
    unsafe { _mm512_mask_mov_ps(_mm512_set1_ps(a), 0xff00, _mm512_set1_ps(b)) }
}

/// `integrate_chunk` of the parent module with AVX-512.
///
/// # Safety
/// The CPU must support AVX-512F, and the frame must have fewer than 2^24 pixels (pixel
/// indices are formed in f32 and gathered without bounds checks).
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn integrate_chunk<const DEPTH_BAND: bool>(chunk: &mut Chunk, f: &FrameView) -> ChunkOutcome {
    const N: usize = CHUNK_SIDE;
    /// Row pairs per chunk.
    const P: usize = N * N / 2;
    let [base, dx, dy, dz] = f.chunk_axes(chunk.key);
    let n_pix = f.depth.len();
    let has_color = !f.color.is_empty();
    let block = &mut *chunk.voxels;
    let mut updated = 0u32;
    let mut near_any: u16 = 0;
    let mut signs = SignSummary::default();
    // SAFETY (whole body): AVX-512F is enabled by the caller's check; every gather index is
    // a pixel index below `n_pix` (lanes off the image are masked off), colour gathers read
    // 4 bytes at most at byte `3 n_pix - 4`, the table index is a count below 256, and row
    // loads/stores stay within the chunk's 512-voxel arrays.
    unsafe {
        let splat = _mm512_set1_ps;
        // Lane l: voxel x = l % 8 of row 2p + l / 8.
        let xs = _mm512_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
        let (step_x, step_y, step_z) =
            (_mm512_mul_ps(xs, splat(dx.x)), _mm512_mul_ps(xs, splat(dx.y)), _mm512_mul_ps(xs, splat(dx.z)));
        let (fx, fy, cx, cy) = (splat(f.k.fx), splat(f.k.fy), splat(f.k.cx), splat(f.k.cy));
        let (wf, hf) = (splat(f.k.width as f32 - 0.5), splat(f.k.height as f32 - 0.5));
        let width = splat(f.k.width as f32);
        let (min_d, max_d) = (splat(f.min_depth), splat(f.max_depth));
        let inv_trunc = splat(1.0 / f.truncation);
        let (band_c, band_q, band_min) = (splat(f.band.constant), splat(f.band.quadratic), splat(f.band.min_relative));
        let noise_offset = splat(NOISE_OFFSET);
        let (zero, half, one) = (_mm512_setzero_ps(), splat(0.5), splat(1.0));
        let neg_half = splat(-0.5);
        let cap = splat(f.weight_cap as f32);
        let four = splat(4.0);
        let obs_scale = splat(f.obs_weight);
        let tiny = splat(1e-30);
        let (color_band, neg_color_band) = (splat(f.color_band), splat(-f.color_band));
        let behind = splat(f.behind);
        let inv_wscale = splat(1.0 / WEIGHT_SCALE);
        let wscale = splat(WEIGHT_SCALE);
        let tscale = splat(TSDF_SCALE);
        let depth_ptr = f.depth.as_ptr();
        let color_ptr = f.color.as_ptr() as *const u8;
        // Colour pixels are 3 bytes; a gather reads 4. The last pixel is read from one byte
        // earlier and shifted, so no read passes the end of the image.
        let last_color_offset = _mm512_set1_epi32((3 * n_pix).saturating_sub(4) as i32);
        let byte_mask = _mm512_set1_epi32(0xff);
        let count_max = _mm512_set1_epi32(255);
        let int_one = _mm512_set1_epi32(1);
        let zero_i = _mm512_setzero_si512();
        let tsdf_ptr = block.tsdf.as_mut_ptr();
        let weight_ptr = block.weight.as_mut_ptr();
        let color_rows = block.color.as_mut_ptr() as *mut u8;
        // First pass: project every row pair and gather its depths (see the AVX2 kernel).
        // Every entry is written by the first pass before the second reads it; left
        // uninitialised, not zeroed (6 KiB per chunk).
        let mut pair_pz = [MaybeUninit::<__m512>::uninit(); P];
        let mut pair_d = [MaybeUninit::<__m512>::uninit(); P];
        let mut pair_pix = [MaybeUninit::<__m512i>::uninit(); P];
        for p in 0..P {
            let r = 2 * p;
            // The block's cache lines are requested along the way, a line or two per row
            // pair, so that the gathers below are not queued behind 96 block requests.
            if p % 2 == 0 {
                _mm_prefetch::<_MM_HINT_T0>(tsdf_ptr.add(r * N) as *const i8);
            } else {
                _mm_prefetch::<_MM_HINT_T0>(weight_ptr.add((r - 2) * N) as *const i8);
            }
            _mm_prefetch::<_MM_HINT_T0>(color_rows.add(r * N * 4) as *const i8);
            let (y, z) = ((r % N) as f32, (r / N) as f32);
            // Each row's start exactly as the other kernels compute it.
            let row0 = base + dy * y + dz * z;
            let row1 = base + dy * (y + 1.0) + dz * z;
            let pz = _mm512_add_ps(pair(row0.z, row1.z), step_z);
            let inv_z = _mm512_div_ps(one, pz);
            let u =
                _mm512_add_ps(_mm512_mul_ps(_mm512_mul_ps(fx, _mm512_add_ps(pair(row0.x, row1.x), step_x)), inv_z), cx);
            let v =
                _mm512_add_ps(_mm512_mul_ps(_mm512_mul_ps(fy, _mm512_add_ps(pair(row0.y, row1.y), step_y)), inv_z), cy);
            let inside = _mm512_cmp_ps_mask::<_CMP_GT_OQ>(pz, zero)
                & _mm512_cmp_ps_mask::<_CMP_GE_OQ>(u, neg_half)
                & _mm512_cmp_ps_mask::<_CMP_LT_OQ>(u, wf)
                & _mm512_cmp_ps_mask::<_CMP_GE_OQ>(v, neg_half)
                & _mm512_cmp_ps_mask::<_CMP_LT_OQ>(v, hf);
            let pu = _mm512_roundscale_ps::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(_mm512_add_ps(u, half));
            let pv = _mm512_roundscale_ps::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(_mm512_add_ps(v, half));
            let pix_f = _mm512_maskz_mov_ps(inside, _mm512_add_ps(_mm512_mul_ps(pv, width), pu));
            let pix = _mm512_cvttps_epi32(pix_f);
            pair_pz[p].write(pz);
            // Lanes off the image read NaN, which fails every validity test.
            pair_d[p].write(_mm512_mask_i32gather_ps::<4>(splat(f32::NAN), inside, pix, depth_ptr));
            pair_pix[p].write(pix);
        }
        for p in 0..P {
            let r = 2 * p;
            let tsdf_row = tsdf_ptr.add(r * N) as *mut __m256i;
            let weight_row = weight_ptr.add(r * N) as *mut __m256i;
            let t_old_i = _mm512_cvtepi16_epi32(_mm256_loadu_si256(tsdf_row));
            let w_old_i = _mm512_cvtepu16_epi32(_mm256_loadu_si256(weight_row));
            let (pz, d, pix) = (pair_pz[p].assume_init(), pair_d[p].assume_init(), pair_pix[p].assume_init());
            let sdf = _mm512_mul_ps(_mm512_sub_ps(d, pz), inv_trunc);
            let mu = if DEPTH_BAND {
                let e = _mm512_sub_ps(d, noise_offset);
                _mm512_min_ps(
                    _mm512_max_ps(_mm512_add_ps(band_c, _mm512_mul_ps(band_q, _mm512_mul_ps(e, e))), band_min),
                    one,
                )
            } else {
                one
            };
            let neg_mu = _mm512_sub_ps(zero, mu);
            let valid = _mm512_cmp_ps_mask::<_CMP_GE_OQ>(d, min_d)
                & _mm512_cmp_ps_mask::<_CMP_LE_OQ>(d, max_d)
                & _mm512_cmp_ps_mask::<_CMP_GE_OQ>(sdf, _mm512_mul_ps(neg_mu, behind));
            // A quarter of the row pairs see no valid observation: they keep their voxels.
            let (t_i, w_i) = if valid == 0 {
                (t_old_i, w_old_i)
            } else {
                let t_old = _mm512_cvtepi32_ps(t_old_i);
                let w_old_q = _mm512_cvtepi32_ps(w_old_i);
                let obs = _mm512_max_ps(_mm512_min_ps(sdf, mu), neg_mu);
                let w_obs = _mm512_maskz_mov_ps(
                    valid,
                    _mm512_mul_ps(_mm512_min_ps(_mm512_div_ps(one, _mm512_mul_ps(d, d)), four), obs_scale),
                );
                let w_old = _mm512_mul_ps(w_old_q, inv_wscale);
                let w_sum = _mm512_add_ps(w_old, w_obs);
                let inv = _mm512_div_ps(one, _mm512_max_ps(w_sum, tiny));
                let a = _mm512_mul_ps(w_old, inv);
                let b = _mm512_mul_ps(w_obs, inv);
                let t = _mm512_add_ps(_mm512_mul_ps(t_old, a), _mm512_mul_ps(obs, _mm512_mul_ps(b, tscale)));
                let t_new = _mm512_mask_mov_ps(t_old, valid, round_half_away(t));
                // `round_half_away` of a non-negative sum needs no sign, and its one special
                // case (the float below 0.5, rounded to 0 instead of 1) is raised to 1 by the
                // floor anyway: `trunc(x + 0.5)` gives the same weights in two operations.
                let w_q = _mm512_min_ps(
                    _mm512_max_ps(
                        _mm512_roundscale_ps::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(_mm512_add_ps(
                            _mm512_mul_ps(w_sum, wscale),
                            half,
                        )),
                        one,
                    ),
                    cap,
                );
                let w_new = _mm512_mask_mov_ps(w_old_q, valid, w_q);
                // Integral and in range: conversions and truncating packs are exact.
                let t_i = _mm512_cvttps_epi32(t_new);
                let w_i = _mm512_cvttps_epi32(w_new);
                _mm256_storeu_si256(tsdf_row, _mm512_cvtepi32_epi16(t_i));
                _mm256_storeu_si256(weight_row, _mm512_cvtepi32_epi16(w_i));
                updated += valid.count_ones();
                let near = valid & _mm512_cmp_ps_mask::<_CMP_LT_OQ>(sdf, mu);
                near_any |= near;
                // Half the row pairs have no voxel near the surface: their colours stay as they are.
                let row_ptr = color_rows.add(r * N * 4) as *mut __m512i;
                let cur = if has_color && near != 0 { _mm512_loadu_si512(row_ptr as *const _) } else { zero_i };
                let near = near
                    & _mm512_cmp_ps_mask::<_CMP_LT_OQ>(sdf, color_band)
                    & _mm512_cmp_ps_mask::<_CMP_GE_OQ>(sdf, neg_color_band);
                // Off colour frames only voxels still warming up take a colour.
                let near = if f.color_all {
                    near
                } else {
                    near & _mm512_cmplt_epu32_mask(_mm512_srli_epi32::<24>(cur), _mm512_set1_epi32(COLOR_WARMUP as i32))
                };
                if has_color && near != 0 {
                    let offset = _mm512_mullo_epi32(pix, _mm512_set1_epi32(3));
                    let clamped = _mm512_min_epi32(offset, last_color_offset);
                    let shift = _mm512_slli_epi32::<3>(_mm512_sub_epi32(offset, clamped));
                    let obs_c = _mm512_srlv_epi32(
                        _mm512_mask_i32gather_epi32::<1>(
                            _mm512_setzero_si512(),
                            near,
                            clamped,
                            color_ptr as *const i32,
                        ),
                        shift,
                    );
                    let count = _mm512_srli_epi32::<24>(cur);
                    let recip = _mm512_i32gather_epi32::<4>(count, RECIPROCAL_TABLE.as_ptr() as *const i32);
                    let channel = |x: __m512i, s: u32| {
                        _mm512_and_si512(_mm512_srl_epi32(x, _mm_cvtsi32_si128(s as i32)), byte_mask)
                    };
                    let nr = blend_channel(channel(cur, 0), channel(obs_c, 0), count, recip);
                    let ng = blend_channel(channel(cur, 8), channel(obs_c, 8), count, recip);
                    let nb = blend_channel(channel(cur, 16), channel(obs_c, 16), count, recip);
                    let nc = _mm512_min_epi32(_mm512_add_epi32(count, int_one), count_max);
                    let packed = _mm512_or_si512(
                        _mm512_or_si512(nr, _mm512_slli_epi32::<8>(ng)),
                        _mm512_or_si512(_mm512_slli_epi32::<16>(nb), _mm512_slli_epi32::<24>(nc)),
                    );
                    _mm512_storeu_si512(row_ptr as *mut _, _mm512_mask_blend_epi32(near, cur, packed));
                }
                (t_i, w_i)
            };
            let observed = _mm512_cmpgt_epi32_mask(w_i, _mm512_setzero_si512());
            let negative = _mm512_cmplt_epi32_mask(t_i, _mm512_setzero_si512());
            let (neg, pos) = (observed & negative, observed & !negative);
            signs.add_row(r, (neg & 0xff) as u32, (pos & 0xff) as u32);
            signs.add_row(r + 1, (neg >> 8) as u32, (pos >> 8) as u32);
        }
    }
    chunk.signs = signs.bits();
    ChunkOutcome { updated, near: near_any != 0 }
}

/// `select_row` of the parent module with AVX-512: the AVX2 walk (`avx2::select_row`) with 16
/// sampled pixels of the row at a time, one per lane, their band walks advanced together
/// sample by sample. Every quantity is computed as the portable walk computes it (same
/// operations in the same order, no fused multiply-add, `1 / steps` by division as the table
/// holds it), so all walks select the same chunks; only which repeats are filtered before the
/// merge differs.
///
/// # Safety
/// The CPU must support AVX-512F.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn select_row(view: &SelectionView, v: usize, out: &mut Candidates) {
    let row_ray = view.row_ray(v);
    let depth = &view.depth[v * view.width..(v + 1) * view.width];
    let stride = view.stride;
    let sampled = view.width.div_ceil(stride);
    // SAFETY (whole body): AVX-512F is enabled by the caller's check; depth gathers are
    // masked to sampled pixels of this row; `out.last_*` hold at least `max_steps + 1`
    // entries and `s <= max_steps`.
    unsafe {
        let splat = _mm512_set1_ps;
        let lane = _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        let left = _mm512_setr_epi32(0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14);
        let zero = _mm512_setzero_ps();
        let limit = splat(2.0 * SELECTION_OFFSET);
        let offset = _mm512_set1_epi32(SELECTION_OFFSET as i32);
        let (min_d, max_d) = (splat(view.min_depth), splat(view.max_depth));
        let (band_c, band_q, band_min) =
            (splat(view.band.constant), splat(view.band.quadratic), splat(view.band.min_relative));
        let (noise_offset, one, two) = (splat(NOISE_OFFSET), splat(1.0), splat(2.0));
        let (trunc, inv_voxel) = (splat(view.trunc), splat(view.inv_voxel));
        let (cx, fx) = (splat(view.k.cx), splat(view.k.fx));
        let (rx, ry, rz) = (splat(view.rot.x_axis.x), splat(view.rot.x_axis.y), splat(view.rot.x_axis.z));
        let (row_x, row_y, row_z) = (splat(row_ray.x), splat(row_ray.y), splat(row_ray.z));
        let (ox, oy, oz) = (splat(view.origin.x), splat(view.origin.y), splat(view.origin.z));
        let int_one = _mm512_set1_epi32(1);
        let max_steps = _mm512_set1_epi32(view.max_steps as i32);
        for g in (0..sampled).step_by(16) {
            let in_row = _mm512_cmpgt_epi32_mask(_mm512_set1_epi32((sampled - g) as i32), lane);
            let u = _mm512_mullo_epi32(
                _mm512_add_epi32(_mm512_set1_epi32(g as i32), lane),
                _mm512_set1_epi32(stride as i32),
            );
            let d = _mm512_mask_i32gather_ps::<4>(splat(f32::NAN), in_row, u, depth.as_ptr());
            let valid = _mm512_cmp_ps_mask::<_CMP_GE_OQ>(d, min_d) & _mm512_cmp_ps_mask::<_CMP_LE_OQ>(d, max_d);
            if valid == 0 {
                continue;
            }
            // `SelectionView::band_walk`, lane by lane.
            let e = _mm512_sub_ps(d, noise_offset);
            let rel = _mm512_min_ps(
                _mm512_max_ps(_mm512_add_ps(band_c, _mm512_mul_ps(band_q, _mm512_mul_ps(e, e))), band_min),
                one,
            );
            let mu = _mm512_mul_ps(rel, trunc);
            let x = _mm512_mul_ps(mu, inv_voxel);
            let whole = _mm512_cvttps_epi32(x);
            // `whole + (whole < x)`.
            let ceil = _mm512_mask_add_epi32(
                whole,
                _mm512_cmp_ps_mask::<_CMP_LT_OQ>(_mm512_cvtepi32_ps(whole), x),
                whole,
                int_one,
            );
            let steps = _mm512_min_epi32(_mm512_max_epi32(ceil, int_one), max_steps);
            let t = _mm512_div_ps(_mm512_sub_ps(_mm512_cvtepi32_ps(u), cx), fx);
            let (ray_x, ray_y, ray_z) = (
                _mm512_add_ps(_mm512_mul_ps(rx, t), row_x),
                _mm512_add_ps(_mm512_mul_ps(ry, t), row_y),
                _mm512_add_ps(_mm512_mul_ps(rz, t), row_z),
            );
            let near = _mm512_sub_ps(d, mu);
            let (px0, py0, pz0) = (
                _mm512_add_ps(ox, _mm512_mul_ps(ray_x, near)),
                _mm512_add_ps(oy, _mm512_mul_ps(ray_y, near)),
                _mm512_add_ps(oz, _mm512_mul_ps(ray_z, near)),
            );
            let len = _mm512_mul_ps(_mm512_mul_ps(two, mu), _mm512_div_ps(one, _mm512_cvtepi32_ps(steps)));
            let (sx, sy, sz) = (_mm512_mul_ps(ray_x, len), _mm512_mul_ps(ray_y, len), _mm512_mul_ps(ray_z, len));
            let mut lane_steps = [0i32; 16];
            _mm512_storeu_si512(lane_steps.as_mut_ptr() as *mut _, _mm512_maskz_mov_epi32(valid, steps));
            let most = lane_steps.iter().copied().max().unwrap_or(0) as usize;
            let walk_end = _mm512_add_epi32(steps, int_one);
            for s in 0..=most {
                let sf = splat(s as f32);
                let px = _mm512_add_ps(px0, _mm512_mul_ps(sx, sf));
                let py = _mm512_add_ps(py0, _mm512_mul_ps(sy, sf));
                let pz = _mm512_add_ps(pz0, _mm512_mul_ps(sz, sf));
                let in_range = _mm512_cmp_ps_mask::<_CMP_GE_OQ>(px, zero)
                    & _mm512_cmp_ps_mask::<_CMP_GE_OQ>(py, zero)
                    & _mm512_cmp_ps_mask::<_CMP_GE_OQ>(pz, zero)
                    & _mm512_cmp_ps_mask::<_CMP_LT_OQ>(px, limit)
                    & _mm512_cmp_ps_mask::<_CMP_LT_OQ>(py, limit)
                    & _mm512_cmp_ps_mask::<_CMP_LT_OQ>(pz, limit);
                let in_walk = _mm512_cmpgt_epi32_mask(walk_end, _mm512_set1_epi32(s as i32));
                let ok = valid & in_walk & in_range;
                if ok == 0 {
                    continue;
                }
                let kx = _mm512_sub_epi32(_mm512_cvttps_epi32(px), offset);
                let ky = _mm512_sub_epi32(_mm512_cvttps_epi32(py), offset);
                let kz = _mm512_sub_epi32(_mm512_cvttps_epi32(pz), offset);
                // A lane repeats the key of its left neighbour (when that one was in the walk)
                // or, lane 0, the last key sample `s` gave in this row.
                let prev = |k: __m512i, last: i32| {
                    _mm512_mask_mov_epi32(_mm512_permutexvar_epi32(left, k), 1, _mm512_set1_epi32(last))
                };
                let prev_ok = (ok << 1) | 1;
                let same = _mm512_cmpeq_epi32_mask(kx, prev(kx, out.last_x[s]))
                    & _mm512_cmpeq_epi32_mask(ky, prev(ky, out.last_y[s]))
                    & _mm512_cmpeq_epi32_mask(kz, prev(kz, out.last_z[s]))
                    & prev_ok;
                let mut changed = (ok & !same) as u32;
                let mut keys = [[0i32; 16]; 3];
                _mm512_storeu_si512(keys[0].as_mut_ptr() as *mut _, kx);
                _mm512_storeu_si512(keys[1].as_mut_ptr() as *mut _, ky);
                _mm512_storeu_si512(keys[2].as_mut_ptr() as *mut _, kz);
                let l = 31 - (ok as u32).leading_zeros() as usize;
                (out.last_x[s], out.last_y[s], out.last_z[s]) = (keys[0][l], keys[1][l], keys[2][l]);
                while changed != 0 {
                    let l = changed.trailing_zeros() as usize;
                    changed &= changed - 1;
                    out.push(ChunkKey::new(keys[0][l], keys[1][l], keys[2][l]));
                }
            }
        }
    }
}
