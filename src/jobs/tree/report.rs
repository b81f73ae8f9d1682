//! What the report shows of a `tree.identify` result (its [`Reportable`] view): the
//! verdict, the cumulative table (published figures beside it for Agile Justin), the
//! largest errors, the last fit's parameters and the result's warnings.

use super::TreeCalibration;
use crate::report::view::{Cell, Held, Num, NumTable, ParamTable, Reportable, VerdictBlock};

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

    fn tables(&self) -> Vec<NumTable> {
        let num = |v: f64, p: String| Cell::Num(Num::at(v, p));
        let rows = self
            .steps
            .iter()
            .enumerate()
            .map(|(k, st)| {
                let p = format!("/steps/{k}/error_mm");
                let mut row = vec![
                    Cell::Head(st.name.clone()),
                    num(st.error_mm.mean, format!("{p}/mean")),
                    num(st.error_mm.std, format!("{p}/std")),
                    num(st.error_mm.max, format!("{p}/max")),
                ];
                match self.published.as_ref().and_then(|v| v.get(k)) {
                    Some(x) => row.extend([
                        num(x.mean_mm, format!("/published/{k}/mean_mm")),
                        num(x.std_mm, format!("/published/{k}/std_mm")),
                        num(x.max_mm, format!("/published/{k}/max_mm")),
                    ]),
                    None => row.extend([Cell::Missing, Cell::Missing, Cell::Missing]),
                }
                row.push(Cell::Text(st.status.clone()));
                row
            })
            .collect();
        let head = [
            "model (cumulative)",
            "mean",
            "std",
            "max",
            "published mean",
            "published std",
            "published max",
            "status",
        ];
        let worst = self
            .worst_samples
            .iter()
            .enumerate()
            .map(|(k, w)| {
                vec![
                    Cell::Text(w.sample.to_string()),
                    Cell::Text(w.marker.clone()),
                    num(w.error_mm, format!("/worst_samples/{k}/error_mm")),
                ]
            })
            .collect();
        vec![
            NumTable {
                title: "Cumulative steps (marker error, mm)".into(),
                head: head.iter().map(|h| h.to_string()).collect(),
                rows,
                note: None,
            },
            NumTable {
                title: "Largest marker errors of the last model (mm)".into(),
                head: ["sample", "marker", "error"]
                    .iter()
                    .map(|h| h.to_string())
                    .collect(),
                rows: worst,
                note: Some("sample: 0-based data row of the samples table".into()),
            },
        ]
    }
}
