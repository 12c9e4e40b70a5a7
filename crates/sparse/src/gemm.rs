//! Micro-GEMMs with row indirection, the arithmetic core of every kernel in this crate.
//!
//! Sparse convolution multiplies *selected rows* of a feature matrix by a small weight matrix
//! and adds the products to *selected rows* of another. Instead of gathering the rows into a
//! packed buffer (a copy) and scattering the result back (another), these kernels read and
//! write the rows in place through row-index lists: an AVX2/FMA register tile of 6 rows x 16
//! columns broadcasts each row's input values and streams the weight row, so indirection costs
//! one pointer per row and tile. An AVX-512 variant (8 rows x 32 columns, masked column tails)
//! runs where the CPU has it. The choice is made once at run time (`is_x86_feature_detected`;
//! `SEMRECON_SPARSE_SIMD=avx2|portable` forces a lower level) with a portable loop nest as the
//! fallback. Measured here (one thread, `[m, k] . [k, n]`, 64 x 64 weights): AVX-512 tile
//! 160-170 GFLOP/s, AVX2 tile 84, `matrixmultiply` 0.3.11 122, `gemm` 0.19 85 (its AVX-512
//! path needs nightly); with row indirection the tiles lose 2-15 %. Hence no GEMM dependency.
//!
//! Determinism: every output element is one fused multiply-add chain over the inner dimension
//! in increasing order, whatever tile it falls into, so results do not depend on how callers
//! split rows among threads.

use std::sync::OnceLock;

/// Which implementation the micro-GEMMs use on this machine.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SimdLevel {
    /// Plain loops (auto-vectorised by the compiler for the baseline target).
    Portable,
    /// Hand-written AVX2 + FMA register tiles (6 rows x 16 columns).
    Avx2Fma,
    /// Hand-written AVX-512F register tiles (8 rows x 32 columns, masked column tails).
    Avx512,
}

/// The implementation selected at run time.
pub fn simd_level() -> SimdLevel {
    static LEVEL: OnceLock<SimdLevel> = OnceLock::new();
    *LEVEL.get_or_init(|| {
        #[cfg(target_arch = "x86_64")]
        {
            let forced = std::env::var("SEMRECON_SPARSE_SIMD").unwrap_or_default();
            if forced != "portable" && forced != "avx2" && is_x86_feature_detected!("avx512f") {
                return SimdLevel::Avx512;
            }
            if forced != "portable" && is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
                return SimdLevel::Avx2Fma;
            }
        }
        SimdLevel::Portable
    })
}

/// Pairs per block of [`gemm_tn_rows`].
const TN_BLOCK: usize = 256;

fn max_row(rows: &[u32]) -> usize {
    rows.iter().copied().max().map_or(0, |r| r as usize)
}

/// `C[c_rows[r], 0..n] (+)= A[a_rows[r], 0..k] . B` for every `r`.
///
/// # Shapes
/// `a`: rows of stride `lda >= k`; `b`: `[k, n]` row-major; `c`: rows of stride `ldc >= n`;
/// `a_rows` and `c_rows` of equal length, `c_rows` without repeats.
///
/// # Panics
/// On index lists that leave the buffers (a bug in the caller, never user data: every caller
/// builds them from validated maps).
#[allow(clippy::too_many_arguments)]
pub(crate) fn gemm_rows(
    a: &[f32],
    lda: usize,
    a_rows: &[u32],
    b: &[f32],
    k: usize,
    n: usize,
    c: &mut [f32],
    ldc: usize,
    c_rows: &[u32],
    accumulate: bool,
) {
    gemm_rows_at(simd_level(), a, lda, a_rows, b, k, n, c, ldc, c_rows, accumulate);
}

/// [`gemm_rows`] with an explicit implementation (which must be supported by the CPU).
#[allow(clippy::too_many_arguments)]
fn gemm_rows_at(
    level: SimdLevel,
    a: &[f32],
    lda: usize,
    a_rows: &[u32],
    b: &[f32],
    k: usize,
    n: usize,
    c: &mut [f32],
    ldc: usize,
    c_rows: &[u32],
    accumulate: bool,
) {
    let m = a_rows.len();
    assert_eq!(m, c_rows.len());
    if m == 0 || n == 0 {
        return;
    }
    assert!(lda >= k && ldc >= n && b.len() >= k * n);
    assert!(max_row(a_rows) * lda + k <= a.len());
    assert!(max_row(c_rows) * ldc + n <= c.len());
    match level {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: the features were detected at run time; the asserts above keep every row
        // access inside the buffers.
        SimdLevel::Avx2Fma => unsafe {
            avx2::gemm_rows(a.as_ptr(), lda, a_rows, b.as_ptr(), k, n, c.as_mut_ptr(), ldc, c_rows, accumulate)
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        SimdLevel::Avx512 => unsafe {
            avx512::gemm_rows(a.as_ptr(), lda, a_rows, b.as_ptr(), k, n, c.as_mut_ptr(), ldc, c_rows, accumulate)
        },
        _ => {
            for (&ar, &cr) in a_rows.iter().zip(c_rows) {
                let arow = &a[ar as usize * lda..ar as usize * lda + k];
                let crow = &mut c[cr as usize * ldc..cr as usize * ldc + n];
                if !accumulate {
                    crow.fill(0.0);
                }
                for (t, &av) in arow.iter().enumerate() {
                    for (cv, &bv) in crow.iter_mut().zip(&b[t * n..t * n + n]) {
                        *cv += av * bv;
                    }
                }
            }
        }
    }
}

/// `C[0..m, 0..n] += sum_p A[a_rows[p], 0..m]^T B[b_rows[p], 0..n]` (weight gradients).
///
/// # Shapes
/// `a`: rows of stride `lda >= m`; `b`: rows of stride `ldb >= n`; `c`: `[m, n]` row-major;
/// `a_rows` and `b_rows` of equal length (the pairs).
///
/// # Panics
/// On index lists that leave the buffers (a caller bug).
#[allow(clippy::too_many_arguments)]
pub(crate) fn gemm_tn_rows(
    a: &[f32],
    lda: usize,
    a_rows: &[u32],
    m: usize,
    b: &[f32],
    ldb: usize,
    b_rows: &[u32],
    n: usize,
    c: &mut [f32],
) {
    gemm_tn_rows_at(simd_level(), a, lda, a_rows, m, b, ldb, b_rows, n, c);
}

/// [`gemm_tn_rows`] with an explicit implementation (which must be supported by the CPU).
#[allow(clippy::too_many_arguments)]
fn gemm_tn_rows_at(
    level: SimdLevel,
    a: &[f32],
    lda: usize,
    a_rows: &[u32],
    m: usize,
    b: &[f32],
    ldb: usize,
    b_rows: &[u32],
    n: usize,
    c: &mut [f32],
) {
    let p = a_rows.len();
    assert_eq!(p, b_rows.len());
    if p == 0 || m == 0 || n == 0 {
        return;
    }
    assert!(lda >= m && ldb >= n && c.len() >= m * n);
    assert!(max_row(a_rows) * lda + m <= a.len());
    assert!(max_row(b_rows) * ldb + n <= b.len());
    // Long pair lists are cut into blocks so that the A and B rows of a block stay in cache
    // while every tile of C walks them; each element still sums the pairs in order.
    if p > TN_BLOCK {
        for (ab, bb) in a_rows.chunks(TN_BLOCK).zip(b_rows.chunks(TN_BLOCK)) {
            gemm_tn_rows_at(level, a, lda, ab, m, b, ldb, bb, n, c);
        }
        return;
    }
    match level {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: features detected at run time; bounds asserted above.
        SimdLevel::Avx2Fma => unsafe {
            avx2::gemm_tn_rows(a.as_ptr(), lda, a_rows, m, b.as_ptr(), ldb, b_rows, n, c.as_mut_ptr())
        },
        #[cfg(target_arch = "x86_64")]
        // SAFETY: as above.
        SimdLevel::Avx512 => unsafe {
            avx512::gemm_tn_rows(a.as_ptr(), lda, a_rows, m, b.as_ptr(), ldb, b_rows, n, c.as_mut_ptr())
        },
        _ => {
            for (&ar, &br) in a_rows.iter().zip(b_rows) {
                let arow = &a[ar as usize * lda..ar as usize * lda + m];
                let brow = &b[br as usize * ldb..br as usize * ldb + n];
                for (i, &av) in arow.iter().enumerate() {
                    for (cv, &bv) in c[i * n..i * n + n].iter_mut().zip(brow) {
                        *cv += av * bv;
                    }
                }
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[allow(clippy::needless_range_loop)] // register tiles read best indexed
mod avx2 {
    use std::arch::x86_64::*;

    const MR: usize = 6;

    #[target_feature(enable = "avx2,fma")]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn gemm_rows(
        a: *const f32,
        lda: usize,
        a_rows: &[u32],
        b: *const f32,
        k: usize,
        n: usize,
        c: *mut f32,
        ldc: usize,
        c_rows: &[u32],
        acc: bool,
    ) {
        let m = a_rows.len();
        let mut r = 0;
        // SAFETY (whole function): the caller guarantees every indexed row is in bounds.
        unsafe {
            while r + MR <= m {
                tile::<MR>(a, lda, &a_rows[r..], b, k, n, c, ldc, &c_rows[r..], acc);
                r += MR;
            }
            let (ar, cr) = (&a_rows[r..], &c_rows[r..]);
            match m - r {
                1 => tile::<1>(a, lda, ar, b, k, n, c, ldc, cr, acc),
                2 => tile::<2>(a, lda, ar, b, k, n, c, ldc, cr, acc),
                3 => tile::<3>(a, lda, ar, b, k, n, c, ldc, cr, acc),
                4 => tile::<4>(a, lda, ar, b, k, n, c, ldc, cr, acc),
                5 => tile::<5>(a, lda, ar, b, k, n, c, ldc, cr, acc),
                _ => {}
            }
        }
    }

    #[target_feature(enable = "avx2,fma")]
    #[inline]
    #[allow(clippy::too_many_arguments)]
    unsafe fn tile<const R: usize>(
        a: *const f32,
        lda: usize,
        a_rows: &[u32],
        b: *const f32,
        k: usize,
        n: usize,
        c: *mut f32,
        ldc: usize,
        c_rows: &[u32],
        acc: bool,
    ) {
        // SAFETY (whole function): rows in bounds per the caller.
        unsafe {
            let mut ap = [a; R];
            let mut cp = [c; R];
            for i in 0..R {
                ap[i] = a.add(a_rows[i] as usize * lda);
                cp[i] = c.add(c_rows[i] as usize * ldc);
            }
            let mut j = 0;
            while j + 16 <= n {
                let mut s0 = [_mm256_setzero_ps(); R];
                let mut s1 = [_mm256_setzero_ps(); R];
                if acc {
                    for i in 0..R {
                        s0[i] = _mm256_loadu_ps(cp[i].add(j));
                        s1[i] = _mm256_loadu_ps(cp[i].add(j + 8));
                    }
                }
                let mut bp = b.add(j);
                for t in 0..k {
                    let b0 = _mm256_loadu_ps(bp);
                    let b1 = _mm256_loadu_ps(bp.add(8));
                    for i in 0..R {
                        let av = _mm256_broadcast_ss(&*ap[i].add(t));
                        s0[i] = _mm256_fmadd_ps(av, b0, s0[i]);
                        s1[i] = _mm256_fmadd_ps(av, b1, s1[i]);
                    }
                    bp = bp.add(n);
                }
                for i in 0..R {
                    _mm256_storeu_ps(cp[i].add(j), s0[i]);
                    _mm256_storeu_ps(cp[i].add(j + 8), s1[i]);
                }
                j += 16;
            }
            if j + 8 <= n {
                let mut s0 = [_mm256_setzero_ps(); R];
                if acc {
                    for i in 0..R {
                        s0[i] = _mm256_loadu_ps(cp[i].add(j));
                    }
                }
                let mut bp = b.add(j);
                for t in 0..k {
                    let b0 = _mm256_loadu_ps(bp);
                    for i in 0..R {
                        let av = _mm256_broadcast_ss(&*ap[i].add(t));
                        s0[i] = _mm256_fmadd_ps(av, b0, s0[i]);
                    }
                    bp = bp.add(n);
                }
                for i in 0..R {
                    _mm256_storeu_ps(cp[i].add(j), s0[i]);
                }
                j += 8;
            }
            while j < n {
                for i in 0..R {
                    let mut s = if acc { *cp[i].add(j) } else { 0.0 };
                    for t in 0..k {
                        s = (*ap[i].add(t)).mul_add(*b.add(t * n + j), s);
                    }
                    *cp[i].add(j) = s;
                }
                j += 1;
            }
        }
    }

    #[target_feature(enable = "avx2,fma")]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn gemm_tn_rows(
        a: *const f32,
        lda: usize,
        a_rows: &[u32],
        m: usize,
        b: *const f32,
        ldb: usize,
        b_rows: &[u32],
        n: usize,
        c: *mut f32,
    ) {
        // SAFETY (whole function): rows in bounds per the caller.
        unsafe {
            let mut i = 0;
            while i + MR <= m {
                tile_tn::<MR>(a.add(i), lda, a_rows, b, ldb, b_rows, n, c.add(i * n));
                i += MR;
            }
            let (ai, ci) = (a.add(i), c.add(i * n));
            match m - i {
                1 => tile_tn::<1>(ai, lda, a_rows, b, ldb, b_rows, n, ci),
                2 => tile_tn::<2>(ai, lda, a_rows, b, ldb, b_rows, n, ci),
                3 => tile_tn::<3>(ai, lda, a_rows, b, ldb, b_rows, n, ci),
                4 => tile_tn::<4>(ai, lda, a_rows, b, ldb, b_rows, n, ci),
                5 => tile_tn::<5>(ai, lda, a_rows, b, ldb, b_rows, n, ci),
                _ => {}
            }
        }
    }

    /// `R` rows of C starting at column `a` of A (pointer already offset).
    #[target_feature(enable = "avx2,fma")]
    #[inline]
    #[allow(clippy::too_many_arguments)]
    unsafe fn tile_tn<const R: usize>(
        a: *const f32,
        lda: usize,
        a_rows: &[u32],
        b: *const f32,
        ldb: usize,
        b_rows: &[u32],
        n: usize,
        c: *mut f32,
    ) {
        // SAFETY (whole function): rows in bounds per the caller.
        unsafe {
            let mut j = 0;
            while j + 16 <= n {
                let mut s0 = [_mm256_setzero_ps(); R];
                let mut s1 = [_mm256_setzero_ps(); R];
                for i in 0..R {
                    s0[i] = _mm256_loadu_ps(c.add(i * n + j));
                    s1[i] = _mm256_loadu_ps(c.add(i * n + j + 8));
                }
                for (&ar, &br) in a_rows.iter().zip(b_rows) {
                    let bp = b.add(br as usize * ldb + j);
                    let ap = a.add(ar as usize * lda);
                    let b0 = _mm256_loadu_ps(bp);
                    let b1 = _mm256_loadu_ps(bp.add(8));
                    for i in 0..R {
                        let av = _mm256_broadcast_ss(&*ap.add(i));
                        s0[i] = _mm256_fmadd_ps(av, b0, s0[i]);
                        s1[i] = _mm256_fmadd_ps(av, b1, s1[i]);
                    }
                }
                for i in 0..R {
                    _mm256_storeu_ps(c.add(i * n + j), s0[i]);
                    _mm256_storeu_ps(c.add(i * n + j + 8), s1[i]);
                }
                j += 16;
            }
            if j + 8 <= n {
                let mut s0 = [_mm256_setzero_ps(); R];
                for i in 0..R {
                    s0[i] = _mm256_loadu_ps(c.add(i * n + j));
                }
                for (&ar, &br) in a_rows.iter().zip(b_rows) {
                    let b0 = _mm256_loadu_ps(b.add(br as usize * ldb + j));
                    let ap = a.add(ar as usize * lda);
                    for i in 0..R {
                        let av = _mm256_broadcast_ss(&*ap.add(i));
                        s0[i] = _mm256_fmadd_ps(av, b0, s0[i]);
                    }
                }
                for i in 0..R {
                    _mm256_storeu_ps(c.add(i * n + j), s0[i]);
                }
                j += 8;
            }
            while j < n {
                for i in 0..R {
                    let mut s = *c.add(i * n + j);
                    for (&ar, &br) in a_rows.iter().zip(b_rows) {
                        s = (*a.add(ar as usize * lda + i)).mul_add(*b.add(br as usize * ldb + j), s);
                    }
                    *c.add(i * n + j) = s;
                }
                j += 1;
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[allow(clippy::needless_range_loop)] // register tiles read best indexed
mod avx512 {
    use std::arch::x86_64::*;

    const MR: usize = 8;

    /// Lane mask of the first `w` (<= 16) columns.
    #[inline]
    fn mask(w: usize) -> __mmask16 {
        if w >= 16 {
            0xffff
        } else {
            ((1u32 << w) - 1) as __mmask16
        }
    }

    #[target_feature(enable = "avx512f")]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn gemm_rows(
        a: *const f32,
        lda: usize,
        a_rows: &[u32],
        b: *const f32,
        k: usize,
        n: usize,
        c: *mut f32,
        ldc: usize,
        c_rows: &[u32],
        acc: bool,
    ) {
        let m = a_rows.len();
        let mut r = 0;
        // SAFETY (whole function): the caller guarantees every indexed row is in bounds.
        unsafe {
            while r + MR <= m {
                tile::<MR>(a, lda, &a_rows[r..], b, k, n, c, ldc, &c_rows[r..], acc);
                r += MR;
            }
            let (ar, cr) = (&a_rows[r..], &c_rows[r..]);
            match m - r {
                1 => tile::<1>(a, lda, ar, b, k, n, c, ldc, cr, acc),
                2 => tile::<2>(a, lda, ar, b, k, n, c, ldc, cr, acc),
                3 => tile::<3>(a, lda, ar, b, k, n, c, ldc, cr, acc),
                4 => tile::<4>(a, lda, ar, b, k, n, c, ldc, cr, acc),
                5 => tile::<5>(a, lda, ar, b, k, n, c, ldc, cr, acc),
                6 => tile::<6>(a, lda, ar, b, k, n, c, ldc, cr, acc),
                7 => tile::<7>(a, lda, ar, b, k, n, c, ldc, cr, acc),
                _ => {}
            }
        }
    }

    #[target_feature(enable = "avx512f")]
    #[inline]
    #[allow(clippy::too_many_arguments)]
    unsafe fn tile<const R: usize>(
        a: *const f32,
        lda: usize,
        a_rows: &[u32],
        b: *const f32,
        k: usize,
        n: usize,
        c: *mut f32,
        ldc: usize,
        c_rows: &[u32],
        acc: bool,
    ) {
        // SAFETY (whole function): rows in bounds per the caller; masked lanes are not touched.
        unsafe {
            let mut ap = [a; R];
            let mut cp = [c; R];
            for i in 0..R {
                ap[i] = a.add(a_rows[i] as usize * lda);
                cp[i] = c.add(c_rows[i] as usize * ldc);
            }
            let mut j = 0;
            while j + 32 <= n {
                let mut s0 = [_mm512_setzero_ps(); R];
                let mut s1 = [_mm512_setzero_ps(); R];
                if acc {
                    for i in 0..R {
                        s0[i] = _mm512_loadu_ps(cp[i].add(j));
                        s1[i] = _mm512_loadu_ps(cp[i].add(j + 16));
                    }
                }
                let mut bp = b.add(j);
                for t in 0..k {
                    let b0 = _mm512_loadu_ps(bp);
                    let b1 = _mm512_loadu_ps(bp.add(16));
                    for i in 0..R {
                        let av = _mm512_set1_ps(*ap[i].add(t));
                        s0[i] = _mm512_fmadd_ps(av, b0, s0[i]);
                        s1[i] = _mm512_fmadd_ps(av, b1, s1[i]);
                    }
                    bp = bp.add(n);
                }
                for i in 0..R {
                    _mm512_storeu_ps(cp[i].add(j), s0[i]);
                    _mm512_storeu_ps(cp[i].add(j + 16), s1[i]);
                }
                j += 32;
            }
            while j < n {
                let mk = mask(n - j);
                let mut s0 = [_mm512_setzero_ps(); R];
                if acc {
                    for i in 0..R {
                        s0[i] = _mm512_maskz_loadu_ps(mk, cp[i].add(j));
                    }
                }
                let mut bp = b.add(j);
                for t in 0..k {
                    let b0 = _mm512_maskz_loadu_ps(mk, bp);
                    for i in 0..R {
                        let av = _mm512_set1_ps(*ap[i].add(t));
                        s0[i] = _mm512_fmadd_ps(av, b0, s0[i]);
                    }
                    bp = bp.add(n);
                }
                for i in 0..R {
                    _mm512_mask_storeu_ps(cp[i].add(j), mk, s0[i]);
                }
                j += 16;
            }
        }
    }

    #[target_feature(enable = "avx512f")]
    #[allow(clippy::too_many_arguments)]
    pub(super) unsafe fn gemm_tn_rows(
        a: *const f32,
        lda: usize,
        a_rows: &[u32],
        m: usize,
        b: *const f32,
        ldb: usize,
        b_rows: &[u32],
        n: usize,
        c: *mut f32,
    ) {
        // SAFETY (whole function): rows in bounds per the caller.
        unsafe {
            let mut i = 0;
            while i + MR <= m {
                tile_tn::<MR>(a.add(i), lda, a_rows, b, ldb, b_rows, n, c.add(i * n));
                i += MR;
            }
            let (ai, ci) = (a.add(i), c.add(i * n));
            match m - i {
                1 => tile_tn::<1>(ai, lda, a_rows, b, ldb, b_rows, n, ci),
                2 => tile_tn::<2>(ai, lda, a_rows, b, ldb, b_rows, n, ci),
                3 => tile_tn::<3>(ai, lda, a_rows, b, ldb, b_rows, n, ci),
                4 => tile_tn::<4>(ai, lda, a_rows, b, ldb, b_rows, n, ci),
                5 => tile_tn::<5>(ai, lda, a_rows, b, ldb, b_rows, n, ci),
                6 => tile_tn::<6>(ai, lda, a_rows, b, ldb, b_rows, n, ci),
                7 => tile_tn::<7>(ai, lda, a_rows, b, ldb, b_rows, n, ci),
                _ => {}
            }
        }
    }

    #[target_feature(enable = "avx512f")]
    #[inline]
    #[allow(clippy::too_many_arguments)]
    unsafe fn tile_tn<const R: usize>(
        a: *const f32,
        lda: usize,
        a_rows: &[u32],
        b: *const f32,
        ldb: usize,
        b_rows: &[u32],
        n: usize,
        c: *mut f32,
    ) {
        // SAFETY (whole function): rows in bounds per the caller; masked lanes untouched.
        unsafe {
            let mut j = 0;
            while j + 32 <= n {
                let mut s0 = [_mm512_setzero_ps(); R];
                let mut s1 = [_mm512_setzero_ps(); R];
                for i in 0..R {
                    s0[i] = _mm512_loadu_ps(c.add(i * n + j));
                    s1[i] = _mm512_loadu_ps(c.add(i * n + j + 16));
                }
                for (&ar, &br) in a_rows.iter().zip(b_rows) {
                    let bp = b.add(br as usize * ldb + j);
                    let ap = a.add(ar as usize * lda);
                    let b0 = _mm512_loadu_ps(bp);
                    let b1 = _mm512_loadu_ps(bp.add(16));
                    for i in 0..R {
                        let av = _mm512_set1_ps(*ap.add(i));
                        s0[i] = _mm512_fmadd_ps(av, b0, s0[i]);
                        s1[i] = _mm512_fmadd_ps(av, b1, s1[i]);
                    }
                }
                for i in 0..R {
                    _mm512_storeu_ps(c.add(i * n + j), s0[i]);
                    _mm512_storeu_ps(c.add(i * n + j + 16), s1[i]);
                }
                j += 32;
            }
            while j < n {
                let mk = mask(n - j);
                let mut s0 = [_mm512_setzero_ps(); R];
                for i in 0..R {
                    s0[i] = _mm512_maskz_loadu_ps(mk, c.add(i * n + j));
                }
                for (&ar, &br) in a_rows.iter().zip(b_rows) {
                    let b0 = _mm512_maskz_loadu_ps(mk, b.add(br as usize * ldb + j));
                    let ap = a.add(ar as usize * lda);
                    for i in 0..R {
                        let av = _mm512_set1_ps(*ap.add(i));
                        s0[i] = _mm512_fmadd_ps(av, b0, s0[i]);
                    }
                }
                for i in 0..R {
                    _mm512_mask_storeu_ps(c.add(i * n + j), mk, s0[i]);
                }
                j += 16;
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[allow(clippy::too_many_arguments)]
    fn naive(a: &[f32], lda: usize, ar: &[u32], b: &[f32], k: usize, n: usize, c: &mut [f32], ldc: usize, cr: &[u32]) {
        for (&x, &y) in ar.iter().zip(cr) {
            for j in 0..n {
                let mut s = f64::from(c[y as usize * ldc + j]);
                for t in 0..k {
                    s += f64::from(a[x as usize * lda + t]) * f64::from(b[t * n + j]);
                }
                c[y as usize * ldc + j] = s as f32;
            }
        }
    }

    /// The implementations this CPU can run: the selected one and everything below it.
    fn levels() -> Vec<SimdLevel> {
        match simd_level() {
            SimdLevel::Portable => vec![SimdLevel::Portable],
            SimdLevel::Avx2Fma => vec![SimdLevel::Portable, SimdLevel::Avx2Fma],
            SimdLevel::Avx512 => {
                let mut v = vec![SimdLevel::Portable, SimdLevel::Avx512];
                #[cfg(target_arch = "x86_64")]
                if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
                    v.push(SimdLevel::Avx2Fma);
                }
                v
            }
        }
    }

    #[test]
    fn gemm_rows_matches_naive_for_odd_shapes() {
        for level in levels() {
            for &(m, k, n) in
                &[(1, 1, 1), (7, 3, 5), (13, 17, 33), (6, 64, 64), (11, 32, 96), (5, 16, 24), (9, 8, 48), (17, 5, 40)]
            {
                let a: Vec<f32> = (0..(m + 3) * (k + 2)).map(|i| ((i * 7 % 13) as f32 - 6.0) / 7.0).collect();
                let b: Vec<f32> = (0..k * n).map(|i| ((i * 5 % 11) as f32 - 5.0) / 5.0).collect();
                let ar: Vec<u32> = (0..m as u32).map(|r| (r * 5 + 1) % (m as u32 + 3)).collect();
                let cr: Vec<u32> = (0..m as u32).rev().collect();
                let mut c = vec![0.5f32; m * (n + 1)];
                let mut want = c.clone();
                gemm_rows_at(level, &a, k + 2, &ar, &b, k, n, &mut c, n + 1, &cr, true);
                naive(&a, k + 2, &ar, &b, k, n, &mut want, n + 1, &cr);
                for (x, y) in c.iter().zip(&want) {
                    assert!((x - y).abs() < 1e-4, "{m}x{k}x{n}: {x} vs {y}");
                }
                // Store mode ignores previous content.
                let mut c2 = vec![9.0f32; m * (n + 1)];
                gemm_rows_at(level, &a, k + 2, &ar, &b, k, n, &mut c2, n + 1, &cr, false);
                for &r in &cr {
                    for j in 0..n {
                        let i = r as usize * (n + 1) + j;
                        assert!((c2[i] - (want[i] - 0.5)).abs() < 1e-4, "{level:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn gemm_tn_rows_matches_naive() {
        for level in levels() {
            for &(p, m, n) in &[(0, 3, 3), (1, 1, 1), (9, 7, 5), (40, 13, 33), (17, 64, 64), (5, 3, 96), (12, 9, 48)] {
                let a: Vec<f32> = (0..(p + 2) * m).map(|i| ((i * 7 % 13) as f32 - 6.0) / 7.0).collect();
                let b: Vec<f32> = (0..(p + 1) * n).map(|i| ((i * 5 % 11) as f32 - 5.0) / 5.0).collect();
                let ar: Vec<u32> = (0..p as u32).map(|r| (r * 3 + 1) % (p as u32 + 2)).collect();
                let br: Vec<u32> = (0..p as u32).rev().collect();
                let mut c = vec![0.25f32; m * n];
                gemm_tn_rows_at(level, &a, m, &ar, m, &b, n, &br, n, &mut c);
                for i in 0..m {
                    for j in 0..n {
                        let mut s = 0.25f64;
                        for (&x, &y) in ar.iter().zip(&br) {
                            s += f64::from(a[x as usize * m + i]) * f64::from(b[y as usize * n + j]);
                        }
                        assert!((c[i * n + j] as f64 - s).abs() < 1e-4, "{level:?}");
                    }
                }
            }
        }
    }
}
