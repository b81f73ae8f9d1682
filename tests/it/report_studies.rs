//! Reports of design and study results: the DETMAX and NOCP/COCP O1 histories end at the
//! O1 the result reports, the dispersion box plots (log axis) are the quartiles of the
//! per-set validation errors recomputed here, and a campaign's report lists its journal
//! entry by entry with the journal's numbers.

use crate::common;

use calibd::jobs::Completed;
use calibd::report::html::number;
use calibd::report::studies::{CHOSEN, HISTORY};
use calibd::report::svg::{series_boxes, series_marks};
use common::report::{assert_cells_are_the_result, figure, report_of, report_with};
use common::{example, run_in_examples};
use serde_json::{Value, json};

/// An independent type-7 quantile (linear between order statistics), for the box checks.
fn quantile7(v: &[f64], p: f64) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.partial_cmp(b).expect("finite"));
    let pos = p * (s.len() - 1) as f64;
    let k = (pos as usize).min(s.len().saturating_sub(2));
    let f = pos - k as f64;
    if s.len() == 1 {
        return s[0];
    }
    s[k] * (1.0 - f) + s[k + 1] * f
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * a.abs().max(b.abs())
}

#[test]
fn dispersion_report_box_plots_are_the_quartiles_of_the_per_set_errors() {
    let mut doc = example("serial_dispersion.json");
    doc["sizes"] = json!([30, 60]);
    doc["repetitions"] = json!(5);
    let done = run_in_examples(&doc).unwrap();
    let r = &done.result;
    let html = report_of(&done);
    assert_cells_are_the_result(&html, r);
    let runs = r["runs"].as_array().expect("runs");
    assert_eq!(
        runs.len() as u64,
        r["identifications"].as_u64().unwrap_or(0)
    );
    for (plot, series, key) in [
        ("dispersion_mean_error.svg", "mean_error", "mean_error"),
        ("dispersion_std_error.svg", "std_error", "std_error"),
    ] {
        let svg = figure(&html, plot);
        assert!(
            svg.contains("data-y-scale=\"log\""),
            "{plot} is not on a log axis"
        );
        assert!(svg.contains("mm, log scale") && svg.contains("validation set errors of"));
        let boxes = series_boxes(svg, series);
        let sizes = r["sizes"].as_array().expect("sizes");
        assert_eq!(boxes.len(), sizes.len());
        for (b, size) in boxes.iter().zip(sizes) {
            let n = size["n"].as_u64().expect("n");
            let v: Vec<f64> = runs
                .iter()
                .filter(|x| x["n"].as_u64() == Some(n))
                .map(|x| x[key].as_f64().expect("error"))
                .collect();
            assert_eq!(
                v.len() as u64,
                size["identifications"].as_u64().unwrap_or(0)
            );
            let want = [0.0, 0.25, 0.5, 0.75, 1.0].map(|p| quantile7(&v, p));
            let stated = ["min", "q1", "median", "q3", "max"]
                .map(|k| size[key][k].as_f64().expect("quartile"));
            for i in 0..5 {
                assert!(
                    close(b[i], want[i]),
                    "{plot} n={n}: drawn {b:?}, recomputed {want:?}"
                );
                assert!(
                    close(stated[i], want[i]),
                    "n={n}: result {stated:?}, recomputed {want:?}"
                );
            }
            assert!(svg.contains(&format!(">{n}</text>")));
        }
        // Every box is drawn with a visible height or, when its quartiles coincide, as a line.
        assert!(series_marks(svg, series).iter().all(|m| m.extent >= 0.5));
    }
}

#[test]
fn design_report_plots_the_detmax_o1_history() {
    let done = run_in_examples(&example("serial_design.json")).unwrap();
    let r = &done.result;
    let html = report_of(&done);
    assert_cells_are_the_result(&html, r);
    let steps = r["history"]["steps"].as_array().expect("history");
    assert_eq!(steps.len() as u64, r["exchanges"].as_u64().unwrap_or(0) + 1);
    assert!(steps.len() >= 3, "DETMAX made {} steps", steps.len());
    let num = |v: &Value| v.as_f64().expect("a number");
    let last = steps.last().expect("a step");
    // The last step is the selection the result reports; the first is the random start.
    assert_eq!(
        num(&last["o1"]),
        num(&r["observability"]["selection"]["o1"])
    );
    assert_eq!(num(&last["log_det"]), num(&r["log_det"]["selection"]));
    assert!((num(&steps[0]["log_det"]) - num(&r["log_det"]["start"])).abs() < 1e-6);
    for w in steps.windows(2) {
        assert!(num(&w[1]["log_det"]) > num(&w[0]["log_det"]) - 1e-9);
        assert_eq!(num(&w[1]["exchanges"]), num(&w[0]["exchanges"]) + 1.0);
    }
    assert!(num(&last["o1"]) > num(&steps[0]["o1"]));
    let svg = figure(&html, "design_history.svg");
    let marks = series_marks(svg, HISTORY);
    let o1: Vec<f64> = steps.iter().map(|s| num(&s["o1"])).collect();
    assert_eq!(marks.iter().map(|m| m.value).collect::<Vec<_>>(), o1);
    // A linear axis from 0: heights in the ratio of the O1 values (to the pixel).
    let (a, b) = (marks[0], marks[marks.len() - 1]);
    assert!((b.extent / a.extent - b.value / a.value).abs() < 0.02 * b.value / a.value);
    assert!(svg.contains("O1 of the selection (dimensionless)"));
    assert!(svg.contains("75 of 360 pool configurations"), "{svg}");
    design_view_is_the_result(&html, r);
}

/// The design section: the selected configurations table holds the result's rows (pool
/// rows counted from 1, every column), O1..O5 of the selection and the pool are the
/// result's, and nothing of an identification (parameter table, identified count,
/// before/after headline, "no validation" warning) is shown.
fn design_view_is_the_result(html: &str, r: &Value) {
    let section = &html[html
        .find("<section id=\"design\">")
        .expect("a design section")..];
    let section = &section[..section.find("</section>").expect("its end")];
    let rows = r["rows"].as_array().expect("rows");
    let selected = r["selected"].as_array().expect("selected");
    assert_eq!(rows.len(), 75);
    let table = &section[section
        .find("Selected configurations (75)")
        .expect("the table")..];
    let body = &table[table.find("<tbody>").unwrap()..table.find("</tbody>").unwrap()];
    let trs: Vec<&str> = body.split("<tr>").skip(1).collect();
    assert_eq!(
        trs.len(),
        rows.len(),
        "one table row per selected configuration"
    );
    for (i, (tr, row)) in trs.iter().zip(rows).enumerate() {
        let pool_row = selected[i].as_u64().unwrap() + 1;
        assert!(
            tr.starts_with(&format!("<th>{}</th><td>{pool_row}</td>", i + 1)),
            "{tr}"
        );
        for (c, v) in row.as_object().unwrap() {
            let cell = format!(
                "data-pointer=\"/rows/{i}/{c}\">{}<",
                number(v.as_f64().unwrap())
            );
            assert!(tr.contains(&cell), "row {i} column {c}: {tr}");
        }
    }
    for k in ["o1", "o2", "o3", "o4", "o5"] {
        for set in ["selection", "pool"] {
            let v = r["observability"][set][k].as_f64().unwrap();
            let cell = format!("data-pointer=\"/observability/{set}/{k}\">{}<", number(v));
            assert!(section.contains(&cell), "{set} {k}");
        }
    }
    // DETMAX improved on its random start.
    assert!(
        r["observability"]["selection"]["o1"].as_f64() > r["history"]["steps"][0]["o1"].as_f64()
    );
    for absent in [
        "class=\"params\"",
        "data-count=\"identified\"",
        "before calibration",
        "No held-out validation",
    ] {
        assert!(!html.contains(absent), "the design report shows {absent}");
    }
}

fn humanoid_design(n: Option<usize>) -> Completed {
    let mut doc = json!({
        "kind": "humanoid.design",
        "urdf": include_str!("../data/robots/talos/talos_reduced.urdf"),
        "root_link": "torso_2_link",
        "joints": (1..=7).map(|k| format!("arm_left_{k}_joint")).collect::<Vec<_>>(),
        "clusters": [
            {"link": "arm_left_4_link", "centre": [0.05, 0.0, -0.12]},
            {"link": "arm_left_7_link", "centre": [0.04, 0.0, -0.10]}
        ],
        "seed": 3,
        "options": {"base_pool": 150, "max_postures": 20, "epsilon": 0.02, "optim_iterations": 3}
    });
    if let Some(n) = n {
        doc["n"] = json!(n);
    }
    calibd::jobs::prepare(&doc, &calibd::jobs::NoReferences)
        .and_then(|j| j.run(&calibd::util::NoMonitor))
        .expect("humanoid.design")
}

#[test]
fn humanoid_design_report_plots_the_nocp_and_cocp_o1_histories() {
    let num = |v: &Value| v.as_f64().expect("a number");
    // NOCP: O1 against the postures after each block; the kept set's O1 is the result's.
    let done = humanoid_design(None);
    let r = &done.result;
    let html = report_of(&done);
    let svg = figure(&html, "design_history.svg");
    let hist = r["o1_history"].as_array().expect("o1_history");
    let marks = series_marks(svg, HISTORY);
    assert_eq!(
        marks.iter().map(|m| m.value).collect::<Vec<_>>(),
        hist.iter().map(|s| num(&s["o1"])).collect::<Vec<_>>()
    );
    let kept = hist
        .iter()
        .find(|s| s["postures"] == r["posture_count"])
        .expect("the kept set is a step of the history");
    assert_eq!(num(&kept["o1"]), num(&r["o1"]));
    let chosen = series_marks(svg, CHOSEN);
    if hist.last() == Some(kept) {
        assert!(chosen.is_empty());
    } else {
        assert_eq!(chosen.len(), 1);
        assert_eq!(chosen[0].value, num(&r["o1"]));
    }
    assert!(svg.contains("O1 during NOCP") && svg.contains("postures in the set"));
    // COCP: O1 after each re-optimised posture, from the random start to the result's O1.
    let done = humanoid_design(Some(8));
    let r = &done.result;
    let h: Vec<f64> = r["cocp_o1_history"]
        .as_array()
        .expect("cocp_o1_history")
        .iter()
        .map(num)
        .collect();
    assert_eq!(h.last().copied(), Some(num(&r["o1"])));
    assert_eq!(h[0], num(&r["o1_history"][0]["o1_start"]));
    assert!(h.len() >= 2 && h[h.len() - 1] > h[0], "{h:?}");
    let html = report_of(&done);
    let svg = figure(&html, "design_history.svg");
    let marks = series_marks(svg, HISTORY);
    assert_eq!(marks.iter().map(|m| m.value).collect::<Vec<_>>(), h);
    assert!(marks.iter().all(|m| m.extent >= 2.0));
}

#[test]
fn campaign_report_lists_the_measurement_journal() {
    use calibd::procedures::{Journal, MemoryJournal};
    use std::sync::Arc;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    let lab = rt
        .block_on(calibd::lab::Lab::simulated(
            &calibd::sim::SimOptions::default(),
        ))
        .map(Arc::new)
        .expect("lab");
    let doc =
        json!({"kind": "cell.pcr_campaign", "poses": 16, "seed": 2, "validation_fraction": 0.25});
    let job = calibd::jobs::prepare(&doc, &calibd::jobs::NoReferences).expect("valid job");
    let journal = Arc::new(MemoryJournal::default());
    let store: Arc<dyn Journal> = journal.clone();
    let done = calibd::offline::run_on(rt.handle(), &job, lab, store, &calibd::util::NoMonitor)
        .expect("campaign");
    let entries: Vec<Value> = journal
        .entries()
        .expect("journal")
        .iter()
        .map(|e| serde_json::to_value(e).expect("entry"))
        .collect();
    assert_eq!(
        entries.len() as u64,
        done.result["campaign"]["journal_entries"]
            .as_u64()
            .unwrap_or(0)
    );
    let html = report_with(&done, &entries);
    assert_cells_are_the_result(&html, &done.result);
    let start = html
        .find("Campaign measurement journal")
        .expect("journal section");
    let section = &html[start..start + html[start..].find("</section>").unwrap_or(0)];
    assert_eq!(section.matches("<tr data-index=").count(), entries.len());
    let measured = entries.iter().filter(|e| e["status"] == "measured").count();
    assert!(section.contains(&format!("data-count=\"journal-measured\">{measured}<")));
    // Every number of the table is the journal's, at its pointer.
    let all = Value::Array(entries.clone());
    let mut numbers = 0;
    for part in section.split("data-journal=\"").skip(1) {
        let (pointer, rest) = part.split_once('"').expect("pointer");
        let from_one = rest.starts_with(" data-from-one=\"\"");
        let rest = rest.trim_start_matches(" data-from-one=\"\"");
        let text = rest[1..].split('<').next().unwrap_or("");
        let v = all
            .pointer(pointer)
            .and_then(Value::as_number)
            .unwrap_or_else(|| panic!("{pointer} is not a number of the journal"));
        // Integers as written; others to 4 significant digits, reading back as the value.
        let x = v.as_f64().unwrap_or(f64::NAN);
        let back: f64 = text.parse().unwrap_or(f64::NAN);
        if from_one {
            // A ball: stored from 0, shown from 1.
            assert!(pointer.ends_with("/ball"), "{pointer}");
            assert_eq!(
                text,
                (v.as_u64().unwrap_or(u64::MAX) + 1).to_string(),
                "{pointer}"
            );
        } else if v.is_i64() || v.is_u64() {
            assert_eq!(text, v.to_string(), "{pointer}");
        } else {
            assert_eq!(text, number(x), "{pointer}");
            assert!(
                (back - x).abs() <= 6e-4 * x.abs(),
                "{pointer}: {text} vs {x}"
            );
        }
        numbers += 1;
    }
    assert!(
        numbers >= entries.len(),
        "only {numbers} journal numbers shown"
    );
    for e in &entries {
        assert!(section.contains(&format!("<tr data-index=\"{}\">", e["index"])));
    }
}
