//! The group kernels of [`super::pass`] in AVX-512 intrinsics: a group's eight lanes in one
//! 512-bit vector. The compiler scalarises the portable kernels at this width (the 3 x 3 x 8
//! accumulators end up in memory), so these spell the vectors out. Every lane sees the same
//! fused operations in the same order as the portable kernel, so the results are identical.

use std::arch::x86_64::{
    __m256, __m512d, _CMP_GT_OQ, _CMP_LT_OQ, _mm256_fmadd_ps, _mm256_loadu_ps, _mm256_set1_ps,
    _mm256_setzero_ps, _mm512_add_pd, _mm512_cmp_pd_mask, _mm512_cvtps_pd, _mm512_fmadd_pd,
    _mm512_fnmadd_pd, _mm512_loadu_pd, _mm512_mask_blend_pd, _mm512_maskz_mov_pd, _mm512_max_pd,
    _mm512_mul_pd, _mm512_permute_pd, _mm512_set1_pd, _mm512_setzero_pd, _mm512_shuffle_f64x2,
    _mm512_storeu_pd, _mm512_sub_pd,
};

use super::pass::dets_group;
use super::{L, upper, upper_len};

/// The lanes of a vector as an array.
#[inline(always)]
fn lanes(v: __m512d) -> [f64; L] {
    let mut out = [0.0; L];
    // SAFETY: `out` holds eight f64.
    unsafe { _mm512_storeu_pd(out.as_mut_ptr(), v) };
    out
}

/// det(I + sign D) of a group's eight candidates (signs `sg`) into `det`, and the group's
/// largest over its outside candidates and over its members (as `pass::dets_group` and
/// `pass::group_max`: for 3 rows the closed form's operations lane by lane, unfused).
///
/// # Safety
/// The CPU must have AVX-512F.
#[target_feature(enable = "avx512f")]
unsafe fn dets_and_max<const R: usize>(
    d: &[[__m512d; R]; R],
    sg: &[f64],
    det: &mut [f64],
) -> [f64; 2] {
    // SAFETY: `sg` and `det` hold a group's eight lanes.
    let s = unsafe { _mm512_loadu_pd(sg[..L].as_ptr()) };
    let zero = _mm512_setzero_pd();
    let v = if R == 3 {
        use _mm512_mul_pd as mul;
        let one = _mm512_set1_pd(1.0);
        // s d is exact (s is +-1 or 0), so the fused s d + 1 rounds as the sum does.
        let a = _mm512_fmadd_pd(s, d[0][0], one);
        let (b, c) = (mul(s, d[0][1]), mul(s, d[0][2]));
        let e = _mm512_fmadd_pd(s, d[1][1], one);
        let f = mul(s, d[1][2]);
        let h = _mm512_fmadd_pd(s, d[2][2], one);
        let m2 = _mm512_sub_pd(mul(a, e), mul(b, b));
        let t1 = mul(a, _mm512_sub_pd(mul(e, h), mul(f, f)));
        let t2 = mul(b, _mm512_sub_pd(mul(b, h), mul(f, c)));
        let t3 = mul(c, _mm512_sub_pd(mul(b, f), mul(e, c)));
        let dt = _mm512_add_pd(_mm512_sub_pd(t1, t2), t3);
        let ok = _mm512_cmp_pd_mask::<_CMP_GT_OQ>(a, zero)
            & _mm512_cmp_pd_mask::<_CMP_GT_OQ>(m2, zero)
            & _mm512_cmp_pd_mask::<_CMP_GT_OQ>(dt, zero);
        let v = _mm512_maskz_mov_pd(ok, dt);
        // SAFETY: as above.
        unsafe { _mm512_storeu_pd(det[..L].as_mut_ptr(), v) };
        v
    } else {
        let mut out = [[[0.0; L]; R]; R];
        for x in 0..R {
            for y in 0..R {
                out[x][y] = lanes(d[x][y]);
            }
        }
        dets_group::<R, L, 0>(&out, sg, det);
        // SAFETY: as above.
        unsafe { _mm512_loadu_pd(det[..L].as_ptr()) }
    };
    // Determinants are never NaN (0 where not positive definite), so the largest is exact
    // in any order: both maxima reduced side by side, the outside ones in lanes 0-3 and
    // the members' in lanes 4-7 of each step.
    let none = _mm512_set1_pd(f64::NEG_INFINITY);
    let outside = _mm512_cmp_pd_mask::<_CMP_GT_OQ>(s, zero);
    let member = _mm512_cmp_pd_mask::<_CMP_LT_OQ>(s, zero);
    let (o, i) = (
        _mm512_mask_blend_pd(outside, none, v),
        _mm512_mask_blend_pd(member, none, v),
    );
    // [o0 o1 o2 o3 | i0 i1 i2 i3] max [o4 o5 o6 o7 | i4 i5 i6 i7]
    let x = _mm512_max_pd(
        _mm512_shuffle_f64x2::<0b01_00_01_00>(o, i),
        _mm512_shuffle_f64x2::<0b11_10_11_10>(o, i),
    );
    // Pairs of 128-bit blocks, then neighbours within a block.
    let x = _mm512_max_pd(x, _mm512_shuffle_f64x2::<0b10_11_00_01>(x, x));
    let x = _mm512_max_pd(x, _mm512_permute_pd::<0b0101_0101>(x));
    let top = lanes(x);
    [top[0], top[4]]
}

/// Groups whose F sums are formed before any of their tails runs: a tail (a chain of
/// dependent operations from the widened F to the group's maxima) then overlaps the next
/// group's tail in the out-of-order window instead of waiting behind its sums.
const CHUNK: usize = 8;

/// D -= sign F F^T, F = C Uw, for every group (as `pass::update_group` with eight lanes:
/// F summed in single precision over the whitened blocks `w` and `uw`, one 256-bit vector
/// per entry, then widened; D's upper triangle read from `src` when given, else from `d`;
/// written to `d`), the determinants (signs `sgn`) into `dets`, and each group's largest
/// outside and member determinant into `gmax` (then `pass::group_max`). The groups are
/// taken [`CHUNK`] at a time, sums first: the same operations per group as one at a time.
///
/// # Safety
/// The CPU must have AVX-512F and FMA.
#[target_feature(enable = "avx512f,fma")]
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn update_groups<const R: usize>(
    w: &[f32],
    uw: &[f32],
    m: usize,
    sign: f64,
    src: Option<&[f64]>,
    d: &mut [f64],
    sgn: &[f64],
    dets: &mut [f64],
    gmax: &mut [[f64; 2]],
) {
    let (wl, t) = (m * R * L, upper_len(R) * L);
    let mut g0 = 0;
    while g0 < gmax.len() {
        let n = CHUNK.min(gmax.len() - g0);
        // Written once each, only the chunk's groups (a zeroed array first would be a
        // memset per chunk).
        let mut sums = [std::mem::MaybeUninit::<[[__m256; R]; R]>::uninit(); CHUNK];
        for (k, s) in sums.iter_mut().take(n).enumerate() {
            let g = g0 + k;
            // SAFETY: the caller's CPU has AVX-512F and FMA.
            s.write(unsafe { f_sums::<R>(&w[g * wl..(g + 1) * wl], uw, m) });
        }
        for (k, s) in sums.iter().take(n).enumerate() {
            let g = g0 + k;
            // SAFETY: the first n were written above.
            let s = unsafe { s.assume_init_ref() };
            let sd = src.map(|x| &x[g * t..(g + 1) * t]);
            let (dg, sg) = (&mut d[g * t..(g + 1) * t], &sgn[g * L..(g + 1) * L]);
            // SAFETY: as above.
            gmax[g] = unsafe { tail::<R>(s, sign, sd, dg, sg, &mut dets[g * L..(g + 1) * L]) };
        }
        g0 += n;
    }
}

/// F = C Uw of one group in single precision (`bw`: its whitened blocks).
///
/// # Safety
/// The CPU must have AVX-512F and FMA.
#[target_feature(enable = "avx512f,fma")]
unsafe fn f_sums<const R: usize>(bw: &[f32], uw: &[f32], m: usize) -> [[__m256; R]; R] {
    let mut f32s = [[_mm256_setzero_ps(); R]; R];
    for (bc, uc) in bw.chunks_exact(R * L).zip(uw.chunks_exact(R)).take(m) {
        let mut bx = [_mm256_setzero_ps(); R];
        for (x, v) in bx.iter_mut().enumerate() {
            // SAFETY: `bc` holds R rows of eight lanes.
            *v = unsafe { _mm256_loadu_ps(bc[x * L..(x + 1) * L].as_ptr()) };
        }
        for (y, &uy) in uc.iter().enumerate() {
            let uy = _mm256_set1_ps(uy);
            for x in 0..R {
                f32s[x][y] = _mm256_fmadd_ps(bx[x], uy, f32s[x][y]);
            }
        }
    }
    f32s
}

/// One group's D -= sign F F^T from its sums, its determinants and maxima.
///
/// # Safety
/// The CPU must have AVX-512F and FMA.
#[target_feature(enable = "avx512f,fma")]
unsafe fn tail<const R: usize>(
    f32s: &[[__m256; R]; R],
    sign: f64,
    sd: Option<&[f64]>,
    dg: &mut [f64],
    sg: &[f64],
    det: &mut [f64],
) -> [f64; 2] {
    let f: [[__m512d; R]; R] =
        std::array::from_fn(|x| std::array::from_fn(|y| _mm512_cvtps_pd(f32s[x][y])));
    let add = sign > 0.0;
    // Where D is read from, chosen once (a branch per entry keeps the compiler from holding
    // the sums in registers); in place, both pointers come from one mutable borrow.
    let t = upper_len(R) * L;
    let to = dg[..t].as_mut_ptr();
    let from: *const f64 = match sd {
        Some(sd) => sd[..t].as_ptr(),
        None => to,
    };
    let mut out = [[_mm512_setzero_pd(); R]; R];
    for x in 0..R {
        for y in x..R {
            // SAFETY: `from` and `to` hold the group's upper triangle of eight lanes (sliced
            // above); an entry is read before it is written.
            let at = upper(x, y, R) * L;
            let mut dv = unsafe { _mm512_loadu_pd(from.add(at)) };
            // D - sign F F^T term by term, fused.
            for k in 0..R {
                dv = if add {
                    _mm512_fnmadd_pd(f[x][k], f[y][k], dv)
                } else {
                    _mm512_fmadd_pd(f[x][k], f[y][k], dv)
                };
            }
            // SAFETY: as above.
            unsafe { _mm512_storeu_pd(to.add(at), dv) };
            out[x][y] = dv;
            out[y][x] = dv;
        }
    }
    // SAFETY: the caller's CPU has AVX-512F.
    unsafe { dets_and_max::<R>(&out, sg, det) }
}

/// D = B P B^T = V^T V, V = L^-1 B^T, for the eight candidates of one group, their
/// determinants (signs `sg`) into `det`, and the group's largest outside and member
/// determinant (as `pass::rebuild_group` with eight lanes, then `pass::group_max`; `li`:
/// L^-1, rows `ps` apart).
///
/// # Safety
/// The CPU must have AVX-512F and FMA.
#[target_feature(enable = "avx512f,fma")]
pub(super) unsafe fn rebuild_group<const R: usize>(
    bg: &[f64],
    li: &[f64],
    m: usize,
    ps: usize,
    dg: &mut [f64],
    sg: &[f64],
    det: &mut [f64],
) -> [f64; 2] {
    let zero = _mm512_setzero_pd();
    let mut d = [[zero; R]; R];
    // The group's B, column by column: R vectors of eight lanes each.
    let col = |k: usize| -> [__m512d; R] {
        let bk = &bg[k * R * L..(k + 1) * R * L];
        // SAFETY: `bk` holds R rows of eight lanes; the caller's CPU has AVX-512F.
        std::array::from_fn(|x| unsafe { _mm512_loadu_pd(bk[x * L..(x + 1) * L].as_ptr()) })
    };
    // Two columns of V at a time (2 R independent sums share the loads of B); each sums its
    // terms in order, as the portable kernel does.
    let mut c = 0;
    while c < m {
        let two = c + 1 < m;
        let (l0, l1) = (&li[c * ps..c * ps + c + 1], &li[(c + two as usize) * ps..]);
        let (mut v0, mut v1) = ([zero; R], [zero; R]);
        for (k, &a0) in l0.iter().enumerate() {
            let b = col(k);
            let (a0, a1) = (_mm512_set1_pd(a0), _mm512_set1_pd(l1[k]));
            for x in 0..R {
                v0[x] = _mm512_fmadd_pd(a0, b[x], v0[x]);
                v1[x] = _mm512_fmadd_pd(a1, b[x], v1[x]);
            }
        }
        for x in 0..R {
            for y in x..R {
                d[x][y] = _mm512_fmadd_pd(v0[x], v0[y], d[x][y]);
            }
        }
        if two {
            let (b, a1) = (col(c + 1), _mm512_set1_pd(l1[c + 1]));
            for x in 0..R {
                v1[x] = _mm512_fmadd_pd(a1, b[x], v1[x]);
            }
            for x in 0..R {
                for y in x..R {
                    d[x][y] = _mm512_fmadd_pd(v1[x], v1[y], d[x][y]);
                }
            }
        }
        c += 1 + two as usize;
    }
    for x in 0..R {
        for y in 0..x {
            d[x][y] = d[y][x];
        }
    }
    for x in 0..R {
        for y in x..R {
            let at = upper(x, y, R) * L;
            let o = &mut dg[at..at + L];
            // SAFETY: `o` holds eight f64.
            unsafe { _mm512_storeu_pd(o.as_mut_ptr(), d[x][y]) };
        }
    }
    // SAFETY: the caller's CPU has AVX-512F.
    unsafe { dets_and_max::<R>(&d, sg, det) }
}

/// U^T = B_a P into `ut` (as `pass::ut_of`, whose per-entry operations these are, in
/// registers: a column block's sums over the rows of P stay in vectors). Every matrix has
/// its rows `ps` apart, a multiple of eight, the padding zero.
///
/// # Safety
/// The CPU must have AVX-512F and FMA.
#[target_feature(enable = "avx512f,fma")]
pub(super) unsafe fn ut_of<const R: usize>(
    p: &[f64],
    ut: &mut [f64],
    ba: &[f64],
    m: usize,
    ps: usize,
) {
    let (p, ut, ba) = (&p[..m * ps], &mut ut[..R * ps], &ba[..R * ps]);
    // U^T, two column blocks of eight at a time (2 R independent sums).
    let mut j = 0;
    while j < ps {
        let two = j + 2 * L <= ps;
        let mut acc = [[_mm512_setzero_pd(); 2]; R];
        for (k, prow) in p.chunks_exact(ps).enumerate() {
            // SAFETY: j + 8 (j + 16 when `two`) <= ps = the row's length.
            let p0 = unsafe { _mm512_loadu_pd(prow[j..j + L].as_ptr()) };
            let p1 = if two {
                unsafe { _mm512_loadu_pd(prow[j + L..j + 2 * L].as_ptr()) }
            } else {
                p0
            };
            for (y, a) in acc.iter_mut().enumerate() {
                let b = _mm512_set1_pd(ba[y * ps + k]);
                a[0] = _mm512_fmadd_pd(b, p0, a[0]);
                a[1] = _mm512_fmadd_pd(b, p1, a[1]);
            }
        }
        for (y, a) in acc.iter().enumerate() {
            let o = &mut ut[y * ps + j..y * ps + j + L];
            // SAFETY: `o` holds eight f64.
            unsafe { _mm512_storeu_pd(o.as_mut_ptr(), a[0]) };
            if two {
                let o = &mut ut[y * ps + j + L..y * ps + j + 2 * L];
                // SAFETY: as above.
                unsafe { _mm512_storeu_pd(o.as_mut_ptr(), a[1]) };
            }
        }
        j += if two { 2 * L } else { L };
    }
}

/// P' = P - sign (U S^-1) U^T from U^T in `ut` (as `pass::p_update`, in registers: each row
/// of P is loaded and stored once).
///
/// # Safety
/// The CPU must have AVX-512F and FMA.
#[target_feature(enable = "avx512f,fma")]
pub(super) unsafe fn p_update<const R: usize>(
    p: &mut [f64],
    ut: &[f64],
    s: &[[f64; R]; R],
    sign: f64,
    m: usize,
    ps: usize,
) {
    let (p, ut) = (&mut p[..m * ps], &ut[..R * ps]);
    // P row by row: f = -sign S^-1 U(c) (scalar, as the portable kernel), then the row's R
    // terms in order, the row in registers block by block.
    for (c, row) in p.chunks_exact_mut(ps).enumerate() {
        let mut f = [0.0; R];
        for (y, v) in f.iter_mut().enumerate() {
            for k in 0..R {
                *v = ut[k * ps + c].mul_add(s[k][y], *v);
            }
            *v *= -sign;
        }
        // SAFETY: the caller's CPU has AVX-512F and FMA.
        unsafe { add_rows::<R>(row, &f, ut, ps) };
    }
}

/// row += sum over y of f[y] times row y of `rows` (rows `ps` apart, ps a multiple of eight
/// and the length of `row`), eight entries at a time in registers, the terms in y order.
///
/// # Safety
/// The CPU must have AVX-512F and FMA.
#[target_feature(enable = "avx512f,fma")]
#[inline]
unsafe fn add_rows<const R: usize>(row: &mut [f64], f: &[f64; R], rows: &[f64], ps: usize) {
    let fv: [__m512d; R] = std::array::from_fn(|y| _mm512_set1_pd(f[y]));
    assert!(ps % L == 0, "rows are padded to whole vectors");
    let (row, rows) = (&mut row[..ps], &rows[..R * ps]);
    // Offsets checked once here, not per block: block jb of row y is at y ps + 8 jb.
    for jb in (0..ps).step_by(L) {
        // SAFETY: jb + 8 <= ps = the row's length, and y ps + jb + 8 <= R ps.
        unsafe {
            let mut v = _mm512_loadu_pd(row.as_ptr().add(jb));
            for (y, &fy) in fv.iter().enumerate() {
                let b = _mm512_loadu_pd(rows.as_ptr().add(y * ps + jb));
                v = _mm512_fmadd_pd(fy, b, v);
            }
            _mm512_storeu_pd(row.as_mut_ptr().add(jb), v);
        }
    }
}

/// M += sign B_a^T B_a (as `pass::info_update`, whose per-entry operations these are, each
/// row in registers block by block; rows `ps` apart, a multiple of eight).
///
/// # Safety
/// The CPU must have AVX-512F and FMA.
#[target_feature(enable = "avx512f,fma")]
pub(super) unsafe fn info_update<const R: usize>(
    info: &mut [f64],
    ba: &[f64],
    sign: f64,
    m: usize,
    ps: usize,
) {
    let ba = &ba[..R * ps];
    for (c, row) in info[..m * ps].chunks_exact_mut(ps).enumerate() {
        let f: [f64; R] = std::array::from_fn(|y| sign * ba[y * ps + c]);
        // SAFETY: the caller's CPU has AVX-512F and FMA.
        unsafe { add_rows::<R>(row, &f, ba, ps) };
    }
}

#[cfg(test)]
mod tests {
    use super::super::pass::{dets_group, group_max};
    use super::{L, dets_and_max};
    use crate::util::Rng;
    use std::arch::x86_64::{__m512d, _mm512_loadu_pd};

    /// The vector determinants and group maxima equal the scalar ones bit for bit, for 2, 3
    /// and 6 rows, outside candidates, members and padding, positive definite or not.
    fn same_as_scalar<const R: usize>(rng: &mut Rng) {
        for _ in 0..200 {
            let mut d = [[[0.0; L]; R]; R];
            for l in 0..L {
                // D = A A^T scaled so that I - D is sometimes not positive definite.
                let a: Vec<f64> = (0..R * R).map(|_| rng.normal()).collect();
                let scale = 0.05 + 0.6 * rng.uniform();
                for x in 0..R {
                    for y in 0..R {
                        let v: f64 = (0..R).map(|k| a[x * R + k] * a[y * R + k]).sum();
                        d[x][y][l] = scale * v;
                    }
                }
            }
            let sg: Vec<f64> = (0..L)
                .map(|_| [1.0, -1.0, -1.0, 0.0][(rng.uniform() * 4.0) as usize % 4])
                .collect();
            let mut want = [0.0; L];
            dets_group::<R, L, 0>(&d, &sg, &mut want);
            let want_max = group_max(&want, &sg);
            // SAFETY: only where the CPU has AVX-512F (checked by the caller).
            let v: [[__m512d; R]; R] = std::array::from_fn(|x| {
                std::array::from_fn(|y| unsafe { _mm512_loadu_pd(d[x][y].as_ptr()) })
            });
            let mut got = [0.0; L];
            // SAFETY: as above.
            let got_max = unsafe { dets_and_max::<R>(&v, &sg, &mut got) };
            assert_eq!(got.map(f64::to_bits), want.map(f64::to_bits), "{R} rows");
            assert_eq!(
                got_max.map(f64::to_bits),
                want_max.map(f64::to_bits),
                "{R} rows"
            );
        }
    }

    #[test]
    fn vector_determinants_equal_the_scalar_ones() {
        if !std::arch::is_x86_feature_detected!("avx512f") {
            eprintln!("no AVX-512F: nothing to compare");
            return;
        }
        let mut rng = Rng::new(3);
        same_as_scalar::<2>(&mut rng);
        same_as_scalar::<3>(&mut rng);
        same_as_scalar::<6>(&mut rng);
    }
}
