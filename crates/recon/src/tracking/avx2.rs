//! The association kernel of tracking in AVX2 intrinsics, selected at run time where the CPU
//! has AVX2.
//!
//! The portable kernel (`block_sums_lanes`) is written as per-lane loops over `[f32; 8]`;
//! compiled for AVX2, LLVM vectorises its sums but leaves the transform, the projection, the
//! pixel index and the tests as scalar code per lane with the lanes spilled to the stack
//! (perf: most of its cycles). Here a group of eight points is one AVX register throughout:
//! the model vertices and normals are fetched with hardware gathers, the distance and normal
//! tests are masks, the rejected lanes are zeroed with them.
//!
//! The arithmetic is the portable kernel's, operation for operation (no fused multiply-add,
//! the same association order, IEEE division, the same NaN outcomes of the ordered
//! comparisons), so both kernels give the same bits (unit test in the parent module).

use std::arch::x86_64::*;

use super::{LaneSums, Normals, PointBlock, StepParams, LANES};

/// `block_sums_lanes` of the parent module with AVX2.
///
/// # Safety
/// The CPU must support AVX2 and FMA; `s.vertices` and `s.normals` must hold at least
/// `s.mw * s.mh` elements, and `3 * s.mw * s.mh` must fit an `i32` (the gathers index them
/// without bounds checks); every `b.coords` vector must be `b.len` rounded up to a multiple
/// of [`LANES`] long.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn block_sums(b: &PointBlock, s: &StepParams) -> Normals {
    let mut out = LaneSums::ZERO;
    // SAFETY (whole body): AVX2 is enabled by the caller's check; loads read `g..g + 8` of
    // coordinate vectors padded to a multiple of 8 past `len`; gather indices are model
    // pixel indices below `mw * mh` (rejected lanes read pixel 0), times 3 plus a component.
    unsafe {
        let splat = _mm256_set1_ps;
        let [r0, r1, r2] = s.rot;
        // Rotation entries by output row (x, y, z), one per column.
        let (c0x, c1x, c2x) = (splat(r0[0]), splat(r1[0]), splat(r2[0]));
        let (c0y, c1y, c2y) = (splat(r0[1]), splat(r1[1]), splat(r2[1]));
        let (c0z, c1z, c2z) = (splat(r0[2]), splat(r1[2]), splat(r2[2]));
        let (tx, ty, tz) = (splat(s.trans[0]), splat(s.trans[1]), splat(s.trans[2]));
        let (fx, fy, cx, cy) = (splat(s.fx), splat(s.fy), splat(s.cx), splat(s.cy));
        let (mwf, mhf) = (splat(s.mw as f32), splat(s.mh as f32));
        let mw = _mm256_set1_epi32(s.mw as i32);
        let (zero, half, one) = (_mm256_setzero_ps(), splat(0.5), splat(1.0));
        let (max_d2, min_cos, huber) = (splat(s.max_d2), splat(s.min_cos), splat(s.huber));
        let sign = splat(-0.0);
        let lane_ids = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        let vptr = s.vertices.as_ptr() as *const f32;
        let nptr = s.normals.as_ptr() as *const f32;
        let mut acc = [_mm256_setzero_ps(); 27];
        let (mut sr, mut sn) = ([_mm256_setzero_pd(); 2], [_mm256_setzero_pd(); 2]);
        let (mut c_in, mut c_far, mut c_turned) =
            (_mm256_setzero_si256(), _mm256_setzero_si256(), _mm256_setzero_si256());
        let [px, py, pz, nx, ny, nz] = &b.coords;
        let mut g = 0;
        while g < b.len {
            let ld = |v: &Vec<f32>| _mm256_loadu_ps(v.as_ptr().add(g));
            let (px, py, pz) = (ld(px), ld(py), ld(pz));
            let (nx, ny, nz) = (ld(nx), ld(ny), ld(nz));
            let (add, mul, div, sub) = (_mm256_add_ps, _mm256_mul_ps, _mm256_div_ps, _mm256_sub_ps);
            // glam's `rot * p + trans`, operation for operation.
            let qx = add(add(add(mul(c0x, px), mul(c1x, py)), mul(c2x, pz)), tx);
            let qy = add(add(add(mul(c0y, px), mul(c1y, py)), mul(c2y, pz)), ty);
            let qz = add(add(add(mul(c0z, px), mul(c1z, py)), mul(c2z, pz)), tz);
            let fu = add(add(div(mul(fx, qx), qz), cx), half);
            let fv = add(add(div(mul(fy, qy), qz), cy), half);
            let in_block = _mm256_castsi256_ps(_mm256_cmpgt_epi32(_mm256_set1_epi32((b.len - g) as i32), lane_ids));
            let ok = _mm256_and_ps(
                _mm256_and_ps(
                    _mm256_and_ps(in_block, _mm256_cmp_ps::<_CMP_GT_OQ>(qz, zero)),
                    _mm256_and_ps(_mm256_cmp_ps::<_CMP_GE_OQ>(fu, zero), _mm256_cmp_ps::<_CMP_GE_OQ>(fv, zero)),
                ),
                _mm256_and_ps(_mm256_cmp_ps::<_CMP_LT_OQ>(fu, mwf), _mm256_cmp_ps::<_CMP_LT_OQ>(fv, mhf)),
            );
            let okm = _mm256_castps_si256(ok);
            let mi = _mm256_and_si256(
                _mm256_add_epi32(_mm256_mullo_epi32(_mm256_cvttps_epi32(fv), mw), _mm256_cvttps_epi32(fu)),
                okm,
            );
            let m3 = _mm256_add_epi32(mi, _mm256_add_epi32(mi, mi));
            let mx = _mm256_i32gather_ps::<4>(vptr, m3);
            let my = _mm256_i32gather_ps::<4>(vptr.add(1), m3);
            let mz = _mm256_i32gather_ps::<4>(vptr.add(2), m3);
            let mnx = _mm256_i32gather_ps::<4>(nptr, m3);
            let mny = _mm256_i32gather_ps::<4>(nptr.add(1), m3);
            let mnz = _mm256_i32gather_ps::<4>(nptr.add(2), m3);
            let on_model = _mm256_and_ps(ok, _mm256_cmp_ps::<_CMP_GT_OQ>(mz, zero));
            let (dx, dy, dz) = (sub(qx, mx), sub(qy, my), sub(qz, mz));
            let d2 = add(add(mul(dx, dx), mul(dy, dy)), mul(dz, dz));
            let is_far = _mm256_and_ps(on_model, _mm256_cmp_ps::<_CMP_GT_OQ>(d2, max_d2));
            let near = _mm256_andnot_ps(is_far, on_model);
            let nrx = add(add(mul(c0x, nx), mul(c1x, ny)), mul(c2x, nz));
            let nry = add(add(mul(c0y, nx), mul(c1y, ny)), mul(c2y, nz));
            let nrz = add(add(mul(c0z, nx), mul(c1z, ny)), mul(c2z, nz));
            let dot = add(add(mul(nrx, mnx), mul(nry, mny)), mul(nrz, mnz));
            let is_turned = _mm256_and_ps(near, _mm256_cmp_ps::<_CMP_LT_OQ>(dot, min_cos));
            let inlier = _mm256_andnot_ps(is_turned, near);
            c_far = _mm256_sub_epi32(c_far, _mm256_castps_si256(is_far));
            c_turned = _mm256_sub_epi32(c_turned, _mm256_castps_si256(is_turned));
            c_in = _mm256_sub_epi32(c_in, _mm256_castps_si256(inlier));
            let res = add(add(mul(mnx, dx), mul(mny, dy)), mul(mnz, dz));
            // `max` returns its second operand for a NaN, as `f32::max(NaN, 0.5)` gives 0.5.
            let z = _mm256_max_ps(mz, half);
            let scale = mul(z, z);
            let a = _mm256_andnot_ps(sign, div(res, scale));
            let hub = _mm256_blendv_ps(div(huber, a), one, _mm256_cmp_ps::<_CMP_LE_OQ>(a, huber));
            let w = div(hub, mul(scale, scale));
            // The lever arm from the model point (see `normal_equations`).
            let j = [
                sub(mul(my, mnz), mul(mny, mz)),
                sub(mul(mz, mnx), mul(mnz, mx)),
                sub(mul(mx, mny), mul(mnx, my)),
                mnx,
                mny,
                mnz,
            ]
            .map(|v| _mm256_and_ps(v, inlier));
            let r = _mm256_and_ps(res, inlier);
            let wgt = _mm256_and_ps(w, inlier);
            let sd = _mm256_blendv_ps(one, scale, inlier);
            let halves = |v: __m256| {
                [_mm256_cvtps_pd(_mm256_castps256_ps128(v)), _mm256_cvtps_pd(_mm256_extractf128_ps::<1>(v))]
            };
            let (rd, sdd) = (halves(r), halves(sd));
            for h in 0..2 {
                sr[h] = _mm256_add_pd(sr[h], _mm256_mul_pd(rd[h], rd[h]));
                let q = _mm256_div_pd(rd[h], sdd[h]);
                sn[h] = _mm256_add_pd(sn[h], _mm256_mul_pd(q, q));
            }
            let mut k = 0;
            for a in 0..6 {
                let wa = mul(wgt, j[a]);
                for bb in a..6 {
                    acc[k] = add(acc[k], mul(wa, j[bb]));
                    k += 1;
                }
                acc[21 + a] = add(acc[21 + a], mul(wa, r));
            }
            g += LANES;
        }
        for (dst, v) in out.sums.iter_mut().zip(&acc) {
            _mm256_storeu_ps(dst.as_mut_ptr(), *v);
        }
        for h in 0..2 {
            _mm256_storeu_pd(out.sq_res.as_mut_ptr().add(4 * h), sr[h]);
            _mm256_storeu_pd(out.sq_norm.as_mut_ptr().add(4 * h), sn[h]);
        }
        for (dst, v) in [(&mut out.inliers, c_in), (&mut out.far, c_far), (&mut out.turned, c_turned)] {
            _mm256_storeu_si256(dst.as_mut_ptr() as *mut __m256i, v);
        }
    }
    out.into_normals()
}
