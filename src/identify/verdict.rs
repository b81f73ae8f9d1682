//! The verdict of an identification: `accepted`, `review` or `rejected`, with the reasons
//! (a code and a sentence each). One pure rule set for every kind: a kind only fills the
//! [`Facts`] (status, degrees of freedom, equations per unknown, duplicated rows, validation
//! outside the training range, held-out error against the nominal model, parameters moved
//! far from nominal, prior-dominated parameters) and calls [`assess`].
//!
//! Rejected: degenerate, not converged, zero degrees of freedom, held-out error worse than
//! the nominal model's, unit mistakes. Review: fewer than [`MIN_EQUATIONS_PER_UNKNOWN`]
//! equations per identified unknown, duplicated or near-duplicated configurations, validation
//! outside the training range, a parameter moved more than [`MOVED_TOLERANCES`] tolerances from
//! nominal, prior-dominated parameters, held-out errors within their predicted 2 sigma less
//! often than [`super::coverage::MIN_COVERAGE`]. Accepted otherwise.

use std::borrow::Cow;

use serde::{Deserialize, Serialize};

pub use super::duplicates::{Duplicates, find_duplicates};
pub use super::extrapolation::{JointAxis, OutOfRange, out_of_range};

/// Fewer equations than this per identified unknown puts a result under review.
pub const MIN_EQUATIONS_PER_UNKNOWN: f64 = 2.0;

/// A model parameter that moved more than this many tolerances (its prior std, else
/// [`DEFAULT_TOLERANCE_MM`] / [`DEFAULT_TOLERANCE_DEG`]) from nominal puts a result under
/// review.
pub const MOVED_TOLERANCES: f64 = 5.0;

/// Tolerance of a length parameter without a prior (mm): 5 of them = 10 mm.
pub const DEFAULT_TOLERANCE_MM: f64 = 2.0;

/// Tolerance of an angle parameter without a prior (deg): 5 of them = 5 deg.
pub const DEFAULT_TOLERANCE_DEG: f64 = 1.0;

/// A parameter whose posterior variance is above this fraction of its prior variance is
/// prior-dominated: the data told less about it than the prior did.
pub const PRIOR_DOMINATED_FRACTION: f64 = 0.5;

/// Whether to use a calibration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Verdict {
    /// Use it.
    Accepted,
    /// Usable only after a person looked at the reasons.
    Review,
    /// Do not use it.
    Rejected,
}

impl Verdict {
    /// `accepted`, `review` or `rejected`.
    pub fn as_str(self) -> &'static str {
        match self {
            Verdict::Accepted => "accepted",
            Verdict::Review => "review",
            Verdict::Rejected => "rejected",
        }
    }

    /// The verdict of a result document's `verdict` field (`None` when absent or unknown).
    pub fn of_result(result: &serde_json::Value) -> Option<Verdict> {
        match result.get("verdict")?.as_str()? {
            "accepted" => Some(Verdict::Accepted),
            "review" => Some(Verdict::Review),
            "rejected" => Some(Verdict::Rejected),
            _ => None,
        }
    }

    /// Exit code of `calibd run`: 0 accepted, 3 review, 4 rejected.
    pub fn exit_code(self) -> i32 {
        match self {
            Verdict::Accepted => 0,
            Verdict::Review => 3,
            Verdict::Rejected => 4,
        }
    }
}

/// One reason of a verdict.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Reason {
    /// Stable code, e.g. `zero_dof`, `duplicates`, `extrapolation`.
    pub code: Cow<'static, str>,
    /// What was found, with the rows, joints, parameters and figures involved.
    pub message: String,
    /// The verdict this reason alone gives (`review` or `rejected`).
    pub severity: Verdict,
}

/// The verdict and its reasons (the result fields `verdict`, `reasons`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Assessment {
    /// The worst severity of the reasons; `accepted` with none.
    pub verdict: Verdict,
    /// Why, worst first.
    #[serde(default)]
    pub reasons: Vec<Reason>,
}

impl Assessment {
    /// An assessment of `reasons`: the worst severity, reasons sorted worst first (stable).
    pub fn of(mut reasons: Vec<Reason>) -> Self {
        reasons.sort_by(|a, b| b.severity.cmp(&a.severity));
        Self {
            verdict: reasons
                .first()
                .map(|r| r.severity)
                .unwrap_or(Verdict::Accepted),
            reasons,
        }
    }

    /// Whether a reason with `code` is present.
    pub fn has(&self, code: &str) -> bool {
        self.reasons.iter().any(|r| r.code == code)
    }
}

/// Held-out errors of the nominal and the calibrated model on the same validation set.
#[derive(Debug, Clone)]
pub struct HeldOut {
    /// RMS error of the starting (nominal) model.
    pub nominal_rms: f64,
    /// RMS error of the calibrated model.
    pub calibrated_rms: f64,
    /// Unit of both.
    pub unit: String,
}

/// A model parameter moved far from its nominal value.
#[derive(Debug, Clone)]
pub struct Moved {
    /// Parameter name.
    pub name: String,
    /// value - nominal (reported unit).
    pub moved: f64,
    /// The tolerance it is measured in (reported unit).
    pub tolerance: f64,
    /// Where the tolerance comes from: `prior std` or `default tolerance`.
    pub tolerance_from: &'static str,
    /// Its standard deviation, if known.
    pub std: Option<f64>,
    /// Reported unit.
    pub unit: String,
}

/// A unit mistake found in the inputs (e.g. joints in rad in a deg column).
#[derive(Debug, Clone)]
pub struct UnitMistake {
    /// `rejected` when nothing usable can come of it, `review` when it only looks suspicious.
    pub severity: Verdict,
    /// What looks wrong and where.
    pub message: String,
}

/// What a kind knows about its identification; [`assess`] turns it into a verdict.
#[derive(Debug, Clone, Default)]
pub struct Facts {
    /// `convergence.status`: `converged`, `degenerate`, `not_converged`.
    pub status: String,
    /// Why degenerate, when it is.
    pub degenerate: Option<String>,
    /// Measurement equations (residual rows, without prior rows).
    pub equations: usize,
    /// Identified (free) unknowns.
    pub unknowns: usize,
    /// Residual degrees of freedom (equations - identified unknowns).
    pub dof: usize,
    /// Duplicated configurations among the calibration rows.
    pub duplicates: Option<Duplicates>,
    /// Joints whose validation range leaves the training range.
    pub extrapolation: Vec<OutOfRange>,
    /// Held-out error of the nominal and the calibrated model.
    pub held_out: Option<HeldOut>,
    /// Model parameters moved more than [`MOVED_TOLERANCES`] tolerances.
    pub moved: Vec<Moved>,
    /// Parameters the prior determined more than the data (names).
    pub prior_dominated: Vec<String>,
    /// Unit mistakes in the inputs.
    pub units: Vec<UnitMistake>,
    /// Coverage of the held-out errors by their predicted 2 sigma.
    pub coverage: Option<super::coverage::Coverage>,
}

/// `dof` of a result: equations minus identified unknowns (0 when not more).
pub fn dof(equations: usize, unknowns: usize) -> usize {
    equations.saturating_sub(unknowns)
}

fn reason(code: &'static str, severity: Verdict, message: String) -> Reason {
    Reason {
        code: code.into(),
        message,
        severity,
    }
}

fn list(names: &[String], most: usize) -> String {
    let mut s = names
        .iter()
        .take(most)
        .cloned()
        .collect::<Vec<_>>()
        .join(", ");
    if names.len() > most {
        s.push_str(&format!(" and {} more", names.len() - most));
    }
    s
}

/// The verdict and reasons of an identification from its facts.
pub fn assess(f: &Facts) -> Assessment {
    use Verdict::{Rejected, Review};
    let mut out = Vec::new();
    for u in &f.units {
        out.push(reason("units", u.severity, u.message.clone()));
    }
    match f.status.as_str() {
        "converged" => {}
        "degenerate" => out.push(reason(
            "degenerate",
            Rejected,
            format!(
                "the identification is degenerate{}: the calibrated model cannot be trusted",
                f.degenerate
                    .as_deref()
                    .map(|d| format!(" ({d})"))
                    .unwrap_or_default()
            ),
        )),
        other => out.push(reason(
            "not_converged",
            Rejected,
            format!("the solver did not converge (status `{other}`)"),
        )),
    }
    if f.dof == 0 {
        out.push(reason(
            "zero_dof",
            Rejected,
            format!(
                "{} equations for {} identified unknowns leave zero degrees of freedom: the \
                 fit is exact whatever the errors, so nothing can be checked and residual_std \
                 is undefined; measure more configurations",
                f.equations, f.unknowns
            ),
        ));
    } else if f.unknowns > 0 {
        let per = f.equations as f64 / f.unknowns as f64;
        if per < MIN_EQUATIONS_PER_UNKNOWN {
            out.push(reason(
                "few_equations",
                Review,
                format!(
                    "{} equations for {} identified unknowns ({per:.2} per unknown, fewer than \
                     {MIN_EQUATIONS_PER_UNKNOWN}): errors in the data are barely visible in the \
                     residuals; measure more configurations",
                    f.equations, f.unknowns
                ),
            ));
        }
    }
    if let Some(d) = f.duplicates.as_ref().filter(|d| d.repeated() > 0) {
        out.push(reason("duplicates", Review, d.message()));
    }
    for e in &f.extrapolation {
        out.push(reason("extrapolation", Review, e.message()));
    }
    if let Some(h) = &f.held_out
        && h.calibrated_rms > h.nominal_rms
    {
        out.push(reason(
            "worse_than_nominal",
            Rejected,
            format!(
                "on the held-out validation set the calibrated model is worse than the \
                 nominal one: RMS {:.4} {u} against {:.4} {u}",
                h.calibrated_rms,
                h.nominal_rms,
                u = h.unit
            ),
        ));
    }
    for m in &f.moved {
        let std = m
            .std
            .map(|s| format!(", std {s:.4} {}", m.unit))
            .unwrap_or_default();
        out.push(reason(
            "moved",
            Review,
            format!(
                "{} moved {:+.4} {u} from nominal, {:.1} times its {} ({:.4} {u}){std}: check \
                 the nominal model, the frames and the data before using it",
                m.name,
                m.moved,
                m.moved.abs() / m.tolerance,
                m.tolerance_from,
                m.tolerance,
                u = m.unit
            ),
        ));
    }
    if !f.prior_dominated.is_empty() {
        out.push(reason(
            "prior_dominated",
            Review,
            format!(
                "{} parameter(s) are determined more by the prior than by the data (posterior \
                 variance above {:.0} % of the prior's): {}; their values are the prior's guess",
                f.prior_dominated.len(),
                100.0 * PRIOR_DOMINATED_FRACTION,
                list(&f.prior_dominated, 8)
            ),
        ));
    }
    if let Some(c) = f.coverage.as_ref().filter(|c| c.optimistic()) {
        out.push(reason(
            "noise_model_optimistic",
            Review,
            format!(
                "{} of {} held-out errors ({:.1} %) lie within their predicted 2 sigma \
                 (expected {:.1} %, at least {:.0} %): the noise model (noise std {:.4} {} from \
                 {}) and the parameter covariance are too optimistic; the standard deviations \
                 understate the real uncertainty",
                c.points.iter().filter(|p| p.within_2sigma).count(),
                c.n,
                100.0 * c.fraction_within_2sigma,
                100.0 * c.expected,
                100.0 * super::coverage::MIN_COVERAGE,
                c.noise_std,
                c.unit,
                c.noise_from
            ),
        ));
    }
    Assessment::of(out)
}

/// Model parameters moved more than [`MOVED_TOLERANCES`] tolerances from nominal. `params`
/// are the result's parameter lines of the model (not nuisance unknowns); `prior_std` gives
/// a parameter's prior std in its reported unit, if it has one. Without one the tolerance is
/// [`DEFAULT_TOLERANCE_MM`] for `mm`/`m` and [`DEFAULT_TOLERANCE_DEG`] for `deg`/`rad`;
/// other units (compliances) are not judged.
pub fn moved_parameters(
    params: &[super::ParamReport],
    prior_std: impl Fn(usize) -> Option<f64>,
) -> Vec<Moved> {
    params
        .iter()
        .enumerate()
        .filter(|(_, p)| p.identifiable)
        .filter_map(|(k, p)| {
            let (tolerance, from) = match prior_std(k) {
                Some(s) if s > 0.0 && s.is_finite() => (s, "prior std"),
                _ => (
                    match p.unit.as_str() {
                        "mm" => DEFAULT_TOLERANCE_MM,
                        "m" => DEFAULT_TOLERANCE_MM * 1e-3,
                        "deg" => DEFAULT_TOLERANCE_DEG,
                        "rad" => DEFAULT_TOLERANCE_DEG.to_radians(),
                        _ => return None,
                    },
                    "default tolerance",
                ),
            };
            let moved = p.value - p.nominal;
            (moved.abs() > MOVED_TOLERANCES * tolerance).then(|| Moved {
                name: p.name.clone(),
                moved,
                tolerance,
                tolerance_from: from,
                std: p.std,
                unit: p.unit.clone(),
            })
        })
        .collect()
}

/// Names of the parameters whose posterior std exceeds `sqrt(PRIOR_DOMINATED_FRACTION)`
/// times their effective prior std (`prior_std(k)`, reported unit; `None` without a prior).
pub fn prior_dominated(
    params: &[super::ParamReport],
    prior_std: impl Fn(usize) -> Option<f64>,
) -> Vec<String> {
    params
        .iter()
        .enumerate()
        .filter_map(|(k, p)| {
            let (s, post) = (prior_std(k)?, p.std?);
            (s > 0.0 && post * post > PRIOR_DOMINATED_FRACTION * s * s).then(|| p.name.clone())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn converged(equations: usize, unknowns: usize) -> Facts {
        Facts {
            status: "converged".into(),
            equations,
            unknowns,
            dof: dof(equations, unknowns),
            ..Default::default()
        }
    }

    #[test]
    fn a_clean_fit_is_accepted() {
        let a = assess(&converged(300, 31));
        assert_eq!(a.verdict, Verdict::Accepted);
        assert!(a.reasons.is_empty());
    }

    #[test]
    fn zero_dof_is_rejected_and_says_why() {
        let a = assess(&converged(15, 15));
        assert_eq!(a.verdict, Verdict::Rejected);
        assert!(a.has("zero_dof"), "{a:?}");
        assert!(a.reasons[0].message.contains("15 equations"));
    }

    #[test]
    fn degenerate_and_not_converged_are_rejected() {
        let mut f = converged(300, 31);
        f.status = "degenerate".into();
        f.degenerate = Some("a2 moved 912 m".into());
        let a = assess(&f);
        assert_eq!(a.verdict, Verdict::Rejected);
        assert!(a.reasons[0].message.contains("a2 moved 912 m"));
        f.status = "not_converged".into();
        assert!(assess(&f).has("not_converged"));
    }

    #[test]
    fn few_equations_per_unknown_is_review() {
        let a = assess(&converged(45, 31));
        assert_eq!(a.verdict, Verdict::Review);
        assert!(a.has("few_equations"));
        assert_eq!(assess(&converged(62, 31)).verdict, Verdict::Accepted);
    }

    #[test]
    fn held_out_worse_than_nominal_is_rejected() {
        let mut f = converged(3000, 31);
        f.held_out = Some(HeldOut {
            nominal_rms: 9.54,
            calibrated_rms: 14.13,
            unit: "mm".into(),
        });
        let a = assess(&f);
        assert_eq!(a.verdict, Verdict::Rejected);
        assert!(a.reasons[0].message.contains("14.13"), "{a:?}");
        f.held_out = Some(HeldOut {
            nominal_rms: 9.54,
            calibrated_rms: 1.0,
            unit: "mm".into(),
        });
        assert_eq!(assess(&f).verdict, Verdict::Accepted);
    }

    #[test]
    fn reasons_are_sorted_worst_first() {
        let mut f = converged(40, 31);
        f.status = "degenerate".into();
        let a = assess(&f);
        assert_eq!(a.verdict, Verdict::Rejected);
        assert_eq!(a.reasons[0].code, "degenerate");
        assert_eq!(
            a.reasons.last().map(|r| r.code.as_ref()),
            Some("few_equations")
        );
    }

    fn param(
        name: &str,
        unit: &str,
        nominal: f64,
        value: f64,
        std: f64,
    ) -> super::super::ParamReport {
        super::super::ParamReport {
            name: name.into(),
            unit: unit.into(),
            nominal,
            value,
            std: Some(std),
            identifiable: true,
            effect_size: 1.0,
            at_bound: None,
        }
    }

    #[test]
    fn moved_parameters_use_the_prior_else_the_default_tolerance() {
        let p = [
            param("a2", "mm", 270.0, 270.5, 0.001),
            param("joint_a1.x", "m", 0.0, 0.54, 0.01),
            param("alpha1", "deg", -90.0, -78.0, 6.0),
        ];
        let none = moved_parameters(&p, |_| None);
        let names: Vec<&str> = none.iter().map(|m| m.name.as_str()).collect();
        assert_eq!(names, ["joint_a1.x", "alpha1"]);
        // A prior std of 0.05 mm on a2: 0.5 mm is 10 of them.
        let with = moved_parameters(&p, |k| (k == 0).then_some(0.05));
        assert_eq!(with[0].name, "a2");
        assert_eq!(with[0].tolerance_from, "prior std");
        let a = assess(&Facts {
            moved: with,
            ..converged(300, 31)
        });
        assert_eq!(a.verdict, Verdict::Review);
        assert!(
            a.reasons[0].message.starts_with("a2 moved +0.5000 mm"),
            "{a:?}"
        );
    }

    #[test]
    fn prior_dominated_parameters_are_review() {
        let p = [
            param("a2", "mm", 0.0, 0.1, 0.45),
            param("d4", "mm", 0.0, 0.1, 0.05),
        ];
        let names = prior_dominated(&p, |_| Some(0.5));
        assert_eq!(names, ["a2"]);
        let a = assess(&Facts {
            prior_dominated: names,
            ..converged(300, 31)
        });
        assert_eq!(a.verdict, Verdict::Review);
        assert!(a.has("prior_dominated"));
    }

    #[test]
    fn exit_codes_follow_the_verdict() {
        assert_eq!(Verdict::Accepted.exit_code(), 0);
        assert_eq!(Verdict::Review.exit_code(), 3);
        assert_eq!(Verdict::Rejected.exit_code(), 4);
        let r = serde_json::json!({"verdict": "review"});
        assert_eq!(Verdict::of_result(&r), Some(Verdict::Review));
        assert_eq!(Verdict::of_result(&serde_json::json!({})), None);
    }
}
