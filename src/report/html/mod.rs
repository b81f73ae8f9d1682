//! The printable report of a job: one self-contained HTML document (inline CSS and SVG,
//! no script, nothing fetched) with the job, its data sets and their hashes, a campaign's
//! measurement journal, the model,
//! the headline numbers, the parameter table with each parameter's observability, the
//! plots, validation, warnings, the software version and a section a quality engineer
//! signs off.
//!
//! The report reads the stored job record, result JSON and artefacts, never models.
//! Every user-supplied string is HTML-escaped. Every number shown from the result carries
//! `data-pointer` (its JSON pointer in the result), so a test or a reader can check the
//! report against the result JSON.

mod assessment;
mod journal;
mod sections;

pub use journal::journal_number;

use std::fmt::Write;

use std::collections::BTreeMap;

use serde::Deserialize;
use serde_json::Value;
use sha2::{Digest, Sha256};

use super::svg::escape;
use super::view::{Cell, Num, Reportable};
use crate::run::Artefact;

/// What a report is made of: the stored job, its result (envelope and typed content) and
/// artefacts, and the cell's model history (when the job calibrated a cell).
#[derive(Debug, Clone, Copy)]
pub struct ReportInput<'a> {
    /// The job record (`GET /v1/jobs/{id}`).
    pub job: &'a Value,
    /// The result's envelope (`GET /v1/jobs/{id}/result`, read once by [`Envelope::read`]).
    pub envelope: &'a Envelope,
    /// The result's content, typed by its kind (`jobs::report_view`).
    pub result: &'a dyn Reportable,
    /// The job's artefacts; the SVG plots among them are embedded.
    pub artefacts: &'a [Artefact],
    /// The model history of the job's cell, newest first (`[]` when none).
    pub cell_history: &'a [Value],
    /// A campaign's measurement journal: its entries (`index`, `status`, `data`) in index
    /// order (`GET /v1/jobs/{id}/measurements`; `[]` for a job that measured nothing).
    pub journal: &'a [Value],
    /// Version of the calibd that writes the report.
    pub generator_version: &'a str,
    /// When the report is written (RFC 3339).
    pub generated_at: &'a str,
}

/// The fields every stored result carries (the job envelope) and the stored model the
/// report hashes, read once from the result JSON; the kind's content is a [`Reportable`].
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(default)]
pub struct Envelope {
    /// The job kind.
    pub kind: Option<String>,
    /// Start of the run (RFC 3339, UTC).
    pub started_at: Option<String>,
    /// End of the run.
    pub finished_at: Option<String>,
    /// Run time (s).
    pub duration_s: Option<f64>,
    /// The calibd that produced the result.
    pub calibd_version: Option<String>,
    /// SHA-256 of each input, by field name.
    pub inputs_sha256: BTreeMap<String, String>,
    /// The cell a campaign calibrated.
    pub cell: Option<String>,
    /// The calibrated model as stored (hashed as stored).
    pub calibrated_model: Option<Value>,
    /// The model of a rejected identification.
    pub rejected_model: Option<Value>,
    /// A note on the calibrated URDF.
    pub calibrated_urdf_note: Option<String>,
    /// How the gauge of the calibrated model is fixed.
    pub gauge: Option<String>,
}

impl Envelope {
    /// The envelope of a stored result (empty fields for anything missing or malformed).
    pub fn read(result: &Value) -> Self {
        Self::deserialize(result).unwrap_or_default()
    }
}

/// A number as the report prints it: 4 significant digits, exponent form for very small
/// or large magnitudes.
pub fn number(v: f64) -> String {
    if !v.is_finite() {
        return "—".into();
    }
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        format!("{v:.3e}")
    } else {
        let decimals = (3 - a.log10().floor() as i32).max(0) as usize;
        format!("{v:.decimals$}")
    }
}

/// A `<td>` with a number of the result and its pointer (a dash when not finite).
pub(crate) fn num_cell(n: &Num) -> String {
    if n.value.is_finite() {
        format!(
            r#"<td class="num" data-pointer="{}">{}</td>"#,
            escape(&n.pointer),
            number(n.value)
        )
    } else {
        r#"<td class="num">—</td>"#.into()
    }
}

/// A table cell as HTML.
pub(crate) fn cell_html(c: &Cell) -> String {
    match c {
        Cell::Head(t) => format!("<th>{}</th>", escape(t)),
        Cell::Text(t) => format!("<td>{}</td>", escape(t)),
        Cell::Num(n) => num_cell(n),
        Cell::Missing => r#"<td class="num">—</td>"#.into(),
    }
}

/// The text of a JSON string (or the JSON of anything else), escaped.
pub(crate) fn text(v: Option<&Value>) -> String {
    match v {
        None | Some(Value::Null) => "—".into(),
        Some(Value::String(s)) => escape(s),
        Some(other) => escape(&other.to_string()),
    }
}

/// Optional text, escaped (a dash when none).
pub(crate) fn opt_text(v: Option<&str>) -> String {
    v.map(escape).unwrap_or_else(|| "—".into())
}

/// The cell a job calibrated: the result's `cell`, else the prefix of its first device
/// (`cell.device`); none for an offline job.
pub fn cell_name(job: &Value, envelope: &Envelope) -> Option<String> {
    if let Some(c) = &envelope.cell {
        return Some(c.clone());
    }
    job.get("devices")
        .and_then(Value::as_array)
        .and_then(|d| d.first())
        .and_then(Value::as_str)
        .and_then(|d| d.split_once('.'))
        .map(|(cell, _)| cell.to_string())
}

const CSS: &str = "body{font-family:sans-serif;max-width:60rem;margin:1.5rem auto;padding:0 1rem;color:#111}\
h1{font-size:1.5rem;margin-bottom:.2rem}h2{font-size:1.15rem;border-bottom:1px solid #999;margin-top:1.6rem}\
table{border-collapse:collapse;margin:.4rem 0 .8rem}th,td{border:1px solid #bbb;padding:.15rem .45rem;font-size:.85rem;text-align:left}\
td.num{text-align:right;font-variant-numeric:tabular-nums}.meta{color:#555;font-size:.85rem}\
.headline td.num{font-size:1.05rem;font-weight:bold}.warn{color:#8a3b00}.held{color:#666}.weak{color:#8a3b00}\
figure{margin:.6rem 0;break-inside:avoid}figure svg{max-width:100%;height:auto;border:1px solid #ddd}\
.sign td{height:2rem;min-width:14rem}code{font-size:.8rem;word-break:break-all}\
@media print{body{margin:0;max-width:none}h2{break-after:avoid}section{break-inside:avoid-page}}";

/// The whole report.
pub fn render(input: &ReportInput<'_>) -> String {
    let (job, env, result) = (input.job, input.envelope, input.result);
    let id = job.get("id").and_then(Value::as_i64).unwrap_or(0);
    let kind = env
        .kind
        .as_deref()
        .or_else(|| job.get("kind").and_then(Value::as_str))
        .unwrap_or("?");
    let mut h = String::new();
    let _ = write!(
        h,
        r#"<!doctype html><html lang="en"><head><meta charset="utf-8"><title>Calibration report: job {id} ({})</title><style>{CSS}</style></head><body>"#,
        escape(kind)
    );
    let cell = cell_name(job, env);
    let _ = write!(
        h,
        r#"<header><h1>Calibration report: job {id}, <code>{}</code>{}</h1><p class="meta">Written {} by calibd {}; the result was produced by calibd {}.</p></header>"#,
        escape(kind),
        cell.as_deref()
            .map(|c| format!(", cell <code>{}</code>", escape(c)))
            .unwrap_or_default(),
        escape(input.generated_at),
        escape(input.generator_version),
        opt_text(env.calibd_version.as_deref()),
    );
    h.push_str(&assessment::verdict(result));
    let design = result.design();
    match &design {
        Some(d) => h.push_str(&sections::design(d)),
        None => h.push_str(&sections::headline(result)),
    }
    h.push_str(&job_section(input));
    h.push_str(&sections::datasets(job, env, result));
    h.push_str(&journal::journal(input.journal));
    h.push_str(&model_section(env));
    h.push_str(&sections::parameters(input));
    if design.is_none() {
        h.push_str(&assessment::validation(result));
    }
    h.push_str(&plots_section(input.artefacts));
    h.push_str(&assessment::warnings(result));
    h.push_str(&assessment::sign_off(input, cell.as_deref()));
    h.push_str("</body></html>\n");
    h
}

fn row(h: &mut String, name: &str, value: &str) {
    let _ = write!(h, "<tr><th>{name}</th><td>{value}</td></tr>");
}

fn job_section(input: &ReportInput<'_>) -> String {
    let j = input.job;
    let r = input.envelope;
    let mut h = String::from("<section><h2>Job</h2><table>");
    row(&mut h, "id", &text(j.get("id")));
    row(&mut h, "kind", &text(j.get("kind")));
    row(&mut h, "state", &text(j.get("state")));
    row(&mut h, "submitted by", &text(j.get("submitted_by")));
    row(&mut h, "submitted at (UTC)", &text(j.get("submitted_at")));
    row(
        &mut h,
        "started at (UTC)",
        &opt_text(r.started_at.as_deref()),
    );
    row(
        &mut h,
        "finished at (UTC)",
        &opt_text(r.finished_at.as_deref()),
    );
    if let Some(d) = r.duration_s {
        row(&mut h, "duration", &format!("{} s", number(d)));
    }
    if let Some(d) = j
        .get("devices")
        .and_then(Value::as_array)
        .filter(|d| !d.is_empty())
    {
        let names: Vec<String> = d.iter().map(|x| text(Some(x))).collect();
        row(&mut h, "devices", &names.join(", "));
    }
    if let Some(s) = j.get("schedule_id").filter(|v| !v.is_null()) {
        row(&mut h, "submitted by schedule", &text(Some(s)));
    }
    if let Some(s) = j.get("rerun_of").filter(|v| !v.is_null()) {
        row(&mut h, "re-run of job", &text(Some(s)));
    }
    h.push_str("</table></section>");
    h
}

/// SHA-256 (hex) of a JSON value as the result stores it (a URDF: its text).
fn sha256_of(v: &Value) -> String {
    let bytes = match v {
        Value::String(s) => s.clone().into_bytes(),
        other => other.to_string().into_bytes(),
    };
    let d = Sha256::digest(&bytes);
    d.iter().map(|b| format!("{b:02x}")).collect()
}

fn model_section(env: &Envelope) -> String {
    let rejected = env.calibrated_model.is_none();
    let Some(m) = env
        .calibrated_model
        .as_ref()
        .or(env.rejected_model.as_ref())
    else {
        return String::new();
    };
    let form = match m {
        Value::String(_) => "URDF text (the calibrated joint origins folded in)",
        Value::Object(o) if o.contains_key("dh") || o.contains_key("joints") => {
            "DH model file (JSON)"
        }
        Value::Object(_) => "model file (JSON)",
        _ => "model",
    };
    let mut h = String::from("<section><h2>Model</h2><table>");
    if rejected {
        row(&mut h, "rejected model (not a calibration)", form);
    } else {
        row(&mut h, "calibrated model", form);
    }
    row(
        &mut h,
        "SHA-256 of the calibrated model",
        &format!("<code>{}</code>", sha256_of(m)),
    );
    if let Some(n) = &env.calibrated_urdf_note {
        row(&mut h, "note", &escape(n));
    }
    if let Some(g) = &env.gauge {
        row(&mut h, "gauge", &escape(g));
    }
    h.push_str("</table><p class=\"meta\">The calibrated model is the artefact of the job (download it from the job; its hash is above). The model the job started from is named by its hash under Data sets.</p></section>");
    h
}

/// Whether an artefact is an SVG this daemon drew (inline-safe: no script, no foreign
/// content, no external references).
fn embeddable_svg(a: &Artefact) -> Option<&str> {
    if a.media_type != "image/svg+xml" {
        return None;
    }
    let s = std::str::from_utf8(&a.content).ok()?.trim();
    let lower = s.to_ascii_lowercase();
    let bad = [
        "<script",
        "<foreignobject",
        "href",
        "<iframe",
        "javascript:",
    ];
    (s.starts_with("<svg")
        && s.ends_with("</svg>")
        && !bad.iter().any(|b| lower.contains(b))
        && !has_event_attribute(&lower))
    .then_some(s)
}

/// Whether markup holds an ` on...=` attribute (an event handler).
fn has_event_attribute(lower: &str) -> bool {
    lower.match_indices(" on").any(|(i, _)| {
        let rest = &lower[i + 3..];
        let name_len = rest.bytes().take_while(u8::is_ascii_alphabetic).count();
        name_len > 0 && rest[name_len..].trim_start().starts_with('=')
    })
}

fn plots_section(artefacts: &[Artefact]) -> String {
    let mut h = String::new();
    for a in artefacts {
        if let Some(svg) = embeddable_svg(a) {
            let _ = write!(
                h,
                r#"<figure data-name="{}">{svg}<figcaption class="meta">{}</figcaption></figure>"#,
                escape(&a.name),
                escape(&a.name)
            );
        }
    }
    if h.is_empty() {
        return String::new();
    }
    format!("<section><h2>Plots</h2>{h}</section>")
}

#[cfg(test)]
mod tests;
