//! `options` of `pcr.identify`: the steps, rank tolerance, bounds, gauge, and the Gaussian
//! prior of a MAP identification, checked with errors that name the option.

use std::collections::BTreeMap;

use serde::Deserialize;
use serde_json::Value;

use crate::identify::prior::PriorWeight;
use crate::jobs::map_options::{MapWeight, check_map_options};
use crate::measure::pcr::prior::PcrPrior;
use crate::measure::pcr::steps::{CalibrationOptions, Step, default_steps};
use crate::measure::pcr::{UNKNOWNS, unknown_name};
use crate::model::pcr::PcrFile;
use crate::run::JobError;

/// `options` of `pcr.identify`.
#[derive(Debug, Clone, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct IdentifyOptions {
    /// The steps: each a list of unknown names (`Ax_1`, `sx`), parameter types (`l`,
    /// `gamma`, ...), `extrinsics` or `all`. Default: the paper's three steps.
    #[serde(default)]
    pub steps: Option<Vec<Vec<String>>>,
    /// Relative tolerance of the rank detection (default 1e-8).
    #[serde(default)]
    pub rank_tolerance: Option<f64>,
    /// Levenberg-Marquardt iteration limit per step (default 100).
    #[serde(default)]
    pub max_iterations: Option<usize>,
    /// Bounds are nominal +/- this many standard uncertainties (default 3).
    #[serde(default)]
    pub bound_sigmas: Option<f64>,
    /// `min_norm` (default): each unidentifiable combination is held at nominal; `hold`: the
    /// unknowns rank detection drops are held at nominal themselves.
    #[serde(default)]
    pub gauge: Option<String>,
    /// A Gaussian prior (MAP identification): mean = the file's nominal values; std = the
    /// file's standard uncertainty for every robot parameter, overridden per name by
    /// `prior.std` (SI units), which may also give the extrinsics one.
    #[serde(default)]
    pub prior: Option<PcrPriorSpec>,
    /// Weight of the prior: a positive number (default 1) or `"cv"` (5-fold on the
    /// calibration poses among 0.01 ... 100).
    #[serde(default)]
    pub prior_weight: Option<PriorWeight>,
    /// Measurement noise of the MAP objective (m); default the file's position repeatability.
    #[serde(default)]
    pub noise_m: Option<f64>,
}

/// `options.prior` of `pcr.identify`.
#[derive(Debug, Clone, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PcrPriorSpec {
    /// Prior std per unknown name (`l_1`, `gamma_2`, `sx`, ...), SI units (m, rad, Pa).
    #[serde(default)]
    pub std: BTreeMap<String, f64>,
}

impl IdentifyOptions {
    /// Parse `options` given as JSON (a campaign's `options.identify`), naming the field.
    pub fn from_value(v: &Value) -> Result<IdentifyOptions, JobError> {
        serde_path_to_error::deserialize(v).map_err(|e| {
            JobError::invalid(format!("options.{}", e.path()), e.into_inner().to_string())
        })
    }
}

/// Turn job options into calibration options (errors name the option).
pub fn calibration_options(o: &IdentifyOptions) -> Result<CalibrationOptions, JobError> {
    let mut c = CalibrationOptions::default();
    if let Some(steps) = &o.steps {
        if steps.is_empty() {
            return Err(JobError::invalid(
                "options.steps",
                "needs at least one step",
            ));
        }
        c.steps = steps
            .iter()
            .enumerate()
            .map(|(i, names)| {
                Step::from_names(&format!("step {}", i + 1), names)
                    .map_err(|e| JobError::invalid(format!("options.steps[{i}]"), e))
            })
            .collect::<Result<_, _>>()?;
    } else {
        c.steps = default_steps();
    }
    for (name, v) in [
        ("options.rank_tolerance", o.rank_tolerance),
        ("options.bound_sigmas", o.bound_sigmas),
    ] {
        if let Some(v) = v
            && !(v.is_finite() && v > 0.0)
        {
            return Err(JobError::invalid(
                name,
                format!("{v} must be a positive number"),
            ));
        }
    }
    if let Some(t) = o.rank_tolerance {
        c.rank_tolerance = t;
    }
    if let Some(b) = o.bound_sigmas {
        c.bound_sigmas = b;
    }
    match o.gauge.as_deref() {
        None | Some("min_norm") => {}
        Some("hold") => c.hold_unidentifiable = true,
        Some(other) => {
            return Err(JobError::invalid(
                "options.gauge",
                format!("`{other}`: expected \"min_norm\" or \"hold\""),
            ));
        }
    }
    if let Some(n) = o.max_iterations {
        if n == 0 {
            return Err(JobError::invalid(
                "options.max_iterations",
                "must be at least 1",
            ));
        }
        c.max_iterations = n;
    }
    check_prior(o)?;
    Ok(c)
}

/// Check the prior options without a model file: names, values, weight, noise, and that
/// `prior_weight`/`noise_m` come with a `prior`.
fn check_prior(o: &IdentifyOptions) -> Result<MapWeight, JobError> {
    let weight = check_map_options(o.prior.is_some(), o.prior_weight.as_ref(), o.noise_m)?;
    for (name, &v) in o.prior.iter().flat_map(|s| &s.std) {
        if !(0..UNKNOWNS).any(|k| unknown_name(k) == *name) {
            return Err(JobError::invalid(
                format!("options.prior.std.{name}"),
                "no such unknown (robot parameters such as l_1, gamma_2, E; extrinsics sx ... mtheta)",
            ));
        }
        if !(v.is_finite() && v > 0.0) {
            return Err(JobError::invalid(
                format!("options.prior.std.{name}"),
                format!("{v} must be a positive number"),
            ));
        }
    }
    Ok(weight)
}

/// The prior of checked options on `file`: `None` without `options.prior`, else the prior
/// (weight 1 while it is to be chosen by K-fold) and whether it is.
pub(super) fn prior_of(o: &IdentifyOptions, file: &PcrFile) -> Option<(PcrPrior, bool)> {
    let spec = o.prior.as_ref()?;
    let (weight, cv) = match check_prior(o) {
        Ok(MapWeight::Fixed(w)) => (w, false),
        Ok(MapWeight::CrossValidated) => (1.0, true),
        Ok(MapWeight::None) | Err(_) => return None,
    };
    let robot = file.uncertainty.robot();
    let sigma = (0..UNKNOWNS)
        .map(|k| {
            spec.std
                .get(&unknown_name(k))
                .copied()
                .or_else(|| robot.get(k).copied().filter(|u| u.is_finite() && *u > 0.0))
        })
        .collect();
    let noise = o.noise_m.unwrap_or(file.repeatability.position);
    Some((
        PcrPrior {
            sigma,
            noise,
            weight,
        },
        cv,
    ))
}
