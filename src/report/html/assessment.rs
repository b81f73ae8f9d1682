//! The report's sections that judge the result: the verdict of an identification with its
//! reasons (first in the report), validation (held-out errors, Table 3, cross-validation),
//! warnings, and the sign-off.

use std::fmt::Write;

use serde_json::Value;

use super::{ReportInput, cell_html, opt_text, text};
use crate::report::svg::escape;
use crate::report::view::{NumTable, Reportable};

/// A table of numbers with its title and note.
pub(super) fn num_table(t: &NumTable) -> String {
    let mut h = format!("<h3>{}</h3><table><thead><tr>", escape(&t.title));
    for k in &t.head {
        let _ = write!(h, "<th>{}</th>", escape(k));
    }
    h.push_str("</tr></thead><tbody>");
    for row in &t.rows {
        h.push_str("<tr>");
        for c in row {
            h.push_str(&cell_html(c));
        }
        h.push_str("</tr>");
    }
    h.push_str("</tbody></table>");
    if let Some(m) = &t.note {
        let _ = write!(h, "<p class=\"meta\">{}</p>", escape(m));
    }
    h
}

/// Validation: held-out errors, the PCR Table 3, cross-validation folds.
pub(super) fn validation(r: &dyn Reportable) -> String {
    let mut h = String::new();
    for t in r.tables() {
        h.push_str(&num_table(&t));
    }
    if h.is_empty() {
        h.push_str("<p class=\"warn\">No held-out validation: the job had no validation set. The errors above are residuals of the fit, which understate the error on new poses.</p>");
    }
    format!("<section><h2>Validation</h2>{h}</section>")
}

/// The verdict (`accepted`, `review`, `rejected`) and its reasons; empty for results
/// without one (kinds that are not identifications).
pub(super) fn verdict(r: &dyn Reportable) -> String {
    let Some(block) = r.verdict() else {
        return String::new();
    };
    let a = &block.assessment;
    let v = a.verdict.as_str();
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
    if !a.reasons.is_empty() {
        h.push_str("<table><tr><th>reason</th><th>gives</th><th>what was found</th></tr>");
        for x in &a.reasons {
            let _ = write!(
                h,
                "<tr><td><code>{}</code></td><td>{}</td><td>{}</td></tr>",
                escape(&x.code),
                escape(x.severity.as_str()),
                escape(&x.message)
            );
        }
        h.push_str("</table>");
    }
    if let Some(d) = block.dof {
        let _ = write!(
            h,
            r#"<p class="meta">Residual degrees of freedom: {d}.</p>"#
        );
    }
    h.push_str("</section>");
    h
}

/// Warnings: the result's own, convergence, held and weakly observable parameters.
pub(super) fn warnings(r: &dyn Reportable) -> String {
    let mut w: Vec<String> = r.warnings().iter().map(|s| escape(s)).collect();
    if let Some(c) = r.convergence() {
        if c.converged == Some(false) {
            w.push(format!(
                "the fit did not converge: {}",
                opt_text(c.status.as_deref())
            ));
        }
        if let Some(d) = &c.degenerate {
            w.push(format!("degenerate solution: {}", escape(d)));
        }
    }
    let held = r.held();
    if !held.unidentifiable.is_empty() {
        w.push(format!(
            "{} parameters held at nominal (not identifiable from these data): {}",
            held.unidentifiable.len(),
            escape(&held.unidentifiable.join(", "))
        ));
    }
    if !held.weakly_observable.is_empty() {
        w.push(format!(
            "weakly observable: {}",
            escape(&held.weakly_observable.join(", "))
        ));
    }
    if let Some(ps) = r.parameters() {
        let at: Vec<String> = ps
            .rows
            .iter()
            .filter(|p| p.at_bound.is_some())
            .map(|p| escape(&p.name))
            .collect();
        if !at.is_empty() {
            w.push(format!("at a bound: {}", at.join(", ")));
        }
    }
    if let Some(g) = r.gauge_freedom() {
        w.push(format!("gauge freedom: {}", escape(&g)));
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
    let env = input.envelope;
    let id = input.job.get("id").and_then(Value::as_i64);
    let mut h = String::from("<section class=\"sign\"><h2>Sign-off</h2><table>");
    let what = format!(
        "{} (job {}){}",
        opt_text(env.kind.as_deref()),
        text(input.job.get("id")),
        input
            .result
            .parameters()
            .map(|p| format!(", {} parameters", p.rows.len()))
            .unwrap_or_default()
    );
    let _ = write!(h, "<tr><th>What was calibrated</th><td>{what}</td></tr>");
    let _ = write!(
        h,
        "<tr><th>When (finished, UTC)</th><td>{}</td></tr>",
        opt_text(env.finished_at.as_deref())
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
