//! Dense kernels of identification behind our own signatures: the R factor of a tall
//! Jacobian, the normal matrix `J^T J`, the SVD of a small square factor and QR with column
//! pivoting. nalgebra below a measured crossover size, faer (`faer` 0.24, `std` only)
//! from it on; `calibd bench kernels` measures both on the shapes identification uses and
//! prints the crossovers that the constants below hold. nalgebra stays the type of every
//! interface: faer sees nalgebra's column-major storage through views (no conversion
//! crate, no copies of the inputs).

use nalgebra::{DMatrix, DVector};

/// Which implementation a kernel uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    /// nalgebra's (unblocked) factorisations.
    Nalgebra,
    /// faer's blocked factorisations.
    Faer,
    /// nalgebra below the measured crossover, faer from it on.
    Auto,
}

impl Backend {
    /// Whether faer computes, given whether the size has reached the kernel's crossover.
    fn faer(self, past_crossover: bool) -> bool {
        match self {
            Backend::Nalgebra => false,
            Backend::Faer => true,
            Backend::Auto => past_crossover,
        }
    }
}

/// Rows from which the R factor of a tall matrix is computed by faer (blocked Householder
/// on row blocks that stay in cache, both cores from [`PARALLEL_MIN_ELEMENTS`]). Measured:
/// faer 0.94x nalgebra's time at 270 x 31, 0.21x at 540 x 31, 0.16x at 300,000 x 31.
pub const QR_FAER_MIN_ROWS: usize = 512;
/// Rows from which Levenberg-Marquardt forms `J^T J` with faer. faer is faster at every
/// measured size (0.07x at 90 x 31), but its summation order moves the iterates of an
/// ill-conditioned fit by rounding, and a fit stops within its tolerances, not at a
/// bit-identical point: below this size (above every shipped example and every dispersion
/// study) the solver keeps nalgebra's arithmetic and its results bit for bit.
pub const GRAM_FAER_MIN_ROWS: usize = 4096;
/// Columns from which the SVD of a square factor is computed by faer. Measured: faer 1.23x
/// nalgebra's time at 63 x 63, 0.22x at 127 x 127.
pub const SVD_FAER_MIN_COLS: usize = 127;
/// Columns from which QR with column pivoting (largest remaining norm first) is computed
/// by faer. Measured against our loop: 0.75x at 31 x 31, 0.47x at 63 x 63; from 64 on,
/// so that DH models (whose Norm pivoting keeps base over link-1 parameters among exact
/// duplicates by the loop's tie rule) keep the loop.
pub const PIVOTED_QR_FAER_MIN_COLS: usize = 64;
/// Elements (rows x columns) from which the tall kernels split the rows into
/// [`crate::util::parts::PARTS`] parts that the cores share.
pub const PARALLEL_MIN_ELEMENTS: usize = 1 << 20;
/// Rows of a block in the blocked reduction: a block and the running R factor stay in
/// cache while Householder reflections sweep them.
pub(crate) const BLOCK_ROWS: usize = 2048;

/// Row parts of a tall kernel over `elements` (rows x columns): one below
/// [`PARALLEL_MIN_ELEMENTS`], else [`crate::util::parts::PARTS`], however many cores there
/// are (so the sums over the parts are the same bits on one core as on all).
pub(crate) fn parts_for(elements: usize) -> usize {
    if elements < PARALLEL_MIN_ELEMENTS {
        1
    } else {
        crate::util::parts::PARTS
    }
}

/// The R factor of the QR decomposition of `j` (`min(rows, cols)` x `cols`, upper
/// triangular, rows signed as the implementation leaves them): `R^T R = J^T J`, so column
/// norms, singular values, right singular vectors and least-squares dependencies of `J`
/// are those of R.
pub fn r_factor(j: &DMatrix<f64>) -> DMatrix<f64> {
    r_factor_with(j, Backend::Auto)
}

/// [`r_factor`] with a chosen implementation.
pub fn r_factor_with(j: &DMatrix<f64>, backend: Backend) -> DMatrix<f64> {
    let faer = backend.faer(j.nrows() >= QR_FAER_MIN_ROWS);
    if !faer || j.ncols() == 0 || j.nrows() == 0 {
        return super::householder::qr_r(j);
    }
    let (n, m) = j.shape();
    let ranges = crate::util::parts::ranges(n, parts_for(n * m));
    let parts = crate::util::parts::map(ranges, &|r| reduce_rows(j, r));
    if parts.len() == 1 {
        return parts
            .into_iter()
            .next()
            .unwrap_or_else(|| DMatrix::zeros(0, m));
    }
    let rows: usize = parts.iter().map(|p| p.nrows()).sum();
    let mut stacked = DMatrix::zeros(rows, m);
    let mut at = 0;
    for p in &parts {
        stacked.rows_mut(at, p.nrows()).copy_from(p);
        at += p.nrows();
    }
    reduce_rows(&stacked, 0..rows)
}

/// The R factor of the rows `rows` of `j` by faer's blocked QR, one block of rows at a
/// time on top of the running factor (a tall-skinny QR: the same R as one factorisation,
/// in a buffer of `cols + BLOCK_ROWS` rows).
fn reduce_rows(j: &DMatrix<f64>, rows: std::ops::Range<usize>) -> DMatrix<f64> {
    let m = j.ncols();
    let mut reducer = RowReducer::new(m, BLOCK_ROWS);
    reducer.push(j.as_slice(), j.nrows(), rows);
    reducer.finish()
}

/// A running R factor of rows pushed in any pieces (faer's blocked QR of the factor so far
/// stacked on the next `block` rows): a tall matrix reduced without ever being held whole.
/// Rows are factored in blocks of `block` counted from the first row pushed, however they
/// arrive, so the factor is the one of [`r_factor`] on the same rows, bit for bit.
pub struct RowReducer {
    m: usize,
    block: usize,
    buf: faer::Mat<f64>,
    coeff: faer::Mat<f64>,
    bs_max: usize,
    mem: faer::dyn_stack::MemBuffer,
    /// Rows of R at the top of `buf`.
    have: usize,
    /// Rows waiting below them.
    pending: usize,
}

impl std::fmt::Debug for RowReducer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RowReducer")
            .field("cols", &self.m)
            .field("rows_held", &self.have)
            .field("rows_pending", &self.pending)
            .finish()
    }
}

impl RowReducer {
    /// A reducer of `m` columns factoring blocks of `block` rows.
    pub fn new(m: usize, block: usize) -> Self {
        use faer::linalg::qr::no_pivoting::factor;
        let block = block.max(m).max(1);
        let bs_max = factor::recommended_block_size::<f64>(m + block, m);
        let mem = faer::dyn_stack::MemBuffer::new(factor::qr_in_place_scratch::<f64>(
            m + block,
            m,
            bs_max,
            faer::Par::Seq,
            Default::default(),
        ));
        Self {
            m,
            block,
            buf: faer::Mat::<f64>::zeros(m + block, m),
            coeff: faer::Mat::<f64>::zeros(bs_max, m),
            bs_max,
            mem,
            have: 0,
            pending: 0,
        }
    }

    /// Append the rows `rows` of the column-major matrix `data` (`m` columns of `ld`
    /// entries each), factoring each block as it fills.
    pub fn push(&mut self, data: &[f64], ld: usize, rows: std::ops::Range<usize>) {
        let m = self.m;
        let mut start = rows.start;
        while start < rows.end {
            let len = (self.block - self.pending).min(rows.end - start);
            let at = self.have + self.pending;
            for c in 0..m {
                self.buf.col_as_slice_mut(c)[at..at + len]
                    .copy_from_slice(&data[c * ld + start..c * ld + start + len]);
            }
            self.pending += len;
            start += len;
            if self.pending == self.block {
                self.factor();
            }
        }
    }

    /// Factor R stacked on the pending rows.
    fn factor(&mut self) {
        use faer::dyn_stack::MemStack;
        use faer::linalg::qr::no_pivoting::factor;
        let m = self.m;
        let tot = self.have + self.pending;
        if self.pending == 0 || m == 0 {
            return;
        }
        let size = tot.min(m);
        let bs = factor::recommended_block_size::<f64>(tot, m).min(self.bs_max);
        factor::qr_in_place(
            self.buf.as_mut().subrows_mut(0, tot),
            self.coeff.as_mut().subrows_mut(0, bs).subcols_mut(0, size),
            faer::Par::Seq,
            MemStack::new(&mut self.mem),
            Default::default(),
        );
        // Keep R (upper triangle of the first `size` rows); clear what Q left below it.
        for c in 0..m {
            let col = self.buf.col_as_slice_mut(c);
            for v in &mut col[(c + 1).min(size)..tot] {
                *v = 0.0;
            }
        }
        self.have = size;
        self.pending = 0;
    }

    /// The factor of every row pushed (`min(rows, m)` x `m`).
    pub fn finish(&mut self) -> DMatrix<f64> {
        self.factor();
        DMatrix::from_fn(self.have, self.m, |r, c| self.buf[(r, c)])
    }
}

/// `J^T J` (the normal matrix of least squares).
pub fn gram(j: &DMatrix<f64>) -> DMatrix<f64> {
    gram_with(j, Backend::Auto)
}

/// [`gram`] with a chosen implementation (faer from [`GRAM_FAER_MIN_ROWS`] rows).
pub fn gram_with(j: &DMatrix<f64>, backend: Backend) -> DMatrix<f64> {
    let faer = backend.faer(j.nrows() >= GRAM_FAER_MIN_ROWS);
    if !faer {
        return j.tr_mul(j);
    }
    let (n, m) = j.shape();
    let ranges = crate::util::parts::ranges(n, parts_for(n * m));
    let part = |r: std::ops::Range<usize>| {
        let view = faer::MatRef::from_column_major_slice_with_stride(
            &j.as_slice()[r.start..],
            r.len(),
            m,
            n,
        );
        let mut g = faer::Mat::<f64>::zeros(m, m);
        faer::linalg::matmul::matmul(
            g.as_mut(),
            faer::Accum::Replace,
            view.transpose(),
            view,
            1.0,
            faer::Par::Seq,
        );
        g
    };
    let parts = crate::util::parts::map(ranges, &part);
    DMatrix::from_fn(m, m, |r, c| parts.iter().map(|p| p[(r, c)]).sum())
}

/// Singular values and right singular vectors of a (small, square or wide) matrix:
/// `(s, v_t)` with `v_t`'s rows the right vectors, in no particular order; `None` if the
/// iteration did not converge.
pub fn svd_right(a: &DMatrix<f64>) -> Option<(DVector<f64>, DMatrix<f64>)> {
    svd_right_with(a, Backend::Auto)
}

/// [`svd_right`] with a chosen implementation.
pub fn svd_right_with(a: &DMatrix<f64>, backend: Backend) -> Option<(DVector<f64>, DMatrix<f64>)> {
    let faer = backend.faer(a.ncols() >= SVD_FAER_MIN_COLS);
    if !faer || a.nrows() == 0 || a.ncols() == 0 {
        let svd = a.clone().svd(false, true);
        return svd.v_t.map(|vt| (svd.singular_values, vt));
    }
    let view = faer::MatRef::from_column_major_slice(a.as_slice(), a.nrows(), a.ncols());
    let svd = view.thin_svd().ok()?;
    let k = a.nrows().min(a.ncols());
    let s = DVector::from_fn(k, |i, _| svd.S()[i]);
    let v = svd.V();
    Some((s, DMatrix::from_fn(k, a.ncols(), |i, c| v[(c, i)])))
}

/// QR with column pivoting (largest remaining column norm first) of a matrix: the column
/// order and `|R_kk|` along it.
#[derive(Debug, Clone)]
pub struct PivotedQr {
    /// Columns in pivot order.
    pub order: Vec<usize>,
    /// `|R_kk|` in pivot order (length `min(rows, cols)`).
    pub r_diag: Vec<f64>,
}

/// QR with column pivoting of `a` by faer (the nalgebra-side implementation, which can stop
/// at a tolerance and follow a priority order, is `rank::rank_revealing`).
pub fn pivoted_qr_faer(a: &DMatrix<f64>) -> PivotedQr {
    let view = faer::MatRef::from_column_major_slice(a.as_slice(), a.nrows(), a.ncols());
    let qr = view.col_piv_qr();
    let (fwd, _) = qr.P().arrays();
    let r = qr.thin_R();
    let k = a.nrows().min(a.ncols());
    PivotedQr {
        order: fwd.to_vec(),
        r_diag: (0..k).map(|i| r[(i, i)].abs()).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::Rng;

    /// Random `rows` x `cols` with column scales over six decades.
    fn random(rows: usize, cols: usize, seed: u64) -> DMatrix<f64> {
        let mut rng = Rng::new(seed);
        let s: Vec<f64> = (0..cols)
            .map(|c| 10f64.powf(-3.0 + 6.0 * c as f64 / cols as f64))
            .collect();
        DMatrix::from_fn(rows, cols, |_, c| rng.normal() * s[c])
    }

    fn rel(a: f64, b: f64, scale: f64) -> f64 {
        (a - b).abs() / scale
    }

    /// The blocked, threaded faer R factor equals nalgebra's to rounding: the same
    /// `|R_kk|` (row signs may differ) and the same `R^T R`, one block, several blocks and
    /// both cores (40,000 x 31 is above the parallel threshold).
    #[test]
    fn faer_r_factor_equals_nalgebra_to_rounding() {
        for (rows, cols) in [(700, 31), (5_000, 63), (40_000, 31), (20, 31)] {
            let j = random(rows, cols, rows as u64);
            let a = r_factor_with(&j, Backend::Nalgebra);
            let b = r_factor_with(&j, Backend::Faer);
            assert_eq!(a.shape(), b.shape(), "{rows} x {cols}");
            for k in 0..a.nrows().min(cols) {
                let (x, y) = (a[(k, k)].abs(), b[(k, k)].abs());
                assert!(rel(x, y, x) < 1e-10, "{rows} x {cols} R_{k}{k}: {x} vs {y}");
            }
            let (ga, gb) = (a.tr_mul(&a), b.tr_mul(&b));
            for p in 0..cols {
                for q in 0..cols {
                    let s = (ga[(p, p)] * ga[(q, q)]).sqrt();
                    assert!(rel(ga[(p, q)], gb[(p, q)], s) < 1e-12, "{rows} x {cols}");
                }
            }
            // The factor is upper triangular.
            for c in 0..cols {
                for r in (c + 1)..b.nrows() {
                    assert_eq!(b[(r, c)], 0.0);
                }
            }
        }
    }

    /// faer's `J^T J` (split over the cores above the threshold) equals nalgebra's.
    #[test]
    fn faer_gram_equals_nalgebra_to_rounding() {
        for rows in [600, 40_000] {
            let j = random(rows, 31, 3);
            let (a, b) = (
                gram_with(&j, Backend::Nalgebra),
                gram_with(&j, Backend::Faer),
            );
            for p in 0..31 {
                for q in 0..31 {
                    let s = (a[(p, p)] * a[(q, q)]).sqrt();
                    assert!(rel(a[(p, q)], b[(p, q)], s) < 1e-13, "{rows} ({p}, {q})");
                }
            }
        }
    }

    /// `f` on a thread allowed on one core only (`available_parallelism` then says 1).
    #[cfg(target_os = "linux")]
    fn on_one_core<T: Send>(f: impl FnOnce() -> T + Send) -> T {
        std::thread::scope(|s| {
            s.spawn(|| {
                let size = std::mem::size_of::<libc::cpu_set_t>();
                // SAFETY: the sets are plain bit masks on this thread's stack, sized as the
                // calls are told; pid 0 is the calling thread.
                let ok = unsafe {
                    let mut set: libc::cpu_set_t = std::mem::zeroed();
                    assert_eq!(libc::sched_getaffinity(0, size, &mut set), 0);
                    let first = (0..libc::CPU_SETSIZE as usize)
                        .find(|&c| libc::CPU_ISSET(c, &set))
                        .expect("this thread may run on some core");
                    let mut one: libc::cpu_set_t = std::mem::zeroed();
                    libc::CPU_SET(first, &mut one);
                    libc::sched_setaffinity(0, size, &one)
                };
                assert_eq!(ok, 0, "sched_setaffinity");
                assert_eq!(
                    std::thread::available_parallelism().map(|n| n.get()).ok(),
                    Some(1)
                );
                f()
            })
            .join()
            .unwrap_or_else(|e| std::panic::resume_unwind(e))
        })
    }

    /// Above the parallel threshold the rows are split into the same parts however many
    /// cores share them, so `J^T J` and R are the same bits on one core as on all of them
    /// (with one part per core they differed in the last bits).
    #[cfg(target_os = "linux")]
    #[test]
    fn tall_kernels_give_the_same_bits_on_one_core_as_on_all() {
        let j = random(40_000, 31, 11);
        assert!(parts_for(j.len()) > 1);
        let all = (
            gram_with(&j, Backend::Faer),
            r_factor_with(&j, Backend::Faer),
        );
        let one = on_one_core(|| {
            (
                gram_with(&j, Backend::Faer),
                r_factor_with(&j, Backend::Faer),
            )
        });
        assert_eq!(all.0.as_slice(), one.0.as_slice(), "J^T J");
        assert_eq!(all.1.as_slice(), one.1.as_slice(), "R");
    }

    /// faer's SVD gives nalgebra's singular values (relative to the largest) and the same
    /// right vectors up to sign, on square factors of 31 and 90 columns.
    #[test]
    fn faer_svd_equals_nalgebra_to_rounding() {
        for m in [31, 90] {
            let a = r_factor_with(&random(3 * m, m, m as u64), Backend::Nalgebra);
            let (sa, va) = svd_right_with(&a, Backend::Nalgebra).expect("nalgebra SVD");
            let (sb, vb) = svd_right_with(&a, Backend::Faer).expect("faer SVD");
            let sort = |s: &DVector<f64>| {
                let mut o: Vec<usize> = (0..s.len()).collect();
                o.sort_by(|x, y| s[*y].total_cmp(&s[*x]));
                o
            };
            let (oa, ob) = (sort(&sa), sort(&sb));
            let smax = sa[oa[0]];
            for (&i, &k) in oa.iter().zip(&ob) {
                assert!(
                    rel(sa[i], sb[k], smax) < 1e-13,
                    "{m}: {} vs {}",
                    sa[i],
                    sb[k]
                );
                // Well-separated values: the vectors agree up to sign.
                let dot: f64 = (0..m).map(|c| va[(i, c)] * vb[(k, c)]).sum();
                assert!((dot.abs() - 1.0).abs() < 1e-6, "{m}: |v_a . v_b| = {dot}");
            }
        }
    }
}
