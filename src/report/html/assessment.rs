//! The report's sections that judge the result: the verdict of an identification with its
//! reasons (first in the report), validation (held-out errors, Table 3, cross-validation),
//! warnings, and the sign-off.

use std::fmt::Write;

use serde_json::Value;

use super::sections::{names, unit_at};
use super::{ReportInput, num_cell, text};
use crate::report::svg::escape;

fn stats_table(r: &Value, base: &str, title: &str) -> String {
    let keys = ["count", "mean", "median", "std", "min", "max", "rms"];
    let present: Vec<&str> = keys
        .iter()
        .copied()
        .filter(|k| r.pointer(&format!("{base}/after/{k}")).is_some())
        .collect();
    let mut h = format!("<h3>{}</h3><table><thead><tr><th></th>", escape(title));
    for k in &present {
        let _ = write!(h, "<th>{k}</th>");
    }
    h.push_str("</tr></thead><tbody>");
    for side in ["before", "after"] {
        let _ = write!(h, "<tr><th>{side}</th>");
        for k in &present {
            h.push_str(&num_cell(r, &format!("{base}/{side}/{k}")));
        }
        h.push_str("</tr>");
    }
    h.push_str("</tbody></table>");
    if let Some(m) = r
        .pointer(&format!("{base}/meaning"))
        .filter(|v| v.is_string())
    {
        let _ = write!(h, "<p class=\"meta\">{}</p>", text(Some(m)));
    }
    h
}

/// Validation: held-out errors, the PCR Table 3, cross-validation folds.
pub(super) fn validation(r: &Value) -> String {
    let mut h = String::new();
    if r.pointer("/validation/after").is_some() {
        let unit = unit_at(r, "/validation/after/unit", "");
        h.push_str(&stats_table(
            r,
            "/validation",
            &format!("Held-out validation errors ({unit})"),
        ));
    }
    if r.pointer("/residuals/after").is_some() {
        let unit = unit_at(r, "/residuals/after/unit", "");
        h.push_str(&stats_table(
            r,
            "/residuals",
            &format!("Residuals of the fit, calibration set ({unit})"),
        ));
    }
    if let Some(t) = r.get("model_error").and_then(Value::as_object) {
        h.push_str("<h3>Model error (Table 3)</h3><table><thead><tr><th>set</th><th>error</th><th>model</th><th>max</th><th>mean</th><th>min</th><th>unit</th></tr></thead><tbody>");
        for set in ["calibration", "validation"]
            .iter()
            .filter(|s| t.contains_key(**s))
        {
            for e in ["e_P", "e_theta"] {
                for m in ["nominal", "identified"] {
                    let p = format!("/model_error/{set}/{e}/{m}");
                    let _ = write!(
                        h,
                        "<tr><td>{set}</td><td>{e}</td><td>{m}</td>{}{}{}<td>{}</td></tr>",
                        num_cell(r, &format!("{p}/max")),
                        num_cell(r, &format!("{p}/mean")),
                        num_cell(r, &format!("{p}/min")),
                        text(r.pointer(&format!("/model_error/{set}/{e}/unit")))
                    );
                }
            }
        }
        h.push_str("</tbody></table>");
    }
    if let Some(folds) = r
        .pointer("/cross_validation/per_fold")
        .and_then(Value::as_array)
    {
        h.push_str("<h3>Cross-validation (held-out marker RMSE, mm)</h3><table><thead><tr><th>fold</th><th>held-out samples</th><th>nominal</th><th>calibrated</th></tr></thead><tbody>");
        for i in 0..folds.len() {
            let p = format!("/cross_validation/per_fold/{i}");
            let _ = write!(
                h,
                "<tr><td>{}</td>{}{}{}</tr>",
                i + 1,
                num_cell(r, &format!("{p}/held_out_samples")),
                num_cell(r, &format!("{p}/rmse_nominal_mm")),
                num_cell(r, &format!("{p}/rmse_calibrated_mm"))
            );
        }
        h.push_str("</tbody></table>");
    }
    if h.is_empty() {
        h.push_str("<p class=\"warn\">No held-out validation: the job had no validation set. The errors above are residuals of the fit, which understate the error on new poses.</p>");
    }
    format!("<section><h2>Validation</h2>{h}</section>")
}

/// Warnings: the result's own, convergence, held and weakly observable parameters.
/// The verdict (`accepted`, `review`, `rejected`) and its reasons; empty for results
/// without one (kinds that are not identifications).
pub(super) fn verdict(r: &Value) -> String {
    let Some(v) = r.get("verdict").and_then(Value::as_str) else {
        return String::new();
    };
    let meaning = match v {
        "accepted" => "use this calibration",
        "review" => "usable only after a person has read the reasons below",
        "rejected" => {
            "nothing usable was made: the model is kept as rejected_model, never as a calibration"
        }
        _ => "",
    };
    let mut h = format!(
        r#"<section id="verdict"><h2>Verdict: {}</h2><p><strong>{}</strong>: {}</p>"#,
        escape(v),
        escape(v),
        escape(meaning)
    );
    let reasons = r
        .get("reasons")
        .and_then(Value::as_array)
        .cloned()
        .unwrap_or_default();
    if !reasons.is_empty() {
        h.push_str("<table><tr><th>reason</th><th>gives</th><th>what was found</th></tr>");
        for x in &reasons {
            let _ = write!(
                h,
                "<tr><td><code>{}</code></td><td>{}</td><td>{}</td></tr>",
                text(x.get("code")),
                text(x.get("severity")),
                text(x.get("message"))
            );
        }
        h.push_str("</table>");
    }
    if let Some(d) = r.get("dof").and_then(Value::as_u64) {
        let _ = write!(
            h,
            r#"<p class="meta">Residual degrees of freedom: {d}.</p>"#
        );
    }
    h.push_str("</section>");
    h
}

pub(super) fn warnings(r: &Value) -> String {
    let mut w: Vec<String> = r
        .get("warnings")
        .and_then(Value::as_array)
        .map(|a| a.iter().map(|v| text(Some(v))).collect())
        .unwrap_or_default();
    if let Some(c) = r.get("convergence") {
        if c.get("converged").and_then(Value::as_bool) == Some(false) {
            w.push(format!(
                "the fit did not converge: {}",
                text(c.get("status"))
            ));
        }
        if let Some(d) = c.get("degenerate").filter(|d| !d.is_null()) {
            w.push(format!("degenerate solution: {}", text(Some(d))));
        }
    }
    let held = names(r, "unidentifiable");
    if !held.is_empty() {
        w.push(format!(
            "{} parameters held at nominal (not identifiable from these data): {}",
            held.len(),
            escape(&held.join(", "))
        ));
    }
    let weak = names(r, "weakly_observable");
    if !weak.is_empty() {
        w.push(format!("weakly observable: {}", escape(&weak.join(", "))));
    }
    if let Some(ps) = r.get("parameters").and_then(Value::as_array) {
        let at: Vec<String> = ps
            .iter()
            .filter(|p| p.get("at_bound").is_some_and(|b| !b.is_null()))
            .map(|p| text(p.get("name")))
            .collect();
        if !at.is_empty() {
            w.push(format!("at a bound: {}", at.join(", ")));
        }
    }
    if let Some(g) = r.get("gauge_freedom").and_then(Value::as_str) {
        w.push(format!("gauge freedom: {}", escape(g)));
    }
    let mut h = String::from("<section><h2>Warnings</h2>");
    if w.is_empty() {
        h.push_str("<p>None.</p>");
    } else {
        h.push_str("<ul class=\"warn\">");
        for x in &w {
            let _ = write!(h, "<li>{x}</li>");
        }
        h.push_str("</ul>");
    }
    h.push_str("</section>");
    h
}

/// What was calibrated, when, on which cell, the decision calibd recorded and the
/// fields a quality engineer fills in.
pub(super) fn sign_off(input: &ReportInput<'_>, cell: Option<&str>) -> String {
    let r = input.result;
    let id = input.job.get("id").and_then(Value::as_i64);
    let mut h = String::from("<section class=\"sign\"><h2>Sign-off</h2><table>");
    let what = format!(
        "{} (job {}){}",
        text(r.get("kind")),
        text(input.job.get("id")),
        r.get("parameters")
            .and_then(Value::as_array)
            .map(|p| format!(", {} parameters", p.len()))
            .unwrap_or_default()
    );
    let _ = write!(h, "<tr><th>What was calibrated</th><td>{what}</td></tr>");
    let _ = write!(
        h,
        "<tr><th>When (finished, UTC)</th><td>{}</td></tr>",
        text(r.get("finished_at"))
    );
    let _ = write!(
        h,
        "<tr><th>Cell</th><td>{}</td></tr>",
        cell.map(escape)
            .unwrap_or_else(|| "none (an offline job on recorded data)".into())
    );
    let decision = input
        .cell_history
        .iter()
        .find(|m| m.get("job_id").and_then(Value::as_i64) == id && id.is_some());
    let recorded = match decision {
        Some(m) => {
            let state = match m.get("state").and_then(Value::as_str) {
                Some("current") => "accepted (the cell's current model)",
                Some("superseded") => "accepted (since superseded by a later calibration)",
                Some("rejected") => "rejected",
                _ => "unknown",
            };
            format!(
                "<span data-decision=\"{state}\">{state}</span>: {} (at {})",
                text(m.get("reason")),
                text(m.get("at"))
            )
        }
        None => "none: this job did not decide a cell's model".into(),
    };
    let _ = write!(
        h,
        "<tr><th>Decision recorded by calibd</th><td>{recorded}</td></tr>"
    );
    h.push_str("<tr><th>Quality decision</th><td>☐ accept &nbsp; ☐ reject</td></tr><tr><th>Reason</th><td></td></tr><tr><th>Name</th><td></td></tr><tr><th>Signature</th><td></td></tr><tr><th>Date</th><td></td></tr></table></section>");
    h
}
