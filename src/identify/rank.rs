//! Rank detection by QR with column pivoting on the column-scaled Jacobian. Columns whose
//! remaining norm falls below a tolerance are structurally unidentifiable with the data:
//! they are reported (with the combination of kept columns they duplicate) and held fixed.

use nalgebra::{DMatrix, DVector};

/// Which column the QR takes next.
#[derive(Debug, Clone, PartialEq)]
pub enum Pivoting {
    /// The column with the largest remaining norm (classic Businger-Golub pivoting).
    Norm,
    /// Columns in this priority order (indices); a column is kept if it adds a direction
    /// not spanned by the columns kept before it.
    Priority(Vec<usize>),
}

/// Result of rank detection.
#[derive(Debug, Clone)]
pub struct RankReport {
    /// Numerical rank.
    pub rank: usize,
    /// Kept (identifiable) columns, in pivot order.
    pub kept: Vec<usize>,
    /// Dropped (unidentifiable) columns.
    pub dropped: Vec<usize>,
    /// |R_kk| of each kept column, in pivot order (columns scaled to unit norm, or by
    /// their physical scales relative to the largest scaled column).
    pub r_diag: Vec<f64>,
    /// For each dropped column, its expression as a combination of kept columns
    /// (unscaled: dropped = sum coef * kept), largest coefficients first.
    pub dependencies: Vec<Vec<(usize, f64)>>,
    /// The relative tolerance used.
    pub tolerance: f64,
}

/// Rank-revealing QR of `j` (rows x columns) with columns scaled to unit norm; a column is
/// dependent when its remaining norm is below `tol` (relative to 1). Unit norms make a
/// column of rounding noise look independent: prefer [`rank_revealing_scaled`] where the
/// unknowns have physical scales.
pub fn rank_revealing(j: &DMatrix<f64>, pivoting: &Pivoting, tol: f64) -> RankReport {
    pivoted_qr(j, None, pivoting, tol)
}

/// Rank-revealing QR of `j * diag(scale)`, `scale` being each unknown's physical scale (a
/// typical magnitude of its error): a column is dependent when its remaining norm is below
/// `tol` times the largest scaled column norm. A column whose whole effect is rounding
/// noise stays as small as it is instead of being blown up to unit norm.
pub fn rank_revealing_scaled(
    j: &DMatrix<f64>,
    scale: &[f64],
    pivoting: &Pivoting,
    tol: f64,
) -> RankReport {
    pivoted_qr(j, Some(scale), pivoting, tol)
}

fn pivoted_qr(
    j: &DMatrix<f64>,
    scale: Option<&[f64]>,
    pivoting: &Pivoting,
    tol: f64,
) -> RankReport {
    pivoted_qr_with(j, scale, pivoting, tol, true)
}

/// [`rank_revealing`] by our own loop at every size (no faer above the crossover), for the
/// kernel benchmark.
pub fn rank_revealing_loop(j: &DMatrix<f64>, pivoting: &Pivoting, tol: f64) -> RankReport {
    pivoted_qr_with(j, None, pivoting, tol, false)
}

/// [`pivoted_qr`]; `allow_faer` false keeps our own loop at every size (for tests).
fn pivoted_qr_with(
    j: &DMatrix<f64>,
    scale: Option<&[f64]>,
    pivoting: &Pivoting,
    tol: f64,
    allow_faer: bool,
) -> RankReport {
    // A tall matrix is first reduced to its R factor: Q is orthogonal, so column norms, the
    // pivoted QR and least-squares dependencies are the same, at a fraction of the cost.
    let reduced;
    let j = if j.nrows() > j.ncols() {
        reduced = super::dense::r_factor(j);
        &reduced
    } else {
        j
    };
    let (n, m) = j.shape();
    let norms: Vec<f64> = (0..m).map(|k| j.column(k).norm()).collect();
    // Column factors: 1 / norm (unit columns), or scale / largest scaled norm.
    let factor: Vec<f64> = match scale {
        None => norms
            .iter()
            .map(|&v| if v > 0.0 { 1.0 / v } else { 0.0 })
            .collect(),
        Some(s) => {
            let sc = |k: usize| s.get(k).copied().unwrap_or(1.0);
            let big = (0..m).map(|k| norms[k] * sc(k)).fold(0.0, f64::max);
            (0..m)
                .map(|k| if big > 0.0 { sc(k) / big } else { 0.0 })
                .collect()
        }
    };
    let mut a = j.clone();
    for (k, f) in factor.iter().enumerate() {
        a.column_mut(k).scale_mut(*f);
    }
    if allow_faer && *pivoting == Pivoting::Norm && m >= super::dense::PIVOTED_QR_FAER_MIN_COLS {
        return faer_pivoted(j, &a, &norms, tol);
    }
    let order: Vec<usize> = match pivoting {
        Pivoting::Norm => (0..m).collect(),
        Pivoting::Priority(p) => p.clone(),
    };
    let mut remaining: Vec<usize> = order.iter().copied().filter(|&k| norms[k] > 0.0).collect();
    let mut dropped: Vec<usize> = order.iter().copied().filter(|&k| norms[k] == 0.0).collect();
    let mut kept = Vec::new();
    let mut r_diag = Vec::new();
    let mut row = 0;
    let tail_norm = |a: &DMatrix<f64>, k: usize, row: usize| a.view((row, k), (n - row, 1)).norm();
    while !remaining.is_empty() && row < n {
        let pick = match pivoting {
            Pivoting::Norm => {
                let (pos, best) = remaining
                    .iter()
                    .enumerate()
                    .map(|(p, &k)| (p, tail_norm(&a, k, row)))
                    .fold((0, -1.0), |acc, v| if v.1 > acc.1 { v } else { acc });
                if best < tol {
                    break;
                }
                pos
            }
            Pivoting::Priority(_) => {
                let k = remaining[0];
                if tail_norm(&a, k, row) < tol {
                    dropped.push(remaining.remove(0));
                    continue;
                }
                0
            }
        };
        let k = remaining.remove(pick);
        // Householder reflection of column k's tail, applied to every remaining column.
        let x = a.view((row, k), (n - row, 1)).clone_owned();
        let alpha = -x[0].signum() * x.norm();
        let mut v: DVector<f64> = DVector::from_iterator(n - row, x.iter().copied());
        v[0] -= alpha;
        let vn2 = v.norm_squared();
        if vn2 > 0.0 {
            for &c in remaining.iter().chain(std::iter::once(&k)) {
                let dot: f64 = (0..n - row).map(|i| v[i] * a[(row + i, c)]).sum();
                let s = 2.0 * dot / vn2;
                for i in 0..n - row {
                    a[(row + i, c)] -= s * v[i];
                }
            }
        }
        r_diag.push(alpha.abs());
        kept.push(k);
        row += 1;
    }
    dropped.extend(remaining);
    let dependencies = dropped.iter().map(|&c| dependency(j, &kept, c)).collect();
    RankReport {
        rank: kept.len(),
        kept,
        dropped,
        r_diag,
        dependencies,
        tolerance: tol,
    }
}

/// Norm pivoting by faer's QR with column pivoting of the scaled matrix `a` (from
/// [`super::dense::PIVOTED_QR_FAER_MIN_COLS`] columns): the columns before the first
/// `|R_kk| < tol` are kept, as the loop of [`pivoted_qr`] keeps them.
fn faer_pivoted(j: &DMatrix<f64>, a: &DMatrix<f64>, norms: &[f64], tol: f64) -> RankReport {
    let qr = super::dense::pivoted_qr_faer(a);
    let rank = qr
        .r_diag
        .iter()
        .zip(&qr.order)
        .position(|(&r, &k)| !(r >= tol && norms[k] > 0.0))
        .unwrap_or(qr.r_diag.len());
    let kept = qr.order[..rank].to_vec();
    let mut dropped: Vec<usize> = qr.order[rank..].to_vec();
    dropped.sort_unstable();
    let dependencies = dropped.iter().map(|&c| dependency(j, &kept, c)).collect();
    RankReport {
        rank,
        kept,
        dropped,
        r_diag: qr.r_diag[..rank].to_vec(),
        dependencies,
        tolerance: tol,
    }
}

/// Least-squares expression of column `c` of `j` in the kept columns, coefficients sorted
/// by decreasing magnitude and truncated to the significant ones.
pub(crate) fn dependency(j: &DMatrix<f64>, kept: &[usize], c: usize) -> Vec<(usize, f64)> {
    if kept.is_empty() {
        return Vec::new();
    }
    let mut a = DMatrix::zeros(j.nrows(), kept.len());
    for (p, &k) in kept.iter().enumerate() {
        a.set_column(p, &j.column(k));
    }
    let b = j.column(c).clone_owned();
    let Some(svd) = nalgebra::linalg::SVD::try_new(a, true, true, 1e-14, 0) else {
        return Vec::new();
    };
    let Ok(coef) = svd.solve(&b, 1e-12) else {
        return Vec::new();
    };
    let mut out: Vec<(usize, f64)> = kept.iter().copied().zip(coef.iter().copied()).collect();
    let big = out.iter().map(|v| v.1.abs()).fold(0.0, f64::max);
    out.retain(|v| v.1.abs() > 1e-6 * big.max(f64::MIN_POSITIVE));
    out.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_dependent_column_and_its_combination() {
        // Column 2 = 2 * col0 - col1: rank 2 of 3.
        let j = DMatrix::from_row_slice(
            4,
            3,
            &[1.0, 0.0, 2.0, 0.0, 1.0, -1.0, 1.0, 1.0, 1.0, 2.0, 0.5, 3.5],
        );
        let r = rank_revealing(&j, &Pivoting::Norm, 1e-10);
        assert_eq!(r.rank, 2);
        assert_eq!(r.dropped.len(), 1);
        // With priority 0, 1, 2 the last one is the dependent one, = 2 c0 - c1.
        let r = rank_revealing(&j, &Pivoting::Priority(vec![0, 1, 2]), 1e-10);
        assert_eq!(r.dropped, vec![2]);
        let dep = &r.dependencies[0];
        let c0 = dep.iter().find(|d| d.0 == 0).unwrap().1;
        let c1 = dep.iter().find(|d| d.0 == 1).unwrap().1;
        assert!(
            (c0 - 2.0).abs() < 1e-12 && (c1 + 1.0).abs() < 1e-12,
            "{dep:?}"
        );
        // Priority 2, 0, 1 keeps 2 and 0 and drops 1.
        let r = rank_revealing(&j, &Pivoting::Priority(vec![2, 0, 1]), 1e-10);
        assert_eq!(r.dropped, vec![1]);
    }

    /// Above the crossover, faer's pivoted QR makes the rank decisions of our loop: the
    /// same kept and dropped columns, the same |R_kk| to rounding, the same dependencies.
    #[test]
    fn faer_pivoted_qr_decides_as_the_loop() {
        let mut rng = crate::util::Rng::new(4);
        let (rows, m) = (400, 150);
        let mut j = DMatrix::from_fn(rows, m, |_, c| {
            rng.normal() * 10f64.powf(-2.0 + 4.0 * c as f64 / m as f64)
        });
        // Columns 20, 75 and 149 depend on others; column 60 is zero.
        for (c, a, b) in [(20, 3, 4), (75, 10, 140), (149, 0, 1)] {
            let v = j.column(a) * 0.5 - j.column(b) * 2.0;
            j.set_column(c, &v);
        }
        j.column_mut(60).fill(0.0);
        for scale in [None, Some(vec![1.0; m])] {
            let s = scale.as_deref();
            let ours = pivoted_qr_with(&j, s, &Pivoting::Norm, 1e-8, false);
            let faer = pivoted_qr_with(&j, s, &Pivoting::Norm, 1e-8, true);
            assert_eq!(ours.rank, m - 4);
            assert_eq!(faer.rank, ours.rank);
            let mut dropped = ours.dropped.clone();
            dropped.sort_unstable();
            assert_eq!(faer.dropped, dropped);
            assert_eq!(faer.kept, ours.kept);
            for (a, b) in ours.r_diag.iter().zip(&faer.r_diag) {
                assert!((a - b).abs() <= 1e-10 * a, "{a} vs {b}");
            }
            for (c, dep) in faer.dropped.iter().zip(&faer.dependencies) {
                let p = ours.dropped.iter().position(|d| d == c).expect("dropped");
                assert_eq!(dep.len(), ours.dependencies[p].len(), "column {c}");
            }
        }
    }

    #[test]
    fn full_rank_keeps_everything() {
        let j = DMatrix::from_row_slice(3, 2, &[1.0, 0.0, 0.0, 1e-6, 0.0, 0.0]);
        let r = rank_revealing(&j, &Pivoting::Norm, 1e-10);
        // Scaling makes the tiny column as good as the big one.
        assert_eq!(r.rank, 2);
    }

    #[test]
    fn physical_scaling_keeps_a_rounding_noise_column_small() {
        // Column 1 is rounding noise (1e-17): unit scaling keeps it, physical scaling drops it;
        // a genuinely small but real column (1e-4) stays.
        let j = DMatrix::from_row_slice(
            4,
            3,
            &[
                1.0, 1e-17, 0.0, 0.5, -2e-17, 1e-4, 0.2, 1e-17, 0.0, 1.0, 3e-17, -1e-4,
            ],
        );
        assert_eq!(rank_revealing(&j, &Pivoting::Norm, 1e-8).rank, 3);
        let r = rank_revealing_scaled(&j, &[1.0, 1.0, 1.0], &Pivoting::Norm, 1e-8);
        assert_eq!((r.rank, r.dropped.clone()), (2, vec![1]));
        let r = rank_revealing_scaled(
            &j,
            &[1.0, 1.0, 1.0],
            &Pivoting::Priority(vec![1, 0, 2]),
            1e-8,
        );
        assert_eq!(r.dropped, vec![1]);
    }
}
