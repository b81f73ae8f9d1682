//! What the report shows of a `tree.identify` result (its [`Reportable`] view): the
//! verdict, the last fit's parameters and the result's warnings.

use super::TreeCalibration;
use crate::report::view::{Held, ParamTable, Reportable, VerdictBlock};

impl Reportable for TreeCalibration {
    fn verdict(&self) -> Option<VerdictBlock> {
        Some(VerdictBlock {
            assessment: self.assessment.clone(),
            dof: Some(self.dof),
        })
    }

    fn parameters(&self) -> Option<ParamTable> {
        // The header's effect unit as the report has always stated it for this kind.
        Some(ParamTable::of(
            &self.parameters,
            Some(self.condition_number),
            "m",
        ))
    }

    fn held(&self) -> Held {
        Held {
            unidentifiable: self.unidentifiable.clone(),
            ..Held::default()
        }
    }

    fn warnings(&self) -> Vec<String> {
        self.warnings.clone()
    }
}
