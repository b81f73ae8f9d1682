//! The verdict of `pcr.identify` ([`crate::identify::verdict`]): convergence of every step,
//! degrees of freedom, distinct stage configurations, validation against the training range
//! of each stage and against the nominal model, parameters moved beyond their stated
//! uncertainties; standard deviations and `residual_std` recounted over distinct
//! configurations.

use super::identify::PcrCalibration;
use crate::identify::extrapolation::{JointAxis, out_of_range};
use crate::identify::verdict::{self, Facts, HeldOut};
use crate::measure::pcr::PcrMeasurement;
use crate::measure::pcr::prior::stage_duplicates;

/// The three stages as the verdict names them (positions in m, reported in mm).
fn stages() -> Vec<JointAxis> {
    (1..=3)
        .map(|k| JointAxis {
            name: format!("q{k}"),
            unit: "mm".into(),
            to_unit: 1e3,
            margin: 0.0,
        })
        .collect()
}

/// Judge `r` (identified from `measurements`, validated on `validation`; `uncertainty[k]`
/// the model file's stated uncertainty of parameter `k`, reported unit) and put the
/// verdict, its reasons and `dof` into it.
pub fn judge(
    measurements: &[PcrMeasurement],
    validation: Option<&[PcrMeasurement]>,
    uncertainty: &[f64],
    r: &mut PcrCalibration,
) {
    let free = r
        .parameters
        .iter()
        .filter(|p| p.report.identifiable)
        .count();
    let dof0 = r.residual_std.dof;
    let equations = dof0 + free;
    let mut dof = dof0;
    let dup = stage_duplicates(measurements);
    if dup.repeated() > 0 && dof0 > 0 {
        let sigma = r.residual_std.value.unwrap_or(f64::NAN);
        let ssr = sigma * sigma * dof0 as f64;
        let e = dup.effective(equations, free, ssr, sigma);
        dof = e.dof;
        r.residual_std.value = e.sigma;
        for p in &mut r.parameters {
            p.report.std = p.report.std.zip(e.std_factor).map(|(s, f)| s * f);
        }
    }
    if dof == 0 {
        r.residual_std.value = None;
    }
    r.residual_std.dof = dof;
    r.dof = dof;
    let train: Vec<&[f64]> = measurements.iter().map(|m| m.q.as_slice()).collect();
    let val: Vec<&[f64]> = validation
        .unwrap_or_default()
        .iter()
        .map(|m| m.q.as_slice())
        .collect();
    let params: Vec<_> = r.parameters.iter().map(|p| p.report.clone()).collect();
    let status = if r.steps.iter().all(|s| s.stop_reason.converged()) {
        "converged"
    } else {
        "not_converged"
    };
    let facts = Facts {
        status: status.into(),
        degenerate: None,
        equations,
        unknowns: free,
        dof,
        duplicates: Some(dup),
        extrapolation: out_of_range(&stages(), &train, &val),
        held_out: r.validation.as_ref().map(|v| HeldOut {
            nominal_rms: v.before.rms,
            calibrated_rms: v.after.rms,
            unit: "m".into(),
        }),
        moved: verdict::moved_parameters(&params, |k| uncertainty.get(k).copied()),
        prior_dominated: Vec::new(),
        units: Vec::new(),
        coverage: None,
    };
    r.assessment = verdict::assess(&facts);
}
