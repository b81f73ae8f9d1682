//! `serial.*` jobs end to end on the example twin data: result fields of jobs.md, the
//! calibrated model round trip, and refusal of bad inputs with field, row and value named.

use crate::common;

use calibd::jobs::serial::identify::parse_inputs;
use calibd::jobs::{DirResolver, Inputs, Table};
use calibd::model::dh::DhFile;
use calibd::util::NoMonitor;
use common::{example, examples, prepare_in_examples, run_in_examples};
use serde_json::{Value, json};

#[test]
fn identify_result_has_every_field_and_validation_is_at_noise_level() {
    let done = run_in_examples(&example("serial_identify.json")).unwrap();
    let r = &done.result;
    for f in [
        "kind",
        "started_at",
        "finished_at",
        "calibd_version",
        "inputs_sha256",
        "parameters",
        "unidentifiable",
        "calibrated_model",
        "validation",
        "residuals",
        "convergence",
    ] {
        assert!(r.get(f).is_some(), "missing field {f}");
    }
    assert_eq!(r["kind"], "serial.identify");
    for k in ["job", "model", "measurements", "validation"] {
        assert_eq!(
            r["inputs_sha256"][k].as_str().map(str::len),
            Some(64),
            "hash of {k}"
        );
    }
    let params = r["parameters"].as_array().unwrap();
    assert_eq!(params.len(), 31);
    for p in params {
        for f in ["name", "unit", "nominal", "value", "std"] {
            assert!(p.get(f).is_some(), "parameter field {f}");
        }
    }
    for side in ["before", "after"] {
        for f in ["mean", "median", "std", "max", "unit"] {
            assert!(
                r["validation"][side].get(f).is_some(),
                "validation.{side}.{f}"
            );
        }
    }
    let before = r["validation"]["before"]["mean"].as_f64().unwrap();
    let after = r["validation"]["after"]["mean"].as_f64().unwrap();
    // Tracker noise 0.010 mm per coordinate: |noise| averages 0.016 mm.
    assert!(
        before > 1.0 && after < 0.025,
        "before {before} after {after}"
    );
    assert_eq!(r["convergence"]["converged"], true);
    // Joint 6 carries almost no torque: its compliance is flagged, not trusted.
    assert!(
        r["weakly_observable"]
            .as_array()
            .unwrap()
            .contains(&json!("c6"))
    );
}

#[test]
fn calibrated_model_file_reloads_and_reproduces_the_identified_fk() {
    let doc = example("serial_identify.json");
    let done = run_in_examples(&doc).unwrap();
    let reloaded = DhFile::from_value(done.result["calibrated_model"].clone())
        .unwrap()
        .to_chain()
        .unwrap();
    // The identified model, computed independently through the library.
    let resolver = DirResolver { dir: examples() };
    let inputs = Inputs::new(&resolver);
    let inp = parse_inputs(
        &inputs,
        &doc["model"],
        None,
        &doc["measurements"],
        serde_json::from_value(doc["ball_plate"].clone())
            .ok()
            .as_ref(),
        Some(&doc["validation"]),
        Default::default(),
    )
    .unwrap();
    let (problem, sol) = inp.identify(None, &NoMonitor).unwrap();
    let identified = problem.model(&sol.x);
    let mut worst_same_tau: f64 = 0.0;
    let mut worst_own_tau: f64 = 0.0;
    for m in inp.validation.as_ref().unwrap() {
        let tau = inp.model.chain.static_torques(&m.q);
        let a = identified.tcp(&m.q, Some(&tau)).p;
        worst_same_tau = worst_same_tau.max((reloaded.tcp(&m.q, Some(&tau)).p - a).norm());
        let own = reloaded.static_torques(&m.q);
        worst_own_tau = worst_own_tau.max((reloaded.tcp(&m.q, Some(&own)).p - a).norm());
    }
    assert!(worst_same_tau < 1e-9, "{worst_same_tau} mm");
    // With its own torques (evaluated with the calibrated geometry, not the starting one) the
    // reloaded model differs by the spec's "few micrometres" at most (measured: 1.8 um).
    assert!(worst_own_tau < 5e-3, "{worst_own_tau} mm");
}

#[test]
fn fk_job_matches_the_library_and_writes_csv_columns() {
    let done = run_in_examples(&example("serial_fk.json")).unwrap();
    let t = done.main_table.unwrap();
    assert_eq!(t.columns, ["x", "y", "z", "a", "b", "c"]);
    let joints = Table::from_csv(
        "j",
        &std::fs::read_to_string(examples().join("data/irb120_twin/tracker.csv")).unwrap(),
    )
    .unwrap();
    let mut chain = DhFile::parse(
        &std::fs::read_to_string(examples().join("data/irb120_twin/irb120.json")).unwrap(),
    )
    .unwrap()
    .to_chain()
    .unwrap();
    let id = chain.param_by_name("a2").unwrap();
    chain.set_param(id, 270.1);
    let q: Vec<f64> = joints.rows[3][..6].iter().map(|v| v.to_radians()).collect();
    let p = chain.tcp(&q, Some(&chain.static_torques(&q))).to_xyzabc();
    for k in 0..3 {
        assert!((t.rows[3][k] - p[k]).abs() < 1e-9);
    }
    assert!((t.rows[3][3] - p[3].to_degrees()).abs() < 1e-9);
}

#[test]
fn design_selects_better_than_random_and_is_reproducible() {
    let doc = example("serial_design.json");
    let a = run_in_examples(&doc).unwrap().result;
    let b = run_in_examples(&doc).unwrap().result;
    assert_eq!(a["selected"], b["selected"]);
    let sel: Vec<usize> = serde_json::from_value(a["selected"].clone()).unwrap();
    assert_eq!(sel.len(), 75);
    let o1_sel = a["observability"]["selection"]["o1"].as_f64().unwrap();
    // Any random subset of 75 is worse (O1 normalises by sqrt(n), so they compare).
    let mut rng = calibd::util::Rng::new(3);
    let resolver = DirResolver { dir: examples() };
    let inputs = Inputs::new(&resolver);
    let inp = parse_inputs(
        &inputs,
        &doc["model"],
        None,
        &doc["pool"],
        serde_json::from_value(doc["ball_plate"].clone())
            .ok()
            .as_ref(),
        None,
        Default::default(),
    )
    .unwrap();
    let dp = calibd::jobs::serial::design::DesignPool::new(&inp).unwrap();
    for _ in 0..5 {
        let random = rng.sample_indices(360, 75);
        assert!(dp.indices(&random).o1 < o1_sel);
    }
    for k in ["o1", "o2", "o3", "o4", "o5"] {
        assert!(a["observability"]["pool"][k].as_f64().unwrap() > 0.0);
    }
}

#[test]
fn dispersion_reports_quartiles_per_size_and_parameter_spread() {
    let mut doc = example("serial_dispersion.json");
    doc["sizes"] = json!([40, 80]);
    doc["repetitions"] = json!(4);
    let r = run_in_examples(&doc).unwrap().result;
    assert_eq!(r["identifications"], 8);
    let sizes = r["sizes"].as_array().unwrap();
    assert_eq!(sizes.len(), 2);
    let med = |i: usize| sizes[i]["mean_error"]["median"].as_f64().unwrap();
    // More configurations, smaller validation errors, all well under the 4 mm of nominal.
    assert!(
        med(1) < med(0) * 1.2 && med(0) < 0.1,
        "{} {}",
        med(0),
        med(1)
    );
    let p = &r["parameters_at_largest_size"]["parameters"]
        .as_array()
        .unwrap()[0];
    for f in ["name", "unit", "mean", "std", "min", "max"] {
        assert!(p.get(f).is_some());
    }
}

/// A copy of the identify example whose measurements are inline rows edited by `edit`.
fn with_rows(edit: impl Fn(&mut Vec<Value>)) -> Value {
    let mut doc = example("serial_identify.json");
    let text = std::fs::read_to_string(examples().join("data/irb120_twin/centring.csv")).unwrap();
    let t = Table::from_csv("m", &text).unwrap();
    let mut rows: Vec<Value> = serde_json::from_value(t.to_json_rows()).unwrap();
    rows.truncate(20);
    edit(&mut rows);
    doc["measurements"] = Value::Array(rows);
    doc
}

fn refusal(doc: &Value) -> String {
    let e = prepare_in_examples(doc).expect_err("must be refused");
    assert!(e.is_invalid_input(), "{e}");
    e.to_string()
}

#[test]
fn bad_inputs_are_refused_with_field_row_and_value() {
    let mut doc = example("serial_identify.json");
    doc["options"]["identify"] = json!(["alpha1", "alpha9"]);
    let e = refusal(&doc);
    assert!(
        e.contains("options.identify") && e.contains("alpha9"),
        "{e}"
    );

    let e = refusal(&with_rows(|r| r[6]["ball"] = json!(4)));
    assert!(
        e.contains("measurements")
            && e.contains("row 7")
            && e.contains("ball = 4")
            && e.contains("1..=3"),
        "{e}"
    );

    let e = refusal(&with_rows(|r| r[2]["q3"] = json!(85.0)));
    assert!(
        e.contains("row 3") && e.contains("q3 = 85") && e.contains("[-110, 70]"),
        "{e}"
    );

    let mut doc = example("serial_identify.json");
    doc["measurements"] = json!("data/bad_nan.csv");
    let dir = tempdir();
    std::fs::write(
        dir.join("bad_nan.csv"),
        "q1,q2,q3,q4,q5,q6,ball\n1,2,3,4,5,6,1\n1,2,NaN,4,5,6,2\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("bad_width.csv"),
        "q1,q2,q3,q4,q5,q6,ball\n1,2,3,4,5,6,1\n1,2,3,4,5,6\n",
    )
    .unwrap();
    std::fs::copy(
        examples().join("data/irb120_twin/irb120.json"),
        dir.join("irb120.json"),
    )
    .unwrap();
    doc["model"] = json!("irb120.json");
    doc["validation"] = Value::Null;
    doc.as_object_mut().unwrap().remove("validation");
    doc["measurements"] = json!("bad_nan.csv");
    let e = calibd::jobs::prepare(&doc, &DirResolver { dir: dir.clone() })
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("measurements") && e.contains("row 2") && e.contains("q3") && e.contains("NaN"),
        "{e}"
    );
    doc["measurements"] = json!("bad_width.csv");
    let e = calibd::jobs::prepare(&doc, &DirResolver { dir })
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("row 2") && e.contains("6 values for 7 columns"),
        "{e}"
    );

    let mut doc = example("serial_identify.json");
    doc["optoins"] = json!({});
    let e = refusal(&doc);
    assert!(e.contains("optoins"), "{e}");

    let e = refusal(&with_rows(|r| {
        for row in r.iter_mut() {
            row.as_object_mut().unwrap().remove("q6");
        }
    }));
    assert!(e.contains("missing column `q6`"), "{e}");

    let mut doc = example("serial_identify.json");
    doc["ball_plate"] = json!({"d12": 100.0, "d13": 10.0, "d23": 10.0});
    let e = refusal(&doc);
    assert!(e.contains("ball_plate") && e.contains("triangle"), "{e}");
}

fn tempdir() -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!(
        "calibd-test-{}-{:?}",
        std::process::id(),
        std::thread::current().id()
    ));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `options.prior` turns the identification into MAP; `prior_weight: "cv"` picks the weight
/// by 5-fold cross-validation and reports the held-out errors; without a prior the result
/// says `least_squares`.
#[test]
fn identify_with_a_prior_reports_map_and_the_k_fold_choice() {
    let mut doc = with_rows(|_| {});
    let ls = run_in_examples(&doc).unwrap();
    assert_eq!(ls.result["prior"]["mode"], "least_squares");
    doc["options"]["prior"] = json!({
        "std": {"base.x": 2.0, "base.y": 2.0, "base.z": 2.0,
                "base.a": 0.2, "base.b": 0.2, "base.c": 0.2},
        "default_std": {"length_mm": 0.5, "angle_deg": 0.1, "compliance": 0.005}
    });
    let map = run_in_examples(&doc).unwrap();
    let p = &map.result["prior"];
    assert_eq!(p["mode"], "map", "{p}");
    assert_eq!(p["weight"], 1.0);
    assert_eq!(p["count"], 31);
    doc["options"]["prior_weight"] = json!("cv");
    let cv = run_in_examples(&doc).unwrap();
    let p = &cv.result["prior"];
    println!("{p}");
    assert_eq!(p["mode"], "map_cv", "{p}");
    let errors = p["k_fold_errors"].as_array().unwrap();
    assert_eq!(errors.len(), 5);
    let w = p["weight"].as_f64().unwrap();
    let best = errors
        .iter()
        .min_by(|a, b| {
            a["rms"]
                .as_f64()
                .unwrap()
                .total_cmp(&b["rms"].as_f64().unwrap())
        })
        .unwrap();
    assert_eq!(best["weight"].as_f64().unwrap(), w);
    for r in [&ls, &map, &cv] {
        println!(
            "{} validation after {}",
            r.result["prior"]["mode"], r.result["validation"]["after"]["mean"]
        );
        for q in r.result["parameters"].as_array().unwrap() {
            assert!(q["value"].as_f64().is_some_and(f64::is_finite), "{q}");
        }
    }
    // The first 20 rows leave LS weakly determined (validation mean 1.231 mm); the prior
    // helps (MAP 1.165 mm, weight 1), the cross-validated weight (0.01, held-out RMS
    // 0.0079 mm against 0.0093 at weight 1) more (1.138 mm).
    let val =
        |r: &calibd::jobs::Completed| r.result["validation"]["after"]["mean"].as_f64().unwrap();
    assert!(
        val(&map) <= val(&ls) && val(&cv) <= val(&ls),
        "{} {} {}",
        val(&ls),
        val(&map),
        val(&cv)
    );
    assert_eq!(w, 0.01);
    // Refusals: a weight that is neither a number nor "cv", a weight without a prior, a
    // name that is not identified.
    doc["options"]["prior_weight"] = json!("auto");
    assert!(refusal(&doc).contains("options.prior_weight"));
    doc["options"]["prior_weight"] = json!(1.0);
    doc["options"]["prior"]["std"]["alpha9"] = json!(1.0);
    let e = refusal(&doc);
    assert!(e.contains("options.prior") && e.contains("alpha9"), "{e}");
    let mut doc = with_rows(|_| {});
    doc["options"]["prior_weight"] = json!(10.0);
    assert!(refusal(&doc).contains("needs options.prior"));
}
