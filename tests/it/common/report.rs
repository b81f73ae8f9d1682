//! Helpers of the report tests: render a job's report and read back what it shows.

use calibd::jobs::Completed;
use calibd::jobs::report_view::typed_result;
use calibd::report::html::{Envelope, ReportInput, number, render};
use serde_json::{Value, json};

/// (pointer, shown text) of every number cell of the report.
pub fn pointed_cells(html: &str) -> Vec<(String, String)> {
    let mut out = Vec::new();
    for part in html.split("data-pointer=\"").skip(1) {
        let Some((pointer, rest)) = part.split_once('"') else {
            continue;
        };
        let Some(text) = rest
            .split_once('>')
            .and_then(|(_, r)| r.split_once('<'))
            .map(|(t, _)| t)
        else {
            continue;
        };
        out.push((pointer.to_string(), text.to_string()));
    }
    out
}

/// The inline SVG of the figure holding artefact `name`.
pub fn figure<'a>(html: &'a str, name: &str) -> &'a str {
    let start = html
        .find(&format!("<figure data-name=\"{name}\">"))
        .unwrap_or_else(|| panic!("no figure {name}"));
    let rest = &html[start..];
    &rest[..rest.find("</figure>").unwrap_or(rest.len())]
}

pub fn report_of(done: &Completed) -> String {
    report_with(done, &[])
}

/// The report of `done` with a campaign journal.
pub fn report_with(done: &Completed, journal: &[Value]) -> String {
    let job = json!({"id": 42, "kind": done.result["kind"], "state": "succeeded",
        "submitted_by": "tester <qa>", "devices": [], "inputs_sha256": done.result["inputs_sha256"]});
    let envelope = Envelope::read(&done.result);
    let html = render(&ReportInput {
        job: &job,
        envelope: &envelope,
        result: typed_result(&done.result).as_ref(),
        artefacts: &done.artefacts,
        cell_history: &[],
        journal,
        generator_version: "test",
        generated_at: "2026-11-25T18:00:00Z",
    });
    // A kind with a typed result must read as its type (else the report warns).
    assert!(
        !html.contains("does not read as"),
        "the stored result did not read as its kind's type"
    );
    html
}

/// Every number cell of the report shows the result's number at its pointer.
pub fn assert_cells_are_the_result(html: &str, r: &Value) -> Vec<(String, String)> {
    let cells = pointed_cells(html);
    for (pointer, text) in &cells {
        let v = r
            .pointer(pointer)
            .and_then(Value::as_f64)
            .unwrap_or_else(|| panic!("{pointer} is not a number of the result"));
        assert_eq!(text, &number(v), "{pointer}");
        // Independently of the formatter: the text reads back as the value (4 digits).
        let back: f64 = text.parse().unwrap_or_else(|_| panic!("{pointer}: {text}"));
        assert!(
            (back - v).abs() <= 6e-4 * v.abs() + 1e-300,
            "{pointer}: shown {text}, result {v}"
        );
    }
    cells
}
