//! Vertex batches in AVX2 intrinsics, for CPUs without AVX-512F (selected at run time): the
//! AVX-512 kernel's steps on two halves of eight lanes, with blends instead of mask
//! registers.
//!
//! The arithmetic is [`super::vertices::vertex`]'s, operation for operation and in the same order (no
//! fused multiply-add), so all kernels give the same bits.

use std::arch::x86_64::*;

use glam::IVec3;

use super::{PaddedBlock, VertexLanes, LANES, PAD, PAD2};
use crate::map::TSDF_SCALE;

/// [`super::vertices::vertices_scalar`] with AVX2.
///
/// # Safety
/// The CPU must support AVX2, and every job must name an edge between padded coordinates
/// 1 ..= 9 (as the crossed edges of a chunk's cells do), so that the ends and their six
/// neighbours lie in the block.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn vertices(
    block: &PaddedBlock,
    jobs: &[u32; LANES],
    key_voxel: IVec3,
    voxel_size: f32,
    out: &mut VertexLanes,
) {
    for half in 0..LANES / 8 {
        // SAFETY: as for the whole function; `half * 8 + 8 <= LANES`.
        unsafe { half_batch(block, jobs, half * 8, key_voxel, voxel_size, out) }
    }
}

/// Lanes `at .. at + 8` of [`vertices`].
#[target_feature(enable = "avx2")]
unsafe fn half_batch(
    block: &PaddedBlock,
    jobs: &[u32; LANES],
    at: usize,
    key_voxel: IVec3,
    voxel_size: f32,
    out: &mut VertexLanes,
) {
    // SAFETY (whole body): AVX2 is enabled by the caller's check; gather indices are the
    // jobs' ends (padded 1 ..= 9 on every axis) and their neighbours one step along an axis
    // (padded 0 ..= 10), all inside `packed` and `color`; loads and stores are of 8 lanes
    // from `at`, inside the 16-lane arrays.
    unsafe {
        let packed = block.packed.as_ptr();
        let colors = block.color.as_ptr() as *const i32;
        let j = _mm256_loadu_si256(jobs.as_ptr().add(at) as *const _);
        let ia = _mm256_and_si256(j, _mm256_set1_epi32(0x7ff));
        let axis = _mm256_and_si256(_mm256_srli_epi32::<11>(j), _mm256_set1_epi32(3));
        let strides = [1, PAD as i32, PAD2 as i32];
        let stride = _mm256_permutevar8x32_epi32(_mm256_setr_epi32(1, PAD as i32, PAD2 as i32, 0, 0, 0, 0, 0), axis);
        let ib = _mm256_add_epi32(ia, stride);
        let raw = |v: __m256i| _mm256_cvtepi32_ps(_mm256_srai_epi32::<16>(v));
        let (pa, pb) = (_mm256_i32gather_epi32::<4>(packed, ia), _mm256_i32gather_epi32::<4>(packed, ib));
        let (ta, tb) = (raw(pa), raw(pb));
        let scale = _mm256_set1_ps(1.0 / TSDF_SCALE);
        let (fa, fb) = (_mm256_mul_ps(ta, scale), _mm256_mul_ps(tb, scale));
        let s = _mm256_div_ps(fa, _mm256_sub_ps(fa, fb));
        let select = |mask: __m256i, yes: __m256, no: __m256| _mm256_blendv_ps(no, yes, _mm256_castsi256_ps(mask));

        let key = key_voxel.to_array();
        let vs = _mm256_set1_ps(voxel_size);
        for (a, dst) in out.position.iter_mut().enumerate() {
            let low =
                _mm256_and_si256(_mm256_srlv_epi32(j, _mm256_set1_epi32(13 + 4 * a as i32)), _mm256_set1_epi32(15));
            let p = _mm256_cvtepi32_ps(_mm256_add_epi32(low, _mm256_set1_epi32(key[a])));
            let on_axis = _mm256_cmpeq_epi32(axis, _mm256_set1_epi32(a as i32));
            let p = select(on_axis, _mm256_add_ps(p, s), p);
            _mm256_storeu_ps(dst.as_mut_ptr().add(at), _mm256_mul_ps(p, vs));
        }

        let (ca, cb) = (_mm256_i32gather_epi32::<4>(colors, ia), _mm256_i32gather_epi32::<4>(colors, ib));
        let count = _mm256_set1_epi32(0xff00_0000u32 as i32);
        let zero_i = _mm256_setzero_si256();
        let none_a = _mm256_cmpeq_epi32(_mm256_and_si256(ca, count), zero_i);
        let none_b = _mm256_cmpeq_epi32(_mm256_and_si256(cb, count), zero_i);
        let ca2 = _mm256_blendv_epi8(ca, cb, _mm256_andnot_si256(none_b, none_a));
        let cb2 = _mm256_blendv_epi8(cb, ca, _mm256_andnot_si256(none_a, none_b));
        let byte = _mm256_set1_epi32(0xff);
        let half = _mm256_set1_ps(0.5);
        let mut color = _mm256_setzero_si256();
        for k in 0..3 {
            let shift = _mm256_set1_epi32(8 * k);
            let channel = |c: __m256i| _mm256_cvtepi32_ps(_mm256_and_si256(_mm256_srlv_epi32(c, shift), byte));
            let (a, b) = (channel(ca2), channel(cb2));
            let v = _mm256_add_ps(_mm256_add_ps(a, _mm256_mul_ps(s, _mm256_sub_ps(b, a))), half);
            let v = _mm256_and_si256(_mm256_cvttps_epi32(v), byte);
            color = _mm256_or_si256(color, _mm256_sllv_epi32(v, shift));
        }
        _mm256_storeu_si256(out.color.as_mut_ptr().add(at) as *mut _, color);

        let observed = _mm256_set1_epi32(super::OBSERVED as i32);
        let zero = _mm256_setzero_ps();
        let gradient = |i: __m256i, t: __m256, step: i32| {
            let step = _mm256_set1_epi32(step);
            let lo = _mm256_i32gather_epi32::<4>(packed, _mm256_sub_epi32(i, step));
            let hi = _mm256_i32gather_epi32::<4>(packed, _mm256_add_epi32(i, step));
            let lo_ok = _mm256_cmpeq_epi32(_mm256_and_si256(lo, observed), observed);
            let hi_ok = _mm256_cmpeq_epi32(_mm256_and_si256(hi, observed), observed);
            let (l, h) = (raw(lo), raw(hi));
            let g = select(_mm256_and_si256(lo_ok, hi_ok), _mm256_mul_ps(half, _mm256_sub_ps(h, l)), zero);
            let g = select(_mm256_andnot_si256(lo_ok, hi_ok), _mm256_sub_ps(h, t), g);
            select(_mm256_andnot_si256(hi_ok, lo_ok), _mm256_sub_ps(t, l), g)
        };
        let one_minus_s = _mm256_sub_ps(_mm256_set1_ps(1.0), s);
        let mut g = [zero; 3];
        for (a, g) in g.iter_mut().enumerate() {
            let (ga, gb) = (gradient(ia, ta, strides[a]), gradient(ib, tb, strides[a]));
            *g = _mm256_add_ps(_mm256_mul_ps(ga, one_minus_s), _mm256_mul_ps(gb, s));
        }
        let dot = _mm256_add_ps(
            _mm256_add_ps(_mm256_mul_ps(g[0], g[0]), _mm256_mul_ps(g[1], g[1])),
            _mm256_mul_ps(g[2], g[2]),
        );
        let rcp = _mm256_div_ps(_mm256_set1_ps(1.0), _mm256_sqrt_ps(dot));
        let ok = _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_LT_OQ>(rcp, _mm256_set1_ps(f32::INFINITY)),
            _mm256_cmp_ps::<_CMP_GT_OQ>(rcp, zero),
        );
        for (a, dst) in out.normal.iter_mut().enumerate() {
            _mm256_storeu_ps(dst.as_mut_ptr().add(at), _mm256_and_ps(ok, _mm256_mul_ps(g[a], rcp)));
        }
    }
}
