//! The printable report of each calibration method (serial, PCR, humanoid), rendered from
//! a job run on the examples' twin data: every number it shows is the result JSON's (read
//! back through its `data-pointer`), the headline numbers are there, the plots are inline
//! with the "after" series drawn at a visible size, and nothing is fetched.

mod common;

use calibd::jobs::Completed;
use calibd::report::html::{ReportInput, number, render};
use calibd::report::plots::AFTER;
use calibd::report::svg::series_marks;
use common::{example, run_in_examples};
use serde_json::{Value, json};

/// (pointer, shown text) of every number cell of the report.
fn pointed_cells(html: &str) -> Vec<(String, String)> {
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
fn figure<'a>(html: &'a str, name: &str) -> &'a str {
    let start = html
        .find(&format!("<figure data-name=\"{name}\">"))
        .unwrap_or_else(|| panic!("no figure {name}"));
    let rest = &html[start..];
    &rest[..rest.find("</figure>").unwrap_or(rest.len())]
}

fn report_of(done: &Completed) -> String {
    let job = json!({"id": 42, "kind": done.result["kind"], "state": "succeeded",
        "submitted_by": "tester <qa>", "devices": [], "inputs_sha256": done.result["inputs_sha256"]});
    render(&ReportInput {
        job: &job,
        result: &done.result,
        artefacts: &done.artefacts,
        cell_history: &[],
        generator_version: "test",
        generated_at: "2026-11-25T18:00:00Z",
    })
}

/// Checks common to every method; returns the report.
fn check(done: &Completed, headline: &[&str], plots: &[&str]) -> String {
    let r = &done.result;
    let html = report_of(done);
    let cells = pointed_cells(&html);
    assert!(cells.len() > 20, "only {} number cells", cells.len());
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
    for p in headline {
        assert!(
            cells.iter().any(|(q, _)| q == p),
            "headline number {p} missing"
        );
    }
    // Every parameter of the result is a row, with its identified value.
    let params = r["parameters"].as_array().expect("parameters");
    for (i, p) in params.iter().enumerate() {
        let name = p["name"].as_str().unwrap_or("");
        assert!(html.contains(&format!("data-param=\"{name}\"")), "{name}");
        assert!(
            cells
                .iter()
                .any(|(q, _)| *q == format!("/parameters/{i}/value"))
        );
    }
    let identified = params
        .iter()
        .filter(|p| p["identifiable"].as_bool() == Some(true))
        .count();
    assert!(html.contains(&format!("data-count=\"identified\">{identified}<")));
    for k in r["inputs_sha256"].as_object().expect("hashes").values() {
        assert!(html.contains(k.as_str().unwrap_or("-")), "hash {k}");
    }
    // The plots: inline, with the after series visible beside the before one.
    for name in plots {
        let svg = figure(&html, name);
        let after = series_marks(svg, AFTER);
        assert!(!after.is_empty(), "{name}: no after series");
        let shown = after.iter().filter(|m| m.extent >= 2.0).count();
        assert!(
            shown * 10 >= after.len() * 9,
            "{name}: only {shown} of {} after marks are visible: {after:?}",
            after.len()
        );
    }
    // Self-contained and inert.
    for bad in ["<script", "<link", " src=", "url("] {
        assert!(!html.contains(bad), "{bad}");
    }
    assert_eq!(
        html.matches("http").count(),
        html.matches("http://www.w3.org/2000/svg").count(),
        "only SVG namespaces name a URL"
    );
    assert!(html.contains("tester &lt;qa&gt;"));
    assert!(
        html.contains("Sign-off") && html.contains(r["calibd_version"].as_str().unwrap_or("?"))
    );
    html
}

#[test]
fn serial_report_shows_the_result_numbers_and_plots() {
    let done = run_in_examples(&example("serial_identify.json")).unwrap();
    let html = check(
        &done,
        &[
            "/validation/before/mean",
            "/validation/after/mean",
            "/residuals/after/mean",
        ],
        &[
            "errors_per_configuration.svg",
            "validation_errors.svg",
            "errors_per_axis.svg",
        ],
    );
    assert!(html.contains("Held-out validation errors"));
}

#[test]
fn pcr_report_shows_table_3_and_the_validation_errors() {
    let done = run_in_examples(&example("pcr_identify.json")).unwrap();
    check(
        &done,
        &[
            "/model_error/calibration/e_P/nominal/mean",
            "/model_error/calibration/e_P/identified/mean",
            "/model_error/validation/e_P/identified/mean",
        ],
        &["errors_per_configuration.svg", "validation_errors.svg"],
    );
}

#[test]
fn humanoid_report_shows_rmse_before_and_after_and_cross_validation() {
    let mut doc = example("humanoid_identify_twin.json");
    doc["options"]["cross_validation"] = json!({"folds": 3});
    let done = run_in_examples(&doc).unwrap();
    let html = check(
        &done,
        &[
            "/rmse_before_mm",
            "/rmse_after_mm",
            "/cross_validation/rmse_calibrated_mm",
        ],
        &[
            "marker_rmse.svg",
            "posture_rmse.svg",
            "validation_errors.svg",
        ],
    );
    assert!(html.contains("Marker RMSE, calibration set"));
    assert!(html.contains("rmse_by_model.svg"));
}
