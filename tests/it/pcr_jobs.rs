//! `pcr.*` jobs end to end on the example twin data (`examples/data/pcr_twin`, written by
//! `calibd twin pcr --seed 3`): every result field jobs.md lists, round trips through the
//! library, the shipped calibrated model, and refusal of bad inputs with field, row and
//! value named.

use crate::common;

use calibd::geometry::Pose2;
use calibd::model::pcr::PcrFile;
use common::{example, examples, prepare_in_examples, run_in_examples};
use serde_json::{Value, json};

fn num(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

#[test]
fn identify_result_has_every_field_and_reaches_the_noise_level() {
    let r = run_in_examples(&example("pcr_identify.json"))
        .expect("identify")
        .result;
    for f in [
        "kind",
        "started_at",
        "finished_at",
        "calibd_version",
        "inputs_sha256",
        "parameters",
        "unidentifiable",
        "model_error",
        "validation",
        "calibrated_model",
        "steps",
    ] {
        assert!(r.get(f).is_some(), "missing field {f}");
    }
    assert_eq!(r["kind"], "pcr.identify");
    for k in ["job", "model", "measurements", "validation"] {
        assert_eq!(
            r["inputs_sha256"][k].as_str().map(str::len),
            Some(64),
            "hash of {k}"
        );
    }
    let params = r["parameters"].as_array().expect("array");
    assert_eq!(params.len(), 34);
    for p in params {
        for f in [
            "name",
            "unit",
            "nominal",
            "value",
            "std",
            "lower",
            "upper",
            "bound_hit",
        ] {
            assert!(p.get(f).is_some(), "parameter field {f}: {p}");
        }
    }
    // Table 3: e_P (um) and e_theta (mrad), max/mean/min, nominal and identified, on both
    // sets.
    for set in ["calibration", "validation"] {
        for (err, unit) in [("e_P", "um"), ("e_theta", "mrad")] {
            let row = &r["model_error"][set][err];
            assert_eq!(row["unit"], unit);
            for model in ["nominal", "identified"] {
                for s in ["max", "mean", "min"] {
                    assert!(row[model][s].is_number(), "{set}.{err}.{model}.{s}");
                }
            }
        }
    }
    let v = &r["model_error"]["validation"]["e_P"];
    assert!(
        num(&v["identified"]["max"]) < 0.1 && num(&v["nominal"]["mean"]) > 2.0,
        "{v}"
    );
    for side in ["before", "after"] {
        for f in ["mean", "median", "std", "max", "unit"] {
            assert!(
                r["validation"][side].get(f).is_some(),
                "validation.{side}.{f}"
            );
        }
    }
    assert_eq!(r["validation"]["after"]["unit"], "m");
    let u: Vec<&str> = r["unidentifiable"]
        .as_array()
        .expect("array")
        .iter()
        .filter_map(Value::as_str)
        .collect();
    assert!(u.contains(&"E") && u.len() == 8, "{u:?}");
    assert_eq!(r["steps"].as_array().map(Vec::len), Some(3));
}

#[test]
fn the_calibrated_model_reloads_and_matches_the_shipped_one() {
    let r = run_in_examples(&example("pcr_identify.json"))
        .expect("identify")
        .result;
    let now = PcrFile::from_value(r["calibrated_model"].clone()).expect("a valid model file");
    let text = std::fs::read_to_string(examples().join("data/pcr_twin/pcr3pf_calibrated.json"))
        .expect("shipped calibrated model");
    let shipped = PcrFile::parse(&text).expect("valid");
    let (a, b) = (now.params().to_array(), shipped.params().to_array());
    for k in 0..a.len() {
        assert!(
            (a[k] - b[k]).abs() <= 1e-9 * a[k].abs().max(1e-3),
            "parameter {k}: {} vs {}",
            a[k],
            b[k]
        );
    }
    assert!(now.calibration.is_some());
    // The reloaded model predicts the validation readings at the noise level.
    let robot = now.robot().expect("robot");
    let val = calibd::jobs::Table::from_csv(
        "validation",
        &std::fs::read_to_string(examples().join("data/pcr_twin/validation.csv")).expect("csv"),
    )
    .expect("table");
    for row in val.rows.iter().take(10) {
        let eq = robot.fk(&[row[0], row[1], row[2]]).expect("fk");
        let meas = calibd::measure::pcr::measured_pose(
            &now.extrinsics,
            &Pose2::new(row[3], row[4], row[5]),
        );
        let e = (eq.pose.x - meas.x).hypot(eq.pose.y - meas.y);
        assert!(e < 6e-8, "{e:e} m");
    }
}

#[test]
fn fk_and_ik_jobs_agree_with_each_other_and_the_library() {
    let fk = run_in_examples(&example("pcr_fk.json")).expect("fk");
    let poses = fk.main_table.expect("poses table");
    assert_eq!(poses.columns, vec!["x", "y", "theta"]);
    assert_eq!(poses.rows.len(), 20);
    let text =
        std::fs::read_to_string(examples().join("data/pcr_twin/pcr3pf.json")).expect("model");
    let robot = PcrFile::parse(&text)
        .map(|f| f.robot())
        .expect("file")
        .expect("robot");
    let joints = calibd::jobs::Table::from_csv(
        "joints",
        &std::fs::read_to_string(examples().join("data/pcr_twin/joints.csv")).expect("csv"),
    )
    .expect("table");
    for (q, p) in joints.rows.iter().zip(&poses.rows) {
        let eq = robot.fk(&[q[0], q[1], q[2]]).expect("cold fk");
        assert!((eq.pose.x - p[0]).abs() < 1e-11 && (eq.pose.theta - p[2]).abs() < 1e-10);
    }
    // An external load moves the platform of the bent configurations.
    let mut doc = example("pcr_fk.json");
    doc["options"] = json!({"load": {"force": [0.003, -0.002], "moment": 1e-5}, "wrenches": true});
    let loaded = run_in_examples(&doc).expect("loaded fk");
    let moved = loaded
        .main_table
        .expect("poses")
        .rows
        .iter()
        .zip(&poses.rows)
        .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
        .fold(0.0, f64::max);
    assert!(moved > 1e-7 && moved < 1e-3, "{moved:e}");
    assert_eq!(
        loaded.result["wrenches"]["rows"].as_array().map(Vec::len),
        Some(20)
    );
    // IK of the 2 mm square, then FK of the joints found: the square again.
    let ik = run_in_examples(&example("pcr_ik.json")).expect("ik");
    let q = ik.main_table.expect("joints table");
    assert_eq!(q.columns, vec!["q1", "q2", "q3"]);
    let doc =
        json!({"kind": "pcr.fk", "model": "data/pcr_twin/pcr3pf.json", "joints": q.to_json_rows()});
    let back = run_in_examples(&doc)
        .expect("fk of ik")
        .main_table
        .expect("poses");
    let square = calibd::design::trajectory::square(&Pose2::default(), 0.002, 5);
    for (p, s) in back.rows.iter().zip(&square) {
        assert!(
            (p[0] - s.x).abs() < 1e-10 && (p[1] - s.y).abs() < 1e-10 && p[2].abs() < 1e-10,
            "{p:?}"
        );
    }
}

#[test]
fn sensitivity_job_reports_table_2_with_exact_zeros() {
    let r = run_in_examples(&example("pcr_sensitivity.json"))
        .expect("sensitivity")
        .result;
    assert_eq!(r["configurations"]["count"], 26);
    let rows = r["sensitivity"].as_array().expect("rows");
    assert_eq!(rows.len(), 11);
    for name in ["E", "d (all)"] {
        let row = rows.iter().find(|x| x["parameter"] == name).expect("row");
        for c in ["dx", "dy", "dtheta"] {
            assert_eq!(num(&row[c]), 0.0, "{name} {c}");
        }
    }
    let l = rows.iter().find(|x| x["parameter"] == "l").expect("l");
    assert!(num(&l["dx"]) > 0.1 && l["position_unit"] == "m/m", "{l}");
}

#[test]
fn accuracy_after_calibration_is_nanometric_and_without_it_is_not() {
    for name in ["pcr_accuracy_square.json", "pcr_accuracy_circle.json"] {
        let done = run_in_examples(&example(name)).expect("accuracy");
        let r = &done.result;
        assert_eq!(r["trajectory"]["poses"], 16);
        assert_eq!(r["trajectory"]["repetitions"], 30);
        for f in ["ap_p_um", "ap_theta_mrad"] {
            for s in ["max", "mean", "min"] {
                assert!(r["summary"][f][s].is_number(), "{f}.{s}");
            }
        }
        // The twin's noise averages down over 30 repetitions; the identified model's error
        // is at the noise level: AP_P of a few nanometres.
        assert!(
            num(&r["summary"]["ap_p_um"]["max"]) < 0.05,
            "{}",
            r["summary"]
        );
        assert_eq!(done.main_table.map(|t| t.rows.len()), Some(16));
        // The nominal model (extrinsics unknown, nominal geometry) misses by far more.
        let mut doc = example(name);
        doc["model"] = json!("data/pcr_twin/pcr3pf.json");
        let nominal = run_in_examples(&doc).expect("nominal accuracy").result;
        assert!(
            num(&nominal["summary"]["ap_p_um"]["mean"]) > 10.0,
            "{}",
            nominal["summary"]
        );
        // Side by side in one job: the nominal model commands the same trajectory on the same
        // twin, measured through the calibrated extrinsics. A second method: a separate run
        // whose control model is the nominal geometry with the calibrated extrinsics.
        let mut doc = example(name);
        doc["compare_with"] = json!("data/pcr_twin/pcr3pf.json");
        let both = run_in_examples(&doc).expect("side by side").result;
        assert_eq!(
            both["summary"], r["summary"],
            "the calibrated side is unchanged"
        );
        let c = &both["compared"];
        let read = |p: &str| -> Value {
            serde_json::from_str(&std::fs::read_to_string(examples().join(p)).expect("model"))
                .expect("json")
        };
        let mut mixed = read("data/pcr_twin/pcr3pf.json");
        mixed["extrinsics"] = read("data/pcr_twin/pcr3pf_calibrated.json")["extrinsics"].clone();
        let mut doc = example(name);
        doc["model"] = mixed;
        let second = run_in_examples(&doc).expect("second method").result;
        let (a, b) = (
            num(&c["summary"]["ap_p_um"]["mean"]),
            num(&second["summary"]["ap_p_um"]["mean"]),
        );
        assert!((a - b).abs() <= 1e-9 * b, "{a} vs {b}");
        assert!(a > 10.0, "nominal AP_P {a} um");
        let ratio = num(&c["mean_ap_p_ratio"]);
        let own = num(&r["summary"]["ap_p_um"]["mean"]);
        assert!(
            (ratio - a / own).abs() <= 1e-9 * ratio && ratio > 100.0,
            "{ratio}"
        );
        assert_eq!(c["ap_p_m"].as_array().map(Vec::len), Some(16));
        eprintln!("{name}: mean AP_P calibrated {own:.4} um, nominal {a:.2} um ({ratio:.0}x)");
    }
    // A reached table holds one model's poses: no comparison.
    let e = refused(
        json!({"kind": "pcr.accuracy", "model": "data/pcr_twin/pcr3pf.json",
        "trajectory": {"square": 0.002}, "reached": "data/pcr_twin/calibration.csv",
        "compare_with": "data/pcr_twin/pcr3pf.json"}),
    );
    assert!(e.contains("compare_with") && e.contains("twin"), "{e}");
}

fn refused(doc: Value) -> String {
    prepare_in_examples(&doc).expect_err("refused").to_string()
}

#[test]
fn bad_inputs_are_refused_with_field_row_and_value() {
    let model = "data/pcr_twin/pcr3pf.json";
    let e = refused(
        json!({"kind": "pcr.fk", "model": model, "joints": [{"q1": 0.0, "q2": 0.004, "q3": 0.0}]}),
    );
    assert!(
        e.contains("joints") && e.contains("row 1") && e.contains("q2 = 0.004"),
        "{e}"
    );
    let e = refused(
        json!({"kind": "pcr.fk", "model": model, "joints": [{"q1": 0.0, "q2": "x", "q3": 0.0}]}),
    );
    assert!(e.contains("row 1") && e.contains("q2"), "{e}");
    let e = refused(json!({"kind": "pcr.fk", "model": model, "joints": [{"q1": 0.0, "q3": 0.0}]}));
    assert!(e.contains("missing column `q2`"), "{e}");
    let e = refused(json!({"kind": "pcr.fk", "model": model, "joints": [], "speed": 1}));
    assert!(e.contains("speed"), "{e}");
    let mut bad_model: Value =
        serde_json::from_str(&std::fs::read_to_string(examples().join(model)).expect("model"))
            .expect("json");
    bad_model["limbs"][1]["l"] = json!(-0.03);
    let e = refused(json!({"kind": "pcr.fk", "model": bad_model, "joints": []}));
    assert!(e.contains("limbs[1].l") && e.contains("-0.03"), "{e}");
    let e = refused(
        json!({"kind": "pcr.identify", "model": model, "measurements": "data/pcr_twin/calibration.csv",
        "options": {"steps": [["extrinsics"], ["l", "lenght"]]}}),
    );
    assert!(
        e.contains("options.steps[1]") && e.contains("lenght"),
        "{e}"
    );
    let e =
        refused(json!({"kind": "pcr.accuracy", "model": model, "trajectory": {"square": 0.002}}));
    assert!(e.contains("reached") && e.contains("twin"), "{e}");
    let e = refused(
        json!({"kind": "pcr.accuracy", "model": model, "trajectory": {"square": 0.002, "circle": 0.003},
        "twin": {"model": model, "seed": 1}}),
    );
    assert!(e.contains("exactly one"), "{e}");
    // A pose the rods cannot reach fails when run, naming the row.
    let doc = json!({"kind": "pcr.ik", "model": model, "poses": [{"x": 0.0, "y": 0.0, "theta": 0.0}, {"x": 0.0, "y": 0.04, "theta": 0.0}]});
    let e = run_in_examples(&doc).expect_err("unreachable").to_string();
    assert!(
        e.contains("poses") && e.contains("row 2") && e.contains("unreachable"),
        "{e}"
    );
}
