//! What the report shows of a `humanoid.identify` result (its [`Reportable`] view):
//! marker RMSE before and after, cross-validation folds, the samples used.

use super::identify_result::HumanoidCalibration;
use crate::report::view::{
    Cell, ConvergenceView, Facts, HeadlineRow, Held, Num, NumTable, ParamTable, Reportable,
    VerdictBlock, folds_table,
};

impl Reportable for HumanoidCalibration {
    fn verdict(&self) -> Option<VerdictBlock> {
        Some(VerdictBlock {
            assessment: self.assessment.clone(),
            dof: Some(self.dof),
        })
    }

    fn headline(&self) -> Vec<HeadlineRow> {
        let mut out = vec![HeadlineRow::new(
            "Marker RMSE, calibration set",
            Num::at(self.rmse_before_mm, "/rmse_before_mm"),
            Num::at(self.rmse_after_mm, "/rmse_after_mm"),
            "mm",
        )];
        if let Some(cv) = &self.cross_validation {
            out.push(HeadlineRow::new(
                "Held-out marker RMSE (cross-validation)",
                Num::at(cv.rmse_nominal_mm, "/cross_validation/rmse_nominal_mm"),
                Num::at(
                    cv.rmse_calibrated_mm,
                    "/cross_validation/rmse_calibrated_mm",
                ),
                "mm",
            ));
        }
        out
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
            weakly_observable: self.weakly_observable.clone(),
            unobservable: Vec::new(),
        }
    }

    fn convergence(&self) -> Option<ConvergenceView> {
        let c = &self.convergence;
        Some(ConvergenceView {
            status: Some(c.status.to_string()),
            converged: Some(c.converged),
            iterations: Some(c.iterations),
            degenerate: c
                .degenerate
                .as_ref()
                .and_then(|d| serde_json::to_string(d).ok()),
        })
    }

    fn facts(&self) -> Vec<Facts> {
        self.samples
            .as_object()
            .map(|o| Facts::of_object("samples", o))
            .into_iter()
            .collect()
    }

    fn tables(&self) -> Vec<NumTable> {
        let Some(cv) = &self.cross_validation else {
            return Vec::new();
        };
        let rows = cv
            .per_fold
            .iter()
            .enumerate()
            .map(|(i, f)| {
                let p = format!("/cross_validation/per_fold/{i}");
                vec![
                    Cell::Text((i + 1).to_string()),
                    Cell::Num(Num::at(
                        f.held_out_samples as f64,
                        format!("{p}/held_out_samples"),
                    )),
                    Cell::Num(Num::at(f.rmse_nominal_mm, format!("{p}/rmse_nominal_mm"))),
                    Cell::Num(Num::at(
                        f.rmse_calibrated_mm,
                        format!("{p}/rmse_calibrated_mm"),
                    )),
                ]
            })
            .collect();
        vec![folds_table(rows)]
    }
}
