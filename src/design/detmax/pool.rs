//! The candidate pool of a D-optimal design: one Jacobian block per configuration, each
//! reduced to its rank so the exchange updates work on the smallest equivalent block.
//!
//! A block B_i enters the design only through B_i^T B_i. A posture seen by marker clusters
//! has 3 rows per marker but at most 6 independent rows per rigid cluster (54 rows, rank 18
//! for three clusters of six markers): replacing B_i by C_i = R_k Π^T from a column-pivoted
//! QR (B_i Π = Q R, k the numerical rank) keeps C_i^T C_i = B_i^T B_i and every determinant,
//! while the rank-k updates cost (k/r)^2 to (k/r)^3 of the full ones. Blocks whose rank is
//! close to the parameter count (marker clusters with their marker parameters) are kept as
//! information matrices instead (`gram`): evaluating each candidate afresh is then cheaper
//! than updating every candidate's D_i.

use std::borrow::Borrow;

use nalgebra::DMatrix;

use super::gram::GramPool;
use super::kernels::{Factor, Info, Strided, gemm};
use super::narrow::LanePool;

/// Blocks with at most this many rows are kept as they are (serial designs: 3 rows per
/// configuration, already full rank); larger ones are reduced to their rank.
const KEEP_ROWS: usize = 6;

/// Relative size of R's diagonal below which a direction carries no information.
const RANK_TOL: f64 = 1e-12;

/// True when blocks of `rows` rows against `m` parameters are better kept as information
/// matrices: a fresh Cholesky per candidate (m^3 / 6) against the update of every candidate's
/// D_i per toggle (rows^2 (m + rows)).
fn prefers_gram(rows: usize, m: usize) -> bool {
    rows > KEEP_ROWS && 6 * rows * rows * (m + rows) > m * m * m
}

/// The candidate configurations: one (reduced) Jacobian block per configuration.
#[derive(Debug, Clone)]
pub struct Pool {
    pub(super) m: usize,
    /// Rows of each (reduced) block; for pools kept as information matrices, each block's
    /// row count capped at the parameter count.
    pub(super) rows: Vec<usize>,
    /// The information matrices, for pools of large blocks (then `stacked` is empty).
    pub(super) gram: Option<GramPool>,
    /// Sum of squares of every block entry.
    frobenius2: f64,
    /// All blocks stacked, column-major (rows x m), for the matrix products of the updates.
    pub(super) stacked: DMatrix<f64>,
    /// First row of each block in `stacked`.
    pub(super) row0: Vec<usize>,
    /// The blocks lane-interleaved, for uniform pools of 2, 3 or 6 rows (fused updates).
    pub(super) lanes: Option<LanePool>,
}

impl Pool {
    /// A pool from per-configuration blocks (all with the same column count, taken one at a
    /// time so a caller need not hold them all); blocks of more than six rows are reduced to
    /// their rank (same information matrix, fewer rows), or, when their rank would stay close
    /// to the parameter count, kept as information matrices.
    pub fn from_blocks<B: Borrow<DMatrix<f64>>>(blocks: impl IntoIterator<Item = B>) -> Self {
        let mut it = blocks.into_iter().peekable();
        let (rows, m) = it
            .peek()
            .map_or((0, 0), |b| (b.borrow().nrows(), b.borrow().ncols()));
        if prefers_gram(rows, m) {
            return Self::gram(m, it);
        }
        Self::thin(it)
    }

    /// [`Pool::from_blocks`] over `n` configurations whose blocks `block(i)` computes, on
    /// every core: blocks are made and reduced (or multiplied out to B^T B) in parallel
    /// batches, so that only one batch of full blocks is held at a time. The pool is the
    /// one `from_blocks` builds from the same blocks, bit for bit.
    pub fn from_block_fn<F>(n: usize, block: F) -> Self
    where
        F: Fn(usize) -> DMatrix<f64> + Sync,
    {
        let Some(first) = (n > 0).then(|| block(0)) else {
            return Self::exact(&[]);
        };
        let (rows, m) = (first.nrows(), first.ncols());
        if prefers_gram(rows, m) {
            let make = |i: usize| {
                let b = if i == 0 { first.clone() } else { block(i) };
                (b.nrows(), super::gram::product(&b))
            };
            let (gram, rows, frobenius2) = GramPool::from_products(m, batches(n, &make));
            return Self::with_gram(m, gram, rows, frobenius2);
        }
        let make = |i: usize| {
            let b = if i == 0 { first.clone() } else { block(i) };
            if b.nrows() > KEEP_ROWS { reduce(&b) } else { b }
        };
        let reduced: Vec<DMatrix<f64>> = batches(n, &make).collect();
        Self::exact(&reduced)
    }

    /// A pool of (rank-reduced) blocks whatever their size.
    pub(super) fn thin<B: Borrow<DMatrix<f64>>>(blocks: impl IntoIterator<Item = B>) -> Self {
        let reduced: Vec<DMatrix<f64>> = blocks
            .into_iter()
            .map(|b| {
                let b = b.borrow();
                if b.nrows() > KEEP_ROWS {
                    reduce(b)
                } else {
                    b.clone()
                }
            })
            .collect();
        Self::exact(&reduced)
    }

    /// A pool kept as information matrices (blocks with `m` columns).
    pub(super) fn gram<B: Borrow<DMatrix<f64>>>(
        m: usize,
        blocks: impl IntoIterator<Item = B>,
    ) -> Self {
        let (gram, rows, frobenius2) = GramPool::build(m, blocks);
        Self::with_gram(m, gram, rows, frobenius2)
    }

    fn with_gram(m: usize, gram: GramPool, rows: Vec<usize>, frobenius2: f64) -> Self {
        Self {
            m,
            rows: rows.into_iter().map(|r| r.min(m)).collect(),
            gram: Some(gram),
            frobenius2,
            stacked: DMatrix::zeros(0, m),
            row0: Vec::new(),
            lanes: None,
        }
    }

    /// A pool holding the blocks exactly as given (the reference the reduced pool is tested
    /// against).
    pub fn exact(blocks: &[DMatrix<f64>]) -> Self {
        let m = blocks.first().map_or(0, |b| b.ncols());
        let rows: Vec<usize> = blocks.iter().map(|b| b.nrows()).collect();
        let mut row0 = Vec::with_capacity(blocks.len());
        let mut total = 0;
        for r in &rows {
            row0.push(total);
            total += r;
        }
        let mut stacked = DMatrix::zeros(total, m);
        for (b, &r) in blocks.iter().zip(&row0) {
            stacked.rows_mut(r, b.nrows()).copy_from(b);
        }
        let uniform = match rows.first() {
            Some(&r) if rows.iter().all(|&x| x == r) => Some(r),
            _ => None,
        };
        let lanes = uniform
            .and_then(|r| LanePool::new(rows.len(), r, m, |i, x, c| stacked[(row0[i] + x, c)]));
        Self {
            m,
            rows,
            gram: None,
            frobenius2: stacked.iter().map(|v| v * v).sum(),
            stacked,
            row0,
            lanes,
        }
    }

    /// A pool from a stacked matrix with `rows` rows per configuration.
    pub fn from_stacked(j: &DMatrix<f64>, rows: usize) -> Self {
        let blocks: Vec<DMatrix<f64>> = (0..j.nrows() / rows.max(1))
            .map(|i| j.rows(i * rows, rows).clone_owned())
            .collect();
        Self::from_blocks(&blocks)
    }

    /// Number of configurations.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// True if empty.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// Number of parameters (columns).
    pub fn params(&self) -> usize {
        self.m
    }

    /// Rows of configuration `i`'s block after reduction (its rank for large blocks).
    pub fn block_rows(&self, i: usize) -> usize {
        self.rows[i]
    }

    /// Configuration `i`'s block (rows x m).
    pub(super) fn block(&self, i: usize) -> nalgebra::DMatrixView<'_, f64> {
        self.stacked.rows(self.row0[i], self.rows[i])
    }

    /// log det of the information matrix of a subset (or -inf if singular).
    pub fn log_det(&self, subset: &[usize]) -> f64 {
        if let Some(g) = &self.gram {
            let mk = g.information(subset, 0.0);
            return g.log_det_of(&mk, &mut super::lanes::Work::new(&g.env));
        }
        self.information_factor(subset, 0.0)
            .map_or(f64::NEG_INFINITY, |f| f.log_det())
    }

    /// The stacked (reduced) blocks of a subset; None for a pool kept as information
    /// matrices.
    pub fn stacked(&self, subset: &[usize]) -> Option<DMatrix<f64>> {
        self.gram.is_none().then(|| self.stacked_rows(subset))
    }

    fn stacked_rows(&self, subset: &[usize]) -> DMatrix<f64> {
        let rows: usize = subset.iter().map(|&i| self.rows[i]).sum();
        let mut out = DMatrix::zeros(rows, self.m);
        let mut r0 = 0;
        for &i in subset {
            let r = self.rows[i];
            out.rows_mut(r0, r).copy_from(&self.block(i));
            r0 += r;
        }
        out
    }

    /// Cholesky factor of the information matrix of `members` plus `ridge` I (thin pools);
    /// None when it is not positive definite.
    pub(super) fn information_factor(&self, members: &[usize], ridge: f64) -> Option<Factor> {
        Info::ridged(self.m, self.information(members), ridge).factor()
    }

    /// The information matrix (row-major m x m) of a subset of a thin pool: the subset's
    /// rows gathered column by column, then one product (no per-block products).
    pub(super) fn information(&self, subset: &[usize]) -> Vec<f64> {
        let (m, rows) = (self.m, self.stacked.nrows());
        let all = self.stacked.as_slice();
        let total: usize = subset.iter().map(|&i| self.rows[i]).sum();
        let mut j = vec![0.0; total * m];
        for (c, col) in j.chunks_exact_mut(total.max(1)).enumerate().take(m) {
            let mut o = 0;
            for &i in subset {
                let (r, s) = (self.rows[i], c * rows + self.row0[i]);
                col[o..o + r].copy_from_slice(&all[s..s + r]);
                o += r;
            }
        }
        let mut a = vec![0.0; m * m];
        let jt = Strided {
            data: &j,
            rs: total,
            cs: 1,
        };
        let jj = Strided {
            data: &j,
            rs: 1,
            cs: total,
        };
        gemm((m, total, m), 1.0, jt, jj, 0.0, &mut a, m, 1);
        a
    }

    /// Sum of squares of every entry (the scale of the start's ridge).
    pub(super) fn frobenius2(&self) -> f64 {
        self.frobenius2
    }
}

/// Configurations per parallel batch of [`Pool::from_block_fn`].
const BATCH: usize = 64;

/// `f(0..n)` in order, computed in batches of [`BATCH`] split over the cores.
fn batches<'a, T: Send + 'a>(
    n: usize,
    f: &'a (dyn Fn(usize) -> T + Sync),
) -> impl Iterator<Item = T> + 'a {
    let threads = std::thread::available_parallelism().map_or(1, |t| t.get());
    (0..n.div_ceil(BATCH)).flat_map(move |b| {
        let range = b * BATCH..((b + 1) * BATCH).min(n);
        let chunk = range.len().div_ceil(threads).max(1);
        let starts: Vec<usize> = range.clone().step_by(chunk).collect();
        let parts: Vec<Vec<T>> = std::thread::scope(|s| {
            let handles: Vec<_> = starts
                .iter()
                .skip(1)
                .map(|&a| {
                    let end = (a + chunk).min(range.end);
                    s.spawn(move || (a..end).map(f).collect::<Vec<T>>())
                })
                .collect();
            let a = range.start;
            let mut parts = vec![(a..(a + chunk).min(range.end)).map(f).collect::<Vec<T>>()];
            parts.extend(
                handles
                    .into_iter()
                    .map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e))),
            );
            parts
        });
        parts.into_iter().flatten()
    })
}

/// C with C^T C = B^T B and as many rows as B has rank: the leading rows of R from a
/// column-pivoted QR of B, with the columns put back in order.
fn reduce(b: &DMatrix<f64>) -> DMatrix<f64> {
    let (_, r, p) = b.clone().col_piv_qr().unpack();
    let diag: Vec<f64> = (0..r.nrows().min(r.ncols()))
        .map(|j| r[(j, j)].abs())
        .collect();
    let top = diag.iter().copied().fold(0.0f64, f64::max);
    let k = diag.iter().take_while(|&&v| v > RANK_TOL * top).count();
    let mut c = r.rows(0, k).clone_owned();
    p.inv_permute_columns(&mut c);
    c
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::Rng;

    /// The parallel, batched builder gives the pool the sequential one gives, bit for bit,
    /// for blocks kept as information matrices (54 x 30, more than one batch) and for
    /// rank-reduced ones (9 x 40 of rank 6).
    #[test]
    fn block_fn_pool_equals_the_sequential_pool() {
        let mut rng = Rng::new(8);
        let big: Vec<DMatrix<f64>> = (0..150)
            .map(|_| DMatrix::from_fn(54, 30, |_, _| rng.normal()))
            .collect();
        let low: Vec<DMatrix<f64>> = (0..70)
            .map(|_| {
                let b = DMatrix::from_fn(6, 40, |_, _| rng.normal());
                DMatrix::from_fn(9, 6, |_, _| rng.normal()) * b
            })
            .collect();
        for blocks in [&big, &low] {
            let a = Pool::from_blocks(blocks.iter());
            let b = Pool::from_block_fn(blocks.len(), |i| blocks[i].clone());
            assert_eq!(a.gram.is_some(), blocks[0].nrows() == 54);
            assert_eq!(a.rows, b.rows);
            assert_eq!(a.frobenius2.to_bits(), b.frobenius2.to_bits());
            for subset in [vec![0, 3, 7, 9, 12, 40, 65], (0..blocks.len()).collect()] {
                let (x, y) = (a.log_det(&subset), b.log_det(&subset));
                assert!(x.is_finite());
                assert_eq!(x.to_bits(), y.to_bits(), "{x} vs {y}");
            }
        }
        assert_eq!(Pool::from_block_fn(0, |_| DMatrix::zeros(3, 4)).len(), 0);
    }

    /// A 54 x 20 block of rank 9 (three rigid 3-row groups repeated six times, as marker
    /// clusters) reduces to 9 rows with the same information matrix.
    #[test]
    fn reduction_keeps_the_information_matrix_and_finds_the_rank() {
        let mut rng = Rng::new(3);
        let base = DMatrix::from_fn(9, 20, |_, _| rng.normal());
        let mix = DMatrix::from_fn(54, 9, |_, _| rng.normal());
        let b = &mix * &base;
        let c = reduce(&b);
        assert_eq!(c.nrows(), 9);
        let (bb, cc) = (b.tr_mul(&b), c.tr_mul(&c));
        let err = (&bb - &cc).abs().max() / bb.abs().max();
        assert!(err < 1e-12, "relative difference {err:e}");
        // A full-rank block keeps all its rows' worth of information.
        let full = DMatrix::from_fn(12, 20, |_, _| rng.normal());
        let c = reduce(&full);
        assert_eq!(c.nrows(), 12);
        let err = (full.tr_mul(&full) - c.tr_mul(&c)).abs().max();
        assert!(err < 1e-10, "{err:e}");
        // An all-zero block carries nothing.
        assert_eq!(reduce(&DMatrix::zeros(9, 4)).nrows(), 0);
    }
}
