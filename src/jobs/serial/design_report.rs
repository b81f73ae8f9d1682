//! What the report shows of a `serial.design` result (its [`Reportable`] view): the
//! selected configurations, O1..O5 of the selection against the pool, the DETMAX history.

use super::design::SerialDesign;
use crate::report::view::{Cell, DesignView, Num, NumTable, Reportable};

impl Reportable for SerialDesign {
    fn design(&self) -> Option<DesignView> {
        let mut head = vec!["#".to_string(), "pool row (from 1)".to_string()];
        head.extend(self.rows.columns.iter().cloned());
        let rows = self
            .rows
            .rows
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let mut row = vec![Cell::Head((i + 1).to_string())];
                row.push(match self.selected.get(i) {
                    Some(p) => Cell::Text((p + 1 - self.row_index_base).to_string()),
                    None => Cell::Missing,
                });
                row.extend(
                    self.rows
                        .columns
                        .iter()
                        .zip(r)
                        .map(|(c, v)| Cell::Num(Num::at(*v, format!("/rows/{i}/{c}")))),
                );
                row
            })
            .collect();
        let o = &self.observability;
        let index_rows = [
            (
                "O1",
                "(s1 ... sm)^(1/m) / sqrt(n)",
                o.selection.o1,
                o.pool.o1,
            ),
            (
                "O2",
                "sm / s1 (inverse condition number)",
                o.selection.o2,
                o.pool.o2,
            ),
            (
                "O3",
                "sm (smallest singular value)",
                o.selection.o3,
                o.pool.o3,
            ),
            (
                "O4",
                "sm^2 / s1 (noise amplification)",
                o.selection.o4,
                o.pool.o4,
            ),
            ("O5", "1 / sum(1 / si)", o.selection.o5, o.pool.o5),
        ]
        .iter()
        .map(|(name, what, sel, pool)| {
            let key = name.to_ascii_lowercase();
            vec![
                Cell::Head((*name).into()),
                Cell::Text((*what).into()),
                Cell::Num(Num::at(*sel, format!("/observability/selection/{key}"))),
                Cell::Num(Num::at(*pool, format!("/observability/pool/{key}"))),
            ]
        })
        .collect();
        let history = self
            .history
            .steps
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let p = |k: &str| format!("/history/steps/{i}/{k}");
                vec![
                    Cell::Num(Num::at(s.exchanges as f64, p("exchanges"))),
                    Cell::Num(Num::at(s.o1, p("o1"))),
                    Cell::Num(Num::at(s.log_det, p("log_det"))),
                ]
            })
            .collect();
        let unidentifiable = if self.unidentifiable.is_empty() {
            String::new()
        } else {
            format!(
                "; the pool cannot identify {}",
                self.unidentifiable.join(", ")
            )
        };
        Some(DesignView {
            summary: format!(
                "{} of {} pool configurations chosen by DETMAX (seed {}, {} exchanges) for {} identifiable parameters{unidentifiable}; log det(JᵀJ) {:.3} at the random start, {:.3} for the selection.",
                self.n,
                o.pool.configurations,
                self.seed,
                self.exchanges,
                self.parameters.len(),
                self.log_det.start,
                self.log_det.selection
            ),
            selected: NumTable {
                title: format!("Selected configurations ({})", self.rows.rows.len()),
                head,
                rows,
                note: Some("The job's main table (table.csv): the pool's rows in the order chosen, with the pool's own columns and units.".into()),
            },
            observability: NumTable {
                title: "Observability of the selection against the pool (dimensionless)".into(),
                head: ["index", "definition", "selection", "pool"]
                    .map(String::from)
                    .to_vec(),
                rows: index_rows,
                note: Some(format!(
                    "Singular values s1 >= ... >= sm of the identification Jacobian, columns scaled to unit norm; selection: {} configurations, pool: {}, m = {} parameters.",
                    o.selection.configurations, o.pool.configurations, o.selection.parameters
                )),
            },
            history: NumTable {
                title: "DETMAX history".into(),
                head: ["improving excursions", "O1", "log det(JᵀJ)"]
                    .map(String::from)
                    .to_vec(),
                rows: history,
                note: Some(format!("{}; {}", self.history.method, self.history.criterion)),
            },
        })
    }
}
