//! The verdict of `serial.identify` ([`crate::identify::verdict`]): the facts of a serial
//! identification (rows, distinct configurations, degrees of freedom, held-out errors,
//! joints beyond the training range, moved and prior-dominated parameters), and the
//! standard deviations and `residual_std` recounted over distinct configurations.

use crate::identify::extrapolation::{JointAxis, out_of_range};
use crate::identify::verdict::{self, Facts, HeldOut, UnitMistake, Verdict};
use crate::identify::{Solution, Unknown};
use crate::measure::Target;
use crate::model::Chain;
use crate::model::params::Quantity;

use super::identify_inputs::IdentifyInputs;
use super::identify_result::SerialCalibration;

/// The joint axes of a chain as the verdict names them: `q1 (name)`, ...
pub fn joint_axes(chain: &Chain) -> Vec<JointAxis> {
    chain
        .actuated()
        .iter()
        .enumerate()
        .map(|(k, &j)| {
            let name = format!("q{} ({})", k + 1, chain.joints[j].name);
            match chain.variable_quantity(k) {
                Quantity::Length => JointAxis::prismatic(name, chain.units.name(Quantity::Length)),
                _ => JointAxis::revolute(name),
            }
        })
        .collect()
}

/// Largest joint value (rad) of a table whose joint columns are all in degrees yet hold
/// what look like radians: every value within 2 pi "deg" = 0.11 rad.
const RADIANS_IN_DEG: f64 = 2.0 * std::f64::consts::PI * std::f64::consts::PI / 180.0;

/// Largest coordinate (model length unit) of Cartesian targets or distances that look like
/// metres in a millimetre column: an arm's workspace spans hundreds of millimetres.
const METRES_IN_MM: f64 = 5.0;

/// Unit mistakes that make the calibration meaningless (rejected): joints in radians in
/// degree columns (every revolute value of every row within 2 pi degrees), Cartesian
/// targets or distances in metres in millimetre columns (every value within 5 mm).
pub fn unit_mistakes(inp: &IdentifyInputs) -> Vec<UnitMistake> {
    let mut out = Vec::new();
    let chain = &inp.model.chain;
    let rows = inp.rows();
    let revolute: Vec<usize> = (0..chain.actuated().len())
        .filter(|&k| chain.variable_quantity(k) == Quantity::Angle)
        .collect();
    let deg = chain.units.name(Quantity::Angle) == "deg";
    if deg && rows.len() >= 3 && !revolute.is_empty() {
        let largest = rows
            .iter()
            .flat_map(|(q, _)| revolute.iter().filter_map(|&k| q.get(k)))
            .fold(0.0f64, |a, v| a.max(v.abs()));
        if largest <= RADIANS_IN_DEG {
            out.push(UnitMistake {
                severity: Verdict::Rejected,
                message: format!(
                    "every joint value of the {} rows lies within {:.2} deg: the joint columns                      are in degrees but these look like radians; convert them (deg = rad *                      180 / pi)",
                    rows.len(),
                    largest.to_degrees()
                ),
            });
        }
    }
    if inp.model.length_unit() == "mm" {
        let points: Vec<f64> = inp
            .meas
            .iter()
            .filter_map(|m| match m.target {
                Target::Point(p) => Some(p.amax()),
                Target::Ball(_) => None,
            })
            .collect();
        let lengths: Vec<f64> = inp.distances.iter().map(|d| d.length.abs()).collect();
        for (what, v) in [("x, y, z", points), ("L_mm", lengths)] {
            let largest = v.iter().fold(0.0f64, |a, b| a.max(*b));
            if v.len() >= 3 && largest <= METRES_IN_MM {
                out.push(UnitMistake {
                    severity: Verdict::Rejected,
                    message: format!(
                        "every {what} value of the {} rows lies within {largest:.3} mm: the                          columns are in millimetres but these look like metres; multiply by 1000",
                        v.len()
                    ),
                });
            }
        }
    }
    out
}

/// Equations per calibration row: 3 for points and balls, 1 for distances.
fn per_row(inp: &IdentifyInputs) -> usize {
    if inp.distances.is_empty() { 3 } else { 1 }
}

/// Judge a serial calibration `r` of `sol` (unknowns `unknowns`, the model's first) and
/// put the verdict, its reasons and `dof` into it; with duplicated rows, the standard
/// deviations and `residual_std` are recounted over distinct configurations first. With the
/// `calibrated` chain of point measurements, the validation's `coverage` is added too.
pub fn judge(
    inp: &IdentifyInputs,
    sol: &Solution,
    unknowns: &[Unknown],
    nuisance: &[usize],
    prior_weight: Option<f64>,
    calibrated: Option<&Chain>,
    r: &mut SerialCalibration,
) {
    let dup = inp.duplicates();
    let n_rows = dup.rows;
    let equations = per_row(inp) * n_rows;
    let free = sol.free.len();
    let mut dof = verdict::dof(equations, free);
    let mut variance_factor = 1.0;
    if dup.repeated() > 0 {
        let ssr: f64 = sol.residuals.iter().take(equations).map(|v| v * v).sum();
        let e = dup.effective(equations, free, ssr, sol.uncertainty.sigma);
        dof = e.dof;
        r.residual_std.value = e.sigma;
        variance_factor = e.std_factor.map_or(f64::NAN, |f| f * f);
        for p in &mut r.parameters {
            p.std = match (p.std, e.std_factor) {
                (Some(s), Some(f)) => Some(s * f),
                _ => None,
            };
        }
    }
    if dof == 0 {
        r.residual_std.value = None;
    }
    r.residual_std.dof = dof;
    r.dof = dof;
    r.coverage = calibrated.and_then(|c| {
        super::coverage::point_coverage(inp, sol, c, variance_factor, r.residual_std.value)
    });
    // Validation rows beyond the training range, per joint.
    let train: Vec<&[f64]> = inp.rows().into_iter().map(|(q, _)| q).collect();
    let val: Vec<&[f64]> = match (&inp.validation, &inp.validation_distances) {
        (_, Some(v)) => v.iter().map(|d| d.q.as_slice()).collect(),
        (Some(v), None) => v.iter().map(|m| m.q.as_slice()).collect(),
        (None, None) => Vec::new(),
    };
    let extrapolation = out_of_range(&joint_axes(&inp.model.chain), &train, &val);
    let held_out = r.validation.as_ref().map(|v| HeldOut {
        nominal_rms: v.before.rms,
        calibrated_rms: v.after.rms,
        unit: v.after.unit.clone(),
    });
    // Prior std per unknown in reported units (the effective one, sigma / sqrt(weight),
    // for the prior-dominated test).
    let prior: Vec<Option<f64>> = match &inp.options.prior {
        Some(spec) => spec
            .sigmas(unknowns, |k| k < inp.ids.len())
            .unwrap_or_default()
            .into_iter()
            .zip(unknowns)
            .map(|(s, u)| s.map(|s| s * u.to_report))
            .collect(),
        None => Vec::new(),
    };
    let prior_at = |k: usize| prior.get(k).copied().flatten();
    let model: Vec<_> = r
        .parameters
        .iter()
        .take(inp.ids.len())
        .enumerate()
        .filter(|(k, _)| !nuisance.contains(k))
        .map(|(_, p)| p.clone())
        .collect();
    let model_index: Vec<usize> = (0..inp.ids.len().min(r.parameters.len()))
        .filter(|k| !nuisance.contains(k))
        .collect();
    let moved = verdict::moved_parameters(&model, |i| prior_at(model_index[i]));
    let prior_dominated = match prior_weight.filter(|w| *w > 0.0) {
        Some(w) => verdict::prior_dominated(&r.parameters, |k| prior_at(k).map(|s| s / w.sqrt())),
        None => Vec::new(),
    };
    let units = unit_mistakes(inp);
    let facts = Facts {
        status: sol.status().to_string(),
        degenerate: sol.degenerate.as_ref().map(|d| d.reasons.join("; ")),
        equations,
        unknowns: free,
        dof,
        duplicates: Some(dup),
        extrapolation,
        held_out,
        moved,
        prior_dominated,
        units,
        coverage: r.coverage.clone(),
    };
    r.assessment = verdict::assess(&facts);
}

#[cfg(test)]
mod tests;
