//! Model decisions: a campaign proposes its calibrated model as a [`Candidate`] with the
//! evidence of a validation (an error before and after) and the identification's verdict;
//! the cell's [`Acceptance`] rule makes it the current model or records it as rejected, with
//! the reason. A model whose identification was rejected never becomes current, however its
//! validation went; one under review may, and the decision repeats the reasons. The service
//! writes the decision in the same transaction as the job's final state.

use serde_json::Value;

use super::CellModel;
use crate::identify::verdict::{Assessment, Verdict};

/// Validation evidence: a mean error of the starting and of the calibrated model.
#[derive(Debug, Clone, PartialEq)]
pub struct Evidence {
    /// What was measured, e.g. "validation mean position error".
    pub what: String,
    /// Error of the model the campaign started from.
    pub before: f64,
    /// Error of the calibrated model.
    pub after: f64,
    /// Unit of both (`mm`, `m`).
    pub unit: &'static str,
}

/// A calibrated model proposed for a cell.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    /// The cell.
    pub cell: String,
    /// The calibrated model.
    pub model: CellModel,
    /// Validation figures, if the campaign validated.
    pub evidence: Option<Evidence>,
    /// The validation document kept in the cell's history.
    pub validation: Value,
    /// The identification's verdict and reasons (`None` for steps that are not an
    /// identification, e.g. commissioning).
    pub assessment: Option<Assessment>,
}

/// When a candidate replaces a cell's model: it must gain more than `min_relative_gain`
/// of the starting error and more than `min_gain` (below it a difference is measurement
/// noise).
#[derive(Debug, Clone, PartialEq)]
pub struct Acceptance {
    /// Smallest relative gain (0.1 = 10 %).
    pub min_relative_gain: f64,
    /// Smallest absolute gain, in `unit`.
    pub min_gain: f64,
    /// Unit of `min_gain` (the evidence must be in the same unit).
    pub unit: &'static str,
}

/// The decision on a candidate.
#[derive(Debug, Clone, PartialEq)]
pub struct Decision {
    /// The cell.
    pub cell: String,
    /// Whether the candidate became the current model.
    pub accepted: bool,
    /// Why, with the figures.
    pub reason: String,
    /// The validation document.
    pub validation: Value,
    /// The model, as stored.
    pub model: Value,
}

impl Acceptance {
    /// Decide on `c`.
    pub fn decide(&self, c: &Candidate) -> Decision {
        let reasons = |a: &Assessment| {
            a.reasons
                .iter()
                .map(|r| format!("{}: {}", r.code, r.message))
                .collect::<Vec<_>>()
                .join("; ")
        };
        if let Some(a) = c
            .assessment
            .as_ref()
            .filter(|a| a.verdict == Verdict::Rejected)
        {
            return Decision {
                cell: c.cell.clone(),
                accepted: false,
                reason: format!("the calibration was rejected: {}", reasons(a)),
                validation: c.validation.clone(),
                model: c.model.to_json(),
            };
        }
        let (accepted, mut reason) = match &c.evidence {
            Some(e) if e.unit != self.unit => (
                false,
                format!(
                    "the validation is in {} but the cell's rule is in {}",
                    e.unit, self.unit
                ),
            ),
            Some(e) if !(e.before.is_finite() && e.after.is_finite()) => (
                false,
                format!("{}: not a number ({} -> {})", e.what, e.before, e.after),
            ),
            Some(e)
                if e.before - e.after > (self.min_relative_gain * e.before).max(self.min_gain) =>
            {
                (
                    true,
                    format!(
                        "{} improved from {} {u} (starting model) to {} {u}",
                        e.what,
                        sig4(e.before),
                        sig4(e.after),
                        u = e.unit
                    ),
                )
            }
            Some(e) => (
                false,
                format!(
                    "validation did not improve enough: {} {} {u} against {} {u} for the starting model (a candidate must gain more than {:.0} % and {} {u})",
                    e.what,
                    sig4(e.after),
                    sig4(e.before),
                    100.0 * self.min_relative_gain,
                    sig4(self.min_gain),
                    u = e.unit
                ),
            ),
            None => (
                false,
                "the campaign had no validation pass: nothing shows the model is better".into(),
            ),
        };
        if let Some(a) = c
            .assessment
            .as_ref()
            .filter(|a| a.verdict == Verdict::Review)
        {
            reason.push_str(&format!(" (verdict review: {})", reasons(a)));
        }
        Decision {
            cell: c.cell.clone(),
            accepted,
            reason,
            validation: c.validation.clone(),
            model: c.model.to_json(),
        }
    }
}

/// `v` with four significant digits, whatever its magnitude (a PCR error of 1.2e-6 m must
/// not print as `0.0000`): plain decimals from 1e-3 to 1e6, scientific notation outside.
fn sig4(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let magnitude = v.abs().log10().floor();
    if (-3.0..6.0).contains(&magnitude) {
        format!("{:.*}", (3.0 - magnitude).max(0.0) as usize, v)
    } else {
        format!("{v:.3e}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn figures_keep_four_significant_digits() {
        assert_eq!(sig4(1.5234e-6), "1.523e-6");
        assert_eq!(sig4(0.0049), "0.004900");
        assert_eq!(sig4(1.5234), "1.523");
        assert_eq!(sig4(1234.4), "1234");
        assert_eq!(sig4(0.0), "0");
        let rule = Acceptance {
            min_relative_gain: 0.1,
            min_gain: 1e-7,
            unit: "m",
        };
        let mut c = candidate(3.2e-6, 1.1e-6);
        if let Some(e) = c.evidence.as_mut() {
            e.unit = "m";
        }
        let d = rule.decide(&c);
        assert!(d.accepted, "{d:?}");
        assert!(
            d.reason.contains("from 3.200e-6 m") && d.reason.contains("to 1.100e-6 m"),
            "{}",
            d.reason
        );
    }

    fn candidate(before: f64, after: f64) -> Candidate {
        Candidate {
            cell: "c".into(),
            model: CellModel::Humanoid("<robot/>".into()),
            evidence: Some(Evidence {
                what: "validation mean error".into(),
                before,
                after,
                unit: "mm",
            }),
            validation: Value::Null,
            assessment: None,
        }
    }

    #[test]
    fn a_gain_must_beat_both_the_relative_and_the_absolute_threshold() {
        let rule = Acceptance {
            min_relative_gain: 0.1,
            min_gain: 0.002,
            unit: "mm",
        };
        assert!(rule.decide(&candidate(0.100, 0.050)).accepted);
        // 5 % is below 10 %.
        assert!(!rule.decide(&candidate(0.100, 0.095)).accepted);
        // 50 % of a tiny error is below the absolute threshold.
        assert!(!rule.decide(&candidate(0.003, 0.0015)).accepted);
        let mut c = candidate(0.1, 0.01);
        c.evidence = None;
        let d = rule.decide(&c);
        assert!(!d.accepted && d.reason.contains("no validation"), "{d:?}");
        let mut c = candidate(0.1, 0.01);
        if let Some(e) = c.evidence.as_mut() {
            e.unit = "m";
        }
        assert!(!rule.decide(&c).accepted);
    }

    #[test]
    fn a_rejected_calibration_never_becomes_current_and_review_says_why() {
        use crate::identify::verdict::Reason;
        let rule = Acceptance {
            min_relative_gain: 0.1,
            min_gain: 0.002,
            unit: "mm",
        };
        let reason = |severity| Reason {
            code: "zero_dof".into(),
            message: "15 equations for 15 identified unknowns".into(),
            severity,
        };
        let mut c = candidate(0.100, 0.050);
        c.assessment = Some(Assessment::of(vec![reason(Verdict::Rejected)]));
        let d = rule.decide(&c);
        assert!(!d.accepted, "{d:?}");
        assert!(
            d.reason.contains("rejected: zero_dof: 15 equations"),
            "{d:?}"
        );
        c.assessment = Some(Assessment::of(vec![reason(Verdict::Review)]));
        let d = rule.decide(&c);
        assert!(d.accepted && d.reason.contains("verdict review"), "{d:?}");
        c.assessment = Some(Assessment::of(Vec::new()));
        assert!(rule.decide(&c).accepted);
    }
}
