use serde_json::json;

use super::*;
use crate::report::JsonResult;

/// Render the report of a result read by field name (these results are hand-made, not a
/// kind's typed result).
fn render_json(job: &Value, result: &Value, history: &[Value]) -> String {
    let envelope = Envelope::read(result);
    let content = JsonResult(result);
    render(&input(job, &envelope, &content, history))
}

fn input<'a>(
    job: &'a Value,
    envelope: &'a Envelope,
    result: &'a dyn Reportable,
    history: &'a [Value],
) -> ReportInput<'a> {
    ReportInput {
        job,
        envelope,
        result,
        artefacts: &[],
        cell_history: history,
        journal: &[],
        generator_version: "0.1.0",
        generated_at: "2026-11-25T18:00:00Z",
    }
}

#[test]
fn numbers_keep_four_significant_digits() {
    assert_eq!(number(0.003123456), "0.003123");
    assert_eq!(number(0.000_312_3), "3.123e-4");
    assert_eq!(number(0.0123456), "0.01235");
    assert_eq!(number(1.5), "1.500");
    assert_eq!(number(2345.6), "2346");
    assert_eq!(number(0.0), "0");
    assert_eq!(number(-12.5), "-12.50");
    assert_eq!(number(f64::NAN), "—");
}

#[test]
fn user_strings_are_escaped_and_nothing_is_fetched() {
    let job = json!({"id": 7, "kind": "trical.campaign", "state": "succeeded",
        "submitted_by": "<script>alert(1)</script>", "devices": ["c<img src=x>.uwave"]});
    let result = json!({"kind": "trical.campaign", "calibd_version": "0.1.0",
        "inputs_sha256": {"<b>file</b>.csv": "ab"},
        "warnings": ["row \"3\" <bad>"],
        "parameters": [{"name": "a<1>", "unit": "mm", "nominal": 1.0, "value": 1.5,
            "std": 0.1, "identifiable": true, "effect_size": 0.2}]});
    let html = render_json(&job, &result, &[]);
    assert!(
        !html.contains("<script>") && !html.contains("<img"),
        "{html}"
    );
    assert!(html.contains("&lt;script&gt;alert(1)&lt;/script&gt;"));
    assert!(html.contains("&lt;b&gt;file&lt;/b&gt;.csv"));
    assert!(html.contains("row &quot;3&quot; &lt;bad&gt;"));
    assert!(!html.contains("http://") && !html.contains("https://"));
    assert!(!html.contains("<link") && !html.contains("<iframe"));
}

#[test]
fn headline_and_parameters_point_at_the_result_numbers() {
    let job = json!({"id": 3, "kind": "serial.identify", "state": "succeeded"});
    let result = json!({"kind": "serial.identify", "started_at": "2026-11-25T10:00:00Z",
        "residuals": {"before": {"mean": 2.5, "max": 4.0, "unit": "mm"},
                      "after": {"mean": 0.0031, "max": 0.009, "unit": "mm"}},
        "validation": {"before": {"mean": 2.0, "max": 3.9, "unit": "mm"},
                       "after": {"mean": 0.0042, "max": 0.01, "unit": "mm"}},
        "weakly_observable": ["b"],
        "unidentifiable": ["c"],
        "parameters": [
            {"name": "a", "unit": "mm", "nominal": 0.0, "value": 0.5, "std": 0.01, "identifiable": true, "effect_size": 1.0},
            {"name": "b", "unit": "deg", "nominal": 90.0, "value": 90.01, "std": 0.2, "identifiable": true, "effect_size": 0.001},
            {"name": "c", "unit": "mm", "nominal": 1.0, "value": 1.0, "std": null, "identifiable": false, "effect_size": 0.0}]});
    let history =
        [json!({"job_id": 1, "state": "superseded", "at": "2026-11-24T10:00:00Z", "reason": "ok"})];
    let html = render_json(&job, &result, &history);
    for p in [
        "/validation/after/mean",
        "/validation/before/mean",
        "/residuals/after/mean",
        "/parameters/0/value",
        "/parameters/1/std",
    ] {
        assert!(html.contains(&format!("data-pointer=\"{p}\"")), "{p}");
    }
    assert!(html.contains(">0.004200<"), "validation after mean shown");
    assert!(html.contains("identified, weakly observable"));
    assert!(html.contains("held: not identifiable"));
    assert!(
        html.contains("calibration accepted from job 1"),
        "the nominal says where it came from"
    );
    assert!(html.contains("data-count=\"identified\">2<"));
    // No cell decision for this job: the sign-off says so.
    assert!(html.contains("did not decide a cell"));
}

#[test]
fn only_clean_svg_is_embedded() {
    let ok = Artefact {
        name: "a.svg".into(),
        media_type: "image/svg+xml".into(),
        content: b"<svg><text>configuration one</text></svg>".to_vec(),
    };
    assert!(embeddable_svg(&ok).is_some());
    for bad in [
        "<svg><script>x</script></svg>",
        "<svg onload=\"x\"></svg>",
        "<svg><image href=\"http://x\"/></svg>",
    ] {
        let a = Artefact {
            content: bad.as_bytes().to_vec(),
            ..ok.clone()
        };
        assert!(embeddable_svg(&a).is_none(), "{bad}");
    }
}
