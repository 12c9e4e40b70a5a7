//! The integration kernel in AVX2 intrinsics, selected at run time where the CPU has AVX2.
//!
//! The portable kernel is written with `wide::f32x8`, which the baseline build (SSE2) turns
//! into pairs of SSE operations with the depth gather, the pixel index and the colour blend
//! done lane by lane. Here one row of 8 voxels is one AVX register throughout: the depths
//! and the colours are fetched with hardware gathers and the colour running mean of the
//! voxels near the surface is blended in 32-bit lanes instead of a scalar loop per voxel.
//!
//! The arithmetic is the portable kernel's operation for operation (no fused multiply-add,
//! same rounding), so both kernels, and the scalar specification `Voxel::fuse`, give the
//! same bits.

use std::arch::x86_64::*;
use std::mem::MaybeUninit;

use super::{Candidates, ChunkOutcome, FrameView, SelectionView, SELECTION_OFFSET};
use crate::map::{
    Chunk, ChunkKey, SignSummary, CHUNK_SIDE, COLOR_WARMUP, NOISE_OFFSET, RECIPROCALS, TSDF_SCALE, WEIGHT_SCALE,
};

/// The colour running mean's reciprocals, in memory for the gather.
static RECIPROCAL_TABLE: [u32; 256] = RECIPROCALS;

/// Rounds half away from zero like `wide`'s `round` and `map::round_half_away`:
/// `trunc(|x| + 0.5)` with the sign restored, the largest float below 0.5 rounding to 0.
/// Inputs here are far below 2^23 in magnitude.
#[inline(always)]
unsafe fn round_half_away(x: __m256) -> __m256 {
    // SAFETY: register-only intrinsics of the features the caller enables.
    unsafe {
        let sign = _mm256_set1_ps(-0.0);
        let abs = _mm256_andnot_ps(sign, x);
        let r = _mm256_round_ps::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(_mm256_add_ps(abs, _mm256_set1_ps(0.5)));
        let r = _mm256_andnot_ps(_mm256_cmp_ps::<_CMP_EQ_OQ>(abs, _mm256_set1_ps(0.5f32.next_down())), r);
        _mm256_or_ps(r, _mm256_and_ps(sign, x))
    }
}

/// One colour channel of `map::blend_color` in 32-bit lanes: `((c n + o) recip + 2^15) >> 16`
/// (no overflow: at most `(255 * 255 + 255) * 65536 + 2^15 < 2^32`).
#[inline(always)]
unsafe fn blend_channel(c: __m256i, o: __m256i, count: __m256i, recip: __m256i) -> __m256i {
    // SAFETY: register-only intrinsics of the features the caller enables.
    unsafe {
        let sum = _mm256_add_epi32(_mm256_mullo_epi32(c, count), o);
        let c = _mm256_srli_epi32::<16>(_mm256_add_epi32(_mm256_mullo_epi32(sum, recip), _mm256_set1_epi32(1 << 15)));
        _mm256_and_si256(c, _mm256_set1_epi32(0xff))
    }
}

/// `integrate_chunk` of the parent module with AVX2.
///
/// # Safety
/// The CPU must support AVX2 and FMA, and the frame must have fewer than 2^24 pixels (pixel
/// indices are formed in f32 and gathered without bounds checks).
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn integrate_chunk<const DEPTH_BAND: bool>(chunk: &mut Chunk, f: &FrameView) -> ChunkOutcome {
    const N: usize = CHUNK_SIDE;
    let [base, dx, dy, dz] = f.chunk_axes(chunk.key);
    let n_pix = f.depth.len();
    let has_color = !f.color.is_empty();
    let block = &mut *chunk.voxels;
    let mut updated = 0u32;
    let mut signs = SignSummary::default();
    // SAFETY (whole body): AVX2/FMA are enabled by the caller's check; every gather index
    // is a pixel index below `n_pix` (lanes off the image read pixel 0, masked afterwards),
    // colour gathers read 4 bytes at most at byte `3 n_pix - 4`, the table index is a
    // count below 256, and row loads/stores stay within the chunk's 512-voxel arrays.
    let near = unsafe {
        let splat = _mm256_set1_ps;
        let steps = _mm256_setr_ps(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0);
        let (step_x, step_y, step_z) =
            (_mm256_mul_ps(steps, splat(dx.x)), _mm256_mul_ps(steps, splat(dx.y)), _mm256_mul_ps(steps, splat(dx.z)));
        let (fx, fy, cx, cy) = (splat(f.k.fx), splat(f.k.fy), splat(f.k.cx), splat(f.k.cy));
        let (wf, hf) = (splat(f.k.width as f32 - 0.5), splat(f.k.height as f32 - 0.5));
        let width = splat(f.k.width as f32);
        let (min_d, max_d) = (splat(f.min_depth), splat(f.max_depth));
        let inv_trunc = splat(1.0 / f.truncation);
        let (band_c, band_q, band_min) = (splat(f.band.constant), splat(f.band.quadratic), splat(f.band.min_relative));
        let noise_offset = splat(NOISE_OFFSET);
        let (zero, half, one) = (_mm256_setzero_ps(), splat(0.5), splat(1.0));
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
        let last_color_offset = _mm256_set1_epi32((3 * n_pix).saturating_sub(4) as i32);
        let byte_mask = _mm256_set1_epi32(0xff);
        let count_max = _mm256_set1_epi32(255);
        let int_one = _mm256_set1_epi32(1);
        let tsdf_ptr = block.tsdf.as_mut_ptr();
        let weight_ptr = block.weight.as_mut_ptr();
        let color_rows = block.color.as_mut_ptr() as *mut u8;
        let mut near_lanes = _mm256_setzero_ps();
        // The block's rows are needed by the second pass: start fetching them now.
        for line in (0..N * N * N).step_by(32) {
            _mm_prefetch::<_MM_HINT_T0>(tsdf_ptr.add(line) as *const i8);
            _mm_prefetch::<_MM_HINT_T0>(weight_ptr.add(line) as *const i8);
        }
        for line in (0..N * N * N * 4).step_by(64) {
            _mm_prefetch::<_MM_HINT_T0>(color_rows.add(line) as *const i8);
        }
        // First pass: project every row and gather its depths. The rows are independent and
        // short, so many gathers are in flight at once; the update pass then finds the
        // depths ready instead of waiting for each row's gather in turn. Lanes off the image
        // read NaN, which fails every validity test below as `inside` did.
        let nan = splat(f32::NAN);
        // Every entry is written by the first pass before the second reads it; left
        // uninitialised, not zeroed (6 KiB per chunk).
        let mut row_pz = [MaybeUninit::<__m256>::uninit(); N * N];
        let mut row_d = [MaybeUninit::<__m256>::uninit(); N * N];
        let mut row_pix = [MaybeUninit::<__m256i>::uninit(); N * N];
        for r in 0..N * N {
            let (y, z) = ((r % N) as f32, (r / N) as f32);
            let row = base + dy * y + dz * z;
            let pz = _mm256_add_ps(splat(row.z), step_z);
            let inv_z = _mm256_div_ps(one, pz);
            let u = _mm256_add_ps(_mm256_mul_ps(_mm256_mul_ps(fx, _mm256_add_ps(splat(row.x), step_x)), inv_z), cx);
            let v = _mm256_add_ps(_mm256_mul_ps(_mm256_mul_ps(fy, _mm256_add_ps(splat(row.y), step_y)), inv_z), cy);
            let inside = _mm256_and_ps(
                _mm256_and_ps(
                    _mm256_and_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(pz, zero), _mm256_cmp_ps::<_CMP_GE_OQ>(u, neg_half)),
                    _mm256_and_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(u, wf), _mm256_cmp_ps::<_CMP_GE_OQ>(v, neg_half)),
                ),
                _mm256_cmp_ps::<_CMP_LT_OQ>(v, hf),
            );
            // Inside lanes have u + 0.5 and v + 0.5 in [0, size): truncation is floor and
            // the index is exact in f32 (below 2^24 pixels).
            let pu = _mm256_round_ps::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(_mm256_add_ps(u, half));
            let pv = _mm256_round_ps::<{ _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC }>(_mm256_add_ps(v, half));
            let pix_f = _mm256_and_ps(inside, _mm256_add_ps(_mm256_mul_ps(pv, width), pu));
            let pix = _mm256_cvttps_epi32(pix_f);
            row_pz[r].write(pz);
            row_d[r].write(_mm256_mask_i32gather_ps::<4>(nan, depth_ptr, pix, inside));
            row_pix[r].write(pix);
        }
        for r in 0..N * N {
            let tsdf_row = tsdf_ptr.add(r * N) as *mut __m128i;
            let weight_row = weight_ptr.add(r * N) as *mut __m128i;
            let t_old_i = _mm256_cvtepi16_epi32(_mm_loadu_si128(tsdf_row));
            let w_old_i = _mm256_cvtepu16_epi32(_mm_loadu_si128(weight_row));
            let (pz, d, pix) = (row_pz[r].assume_init(), row_d[r].assume_init(), row_pix[r].assume_init());
            let (t_now, w_now) = 'row: {
                let sdf = _mm256_mul_ps(_mm256_sub_ps(d, pz), inv_trunc);
                let mu = if DEPTH_BAND {
                    let e = _mm256_sub_ps(d, noise_offset);
                    _mm256_min_ps(
                        _mm256_max_ps(_mm256_add_ps(band_c, _mm256_mul_ps(band_q, _mm256_mul_ps(e, e))), band_min),
                        one,
                    )
                } else {
                    one
                };
                let neg_mu = _mm256_sub_ps(zero, mu);
                let valid = _mm256_and_ps(
                    _mm256_cmp_ps::<_CMP_GE_OQ>(d, min_d),
                    _mm256_and_ps(
                        _mm256_cmp_ps::<_CMP_LE_OQ>(d, max_d),
                        _mm256_cmp_ps::<_CMP_GE_OQ>(sdf, _mm256_mul_ps(neg_mu, behind)),
                    ),
                );
                // With the gathers done in the first pass, branching on the outcome pays: a
                // quarter of the rows see no valid observation and keep their voxels.
                let valid_bits = _mm256_movemask_ps(valid) as u32;
                if valid_bits == 0 {
                    break 'row (t_old_i, w_old_i);
                }
                let t_old = _mm256_cvtepi32_ps(t_old_i);
                let w_old_q = _mm256_cvtepi32_ps(w_old_i);
                let obs = _mm256_max_ps(_mm256_min_ps(sdf, mu), neg_mu);
                let w_obs = _mm256_and_ps(
                    valid,
                    _mm256_mul_ps(_mm256_min_ps(_mm256_div_ps(one, _mm256_mul_ps(d, d)), four), obs_scale),
                );
                let w_old = _mm256_mul_ps(w_old_q, inv_wscale);
                let w_sum = _mm256_add_ps(w_old, w_obs);
                let inv = _mm256_div_ps(one, _mm256_max_ps(w_sum, tiny));
                let a = _mm256_mul_ps(w_old, inv);
                let b = _mm256_mul_ps(w_obs, inv);
                let t = _mm256_add_ps(_mm256_mul_ps(t_old, a), _mm256_mul_ps(obs, _mm256_mul_ps(b, tscale)));
                let t_new = _mm256_blendv_ps(t_old, round_half_away(t), valid);
                let w_q = _mm256_min_ps(_mm256_max_ps(round_half_away(_mm256_mul_ps(w_sum, wscale)), one), cap);
                let w_new = _mm256_blendv_ps(w_old_q, w_q, valid);
                // Integral and in range: conversions and packs are exact.
                let t_i = _mm256_cvttps_epi32(t_new);
                let w_i = _mm256_cvttps_epi32(w_new);
                _mm_storeu_si128(
                    tsdf_row,
                    _mm_packs_epi32(_mm256_castsi256_si128(t_i), _mm256_extracti128_si256::<1>(t_i)),
                );
                _mm_storeu_si128(
                    weight_row,
                    _mm_packus_epi32(_mm256_castsi256_si128(w_i), _mm256_extracti128_si256::<1>(w_i)),
                );
                updated += valid_bits.count_ones();
                let near = _mm256_and_ps(valid, _mm256_cmp_ps::<_CMP_LT_OQ>(sdf, mu));
                near_lanes = _mm256_or_ps(near_lanes, near);
                // Half the rows have no voxel near the surface: their colours stay as they are.
                if has_color && _mm256_movemask_ps(near) != 0 {
                    let row_ptr = color_rows.add(r * N * 4) as *mut __m256i;
                    let cur = _mm256_loadu_si256(row_ptr);
                    // Colour only within the colour band; off colour frames only voxels still
                    // warming up take a colour.
                    let colored = _mm256_and_ps(
                        near,
                        _mm256_and_ps(
                            _mm256_cmp_ps::<_CMP_LT_OQ>(sdf, color_band),
                            _mm256_cmp_ps::<_CMP_GE_OQ>(sdf, neg_color_band),
                        ),
                    );
                    let near_i = if f.color_all {
                        _mm256_castps_si256(colored)
                    } else {
                        let uncoloured =
                            _mm256_cmpgt_epi32(_mm256_set1_epi32(COLOR_WARMUP as i32), _mm256_srli_epi32::<24>(cur));
                        _mm256_and_si256(_mm256_castps_si256(colored), uncoloured)
                    };
                    if _mm256_testz_si256(near_i, near_i) == 0 {
                        // The observed colours, `[r, g, b, x]` per lane.
                        let offset = _mm256_mullo_epi32(pix, _mm256_set1_epi32(3));
                        let clamped = _mm256_min_epi32(offset, last_color_offset);
                        let shift = _mm256_slli_epi32::<3>(_mm256_sub_epi32(offset, clamped));
                        let obs_c = _mm256_srlv_epi32(
                            _mm256_mask_i32gather_epi32::<1>(
                                _mm256_setzero_si256(),
                                color_ptr as *const i32,
                                clamped,
                                near_i,
                            ),
                            shift,
                        );
                        let count = _mm256_srli_epi32::<24>(cur);
                        let recip = _mm256_i32gather_epi32::<4>(RECIPROCAL_TABLE.as_ptr() as *const i32, count);
                        let nr = blend_channel(
                            _mm256_and_si256(cur, byte_mask),
                            _mm256_and_si256(obs_c, byte_mask),
                            count,
                            recip,
                        );
                        let ng = blend_channel(
                            _mm256_and_si256(_mm256_srli_epi32::<8>(cur), byte_mask),
                            _mm256_and_si256(_mm256_srli_epi32::<8>(obs_c), byte_mask),
                            count,
                            recip,
                        );
                        let nb = blend_channel(
                            _mm256_and_si256(_mm256_srli_epi32::<16>(cur), byte_mask),
                            _mm256_and_si256(_mm256_srli_epi32::<16>(obs_c), byte_mask),
                            count,
                            recip,
                        );
                        let nc = _mm256_min_epi32(_mm256_add_epi32(count, int_one), count_max);
                        let packed = _mm256_or_si256(
                            _mm256_or_si256(nr, _mm256_slli_epi32::<8>(ng)),
                            _mm256_or_si256(_mm256_slli_epi32::<16>(nb), _mm256_slli_epi32::<24>(nc)),
                        );
                        _mm256_storeu_si256(row_ptr, _mm256_blendv_epi8(cur, packed, near_i));
                    }
                }
                (t_i, w_i)
            };
            let observed = _mm256_cmpgt_epi32(w_now, _mm256_setzero_si256());
            let negative = _mm256_cmpgt_epi32(_mm256_setzero_si256(), t_now);
            let neg = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_and_si256(observed, negative))) as u32;
            let pos = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_andnot_si256(negative, observed))) as u32;
            signs.add_row(r, neg, pos);
        }
        _mm256_movemask_ps(near_lanes) != 0
    };
    chunk.signs = signs.bits();
    ChunkOutcome { updated, near }
}

/// `select_row` of the parent module with AVX2: 8 sampled pixels of the row at a time, one
/// per lane, their band walks advanced together sample by sample. Every quantity is computed
/// as the portable walk computes it (same operations in the same order, no fused
/// multiply-add, `1 / steps` by division as the table holds it), so both select the same
/// chunks; only which repeats are filtered before the merge differs.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn select_row(view: &SelectionView, v: usize, out: &mut Candidates) {
    let row_ray = view.row_ray(v);
    let depth = &view.depth[v * view.width..(v + 1) * view.width];
    let stride = view.stride;
    let sampled = view.width.div_ceil(stride);
    // SAFETY (whole body): AVX2/FMA are enabled by the caller's check; depth gathers are
    // masked to sampled pixels of this row; `out.last_*` hold at least `max_steps + 1`
    // entries and `s <= max_steps`.
    unsafe {
        let splat = _mm256_set1_ps;
        let lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let left = _mm256_setr_epi32(0, 0, 1, 2, 3, 4, 5, 6);
        let zero = _mm256_setzero_ps();
        let limit = splat(2.0 * SELECTION_OFFSET);
        let offset = _mm256_set1_epi32(SELECTION_OFFSET as i32);
        let (min_d, max_d) = (splat(view.min_depth), splat(view.max_depth));
        let (band_c, band_q, band_min) =
            (splat(view.band.constant), splat(view.band.quadratic), splat(view.band.min_relative));
        let (noise_offset, one, two) = (splat(NOISE_OFFSET), splat(1.0), splat(2.0));
        let (trunc, inv_voxel) = (splat(view.trunc), splat(view.inv_voxel));
        let (cx, fx) = (splat(view.k.cx), splat(view.k.fx));
        let (rx, ry, rz) = (splat(view.rot.x_axis.x), splat(view.rot.x_axis.y), splat(view.rot.x_axis.z));
        let (row_x, row_y, row_z) = (splat(row_ray.x), splat(row_ray.y), splat(row_ray.z));
        let (ox, oy, oz) = (splat(view.origin.x), splat(view.origin.y), splat(view.origin.z));
        let (min_steps, max_steps) = (_mm256_set1_epi32(1), _mm256_set1_epi32(view.max_steps as i32));
        let lane0 = _mm256_setr_epi32(-1, 0, 0, 0, 0, 0, 0, 0);
        for g in (0..sampled).step_by(8) {
            let in_row = _mm256_cmpgt_epi32(_mm256_set1_epi32((sampled - g) as i32), lane);
            let u = _mm256_mullo_epi32(
                _mm256_add_epi32(_mm256_set1_epi32(g as i32), lane),
                _mm256_set1_epi32(stride as i32),
            );
            let d = _mm256_mask_i32gather_ps::<4>(splat(f32::NAN), depth.as_ptr(), u, _mm256_castsi256_ps(in_row));
            let valid = _mm256_and_ps(_mm256_cmp_ps::<_CMP_GE_OQ>(d, min_d), _mm256_cmp_ps::<_CMP_LE_OQ>(d, max_d));
            if _mm256_movemask_ps(valid) == 0 {
                continue;
            }
            // `SelectionView::band_walk`, lane by lane.
            let e = _mm256_sub_ps(d, noise_offset);
            let rel = _mm256_min_ps(
                _mm256_max_ps(_mm256_add_ps(band_c, _mm256_mul_ps(band_q, _mm256_mul_ps(e, e))), band_min),
                one,
            );
            let mu = _mm256_mul_ps(rel, trunc);
            let x = _mm256_mul_ps(mu, inv_voxel);
            let whole = _mm256_cvttps_epi32(x);
            // `whole + (whole < x)`: the comparison mask is -1 where true.
            let ceil =
                _mm256_sub_epi32(whole, _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LT_OQ>(_mm256_cvtepi32_ps(whole), x)));
            let steps = _mm256_min_epi32(_mm256_max_epi32(ceil, min_steps), max_steps);
            let t = _mm256_div_ps(_mm256_sub_ps(_mm256_cvtepi32_ps(u), cx), fx);
            let (ray_x, ray_y, ray_z) = (
                _mm256_add_ps(_mm256_mul_ps(rx, t), row_x),
                _mm256_add_ps(_mm256_mul_ps(ry, t), row_y),
                _mm256_add_ps(_mm256_mul_ps(rz, t), row_z),
            );
            let near = _mm256_sub_ps(d, mu);
            let (px0, py0, pz0) = (
                _mm256_add_ps(ox, _mm256_mul_ps(ray_x, near)),
                _mm256_add_ps(oy, _mm256_mul_ps(ray_y, near)),
                _mm256_add_ps(oz, _mm256_mul_ps(ray_z, near)),
            );
            let len = _mm256_mul_ps(_mm256_mul_ps(two, mu), _mm256_div_ps(one, _mm256_cvtepi32_ps(steps)));
            let (sx, sy, sz) = (_mm256_mul_ps(ray_x, len), _mm256_mul_ps(ray_y, len), _mm256_mul_ps(ray_z, len));
            let mut lane_steps = [0i32; 8];
            _mm256_storeu_si256(
                lane_steps.as_mut_ptr() as *mut __m256i,
                _mm256_and_si256(steps, _mm256_castps_si256(valid)),
            );
            let most = lane_steps.iter().copied().max().unwrap_or(0) as usize;
            for s in 0..=most {
                let sf = splat(s as f32);
                let px = _mm256_add_ps(px0, _mm256_mul_ps(sx, sf));
                let py = _mm256_add_ps(py0, _mm256_mul_ps(sy, sf));
                let pz = _mm256_add_ps(pz0, _mm256_mul_ps(sz, sf));
                let in_range = _mm256_and_ps(
                    _mm256_and_ps(
                        _mm256_and_ps(_mm256_cmp_ps::<_CMP_GE_OQ>(px, zero), _mm256_cmp_ps::<_CMP_GE_OQ>(py, zero)),
                        _mm256_and_ps(_mm256_cmp_ps::<_CMP_GE_OQ>(pz, zero), _mm256_cmp_ps::<_CMP_LT_OQ>(px, limit)),
                    ),
                    _mm256_and_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(py, limit), _mm256_cmp_ps::<_CMP_LT_OQ>(pz, limit)),
                );
                let in_walk = _mm256_castsi256_ps(_mm256_cmpgt_epi32(
                    _mm256_add_epi32(steps, min_steps),
                    _mm256_set1_epi32(s as i32),
                ));
                let ok = _mm256_castps_si256(_mm256_and_ps(_mm256_and_ps(valid, in_walk), in_range));
                let ok_bits = _mm256_movemask_ps(_mm256_castsi256_ps(ok)) as u32;
                if ok_bits == 0 {
                    continue;
                }
                let kx = _mm256_sub_epi32(_mm256_cvttps_epi32(px), offset);
                let ky = _mm256_sub_epi32(_mm256_cvttps_epi32(py), offset);
                let kz = _mm256_sub_epi32(_mm256_cvttps_epi32(pz), offset);
                // A lane repeats the key of its left neighbour (when that one was in the walk)
                // or, lane 0, the last key sample `s` gave in this row.
                let prev = |k: __m256i, last: i32| {
                    _mm256_blendv_epi8(_mm256_permutevar8x32_epi32(k, left), _mm256_set1_epi32(last), lane0)
                };
                let prev_ok = _mm256_or_si256(_mm256_permutevar8x32_epi32(ok, left), lane0);
                let same = _mm256_and_si256(
                    _mm256_and_si256(
                        _mm256_cmpeq_epi32(kx, prev(kx, out.last_x[s])),
                        _mm256_cmpeq_epi32(ky, prev(ky, out.last_y[s])),
                    ),
                    _mm256_and_si256(_mm256_cmpeq_epi32(kz, prev(kz, out.last_z[s])), prev_ok),
                );
                let mut changed = _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_andnot_si256(same, ok))) as u32;
                let mut keys = [[0i32; 8]; 3];
                _mm256_storeu_si256(keys[0].as_mut_ptr() as *mut __m256i, kx);
                _mm256_storeu_si256(keys[1].as_mut_ptr() as *mut __m256i, ky);
                _mm256_storeu_si256(keys[2].as_mut_ptr() as *mut __m256i, kz);
                let l = 31 - ok_bits.leading_zeros() as usize;
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
