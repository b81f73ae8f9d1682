//! A tall Jacobian reduced once to its R factor (`J = Q R`: the same column norms, singular
//! values and right singular vectors), and the rows a fit plan judges effects on, so that
//! the identification pipeline factors each tall Jacobian only once.

use nalgebra::{DMatrix, DVector};

use super::blocked::{Want, fold};
use super::{IdentifyError, Problem};

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
    (j * move_of(cols, w)).amax()
}

/// The move `w` (indexed by unknown) on the columns `cols`.
fn move_of(cols: &[usize], w: &[f64]) -> DVector<f64> {
    DVector::from_fn(cols.len(), |p, _| w[cols[p]])
}

/// A block of Jacobian rows: held, or folded from its problem on demand (too tall to hold).
#[derive(Clone, Copy)]
pub(crate) enum Src<'a> {
    /// The rows themselves.
    Dense(&'a DMatrix<f64>),
    /// The Jacobian of `problem` at `x` (its columns those of the block), evaluated again in
    /// blocks when a row effect is wanted; `r` its R factor, `rows` its row count.
    Blocked {
        problem: &'a dyn Problem,
        x: &'a [f64],
        r: &'a DMatrix<f64>,
        rows: usize,
    },
}

impl Src<'_> {
    /// A matrix with the block's column dots (the rows, or their R factor) and the rows'
    /// count.
    pub(crate) fn dots_source(&self) -> (&DMatrix<f64>, usize) {
        match self {
            Src::Dense(j) => (j, j.nrows()),
            Src::Blocked { r, rows, .. } => (r, *rows),
        }
    }
}

/// The Jacobian rows a plan judges effects on: blocks of rows, each with the unknown of
/// each of its columns, and the R factor of all of them stacked (for spectra).
pub(crate) struct Rows<'a> {
    pub(crate) blocks: Vec<(Src<'a>, Vec<usize>)>,
    pub(crate) r: DMatrix<f64>,
}

impl Rows<'_> {
    /// Largest single-residual change for each move `vs[i]` of the unknowns `free`
    /// (scaled); a folded block is evaluated once for all of them.
    pub(crate) fn effects(
        &self,
        free: &[usize],
        vs: &[&[f64]],
        scale: &[f64],
    ) -> Result<Vec<f64>, IdentifyError> {
        let ws: Vec<Vec<f64>> = vs
            .iter()
            .map(|v| {
                let mut w = vec![0.0; scale.len()];
                for (&k, c) in free.iter().zip(v.iter()) {
                    w[k] = scale[k] * c;
                }
                w
            })
            .collect();
        let mut out = vec![0.0f64; vs.len()];
        // Last block first: the latest rows were evaluated last, so a problem's memos of
        // that point still hold (the maxima do not depend on the order).
        for (src, cols) in self.blocks.iter().rev() {
            match src {
                Src::Dense(j) => {
                    for (o, w) in out.iter_mut().zip(&ws) {
                        *o = o.max(row_effect(j, cols, w));
                    }
                }
                Src::Blocked { problem, x, .. } => {
                    let moves: Vec<DVector<f64>> = ws.iter().map(|w| move_of(cols, w)).collect();
                    let want = Want {
                        moves: &moves,
                        ..Want::default()
                    };
                    let f = fold(*problem, x, Some(cols), &want)?.ok_or_else(|| {
                        IdentifyError::Model("the Jacobian has no blocked form".into())
                    })?;
                    for (o, e) in out.iter_mut().zip(f.effects) {
                        *o = o.max(e);
                    }
                }
            }
        }
        Ok(out)
    }
}
