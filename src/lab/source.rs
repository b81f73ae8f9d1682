//! Where a cell's current model comes from: the lab file's nominal model, or the k-th
//! calibration accepted for the cell, so a campaign can say what its "before" figures are.

use serde::{Deserialize, Serialize};

/// The origin of a cell's current model.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "is", rename_all = "snake_case")]
pub enum ModelSource {
    /// The lab file's nominal model (no calibration accepted yet).
    #[default]
    Nominal,
    /// A calibration the cell accepted.
    Calibration {
        /// Its number among the cell's accepted calibrations (1 the first).
        number: usize,
        /// The campaign job that produced it.
        job_id: Option<i64>,
        /// When it was accepted (RFC 3339, UTC).
        at: String,
    },
}

impl ModelSource {
    /// The model named for a person: `nominal (the lab file's model)` or `calibration #2
    /// of 2026-11-28 09:14 UTC (job 7)`.
    pub fn label(&self) -> String {
        match self {
            ModelSource::Nominal => "nominal (the lab file's model)".into(),
            ModelSource::Calibration { number, job_id, at } => {
                // `2026-11-28T09:14:03.123Z` -> `2026-11-28 09:14 UTC`.
                let day = at.get(..10).unwrap_or(at);
                let time = at
                    .get(11..16)
                    .map(|t| format!(" {t} UTC"))
                    .unwrap_or_default();
                let job = job_id.map(|j| format!(" (job {j})")).unwrap_or_default();
                format!("calibration #{number} of {day}{time}{job}")
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_name_the_nominal_or_the_calibration_with_its_date() {
        assert_eq!(
            ModelSource::Nominal.label(),
            "nominal (the lab file's model)"
        );
        let c = ModelSource::Calibration {
            number: 2,
            job_id: Some(7),
            at: "2026-11-28T09:14:03.123Z".into(),
        };
        assert_eq!(c.label(), "calibration #2 of 2026-11-28 09:14 UTC (job 7)");
    }
}
