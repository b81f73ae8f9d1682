//! Exchange state for pools whose blocks all have 2, 3 or 6 rows (a serial arm's ball-centring
//! or tracker measurement is 3 rows). The candidates are stored in groups of eight,
//! lane-interleaved, so the Woodbury update of every D_i after a toggle is one fused pass
//! over the pool in SIMD lanes: E_i = B_i U and D_i -= sign E_i S^-1 E_i^T together, in
//! registers, with no packing and no temporaries. E_i is summed in single precision over
//! whitened blocks (see [`LanePool`]), so the tracked D_i only rank candidates: the toggled
//! candidate's D_a, and the determinant an exchange is accepted on, come from P in double
//! precision. The general [`super::exchange`] state is the reference it is tested against.

#[cfg(target_arch = "x86_64")]
mod avx512;
mod pass;
#[cfg(test)]
pub(super) use pass::WIDEST;

use super::kernels::Info;
use super::pool::Pool;
use pass::{Kernel, dispatch};

/// Candidates per group (one 512-bit vector of f64, or two 256-bit ones).
pub(super) const L: usize = 8;

/// The blocks of a uniform pool, lane-interleaved: entry (x, c) of candidate 8 g + l at
/// `b[((g m + c) r + x) L + l]`; padding candidates are zero.
///
/// Beside them, the same blocks whitened by the pool's own information M0 = L0 L0^T, in
/// single precision: C_i = B_i L0^-T (same layout, `w`). The passes form E_i = B_i U as
/// C_i (L0^T U): in whitened coordinates the sum has no cancellation between columns of
/// different units or correlated columns, so single precision (twice the lanes per
/// instruction) costs ~1e-7 relative in E_i, which only the ranking of candidates sees;
/// every determinant a decision is taken on is recomputed in double precision.
#[derive(Debug, Clone)]
pub(super) struct LanePool {
    r: usize,
    m: usize,
    n: usize,
    b: Vec<f64>,
    /// The same blocks one after another, each row-major with rows [`LanePool::stride`]
    /// apart: what a toggle reads of its candidate (one slice, not a gather from the lanes).
    rows: Vec<f64>,
    w: Vec<f32>,
    /// L0 (row-major m x m, lower triangular, rows [`LanePool::stride`] apart).
    l0: Vec<f64>,
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
        let ps = m.next_multiple_of(L);
        let mut rows = vec![0.0; n * r * ps];
        for (i, bi) in rows.chunks_exact_mut(r * ps).enumerate() {
            for (x, row) in bi.chunks_exact_mut(ps).enumerate() {
                for (c, v) in row[..m].iter_mut().enumerate() {
                    *v = block(i, x, c);
                }
            }
        }
        let mut lp = Self {
            r,
            m,
            n,
            b,
            rows,
            w: Vec::new(),
            l0: Vec::new(),
        };
        lp.whiten();
        Some(lp)
    }

    /// The whitened single-precision blocks `w` and L0, the Cholesky factor of the
    /// pool's information matrix (with the designs' tiny ridge); a pool whose information
    /// is singular even so is scaled by its column norms instead (L0 diagonal).
    fn whiten(&mut self) {
        let (r, m) = (self.r, self.m);
        let mut info = vec![0.0; m * m];
        for i in 0..self.n {
            for c in 0..m {
                for c2 in 0..=c {
                    let v: f64 = (0..r).map(|x| self.at(i, x, c) * self.at(i, x, c2)).sum();
                    info[c * m + c2] += v;
                }
            }
        }
        let trace: f64 = (0..m).map(|c| info[c * m + c]).sum();
        let ridge = 1e-9 * trace / m.max(1) as f64;
        let (l0, li) = match Info::ridged(m, info.clone(), ridge).factor() {
            Some(f) => (f.lower().to_vec(), f.inverse_and_lower().1),
            None => {
                let (mut l0, mut li) = (vec![0.0; m * m], vec![0.0; m * m]);
                for c in 0..m {
                    let d = (info[c * m + c] + ridge).sqrt();
                    let d = if d > 0.0 && d.is_finite() { d } else { 1.0 };
                    l0[c * m + c] = d;
                    li[c * m + c] = 1.0 / d;
                }
                (l0, li)
            }
        };
        self.l0 = padded(&l0, m, self.stride());
        // C_i = B_i L0^-T: entry (x, c) = sum over k <= c of B_i(x, k) L0^-1(c, k).
        self.w = vec![0.0; self.b.len()];
        for i in 0..self.n {
            let (g, l) = (i / L, i % L);
            for c in 0..m {
                for x in 0..r {
                    let v: f64 = (0..=c).map(|k| self.at(i, x, k) * li[c * m + k]).sum();
                    self.w[((g * m + c) * r + x) * L + l] = v as f32;
                }
            }
        }
    }

    /// Entry (x, c) of candidate i's block.
    fn at(&self, i: usize, x: usize, c: usize) -> f64 {
        self.block(i)[x * self.stride() + c]
    }

    /// The row stride of the design's m-wide matrices: m rounded up to whole vectors, the
    /// padding zero, so their row operations run at the full width with no remainder.
    fn stride(&self) -> usize {
        self.m.next_multiple_of(L)
    }

    /// Candidate i's block (r x m, row-major, rows [`LanePool::stride`] apart).
    fn block(&self, i: usize) -> &[f64] {
        let t = self.r * self.stride();
        &self.rows[i * t..(i + 1) * t]
    }
}

/// Index of entry (x, y), x <= y, of an r x r symmetric matrix stored as its upper
/// triangle row by row.
pub(super) const fn upper(x: usize, y: usize, r: usize) -> usize {
    x * r - x * x.saturating_sub(1) / 2 + (y - x)
}

/// Entries of an r x r upper triangle.
pub(super) const fn upper_len(r: usize) -> usize {
    r * (r + 1) / 2
}

#[cfg(test)]
mod upper_tests {
    /// Every entry of the upper triangle has its own index, row by row, and they fill
    /// 0..upper_len(r).
    #[test]
    fn upper_triangle_indices_are_dense_and_row_major() {
        for r in [2, 3, 6] {
            let mut seen = Vec::new();
            for x in 0..r {
                for y in x..r {
                    seen.push(super::upper(x, y, r));
                }
            }
            assert_eq!(
                seen,
                (0..super::upper_len(r)).collect::<Vec<_>>(),
                "r = {r}"
            );
        }
    }
}

/// A number no design's `info_id` has had yet.
fn fresh_info_id() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static NEXT: AtomicU64 = AtomicU64::new(1);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// An m x m row-major matrix with its rows `s` apart (zero padding).
fn padded(a: &[f64], m: usize, s: usize) -> Vec<f64> {
    let mut out = vec![0.0; m * s];
    for (o, row) in out.chunks_exact_mut(s).zip(a.chunks_exact(m)) {
        o[..m].copy_from_slice(row);
    }
    out
}

/// The m x m row-major matrix of a padded one (rows `s` apart).
fn unpadded(a: &[f64], m: usize, s: usize) -> Vec<f64> {
    a.chunks_exact(s)
        .flat_map(|row| &row[..m])
        .copied()
        .collect()
}

/// Exchange state of a design over a [`LanePool`].
pub(super) struct Design<'a> {
    lp: &'a LanePool,
    pub(super) member: Vec<bool>,
    pub(super) log_det: f64,
    /// P = (M + ridge I)^-1 (m x m, row-major, symmetric; rows [`LanePool::stride`] apart).
    p: Vec<f64>,
    /// M = sum of the members' B_i^T B_i (m x m, row-major, rows [`LanePool::stride`] apart)
    /// but for the toggles in `info_pending`, which it takes when an exact determinant asks
    /// (most trial designs are dropped without one): an exact determinant costs one
    /// Cholesky, not a product over the design's rows.
    info: Vec<f64>,
    /// Which content `info` holds: a fresh number at every change, carried with every copy,
    /// so a copy from a design with the same number skips `info` (it changes only when an
    /// exact determinant or a rebuild asks, far less often than designs are copied).
    info_id: u64,
    /// Toggles (candidate, sign) made since `info` was last brought up to date.
    info_pending: Vec<(usize, f64)>,
    /// D_i = B_i P B_i^T (symmetric: its upper triangle), lane-interleaved: entry (x, y),
    /// x <= y, of candidate 8 g + l at `d[(g t + upper(x, y, r)) L + l]`, t = r (r + 1) / 2
    /// (see [`upper`]).
    d: Vec<f64>,
    /// det(I + D_i) of an outside candidate, det(I - D_i) of a member (0: not positive
    /// definite): the determinant its toggle would bring, kept by the kernels so a greedy
    /// scan reads one number per candidate.
    dets: Vec<f64>,
    /// The sign of candidate i's toggle (+1 outside, -1 member; padding 0), the kernels'
    /// per-lane sign of `dets`.
    sgn: Vec<f64>,
    /// Per group, the largest det of its outside candidates and of its members (-inf: none),
    /// kept by the passes, so a greedy scan reads one number per group.
    gmax: Vec<[f64; 2]>,
    /// Scratch of a toggle: U^T = B_a P (r x m, row-major), rows a stride apart.
    ut: Vec<f64>,
    /// U^T L0 (r x m, rows a stride apart), U = P B_a^T.
    wt: Vec<f64>,
    /// L0^T U in single precision (m x r, row-major): what the whitened blocks multiply.
    uw: Vec<f32>,
    /// D of the candidate [`Design::exact_change`] asked for (row-major r x r).
    exact: [f64; 36],
    /// The candidate whose U^T (`ut`) and D (`exact`) an exact change left from P as it is
    /// now (None once P changes): a toggle of it, the commit of a peeked step, reads them
    /// instead of forming them again.
    exact_of: Option<usize>,
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
            info_id: self.info_id,
            info_pending: self.info_pending.clone(),
            d: self.d.clone(),
            dets: self.dets.clone(),
            sgn: self.sgn.clone(),
            gmax: self.gmax.clone(),
            ut: self.ut.clone(),
            wt: self.wt.clone(),
            uw: self.uw.clone(),
            exact: self.exact,
            exact_of: self.exact_of,
            updates: self.updates,
        }
    }

    /// A copy into the buffers already held (an excursion's trial design, once per try).
    fn clone_from(&mut self, src: &Self) {
        self.copy_but_candidates(src);
        self.d.clone_from(&src.d);
        self.dets.clone_from(&src.dets);
        self.gmax.clone_from(&src.gmax);
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
        let (m, r, s) = (lp.m, lp.r, lp.stride());
        let mut d = Self {
            lp,
            member,
            log_det: 0.0,
            p: vec![0.0; m * s],
            info: Vec::new(),
            info_id: 0,
            info_pending: Vec::new(),
            d: vec![0.0; lp.n.div_ceil(L) * upper_len(r) * L],
            dets: vec![0.0; lp.n.div_ceil(L) * L],
            sgn: vec![0.0; lp.n.div_ceil(L) * L],
            gmax: vec![[f64::NEG_INFINITY; 2]; lp.n.div_ceil(L)],
            ut: vec![0.0; s * r],
            wt: vec![0.0; s * r],
            uw: vec![0.0; m * r],
            exact: [0.0; 36],
            exact_of: None,
            updates: 0,
        };
        d.rebuild(pool, ridge)?;
        Some(d)
    }

    /// Recompute P and every D_i from the member set (start, and to stop drift).
    pub(super) fn rebuild(&mut self, pool: &Pool, ridge: f64) -> Option<()> {
        let members: Vec<usize> = self.selected();
        for (s, &inside) in self.sgn.iter_mut().zip(&self.member) {
            *s = if inside { -1.0 } else { 1.0 };
        }
        let (m, s) = (self.lp.m, self.lp.stride());
        let info = pool.information(&members);
        self.info = padded(&info, m, s);
        self.info_id = fresh_info_id();
        self.info_pending.clear();
        let f = Info::ridged(m, info, ridge).factor()?;
        self.log_det = f.log_det();
        let (p, li) = f.inverse_and_lower();
        self.p = padded(&p, m, s);
        self.exact_of = None;
        // D_i = B_i P B_i^T = V_i^T V_i with V_i = L^-1 B_i^T: half the products of B P B^T.
        let li = padded(&li, m, s);
        let kernel = Kernel::Rebuild { li: &li };
        match self.lp.r {
            2 => dispatch::<2>(kernel, self),
            3 => dispatch::<3>(kernel, self),
            _ => dispatch::<6>(kernel, self),
        };
        self.updates = 0;
        Some(())
    }

    /// The change of log det that toggling candidate i (add: an outside one) brings, from its
    /// D in double precision: what [`Design::best`]'s ranking is confirmed on.
    pub(super) fn exact_change(&mut self, i: usize, add: bool) -> f64 {
        let r = self.lp.r;
        let kernel = Kernel::Exact { a: i };
        match r {
            2 => dispatch::<2>(kernel, self),
            3 => dispatch::<3>(kernel, self),
            _ => dispatch::<6>(kernel, self),
        };
        let det = pass::det_identity_plus(&self.exact[..r * r], r, if add { 1.0 } else { -1.0 });
        if det > 0.0 {
            det.ln()
        } else {
            f64::NEG_INFINITY
        }
    }

    /// The candidate whose toggle (add: an outside one, else an inside one) leaves the
    /// largest determinant, with the change of log det; nothing is changed. Ties go to the
    /// lowest index.
    pub(super) fn best(&self, add: bool) -> Option<(usize, f64)> {
        // Compare determinants, take the logarithm of the winner only: the largest of the
        // group maxima, then the first candidate of the first group that holds it.
        let (col, want) = if add { (0, 1.0) } else { (1, -1.0) };
        let det = self.gmax.iter().fold(
            f64::NEG_INFINITY,
            |a, g| if g[col] > a { g[col] } else { a },
        );
        if det == f64::NEG_INFINITY {
            return None;
        }
        let g = self.gmax.iter().position(|m| m[col] == det)?;
        let l = (0..L).find(|&l| self.sgn[g * L + l] == want && self.dets[g * L + l] == det)?;
        Some((
            g * L + l,
            if det > 0.0 {
                det.ln()
            } else {
                f64::NEG_INFINITY
            },
        ))
    }

    /// Add (sign +1) or remove (sign -1) candidate `a`: P and every D_i by Woodbury.
    pub(super) fn toggle(&mut self, a: usize, sign: f64) -> Option<()> {
        self.toggle_over(a, sign, None)
    }

    /// `src`'s information matrix, copied only when this design holds another content.
    fn info_from(&mut self, src: &Self) {
        if self.info_id != src.info_id || self.info.len() != src.info.len() {
            self.info.clone_from(&src.info);
            self.info_id = src.info_id;
        }
    }

    /// `src` with candidate `a` toggled, into this design's buffers: the pass reads `src`'s
    /// D and writes this design's D, determinants and group maxima, so they are not copied
    /// first. On None this design is left in no useful state.
    pub(super) fn toggle_from(&mut self, src: &Self, a: usize, sign: f64) -> Option<()> {
        self.copy_but_candidates(src);
        self.toggle_over(a, sign, Some(&src.d))
    }

    /// `src`'s state but the per-candidate D, determinants and group maxima (which a pass
    /// writes), into the buffers already held.
    fn copy_but_candidates(&mut self, src: &Self) {
        self.lp = src.lp;
        self.member.clone_from(&src.member);
        self.log_det = src.log_det;
        self.p.clone_from(&src.p);
        self.exact_of = None;
        self.info_from(src);
        self.info_pending.clone_from(&src.info_pending);
        self.sgn.clone_from(&src.sgn);
        self.updates = src.updates;
    }

    /// The toggle, the candidates' D read from `src_d` (another design's, whose P this
    /// design holds) or, when None, from this design's own.
    fn toggle_over(&mut self, a: usize, sign: f64, src_d: Option<&[f64]>) -> Option<()> {
        let kernel = Kernel::Update {
            a,
            sign,
            src: src_d,
        };
        let ld = match self.lp.r {
            2 => dispatch::<2>(kernel, self),
            3 => dispatch::<3>(kernel, self),
            _ => dispatch::<6>(kernel, self),
        }?;
        self.log_det += ld;
        self.info_pending.push((a, sign));
        self.updates += 1;
        Some(())
    }

    /// log det M (no ridge) of the members, with candidate `extra` added (true) or removed
    /// (false) if given; -inf when singular.
    pub(super) fn exact_log_det(&mut self, extra: Option<(usize, bool)>) -> f64 {
        let (m, r) = (self.lp.m, self.lp.r);
        if !self.info_pending.is_empty() {
            self.info_id = fresh_info_id();
            match r {
                2 => dispatch::<2>(Kernel::Info, self),
                3 => dispatch::<3>(Kernel::Info, self),
                _ => dispatch::<6>(Kernel::Info, self),
            };
        }
        let mut a = Info::ridged(m, unpadded(&self.info, m, self.lp.stride()), 0.0);
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
