//! What the report shows of a `serial.identify` result (its [`Reportable`] view).

use super::identify_result::SerialCalibration;
use crate::report::view::{
    ConvergenceView, HeadlineRow, Held, NumTable, ParamTable, Reportable, VerdictBlock,
};

impl Reportable for SerialCalibration {
    fn verdict(&self) -> Option<VerdictBlock> {
        Some(VerdictBlock {
            assessment: self.assessment.clone(),
            dof: Some(self.dof),
        })
    }

    fn headline(&self) -> Vec<HeadlineRow> {
        let r = &self.residuals;
        let mut out = HeadlineRow::mean_max(
            "Residual",
            "calibration set",
            "/residuals",
            &r.before,
            &r.after,
        );
        if let Some(v) = &self.validation {
            out.extend(HeadlineRow::mean_max(
                "Held-out error",
                "validation set",
                "/validation",
                &v.before,
                &v.after,
            ));
        }
        out
    }

    fn parameters(&self) -> Option<ParamTable> {
        Some(ParamTable::of(
            &self.parameters,
            Some(self.condition_number),
            &self.residual_std.unit,
        ))
    }

    fn held(&self) -> Held {
        Held {
            unidentifiable: self.unidentifiable.clone(),
            weakly_observable: self.weakly_observable.clone(),
            unobservable: self.unobservable.iter().map(|u| u.name.clone()).collect(),
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

    fn tables(&self) -> Vec<NumTable> {
        let mut out = Vec::new();
        if let Some(v) = &self.validation {
            out.push(NumTable::before_after(
                "Held-out validation errors",
                "/validation",
                &v.before,
                &v.after,
                v.meaning.as_deref(),
            ));
        }
        let r = &self.residuals;
        out.push(NumTable::before_after(
            "Residuals of the fit, calibration set",
            "/residuals",
            &r.before,
            &r.after,
            r.meaning.as_deref(),
        ));
        out
    }

    fn warnings(&self) -> Vec<String> {
        self.warnings.clone().unwrap_or_default()
    }

    fn gauge_freedom(&self) -> Option<String> {
        self.gauge_freedom.clone().flatten()
    }
}
