//! What the report shows of a campaign's result: its identification's (embedded) and the
//! campaign's own figures (`campaign`: counts and times).

use super::results::{MocapCampaign, PcrCampaign, TricalCampaign};
use crate::report::view::{Cell, Facts, Num, Reportable};

impl Reportable for TricalCampaign {
    fn embedded(&self) -> Option<&dyn Reportable> {
        Some(&self.calibration)
    }

    fn before_label(&self) -> Option<String> {
        started_from(&self.started_from)
    }

    /// The campaign's figures, the instruments that measured and the declared tolerance.
    fn facts(&self) -> Vec<Facts> {
        let mut out: Vec<Facts> = Facts::of("campaign", &self.campaign).into_iter().collect();
        if !self.instruments.is_empty() {
            out.push(Facts {
                name: "instruments (robot controller and measuring devices, as they identified themselves)".into(),
                rows: self
                    .instruments
                    .iter()
                    .map(|i| {
                        let text = format!("{} at {}: {}", i.kind, i.address, i.identity);
                        (i.device.clone(), Cell::Text(text))
                    })
                    .collect(),
            });
        }
        if let Some(t) = &self.tolerance {
            let held = match t.held_out_max {
                Some(m) => Cell::Num(Num::at(m, "/tolerance/held_out_max")),
                None => Cell::Missing,
            };
            out.push(Facts {
                name: "tolerance".into(),
                rows: vec![
                    (
                        format!("declared ({})", t.unit),
                        Cell::Num(Num::at(t.declared, "/tolerance/declared")),
                    ),
                    (format!("held-out max error after ({})", t.unit), held),
                    ("outcome".into(), Cell::Text(t.outcome.clone())),
                ],
            });
        }
        out
    }
}

impl Reportable for PcrCampaign {
    fn embedded(&self) -> Option<&dyn Reportable> {
        Some(&self.calibration)
    }

    fn before_label(&self) -> Option<String> {
        started_from(&self.started_from)
    }

    fn facts(&self) -> Vec<Facts> {
        Facts::of("campaign", &self.campaign).into_iter().collect()
    }
}

impl Reportable for MocapCampaign {
    fn embedded(&self) -> Option<&dyn Reportable> {
        Some(&self.calibration)
    }

    fn before_label(&self) -> Option<String> {
        started_from(&self.started_from)
    }

    /// The campaign's figures, then the identification's samples (the order the result
    /// stores them in).
    fn facts(&self) -> Vec<Facts> {
        let mut out: Vec<Facts> = Facts::of("campaign", &self.campaign).into_iter().collect();
        out.extend(self.calibration.facts());
        out
    }
}

/// A campaign's "before" label (none from a result stored before campaigns said it).
fn started_from(s: &str) -> Option<String> {
    (!s.is_empty()).then(|| s.to_string())
}
