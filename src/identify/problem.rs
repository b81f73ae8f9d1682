//! The `Problem` trait every identification implements, and `Restricted`, which holds some
//! unknowns fixed (the ones rank detection found unidentifiable).

use nalgebra::DMatrix;

use super::IdentifyError;

/// A nonlinear least-squares problem: minimise `|r(x)|^2`.
pub trait Problem: Sync {
    /// Number of residuals.
    fn residual_count(&self) -> usize;
    /// Number of unknowns.
    fn unknown_count(&self) -> usize;
    /// Residuals at `x` into `r` (length `residual_count`).
    fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError>;
    /// Jacobian `dr/dx` at `x` into `j` (`residual_count` x `unknown_count`). The default
    /// uses central differences with steps `1e-6 * max(1, |x_i|)`; override it with an
    /// analytic one where possible.
    fn jacobian(&self, x: &[f64], j: &mut DMatrix<f64>) -> Result<(), IdentifyError> {
        central_differences(self, x, j)
    }
    /// The Jacobian columns of the unknowns `cols` alone at `x` into `j` (column `c` is
    /// unknown `cols[c]`), the same values as those columns of [`Problem::jacobian`], when
    /// the problem computes them directly: `Ok(true)`. `Ok(false)` (the default): not
    /// supported, `j` untouched.
    fn jacobian_columns(
        &self,
        _x: &[f64],
        _cols: &[usize],
        _j: &mut DMatrix<f64>,
    ) -> Result<bool, IdentifyError> {
        Ok(false)
    }
    /// The Jacobian at `x` in row blocks, for solvers that fold each block into small
    /// accumulators instead of holding the whole matrix: the rows are split into
    /// `visitors.len()` contiguous parts of `ceil(rows / parts)` rows (the last shorter, as
    /// [`crate::util::parts::ranges`] splits them), the parts shared out among the cores
    /// ([`crate::util::parts::for_each`]), part `k` evaluated by one thread in order, in
    /// blocks of about `block_rows` rows, each handed to `visitors[k]` with its row range
    /// (columns: `cols`, or every unknown when `None`; the values of [`Problem::jacobian`]
    /// bit for bit). `Ok(false)` (the default): not supported.
    fn jacobian_blocks(
        &self,
        _x: &[f64],
        _cols: Option<&[usize]>,
        _block_rows: usize,
        _visitors: &mut [&mut (dyn FnMut(std::ops::Range<usize>, &DMatrix<f64>) + Send)],
    ) -> Result<bool, IdentifyError> {
        Ok(false)
    }
    /// This problem with only the unknowns `free` varying and the others held at `x`, in a
    /// cheaper form than [`Restricted`] (the same residuals and Jacobian to rounding), if
    /// the problem has one for that set; `None` (the default): use [`Restricted`].
    fn held(&self, _x: &[f64], _free: &[usize]) -> Option<Box<dyn Problem + '_>> {
        None
    }

    /// Trailing residual rows that only fix a gauge (no data): rank detection leaves them
    /// out, so a column duplicating others in the data stays dropped (default none).
    fn gauge_rows(&self) -> usize {
        0
    }
}

/// Central-difference Jacobian of any problem (used as default and to check analytic ones).
pub fn central_differences<P: Problem + ?Sized>(
    p: &P,
    x: &[f64],
    j: &mut DMatrix<f64>,
) -> Result<(), IdentifyError> {
    let n = p.residual_count();
    let mut xp = x.to_vec();
    let mut rp = vec![0.0; n];
    let mut rm = vec![0.0; n];
    for k in 0..x.len() {
        let h = 1e-6 * x[k].abs().max(1.0);
        xp[k] = x[k] + h;
        p.residuals(&xp, &mut rp)?;
        xp[k] = x[k] - h;
        p.residuals(&xp, &mut rm)?;
        xp[k] = x[k];
        for i in 0..n {
            j[(i, k)] = (rp[i] - rm[i]) / (2.0 * h);
        }
    }
    Ok(())
}

/// A view of a problem in which only the unknowns `free` vary; the others stay at `fixed`.
pub struct Restricted<'a> {
    inner: &'a dyn Problem,
    fixed: Vec<f64>,
    free: Vec<usize>,
    /// The inner problem's full Jacobian, kept between calls (a tall Jacobian is not
    /// allocated again on every iteration).
    full: std::sync::Mutex<DMatrix<f64>>,
}

impl std::fmt::Debug for Restricted<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Restricted")
            .field("free", &self.free)
            .finish()
    }
}

impl<'a> Restricted<'a> {
    /// Vary `free` (indices into the inner unknowns); hold the rest at `fixed`.
    pub fn new(inner: &'a dyn Problem, fixed: Vec<f64>, free: Vec<usize>) -> Self {
        Self {
            inner,
            fixed,
            free,
            full: std::sync::Mutex::new(DMatrix::zeros(0, 0)),
        }
    }

    /// The full unknown vector for a restricted one.
    pub fn expand(&self, x: &[f64]) -> Vec<f64> {
        let mut full = self.fixed.clone();
        for (k, &i) in self.free.iter().enumerate() {
            full[i] = x[k];
        }
        full
    }
}

impl Problem for Restricted<'_> {
    fn residual_count(&self) -> usize {
        self.inner.residual_count()
    }
    fn unknown_count(&self) -> usize {
        self.free.len()
    }
    fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
        self.inner.residuals(&self.expand(x), r)
    }
    fn jacobian(&self, x: &[f64], j: &mut DMatrix<f64>) -> Result<(), IdentifyError> {
        let (n, m) = (self.inner.residual_count(), self.inner.unknown_count());
        if self.free.len() == m && self.free.iter().enumerate().all(|(k, &i)| k == i) {
            // The inner problem writes straight into `j`, zeroed as a fresh matrix.
            j.as_mut_slice().fill(0.0);
            return self.inner.jacobian(&self.expand(x), j);
        }
        let x = self.expand(x);
        if self.inner.jacobian_columns(&x, &self.free, j)? {
            return Ok(());
        }
        let mut full = self
            .full
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if full.shape() == (n, m) {
            full.as_mut_slice().fill(0.0);
        } else {
            *full = DMatrix::zeros(n, m);
        }
        self.inner.jacobian(&x, &mut full)?;
        for (k, &i) in self.free.iter().enumerate() {
            j.set_column(k, &full.column(i));
        }
        Ok(())
    }
    fn jacobian_blocks(
        &self,
        x: &[f64],
        cols: Option<&[usize]>,
        block_rows: usize,
        visitors: &mut [&mut (dyn FnMut(std::ops::Range<usize>, &DMatrix<f64>) + Send)],
    ) -> Result<bool, IdentifyError> {
        let inner: Vec<usize> = match cols {
            None => self.free.clone(),
            Some(c) => c.iter().map(|&k| self.free[k]).collect(),
        };
        self.inner
            .jacobian_blocks(&self.expand(x), Some(&inner), block_rows, visitors)
    }
}
