//! What the report shows of a campaign's result: its identification's (embedded) and the
//! campaign's own figures (`campaign`: counts and times).

use super::instruments::{Instrument, ToleranceCheck, instrument_facts};
use super::results::{MocapCampaign, PcrCampaign, TricalCampaign};
use crate::report::view::{Facts, Reportable};

impl Reportable for TricalCampaign {
    fn embedded(&self) -> Option<&dyn Reportable> {
        Some(&self.calibration)
    }

    fn before_label(&self) -> Option<String> {
        started_from(&self.started_from)
    }

    /// The campaign's figures, the instruments that measured and the declared tolerance.
    fn facts(&self) -> Vec<Facts> {
        campaign_facts(
            Facts::of("campaign", &self.campaign),
            &self.instruments,
            self.tolerance.as_ref(),
        )
    }
}

impl Reportable for PcrCampaign {
    fn embedded(&self) -> Option<&dyn Reportable> {
        Some(&self.calibration)
    }

    fn before_label(&self) -> Option<String> {
        started_from(&self.started_from)
    }

    /// The campaign's figures, the instruments that measured and the declared tolerance.
    fn facts(&self) -> Vec<Facts> {
        campaign_facts(
            Facts::of("campaign", &self.campaign),
            &self.instruments,
            self.tolerance.as_ref(),
        )
    }
}

impl Reportable for MocapCampaign {
    fn embedded(&self) -> Option<&dyn Reportable> {
        Some(&self.calibration)
    }

    fn before_label(&self) -> Option<String> {
        started_from(&self.started_from)
    }

    /// The campaign's figures, instruments and tolerance, then the identification's samples
    /// (the order the result stores them in).
    fn facts(&self) -> Vec<Facts> {
        let mut out = campaign_facts(
            Facts::of("campaign", &self.campaign),
            &self.instruments,
            self.tolerance.as_ref(),
        );
        out.extend(self.calibration.facts());
        out
    }
}

/// A campaign's own figures, then who measured, then the declared tolerance's outcome.
fn campaign_facts(
    campaign: Option<Facts>,
    instruments: &[Instrument],
    tolerance: Option<&ToleranceCheck>,
) -> Vec<Facts> {
    let mut out: Vec<Facts> = campaign.into_iter().collect();
    out.extend(instrument_facts(instruments));
    out.extend(tolerance.map(ToleranceCheck::facts));
    out
}

/// A campaign's "before" label (none from a result stored before campaigns said it).
fn started_from(s: &str) -> Option<String> {
    (!s.is_empty()).then(|| s.to_string())
}
