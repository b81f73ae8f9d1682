//! The report's sections that show the result's numbers: headline, data sets and
//! parameters.

use std::fmt::Write;

use serde_json::Value;

use super::{ReportInput, num_cell, number, text};
use crate::report::svg::escape;

/// One headline line: the same quantity before and after calibration.
struct Line {
    label: &'static str,
    before: String,
    after: String,
    unit: String,
}

pub(super) fn unit_at(r: &Value, pointer: &str, default: &str) -> String {
    r.pointer(pointer)
        .and_then(Value::as_str)
        .unwrap_or(default)
        .to_string()
}

fn lines(r: &Value) -> Vec<Line> {
    let mut out = Vec::new();
    let mut pair = |label, before: &str, after: &str, unit: String| {
        if r.pointer(before).is_some() && r.pointer(after).is_some() {
            out.push(Line {
                label,
                before: before.into(),
                after: after.into(),
                unit,
            });
        }
    };
    // Serial kinds (and their campaigns): residuals and held-out validation.
    let u = unit_at(r, "/residuals/after/unit", "mm");
    pair(
        "Residual mean, calibration set",
        "/residuals/before/mean",
        "/residuals/after/mean",
        u.clone(),
    );
    pair(
        "Residual max, calibration set",
        "/residuals/before/max",
        "/residuals/after/max",
        u,
    );
    // Humanoid kinds: marker RMSE and cross-validation.
    pair(
        "Marker RMSE, calibration set",
        "/rmse_before_mm",
        "/rmse_after_mm",
        "mm".into(),
    );
    pair(
        "Held-out marker RMSE (cross-validation)",
        "/cross_validation/rmse_nominal_mm",
        "/cross_validation/rmse_calibrated_mm",
        "mm".into(),
    );
    // PCR kinds: the paper's Table 3.
    for (set, label_p, label_t) in [
        (
            "calibration",
            "Position error e_P mean, calibration set",
            "Orientation error e_θ mean, calibration set",
        ),
        (
            "validation",
            "Position error e_P mean, validation set",
            "Orientation error e_θ mean, validation set",
        ),
    ] {
        let p = format!("/model_error/{set}");
        let up = unit_at(r, &format!("{p}/e_P/unit"), "µm");
        let ut = unit_at(r, &format!("{p}/e_theta/unit"), "mrad");
        pair(
            label_p,
            &format!("{p}/e_P/nominal/mean"),
            &format!("{p}/e_P/identified/mean"),
            up,
        );
        pair(
            label_t,
            &format!("{p}/e_theta/nominal/mean"),
            &format!("{p}/e_theta/identified/mean"),
            ut,
        );
    }
    let u = unit_at(r, "/validation/after/unit", "mm");
    pair(
        "Held-out error mean, validation set",
        "/validation/before/mean",
        "/validation/after/mean",
        u.clone(),
    );
    pair(
        "Held-out error max, validation set",
        "/validation/before/max",
        "/validation/after/max",
        u,
    );
    out
}

/// The headline numbers: before and after calibration, first thing in the report.
pub(super) fn headline(r: &Value) -> String {
    let mut h = String::from(
        "<section><h2>Result</h2><table class=\"headline\"><thead><tr><th></th><th>before calibration</th><th>after calibration</th><th>unit</th><th>ratio before / after</th></tr></thead><tbody>",
    );
    let ls = lines(r);
    for l in &ls {
        let ratio = match (
            r.pointer(&l.before).and_then(Value::as_f64),
            r.pointer(&l.after).and_then(Value::as_f64),
        ) {
            (Some(b), Some(a)) if a > 0.0 => number(b / a),
            _ => "—".into(),
        };
        let _ = write!(
            h,
            "<tr><th>{}</th>{}{}<td>{}</td><td class=\"num\">{ratio}</td></tr>",
            escape(l.label),
            num_cell(r, &l.before),
            num_cell(r, &l.after),
            escape(&l.unit)
        );
    }
    h.push_str("</tbody></table>");
    if ls.is_empty() {
        h.push_str("<p class=\"meta\">This kind of job reports no before/after errors.</p>");
    }
    if let Some(ps) = r.get("parameters").and_then(Value::as_array) {
        let identified = ps
            .iter()
            .filter(|p| p.get("identifiable").and_then(Value::as_bool) == Some(true))
            .count();
        let _ = write!(
            h,
            "<p>Parameters identified: <strong data-count=\"identified\">{identified}</strong> of {} (the others are held; see the parameter table).",
            ps.len()
        );
        if let Some(c) = r.get("condition_number").and_then(Value::as_f64) {
            let _ = write!(h, " Condition number {}.", number(c));
        }
        h.push_str("</p>");
    }
    if let Some(c) = r.get("convergence") {
        let _ = write!(
            h,
            "<p>Convergence: {}{}.</p>",
            text(c.get("status").or_else(|| c.get("converged"))),
            c.get("iterations")
                .map(|i| format!(", {} iterations", text(Some(i))))
                .unwrap_or_default()
        );
    }
    h.push_str("</section>");
    h
}

/// Inputs and their SHA-256, and the campaign's measurement counts.
pub(super) fn datasets(job: &Value, r: &Value) -> String {
    let mut h = String::from(
        "<section><h2>Data sets</h2><table><thead><tr><th>input</th><th>SHA-256</th></tr></thead><tbody>",
    );
    let hashes = r
        .get("inputs_sha256")
        .or_else(|| job.get("inputs_sha256"))
        .and_then(Value::as_object);
    for (name, hash) in hashes.into_iter().flatten() {
        let _ = write!(
            h,
            "<tr><td>{}</td><td><code>{}</code></td></tr>",
            escape(name),
            text(Some(hash))
        );
    }
    h.push_str("</tbody></table>");
    for key in ["campaign", "samples"] {
        let Some(o) = r.get(key).and_then(Value::as_object) else {
            continue;
        };
        let _ = write!(
            h,
            "<table><thead><tr><th colspan=\"2\">{key}</th></tr></thead><tbody>"
        );
        for (k, v) in o.iter().filter(|(_, v)| !v.is_object() && !v.is_array()) {
            let cell = match v.as_f64() {
                Some(_) => num_cell(r, &format!("/{key}/{k}")),
                None => format!("<td>{}</td>", text(Some(v))),
            };
            let _ = write!(h, "<tr><th>{}</th>{cell}</tr>", escape(k));
        }
        h.push_str("</tbody></table>");
    }
    h.push_str("</section>");
    h
}

pub(super) fn names(r: &Value, key: &str) -> Vec<String> {
    r.get(key)
        .and_then(Value::as_array)
        .map(|a| {
            a.iter()
                .filter_map(|v| v.as_str().or_else(|| v.get("name").and_then(Value::as_str)))
                .map(str::to_string)
                .collect()
        })
        .unwrap_or_default()
}

/// Where the nominal values come from: for a cell that had an accepted model before this
/// job started, that earlier calibration.
fn nominal_note(input: &ReportInput<'_>) -> String {
    let started = input
        .result
        .get("started_at")
        .and_then(Value::as_str)
        .unwrap_or("");
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
    let r = input.result;
    let Some(ps) = r.get("parameters").and_then(Value::as_array) else {
        return String::new();
    };
    let weak = names(r, "weakly_observable");
    let unobservable = names(r, "unobservable");
    let effect_unit = unit_at(r, "/residual_std/unit", "m");
    let mut h = String::from("<section><h2>Parameters</h2>");
    h.push_str(&nominal_note(input));
    let _ = write!(
        h,
        "<table class=\"params\"><thead><tr><th>parameter</th><th>unit</th><th>nominal</th><th>identified</th><th>change</th><th>std</th><th>status</th><th>effect size ({})</th></tr></thead><tbody>",
        escape(&effect_unit)
    );
    for (i, p) in ps.iter().enumerate() {
        let name = p.get("name").and_then(Value::as_str).unwrap_or("?");
        let identifiable = p
            .get("identifiable")
            .and_then(Value::as_bool)
            .unwrap_or(true);
        let (status, class) = if !identifiable && unobservable.iter().any(|n| n == name) {
            ("held: effect below the noise".to_string(), "held")
        } else if !identifiable {
            ("held: not identifiable from these data".to_string(), "held")
        } else if weak.iter().any(|n| n == name) {
            ("identified, weakly observable".to_string(), "weak")
        } else if let Some(b) = p.get("at_bound").and_then(Value::as_str) {
            (format!("identified, at its {} bound", escape(b)), "weak")
        } else {
            ("identified".to_string(), "")
        };
        let change = match (
            p.get("value").and_then(Value::as_f64),
            p.get("nominal").and_then(Value::as_f64),
        ) {
            (Some(v), Some(n)) => number(v - n),
            _ => "—".into(),
        };
        let _ = write!(
            h,
            "<tr data-param=\"{}\" class=\"{class}\"><td>{}</td><td>{}</td>{}{}<td class=\"num\">{change}</td>{}<td>{status}</td>{}</tr>",
            escape(name),
            escape(name),
            text(p.get("unit")),
            num_cell(r, &format!("/parameters/{i}/nominal")),
            num_cell(r, &format!("/parameters/{i}/value")),
            num_cell(r, &format!("/parameters/{i}/std")),
            num_cell(r, &format!("/parameters/{i}/effect_size")),
        );
    }
    h.push_str("</tbody></table><p class=\"meta\">Effect size: the largest change of any residual over the parameter's plausible range. Held parameters keep their nominal value.</p></section>");
    h
}
