//! The identification pipeline every method uses: rank detection at the starting point,
//! Levenberg-Marquardt on the identifiable unknowns (the others held at their start
//! values), standard deviations, effect sizes, and a per-parameter report.

use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use super::{
    IdentifyError, LmOptions, Pivoting, Problem, Restricted, StopReason, Uncertainty,
    levenberg_marquardt, rank_revealing, uncertainty,
};
use crate::util::Monitor;

/// Description of one unknown for reports.
#[derive(Debug, Clone)]
pub struct Unknown {
    /// Public name.
    pub name: String,
    /// Unit of reported values.
    pub unit: String,
    /// Factor from internal units to the reported unit.
    pub to_report: f64,
    /// Nominal value (internal units).
    pub nominal: f64,
    /// Plausible range of the parameter (internal units), for the effect size.
    pub plausible_range: f64,
    /// Lower bound (internal units), if bounded.
    pub lower: Option<f64>,
    /// Upper bound (internal units), if bounded.
    pub upper: Option<f64>,
}

/// Settings of [`solve`].
#[derive(Debug, Clone)]
pub struct SolveOptions {
    /// Solver settings (bounds are taken from the unknowns).
    pub lm: LmOptions,
    /// Column order of the rank detection.
    pub pivoting: Pivoting,
    /// Relative tolerance of the rank detection.
    pub rank_tolerance: f64,
    /// Measurement noise in residual units; parameters whose effect size is below it are
    /// flagged as weakly observable (default: the fitted residual sigma).
    pub noise: Option<f64>,
}

impl Default for SolveOptions {
    fn default() -> Self {
        Self {
            lm: LmOptions::default(),
            pivoting: Pivoting::Norm,
            rank_tolerance: 1e-8,
            noise: None,
        }
    }
}

/// One line of the parameter table of a result (binding field names of jobs.md).
#[derive(Debug, Clone, Serialize)]
pub struct ParamReport {
    /// Parameter name.
    pub name: String,
    /// Unit of nominal, value and std.
    pub unit: String,
    /// Nominal value.
    pub nominal: f64,
    /// Identified value (nominal if unidentifiable).
    pub value: f64,
    /// Standard deviation (null if held fixed).
    pub std: Option<f64>,
    /// Whether the data determine it.
    pub identifiable: bool,
    /// Largest change of any residual over the parameter's plausible range (residual unit).
    pub effect_size: f64,
    /// `lower` or `upper` when the solution sits on a bound.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub at_bound: Option<&'static str>,
}

/// An unidentifiable parameter and the identifiable ones it duplicates.
#[derive(Debug, Clone, Serialize)]
pub struct Dependency {
    /// The unidentifiable parameter.
    pub name: String,
    /// Its column as a combination of kept columns: (name, coefficient in internal units).
    pub combination: Vec<(String, f64)>,
}

/// Outcome of an identification.
#[derive(Debug, Clone)]
pub struct Solution {
    /// All unknowns at the solution (internal units).
    pub x: Vec<f64>,
    /// Report per unknown, in input order.
    pub params: Vec<ParamReport>,
    /// Names of unknowns held at their start value because the data cannot determine them.
    pub unidentifiable: Vec<String>,
    /// What each unidentifiable parameter duplicates.
    pub dependencies: Vec<Dependency>,
    /// Identifiable but with an effect below the noise.
    pub weakly_observable: Vec<String>,
    /// Indices of the identified unknowns.
    pub free: Vec<usize>,
    /// Why LM stopped.
    pub stop: StopReason,
    /// LM iterations.
    pub iterations: usize,
    /// Sum of squared residuals at the start and at the end.
    pub cost_before: f64,
    /// Sum of squared residuals at the solution.
    pub cost_after: f64,
    /// Residuals at the start.
    pub residuals_before: DVector<f64>,
    /// Residuals at the solution.
    pub residuals: DVector<f64>,
    /// Uncertainty of the identified unknowns (in `free` order).
    pub uncertainty: Uncertainty,
    /// What a robust loss did (`None` for plain least squares).
    pub robust: Option<super::RobustReport>,
}

/// Identify `unknowns` from `x0`: rank detection, bounded LM, uncertainty, report.
pub fn solve(
    problem: &dyn Problem,
    unknowns: &[Unknown],
    x0: &[f64],
    opts: &SolveOptions,
    monitor: &dyn Monitor,
) -> Result<Solution, IdentifyError> {
    let (n, m) = (problem.residual_count(), problem.unknown_count());
    monitor.progress(0.0, "rank detection");
    let mut r0 = DVector::zeros(n);
    problem.residuals(x0, r0.as_mut_slice())?;
    if let Some(index) = r0.iter().position(|v| !v.is_finite()) {
        return Err(IdentifyError::NonFinite { index });
    }
    let mut j0 = DMatrix::zeros(n, m);
    problem.jacobian(x0, &mut j0)?;
    let rank = rank_revealing(&j0, &opts.pivoting, opts.rank_tolerance);
    let mut free = rank.kept.clone();
    free.sort_unstable();
    let restricted = Restricted::new(problem, x0.to_vec(), free.clone());
    let pick = |f: &dyn Fn(&Unknown) -> Option<f64>, default: f64| -> Option<Vec<f64>> {
        free.iter().any(|&k| f(&unknowns[k]).is_some()).then(|| {
            free.iter()
                .map(|&k| f(&unknowns[k]).unwrap_or(default))
                .collect()
        })
    };
    let lm_opts = LmOptions {
        lower: pick(&|u: &Unknown| u.lower, f64::NEG_INFINITY),
        upper: pick(&|u: &Unknown| u.upper, f64::INFINITY),
        ..opts.lm.clone()
    };
    let xs0: Vec<f64> = free.iter().map(|&k| x0[k]).collect();
    let sub = crate::util::SubMonitor::new(monitor, 0.05, 0.95);
    let rep = levenberg_marquardt(&restricted, &xs0, &lm_opts, &sub)?;
    monitor.progress(0.95, "uncertainty");
    let unc = uncertainty(&rep.jacobian, &rep.residuals);
    let x = restricted.expand(&rep.x);
    let noise = opts.noise.unwrap_or(unc.sigma);
    let mut params = Vec::with_capacity(m);
    let mut weakly = Vec::new();
    for (k, u) in unknowns.iter().enumerate() {
        let effect = j0.column(k).amax() * u.plausible_range;
        let pos = free.iter().position(|&f| f == k);
        if pos.is_some() && effect < noise {
            weakly.push(u.name.clone());
        }
        let at_bound = pos.and_then(|p| match rep.at_bound[p] {
            -1 => Some("lower"),
            1 => Some("upper"),
            _ => None,
        });
        params.push(ParamReport {
            name: u.name.clone(),
            unit: u.unit.clone(),
            nominal: u.nominal * u.to_report,
            value: x[k] * u.to_report,
            std: pos.map(|p| unc.std[p] * u.to_report),
            identifiable: pos.is_some(),
            effect_size: effect,
            at_bound,
        });
    }
    let dependencies = rank
        .dropped
        .iter()
        .zip(&rank.dependencies)
        .map(|(&c, dep)| Dependency {
            name: unknowns[c].name.clone(),
            combination: dep
                .iter()
                .take(6)
                .map(|&(k, v)| (unknowns[k].name.clone(), v))
                .collect(),
        })
        .collect();
    let mut dropped = rank.dropped.clone();
    dropped.sort_unstable();
    Ok(Solution {
        x,
        params,
        unidentifiable: dropped.iter().map(|&k| unknowns[k].name.clone()).collect(),
        dependencies,
        weakly_observable: weakly,
        free,
        stop: rep.stop,
        iterations: rep.iterations,
        cost_before: rep.initial_cost.min(r0.norm_squared()),
        cost_after: rep.cost,
        residuals_before: r0,
        residuals: rep.residuals,
        uncertainty: unc,
        robust: None,
    })
}
