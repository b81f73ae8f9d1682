//! The MAP options shared by the identification jobs: `options.prior_weight` and
//! `options.noise_m` belong to an `options.prior`, the weight is a positive number or
//! `"cv"`, the noise a positive number of metres. Errors name the option.

use crate::identify::prior::PriorWeight;
use crate::run::JobError;

/// What checked MAP options ask for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MapWeight {
    /// No `options.prior`: least squares.
    None,
    /// A fixed weight (1 when not given).
    Fixed(f64),
    /// `"cv"`: chosen by K-fold.
    CrossValidated,
}

/// Check `prior_weight` and `noise_m` against whether a prior is given.
pub fn check_map_options(
    has_prior: bool,
    weight: Option<&PriorWeight>,
    noise_m: Option<f64>,
) -> Result<MapWeight, JobError> {
    if !has_prior {
        for (name, given) in [
            ("options.prior_weight", weight.is_some()),
            ("options.noise_m", noise_m.is_some()),
        ] {
            if given {
                return Err(JobError::invalid(name, "needs options.prior"));
            }
        }
        return Ok(MapWeight::None);
    }
    if let Some(n) = noise_m
        && !(n.is_finite() && n > 0.0)
    {
        return Err(JobError::invalid(
            "options.noise_m",
            format!("{n} must be a positive number of metres"),
        ));
    }
    match weight.map(PriorWeight::fixed).transpose() {
        Err(m) => Err(JobError::invalid("options.prior_weight", m)),
        Ok(None) => Ok(MapWeight::Fixed(1.0)),
        Ok(Some(Some(w))) => Ok(MapWeight::Fixed(w)),
        Ok(Some(None)) => Ok(MapWeight::CrossValidated),
    }
}
