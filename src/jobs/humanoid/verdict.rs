//! The verdict of `humanoid.identify` ([`crate::identify::verdict`]): marker equations,
//! distinct postures, degrees of freedom, the K-fold held-out error against the frames-only
//! model, moved and prior-dominated joint parameters; standard deviations and the residual
//! std recounted over distinct postures.

use super::identify_result::{CrossValidation, HumanoidCalibration};
use crate::identify::coverage::Coverage;
use crate::identify::duplicates::duplicate_configurations;
use crate::identify::verdict::{self, Facts, HeldOut};
use crate::measure::marker_fit::{FitOptions, MarkerFit};
use crate::measure::markers::MarkerSample;
use crate::model::humanoid::HParam;
use crate::run::JobError;

/// The held-out coverage given the parameter covariance's factor (duplicated postures
/// recounted) and the per-axis noise (m, `None` with zero degrees of freedom).
pub type HeldOutCoverage<'a> = dyn Fn(f64, Option<f64>) -> Result<Option<Coverage>, JobError> + 'a;

/// Judge the calibration `r` of `full` on `samples` and put the verdict, its reasons, `dof`
/// and the held-out `coverage` into it (standard deviations and `residual_std_mm` recounted
/// over distinct postures when some repeat).
pub fn judge(
    samples: &[MarkerSample],
    full: &MarkerFit,
    opts: &FitOptions,
    cv: Option<&CrossValidation>,
    coverage: &HeldOutCoverage<'_>,
    r: &mut HumanoidCalibration,
) -> Result<(), JobError> {
    let sol = &full.solution;
    let equations: usize = 3 * samples
        .iter()
        .map(|s| s.points.iter().flatten().count())
        .sum::<usize>();
    let free = sol.free.len();
    let dup = duplicate_configurations(samples.iter().map(|s| s.state.q.as_slice()));
    let mut dof = verdict::dof(equations, free);
    let mut sigma_m = Some(sol.uncertainty.sigma).filter(|s| s.is_finite());
    let mut variance_factor = 1.0;
    if dup.repeated() > 0 {
        let ssr: f64 = sol.residuals.iter().take(equations).map(|v| v * v).sum();
        let e = dup.effective(equations, free, ssr, sol.uncertainty.sigma);
        dof = e.dof;
        sigma_m = e.sigma;
        for p in &mut r.parameters {
            p.std = p.std.zip(e.std_factor).map(|(s, f)| s * f);
        }
        variance_factor = e.std_factor.map_or(f64::NAN, |f| f * f);
    }
    if dof == 0 {
        sigma_m = None;
    }
    r.residual_std_mm = sigma_m.map(|s| s * 1e3);
    r.coverage = if variance_factor.is_finite() {
        coverage(variance_factor, sigma_m)?
    } else {
        None
    };
    r.dof = dof;
    let is_model = |k: usize| {
        full.problem.free().get(k).is_some_and(|&i| {
            matches!(
                full.model.params[i],
                HParam::Joint(..) | HParam::BaseCompliance(_)
            )
        })
    };
    let unknowns = full.problem.unknowns();
    // Prior std per unknown (reported unit), from the job's prior.
    let prior: Vec<Option<f64>> = opts
        .prior
        .as_ref()
        .and_then(|map| map.spec.sigmas(&unknowns, is_model).ok())
        .map(|s| {
            s.into_iter()
                .zip(&unknowns)
                .map(|(s, u)| s.map(|s| s * u.to_report))
                .collect()
        })
        .unwrap_or_default();
    let prior_at = |k: usize| prior.get(k).copied().flatten();
    let model_index: Vec<usize> = (0..r.parameters.len()).filter(|&k| is_model(k)).collect();
    let model: Vec<_> = model_index
        .iter()
        .map(|&k| r.parameters[k].clone())
        .collect();
    let moved = verdict::moved_parameters(&model, |i| prior_at(model_index[i]));
    let prior_dominated = match r.prior.weight.filter(|w| *w > 0.0) {
        Some(w) => verdict::prior_dominated(&r.parameters, |k| prior_at(k).map(|s| s / w.sqrt())),
        None => Vec::new(),
    };
    let facts = Facts {
        status: sol.status().to_string(),
        degenerate: sol.degenerate.as_ref().map(|d| d.reasons.join("; ")),
        equations,
        unknowns: free,
        dof,
        duplicates: Some(dup),
        extrapolation: Vec::new(),
        held_out: cv.map(|cv| HeldOut {
            nominal_rms: cv.rmse_nominal_mm,
            calibrated_rms: cv.rmse_calibrated_mm,
            unit: "mm (K-fold held out; nominal: frames-only fit)".into(),
        }),
        moved,
        prior_dominated,
        units: Vec::new(),
        coverage: r.coverage.clone(),
    };
    r.assessment = verdict::assess(&facts);
    Ok(())
}
