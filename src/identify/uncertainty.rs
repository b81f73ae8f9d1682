//! Standard deviations of identified unknowns from the residual variance and `(J^T J)^-1`,
//! and the conditioning of the scaled Jacobian.

use nalgebra::{DMatrix, DVector};
use serde::Serialize;

/// Uncertainty of a least-squares solution.
#[derive(Debug, Clone, Serialize)]
pub struct Uncertainty {
    /// Standard deviation of each unknown (internal units).
    pub std: Vec<f64>,
    /// Estimated residual standard deviation: sqrt(SSR / (n - m)).
    pub sigma: f64,
    /// Degrees of freedom n - m.
    pub dof: usize,
    /// Condition number of the column-scaled Jacobian (s_max / s_min).
    pub condition_number: f64,
    /// Singular values of the column-scaled Jacobian, largest first.
    pub singular_values: Vec<f64>,
    /// Covariance of the identified unknowns (internal units, the order of `std`): its
    /// diagonal is `std` squared; `None` when not computed or singular.
    #[serde(skip)]
    pub covariance: Option<DMatrix<f64>>,
}

/// Uncertainty at a solution with Jacobian `j` and residuals `r`.
pub fn uncertainty(j: &DMatrix<f64>, r: &DVector<f64>) -> Uncertainty {
    uncertainty_of_r(&super::reduced::tall_r(j), j.nrows(), r)
}

/// [`uncertainty`] from the R factor of the Jacobian (`J = Q R`: the same column norms,
/// singular values and right vectors) or the Jacobian itself, and its row count `n`.
pub fn uncertainty_of_r(rf: &DMatrix<f64>, n: usize, r: &DVector<f64>) -> Uncertainty {
    let m = rf.ncols();
    let dof = n.saturating_sub(m);
    let sigma = if dof > 0 {
        (r.norm_squared() / dof as f64).sqrt()
    } else {
        f64::NAN
    };
    if m == 0 {
        return Uncertainty {
            std: vec![],
            sigma,
            dof,
            condition_number: 1.0,
            singular_values: vec![],
            covariance: None,
        };
    }
    let d: Vec<f64> = (0..m)
        .map(|k| rf.column(k).norm())
        .map(|v| if v > 0.0 { v } else { 1.0 })
        .collect();
    // The column-scaled R is the R factor of the column-scaled Jacobian.
    let mut rmat = rf.clone();
    for k in 0..m {
        rmat.column_mut(k).unscale_mut(d[k]);
    }
    // nalgebra here: a tall input is below the crossover (its arithmetic as before).
    if rmat.nrows() > m {
        rmat = super::dense::r_factor_with(&rmat, super::dense::Backend::Nalgebra);
    }
    let Some((s, vt)) = super::dense::svd_right(&rmat) else {
        return Uncertainty {
            std: vec![f64::NAN; m],
            sigma,
            dof,
            condition_number: f64::INFINITY,
            singular_values: vec![],
            covariance: None,
        };
    };
    let mut order: Vec<usize> = (0..s.len()).collect();
    order.sort_by(|a, b| s[*b].total_cmp(&s[*a]));
    let smax = s[order[0]];
    let smin = s[order[s.len() - 1]];
    let std = (0..m)
        .map(|k| {
            let var: f64 = (0..s.len())
                .map(|i| {
                    if s[i] > 0.0 {
                        (vt[(i, k)] / s[i]).powi(2)
                    } else {
                        f64::INFINITY
                    }
                })
                .sum();
            sigma * var.sqrt() / d[k]
        })
        .collect();
    // sigma^2 V S^-2 V^T, unscaled by the column norms.
    let covariance = s.iter().all(|v| *v > 0.0).then(|| {
        DMatrix::from_fn(m, m, |k, l| {
            let sum: f64 = (0..s.len())
                .map(|i| vt[(i, k)] * vt[(i, l)] / (s[i] * s[i]))
                .sum();
            sigma * sigma * sum / (d[k] * d[l])
        })
    });
    Uncertainty {
        std,
        covariance,
        sigma,
        dof,
        condition_number: if smin > 0.0 {
            smax / smin
        } else {
            f64::INFINITY
        },
        singular_values: order.iter().map(|&i| s[i]).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Straight-line fit y = a + b x: textbook standard errors.
    #[test]
    fn line_fit_standard_errors_match_the_closed_form() {
        let xs = [0.0, 1.0, 2.0, 3.0, 4.0];
        let res = [0.1, -0.2, 0.05, 0.15, -0.1];
        let j = DMatrix::from_fn(5, 2, |i, k| if k == 0 { 1.0 } else { xs[i] });
        let r = DVector::from_row_slice(&res);
        let u = uncertainty(&j, &r);
        let s2 = res.iter().map(|v| v * v).sum::<f64>() / 3.0;
        let sxx: f64 = xs.iter().map(|x| (x - 2.0f64).powi(2)).sum();
        let sb = (s2 / sxx).sqrt();
        let sa = (s2 * (1.0 / 5.0 + 4.0 / sxx)).sqrt();
        assert!(
            (u.std[0] - sa).abs() < 1e-12 && (u.std[1] - sb).abs() < 1e-12,
            "{:?} vs {sa} {sb}",
            u.std
        );
        // The covariance of a and b: -s2 mean(x) / sxx.
        let c = u.covariance.expect("covariance");
        assert!((c[(0, 1)] + s2 * 2.0 / sxx).abs() < 1e-12, "{c}");
        assert!((c[(0, 0)] - sa * sa).abs() < 1e-12);
    }
}
