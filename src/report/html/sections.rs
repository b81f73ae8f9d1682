//! The report's sections that show the result's numbers: headline, data sets and
//! parameters.

use std::fmt::Write;

use serde_json::Value;

use super::assessment::num_table;
use super::{Envelope, ReportInput, cell_html, num_cell, number, text};
use crate::report::svg::escape;
use crate::report::view::{DesignView, Reportable};

/// The headline numbers: before and after calibration, first thing in the report.
pub(super) fn headline(r: &dyn Reportable) -> String {
    let before = match r.before_label() {
        Some(l) => format!("before: {}", escape(&l)),
        None => "before calibration".into(),
    };
    let mut h = format!(
        "<section><h2>Result</h2><table class=\"headline\"><thead><tr><th></th><th data-before>{before}</th><th>after calibration</th><th>unit</th><th>ratio before / after</th></tr></thead><tbody>",
    );
    let ls = r.headline();
    for l in &ls {
        let (b, a) = (l.before.value, l.after.value);
        let ratio = if a > 0.0 && b.is_finite() && a.is_finite() {
            number(b / a)
        } else {
            "—".into()
        };
        let _ = write!(
            h,
            "<tr><th>{}</th>{}{}<td>{}</td><td class=\"num\">{ratio}</td></tr>",
            escape(&l.label),
            num_cell(&l.before),
            num_cell(&l.after),
            escape(&l.unit)
        );
    }
    h.push_str("</tbody></table>");
    if ls.is_empty() {
        h.push_str("<p class=\"meta\">This kind of job reports no before/after errors.</p>");
    }
    if let Some(ps) = r.parameters() {
        let identified = ps.rows.iter().filter(|p| p.identifiable).count();
        let _ = write!(
            h,
            "<p>Parameters identified: <strong data-count=\"identified\">{identified}</strong> of {} (the others are held; see the parameter table).",
            ps.rows.len()
        );
        if let Some(c) = ps.condition_number {
            let _ = write!(h, " Condition number {}.", number(c));
        }
        h.push_str("</p>");
    }
    if let Some(c) = r.convergence() {
        let status = c
            .status
            .or_else(|| c.converged.map(|b| b.to_string()))
            .map(|s| escape(&s))
            .unwrap_or_else(|| "—".into());
        let _ = write!(
            h,
            "<p>Convergence: {status}{}.</p>",
            c.iterations
                .map(|i| format!(", {i} iterations"))
                .unwrap_or_default()
        );
    }
    h.push_str("</section>");
    h
}

/// A design of experiments: what was chosen, O1..O5 against the pool, the search's
/// history (in place of before/after errors, which a design has none of).
pub(super) fn design(d: &DesignView) -> String {
    format!(
        "<section id=\"design\"><h2>Design</h2><p>{}</p>{}{}{}</section>",
        escape(&d.summary),
        num_table(&d.observability),
        num_table(&d.selected),
        num_table(&d.history)
    )
}

/// Inputs and their SHA-256, and the campaign's measurement counts.
pub(super) fn datasets(job: &Value, env: &Envelope, r: &dyn Reportable) -> String {
    let mut h = String::from(
        "<section><h2>Data sets</h2><table><thead><tr><th>input</th><th>SHA-256</th></tr></thead><tbody>",
    );
    if env.inputs_sha256.is_empty() {
        let hashes = job.get("inputs_sha256").and_then(Value::as_object);
        for (name, hash) in hashes.into_iter().flatten() {
            let _ = write!(
                h,
                "<tr><td>{}</td><td><code>{}</code></td></tr>",
                escape(name),
                text(Some(hash))
            );
        }
    }
    for (name, hash) in &env.inputs_sha256 {
        let _ = write!(
            h,
            "<tr><td>{}</td><td><code>{}</code></td></tr>",
            escape(name),
            escape(hash)
        );
    }
    h.push_str("</tbody></table>");
    for f in r.facts() {
        let _ = write!(
            h,
            "<table><thead><tr><th colspan=\"2\">{}</th></tr></thead><tbody>",
            escape(&f.name)
        );
        for (k, v) in &f.rows {
            let _ = write!(h, "<tr><th>{}</th>{}</tr>", escape(k), cell_html(v));
        }
        h.push_str("</tbody></table>");
    }
    h.push_str("</section>");
    h
}

/// Where the nominal values come from: for a cell that had an accepted model before this
/// job started, that earlier calibration.
fn nominal_note(input: &ReportInput<'_>) -> String {
    let started = input.envelope.started_at.as_deref().unwrap_or("");
    let id = input.job.get("id").and_then(Value::as_i64);
    let earlier = input.cell_history.iter().find(|m| {
        let accepted = matches!(
            m.get("state").and_then(Value::as_str),
            Some("current" | "superseded")
        );
        let at = m.get("at").and_then(Value::as_str).unwrap_or("");
        accepted
            && m.get("job_id").and_then(Value::as_i64) != id
            && !started.is_empty()
            && at < started
    });
    match earlier {
        Some(m) => format!(
            "<p class=\"warn\">Nominal: the cell's model when this job started, which is the calibration accepted from job {} at {} (not the manufacturer's nominal).</p>",
            text(m.get("job_id")),
            text(m.get("at"))
        ),
        None => {
            "<p class=\"meta\">Nominal: the value in the model this job started from.</p>".into()
        }
    }
}

/// The parameter table: nominal, identified, std, status and effect size.
pub(super) fn parameters(input: &ReportInput<'_>) -> String {
    let Some(ps) = input.result.parameters() else {
        return String::new();
    };
    let held = input.result.held();
    let mut h = String::from("<section><h2>Parameters</h2>");
    h.push_str(&nominal_note(input));
    let _ = write!(
        h,
        "<table class=\"params\"><thead><tr><th>parameter</th><th>unit</th><th>nominal</th><th>identified</th><th>change</th><th>std</th><th>status</th><th>effect size ({})</th></tr></thead><tbody>",
        escape(&ps.effect_unit)
    );
    for p in &ps.rows {
        let name = p.name.as_str();
        let (status, class) = if !p.identifiable && held.unobservable.iter().any(|n| n == name) {
            ("held: effect below the noise".to_string(), "held")
        } else if !p.identifiable {
            ("held: not identifiable from these data".to_string(), "held")
        } else if held.weakly_observable.iter().any(|n| n == name) {
            ("identified, weakly observable".to_string(), "weak")
        } else if let Some(b) = &p.at_bound {
            (format!("identified, at its {} bound", escape(b)), "weak")
        } else {
            ("identified".to_string(), "")
        };
        let change = number(p.value.value - p.nominal.value);
        let std = p
            .std
            .as_ref()
            .map(num_cell)
            .unwrap_or_else(|| r#"<td class="num">—</td>"#.into());
        let _ = write!(
            h,
            "<tr data-param=\"{}\" class=\"{class}\"><td>{}</td><td>{}</td>{}{}<td class=\"num\">{change}</td>{std}<td>{status}</td>{}</tr>",
            escape(name),
            escape(name),
            escape(&p.unit),
            num_cell(&p.nominal),
            num_cell(&p.value),
            num_cell(&p.effect_size),
        );
    }
    h.push_str("</tbody></table><p class=\"meta\">Effect size: the largest change of any residual over the parameter's plausible range. Held parameters keep their nominal value.</p></section>");
    h
}
