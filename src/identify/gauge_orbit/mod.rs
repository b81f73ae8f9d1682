//! A gauge the measurements cannot see, given by its structure: a one-parameter motion of
//! the unknowns (`orbit(x, t)`, e.g. the world frame turned by `t` about the line through
//! two sockets) that changes no residual. [`hold_orbit`] picks the point of the free fit's
//! orbit closest to the start in units of the physical scales and refits with that
//! combination held ([`super::Gauged`]), so the fit neither wanders along the freedom nor
//! pushes it into a link's parameters, and the covariance has no infinite direction.

use super::trust::physical_scales;
use super::{Gauge, Gauged, IdentifyError, Problem, Solution, SolveOptions, Unknown, solve};
use crate::util::Monitor;

/// Samples of the coarse search for the closest orbit point over one turn.
const SEARCH_SAMPLES: usize = 720;

pub use super::solution::HeldGauge;

/// A one-parameter gauge of a problem: `map(x, t)` moves `x` by `t` along it.
pub struct Orbit<'a> {
    /// What the freedom is (reported).
    pub freedom: String,
    /// The motion; `map(x, 0) == x`.
    pub map: &'a dyn Fn(&[f64], f64) -> Vec<f64>,
    /// Range searched, `[-half_range, half_range]` (one turn: pi).
    pub half_range: f64,
    /// Unit `t` is reported in, and the factor to it.
    pub unit: (&'a str, f64),
}

impl std::fmt::Debug for Orbit<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Orbit")
            .field("freedom", &self.freedom)
            .field("half_range", &self.half_range)
            .finish()
    }
}

/// Difference of unknowns in physical scales, angles (unit `deg`/`rad`) wrapped to a half
/// turn.
fn scaled_diff(a: &[f64], b: &[f64], unknowns: &[Unknown], scale: &[f64]) -> Vec<f64> {
    a.iter()
        .zip(b)
        .zip(unknowns.iter().zip(scale))
        .map(|((x, y), (u, s))| {
            let mut d = x - y;
            if matches!(u.unit.as_str(), "deg" | "rad") {
                let turn = std::f64::consts::TAU;
                d -= turn * (d / turn).round();
            }
            d / s
        })
        .collect()
}

/// The `t` whose orbit point of `x` is closest to `x0` in physical scales: a coarse scan,
/// then golden-section refinement around its best sample.
fn closest(orbit: &Orbit<'_>, x: &[f64], x0: &[f64], unknowns: &[Unknown], scale: &[f64]) -> f64 {
    let dist = |t: f64| -> f64 {
        scaled_diff(&(orbit.map)(x, t), x0, unknowns, scale)
            .iter()
            .map(|v| v * v)
            .sum()
    };
    let step = 2.0 * orbit.half_range / SEARCH_SAMPLES as f64;
    let mut best = (0.0, dist(0.0));
    for i in 0..=SEARCH_SAMPLES {
        let t = -orbit.half_range + step * i as f64;
        let d = dist(t);
        if d < best.1 {
            best = (t, d);
        }
    }
    let (mut a, mut b) = (best.0 - step, best.0 + step);
    let g = (5f64.sqrt() - 1.0) / 2.0;
    for _ in 0..60 {
        let (c, d) = (b - g * (b - a), a + g * (b - a));
        if dist(c) < dist(d) {
            b = d;
        } else {
            a = c;
        }
    }
    0.5 * (a + b)
}

/// Refit `problem` from `x0` with the gauge `orbit` held at the point of the `free` fit's
/// orbit closest to `x0`; the solution's residuals and costs are the data's alone.
pub fn hold_orbit(
    problem: &dyn Problem,
    unknowns: &[Unknown],
    x0: &[f64],
    free: &Solution,
    orbit: &Orbit<'_>,
    opts: &SolveOptions,
    monitor: &dyn Monitor,
) -> Result<(Solution, HeldGauge), IdentifyError> {
    let scale = physical_scales(unknowns);
    let t = closest(orbit, &free.x, x0, unknowns, &scale);
    let x_held = (orbit.map)(&free.x, t);
    // The orbit's tangent at the held point, in scaled unknowns, as a unit direction.
    let h = 1e-6;
    let mut v = scaled_diff(
        &(orbit.map)(&x_held, h),
        &(orbit.map)(&x_held, -h),
        unknowns,
        &scale,
    );
    let norm = v.iter().map(|c| c * c).sum::<f64>().sqrt();
    if !(norm > 0.0 && norm.is_finite()) {
        return Err(IdentifyError::Model(format!(
            "the gauge `{}` does not move the unknowns",
            orbit.freedom
        )));
    }
    v.iter_mut().for_each(|c| *c /= norm);
    let coefficients = v.iter().zip(&scale).map(|(d, s)| d / s).collect();
    let mut j = nalgebra::DMatrix::zeros(problem.residual_count(), problem.unknown_count());
    problem.jacobian(&x_held, &mut j)?;
    // Weighted like the data's strongest scaled column, so the row neither dominates nor
    // vanishes.
    let weight = (0..j.ncols())
        .map(|k| j.column(k).norm() * scale[k])
        .fold(0.0, f64::max)
        .max(1e-12);
    let gauge = Gauge {
        direction: v.clone(),
        coefficients,
    };
    // A gauge the data see at the start (only the cost is invariant along it, as for a
    // rotation about the sockets with large start residuals) is left out of the rank
    // detection, so that no column duplicating the base in the data is freed by its row; a
    // gauge null in the data at the start (a linear one) needs its row there.
    let mut j0 = nalgebra::DMatrix::zeros(problem.residual_count(), problem.unknown_count());
    problem.jacobian(x0, &mut j0)?;
    // The orbit's tangent in unknown units (the unit direction times the scales).
    let tangent =
        nalgebra::DVector::from_iterator(v.len(), v.iter().zip(&scale).map(|(d, s)| d * s));
    let seen = (&j0 * tangent).norm();
    let gauged = Gauged::new(problem, vec![gauge], x_held, weight);
    let gauged = if seen > 1e-6 * weight {
        gauged.outside_rank()
    } else {
        gauged
    };
    let mut sol = solve(&gauged, unknowns, x0, opts, monitor)?;
    let n = problem.residual_count();
    sol.residuals_before = sol.residuals_before.rows(0, n).into_owned();
    sol.residuals = sol.residuals.rows(0, n).into_owned();
    sol.cost_before = sol.residuals_before.norm_squared();
    sol.cost_after = sol.residuals.norm_squared();
    let mut comps: Vec<(usize, f64)> = v.iter().copied().enumerate().collect();
    comps.sort_by(|a, b| b.1.abs().total_cmp(&a.1.abs()));
    let held = HeldGauge {
        freedom: orbit.freedom.clone(),
        combination: comps
            .iter()
            .take(4)
            .map(|&(k, c)| (unknowns[k].name.clone(), c))
            .collect(),
        moved: t * orbit.unit.1,
        unit: orbit.unit.0.to_string(),
        cost_change: sol.cost_after - free.cost_after,
    };
    Ok((sol, held))
}

#[cfg(test)]
mod tests;
