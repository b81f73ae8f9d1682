//! What the report shows of a campaign's result: its identification's (embedded) and the
//! campaign's own figures (`campaign`: counts and times).

use super::results::{MocapCampaign, PcrCampaign, TricalCampaign};
use crate::report::view::{Facts, Reportable};

impl Reportable for TricalCampaign {
    fn embedded(&self) -> Option<&dyn Reportable> {
        Some(&self.calibration)
    }

    fn facts(&self) -> Vec<Facts> {
        Facts::of("campaign", &self.campaign).into_iter().collect()
    }
}

impl Reportable for PcrCampaign {
    fn embedded(&self) -> Option<&dyn Reportable> {
        Some(&self.calibration)
    }

    fn facts(&self) -> Vec<Facts> {
        Facts::of("campaign", &self.campaign).into_iter().collect()
    }
}

impl Reportable for MocapCampaign {
    fn embedded(&self) -> Option<&dyn Reportable> {
        Some(&self.calibration)
    }

    /// The campaign's figures, then the identification's samples (the order the result
    /// stores them in).
    fn facts(&self) -> Vec<Facts> {
        let mut out: Vec<Facts> = Facts::of("campaign", &self.campaign).into_iter().collect();
        out.extend(self.calibration.facts());
        out
    }
}
