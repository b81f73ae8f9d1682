//! Who measured: each device of a campaign's cell as it identified itself (the robot's
//! controller, the receivers, the microscope, ...), kept in the result for the report;
//! and the pass/fail of a calibration against the tolerance its job declared.

use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::lab::{DeviceLink, DeviceStatus};
use crate::report::view::{Cell, Facts, Num};
use crate::run::JobError;

/// One device of the cell at the campaign's start.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Instrument {
    /// Device name (`cell.role`).
    pub device: String,
    /// What it is (e.g. `ABB IRC5 (RWS 1.0)`).
    pub kind: String,
    /// Where it was reached.
    pub address: String,
    /// What it said about itself (as `calibd lab check` prints it), or why it did not.
    pub identity: String,
    /// When it said so (RFC 3339, UTC).
    pub checked_at: String,
}

/// The cell's devices as they identified themselves: the last check, probed now (within
/// `timeout`) when the device was not checked yet or its last check failed.
pub async fn identify(links: &[DeviceLink], timeout: Duration) -> Vec<Instrument> {
    let mut out = Vec::with_capacity(links.len());
    for l in links {
        let status = match l.status() {
            s @ DeviceStatus::Ok { .. } => s,
            _ => l.check(timeout).await,
        };
        let (identity, checked_at) = match status {
            DeviceStatus::Ok {
                identity,
                checked_at,
            } => (identity.summary, checked_at),
            DeviceStatus::Failed {
                error, checked_at, ..
            } => (format!("no identity: {error}"), checked_at),
            DeviceStatus::Unchecked => ("not checked".into(), String::new()),
        };
        out.push(Instrument {
            device: l.name.clone(),
            kind: l.kind.to_string(),
            address: l.address.clone(),
            identity,
            checked_at,
        });
    }
    out
}

/// A calibration against the tolerance its job declared: the held-out maximum error of the
/// calibrated model must not exceed it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ToleranceCheck {
    /// The tolerance the job declared.
    pub declared: f64,
    /// The figure compared: the largest held-out error after calibration, or what
    /// `compared` names (none without a held-out set).
    pub held_out_max: Option<f64>,
    /// What `held_out_max` is (e.g. `largest held-out position error after calibration`).
    #[serde(default = "held_out_label")]
    pub compared: String,
    /// Unit of both.
    pub unit: String,
    /// `pass`, `fail`, or `not checked` (no held-out validation).
    pub outcome: String,
}

fn held_out_label() -> String {
    "largest held-out error after calibration".into()
}

impl ToleranceCheck {
    /// The largest held-out error `held_out_max` against `declared` (both in `unit`).
    pub fn new(declared: f64, held_out_max: Option<f64>, unit: &str) -> Self {
        Self::of(declared, held_out_max, unit, &held_out_label())
    }

    /// A held-out `figure` (what `compared` says it is) against `declared`, both in `unit`.
    pub fn of(declared: f64, figure: Option<f64>, unit: &str, compared: &str) -> Self {
        let outcome = match figure {
            Some(m) if m <= declared => "pass",
            Some(_) => "fail",
            None => "not checked (no held-out validation set)",
        };
        Self {
            declared,
            held_out_max: figure,
            compared: compared.into(),
            unit: unit.into(),
            outcome: outcome.into(),
        }
    }

    /// The check as report facts (declared, the figure, the outcome).
    pub fn facts(&self) -> Facts {
        let figure = match self.held_out_max {
            Some(m) => Cell::Num(Num::at(m, "/tolerance/held_out_max")),
            None => Cell::Missing,
        };
        Facts {
            name: "tolerance".into(),
            rows: vec![
                (
                    format!("declared ({})", self.unit),
                    Cell::Num(Num::at(self.declared, "/tolerance/declared")),
                ),
                (format!("{} ({})", self.compared, self.unit), figure),
                ("outcome".into(), Cell::Text(self.outcome.clone())),
            ],
        }
    }
}

/// A declared tolerance `field` (in `unit`) must be a positive finite length.
pub fn check_tolerance(field: &str, value: Option<f64>, unit: &str) -> Result<(), JobError> {
    match value {
        Some(t) if !(t.is_finite() && t > 0.0) => Err(JobError::invalid(
            field,
            format!("{t} must be a positive length ({unit})"),
        )),
        _ => Ok(()),
    }
}

/// The instruments of a campaign as report facts (none when the result has none).
pub fn instrument_facts(instruments: &[Instrument]) -> Option<Facts> {
    (!instruments.is_empty()).then(|| Facts {
        name: "instruments (robot controller and measuring devices, as they identified themselves)"
            .into(),
        rows: instruments
            .iter()
            .map(|i| {
                let text = format!("{} at {}: {}", i.kind, i.address, i.identity);
                (i.device.clone(), Cell::Text(text))
            })
            .collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_held_out_maximum_passes_at_or_below_the_tolerance() {
        assert_eq!(ToleranceCheck::new(0.02, Some(0.019), "mm").outcome, "pass");
        assert_eq!(ToleranceCheck::new(0.02, Some(0.02), "mm").outcome, "pass");
        assert_eq!(ToleranceCheck::new(0.02, Some(0.021), "mm").outcome, "fail");
        assert!(
            ToleranceCheck::new(0.02, None, "mm")
                .outcome
                .starts_with("not checked")
        );
    }
}
