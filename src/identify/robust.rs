//! Robust losses (Huber, Cauchy) by iteratively reweighted least squares around [`solve`]:
//! each round weights residual groups by `psi(r)/r` at the current solution and solves the
//! weighted problem; the scale is given or estimated by the MAD of the first residuals and
//! reported.

use nalgebra::DMatrix;
use serde::Serialize;

use super::{IdentifyError, Problem, Solution, SolveOptions, Unknown, solve};
use crate::util::Monitor;

/// A robust loss on the norm of a group of residuals (e.g. the 3 coordinates of a marker).
#[derive(Debug, Clone, PartialEq)]
pub struct Robust {
    /// Which loss.
    pub kind: RobustKind,
    /// Scale (residual units); `None`: tuning constant x 1.4826 x median group norm at start.
    pub scale: Option<f64>,
    /// Consecutive residual rows that form one group.
    pub group: usize,
}

/// The loss function.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum RobustKind {
    /// Quadratic below the scale, linear above (tuning constant 1.345).
    Huber,
    /// log(1 + (r/s)^2) (tuning constant 2.385).
    Cauchy,
}

/// What the robust rounds did.
#[derive(Debug, Clone, Serialize)]
pub struct RobustReport {
    /// The loss.
    pub kind: RobustKind,
    /// The scale used (residual units).
    pub scale: f64,
    /// Reweighting rounds.
    pub rounds: usize,
    /// Groups with weight below 0.5 at the end.
    pub downweighted: usize,
    /// Number of groups.
    pub groups: usize,
}

impl Robust {
    fn weight(&self, r: f64, s: f64) -> f64 {
        let u = r / s;
        match self.kind {
            RobustKind::Huber => {
                if u <= 1.0 {
                    1.0
                } else {
                    1.0 / u
                }
            }
            RobustKind::Cauchy => 1.0 / (1.0 + u * u),
        }
    }

    fn tuning(&self) -> f64 {
        match self.kind {
            RobustKind::Huber => 1.345,
            RobustKind::Cauchy => 2.385,
        }
    }
}

/// A problem whose residual rows are multiplied by fixed factors.
struct Weighted<'a> {
    inner: &'a dyn Problem,
    sqrt_w: Vec<f64>,
}

impl Problem for Weighted<'_> {
    fn residual_count(&self) -> usize {
        self.inner.residual_count()
    }
    fn unknown_count(&self) -> usize {
        self.inner.unknown_count()
    }
    fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
        self.inner.residuals(x, r)?;
        for (v, w) in r.iter_mut().zip(&self.sqrt_w) {
            *v *= w;
        }
        Ok(())
    }
    fn jacobian(&self, x: &[f64], j: &mut DMatrix<f64>) -> Result<(), IdentifyError> {
        self.inner.jacobian(x, j)?;
        for (i, w) in self.sqrt_w.iter().enumerate() {
            j.row_mut(i).scale_mut(*w);
        }
        Ok(())
    }
}

fn group_norms(r: &[f64], g: usize) -> Vec<f64> {
    r.chunks(g.max(1))
        .map(|c| c.iter().map(|v| v * v).sum::<f64>().sqrt())
        .collect()
}

/// [`solve`] with a robust loss by IRLS (at most 20 rounds, until no weight moves by more
/// than 1e-3). The returned residuals and costs are unweighted; the uncertainty is that of
/// the last weighted problem.
pub fn solve_robust(
    problem: &dyn Problem,
    unknowns: &[Unknown],
    x0: &[f64],
    opts: &SolveOptions,
    robust: &Robust,
    monitor: &dyn Monitor,
) -> Result<Solution, IdentifyError> {
    let n = problem.residual_count();
    let g = robust.group.max(1);
    let mut r = vec![0.0; n];
    problem.residuals(x0, &mut r)?;
    let r0 = r.clone();
    // Round 1 is plain least squares; the scale (if not given) is re-estimated from the
    // current residuals before each reweighting.
    let estimate = |r: &[f64]| -> f64 {
        match robust.scale {
            Some(s) if s > 0.0 => s,
            _ => {
                let mad = crate::util::stats::quantile(&group_norms(r, g), 0.5) * 1.4826;
                (robust.tuning() * mad).max(f64::MIN_POSITIVE)
            }
        }
    };
    let mut sol = solve(problem, unknowns, x0, opts, monitor)?;
    let mut x = sol.x.clone();
    problem.residuals(&x, &mut r)?;
    let mut weights = vec![1.0; n.div_ceil(g)];
    let mut scale = estimate(&r);
    let mut rounds = 1;
    while rounds < 20 {
        scale = estimate(&r);
        let new: Vec<f64> = group_norms(&r, g)
            .iter()
            .map(|&v| robust.weight(v, scale))
            .collect();
        let moved = new
            .iter()
            .zip(&weights)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        weights = new;
        if moved < 1e-3 {
            break;
        }
        rounds += 1;
        let sqrt_w = (0..n).map(|i| weights[i / g].sqrt()).collect();
        let wp = Weighted {
            inner: problem,
            sqrt_w,
        };
        sol = solve(&wp, unknowns, &x, opts, monitor)?;
        x = sol.x.clone();
        problem.residuals(&x, &mut r)?;
    }
    let sol = Some(sol);
    let Some(mut s) = sol else {
        return Err(IdentifyError::Model("robust fit made no round".into()));
    };
    s.residuals_before = nalgebra::DVector::from_vec(r0.clone());
    s.cost_before = r0.iter().map(|v| v * v).sum();
    s.residuals = nalgebra::DVector::from_vec(r.clone());
    s.cost_after = r.iter().map(|v| v * v).sum();
    s.robust = Some(RobustReport {
        kind: robust.kind,
        scale,
        rounds,
        downweighted: weights.iter().filter(|&&w| w < 0.5).count(),
        groups: weights.len(),
    });
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::{NoMonitor, Rng};

    /// Line fit with 10% gross outliers: least squares is pulled away, Huber and Cauchy
    /// recover the true line to the noise level.
    struct Line {
        x: Vec<f64>,
        y: Vec<f64>,
    }
    impl Problem for Line {
        fn residual_count(&self) -> usize {
            self.x.len()
        }
        fn unknown_count(&self) -> usize {
            2
        }
        fn residuals(&self, p: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
            for i in 0..self.x.len() {
                r[i] = p[0] + p[1] * self.x[i] - self.y[i];
            }
            Ok(())
        }
    }

    #[test]
    fn robust_losses_reject_outliers() {
        let mut rng = Rng::new(4);
        let x: Vec<f64> = (0..100).map(|i| i as f64 / 10.0).collect();
        let mut y: Vec<f64> = x
            .iter()
            .map(|v| 1.0 + 2.0 * v + 0.01 * rng.normal())
            .collect();
        for i in (0..100).step_by(10) {
            y[i] += 5.0;
        }
        let p = Line { x, y };
        let u = |n: &str| Unknown {
            name: n.into(),
            unit: "1".into(),
            to_report: 1.0,
            nominal: 0.0,
            plausible_range: 1.0,
            lower: None,
            upper: None,
        };
        let unknowns = [u("a"), u("b")];
        let o = SolveOptions::default();
        let ls = solve(&p, &unknowns, &[0.0, 0.0], &o, &NoMonitor).unwrap();
        assert!((ls.x[0] - 1.0).abs() > 0.2, "{:?}", ls.x);
        for kind in [RobustKind::Huber, RobustKind::Cauchy] {
            let r = Robust {
                kind,
                scale: None,
                group: 1,
            };
            let s = solve_robust(&p, &unknowns, &[0.0, 0.0], &o, &r, &NoMonitor).unwrap();
            // Noise 0.01 on 100 points: intercept std ~0.002; outliers are fully rejected.
            let tol = 0.01;
            assert!(
                (s.x[0] - 1.0).abs() < tol && (s.x[1] - 2.0).abs() < tol / 5.0,
                "{kind:?} {:?}",
                s.x
            );
            let rep = s.robust.unwrap();
            assert!(rep.downweighted >= 10, "{rep:?}");
        }
    }
}
