//! The report's view of a result whose kind has no typed result (or a stored result that
//! no longer reads as its kind's type): the fields read from the JSON by name. Kinds with
//! a typed result never come here (`jobs::report_view` dispatches them).

use serde_json::Value;

use super::view::{
    Cell, ConvergenceView, Facts, HeadlineRow, Held, Num, NumTable, ParamRow, ParamTable,
    Reportable, VerdictBlock,
};
use crate::identify::verdict::Assessment;

/// A result document read by field name.
#[derive(Debug, Clone, Copy)]
pub struct JsonResult<'a>(pub &'a Value);

impl JsonResult<'_> {
    fn num(&self, pointer: &str) -> Option<Num> {
        let v = self.0.pointer(pointer)?.as_f64()?;
        Some(Num::at(v, pointer))
    }

    fn cell(&self, pointer: &str) -> Cell {
        self.num(pointer).map(Cell::Num).unwrap_or(Cell::Missing)
    }

    fn unit(&self, pointer: &str, default: &str) -> String {
        self.0
            .pointer(pointer)
            .and_then(Value::as_str)
            .unwrap_or(default)
            .to_string()
    }

    fn names(&self, key: &str) -> Vec<String> {
        self.0
            .get(key)
            .and_then(Value::as_array)
            .map(|a| {
                a.iter()
                    .filter_map(|v| v.as_str().or_else(|| v.get("name").and_then(Value::as_str)))
                    .map(str::to_string)
                    .collect()
            })
            .unwrap_or_default()
    }

    fn pair(&self, out: &mut Vec<HeadlineRow>, label: &str, before: &str, after: &str, unit: &str) {
        if self.0.pointer(before).is_some() && self.0.pointer(after).is_some() {
            let num = |p: &str| self.num(p).unwrap_or_else(|| Num::at(f64::NAN, p));
            out.push(HeadlineRow::new(label, num(before), num(after), unit));
        }
    }

    fn stats(&self, base: &str, title: &str) -> NumTable {
        let keys = ["count", "mean", "median", "std", "min", "max", "rms"];
        let present: Vec<&str> = keys
            .iter()
            .copied()
            .filter(|k| self.0.pointer(&format!("{base}/after/{k}")).is_some())
            .collect();
        let mut head = vec![String::new()];
        head.extend(present.iter().map(|k| k.to_string()));
        let rows = ["before", "after"]
            .iter()
            .map(|side| {
                let mut row = vec![Cell::Head(side.to_string())];
                row.extend(
                    present
                        .iter()
                        .map(|k| self.cell(&format!("{base}/{side}/{k}"))),
                );
                row
            })
            .collect();
        let note = self
            .0
            .pointer(&format!("{base}/meaning"))
            .and_then(Value::as_str)
            .map(str::to_string);
        NumTable {
            title: title.into(),
            head,
            rows,
            note,
        }
    }
}

/// The text of a JSON value: a string as is, anything else as JSON.
fn plain(v: Option<&Value>) -> Option<String> {
    match v {
        None | Some(Value::Null) => None,
        Some(Value::String(s)) => Some(s.clone()),
        Some(other) => Some(other.to_string()),
    }
}

impl Reportable for JsonResult<'_> {
    fn verdict(&self) -> Option<VerdictBlock> {
        let assessment: Assessment = serde_json::from_value(self.0.clone()).ok()?;
        Some(VerdictBlock {
            assessment,
            dof: self
                .0
                .get("dof")
                .and_then(Value::as_u64)
                .map(|d| d as usize),
        })
    }

    fn headline(&self) -> Vec<HeadlineRow> {
        let mut out = Vec::new();
        let u = self.unit("/residuals/after/unit", "mm");
        let (b, a) = ("/residuals/before", "/residuals/after");
        self.pair(
            &mut out,
            "Residual mean, calibration set",
            &format!("{b}/mean"),
            &format!("{a}/mean"),
            &u,
        );
        self.pair(
            &mut out,
            "Residual max, calibration set",
            &format!("{b}/max"),
            &format!("{a}/max"),
            &u,
        );
        self.pair(
            &mut out,
            "Marker RMSE, calibration set",
            "/rmse_before_mm",
            "/rmse_after_mm",
            "mm",
        );
        self.pair(
            &mut out,
            "Held-out marker RMSE (cross-validation)",
            "/cross_validation/rmse_nominal_mm",
            "/cross_validation/rmse_calibrated_mm",
            "mm",
        );
        for set in ["calibration", "validation"] {
            let p = format!("/model_error/{set}");
            for (e, label, default) in [
                ("e_P", "Position error e_P", "µm"),
                ("e_theta", "Orientation error e_θ", "mrad"),
            ] {
                let unit = self.unit(&format!("{p}/{e}/unit"), default);
                self.pair(
                    &mut out,
                    &format!("{label} mean, {set} set"),
                    &format!("{p}/{e}/nominal/mean"),
                    &format!("{p}/{e}/identified/mean"),
                    &unit,
                );
            }
        }
        let u = self.unit("/validation/after/unit", "mm");
        let (b, a) = ("/validation/before", "/validation/after");
        self.pair(
            &mut out,
            "Held-out error mean, validation set",
            &format!("{b}/mean"),
            &format!("{a}/mean"),
            &u,
        );
        self.pair(
            &mut out,
            "Held-out error max, validation set",
            &format!("{b}/max"),
            &format!("{a}/max"),
            &u,
        );
        out
    }

    fn parameters(&self) -> Option<ParamTable> {
        let ps = self.0.get("parameters").and_then(Value::as_array)?;
        let rows = ps
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let at = |k: &str| format!("/parameters/{i}/{k}");
                let num = |k: &str| self.num(&at(k)).unwrap_or_else(|| Num::at(f64::NAN, at(k)));
                ParamRow {
                    name: p.get("name").and_then(Value::as_str).unwrap_or("?").into(),
                    unit: plain(p.get("unit")).unwrap_or_else(|| "—".into()),
                    nominal: num("nominal"),
                    value: num("value"),
                    std: self.num(&at("std")),
                    identifiable: p
                        .get("identifiable")
                        .and_then(Value::as_bool)
                        .unwrap_or(true),
                    at_bound: p
                        .get("at_bound")
                        .and_then(Value::as_str)
                        .map(str::to_string),
                    effect_size: num("effect_size"),
                }
            })
            .collect();
        Some(ParamTable {
            rows,
            condition_number: self.0.get("condition_number").and_then(Value::as_f64),
            effect_unit: self.unit("/residual_std/unit", "m"),
        })
    }

    fn held(&self) -> Held {
        Held {
            unidentifiable: self.names("unidentifiable"),
            weakly_observable: self.names("weakly_observable"),
            unobservable: self.names("unobservable"),
        }
    }

    fn convergence(&self) -> Option<ConvergenceView> {
        let c = self.0.get("convergence")?;
        Some(ConvergenceView {
            status: plain(c.get("status")),
            converged: c.get("converged").and_then(Value::as_bool),
            iterations: c
                .get("iterations")
                .and_then(Value::as_u64)
                .map(|i| i as usize),
            degenerate: plain(c.get("degenerate")),
        })
    }

    fn facts(&self) -> Vec<Facts> {
        ["campaign", "samples"]
            .iter()
            .filter_map(|k| Some(Facts::of_object(k, self.0.get(*k)?.as_object()?)))
            .collect()
    }

    fn tables(&self) -> Vec<NumTable> {
        let mut out = Vec::new();
        if self.0.pointer("/validation/after").is_some() {
            let unit = self.unit("/validation/after/unit", "");
            out.push(self.stats(
                "/validation",
                &format!("Held-out validation errors ({unit})"),
            ));
        }
        if self.0.pointer("/residuals/after").is_some() {
            let unit = self.unit("/residuals/after/unit", "");
            out.push(self.stats(
                "/residuals",
                &format!("Residuals of the fit, calibration set ({unit})"),
            ));
        }
        if let Some(t) = self.0.get("model_error").and_then(Value::as_object) {
            let mut rows = Vec::new();
            for set in ["calibration", "validation"]
                .iter()
                .filter(|s| t.contains_key(**s))
            {
                for e in ["e_P", "e_theta"] {
                    for m in ["nominal", "identified"] {
                        let p = format!("/model_error/{set}/{e}/{m}");
                        rows.push(vec![
                            Cell::Text(set.to_string()),
                            Cell::Text(e.into()),
                            Cell::Text(m.into()),
                            self.cell(&format!("{p}/max")),
                            self.cell(&format!("{p}/mean")),
                            self.cell(&format!("{p}/min")),
                            plain(self.0.pointer(&format!("/model_error/{set}/{e}/unit")))
                                .map(Cell::Text)
                                .unwrap_or(Cell::Text("—".into())),
                        ]);
                    }
                }
            }
            out.push(super::view::model_error_table(rows));
        }
        if let Some(folds) = self
            .0
            .pointer("/cross_validation/per_fold")
            .and_then(Value::as_array)
        {
            let rows = (0..folds.len())
                .map(|i| {
                    let p = format!("/cross_validation/per_fold/{i}");
                    vec![
                        Cell::Text((i + 1).to_string()),
                        self.cell(&format!("{p}/held_out_samples")),
                        self.cell(&format!("{p}/rmse_nominal_mm")),
                        self.cell(&format!("{p}/rmse_calibrated_mm")),
                    ]
                })
                .collect();
            out.push(super::view::folds_table(rows));
        }
        out
    }

    fn warnings(&self) -> Vec<String> {
        self.0
            .get("warnings")
            .and_then(Value::as_array)
            .map(|a| {
                a.iter()
                    .map(|v| plain(Some(v)).unwrap_or_else(|| "—".into()))
                    .collect()
            })
            .unwrap_or_default()
    }

    fn gauge_freedom(&self) -> Option<String> {
        self.0
            .get("gauge_freedom")
            .and_then(Value::as_str)
            .map(str::to_string)
    }
}
