//! What the identification pipeline ([`super::solve`]) takes and gives: the unknowns'
//! descriptions, the options, and the solution with its per-parameter report, held
//! combinations and unobservable directions.

use nalgebra::DVector;
use std::borrow::Cow;

use serde::{Deserialize, Serialize};

use crate::util::serde_num::f64_or_nan;

use super::trust::{Degeneracy, NearDependent};
use super::{LmOptions, Pivoting, StopReason, Uncertainty};

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
    /// Decide rank on the Jacobian scaled by the unknowns' physical scales (their plausible
    /// ranges) instead of unit column norms (default true).
    pub physical_rank: bool,
    /// Hold at nominal every unknown whose effect size is below this fraction of the noise,
    /// and every combination whose singular value (residual 2-norm per scale unit) is; with
    /// no `noise` given, the fitted sigma is used and the fit repeated once. Default 0.01:
    /// far above rounding noise (an effect of 1e-15 mm), far below weak but real effects,
    /// which stay identified and are flagged as weakly observable (the IRB 120 twin's c6 sits
    /// at 0.09 sigma; 0.1 would hold it in some data sets and not in others).
    pub effect_fraction: Option<f64>,
    /// Indices of the nuisance unknowns (frames, unknown points): when given, they alone are
    /// also fitted from the same start, and a full fit ending above that cost is degenerate.
    pub nuisance: Option<Vec<usize>>,
    /// A move beyond this many physical scales (angles modulo a turn; an angle running
    /// through more than 1,000 turns) makes the
    /// result degenerate (default 1000).
    pub degenerate_factor: f64,
    /// Compute the standard deviations and the condition numbers of the result (default
    /// true). False leaves `params[].std` null, `condition_number` and the uncertainty's
    /// spectrum NaN/empty (its `sigma` stays): for studies that use only the identified
    /// values, which are the same either way.
    pub uncertainty: bool,
    /// Report the near-dependent combinations of the plans (default true). False leaves
    /// `near_dependent` empty except for combinations held, and skips the spectra where a
    /// cheap certificate shows nothing is to be held: the same identified values, free set
    /// and convergence.
    pub near_dependent: bool,
    /// Unknowns held at their start values whatever the data say, each with why (e.g. a
    /// joint placement that duplicates the base frame): reported not identifiable, with the
    /// reason and the combination of identified unknowns they duplicate in `dependencies`.
    pub hold: Vec<(usize, String)>,
}

impl Default for SolveOptions {
    fn default() -> Self {
        Self {
            lm: LmOptions::default(),
            pivoting: Pivoting::Norm,
            rank_tolerance: 1e-8,
            noise: None,
            physical_rank: true,
            effect_fraction: Some(0.01),
            nuisance: None,
            degenerate_factor: 1000.0,
            uncertainty: true,
            near_dependent: true,
            hold: Vec::new(),
        }
    }
}

/// One line of the parameter table of a result (binding field names of jobs.md).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ParamReport {
    /// Parameter name.
    pub name: String,
    /// Unit of nominal, value and std.
    pub unit: String,
    /// Nominal value.
    #[serde(deserialize_with = "f64_or_nan")]
    pub nominal: f64,
    /// Identified value (nominal if unidentifiable).
    #[serde(deserialize_with = "f64_or_nan")]
    pub value: f64,
    /// Standard deviation (null if held fixed).
    pub std: Option<f64>,
    /// Whether the data determine it.
    pub identifiable: bool,
    /// Largest change of any residual over the parameter's plausible range (residual unit).
    #[serde(deserialize_with = "f64_or_nan")]
    pub effect_size: f64,
    /// `lower` or `upper` when the solution sits on a bound.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub at_bound: Option<Cow<'static, str>>,
}

/// An unidentifiable parameter and the identifiable ones it duplicates.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Dependency {
    /// The unidentifiable parameter.
    pub name: String,
    /// Its column as a combination of kept columns: (name, coefficient in internal units).
    pub combination: Vec<(String, f64)>,
    /// Why it is held when not by rank detection alone (e.g. `duplicates the base frame`).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub reason: Option<String>,
}

/// An unknown held at its start value because its whole effect is below the noise.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Unobservable {
    /// The unknown.
    pub name: String,
    /// Its effect size (residual units): largest residual change over its physical scale.
    pub effect_size: f64,
    /// The threshold it fell below (residual units).
    pub threshold: f64,
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
    /// What each structurally unidentifiable parameter duplicates.
    pub dependencies: Vec<Dependency>,
    /// Unknowns held because their effect is below a fraction of the noise (also listed in
    /// `unidentifiable`, as are the unknowns held for a near-dependent combination).
    pub unobservable: Vec<Unobservable>,
    /// The least-determined combinations (smallest singular values of the physically scaled
    /// Jacobian): each one that led to holding its dominant unknown at nominal, then the
    /// three smallest of the identified set. With the noise estimated from the fit, the
    /// Jacobians at the start and at the first solution are judged together (rows stacked).
    pub near_dependent: Vec<NearDependent>,
    /// Condition number of the physically scaled Jacobian of the identified set at the
    /// solution.
    pub condition_number: f64,
    /// Cost of the fit of the nuisance unknowns only, if asked for.
    pub nuisance_cost: Option<f64>,
    /// Why the result cannot be trusted, if it cannot.
    pub degenerate: Option<Degeneracy>,
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
    /// Uncertainty of the identified unknowns (in `free` order; unit-norm conditioning).
    pub uncertainty: Uncertainty,
    /// What a robust loss did (`None` for plain least squares).
    pub robust: Option<super::RobustReport>,
    /// A gauge held by its structure ([`super::gauge_orbit::hold_orbit`]), if any.
    pub held_gauge: Option<HeldGauge>,
}

impl Solution {
    /// Converged and not degenerate.
    pub fn converged(&self) -> bool {
        self.stop.converged() && self.degenerate.is_none()
    }

    /// `converged`, `degenerate` or `not_converged`.
    pub fn status(&self) -> &'static str {
        if self.degenerate.is_some() {
            "degenerate"
        } else if self.stop.converged() {
            "converged"
        } else {
            "not_converged"
        }
    }
}

/// A gauge held by [`super::gauge_orbit::hold_orbit`] (the result field `gauge_held`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct HeldGauge {
    /// What the freedom is.
    pub freedom: String,
    /// The held combination: its largest components (unknown name, component of the unit
    /// direction in physically scaled unknowns), largest first.
    pub combination: Vec<(String, f64)>,
    /// How far the free fit's solution was moved along the freedom to the held point (the
    /// orbit's unit, e.g. deg).
    pub moved: f64,
    /// Unit of `moved`.
    pub unit: String,
    /// Cost of the held fit minus that of the free fit (squared residual unit): zero to
    /// rounding when the freedom is a true gauge (the predictions are the free fit's).
    pub cost_change: f64,
}
