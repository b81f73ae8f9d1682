//! A tall Jacobian reduced once to its R factor (`J = Q R`: the same column norms, singular
//! values and right singular vectors), and the rows a fit plan judges effects on, so that
//! the identification pipeline factors each tall Jacobian only once.

use nalgebra::DMatrix;

/// The R factor of a tall matrix from [`super::dense::QR_FAER_MIN_ROWS`] rows on (the
/// matrix itself otherwise): the same column norms, singular values and right singular
/// vectors. Below the crossover every consumer factors the matrix it is given itself, as
/// before the faer kernels, so that small identifications keep their arithmetic exactly.
pub(crate) fn tall_r(j: &DMatrix<f64>) -> DMatrix<f64> {
    if j.nrows() > j.ncols() && j.nrows() >= super::dense::QR_FAER_MIN_ROWS {
        super::dense::r_factor(j)
    } else {
        j.clone()
    }
}

/// `r`'s columns placed at the unknowns `cols` of an `m`-column matrix (zeros elsewhere).
pub(crate) fn expand_cols(r: &DMatrix<f64>, cols: &[usize], m: usize) -> DMatrix<f64> {
    let mut out = DMatrix::zeros(r.nrows(), m);
    for (p, &k) in cols.iter().enumerate() {
        out.set_column(k, &r.column(p));
    }
    out
}

/// Largest single-residual change of `j` (columns `cols`: column p is unknown `cols[p]`)
/// for the move `w` (indexed by unknown).
fn row_effect(j: &DMatrix<f64>, cols: &[usize], w: &[f64]) -> f64 {
    let wc = nalgebra::DVector::from_fn(cols.len(), |p, _| w[cols[p]]);
    (j * wc).amax()
}

/// The Jacobian rows a plan judges effects on: blocks of rows, each with the unknown of
/// each of its columns, and the R factor of all of them stacked (for spectra).
pub(crate) struct Rows<'a> {
    pub(crate) blocks: Vec<(&'a DMatrix<f64>, Vec<usize>)>,
    pub(crate) r: DMatrix<f64>,
}

impl Rows<'_> {
    /// Largest single-residual change for the move `v` of the unknowns `free` (scaled).
    pub(crate) fn effect(&self, free: &[usize], v: &[f64], scale: &[f64]) -> f64 {
        let mut w = vec![0.0; scale.len()];
        for (&k, c) in free.iter().zip(v) {
            w[k] = scale[k] * c;
        }
        self.blocks
            .iter()
            .map(|(j, cols)| row_effect(j, cols, &w))
            .fold(0.0, f64::max)
    }
}
