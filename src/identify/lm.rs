//! Levenberg-Marquardt on the full nonlinear model, with column scaling (Moré's diagonal),
//! box bounds by projection with an active set, a stated stopping reason, and cancellation.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::{IdentifyError, Problem};
use crate::util::Monitor;

/// Settings of the solver; the defaults suit calibration problems.
#[derive(Debug, Clone)]
pub struct LmOptions {
    /// Maximum number of iterations (Jacobian evaluations).
    pub max_iterations: usize,
    /// Stop when the relative reduction of the cost in an accepted step is below this.
    pub ftol: f64,
    /// Stop when the scaled step is below `xtol` times the scaled parameter norm.
    pub xtol: f64,
    /// Stop when the largest cosine between the residual and a Jacobian column is below this.
    pub gtol: f64,
    /// Lower bounds (same length as x), if any.
    pub lower: Option<Vec<f64>>,
    /// Upper bounds, if any.
    pub upper: Option<Vec<f64>>,
    /// Initial damping relative to the largest diagonal of the scaled normal matrix (Nielsen's
    /// tau): 1e-3 for a start far from the solution; a start known to be close (a previous
    /// identification step) can take a much smaller value and skip the damping's slow decay
    /// (at most a factor 3 per iteration) on ill-conditioned problems.
    pub initial_damping: f64,
    /// The problem is nearly linear from its start (a calibration from its nominal model):
    /// a well predicted step cuts the damping a hundredfold ([`damping_decrease`]) and a
    /// last correction below the cost's rounding is taken ([`at_minimum`]). Off, the
    /// damping follows Nielsen's rule alone: on strongly nonlinear fits (a humanoid's
    /// whole body: 17 iterations against 15) the fast cut costs more than it saves.
    pub nearly_linear: bool,
}

impl Default for LmOptions {
    fn default() -> Self {
        Self {
            max_iterations: 200,
            ftol: 1e-12,
            xtol: 1e-12,
            gtol: 1e-10,
            lower: None,
            upper: None,
            initial_damping: 1e-3,
            nearly_linear: false,
        }
    }
}

/// Why the solver stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StopReason {
    /// Converged: the relative cost reduction fell below `ftol`.
    SmallCostReduction,
    /// Converged: the step fell below `xtol`.
    SmallStep,
    /// Converged: the gradient is orthogonal to the residual within `gtol`.
    SmallGradient,
    /// Converged: the residual is zero to machine precision.
    ZeroResidual,
    /// No step reduces the cost any more (damping exhausted): at a minimum to precision.
    NoFurtherProgress,
    /// The iteration limit was reached before convergence.
    MaxIterations,
}

impl StopReason {
    /// True for the reasons that mean convergence.
    pub fn converged(self) -> bool {
        !matches!(self, StopReason::MaxIterations)
    }
}

/// Outcome of a run.
#[derive(Debug, Clone)]
pub struct LmReport {
    /// Final unknowns.
    pub x: Vec<f64>,
    /// Final residuals.
    pub residuals: DVector<f64>,
    /// Jacobian at the final unknowns.
    pub jacobian: DMatrix<f64>,
    /// Sum of squared residuals at the start.
    pub initial_cost: f64,
    /// Sum of squared residuals at the end.
    pub cost: f64,
    /// Iterations performed.
    pub iterations: usize,
    /// Why it stopped.
    pub stop: StopReason,
    /// Per unknown: -1 at its lower bound, +1 at its upper bound, 0 inside.
    pub at_bound: Vec<i8>,
}

pub(super) fn project(x: &mut [f64], o: &LmOptions) {
    for (i, v) in x.iter_mut().enumerate() {
        if let Some(l) = &o.lower {
            *v = v.max(l[i]);
        }
        if let Some(u) = &o.upper {
            *v = v.min(u[i]);
        }
    }
}

pub(super) fn bound_state(x: &[f64], o: &LmOptions) -> Vec<i8> {
    (0..x.len())
        .map(|i| {
            if o.lower.as_ref().is_some_and(|l| x[i] <= l[i]) {
                -1
            } else if o.upper.as_ref().is_some_and(|u| x[i] >= u[i]) {
                1
            } else {
                0
            }
        })
        .collect()
}

/// The factor on the damping after an accepted step of gain ratio `rho`: a step the linear
/// model predicted well (rho > 0.9) cuts it a hundredfold, so a nearly linear problem (a
/// calibration from its nominal model) turns into Gauss-Newton within two steps and
/// converges quadratically; otherwise Nielsen's rule, max(1/3, 1 - (2 rho - 1)^3). With
/// Nielsen's rule alone the damping falls by 3 per step and holds back the weakly
/// determined directions: the ball-centring fits of a dispersion study converged linearly
/// (each step ~10x shorter) in 8 Jacobians instead of 5.
pub(super) fn damping_decrease(rho: f64, nearly_linear: bool) -> f64 {
    if nearly_linear && rho > 0.9 {
        0.01
    } else {
        (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0)
    }
}

/// A relative change of the cost below rounding (a sum of squares of a few thousand terms).
const ROUNDING_COST: f64 = 1e-13;

/// MINPACK's test on a rejected step: neither the linear model nor the trial lowers the
/// cost by more than `ftol` (relative), so the cost is at its minimum to rounding and more
/// damping would only shorten a step that cannot help.
pub(super) fn at_minimum(predicted: f64, cost_new: f64, cost: f64, ftol: f64) -> bool {
    predicted <= ftol * cost && (cost_new - cost).abs() <= ftol * cost
}

/// Whether a step rejected at the minimum ([`at_minimum`]) is still taken: the linear model
/// predicts a gain and the cost stayed where it was to rounding.
pub(super) fn takes_last_correction(predicted: f64, cost_new: f64, cost: f64) -> bool {
    predicted > 0.0 && cost_new <= cost * (1.0 + ROUNDING_COST)
}

/// The scaled normal matrix and gradient of the columns `free`: `D^-1 J^T J D^-1` and
/// `D^-1 J^T r`. From [`super::dense::GRAM_FAER_MIN_ROWS`] rows on they come from `J^T J`
/// (faer, no scaled copy of the tall Jacobian); below it from the scaled copy, as before
/// the faer kernels (the same arithmetic, step for step).
fn scaled_normal(
    j: &DMatrix<f64>,
    r: &DVector<f64>,
    g: &DVector<f64>,
    free: &[usize],
    d: &[f64],
) -> (DMatrix<f64>, DVector<f64>) {
    let mf = free.len();
    if j.nrows() >= super::dense::GRAM_FAER_MIN_ROWS {
        let jtj = super::dense::gram(j);
        let a = DMatrix::from_fn(mf, mf, |p, q| {
            jtj[(free[p], free[q])] / (d[free[p]] * d[free[q]])
        });
        return (a, DVector::from_fn(mf, |p, _| g[free[p]] / d[free[p]]));
    }
    let n = j.nrows();
    let mut js = DMatrix::zeros(n, mf);
    scaled_columns(j.as_slice(), js.as_mut_slice(), n, free, d);
    // `js^T js` entry by entry as nalgebra's `tr_mul` forms it (the same dot of two
    // columns, see `super::dots`), one triangle computed and mirrored: a dot product is
    // symmetric bit for bit.
    let cols: Vec<&[f64]> = js.as_slice().chunks_exact(n.max(1)).take(mf).collect();
    let mut a = DMatrix::zeros(mf, mf);
    let mut column = vec![0.0; mf];
    for q in 0..mf {
        super::dots::dots(&cols[..=q], cols[q], &mut column[..=q]);
        for (p, &v) in column[..=q].iter().enumerate() {
            a[(p, q)] = v;
            a[(q, p)] = v;
        }
    }
    (a, tr_mul(&js, r))
}

/// Column c of `dst` = column `free[c]` of `src` divided by `d[free[c]]` (both n rows,
/// column-major): IEEE divisions, four at a time where the CPU has AVX2.
fn scaled_columns(src: &[f64], dst: &mut [f64], n: usize, free: &[usize], d: &[f64]) {
    #[inline(always)]
    fn body(src: &[f64], dst: &mut [f64], n: usize, free: &[usize], d: &[f64]) {
        for (c, &k) in free.iter().enumerate() {
            let dk = d[k];
            for (o, v) in dst[c * n..(c + 1) * n]
                .iter_mut()
                .zip(&src[k * n..(k + 1) * n])
            {
                *o = v / dk;
            }
        }
    }
    /// # Safety
    /// The CPU must have AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn avx2(src: &[f64], dst: &mut [f64], n: usize, free: &[usize], d: &[f64]) {
        body(src, dst, n, free, d)
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2.
        return unsafe { avx2(src, dst, n, free, d) };
    }
    body(src, dst, n, free, d)
}

/// Evaluate the trial point `xn` of a step whose linear model predicts the cost reduction
/// `predicted`: its cost (infinite when the model fails or is not finite there) and the gain
/// ratio. A step the linear model does not even predict to help is not evaluated.
pub(super) fn trial<P: Problem + ?Sized>(
    problem: &P,
    xn: &[f64],
    r_new: &mut DVector<f64>,
    cost: f64,
    predicted: f64,
) -> (f64, f64) {
    if predicted <= 0.0 {
        return (f64::INFINITY, -1.0);
    }
    let eval = problem.residuals(xn, r_new.as_mut_slice());
    let cost_new = if eval.is_ok() && r_new.iter().all(|v| v.is_finite()) {
        super::dots::norm_squared(r_new.as_slice())
    } else {
        f64::INFINITY
    };
    (cost_new, (cost - cost_new) / predicted)
}

/// `j^T r` as nalgebra's `tr_mul` forms it (one dot per column).
fn tr_mul(j: &DMatrix<f64>, r: &DVector<f64>) -> DVector<f64> {
    let n = j.nrows();
    let mut out = DVector::zeros(j.ncols());
    if n == 0 {
        return out;
    }
    let cols: Vec<&[f64]> = j.as_slice().chunks_exact(n).collect();
    super::dots::dots(&cols, r.as_slice(), out.as_mut_slice());
    out
}

/// Residuals and Jacobian of a problem already evaluated at the start point (as the caller
/// of [`levenberg_marquardt_from`] has them from its own analysis of the start).
#[derive(Debug, Clone)]
pub struct LmStart {
    /// Residuals at `x0`.
    pub residuals: DVector<f64>,
    /// Jacobian at `x0` (`residual_count` x `unknown_count`).
    pub jacobian: DMatrix<f64>,
}

/// Minimise `|r(x)|^2` from `x0` (projected into the bounds).
pub fn levenberg_marquardt(
    problem: &dyn Problem,
    x0: &[f64],
    opts: &LmOptions,
    monitor: &dyn Monitor,
) -> Result<LmReport, IdentifyError> {
    levenberg_marquardt_from(problem, x0, None, opts, monitor)
}

/// [`levenberg_marquardt`] given the residuals and Jacobian at `x0`: they replace the first
/// evaluations when `x0` is inside the bounds and their shapes fit (the same iterates as
/// evaluating them again).
pub fn levenberg_marquardt_from(
    problem: &dyn Problem,
    x0: &[f64],
    start: Option<LmStart>,
    opts: &LmOptions,
    monitor: &dyn Monitor,
) -> Result<LmReport, IdentifyError> {
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
            && s.jacobian.shape() == (n, m)
    });
    let (mut r, mut j) = match start {
        Some(s) => (s.residuals, s.jacobian),
        None => {
            let mut r = DVector::zeros(n);
            problem.residuals(&x, r.as_mut_slice())?;
            if r.iter().all(|v| v.is_finite()) {
                let mut j = DMatrix::zeros(n, m);
                problem.jacobian(&x, &mut j)?;
                (r, j)
            } else {
                (r, DMatrix::zeros(0, 0))
            }
        }
    };
    if let Some(index) = r.iter().position(|v| !v.is_finite()) {
        return Err(IdentifyError::NonFinite { index });
    }
    let mut cost = super::dots::norm_squared(r.as_slice());
    let initial_cost = cost;
    // The Jacobian's column norms, formed once per Jacobian (the gradient test and the
    // scaling both read them), each nalgebra's `norm` bit for bit.
    let column_norms = |j: &DMatrix<f64>| -> Vec<f64> {
        (0..m)
            .map(|k| super::dots::norm_squared(&j.as_slice()[k * n..(k + 1) * n]).sqrt())
            .collect()
    };
    let mut norms = column_norms(&j);
    // Moré's scaling: the largest column norm seen so far.
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
        let g = tr_mul(&j, &r);
        // Active set: unknowns on a bound whose descent direction points outwards.
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
        let (a, gs) = scaled_normal(&j, &r, &g, &free, &d);
        if mu == 0.0 {
            mu = opts.initial_damping * (0..free.len()).map(|k| a[(k, k)]).fold(0.0, f64::max);
        }
        let xnorm = free
            .iter()
            .map(|&k| (d[k] * x[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        // Inner loop: raise the damping until a step is accepted.
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
            let step: Vec<f64> = (0..m).map(|k| xn[k] - x[k]).collect();
            let step_norm = free
                .iter()
                .map(|&k| (d[k] * step[k]).powi(2))
                .sum::<f64>()
                .sqrt();
            // Predicted cost from the linear model with the (bounded) step.
            // |r|^2 - |r + J s|^2 = -(2 s.g + |J s|^2): without |r|^2 in the difference,
            // a step below the cost's rounding still has its reduction resolved.
            let js = &j * DVector::from_vec(step.clone());
            let predicted = if opts.nearly_linear {
                let sg: f64 = step.iter().zip(g.iter()).map(|(a, b)| a * b).sum();
                -(2.0 * sg + super::dots::norm_squared(js.as_slice()))
            } else {
                cost - super::dots::norm_squared((&r + js).as_slice())
            };
            // A step the linear model does not even predict to help is not worth a model
            // evaluation.
            let (cost_new, rho) = trial(problem, &xn, &mut r_new, cost, predicted);
            if rho > 0.0 && cost_new < cost {
                let reduction = (cost - cost_new) / cost;
                x = xn;
                std::mem::swap(&mut r, &mut r_new);
                cost = cost_new;
                problem.jacobian(&x, &mut j)?;
                norms = column_norms(&j);
                for k in 0..m {
                    d[k] = d[k].max(norms[k]);
                }
                mu *= damping_decrease(rho, opts.nearly_linear);
                nu = 2.0;
                if reduction <= opts.ftol {
                    stop = StopReason::SmallCostReduction;
                } else if step_norm <= opts.xtol * (xnorm + opts.xtol) {
                    stop = StopReason::SmallStep;
                }
                break;
            }
            if step_norm <= opts.xtol * (xnorm + opts.xtol) {
                stop = StopReason::SmallStep;
                break;
            }
            if opts.nearly_linear && at_minimum(predicted, cost_new, cost, opts.ftol) {
                // A step whose gain the cost cannot resolve, and which leaves the cost as it
                // was to rounding, is the linear model's last correction: take it.
                if takes_last_correction(predicted, cost_new, cost) {
                    x = xn;
                    std::mem::swap(&mut r, &mut r_new);
                    cost = cost_new;
                    problem.jacobian(&x, &mut j)?;
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
    let at_bound = bound_state(&x, opts);
    Ok(LmReport {
        x,
        residuals: r,
        jacobian: j,
        initial_cost,
        cost,
        iterations,
        stop,
        at_bound,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::NoMonitor;

    /// Rosenbrock as least squares: r = [10 (x2 - x1^2), 1 - x1]; minimum at (1, 1).
    struct Rosenbrock;
    impl Problem for Rosenbrock {
        fn residual_count(&self) -> usize {
            2
        }
        fn unknown_count(&self) -> usize {
            2
        }
        fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
            r[0] = 10.0 * (x[1] - x[0] * x[0]);
            r[1] = 1.0 - x[0];
            Ok(())
        }
    }

    #[test]
    fn finds_the_rosenbrock_minimum() {
        let rep = levenberg_marquardt(&Rosenbrock, &[-1.2, 1.0], &LmOptions::default(), &NoMonitor)
            .unwrap();
        assert!(rep.stop.converged(), "{:?}", rep.stop);
        assert!(
            (rep.x[0] - 1.0).abs() < 1e-9 && (rep.x[1] - 1.0).abs() < 1e-9,
            "{:?}",
            rep.x
        );
    }

    /// With x1 <= 0.5 the constrained minimum of Rosenbrock is on the bound: x1 = 0.5 and
    /// x2 = 0.25 (r0 = 0 is reachable on the bound).
    #[test]
    fn respects_bounds_and_reports_them() {
        let o = LmOptions {
            upper: Some(vec![0.5, 10.0]),
            lower: Some(vec![-10.0, -10.0]),
            ..Default::default()
        };
        let rep = levenberg_marquardt(&Rosenbrock, &[-1.2, 1.0], &o, &NoMonitor).unwrap();
        assert!(
            (rep.x[0] - 0.5).abs() < 1e-12 && (rep.x[1] - 0.25).abs() < 1e-8,
            "{:?}",
            rep.x
        );
        assert_eq!(rep.at_bound, vec![1, 0]);
    }

    /// A badly scaled linear problem (Jacobian columns 1e9 apart). With a = 1e6 (x0 - 2) and
    /// b = 1e-3 (x1 - 3) the cost is 2a^2 + 2b^2 + (b/2 + 1e-4)^2: a = 0, b = -1e-4 / 4.5.
    struct Scaled;
    impl Problem for Scaled {
        fn residual_count(&self) -> usize {
            3
        }
        fn unknown_count(&self) -> usize {
            2
        }
        fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
            let (a, b) = (1e6 * (x[0] - 2.0), 1e-3 * (x[1] - 3.0));
            r[0] = a + b;
            r[1] = a - b;
            r[2] = 0.5 * b + 1e-4;
            Ok(())
        }
    }

    #[test]
    fn column_scaling_handles_units_a_million_apart() {
        let rep =
            levenberg_marquardt(&Scaled, &[0.0, 0.0], &LmOptions::default(), &NoMonitor).unwrap();
        let x1 = 3.0 - 1e-4 / 4.5 / 1e-3;
        assert!(
            (rep.x[0] - 2.0).abs() < 1e-12 && (rep.x[1] - x1).abs() < 1e-9,
            "{:?} {:?} {}",
            rep.x,
            rep.stop,
            rep.iterations
        );
    }

    /// A linear problem with two nearly dependent columns (the weak direction of the scaled
    /// normal matrix ~1e-4 of the strong ones, as in a calibration from a nominal model):
    /// with `nearly_linear`, the well predicted steps drop the damping fast enough that the fit reaches the
    /// least-squares solution (by SVD) to 1e-8 in at most five iterations (Nielsen's rule alone,
    /// dividing the damping by 3 per step, took 9), and the last correction below the cost's
    /// rounding is taken.
    struct Correlated {
        a: DMatrix<f64>,
        b: DVector<f64>,
    }
    impl Problem for Correlated {
        fn residual_count(&self) -> usize {
            self.a.nrows()
        }
        fn unknown_count(&self) -> usize {
            self.a.ncols()
        }
        fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
            let v = &self.a * DVector::from_column_slice(x) - &self.b;
            r.copy_from_slice(v.as_slice());
            Ok(())
        }
        fn jacobian(&self, _x: &[f64], j: &mut DMatrix<f64>) -> Result<(), IdentifyError> {
            j.copy_from(&self.a);
            Ok(())
        }
    }

    #[test]
    fn nearly_linear_fits_converge_in_a_few_iterations() {
        let mut rng = crate::util::Rng::new(8);
        let (n, m) = (60, 6);
        let mut a = DMatrix::from_fn(n, m, |_, _| rng.normal());
        for r in 0..n {
            a[(r, 5)] = a[(r, 4)] + 1e-2 * a[(r, 5)];
        }
        let b = DVector::from_fn(n, |_, _| 10.0 * rng.normal());
        let want = a.clone().svd(true, true).solve(&b, 0.0).expect("full rank");
        let p = Correlated { a, b };
        let o = LmOptions {
            nearly_linear: true,
            ..Default::default()
        };
        let rep = levenberg_marquardt(&p, &[0.0; 6], &o, &NoMonitor).unwrap();
        assert!(rep.stop.converged(), "{:?}", rep.stop);
        // Nielsen's rule alone (a strongly nonlinear fit's setting) is slower here.
        let slow = levenberg_marquardt(&p, &[0.0; 6], &LmOptions::default(), &NoMonitor).unwrap();
        assert!(
            slow.iterations > rep.iterations + 2,
            "{} vs {}",
            slow.iterations,
            rep.iterations
        );
        for (k, (x, w)) in rep.x.iter().zip(want.iter()).enumerate() {
            assert!((x - w).abs() < 1e-8 * w.abs().max(1.0), "x{k}: {x} vs {w}");
        }
        assert!(rep.iterations <= 5, "{} iterations", rep.iterations);
    }
}
