//! What the report shows of a `pcr.identify` result (its [`Reportable`] view): the
//! paper's Table 3 first, then the held-out errors and the parameters with their bounds.

use super::identify::PcrCalibration;
use crate::measure::pcr::report::{Table3Row, Table3Set};
use crate::report::view::{
    Cell, ConvergenceView, HeadlineRow, Held, Num, NumTable, ParamTable, Reportable, VerdictBlock,
    model_error_table,
};

/// The sets of Table 3 present, with their names.
fn sets(r: &PcrCalibration) -> Vec<(&'static str, &Table3Set)> {
    let t = &r.model_error;
    let mut out = vec![("calibration", &t.calibration)];
    if let Some(v) = &t.validation {
        out.push(("validation", v));
    }
    out
}

/// The errors of one set: (field name, label, row).
fn errors(s: &Table3Set) -> [(&'static str, &'static str, &Table3Row); 2] {
    [
        ("e_P", "Position error e_P", &s.e_p),
        ("e_theta", "Orientation error e_θ", &s.e_theta),
    ]
}

impl Reportable for PcrCalibration {
    fn verdict(&self) -> Option<VerdictBlock> {
        Some(VerdictBlock {
            assessment: self.assessment.clone(),
            dof: Some(self.dof),
        })
    }

    fn headline(&self) -> Vec<HeadlineRow> {
        let mut out = Vec::new();
        for (set, s) in sets(self) {
            for (e, label, row) in errors(s) {
                let p = format!("/model_error/{set}/{e}");
                out.push(HeadlineRow::new(
                    &format!("{label} mean, {set} set"),
                    Num::at(row.nominal.mean, format!("{p}/nominal/mean")),
                    Num::at(row.identified.mean, format!("{p}/identified/mean")),
                    &row.unit,
                ));
            }
        }
        // The held-out errors are Table 3's validation e_P (in m rather than um): shown
        // once, from Table 3, when it has the validation set.
        if let Some(v) = self
            .validation
            .as_ref()
            .filter(|_| self.model_error.validation.is_none())
        {
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
        // Residuals are poses in m (`residual_std.unit`).
        Some(ParamTable::of(
            self.parameters.iter().map(|p| &p.report),
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

    fn convergence(&self) -> Option<ConvergenceView> {
        Some(ConvergenceView {
            converged: Some(self.convergence.converged),
            iterations: Some(self.convergence.iterations),
            ..ConvergenceView::default()
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
                None,
            ));
        }
        let mut rows = Vec::new();
        for (set, s) in sets(self) {
            for (e, _, row) in errors(s) {
                for (m, stats) in [("nominal", &row.nominal), ("identified", &row.identified)] {
                    let p = format!("/model_error/{set}/{e}/{m}");
                    rows.push(vec![
                        Cell::Text(set.into()),
                        Cell::Text(e.into()),
                        Cell::Text(m.into()),
                        Cell::Num(Num::at(stats.max, format!("{p}/max"))),
                        Cell::Num(Num::at(stats.mean, format!("{p}/mean"))),
                        Cell::Num(Num::at(stats.min, format!("{p}/min"))),
                        Cell::Text(row.unit.to_string()),
                    ]);
                }
            }
        }
        out.push(model_error_table(rows));
        out
    }
}
