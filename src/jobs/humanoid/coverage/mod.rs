//! `coverage` of `humanoid.identify` on a held-out session (`validation`): the base frame and
//! marker positions refitted there with the joints held (markers are re-mounted between
//! sessions), then per visible marker the predicted covariance of its 3-D error after that
//! refit, `P (J Sigma_p J^T + sigma^2 I) P`, and the fraction within 2 sigma
//! ([`crate::identify::coverage`]).

use nalgebra::{DMatrix, Vector3};

use crate::identify::IdentifyError;
use crate::identify::coverage::{Coverage, coverage_after_refit};
use crate::measure::marker_fit::{FitOptions, MarkerFit, refit_frames};
use crate::measure::markers::MarkerSample;
use crate::model::humanoid::{HParam, Humanoid};
use crate::util::Monitor;

/// Millimetres per metre: the coverage of a humanoid is reported in mm like its RMSEs.
const MM_PER_M: f64 = 1e3;

/// Per visible (sample, marker) of `samples`: the error of `model` (predicted minus
/// measured, m) and the 3 x `params.len()` Jacobian of the marker position with respect to
/// the model parameters `params` (indices into `model.params`; `None` gives a zero column).
pub(crate) fn marker_errors_and_jacobians(
    model: &Humanoid,
    params: &[Option<usize>],
    samples: &[MarkerSample],
) -> (Vec<Vector3<f64>>, Vec<DMatrix<f64>>) {
    let mut jac = vec![Vector3::zeros(); model.params.len()];
    let (mut errors, mut jacobians) = (Vec::new(), Vec::new());
    for s in samples {
        for (m, y) in s.points.iter().enumerate() {
            let Some(y) = y else { continue };
            let p = model.marker_jacobian(m, &s.state, &mut jac);
            errors.push(p - y);
            jacobians.push(DMatrix::from_fn(3, params.len(), |r, c| {
                params[c].map_or(0.0, |g| jac[g][r])
            }));
        }
    }
    (errors, jacobians)
}

/// The coverage of the held-out `validation` samples by the calibration `full`: frames
/// refitted on them (joints held), `Sigma_p` the covariance of the identified joint
/// parameters times `variance_factor` (duplicated postures recounted), projected past the
/// refit's directions (the frames absorb what of it looks like a frame),
/// `noise_m` the per-axis noise (m). `None` without a covariance or when a predicted
/// covariance is not positive semi-definite.
pub(crate) fn held_out_coverage(
    full: &MarkerFit,
    validation: &[MarkerSample],
    opts: &FitOptions,
    variance_factor: f64,
    noise_m: f64,
    monitor: &dyn Monitor,
) -> Result<Option<Coverage>, IdentifyError> {
    let sol = &full.solution;
    let Some(cov) = sol.uncertainty.covariance.as_ref() else {
        return Ok(None);
    };
    let refit = refit_frames(&full.model, validation, opts, monitor)?;
    // The identified unknowns (columns of the covariance) as model parameters; frames none.
    let free = full.problem.free();
    let params: Vec<Option<usize>> = sol
        .free
        .iter()
        .map(|&k| {
            let g = free[k];
            matches!(
                full.model.params[g],
                HParam::Joint(..) | HParam::BaseCompliance(_)
            )
            .then_some(g)
        })
        .collect();
    // The frame unknowns the refit moved, after them.
    let refitted = refit.problem.free();
    let mut all = params.clone();
    all.extend(refit.solution.free.iter().map(|&k| Some(refitted[k])));
    let (errors, jacobians) = marker_errors_and_jacobians(&refit.model, &all, validation);
    let errors: Vec<Vector3<f64>> = errors.iter().map(|e| e * MM_PER_M).collect();
    let held = params.len();
    let split = |cols: std::ops::Range<usize>| -> Vec<DMatrix<f64>> {
        jacobians
            .iter()
            .map(|j| j.columns(cols.start, cols.len()) * MM_PER_M)
            .collect()
    };
    Ok(coverage_after_refit(
        &errors,
        &split(0..held),
        &split(held..all.len()),
        &(cov * variance_factor),
        noise_m * MM_PER_M,
        "training residual",
        "mm",
    ))
}

#[cfg(test)]
mod tests;
