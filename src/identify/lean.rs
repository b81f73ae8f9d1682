//! The values-only shortcut of a fit plan ([`super::SolveOptions::near_dependent`] false):
//! a plan holds a combination only when the smallest singular value of the physically
//! scaled Jacobian of its free unknowns is below the floor, so a cheap certificate that it
//! is clearly above (a Cholesky factorisation of the scaled normal matrix shifted by twice
//! the floor squared and its rounding bound) makes the QR and SVD of the stacked rows unnecessary. Where the certificate
//! fails, the plan computes the spectrum as before (the same decision either way).

use nalgebra::DMatrix;

use super::reduced::Rows;

/// Whether the smallest singular value of `[blocks][:, free] * diag(scale)` is certainly
/// above `floor` (at least `sqrt(2) floor`): `G - shift I` is positive definite, with `G`
/// the scaled normal matrix summed over the blocks and `shift = 2 floor^2 + 2 e`, where `e`
/// bounds the rounding of `G` and of its factorisation (`(rows + 2 m^2) eps trace(G)`).
/// `false` means "not certain", never "below".
pub(crate) fn clearly_above(rows: &Rows<'_>, free: &[usize], scale: &[f64], floor: f64) -> bool {
    let m = free.len();
    if m == 0 || !(floor.is_finite() && floor > 0.0) {
        return false;
    }
    let mut g = DMatrix::<f64>::zeros(m, m);
    let mut length = 0;
    for (src, cols) in &rows.blocks {
        // A folded block's R factor has its column dots (`R^T R = J^T J`).
        let (j, count) = src.dots_source();
        length += count;
        // Column of the block holding each free unknown (none: a zero column).
        let at: Vec<Option<usize>> = free
            .iter()
            .map(|k| cols.iter().position(|c| c == k))
            .collect();
        // The dots of each column with those before it at once (each as nalgebra's `dot`).
        let n = j.nrows();
        let column = |c: usize| &j.as_slice()[c * n..(c + 1) * n];
        let mut others: Vec<&[f64]> = Vec::with_capacity(m);
        let mut at_p: Vec<usize> = Vec::with_capacity(m);
        let mut d = vec![0.0; m];
        for q in 0..m {
            let Some(cq) = at[q] else { continue };
            others.clear();
            at_p.clear();
            for p in 0..=q {
                if let Some(cp) = at[p] {
                    others.push(column(cp));
                    at_p.push(p);
                }
            }
            super::dots::dots(&others, column(cq), &mut d[..others.len()]);
            for (&p, &v) in at_p.iter().zip(&d) {
                g[(p, q)] += v * scale[free[p]] * scale[free[q]];
            }
        }
    }
    let trace: f64 = (0..m).map(|p| g[(p, p)]).sum();
    let rounding = (length + 2 * m * m) as f64 * 1.2e-16 * trace;
    let shift = 2.0 * floor * floor + 2.0 * rounding;
    if !shift.is_finite() {
        return false;
    }
    for q in 0..m {
        for p in 0..q {
            g[(q, p)] = g[(p, q)];
        }
        g[(q, q)] -= shift;
    }
    g.cholesky().is_some()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Columns (1, 1, 0) and (1, 1, s): the smallest singular value is about `s / sqrt(2)`
    /// (scaled by 1); certain above a floor below it by more than sqrt(2), never above one
    /// closer or over it.
    #[test]
    fn certifies_only_a_clear_margin() {
        let s = 1e-3;
        let j = DMatrix::from_row_slice(3, 2, &[1.0, 1.0, 1.0, 1.0, 0.0, s]);
        let smin = crate::identify::trust::spectrum(&j, &[0, 1], &[1.0, 1.0]).smallest[0].0;
        let rows = Rows {
            blocks: vec![(crate::identify::reduced::Src::Dense(&j), vec![0, 1])],
            r: j.clone(),
        };
        assert!(clearly_above(&rows, &[0, 1], &[1.0, 1.0], smin / 3.0));
        assert!(!clearly_above(&rows, &[0, 1], &[1.0, 1.0], smin / 1.2));
        assert!(!clearly_above(&rows, &[0, 1], &[1.0, 1.0], smin * 1.01));
        // One column alone: its norm sqrt(2) is the singular value.
        assert!(clearly_above(&rows, &[0], &[1.0, 1.0], 0.9));
        assert!(!clearly_above(&rows, &[0], &[1.0, 1.0], 1.01));
    }
}
