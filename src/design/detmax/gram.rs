//! Pools of large blocks (marker clusters: 54 rows of rank 54 against 82 parameters) kept as
//! information matrices A_i = B_i^T B_i, and their exchange state.
//!
//! When a block's rank is close to the parameter count, keeping D_i = B_i M^-1 B_i^T up to
//! date for every candidate costs more per toggle than evaluating log det(M + A_i) afresh for
//! every candidate, which the lane kernel does eight candidates at a time over the envelope
//! of the A_i; a cheap upper bound per candidate (from tr(M^-1 A_i)) skips the candidates
//! that cannot win the scan for the best addition. A design is its member set: M is summed from the members in index order, so
//! every value is a function of the set and a scan done once (on an excursion's way) is reused
//! from the memo when DETMAX comes back to the same design.

use std::collections::HashMap;

use nalgebra::DMatrix;

use super::kernels::{Info, Strided, gemm};
use super::lanes::{Envelope, LANES, Work, log_dets};

/// Information matrices of the candidates, lane-interleaved in groups of [`LANES`] (entry k
/// of candidate g * LANES + l at `data[(g * len + k) * LANES + l]`), in envelope storage.
#[derive(Debug, Clone)]
pub(super) struct GramPool {
    pub(super) env: Envelope,
    pub(super) n: usize,
    data: Vec<f64>,
    /// Each block's row count capped at m: a bound on the rank of its A_i.
    rank: Vec<usize>,
}

impl GramPool {
    /// Accumulate B_i^T B_i of each block (m columns), then lay the pool out over the envelope
    /// of their common nonzero pattern. Returns the pool, each block's row count and the sum
    /// of squares of every block entry.
    pub(super) fn build<B: std::borrow::Borrow<DMatrix<f64>>>(
        m: usize,
        blocks: impl IntoIterator<Item = B>,
    ) -> (Self, Vec<usize>, f64) {
        Self::from_products(
            m,
            blocks
                .into_iter()
                .map(|b| (b.borrow().nrows(), product(b.borrow()))),
        )
    }

    /// [`GramPool::build`] from each block's row count and B_i^T B_i (row-major m x m).
    pub(super) fn from_products<A: AsRef<[f64]>>(
        m: usize,
        products: impl IntoIterator<Item = (usize, A)>,
    ) -> (Self, Vec<usize>, f64) {
        let pk = m * (m + 1) / 2;
        let mut data: Vec<f64> = Vec::new();
        let mut rows = Vec::new();
        let mut nz = vec![false; m * m];
        let mut frobenius2 = 0.0;
        for (i, (r, a)) in products.into_iter().enumerate() {
            let a = a.as_ref();
            frobenius2 += (0..m).map(|k| a[k * m + k]).sum::<f64>();
            rows.push(r);
            if i % LANES == 0 {
                data.resize(data.len() + pk * LANES, 0.0);
            }
            let base = (i / LANES) * pk * LANES + i % LANES;
            for x in 0..m {
                for y in 0..=x {
                    let v = a[x * m + y];
                    if v != 0.0 {
                        nz[x * m + y] = true;
                        nz[y * m + x] = true;
                    }
                    data[base + (x * (x + 1) / 2 + y) * LANES] = v;
                }
            }
        }
        let env = Envelope::from_pattern(&nz, m);
        // Re-lay each group from packed lower storage (pk entries) to the envelope (len <= pk)
        // in place: group g's new range ends before its old one does.
        let mut old = vec![0.0; pk * LANES];
        let groups = rows.len().div_ceil(LANES);
        for g in 0..groups {
            old.copy_from_slice(&data[g * pk * LANES..(g + 1) * pk * LANES]);
            let new = &mut data[g * env.len * LANES..(g + 1) * env.len * LANES];
            for i in 0..m {
                for j in env.first[i]..=i {
                    let (r, c) = (
                        env.order[i].max(env.order[j]),
                        env.order[i].min(env.order[j]),
                    );
                    let (to, from) = (env.off[i] + j - env.first[i], r * (r + 1) / 2 + c);
                    new[to * LANES..(to + 1) * LANES]
                        .copy_from_slice(&old[from * LANES..(from + 1) * LANES]);
                }
            }
        }
        data.truncate(groups * env.len * LANES);
        data.shrink_to_fit();
        let n = rows.len();
        let rank = rows.iter().map(|&r| r.min(m)).collect();
        (Self { env, n, data, rank }, rows, frobenius2)
    }

    /// The lanes of group g.
    /// Copy candidate `i`'s packed block into lane `l` of `lanes` (the kernel's layout).
    fn gather(&self, lanes: &mut [f64], l: usize, i: usize) {
        let (g, li) = (i / LANES, i % LANES);
        for (d, s) in lanes
            .chunks_exact_mut(LANES)
            .zip(self.group(g).chunks_exact(LANES))
        {
            d[l] = s[li];
        }
    }

    fn group(&self, g: usize) -> &[f64] {
        let len = self.env.len * LANES;
        &self.data[g * len..(g + 1) * len]
    }

    /// M += sign A_i (envelope storage).
    fn add_to(&self, i: usize, sign: f64, mk: &mut [f64]) {
        let (g, l) = (i / LANES, i % LANES);
        for (v, a) in mk.iter_mut().zip(self.group(g).chunks_exact(LANES)) {
            *v += sign * a[l];
        }
    }

    /// The information matrix of a subset (members in index order) plus `ridge` on the
    /// diagonal, in envelope storage.
    pub(super) fn information(&self, subset: &[usize], ridge: f64) -> Vec<f64> {
        let mut mk = vec![0.0; self.env.len];
        let mut sorted = subset.to_vec();
        sorted.sort_unstable();
        for &i in &sorted {
            self.add_to(i, 1.0, &mut mk);
        }
        for i in 0..self.env.m {
            mk[self.env.off[i] + i - self.env.first[i]] += ridge;
        }
        mk
    }

    /// log det of an information matrix in envelope storage (-inf if not positive definite).
    pub(super) fn log_det_of(&self, mk: &[f64], work: &mut Work) -> f64 {
        let zero = vec![0.0; self.env.len * LANES];
        let mut out = [0.0; LANES];
        log_dets(&self.env, mk, &zero, 0.0, work, &mut out);
        out[0]
    }
}

/// B^T B (row-major m x m) of a column-major block, through matrixmultiply.
pub(super) fn product(b: &DMatrix<f64>) -> Vec<f64> {
    let (r, m, bs) = (b.nrows(), b.ncols(), b.as_slice());
    let mut a = vec![0.0; m * m];
    let op = |rs, cs| Strided { data: bs, rs, cs };
    gemm((m, r, m), 1.0, op(r, 1), op(1, r), 0.0, &mut a, m, 1);
    a
}

/// Candidates times envelope entries from which a scan for the best addition runs on two
/// cores (1,000 marker-cluster blocks against 82 parameters: 3.4 million).
pub(super) const PARALLEL_MIN_ENTRIES: usize = 1 << 20;

/// Greedy steps already taken: (design, adding) -> (candidate, log det after the step).
pub(super) type Memo = HashMap<(Vec<usize>, bool), (usize, f64)>;

/// Exchange state of a design over a [`GramPool`].
#[derive(Clone)]
pub(super) struct Design<'a> {
    pool: &'a GramPool,
    pub(super) member: Vec<bool>,
    pub(super) log_det: f64,
    ridge: f64,
    mk: Vec<f64>,
    work: Work,
    lanes: Vec<f64>,
}

impl<'a> Design<'a> {
    pub(super) fn new(pool: &'a GramPool, start: &[usize], ridge: f64) -> Option<Self> {
        let mut member = vec![false; pool.n];
        for &i in start {
            member[i] = true;
        }
        let mut d = Self {
            pool,
            member,
            log_det: 0.0,
            ridge,
            mk: Vec::new(),
            work: Work::new(&pool.env),
            lanes: vec![0.0; pool.env.len * LANES],
        };
        d.mk = pool.information(&d.selected(), ridge);
        d.log_det = pool.log_det_of(&d.mk, &mut d.work);
        d.log_det.is_finite().then_some(d)
    }

    pub(super) fn selected(&self) -> Vec<usize> {
        (0..self.member.len()).filter(|&i| self.member[i]).collect()
    }

    /// Greedy step: add the outside candidate giving the largest log det, or remove the
    /// inside one leaving the largest (the first in index order on ties); None if the
    /// step would leave the information matrix singular.
    pub(super) fn greedy(&mut self, add: bool, memo: &mut Memo) -> Option<usize> {
        let key = (self.selected(), add);
        let (best, value) = match memo.get(&key) {
            Some(&hit) => hit,
            None => {
                let found = if add {
                    self.best_add()
                } else {
                    self.best_remove()
                }?;
                memo.insert(key, found);
                found
            }
        };
        if value == f64::NEG_INFINITY {
            return None;
        }
        self.member[best] = add;
        self.mk = self.pool.information(&self.selected(), self.ridge);
        self.log_det = value;
        Some(best)
    }

    fn best_add(&mut self) -> Option<(usize, f64)> {
        if let Some(found) = self.best_add_bounded() {
            return found;
        }
        self.best_add_full()
    }

    /// [`Design::best_add`] evaluating only the candidates that can win: with t_i =
    /// tr(M^-1 A_i) and r_i >= rank A_i, log det(M + A_i) <= log det M + r_i ln(1 + t_i / r_i)
    /// (Jensen on the eigenvalues of M^-1 A_i), so candidates are evaluated by the lane
    /// kernel in order of decreasing bound until the best value found exceeds every bound
    /// left. The same values (lanes are independent) and the same winner (the first of a
    /// tie) as the full scan; None when M cannot be factored densely (then scan all).
    pub(super) fn best_add_bounded(&mut self) -> Option<Option<(usize, f64)>> {
        let pool = self.pool;
        let env = &pool.env;
        let m = env.m;
        // M (positions in envelope order) densely, its log det and inverse.
        let mut dense = vec![0.0; m * m];
        for i in 0..m {
            for j in env.first[i]..=i {
                let v = self.mk[env.off[i] + j - env.first[i]];
                dense[i * m + j] = v;
                dense[j * m + i] = v;
            }
        }
        let factor = Info { m, a: dense }.factor()?;
        let (base, inv) = (factor.log_det(), factor.inverse());
        // tr(M^-1 A) = sum over the envelope of P_ij A_ij, off-diagonal entries twice.
        let mut w = vec![0.0; env.len];
        for i in 0..m {
            for j in env.first[i]..=i {
                let f = if i == j { 1.0 } else { 2.0 };
                w[env.off[i] + j - env.first[i]] = f * inv[i * m + j];
            }
        }
        let mut bounds: Vec<(f64, usize)> = Vec::with_capacity(pool.n);
        for g in 0..pool.n.div_ceil(LANES) {
            let mut t = [0.0f64; LANES];
            for (wk, a) in w.iter().zip(pool.group(g).chunks_exact(LANES)) {
                for l in 0..LANES {
                    t[l] += wk * a[l];
                }
            }
            for (l, &tl) in t.iter().enumerate() {
                let i = g * LANES + l;
                if i < pool.n && !self.member[i] {
                    let r = pool.rank[i].max(1) as f64;
                    bounds.push((base + r * (tl.max(0.0) / r).ln_1p(), i));
                }
            }
        }
        bounds.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
        let mut best: Option<(usize, f64)> = None;
        let mut out = [0.0; LANES];
        for chunk in bounds.chunks(LANES) {
            if let Some((_, v)) = best {
                // Rounding of the kernel's values and of the bound: a relative margin.
                let margin = 1e-9 * v.abs().max(1.0);
                if chunk[0].0 + margin < v {
                    break;
                }
            }
            for (l, &(_, i)) in chunk.iter().enumerate() {
                pool.gather(&mut self.lanes, l, i);
            }
            log_dets(env, &self.mk, &self.lanes, 1.0, &mut self.work, &mut out);
            for (&(_, i), &v) in chunk.iter().zip(&out) {
                let wins = match best {
                    None => true,
                    Some((bi, bv)) => v > bv || (v == bv && i < bi),
                };
                if wins {
                    best = Some((i, v));
                }
            }
        }
        Some(best)
    }

    /// Every outside candidate evaluated (on two cores for large pools).
    pub(super) fn best_add_full(&mut self) -> Option<(usize, f64)> {
        let pool = self.pool;
        let (member, mk) = (&self.member, &self.mk);
        // The first outside candidate with the largest log det among the groups `range`.
        let scan = |range: std::ops::Range<usize>, work: &mut Work| {
            let mut best: Option<(usize, f64)> = None;
            let mut out = [0.0; LANES];
            for g in range {
                log_dets(&pool.env, mk, pool.group(g), 1.0, work, &mut out);
                for (l, &v) in out.iter().enumerate() {
                    let i = g * LANES + l;
                    if i < pool.n && !member[i] && best.is_none_or(|b| v > b.1) {
                        best = Some((i, v));
                    }
                }
            }
            best
        };
        let groups = pool.n.div_ceil(LANES);
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        if threads < 2 || groups < 2 || pool.n * pool.env.len < PARALLEL_MIN_ENTRIES {
            return scan(0..groups, &mut self.work);
        }
        // Two halves on two cores; the first half's candidate wins ties (the serial order).
        let mid = groups / 2;
        let work = &mut self.work;
        let (first, second) = std::thread::scope(|s| {
            let later = s.spawn(|| scan(mid..groups, &mut Work::new(&pool.env)));
            let first = scan(0..mid, work);
            let second = later
                .join()
                .unwrap_or_else(|e| std::panic::resume_unwind(e));
            (first, second)
        });
        match (first, second) {
            (Some(a), Some(b)) if b.1 > a.1 => Some(b),
            (Some(a), _) => Some(a),
            (None, b) => b,
        }
    }

    fn best_remove(&mut self) -> Option<(usize, f64)> {
        let pool = self.pool;
        let inside = self.selected();
        let mut best: Option<(usize, f64)> = None;
        let mut out = [0.0; LANES];
        for chunk in inside.chunks(LANES) {
            for (l, &i) in chunk.iter().enumerate() {
                pool.gather(&mut self.lanes, l, i);
            }
            log_dets(
                &pool.env,
                &self.mk,
                &self.lanes,
                -1.0,
                &mut self.work,
                &mut out,
            );
            for (&i, &v) in chunk.iter().zip(&out) {
                if best.is_none_or(|b| v > b.1) {
                    best = Some((i, v));
                }
            }
        }
        best
    }
}
