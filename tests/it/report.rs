//! The printable report of each calibration method (serial, PCR, humanoid), rendered from
//! a job run on the examples' twin data: every number it shows is the result JSON's (read
//! back through its `data-pointer`), the headline numbers are there, the plots are inline
//! with the "after" series drawn at a visible size, and nothing is fetched; PCR's Table 2
//! bars are the result's sensitivities. (Design, dispersion and campaign reports:
//! `report_studies.rs`.)

use crate::common;

use calibd::jobs::Completed;
use calibd::report::plots::AFTER;
use calibd::report::svg::series_marks;
use common::report::{assert_cells_are_the_result, figure, report_of};
use common::{example, run_in_examples};
use serde_json::json;

/// Checks common to every method; returns the report.
fn check(done: &Completed, headline: &[&str], plots: &[&str]) -> String {
    let r = &done.result;
    let html = report_of(done);
    let cells = assert_cells_are_the_result(&html, r);
    assert!(cells.len() > 20, "only {} number cells", cells.len());
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
fn pcr_report_shows_table_3_the_validation_errors_and_table_2_bars() {
    let done = run_in_examples(&example("pcr_identify.json")).unwrap();
    let html = check(
        &done,
        &[
            "/model_error/calibration/e_P/nominal/mean",
            "/model_error/calibration/e_P/identified/mean",
            "/model_error/validation/e_P/identified/mean",
        ],
        &["errors_per_configuration.svg", "validation_errors.svg"],
    );
    // Table 2 of the nominal model: every non-zero sensitivity is a bar with its value, in
    // the order of the result's rows; the zero ones (E without load, all d together) are
    // said to be zero; the units are on the labels.
    let t = &done.result["sensitivity"];
    assert_eq!(t["configurations"]["count"], 26);
    let rows = t["sensitivity"].as_array().expect("Table 2 rows");
    assert_eq!(rows.len(), 11);
    for (plot, series) in [
        ("sensitivity_position.svg", "dx"),
        ("sensitivity_position.svg", "dy"),
        ("sensitivity_orientation.svg", "dtheta"),
    ] {
        let svg = figure(&html, plot);
        let want: Vec<f64> = rows
            .iter()
            .map(|r| r[series].as_f64().expect("a number"))
            .filter(|v| *v > 0.0)
            .collect();
        let marks = series_marks(svg, series);
        assert_eq!(
            marks.iter().map(|m| m.value).collect::<Vec<_>>(),
            want,
            "{plot} {series}"
        );
        assert!(want.len() >= 8, "{plot} {series}: {want:?}");
        assert!(marks.iter().all(|m| m.extent >= 2.0), "{plot}: {marks:?}");
    }
    let row = |name: &str| {
        rows.iter()
            .find(|r| r["parameter"] == name)
            .unwrap_or_else(|| panic!("no row {name}"))
    };
    let e = row("E");
    assert_eq!(
        (e["dx"].as_f64(), e["unit"].as_str()),
        (Some(0.0), Some("Pa"))
    );
    let pos = figure(&html, "sensitivity_position.svg");
    assert!(pos.contains(">E (m/Pa) = 0<"), "E is not said to be zero");
    assert!(pos.contains(">Ax (m/m)<") && pos.contains("(m/rad)"));
    assert!(row("Ax")["dx"].as_f64().unwrap_or(0.0) > 0.1);
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

/// The typed path: `serial.identify`'s stored result (run on the twin data, written out
/// and read back as text) deserialises into its own result type, whose fields serialise
/// back to the stored ones, and the report renders its verdict and parameter table from
/// it. A stored result missing a field of the type is shown by field name, with a warning
/// that names the field.
#[test]
fn stored_serial_result_reads_back_as_its_type_and_renders_verdict_and_parameters() {
    use calibd::jobs::report_view::typed_result;
    use calibd::jobs::serial::identify::SerialCalibration;
    use serde_json::Value;

    let done = run_in_examples(&example("serial_identify.json")).unwrap();
    let stored: Value = serde_json::from_str(&done.result.to_string()).expect("stored JSON");
    let typed: SerialCalibration =
        serde_json::from_value(stored.clone()).expect("reads as SerialCalibration");
    let back = serde_json::to_value(&typed).expect("serialises");
    for k in [
        "verdict",
        "reasons",
        "dof",
        "parameters",
        "unidentifiable",
        "weakly_observable",
        "residuals",
        "validation",
        "condition_number",
        "convergence",
        "calibrated_model",
    ] {
        assert_eq!(back[k], stored[k], "{k} does not round-trip");
    }
    let params = stored["parameters"].as_array().expect("parameters");
    assert_eq!(typed.parameters.len(), params.len());
    assert!(params.len() > 20, "{} parameters", params.len());

    let html = report_of(&done);
    assert!(!html.contains("does not read as"), "typed path not taken");
    let verdict = stored["verdict"].as_str().expect("verdict");
    assert!(html.contains(&format!("<h2>Verdict: {verdict}</h2>")));
    let reasons = stored["reasons"].as_array().expect("reasons");
    assert!(
        !reasons.is_empty(),
        "the twin job is under review with reasons"
    );
    for r in reasons {
        let code = r["code"].as_str().unwrap_or("?");
        assert!(
            html.contains(&format!("<td><code>{code}</code></td>")),
            "{code}"
        );
    }
    assert!(html.contains(&format!(
        "Residual degrees of freedom: {}.",
        stored["dof"].as_u64().unwrap_or(0)
    )));
    let rows = html.matches("<tr data-param=").count();
    assert_eq!(rows, params.len(), "one parameter row each");
    for (i, p) in params.iter().enumerate() {
        let shown = calibd::report::html::number(p["value"].as_f64().unwrap_or(f64::NAN));
        assert!(
            html.contains(&format!("data-pointer=\"/parameters/{i}/value\">{shown}<")),
            "parameter {i}"
        );
    }

    // A stored result without `parameters` (a renamed field): shown by field name, the
    // missing field named among the warnings.
    let mut renamed = stored.clone();
    let o = renamed.as_object_mut().expect("object");
    let ps = o.remove("parameters").expect("parameters");
    o.insert("params".into(), ps);
    let view = typed_result(&renamed);
    let warned = view.warnings();
    assert!(
        warned
            .iter()
            .any(|w| w.contains("does not read as a serial.identify result")
                && w.contains("parameters")),
        "{warned:?}"
    );
    assert!(view.parameters().is_none());
    assert_eq!(
        view.verdict().map(|v| v.assessment.verdict.as_str()),
        Some(verdict)
    );
}
