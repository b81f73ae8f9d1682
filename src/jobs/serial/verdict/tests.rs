//! The rows of issue 30's table that concern `serial.identify`, on the IRB 120 twin: each
//! with its honest verdict.

use serde_json::{Value, json};

use crate::identify::Verdict;
use crate::jobs::examples::twin_identify;
use crate::jobs::serial::identify::{IdentifyJob, SerialCalibration, prepare};
use crate::jobs::withhold_rejected;
use crate::run::Run;
use crate::run::{Inputs, NoReferences};
use crate::util::monitor::NoMonitor;

fn run(doc: &Value) -> Run<SerialCalibration> {
    let job: IdentifyJob = prepare(doc, &Inputs::new(&NoReferences)).expect("a valid job");
    job.calibrate(&NoMonitor).expect("the identification runs")
}

/// The twin job with `per_ball` centrings per ball, `validation` tracker points and the
/// twin's noise given (so that rank decisions do not hang on the fitted sigma).
fn twin(per_ball: usize, validation: usize) -> Value {
    let mut doc = twin_identify(per_ball, validation.max(1));
    doc["options"] = json!({"noise": 0.010});
    if validation == 0
        && let Some(o) = doc.as_object_mut()
    {
        o.remove("validation");
    }
    doc
}

fn rows(doc: &Value, key: &str) -> Vec<Value> {
    doc[key].as_array().cloned().unwrap_or_default()
}

#[test]
fn the_twin_with_enough_distinct_rows_is_not_rejected() {
    let r = run(&twin(20, 0)).result;
    assert_eq!(r.convergence.status, "converged");
    assert!(r.dof > 100, "dof {}", r.dof);
    assert_ne!(
        r.assessment.verdict,
        Verdict::Rejected,
        "{:?}",
        r.assessment
    );
    assert!(!r.assessment.has("duplicates"));
    assert!(!r.assessment.has("units"));
}

#[test]
fn joints_in_radians_in_a_degree_column_are_rejected_and_no_calibrated_model_is_made() {
    let mut doc = twin(20, 0);
    let mut meas = rows(&doc, "measurements");
    for m in &mut meas {
        for k in 1..=6 {
            let key = format!("q{k}");
            let deg = m[&key].as_f64().unwrap_or_default();
            m[&key] = json!(deg.to_radians());
        }
    }
    doc["measurements"] = Value::Array(meas);
    let run = run(&doc);
    let a = run.result.assessment.clone();
    assert_eq!(a.verdict, Verdict::Rejected, "{a:?}");
    assert!(a.has("units"), "{a:?}");
    assert!(
        a.reasons
            .iter()
            .any(|r| r.message.contains("look like radians")),
        "{a:?}"
    );
    assert_eq!(a.verdict.exit_code(), 4);
    let mut out = run.into_output().expect("output");
    withhold_rejected(&mut out);
    let names: Vec<&str> = out.artefacts.iter().map(|a| a.name.as_str()).collect();
    assert!(names.contains(&"rejected_model.json"), "{names:?}");
    assert!(
        !names.iter().any(|n| n.starts_with("calibrated_model")),
        "{names:?}"
    );
    assert!(out.fields.contains_key("rejected_model"));
    assert!(!out.fields.contains_key("calibrated_model"));
}

#[test]
fn five_ball_centrings_leave_zero_dof_and_are_rejected() {
    let mut doc = twin(2, 0);
    let mut meas = rows(&doc, "measurements");
    meas.truncate(5);
    doc["measurements"] = Value::Array(meas);
    let r = run(&doc).result;
    assert_eq!(r.dof, 0);
    assert_eq!(r.residual_std.dof, 0);
    assert!(r.residual_std.value.is_none());
    assert_eq!(
        r.assessment.verdict,
        Verdict::Rejected,
        "{:?}",
        r.assessment
    );
    assert!(r.assessment.has("zero_dof"), "{:?}", r.assessment);
}

#[test]
fn twelve_rows_repeated_twenty_times_are_review_with_the_std_of_the_twelve() {
    let twelve = twin(4, 0);
    let meas = rows(&twelve, "measurements");
    assert_eq!(meas.len(), 12);
    let mut repeated = twelve.clone();
    repeated["measurements"] = Value::Array(
        (0..20)
            .flat_map(|_| meas.iter().cloned())
            .collect::<Vec<_>>(),
    );
    let (a, b) = (run(&twelve).result, run(&repeated).result);
    assert_eq!(b.assessment.verdict, Verdict::Review, "{:?}", b.assessment);
    assert!(b.assessment.has("duplicates"), "{:?}", b.assessment);
    let msg = &b
        .assessment
        .reasons
        .iter()
        .find(|r| r.code == "duplicates")
        .unwrap()
        .message;
    assert!(msg.starts_with("228 of 240 rows repeat"), "{msg}");
    assert_eq!(b.dof, a.dof);
    let (sa, sb) = (a.residual_std.value.unwrap(), b.residual_std.value.unwrap());
    assert!((sa - sb).abs() < 1e-6 * sa, "residual std {sa} vs {sb}");
    let mut compared = 0;
    for (p, q) in a.parameters.iter().zip(&b.parameters) {
        assert_eq!(p.name, q.name);
        if let (Some(x), Some(y)) = (p.std, q.std) {
            assert!(
                (x - y).abs() < 1e-3 * x,
                "{}: std {x} (12 rows) vs {y}",
                p.name
            );
            compared += 1;
        }
    }
    assert!(
        compared > 10,
        "only {compared} standard deviations compared"
    );
}

#[test]
fn validation_beyond_the_training_range_of_a_joint_is_named() {
    let mut doc = twin(30, 120);
    let q6 = |m: &Value| m["q6"].as_f64().unwrap_or_default();
    let train: Vec<Value> = rows(&doc, "measurements")
        .into_iter()
        .filter(|m| q6(m) <= 0.0)
        .collect();
    let top = train.iter().map(q6).fold(f64::MIN, f64::max);
    let val: Vec<Value> = rows(&doc, "validation")
        .into_iter()
        .filter(|m| q6(m) > top + 20.0)
        .collect();
    assert!(
        train.len() > 20 && val.len() > 5,
        "{} {}",
        train.len(),
        val.len()
    );
    doc["measurements"] = Value::Array(train);
    doc["validation"] = Value::Array(val.clone());
    let r = run(&doc).result;
    let e = r
        .assessment
        .reasons
        .iter()
        .find(|x| x.code == "extrapolation" && x.message.starts_with("joint q6"))
        .unwrap_or_else(|| panic!("{:?}", r.assessment));
    assert!(
        e.message
            .contains(&format!("{} of {} validation rows", val.len(), val.len())),
        "{}",
        e.message
    );
    assert_ne!(r.assessment.verdict, Verdict::Accepted);
}
