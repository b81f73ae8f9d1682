//! The group kernels of [`super::pass`] in AVX-512 intrinsics: a group's eight lanes in one
//! 512-bit vector. The compiler scalarises the portable kernels at this width (the 3 x 3 x 8
//! accumulators end up in memory), so these spell the vectors out. Every lane sees the same
//! fused operations in the same order as the portable kernel, so the results are identical.

use std::arch::x86_64::{
    __m512d, _mm512_fmadd_pd, _mm512_loadu_pd, _mm512_mul_pd, _mm512_set1_pd, _mm512_setzero_pd,
    _mm512_storeu_pd, _mm512_sub_pd,
};

use super::L;
use super::pass::dets_group;

/// The lanes of a vector as an array.
#[inline(always)]
fn lanes(v: __m512d) -> [f64; L] {
    let mut out = [0.0; L];
    // SAFETY: `out` holds eight f64.
    unsafe { _mm512_storeu_pd(out.as_mut_ptr(), v) };
    out
}

/// D -= sign (B U) S^-1 (B U)^T for the eight candidates of one group, and their
/// determinants (signs `sg`) into `det` (as `pass::update_group` with eight lanes).
///
/// # Safety
/// The CPU must have AVX-512F and FMA.
#[target_feature(enable = "avx512f,fma")]
pub(super) unsafe fn update_group<const R: usize>(
    bg: &[f64],
    u: &[f64],
    m: usize,
    s: &[[f64; R]; R],
    sign: f64,
    dg: &mut [f64],
    sg: &[f64],
    det: &mut [f64],
) {
    let mut e = [[_mm512_setzero_pd(); R]; R];
    for (bc, uc) in bg.chunks_exact(R * L).zip(u.chunks_exact(R)).take(m) {
        let mut bx = [_mm512_setzero_pd(); R];
        for (x, v) in bx.iter_mut().enumerate() {
            // SAFETY: `bc` holds R rows of eight lanes.
            *v = unsafe { _mm512_loadu_pd(bc[x * L..(x + 1) * L].as_ptr()) };
        }
        for (y, &uy) in uc.iter().enumerate() {
            let uy = _mm512_set1_pd(uy);
            for x in 0..R {
                e[x][y] = _mm512_fmadd_pd(bx[x], uy, e[x][y]);
            }
        }
    }
    let mut es = [[_mm512_setzero_pd(); R]; R];
    for x in 0..R {
        for y in 0..R {
            for k in 0..R {
                es[x][y] = _mm512_fmadd_pd(e[x][k], _mm512_set1_pd(s[k][y]), es[x][y]);
            }
        }
    }
    let sign = _mm512_set1_pd(sign);
    let mut out = [[[0.0; L]; R]; R];
    for x in 0..R {
        for y in 0..R {
            let mut v = _mm512_setzero_pd();
            for k in 0..R {
                v = _mm512_fmadd_pd(es[x][k], e[y][k], v);
            }
            let o = &mut dg[(x * R + y) * L..(x * R + y + 1) * L];
            // SAFETY: `o` holds eight f64.
            let dv = unsafe { _mm512_loadu_pd(o.as_ptr()) };
            let dv = _mm512_sub_pd(dv, _mm512_mul_pd(sign, v));
            unsafe { _mm512_storeu_pd(o.as_mut_ptr(), dv) };
            out[x][y] = lanes(dv);
        }
    }
    dets_group::<R, L, 0>(&out, sg, det);
}

/// D = B P B^T for the eight candidates of one group, and their determinants (signs `sg`) into `det`
/// (as `pass::rebuild_group` with eight lanes).
///
/// # Safety
/// The CPU must have AVX-512F and FMA.
#[target_feature(enable = "avx512f,fma")]
pub(super) unsafe fn rebuild_group<const R: usize>(
    bg: &[f64],
    p: &[f64],
    m: usize,
    dg: &mut [f64],
    sg: &[f64],
    det: &mut [f64],
) {
    let mut d = [[_mm512_setzero_pd(); R]; R];
    // Three columns of B P at a time: 3 R independent sums keep both FMA pipes busy (one
    // column at a time, the R sums wait on the FMA latency).
    let mut c2 = 0;
    while c2 + 3 <= m {
        // SAFETY: the caller's CPU has AVX-512F and FMA.
        unsafe { rebuild_columns::<R, 3>(bg, p, m, c2, &mut d) };
        c2 += 3;
    }
    while c2 < m {
        // SAFETY: as above.
        unsafe { rebuild_columns::<R, 1>(bg, p, m, c2, &mut d) };
        c2 += 1;
    }
    let mut out = [[[0.0; L]; R]; R];
    for x in 0..R {
        for y in 0..R {
            out[x][y] = lanes(d[x][y]);
            dg[(x * R + y) * L..(x * R + y + 1) * L].copy_from_slice(&out[x][y]);
        }
    }
    dets_group::<R, L, 0>(&out, sg, det);
}

/// D += W W' for columns c2..c2 + C of W = B P (w[j][x] = (B P)(x, c2 + j)), each column summed
/// over the pool's m columns in order (as the portable kernel does).
///
/// # Safety
/// The CPU must have AVX-512F and FMA.
#[target_feature(enable = "avx512f,fma")]
#[inline]
unsafe fn rebuild_columns<const R: usize, const C: usize>(
    bg: &[f64],
    p: &[f64],
    m: usize,
    c2: usize,
    d: &mut [[__m512d; R]; R],
) {
    let mut w = [[_mm512_setzero_pd(); R]; C];
    for (bc, prow) in bg.chunks_exact(R * L).zip(p.chunks_exact(m)).take(m) {
        let mut b = [_mm512_setzero_pd(); R];
        for (x, bx) in b.iter_mut().enumerate() {
            // SAFETY: `bc` holds R rows of eight lanes.
            *bx = unsafe { _mm512_loadu_pd(bc[x * L..(x + 1) * L].as_ptr()) };
        }
        for (j, wj) in w.iter_mut().enumerate() {
            let pc = _mm512_set1_pd(prow[c2 + j]);
            for x in 0..R {
                wj[x] = _mm512_fmadd_pd(b[x], pc, wj[x]);
            }
        }
    }
    for (j, wj) in w.iter().enumerate() {
        let bc2 = &bg[(c2 + j) * R * L..(c2 + j + 1) * R * L];
        for x in 0..R {
            for y in 0..R {
                // SAFETY: `bc2` holds R rows of eight lanes.
                let b = unsafe { _mm512_loadu_pd(bc2[y * L..(y + 1) * L].as_ptr()) };
                d[x][y] = _mm512_fmadd_pd(wj[x], b, d[x][y]);
            }
        }
    }
}
