//! Levenberg-Marquardt on the normal equations of a Jacobian folded block by block
//! ([`super::blocked`]), for problems too tall to hold their Jacobian: the steps of
//! [`super::lm`] (Moré's column scaling, damping, bounds, stopping rules) from `J^T J` and
//! `J^T r`, plus a stop once the scaled step is negligible against the scaled unknowns.

use nalgebra::{DMatrix, DVector};

use super::blocked::{Folded, Want, fold};
use super::lm::{bound_state, project, trial};
use super::{IdentifyError, LmOptions, LmReport, Problem, StopReason};
use crate::util::Monitor;

/// Scaled step, relative to the scaled unknowns, below which an accepted iterate has
/// converged. Near the solution each step shrinks the next by about a hundred (100,000
/// twin measurements: 2e-3, 3e-4, 9e-5, 2e-5, 1e-6, 3e-8, 3e-10); stopping at 1e-7 moved
/// the final cost by more than 1e-9 relative on 3,000 measurements. After a step below
/// 1e-9 the next would move the unknowns by about 1e-11 of their size, far inside the 1e-9
/// the folded result keeps to the dense one (`blocked::tests`), and one Jacobian fold fewer.
pub(crate) const STEP_RTOL: f64 = 1e-9;

/// The outcome of [`levenberg_marquardt_blocked`]: the report (with an empty Jacobian),
/// and what the callers need of the final Jacobian.
#[derive(Debug, Clone)]
pub(crate) struct BlockedReport {
    /// The run, `jacobian` 0 x 0.
    pub(crate) rep: LmReport,
    /// R factor of the Jacobian at the solution.
    pub(crate) r: DMatrix<f64>,
    /// Largest absolute value of each column of that Jacobian.
    pub(crate) amax: Vec<f64>,
}

/// The residuals at `x0` and the fold of the Jacobian there (`J^T J` and `J^T r`), when
/// the caller has them.
#[derive(Debug, Clone)]
pub(crate) struct BlockedStart {
    pub(crate) residuals: DVector<f64>,
    pub(crate) gram: DMatrix<f64>,
    pub(crate) jtr: DVector<f64>,
}

/// `J^T J` and `J^T r` at `x`; None without a blocked form.
fn normal(
    problem: &dyn Problem,
    x: &[f64],
    r: &DVector<f64>,
) -> Result<Option<(DMatrix<f64>, DVector<f64>)>, IdentifyError> {
    let want = Want {
        gram: true,
        residuals: Some(r.as_slice()),
        ..Want::default()
    };
    Ok(fold(problem, x, None, &want)?.map(|f| (f.gram, f.jtr)))
}

/// Column norms from the diagonal of `J^T J`.
fn column_norms(gram: &DMatrix<f64>) -> Vec<f64> {
    (0..gram.ncols())
        .map(|k| gram[(k, k)].max(0.0).sqrt())
        .collect()
}

/// Minimise `|r(x)|^2` from `x0` with the Jacobian folded in blocks; `Ok(None)` when the
/// problem has no blocked form (the caller uses [`super::levenberg_marquardt_from`]).
pub(crate) fn levenberg_marquardt_blocked(
    problem: &dyn Problem,
    x0: &[f64],
    start: Option<BlockedStart>,
    opts: &LmOptions,
    monitor: &dyn Monitor,
) -> Result<Option<BlockedReport>, IdentifyError> {
    let (n, m) = (problem.residual_count(), problem.unknown_count());
    if n < m {
        return Err(IdentifyError::Underdetermined {
            residuals: n,
            unknowns: m,
        });
    }
    let mut x = x0.to_vec();
    project(&mut x, opts);
    let start = start.filter(|s| {
        x.iter().zip(x0).all(|(a, b)| a.to_bits() == b.to_bits())
            && s.residuals.len() == n
            && s.gram.shape() == (m, m)
            && s.jtr.len() == m
    });
    let (mut r, mut gram, mut g) = match start {
        Some(s) => (s.residuals, s.gram, s.jtr),
        None => {
            let mut r = DVector::zeros(n);
            problem.residuals(&x, r.as_mut_slice())?;
            if let Some(index) = r.iter().position(|v| !v.is_finite()) {
                return Err(IdentifyError::NonFinite { index });
            }
            let Some((gram, g)) = normal(problem, &x, &r)? else {
                return Ok(None);
            };
            (r, gram, g)
        }
    };
    if let Some(index) = r.iter().position(|v| !v.is_finite()) {
        return Err(IdentifyError::NonFinite { index });
    }
    let mut cost = r.norm_squared();
    let initial_cost = cost;
    let mut norms = column_norms(&gram);
    let mut d: Vec<f64> = norms
        .iter()
        .map(|&v| if v > 0.0 { v } else { 1.0 })
        .collect();
    let mut mu = 0.0;
    let mut nu = 2.0;
    let mut stop = StopReason::MaxIterations;
    let mut iterations = 0;
    let mut r_new = DVector::zeros(n);
    while iterations < opts.max_iterations {
        if monitor.is_cancelled() {
            return Err(IdentifyError::Cancelled);
        }
        iterations += 1;
        monitor.progress(
            iterations as f64 / opts.max_iterations as f64,
            "levenberg-marquardt",
        );
        if cost <= f64::MIN_POSITIVE * 1e10 {
            stop = StopReason::ZeroResidual;
            break;
        }
        let bounds = bound_state(&x, opts);
        let free: Vec<usize> = (0..m)
            .filter(|&k| !((bounds[k] < 0 && g[k] > 0.0) || (bounds[k] > 0 && g[k] < 0.0)))
            .collect();
        let rn = cost.sqrt();
        let gmax = free
            .iter()
            .map(|&k| g[k].abs() / (norms[k].max(f64::MIN_POSITIVE) * rn))
            .fold(0.0, f64::max);
        if gmax <= opts.gtol {
            stop = StopReason::SmallGradient;
            break;
        }
        let mf = free.len();
        let a = DMatrix::from_fn(mf, mf, |p, q| {
            gram[(free[p], free[q])] / (d[free[p]] * d[free[q]])
        });
        let gs = DVector::from_fn(mf, |p, _| g[free[p]] / d[free[p]]);
        if mu == 0.0 {
            mu = opts.initial_damping * (0..mf).map(|k| a[(k, k)]).fold(0.0, f64::max);
        }
        let xnorm = free
            .iter()
            .map(|&k| (d[k] * x[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        loop {
            let Some(step) = super::bounds::bounded_step(&a, &gs, &x, &free, &d, mu, opts) else {
                mu *= nu;
                nu *= 2.0;
                if !mu.is_finite() || mu > 1e300 {
                    stop = StopReason::NoFurtherProgress;
                    break;
                }
                continue;
            };
            let mut xn: Vec<f64> = (0..m).map(|k| x[k] + step[k]).collect();
            project(&mut xn, opts);
            let step = DVector::from_fn(m, |k, _| xn[k] - x[k]);
            let step_norm = free
                .iter()
                .map(|&k| (d[k] * step[k]).powi(2))
                .sum::<f64>()
                .sqrt();
            // The linear model's reduction |r|^2 - |r + J s|^2 = -(2 s.J^T r + s^T J^T J s).
            let predicted = -(2.0 * step.dot(&g) + step.dot(&(&gram * &step)));
            let (cost_new, rho) = trial(problem, &xn, &mut r_new, cost, predicted);
            if rho > 0.0 && cost_new < cost {
                let reduction = (cost - cost_new) / cost;
                x = xn;
                std::mem::swap(&mut r, &mut r_new);
                cost = cost_new;
                if reduction <= opts.ftol {
                    stop = StopReason::SmallCostReduction;
                } else if step_norm <= opts.xtol * (xnorm + opts.xtol)
                    || step_norm <= STEP_RTOL * xnorm
                {
                    stop = StopReason::SmallStep;
                }
                if stop != StopReason::MaxIterations {
                    // Converged: the final fold below is the only pass still needed at x.
                    break;
                }
                let Some((gn, g_new)) = normal(problem, &x, &r)? else {
                    return Ok(None);
                };
                (gram, g) = (gn, g_new);
                norms = column_norms(&gram);
                for k in 0..m {
                    d[k] = d[k].max(norms[k]);
                }
                mu *= super::lm::damping_decrease(rho, opts.nearly_linear);
                nu = 2.0;
                break;
            }
            if step_norm <= opts.xtol * (xnorm + opts.xtol) {
                stop = StopReason::SmallStep;
                break;
            }
            if opts.nearly_linear && super::lm::at_minimum(predicted, cost_new, cost, opts.ftol) {
                // As the held fit: the last correction, below the cost's rounding, is taken.
                if super::lm::takes_last_correction(predicted, cost_new, cost) {
                    x = xn;
                    std::mem::swap(&mut r, &mut r_new);
                    cost = cost_new;
                }
                stop = StopReason::SmallCostReduction;
                break;
            }
            mu *= nu;
            nu *= 2.0;
            if !mu.is_finite() || mu > 1e300 {
                stop = StopReason::NoFurtherProgress;
                break;
            }
        }
        if stop != StopReason::MaxIterations {
            break;
        }
    }
    let want = Want {
        r_factor: true,
        amax: true,
        ..Want::default()
    };
    let Some(Folded { r: rf, amax, .. }) = fold(problem, &x, None, &want)? else {
        return Ok(None);
    };
    let at_bound = bound_state(&x, opts);
    Ok(Some(BlockedReport {
        rep: LmReport {
            x,
            residuals: r,
            jacobian: DMatrix::zeros(0, 0),
            initial_cost,
            cost,
            iterations,
            stop,
            at_bound,
        },
        r: rf,
        amax,
    }))
}
