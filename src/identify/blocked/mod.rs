//! A tall Jacobian folded block by block ([`Problem::jacobian_blocks`]) into what large
//! identifications need of it: the normal matrix `J^T J`, the gradient `J^T r`, the R
//! factor, column maxima and the largest row effects of given moves, without ever holding
//! the whole matrix (300,000 x 31 is 74 MB). The rows are split into parts the cores take
//! in turn ([`crate::util::parts`]), each folded on its own; the parts are summed (or
//! stacked and reduced) in order at the end.

use nalgebra::{DMatrix, DVector};

use super::dense::RowReducer;
use super::{IdentifyError, Problem};

/// Rows of a block: the block, the problem's staging copy of it and the row reducer's
/// buffer stay in a 1 MB second-level cache together (at 3 x 512 rows, writing the blocks
/// took 15 % of a 100,000-measurement identification; 11 % at 3 x 128).
pub(crate) const BLOCK_ROWS: usize = 3 * 128;
/// Jacobian elements (rows x unknowns) from which [`super::solve`] folds blocks instead
/// of holding the Jacobian (when the problem evaluates blocks): 4 Mi elements, 32 MB.
pub(crate) const BLOCKED_MIN_ELEMENTS: usize = 1 << 22;

/// What a fold computes.
#[derive(Default)]
pub(crate) struct Want<'a> {
    /// `J^T J`.
    pub(crate) gram: bool,
    /// The R factor of J.
    pub(crate) r_factor: bool,
    /// The largest absolute value of each column.
    pub(crate) amax: bool,
    /// `J^T r` for these residuals (all rows).
    pub(crate) residuals: Option<&'a [f64]>,
    /// The largest `|(J w)_i|` over the rows for each move `w` (one value per column).
    pub(crate) moves: &'a [DVector<f64>],
}

/// The result of a fold (the parts not wanted are empty).
#[derive(Debug, Clone)]
pub(crate) struct Folded {
    /// `J^T J` (`width` x `width`).
    pub(crate) gram: DMatrix<f64>,
    /// `J^T r`.
    pub(crate) jtr: DVector<f64>,
    /// The R factor (`min(rows, width)` x `width`).
    pub(crate) r: DMatrix<f64>,
    /// Largest absolute value per column.
    pub(crate) amax: Vec<f64>,
    /// Largest row effect per move.
    pub(crate) effects: Vec<f64>,
    /// Rows folded.
    pub(crate) rows: usize,
}

/// One part's accumulators.
struct Part {
    gram: faer::Mat<f64>,
    jtr: Vec<f64>,
    reducer: Option<RowReducer>,
    amax: Vec<f64>,
    effects: Vec<f64>,
    rows: usize,
}

impl Part {
    fn new(width: usize, want: &Want<'_>) -> Self {
        Self {
            gram: faer::Mat::zeros(if want.gram { width } else { 0 }, width),
            jtr: vec![0.0; if want.residuals.is_some() { width } else { 0 }],
            reducer: want
                .r_factor
                .then(|| RowReducer::new(width, super::dense::BLOCK_ROWS)),
            amax: vec![0.0; if want.amax { width } else { 0 }],
            effects: vec![0.0; want.moves.len()],
            rows: 0,
        }
    }

    fn add(&mut self, rows: std::ops::Range<usize>, j: &DMatrix<f64>, want: &Want<'_>) {
        let (n, m) = j.shape();
        self.rows += n;
        if n == 0 || m == 0 {
            return;
        }
        let data = j.as_slice();
        if want.gram {
            let view = faer::MatRef::from_column_major_slice(data, n, m);
            faer::linalg::matmul::matmul(
                self.gram.as_mut(),
                faer::Accum::Add,
                view.transpose(),
                view,
                1.0,
                faer::Par::Seq,
            );
        }
        if let Some(r) = want.residuals {
            let cols: Vec<&[f64]> = data.chunks_exact(n).collect();
            let mut out = vec![0.0; m];
            super::dots::dots(&cols, &r[rows], &mut out);
            for (a, v) in self.jtr.iter_mut().zip(out) {
                *a += v;
            }
        }
        if let Some(red) = &mut self.reducer {
            red.push(data, n, 0..n);
        }
        if want.amax {
            for (a, col) in self.amax.iter_mut().zip(data.chunks_exact(n)) {
                *a = col.iter().fold(*a, |x, v| x.max(v.abs()));
            }
        }
        for (e, w) in self.effects.iter_mut().zip(want.moves) {
            *e = e.max((j * w).amax());
        }
    }
}

/// Fold the Jacobian of `problem` at `x` (columns `cols`, or all; `width` of them) as
/// `want` asks, on every core. `None`: the problem has no blocked form.
pub(crate) fn fold(
    problem: &dyn Problem,
    x: &[f64],
    cols: Option<&[usize]>,
    want: &Want<'_>,
) -> Result<Option<Folded>, IdentifyError> {
    let width = cols.map_or(problem.unknown_count(), <[usize]>::len);
    // The row parts of the held path's kernels (`super::dense::r_factor`): the same R.
    let n = problem.residual_count();
    fold_in_parts(problem, x, cols, want, super::dense::parts_for(n * width))
}

/// [`fold`] with the rows in (up to) `parts` parts.
fn fold_in_parts(
    problem: &dyn Problem,
    x: &[f64],
    cols: Option<&[usize]>,
    want: &Want<'_>,
    parts: usize,
) -> Result<Option<Folded>, IdentifyError> {
    let width = cols.map_or(problem.unknown_count(), <[usize]>::len);
    let n = problem.residual_count();
    let count = crate::util::parts::ranges(n, parts).len().max(1);
    let mut parts: Vec<Part> = (0..count).map(|_| Part::new(width, want)).collect();
    let mut visits: Vec<_> = parts
        .iter_mut()
        .map(|p| move |rows: std::ops::Range<usize>, j: &DMatrix<f64>| p.add(rows, j, want))
        .collect();
    let mut visitors: Vec<&mut (dyn FnMut(std::ops::Range<usize>, &DMatrix<f64>) + Send)> = visits
        .iter_mut()
        .map(|v| v as &mut (dyn FnMut(std::ops::Range<usize>, &DMatrix<f64>) + Send))
        .collect();
    if !problem.jacobian_blocks(x, cols, BLOCK_ROWS, &mut visitors)? {
        return Ok(None);
    }
    drop(visitors);
    drop(visits);
    let mut out = Folded {
        gram: DMatrix::zeros(if want.gram { width } else { 0 }, width),
        jtr: DVector::zeros(if want.residuals.is_some() { width } else { 0 }),
        r: DMatrix::zeros(0, width),
        amax: vec![0.0; if want.amax { width } else { 0 }],
        effects: vec![0.0; want.moves.len()],
        rows: 0,
    };
    let mut stacked =
        (want.r_factor && count > 1).then(|| RowReducer::new(width, super::dense::BLOCK_ROWS));
    for p in &mut parts {
        out.rows += p.rows;
        for c in 0..p.gram.ncols() {
            for r in 0..p.gram.nrows() {
                out.gram[(r, c)] += p.gram[(r, c)];
            }
        }
        for (a, v) in out.jtr.iter_mut().zip(&p.jtr) {
            *a += v;
        }
        for (a, v) in out.amax.iter_mut().zip(&p.amax) {
            *a = a.max(*v);
        }
        for (a, v) in out.effects.iter_mut().zip(&p.effects) {
            *a = a.max(*v);
        }
        if let Some(red) = &mut p.reducer {
            let r = red.finish();
            match &mut stacked {
                Some(s) => s.push(r.as_slice(), r.nrows(), 0..r.nrows()),
                None => out.r = r,
            }
        }
    }
    if let Some(mut s) = stacked {
        out.r = s.finish();
    }
    Ok(Some(out))
}

#[cfg(test)]
mod tests;
