//! The Taylor integration of `taylor` on x86-64 vector units: the residual's integration
//! written with 256-bit intrinsics (four rods in one register, the series unrolled so its
//! coefficients stay in registers), compiled for AVX2 and for AVX-512 VL (twice the
//! registers), and the variational integration compiled for AVX2. Only additions,
//! multiplications and negations in the portable code's order (no fused multiply-add): the
//! results are bit for bit those of the portable code.

use std::arch::x86_64::{
    _mm256_add_pd, _mm256_loadu_pd, _mm256_mul_pd, _mm256_setzero_pd, _mm256_storeu_pd,
    _mm256_sub_pd,
};

use super::rod::{C, DIM, M, PHI, Rod, S, Seed, State, X, Y};
use super::taylor::{Factors, INV, L, Lanes, TERMS, integrate_var_body, pack};

/// Whether the processor has AVX2.
pub(super) fn avx2() -> bool {
    std::arch::is_x86_feature_detected!("avx2")
}

/// Whether the processor has AVX-512 F and VL.
pub(super) fn avx512() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
        && std::arch::is_x86_feature_detected!("avx512vl")
}

/// The residual's integration compiled for AVX2.
///
/// # Safety
/// The processor must support AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn integrate_avx2<const R: usize>(
    rods: &[Rod; R],
    y0: &[State; R],
) -> [State; R] {
    // SAFETY: AVX2 is enabled here, the only feature the kernel's intrinsics need.
    unsafe { kernel(rods, y0) }
}

/// The residual's integration compiled for AVX-512 VL: the same 256-bit lanes with 32
/// vector registers instead of 16.
///
/// # Safety
/// The processor must support AVX2, AVX-512 F and AVX-512 VL.
#[target_feature(enable = "avx2,avx512f,avx512vl")]
pub(super) unsafe fn integrate_avx512<const R: usize>(
    rods: &[Rod; R],
    y0: &[State; R],
) -> [State; R] {
    // SAFETY: AVX2 is enabled here, the only feature the kernel's intrinsics need.
    unsafe { kernel(rods, y0) }
}

/// The variational integration compiled for AVX2 (the portable code, vectorised by the
/// compiler).
///
/// # Safety
/// The processor must support AVX2.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn integrate_var_avx2<const R: usize, const K: usize>(
    rods: &[Rod; R],
    y0: &[State; R],
    seeds: [Seed; K],
) -> ([State; R], [[State; K]; R]) {
    integrate_var_body(rods, y0, seeds)
}

/// The residual's integration with intrinsics: `taylor::integrate_terms` with
/// [`TERMS`] terms, the same operations in the same order.
///
/// # Safety
/// Only for functions compiled with AVX2 enabled.
#[inline(always)]
unsafe fn kernel<const R: usize>(rods: &[Rod; R], y0: &[State; R]) -> [State; R] {
    let add = |a, b| unsafe { _mm256_add_pd(a, b) };
    let sub = |a, b| unsafe { _mm256_sub_pd(a, b) };
    let mul = |a, b| unsafe { _mm256_mul_pd(a, b) };
    // SAFETY: the caller has AVX2.
    let zero = unsafe { _mm256_setzero_pd() };
    let mut out = *y0;
    for first in (0..R).step_by(L) {
        let (steps, co, y) = pack(rods, y0, first);
        let fa = Factors::<TERMS>::new(&co);
        // Plain loops, no closures: the loads must be compiled with the caller's features.
        let (mut f, mut nf, mut kx, mut ky) =
            ([zero; TERMS], [zero; TERMS], [zero; TERMS], [zero; TERMS]);
        let mut inv = [zero; TERMS + 1];
        let mut v = [zero; DIM];
        // SAFETY: every pointer is to four contiguous f64 (a `Lanes`); the caller has AVX2.
        let (nx, ny, flex, h) = unsafe {
            for j in 0..TERMS {
                let neg: Lanes = fa.f[j].map(|x| -x);
                f[j] = _mm256_loadu_pd(fa.f[j].as_ptr());
                nf[j] = _mm256_loadu_pd(neg.as_ptr());
                kx[j] = _mm256_loadu_pd(fa.kx[j].as_ptr());
                ky[j] = _mm256_loadu_pd(fa.ky[j].as_ptr());
            }
            for (j, w) in inv.iter_mut().enumerate() {
                *w = _mm256_loadu_pd([INV[j]; L].as_ptr());
            }
            for i in 0..DIM {
                v[i] = _mm256_loadu_pd(y[i].as_ptr());
            }
            (
                _mm256_loadu_pd(co.nx.as_ptr()),
                _mm256_loadu_pd(co.ny.as_ptr()),
                _mm256_loadu_pd(co.flex.as_ptr()),
                _mm256_loadu_pd(co.h.as_ptr()),
            )
        };
        for _ in 0..steps {
            let (mut c, mut s, mut m, mut k) =
                ([zero; TERMS], [zero; TERMS], [zero; TERMS], [zero; TERMS]);
            c[0] = v[C];
            s[0] = v[S];
            m[0] = v[M];
            k[0] = mul(flex, m[0]);
            // One order: `taylor::order` (products from the middle outwards, then the ends).
            macro_rules! orders {
                ($($j:literal)*) => { $( {
                    const J: usize = $j;
                    let (mut p0, mut p1, mut q0, mut q1) = (zero, zero, zero, zero);
                    let mut i = J / 2;
                    while i >= 1 {
                        p0 = add(p0, mul(s[i], k[J - i]));
                        q0 = add(q0, mul(c[i], k[J - i]));
                        i -= 1;
                    }
                    let mut i = J / 2 + 1;
                    while i < J {
                        p1 = add(p1, mul(s[i], k[J - i]));
                        q1 = add(q1, mul(c[i], k[J - i]));
                        i += 1;
                    }
                    let (a, b) = if J == 0 {
                        (mul(s[0], k[0]), mul(c[0], k[0]))
                    } else {
                        (
                            add(add(add(p0, p1), mul(s[0], k[J])), mul(s[J], k[0])),
                            add(add(add(q0, q1), mul(c[0], k[J])), mul(c[J], k[0])),
                        )
                    };
                    c[J + 1] = mul(nf[J], a);
                    s[J + 1] = mul(f[J], b);
                    m[J + 1] = mul(f[J], sub(mul(nx, s[J]), mul(ny, c[J])));
                    k[J + 1] = sub(mul(kx[J], s[J]), mul(ky[J], c[J]));
                } )* };
            }
            const { assert!(TERMS == 14) };
            orders!(0 1 2 3 4 5 6 7 8 9 10 11 12);
            // `taylor::advance`.
            let (mut oc, mut os, mut om) = (c[0], s[0], m[0]);
            for j in 1..TERMS {
                oc = add(oc, c[j]);
                os = add(os, s[j]);
                om = add(om, m[j]);
            }
            let (mut ox, mut oy, mut op) = (zero, zero, zero);
            for j in (0..TERMS).rev() {
                ox = add(ox, mul(c[j], inv[j + 1]));
                oy = add(oy, mul(s[j], inv[j + 1]));
                op = add(op, mul(k[j], inv[j + 1]));
            }
            v[X] = add(v[X], mul(h, ox));
            v[Y] = add(v[Y], mul(h, oy));
            v[PHI] = add(v[PHI], mul(h, op));
            v[C] = oc;
            v[S] = os;
            v[M] = om;
        }
        let mut lanes = [[0.0; L]; DIM];
        for (o, vi) in lanes.iter_mut().zip(v) {
            // SAFETY: a `Lanes` is four contiguous f64.
            unsafe { _mm256_storeu_pd(o.as_mut_ptr(), vi) };
        }
        for (l, o) in out.iter_mut().skip(first).take(L).enumerate() {
            *o = std::array::from_fn(|i| lanes[i][l]);
        }
    }
    out
}
