//! Exchange state for pools whose blocks all have 2, 3 or 6 rows (a serial arm's ball-centring
//! or tracker measurement is 3 rows). The candidates are stored in groups of four,
//! lane-interleaved, so the Woodbury update of every D_i after a toggle is one fused pass
//! over the pool in SIMD lanes: E_i = B_i U and D_i -= sign E_i S^-1 E_i^T together, in
//! registers, with no packing and no temporaries. The general [`super::exchange`] state is
//! the reference it is tested against.

use super::kernels::{Info, madd};
use super::pool::Pool;

/// Candidates per group (one 256-bit vector of f64).
pub(super) const L: usize = 4;

/// The blocks of a uniform pool, lane-interleaved: entry (x, c) of candidate 4 g + l at
/// `b[((g m + c) r + x) L + l]`; padding candidates are zero.
#[derive(Debug, Clone)]
pub(super) struct LanePool {
    r: usize,
    m: usize,
    n: usize,
    b: Vec<f64>,
}

impl LanePool {
    /// The lane layout of `n` blocks of `r` rows, `block(i, x, c)` giving entry (x, c) of
    /// block i; None when r has no fused kernel.
    pub(super) fn new(
        n: usize,
        r: usize,
        m: usize,
        block: impl Fn(usize, usize, usize) -> f64,
    ) -> Option<Self> {
        if !matches!(r, 2 | 3 | 6) {
            return None;
        }
        let groups = n.div_ceil(L);
        let mut b = vec![0.0; groups * m * r * L];
        for i in 0..n {
            let (g, l) = (i / L, i % L);
            for c in 0..m {
                for x in 0..r {
                    b[((g * m + c) * r + x) * L + l] = block(i, x, c);
                }
            }
        }
        Some(Self { r, m, n, b })
    }

    /// Entry (x, c) of candidate i's block.
    fn at(&self, i: usize, x: usize, c: usize) -> f64 {
        let (g, l) = (i / L, i % L);
        self.b[((g * self.m + c) * self.r + x) * L + l]
    }
}

/// Exchange state of a design over a [`LanePool`].
pub(super) struct Design<'a> {
    lp: &'a LanePool,
    pub(super) member: Vec<bool>,
    pub(super) log_det: f64,
    /// P = (M + ridge I)^-1 (m x m, row-major, symmetric).
    p: Vec<f64>,
    /// M = sum of the members' B_i^T B_i (m x m, row-major), kept by every toggle so the
    /// exact determinant of a design costs one Cholesky, not a product over its rows.
    info: Vec<f64>,
    /// D_i = B_i P B_i^T, lane-interleaved: entry (x, y) of candidate 4 g + l at
    /// `d[((g r + x) r + y) L + l]`.
    d: Vec<f64>,
    /// det(I + D_i) and det(I - D_i), lane-interleaved: candidate 4 g + l at
    /// `dets[(2 g + s) L + l]`, s = 0 for adding and 1 for removing (0: not positive
    /// definite). Kept by the kernels, so a greedy scan reads one number per candidate.
    dets: Vec<f64>,
    /// Scratch of a toggle: B_a (r x m, row-major) and U^T (r x m).
    ba: Vec<f64>,
    ut: Vec<f64>,
    /// U = P B_a^T (m x r, row-major).
    u: Vec<f64>,
    pub(super) updates: usize,
}

impl Clone for Design<'_> {
    fn clone(&self) -> Self {
        Self {
            lp: self.lp,
            member: self.member.clone(),
            log_det: self.log_det,
            p: self.p.clone(),
            info: self.info.clone(),
            d: self.d.clone(),
            dets: self.dets.clone(),
            ba: self.ba.clone(),
            ut: self.ut.clone(),
            u: self.u.clone(),
            updates: self.updates,
        }
    }

    /// A copy into the buffers already held (an excursion's trial design, once per try).
    fn clone_from(&mut self, src: &Self) {
        self.lp = src.lp;
        self.member.clone_from(&src.member);
        self.log_det = src.log_det;
        self.p.clone_from(&src.p);
        self.info.clone_from(&src.info);
        self.d.clone_from(&src.d);
        self.dets.clone_from(&src.dets);
        self.updates = src.updates;
    }
}

impl<'a> Design<'a> {
    pub(super) fn new(
        pool: &'a Pool,
        lp: &'a LanePool,
        start: &[usize],
        ridge: f64,
    ) -> Option<Self> {
        let mut member = vec![false; lp.n];
        for &i in start {
            member[i] = true;
        }
        let (m, r) = (lp.m, lp.r);
        let mut d = Self {
            lp,
            member,
            log_det: 0.0,
            p: vec![0.0; m * m],
            info: Vec::new(),
            d: vec![0.0; lp.n.div_ceil(L) * r * r * L],
            dets: vec![0.0; lp.n.div_ceil(L) * 2 * L],
            ba: vec![0.0; m * r],
            ut: vec![0.0; m * r],
            u: vec![0.0; m * r],
            updates: 0,
        };
        d.rebuild(pool, ridge)?;
        Some(d)
    }

    /// Recompute P and every D_i from the member set (start, and to stop drift).
    pub(super) fn rebuild(&mut self, pool: &Pool, ridge: f64) -> Option<()> {
        let members: Vec<usize> = self.selected();
        self.info = pool.information(&members);
        let mut a = Info::new(self.lp.m);
        a.a.clone_from(&self.info);
        for k in 0..self.lp.m {
            a.a[k * self.lp.m + k] += ridge;
        }
        let f = a.factor()?;
        self.log_det = f.log_det();
        self.p = f.inverse();
        match self.lp.r {
            2 => dispatch::<2>(Kernel::Rebuild, self),
            3 => dispatch::<3>(Kernel::Rebuild, self),
            _ => dispatch::<6>(Kernel::Rebuild, self),
        }
        self.updates = 0;
        Some(())
    }

    /// D_i of candidate i as a row-major r x r block.
    fn d_of(&self, i: usize, out: &mut [f64; 36]) {
        let r = self.lp.r;
        let (g, l) = (i / L, i % L);
        for k in 0..r * r {
            out[k] = self.d[(g * r * r + k) * L + l];
        }
    }

    /// The candidate whose toggle (add: an outside one, else an inside one) leaves the
    /// largest determinant, with the change of log det; nothing is changed.
    pub(super) fn best(&self, add: bool) -> Option<(usize, f64)> {
        let s = usize::from(!add);
        // Compare determinants, take the logarithm of the winner only.
        let mut best: Option<(usize, f64)> = None;
        for i in 0..self.lp.n {
            if self.member[i] == add {
                continue;
            }
            let det = self.dets[(2 * (i / L) + s) * L + i % L];
            if best.is_none_or(|b| det > b.1) {
                best = Some((i, det));
            }
        }
        best.map(|(i, det)| {
            (
                i,
                if det > 0.0 {
                    det.ln()
                } else {
                    f64::NEG_INFINITY
                },
            )
        })
    }

    /// Add (sign +1) or remove (sign -1) candidate `a`: P and every D_i by Woodbury.
    pub(super) fn toggle(&mut self, a: usize, sign: f64) -> Option<()> {
        let (m, r) = (self.lp.m, self.lp.r);
        let mut block = [0.0; 36];
        self.d_of(a, &mut block);
        for x in 0..r {
            for y in 0..r {
                block[x * r + y] = sign * block[x * r + y] + if x == y { 1.0 } else { 0.0 };
            }
        }
        let (ld, sinv) = super::kernels::small_inverse(&block[..r * r], r)?;
        for y in 0..r {
            for k in 0..m {
                self.ba[y * m + k] = self.lp.at(a, y, k);
            }
        }
        let kernel = Kernel::Update { sinv: &sinv, sign };
        match r {
            2 => dispatch::<2>(kernel, self),
            3 => dispatch::<3>(kernel, self),
            _ => dispatch::<6>(kernel, self),
        }
        self.log_det += ld;
        self.member[a] = sign > 0.0;
        self.updates += 1;
        Some(())
    }

    /// log det M (no ridge) of the members, with candidate `extra` added (true) or removed
    /// (false) if given; -inf when singular.
    pub(super) fn exact_log_det(&self, extra: Option<(usize, bool)>) -> f64 {
        let (m, r) = (self.lp.m, self.lp.r);
        let mut a = Info::new(m);
        a.a.clone_from(&self.info);
        if let Some((i, add)) = extra {
            let sign = if add { 1.0 } else { -1.0 };
            for c in 0..m {
                for c2 in 0..=c {
                    let v: f64 = (0..r)
                        .map(|y| self.lp.at(i, y, c) * self.lp.at(i, y, c2))
                        .sum();
                    a.a[c * m + c2] += sign * v;
                }
            }
        }
        a.factor().map_or(f64::NEG_INFINITY, |f| f.log_det())
    }

    pub(super) fn selected(&self) -> Vec<usize> {
        (0..self.member.len()).filter(|&i| self.member[i]).collect()
    }
}

/// det(I + sign D) of a symmetric r x r block (row-major), 0 when the matrix is not positive
/// definite (closed form for 2 and 3 rows, else the product of the Cholesky pivots).
fn det_identity_plus(d: &[f64], r: usize, sign: f64) -> f64 {
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
enum Kernel<'s> {
    /// D_i = B_i P B_i^T for every candidate.
    Rebuild,
    /// D_i -= sign E_i S^-1 E_i^T with E_i = B_i U.
    Update { sinv: &'s [f64], sign: f64 },
}

/// Run a kernel with FMA and 256-bit vectors when the CPU has them.
fn dispatch<const R: usize>(k: Kernel<'_>, d: &mut Design<'_>) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports the features the function is compiled for.
        unsafe { run_fma::<R>(k, d) };
        return;
    }
    run::<R, false>(k, d);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn run_fma<const R: usize>(k: Kernel<'_>, d: &mut Design<'_>) {
    run::<R, true>(k, d);
}

#[inline(always)]
fn run<const R: usize, const FMA: bool>(k: Kernel<'_>, d: &mut Design<'_>) {
    let m = d.lp.m;
    let blocks = d.lp.b.chunks_exact(m * R * L);
    match k {
        Kernel::Rebuild => {
            let outs =
                d.d.chunks_exact_mut(R * R * L)
                    .zip(d.dets.chunks_exact_mut(2 * L));
            for (bg, (dg, det)) in blocks.zip(outs) {
                let dr = rebuild_group::<R, FMA>(bg, &d.p, m, dg);
                dets_group::<R>(&dr, det);
            }
        }
        Kernel::Update { sinv, sign } => {
            let mut s = [[0.0; R]; R];
            for x in 0..R {
                for y in 0..R {
                    s[x][y] = sinv[x * R + y];
                }
            }
            // U^T = (P B_a^T)^T, then P' = P - sign (U S^-1) U^T, row by row.
            for y in 0..R {
                let bay = &d.ba[y * m..(y + 1) * m];
                for c in 0..m {
                    d.ut[y * m + c] = dot::<FMA>(&d.p[c * m..(c + 1) * m], bay);
                }
            }
            for c in 0..m {
                let mut us = [0.0; R];
                for (y, v) in us.iter_mut().enumerate() {
                    for k in 0..R {
                        *v = madd::<FMA>(d.ut[k * m + c], s[k][y], *v);
                    }
                }
                let row = &mut d.p[c * m..(c + 1) * m];
                for (y, &v) in us.iter().enumerate() {
                    let f = -sign * v;
                    for (pv, &uv) in row.iter_mut().zip(&d.ut[y * m..(y + 1) * m]) {
                        *pv = madd::<FMA>(f, uv, *pv);
                    }
                }
            }
            for c in 0..m {
                for y in 0..R {
                    d.u[c * R + y] = d.ut[y * m + c];
                }
            }
            // M' = M + sign B_a^T B_a.
            for c in 0..m {
                let row = &mut d.info[c * m..(c + 1) * m];
                for y in 0..R {
                    let f = sign * d.ba[y * m + c];
                    for (mv, &bv) in row.iter_mut().zip(&d.ba[y * m..(y + 1) * m]) {
                        *mv = madd::<FMA>(f, bv, *mv);
                    }
                }
            }
            let outs =
                d.d.chunks_exact_mut(R * R * L)
                    .zip(d.dets.chunks_exact_mut(2 * L));
            for (bg, (dg, det)) in blocks.zip(outs) {
                let dr = update_group::<R, FMA>(bg, &d.u, m, &s, sign, dg);
                dets_group::<R>(&dr, det);
            }
        }
    }
}

/// Dot product with four accumulators (fused when compiled for FMA).
#[inline(always)]
fn dot<const FMA: bool>(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for l in 0..4 {
            acc[l] = madd::<FMA>(x[l], y[l], acc[l]);
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for (x, y) in ra.iter().zip(rb) {
        s = madd::<FMA>(*x, *y, s);
    }
    s
}

/// det(I + D) and det(I - D) of the four candidates of a group (0 where not positive
/// definite), into `out` (adding lanes, then removing lanes).
#[inline(always)]
fn dets_group<const R: usize>(d: &[[[f64; L]; R]; R], out: &mut [f64]) {
    for (s, sign) in [(0, 1.0), (1, -1.0)] {
        let o = &mut out[s * L..(s + 1) * L];
        if R == 3 {
            // The closed form of det_identity_plus, lane by lane.
            for l in 0..L {
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
            for l in 0..L {
                let mut block = [0.0; 36];
                for x in 0..R {
                    for y in 0..R {
                        block[x * R + y] = d[x][y][l];
                    }
                }
                o[l] = det_identity_plus(&block[..R * R], R, sign);
            }
        }
    }
}

/// D = B P B^T for the four candidates of one group.
#[inline(always)]
fn rebuild_group<const R: usize, const FMA: bool>(
    bg: &[f64],
    p: &[f64],
    m: usize,
    dg: &mut [f64],
) -> [[[f64; L]; R]; R] {
    let mut d = [[[0.0; L]; R]; R];
    for c2 in 0..m {
        // w[x] = (B P)(x, c2), then D(x, y) += w[x] B(y, c2).
        let mut w = [[0.0; L]; R];
        for (bc, prow) in bg.chunks_exact(R * L).zip(p.chunks_exact(m)).take(m) {
            let pc = prow[c2];
            for x in 0..R {
                for l in 0..L {
                    w[x][l] = madd::<FMA>(bc[x * L + l], pc, w[x][l]);
                }
            }
        }
        let bc2 = &bg[c2 * R * L..(c2 + 1) * R * L];
        for x in 0..R {
            for y in 0..R {
                for l in 0..L {
                    d[x][y][l] = madd::<FMA>(w[x][l], bc2[y * L + l], d[x][y][l]);
                }
            }
        }
    }
    for x in 0..R {
        for y in 0..R {
            dg[(x * R + y) * L..(x * R + y + 1) * L].copy_from_slice(&d[x][y]);
        }
    }
    d
}

/// D -= sign (B U) S^-1 (B U)^T for the four candidates of one group.
#[inline(always)]
fn update_group<const R: usize, const FMA: bool>(
    bg: &[f64],
    u: &[f64],
    m: usize,
    s: &[[f64; R]; R],
    sign: f64,
    dg: &mut [f64],
) -> [[[f64; L]; R]; R] {
    let mut e = [[[0.0; L]; R]; R];
    // Iterators, not indices: no bounds checks in the innermost loop.
    for (bc, uc) in bg.chunks_exact(R * L).zip(u.chunks_exact(R)).take(m) {
        for x in 0..R {
            for y in 0..R {
                for l in 0..L {
                    e[x][y][l] = madd::<FMA>(bc[x * L + l], uc[y], e[x][y][l]);
                }
            }
        }
    }
    let mut es = [[[0.0; L]; R]; R];
    for x in 0..R {
        for y in 0..R {
            for k in 0..R {
                for l in 0..L {
                    es[x][y][l] = madd::<FMA>(e[x][k][l], s[k][y], es[x][y][l]);
                }
            }
        }
    }
    let mut out = [[[0.0; L]; R]; R];
    for x in 0..R {
        for y in 0..R {
            let o = (x * R + y) * L;
            for l in 0..L {
                let mut v = 0.0;
                for k in 0..R {
                    v = madd::<FMA>(es[x][k][l], e[y][k][l], v);
                }
                dg[o + l] -= sign * v;
                out[x][y][l] = dg[o + l];
            }
        }
    }
    out
}
