//! The drift policy of a `cell.verify` job (`drift`): after the verification, submit the
//! recalibration campaign when the compensated AP crosses a threshold or grew by a factor
//! over the first verification since the last calibration; otherwise record "within
//! tolerance". The service applies it ([`crate::service`]); the decision is here.

use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::run::JobError;

/// `drift` of a `cell.verify` job.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DriftPolicy {
    /// Recalibrate when the mean compensated AP is above this (mm).
    #[serde(default)]
    pub ap_threshold_mm: Option<f64>,
    /// ... or when it is above this factor times the baseline: the first verification
    /// since the cell's last calibration.
    #[serde(default)]
    pub growth_factor: Option<f64>,
    /// The job submitted to recalibrate (e.g. a `cell.trical_campaign` document).
    pub recalibrate: Value,
}

/// What the policy decided for one verification.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DriftDecision {
    /// `recalibrate` or `within_tolerance`.
    pub action: &'static str,
    /// Mean compensated AP of this verification (mm).
    pub ap_mm: f64,
    /// Baseline AP (mm), if a verification since the last calibration precedes this one.
    pub baseline_ap_mm: Option<f64>,
    /// Why, with the numbers.
    pub reason: String,
}

impl DriftPolicy {
    /// Check the policy: at least one positive criterion, a job document with a kind.
    pub fn validate(&self) -> Result<(), JobError> {
        let bad = |f: &str, v: f64| {
            JobError::invalid(
                format!("drift.{f}"),
                format!("{v} must be a positive number"),
            )
        };
        match (self.ap_threshold_mm, self.growth_factor) {
            (None, None) => {
                return Err(JobError::invalid(
                    "drift",
                    "give ap_threshold_mm (mm) or growth_factor (or both)",
                ));
            }
            (Some(v), _) if !(v.is_finite() && v > 0.0) => return Err(bad("ap_threshold_mm", v)),
            (_, Some(v)) if !(v.is_finite() && v > 1.0) => {
                return Err(JobError::invalid(
                    "drift.growth_factor",
                    format!("{v} must be a number above 1"),
                ));
            }
            _ => {}
        }
        if !self.recalibrate.get("kind").is_some_and(Value::is_string) {
            return Err(JobError::invalid(
                "drift.recalibrate",
                "must be a job document with a `kind`",
            ));
        }
        Ok(())
    }

    /// The decision for a verification of mean compensated AP `ap_mm`, after `baseline`.
    pub fn decide(&self, ap_mm: f64, baseline: Option<f64>) -> DriftDecision {
        let over = self.ap_threshold_mm.filter(|t| ap_mm > *t);
        let grown = match (self.growth_factor, baseline) {
            (Some(f), Some(b)) if ap_mm > f * b => Some((f, b)),
            _ => None,
        };
        let (action, reason) = match (over, grown) {
            (Some(t), _) => (
                "recalibrate",
                format!("AP {ap_mm:.4} mm is above the threshold {t} mm"),
            ),
            (None, Some((f, b))) => (
                "recalibrate",
                format!("AP {ap_mm:.4} mm grew more than {f} times the baseline {b:.4} mm"),
            ),
            (None, None) => (
                "within_tolerance",
                format!(
                    "AP {ap_mm:.4} mm is within tolerance{}{}",
                    self.ap_threshold_mm
                        .map(|t| format!(" (threshold {t} mm)"))
                        .unwrap_or_default(),
                    match (self.growth_factor, baseline) {
                        (Some(f), Some(b)) => format!(" (at most {f} x baseline {b:.4} mm)"),
                        _ => String::new(),
                    }
                ),
            ),
        };
        DriftDecision {
            action,
            ap_mm,
            baseline_ap_mm: baseline,
            reason,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn threshold_and_growth_decide_and_invalid_policies_name_the_field() {
        let p = DriftPolicy {
            ap_threshold_mm: Some(0.05),
            growth_factor: Some(3.0),
            recalibrate: serde_json::json!({"kind": "cell.trical_campaign"}),
        };
        assert_eq!(p.decide(0.02, Some(0.01)).action, "within_tolerance");
        assert_eq!(p.decide(0.051, None).action, "recalibrate");
        // 0.031 > 3 x 0.010 though below the threshold.
        let d = p.decide(0.031, Some(0.010));
        assert!(
            d.action == "recalibrate" && d.reason.contains("3 times"),
            "{d:?}"
        );
        let mut bad = p.clone();
        bad.growth_factor = Some(0.5);
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("drift.growth_factor")
        );
        bad = p.clone();
        bad.recalibrate = serde_json::json!({});
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("drift.recalibrate")
        );
        assert!(p.validate().is_ok());
    }
}
