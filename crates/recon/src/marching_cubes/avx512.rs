//! Vertex batches in AVX-512F intrinsics, selected at run time where the CPU has them: the
//! sixteen vertices of a batch are made in the lanes of one register each, their distances,
//! flags and colours gathered from the padded block.
//!
//! The arithmetic is [`super::vertices::vertex`]'s, operation for operation and in the same order (no
//! fused multiply-add, the same roundings), so both give the same bits; the central
//! differences are exact (integers and halves), the rest is the same IEEE operations.

use std::arch::x86_64::*;

use glam::IVec3;

use super::{PaddedBlock, VertexLanes, LANES, PAD, PAD2};
use crate::map::TSDF_SCALE;

/// [`super::vertices::vertices_scalar`] with AVX-512F.
///
/// # Safety
/// The CPU must support AVX-512F, and every job must name an edge between padded
/// coordinates 1 ..= 9 (as the crossed edges of a chunk's cells do), so that the ends and
/// their six neighbours lie in the block.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn vertices(
    block: &PaddedBlock,
    jobs: &[u32; LANES],
    key_voxel: IVec3,
    voxel_size: f32,
    out: &mut VertexLanes,
) {
    // SAFETY (whole body): AVX-512F is enabled by the caller's check; gather indices are the
    // jobs' ends (padded 1 ..= 9 on every axis, below PAD^3) and their neighbours one step
    // along an axis (padded 0 ..= 10), all inside `packed` and `color`; loads and stores are
    // of whole 16-lane arrays.
    unsafe {
        let packed = block.packed.as_ptr();
        let colors = block.color.as_ptr() as *const i32;
        let j = _mm512_loadu_si512(jobs.as_ptr() as *const _);
        let ia = _mm512_and_si512(j, _mm512_set1_epi32(0x7ff));
        let axis = _mm512_and_si512(_mm512_srli_epi32::<11>(j), _mm512_set1_epi32(3));
        let strides = [1, PAD as i32, PAD2 as i32];
        let stride = _mm512_permutexvar_epi32(
            axis,
            _mm512_setr_epi32(1, PAD as i32, PAD2 as i32, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0),
        );
        let ib = _mm512_add_epi32(ia, stride);
        // Raw distance (the high half of a packed entry) as f32.
        let raw = |v: __m512i| _mm512_cvtepi32_ps(_mm512_srai_epi32::<16>(v));
        let (pa, pb) = (_mm512_i32gather_epi32::<4>(ia, packed), _mm512_i32gather_epi32::<4>(ib, packed));
        let (ta, tb) = (raw(pa), raw(pb));
        let scale = _mm512_set1_ps(1.0 / TSDF_SCALE);
        let (fa, fb) = (_mm512_mul_ps(ta, scale), _mm512_mul_ps(tb, scale));
        let s = _mm512_div_ps(fa, _mm512_sub_ps(fa, fb));

        // Position: the lower end's global voxel, moved by s along the axis, in metres.
        let key = key_voxel.to_array();
        let vs = _mm512_set1_ps(voxel_size);
        for (a, dst) in out.position.iter_mut().enumerate() {
            let low =
                _mm512_and_si512(_mm512_srlv_epi32(j, _mm512_set1_epi32(13 + 4 * a as i32)), _mm512_set1_epi32(15));
            let p = _mm512_cvtepi32_ps(_mm512_add_epi32(low, _mm512_set1_epi32(key[a])));
            let on_axis = _mm512_cmpeq_epi32_mask(axis, _mm512_set1_epi32(a as i32));
            let p = _mm512_mask_add_ps(p, on_axis, p, s);
            _mm512_storeu_ps(dst.as_mut_ptr(), _mm512_mul_ps(p, vs));
        }

        // Colour: a colourless end takes the other's colour, then `a + s (b - a) + 0.5`
        // truncated, per channel.
        let (ca, cb) = (_mm512_i32gather_epi32::<4>(ia, colors), _mm512_i32gather_epi32::<4>(ib, colors));
        let count = _mm512_set1_epi32(0xff00_0000u32 as i32);
        let (none_a, none_b) = (_mm512_testn_epi32_mask(ca, count), _mm512_testn_epi32_mask(cb, count));
        let ca2 = _mm512_mask_mov_epi32(ca, none_a & !none_b, cb);
        let cb2 = _mm512_mask_mov_epi32(cb, none_b & !none_a, ca);
        let byte = _mm512_set1_epi32(0xff);
        let half = _mm512_set1_ps(0.5);
        let mut color = _mm512_setzero_si512();
        for k in 0..3 {
            let shift = _mm512_set1_epi32(8 * k);
            let channel = |c: __m512i| _mm512_cvtepi32_ps(_mm512_and_si512(_mm512_srlv_epi32(c, shift), byte));
            let (a, b) = (channel(ca2), channel(cb2));
            let v = _mm512_add_ps(_mm512_add_ps(a, _mm512_mul_ps(s, _mm512_sub_ps(b, a))), half);
            let v = _mm512_and_si512(_mm512_cvttps_epi32(v), byte);
            color = _mm512_or_si512(color, _mm512_sllv_epi32(v, shift));
        }
        _mm512_storeu_si512(out.color.as_mut_ptr() as *mut _, color);

        // Normal: the central-difference gradients at both ends, interpolated, normalised.
        let observed = _mm512_set1_epi32(super::OBSERVED as i32);
        let zero = _mm512_setzero_ps();
        let gradient = |i: __m512i, t: __m512, step: i32| {
            let step = _mm512_set1_epi32(step);
            let lo = _mm512_i32gather_epi32::<4>(_mm512_sub_epi32(i, step), packed);
            let hi = _mm512_i32gather_epi32::<4>(_mm512_add_epi32(i, step), packed);
            let (lo_ok, hi_ok) = (_mm512_test_epi32_mask(lo, observed), _mm512_test_epi32_mask(hi, observed));
            let (l, h) = (raw(lo), raw(hi));
            let g = _mm512_mask_mov_ps(zero, lo_ok & hi_ok, _mm512_mul_ps(half, _mm512_sub_ps(h, l)));
            let g = _mm512_mask_mov_ps(g, hi_ok & !lo_ok, _mm512_sub_ps(h, t));
            _mm512_mask_mov_ps(g, lo_ok & !hi_ok, _mm512_sub_ps(t, l))
        };
        let one_minus_s = _mm512_sub_ps(_mm512_set1_ps(1.0), s);
        let mut g = [zero; 3];
        for (a, g) in g.iter_mut().enumerate() {
            let (ga, gb) = (gradient(ia, ta, strides[a]), gradient(ib, tb, strides[a]));
            *g = _mm512_add_ps(_mm512_mul_ps(ga, one_minus_s), _mm512_mul_ps(gb, s));
        }
        let dot = _mm512_add_ps(
            _mm512_add_ps(_mm512_mul_ps(g[0], g[0]), _mm512_mul_ps(g[1], g[1])),
            _mm512_mul_ps(g[2], g[2]),
        );
        let rcp = _mm512_div_ps(_mm512_set1_ps(1.0), _mm512_sqrt_ps(dot));
        let ok = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(rcp, _mm512_set1_ps(f32::INFINITY))
            & _mm512_cmp_ps_mask::<_CMP_GT_OQ>(rcp, zero);
        for (a, dst) in out.normal.iter_mut().enumerate() {
            _mm512_storeu_ps(dst.as_mut_ptr(), _mm512_maskz_mul_ps(ok, g[a], rcp));
        }
    }
}
