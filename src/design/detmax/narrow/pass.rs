//! The passes of the lane design over the pool: the fused Woodbury update of every D_i
//! (E_i = B_i U, D_i -= sign E_i S^-1 E_i^T, both determinants) and the rebuild
//! D_i = B_i P B_i^T, compiled for AVX2 and FMA where the CPU has them.

use super::super::kernels::{madd, madd32};
use super::{Design, L, upper, upper_len};

/// det(I + sign D) of a symmetric r x r block (row-major), 0 when the matrix is not positive
/// definite (closed form for 2 and 3 rows, else the product of the Cholesky pivots).
pub(super) fn det_identity_plus(d: &[f64], r: usize, sign: f64) -> f64 {
    let g = |a: usize, b: usize| sign * d[a * r + b] + if a == b { 1.0 } else { 0.0 };
    match r {
        2 => {
            let (a, b, e) = (g(0, 0), g(0, 1), g(1, 1));
            let det = a * e - b * b;
            if a > 0.0 && det > 0.0 { det } else { 0.0 }
        }
        3 => {
            let (a, b, c, e, f, h) = (g(0, 0), g(0, 1), g(0, 2), g(1, 1), g(1, 2), g(2, 2));
            let m2 = a * e - b * b;
            let det = a * (e * h - f * f) - b * (b * h - f * c) + c * (b * f - e * c);
            if a > 0.0 && m2 > 0.0 && det > 0.0 {
                det
            } else {
                0.0
            }
        }
        _ => {
            let mut l = [0.0; 36];
            let mut det = 1.0;
            for i in 0..r {
                for j in 0..=i {
                    let s = g(i, j) - (0..j).map(|k| l[i * r + k] * l[j * r + k]).sum::<f64>();
                    if i == j {
                        if !(s > 0.0) {
                            return 0.0;
                        }
                        l[i * r + i] = s.sqrt();
                        det *= s;
                    } else {
                        l[i * r + j] = s / l[j * r + j];
                    }
                }
            }
            det
        }
    }
}

/// Which pass over the pool a kernel makes.
#[derive(Clone, Copy)]
pub(super) enum Kernel<'s> {
    /// D_i = B_i P B_i^T = V_i^T V_i with V_i = L^-1 B_i^T for every candidate (`li`: L^-1 of
    /// the Cholesky factor of P^-1, lower triangular, rows a stride apart).
    Rebuild { li: &'s [f64] },
    /// M += sign B_a^T B_a for the toggles M has not taken yet (`Design::info_pending`).
    Info,
    /// Candidate `a`'s D in double precision from P as it is, into `Design::exact`.
    Exact { a: usize },
    /// Toggle candidate `a` (sign +1: add): S = I + sign D_a from its exact D, P by
    /// Woodbury, then D_i -= sign E_i S^-1 E_i^T for every candidate with E_i = B_i U,
    /// as F_i F_i^T with F_i = E_i L^-T (S = L L^T) formed in single precision as
    /// C_i (L0^T U L^-T) from the whitened blocks; D read from
    /// `src` (another design's, the one this design is a toggle of) when given, else from
    /// the design's own.
    Update {
        a: usize,
        sign: f64,
        src: Option<&'s [f64]>,
    },
}

/// Run a kernel with FMA and 512-bit vectors (a group's eight lanes at once) when the CPU has
/// them, else with FMA and 256-bit vectors (a group in two halves of four). Each lane sees
/// the same operations in the same order on every path, so the results are identical.
/// An update answers the change of log det it made, None when S is not positive definite
/// (then nothing was changed); the other kernels answer Some(0).
pub(super) fn dispatch<const R: usize>(k: Kernel<'_>, d: &mut Design<'_>) -> Option<f64> {
    #[cfg(target_arch = "x86_64")]
    {
        let widest = widest();
        if widest >= 8
            && std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports the features the function is compiled for.
            return unsafe { run_avx512::<R>(k, d) };
        }
        if widest >= 4
            && std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: as above.
            return unsafe { run_fma::<R>(k, d) };
        }
    }
    run::<R, false, 4>(k, d)
}

#[cfg(test)]
thread_local! {
    /// The widest kernel a test lets this thread use (8: AVX-512, 4: AVX2, 0: portable).
    pub(in super::super) static WIDEST: std::cell::Cell<usize> = const { std::cell::Cell::new(8) };
}

/// The widest kernel allowed: all of them, except where a test narrows it.
#[inline]
fn widest() -> usize {
    #[cfg(test)]
    return WIDEST.with(|w| w.get());
    #[cfg(not(test))]
    8
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
unsafe fn run_avx512<const R: usize>(k: Kernel<'_>, d: &mut Design<'_>) -> Option<f64> {
    run::<R, true, 8>(k, d)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn run_fma<const R: usize>(k: Kernel<'_>, d: &mut Design<'_>) -> Option<f64> {
    run::<R, true, 4>(k, d)
}

/// One pass, `W` lanes at a time (W = 8: a whole group, in the AVX-512 kernels, only when
/// called from `run_avx512`; W = 4: a group in two halves).
#[inline(always)]
fn run<const R: usize, const FMA: bool, const W: usize>(
    k: Kernel<'_>,
    d: &mut Design<'_>,
) -> Option<f64> {
    let (m, ps) = (d.lp.m, d.lp.stride());
    let blocks = d.lp.b.chunks_exact(m * R * L);
    match k {
        Kernel::Rebuild { li } => {
            let outs =
                d.d.chunks_exact_mut(upper_len(R) * L)
                    .zip(d.dets.chunks_exact_mut(L).zip(d.sgn.chunks_exact(L)));
            for ((bg, (dg, (det, sg))), gm) in blocks.zip(outs).zip(&mut d.gmax) {
                #[cfg(target_arch = "x86_64")]
                if W == L {
                    // SAFETY: a whole group per vector only from `run_avx512`.
                    *gm = unsafe { super::avx512::rebuild_group::<R>(bg, li, m, ps, dg, sg, det) };
                    continue;
                }
                let dr = rebuild_group::<R, FMA, W, 0>(bg, li, m, ps, dg);
                dets_group::<R, W, 0>(&dr, sg, det);
                if W < L {
                    let dr = rebuild_group::<R, FMA, W, 1>(bg, li, m, ps, dg);
                    dets_group::<R, W, 1>(&dr, sg, det);
                }
                *gm = group_max(det, sg);
            }
        }
        Kernel::Info => {
            // M' = M + sign B_a^T B_a, toggle by toggle in the order they were made.
            let lp = d.lp;
            for &(a, sign) in &d.info_pending {
                let ba = lp.block(a);
                #[cfg(target_arch = "x86_64")]
                if W == L {
                    // SAFETY: whole vectors only from `run_avx512`.
                    unsafe { super::avx512::info_update::<R>(&mut d.info, ba, sign, m, ps) };
                    continue;
                }
                info_update::<R, FMA>(&mut d.info, ba, sign, m, ps);
            }
            d.info_pending.clear();
        }
        Kernel::Exact { a } => {
            d.exact = exact_at::<R, FMA, W>(d, a);
            d.exact_of = Some(a);
        }
        Kernel::Update { a, sign, src } => {
            // U^T and D_a as an exact change of `a` left them from this P, else afresh (P
            // changes below either way).
            let mut block = match d.exact_of.take() {
                Some(e) if e == a => d.exact,
                _ => exact_at::<R, FMA, W>(d, a),
            };
            for x in 0..R {
                block[x * R + x] = sign * block[x * R + x] + 1.0;
                for y in (0..R).filter(|&y| y != x) {
                    block[x * R + y] *= sign;
                }
            }
            let (ld, sinv, li) = super::super::kernels::small_inverse6(&block[..R * R], R)?;
            // The pass writes a's determinant for its next toggle, the other way.
            d.member[a] = sign > 0.0;
            d.sgn[a] = -sign;
            let s: [[f64; R]; R] =
                std::array::from_fn(|x| std::array::from_fn(|y| sinv[x * R + y]));
            p_update::<R, FMA, W>(d, &s, sign);
            // (L0^T U)^T = U^T L0, eight columns at a time in registers (L0 is lower
            // triangular: rows above a block are zero there), rounded once to single
            // precision.
            // The R rows' sums of a block side by side: R independent chains per row of L0.
            let l0 = &d.lp.l0[..m * ps];
            let uts: [&[f64]; R] = std::array::from_fn(|y| &d.ut[y * ps..y * ps + m]);
            for j in (0..ps).step_by(L) {
                let mut acc = [[0.0; L]; R];
                for (k, lrow) in l0.chunks_exact(ps).enumerate().skip(j) {
                    let lb = &lrow[j..j + L];
                    for (ay, uty) in acc.iter_mut().zip(&uts) {
                        let f = uty[k];
                        for l in 0..L {
                            ay[l] = madd::<FMA>(f, lb[l], ay[l]);
                        }
                    }
                }
                for (y, ay) in acc.iter().enumerate() {
                    d.wt[y * ps + j..y * ps + j + L].copy_from_slice(ay);
                }
            }
            // S^-1 = L^-T L^-1 (L the Cholesky factor of S), so E S^-1 E^T = F F^T with
            // F = E L^-T = C (L0^T U L^-T): the factor goes into what the blocks multiply,
            // and the pass forms F F^T (6 of 9 sums for three rows) with no product by S^-1.
            for c in 0..m {
                for k in 0..R {
                    let mut v = 0.0;
                    for y in 0..=k {
                        v = madd::<FMA>(d.wt[y * ps + c], li[k * R + y], v);
                    }
                    d.uw[c * R + k] = v as f32;
                }
            }
            #[cfg(target_arch = "x86_64")]
            if W == L {
                // SAFETY: whole groups per vector only from `run_avx512`.
                unsafe {
                    super::avx512::update_groups::<R>(
                        &d.lp.w,
                        &d.uw,
                        m,
                        sign,
                        src,
                        &mut d.d,
                        &d.sgn,
                        &mut d.dets,
                        &mut d.gmax,
                    )
                };
                return Some(ld);
            }
            let wblocks = d.lp.w.chunks_exact(m * R * L);
            let outs =
                d.d.chunks_exact_mut(upper_len(R) * L)
                    .zip(d.dets.chunks_exact_mut(L).zip(d.sgn.chunks_exact(L)));
            for (g, ((wg, (dg, (det, sg))), gm)) in wblocks.zip(outs).zip(&mut d.gmax).enumerate() {
                let t = upper_len(R) * L;
                let sd = src.map(|x| &x[g * t..(g + 1) * t]);
                let dr = update_group::<R, FMA, W, 0>(wg, &d.uw, m, sign, sd, dg);
                dets_group::<R, W, 0>(&dr, sg, det);
                if W < L {
                    let dr = update_group::<R, FMA, W, 1>(wg, &d.uw, m, sign, sd, dg);
                    dets_group::<R, W, 1>(&dr, sg, det);
                }
                *gm = group_max(det, sg);
            }
            return Some(ld);
        }
    }
    Some(0.0)
}

/// M += sign B_a^T B_a (m x m `info`, B_a r x m, rows `ps` apart), row by row, each entry
/// taking its R terms in order (whole padded rows, so they vectorise without a remainder).
#[inline(always)]
fn info_update<const R: usize, const FMA: bool>(
    info: &mut [f64],
    ba: &[f64],
    sign: f64,
    m: usize,
    ps: usize,
) {
    let ba = &ba[..R * ps];
    for (c, row) in info[..m * ps].chunks_exact_mut(ps).enumerate() {
        for bay in ba.chunks_exact(ps) {
            let f = sign * bay[c];
            for (mv, &bv) in row.iter_mut().zip(bay) {
                *mv = madd::<FMA>(f, bv, *mv);
            }
        }
    }
}

/// U^T = B_a P into the design's `ut`, then D_a = U^T B_a^T, candidate a's D in double
/// precision from P as it is (row-major R x R), in AVX-512 registers when called from
/// `run_avx512`.
#[inline(always)]
fn exact_at<const R: usize, const FMA: bool, const W: usize>(
    d: &mut Design<'_>,
    a: usize,
) -> [f64; 36] {
    let ba = d.lp.block(a);
    ut_at::<R, FMA, W>(d, ba);
    let ps = d.lp.stride();
    let mut out = [0.0; 36];
    for x in 0..R {
        for y in 0..R {
            let (a, b) = (&d.ut[x * ps..(x + 1) * ps], &ba[y * ps..(y + 1) * ps]);
            out[x * R + y] = dot8::<FMA>(a, b);
        }
    }
    out
}

/// [`ut_of`] of the design's P and B_a into its `ut`, in AVX-512 registers when called from
/// `run_avx512`.
#[inline(always)]
fn ut_at<const R: usize, const FMA: bool, const W: usize>(d: &mut Design<'_>, ba: &[f64]) {
    let (m, ps) = (d.lp.m, d.lp.stride());
    #[cfg(target_arch = "x86_64")]
    if W == L {
        // SAFETY: whole vectors only from `run_avx512`.
        unsafe { super::avx512::ut_of::<R>(&d.p, &mut d.ut, ba, m, ps) };
        return;
    }
    ut_of::<R, FMA>(&d.p, &mut d.ut, ba, m, ps);
}

/// The dot product of two padded rows (length a multiple of eight) in eight lanes, summed
/// in a fixed tree: the same value at every vector width.
#[inline(always)]
fn dot8<const FMA: bool>(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0; L];
    for (ac, bc) in a.chunks_exact(L).zip(b.chunks_exact(L)) {
        for l in 0..L {
            acc[l] = madd::<FMA>(ac[l], bc[l], acc[l]);
        }
    }
    ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]))
}

/// U^T = B_a P into `ut` (r x m; P is symmetric, so this is (P B_a^T)^T), along whole padded
/// rows of P, so it vectorises without a remainder.
#[inline(always)]
fn ut_of<const R: usize, const FMA: bool>(
    p: &[f64],
    ut: &mut [f64],
    ba: &[f64],
    m: usize,
    ps: usize,
) {
    let (p, ut, ba) = (&p[..m * ps], &mut ut[..R * ps], &ba[..R * ps]);
    ut.fill(0.0);
    for (k, prow) in p.chunks_exact(ps).enumerate() {
        for (uty, bay) in ut.chunks_exact_mut(ps).zip(ba.chunks_exact(ps)) {
            let b = bay[k];
            for (u, &pv) in uty.iter_mut().zip(prow) {
                *u = madd::<FMA>(b, pv, *u);
            }
        }
    }
}

/// P' = P - sign (U S^-1) U^T row by row (P m x m, U^T in `ut`, S^-1 as `s`; every matrix
/// with rows `ps` apart), in AVX-512 registers when called from `run_avx512`.
#[inline(always)]
fn p_update<const R: usize, const FMA: bool, const W: usize>(
    d: &mut Design<'_>,
    s: &[[f64; R]; R],
    sign: f64,
) {
    let (m, ps) = (d.lp.m, d.lp.stride());
    #[cfg(target_arch = "x86_64")]
    if W == L {
        // SAFETY: whole vectors only from `run_avx512`.
        unsafe { super::avx512::p_update::<R>(&mut d.p, &d.ut, s, sign, m, ps) };
        return;
    }
    let (p, ut) = (&mut d.p[..m * ps], &d.ut[..R * ps]);
    let rows: [&[f64]; R] = std::array::from_fn(|y| &ut[y * ps..(y + 1) * ps]);
    for (c, row) in p.chunks_exact_mut(ps).enumerate() {
        let mut f = [0.0; R];
        for (y, v) in f.iter_mut().enumerate() {
            for k in 0..R {
                *v = madd::<FMA>(rows[k][c], s[k][y], *v);
            }
            *v *= -sign;
        }
        // Each entry takes its R terms in order (y by y, a whole row per term).
        for (&fy, uty) in f.iter().zip(rows) {
            for (pv, &uv) in row.iter_mut().zip(uty) {
                *pv = madd::<FMA>(fy, uv, *pv);
            }
        }
    }
}

/// The largest det of a group's outside candidates (sign +1) and of its members (-1); -inf
/// where it has none (padding has sign 0).
#[inline(always)]
pub(super) fn group_max(det: &[f64], sg: &[f64]) -> [f64; 2] {
    let (mut out, mut ins) = ([f64::NEG_INFINITY; L], [f64::NEG_INFINITY; L]);
    for l in 0..L {
        let v = det[l];
        out[l] = if sg[l] > 0.0 && v > out[l] { v } else { out[l] };
        ins[l] = if sg[l] < 0.0 && v > ins[l] { v } else { ins[l] };
    }
    let top = |x: [f64; L]| {
        x.iter()
            .fold(f64::NEG_INFINITY, |a, &b| if b > a { b } else { a })
    };
    [top(out), top(ins)]
}

/// det(I + sign D) of the `W` candidates from lane `H W` of a group, each with its own sign
/// (`sg`: +1 for an outside candidate, whose add is what a scan asks, -1 for a member), 0
/// where not positive definite, into `out` (the group's lanes).
#[inline(always)]
pub(super) fn dets_group<const R: usize, const W: usize, const H: usize>(
    d: &[[[f64; W]; R]; R],
    sg: &[f64],
    out: &mut [f64],
) {
    let sg = &sg[H * W..(H + 1) * W];
    let o = &mut out[H * W..(H + 1) * W];
    if R == 3 {
        // The closed form of det_identity_plus, lane by lane.
        for l in 0..W {
            let sign = sg[l];
            let a = sign * d[0][0][l] + 1.0;
            let b = sign * d[0][1][l];
            let c = sign * d[0][2][l];
            let e = sign * d[1][1][l] + 1.0;
            let f = sign * d[1][2][l];
            let h = sign * d[2][2][l] + 1.0;
            let m2 = a * e - b * b;
            let det = a * (e * h - f * f) - b * (b * h - f * c) + c * (b * f - e * c);
            o[l] = if a > 0.0 && m2 > 0.0 && det > 0.0 {
                det
            } else {
                0.0
            };
        }
    } else {
        for l in 0..W {
            let mut block = [0.0; 36];
            for x in 0..R {
                for y in 0..R {
                    block[x * R + y] = d[x][y][l];
                }
            }
            o[l] = det_identity_plus(&block[..R * R], R, sg[l]);
        }
    }
}

/// D = B P B^T = V^T V, V = L^-1 B^T, for the `W` candidates from lane `H W` of one group:
/// column c of V sums its c + 1 terms in order, then D's upper triangle takes V's columns in
/// order; stored as it is and mirrored for the determinants (`li`: L^-1, rows `ps` apart).
#[inline(always)]
fn rebuild_group<const R: usize, const FMA: bool, const W: usize, const H: usize>(
    bg: &[f64],
    li: &[f64],
    m: usize,
    ps: usize,
    dg: &mut [f64],
) -> [[[f64; W]; R]; R] {
    let mut d = [[[0.0; W]; R]; R];
    for (c, lrow) in li.chunks_exact(ps).take(m).enumerate() {
        let mut v = [[0.0; W]; R];
        for (bk, &lk) in bg.chunks_exact(R * L).zip(&lrow[..=c]) {
            for x in 0..R {
                for l in 0..W {
                    v[x][l] = madd::<FMA>(lk, bk[x * L + H * W + l], v[x][l]);
                }
            }
        }
        for x in 0..R {
            for y in x..R {
                for l in 0..W {
                    d[x][y][l] = madd::<FMA>(v[x][l], v[y][l], d[x][y][l]);
                }
            }
        }
    }
    for x in 0..R {
        for y in 0..x {
            d[x][y] = d[y][x];
        }
    }
    for x in 0..R {
        for y in x..R {
            let o = upper(x, y, R) * L + H * W;
            dg[o..o + W].copy_from_slice(&d[x][y]);
        }
    }
    d
}

/// D -= sign F F^T, F = C Uw, for the `W` candidates from lane `H W` of one group (`bw`:
/// the group's whitened single-precision blocks, `uw`: L0^T U L^-T, F summed in single
/// precision and then widened; D, its upper triangle, read from `sd` when given, else from
/// `dg`; written to `dg`).
#[inline(always)]
fn update_group<const R: usize, const FMA: bool, const W: usize, const H: usize>(
    bw: &[f32],
    uw: &[f32],
    m: usize,
    sign: f64,
    sd: Option<&[f64]>,
    dg: &mut [f64],
) -> [[[f64; W]; R]; R] {
    let mut f32s = [[[0.0f32; W]; R]; R];
    // Iterators, not indices: no bounds checks in the innermost loop.
    for (bc, uc) in bw.chunks_exact(R * L).zip(uw.chunks_exact(R)).take(m) {
        for x in 0..R {
            for y in 0..R {
                for l in 0..W {
                    f32s[x][y][l] = madd32::<FMA>(bc[x * L + H * W + l], uc[y], f32s[x][y][l]);
                }
            }
        }
    }
    let f: [[[f64; W]; R]; R] =
        std::array::from_fn(|x| std::array::from_fn(|y| f32s[x][y].map(f64::from)));
    let mut out = [[[0.0; W]; R]; R];
    for x in 0..R {
        for y in x..R {
            let o = upper(x, y, R) * L + H * W;
            for l in 0..W {
                // D - sign F F^T term by term from D, each fused (the product by +-1 is
                // exact: the AVX-512 kernel's fnmadd or fmadd).
                let mut nv = sd.map_or(dg[o + l], |sd| sd[o + l]);
                for k in 0..R {
                    nv = madd::<FMA>(-sign * f[x][k][l], f[y][k][l], nv);
                }
                dg[o + l] = nv;
                out[x][y][l] = nv;
                out[y][x][l] = nv;
            }
        }
    }
    out
}
