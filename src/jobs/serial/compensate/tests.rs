use serde_json::{Map, Value, json};

use super::*;
use crate::jobs::prepare as prepare_job;
use crate::run::NoReferences;
use crate::twin::SerialTwin;
use crate::util::{NoMonitor, Rng};

/// A targets row: the pose (mm, deg) of `f` as `serial.fk` writes it, and optional
/// reference joints (rad, written in deg).
fn row(f: &Frame, reference: Option<&[f64]>) -> Value {
    let v = f.to_xyzabc();
    let mut o = Map::new();
    for (k, name) in POSE_COLUMNS.iter().enumerate() {
        let x = if k < 3 { v[k] } else { v[k].to_degrees() };
        o.insert(name.to_string(), json!(x));
    }
    if let Some(q) = reference {
        for (k, x) in q.iter().enumerate() {
            o.insert(format!("q{}", k + 1), json!(x.to_degrees()));
        }
    }
    Value::Object(o)
}

fn run(doc: &Value) -> crate::jobs::Completed {
    prepare_job(doc, &NoReferences)
        .expect("valid job")
        .run(&NoMonitor)
        .expect("job runs")
}

/// Joints (rad) of every row of a compensate main table.
fn joints(t: &Table) -> Vec<Vec<f64>> {
    t.rows
        .iter()
        .map(|r| r[..6].iter().map(|v| v.to_radians()).collect())
        .collect()
}

fn mean_max(v: &[f64]) -> (f64, f64) {
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    (mean, v.iter().copied().fold(0.0, f64::max))
}

#[test]
fn on_the_twin_compensated_joints_land_as_close_as_the_calibration_nominal_ones_do_not() {
    // Calibrate the twin: serial.identify on its ball-centring measurements.
    let identified = run(&crate::jobs::examples::twin_identify(40, 60));
    let twin = SerialTwin::irb120(1);
    // Targets: poses an offline program asks for (nominal FK of random joints).
    let mut rng = Rng::new(21);
    let qs: Vec<Vec<f64>> = (0..200).map(|_| twin.random_q(&mut rng)).collect();
    let rows: Vec<Value> = qs
        .iter()
        .map(|q| row(&twin.nominal.tcp(q, None), Some(q)))
        .collect();
    let targets: Vec<Frame> = qs.iter().map(|q| twin.nominal.tcp(q, None)).collect();
    let nominal_model = serde_json::to_value(&twin.file).unwrap();
    let errors = |model: Value| -> (Vec<f64>, usize) {
        let done = run(&json!({"kind": "serial.compensate", "model": model, "targets": rows}));
        let t = done.main_table.expect("main table");
        let mut e = Vec::new();
        for ((q, r), target) in joints(&t).iter().zip(&t.rows).zip(&targets) {
            if r[8] == Status::Reached.code() {
                e.push((twin.true_tcp(q) - target.p).norm());
            }
        }
        (e, t.rows.len())
    };
    // The identify result itself is the model: its calibrated_model is used.
    let (comp, n) = errors(identified.result.clone());
    let (nom, _) = errors(nominal_model);
    assert!(
        comp.len() > n * 9 / 10 && nom.len() > n * 9 / 10,
        "{} {}",
        comp.len(),
        nom.len()
    );
    // The calibrated model's own error against the truth (validation error) on other joints.
    let cal = crate::model::dh::DhFile::from_value(identified.result["calibrated_model"].clone())
        .unwrap()
        .to_chain()
        .unwrap();
    let val: Vec<f64> = (0..500)
        .map(|_| {
            let q = twin.random_q(&mut rng);
            let tau = cal.static_torques(&q);
            (cal.tcp(&q, Some(&tau)).p - twin.true_tcp(&q)).norm()
        })
        .collect();
    let ((cm, cx), (nm, nx), (vm, vx)) = (mean_max(&comp), mean_max(&nom), mean_max(&val));
    println!(
        "true TCP position error on {n} targets: compensated mean {cm:.4} mm max {cx:.4} mm; \
         nominal mean {nm:.4} mm max {nx:.4} mm; calibrated model vs truth (validation) \
         mean {vm:.4} mm max {vx:.4} mm"
    );
    assert!(cm < 0.05, "compensated mean {cm} mm");
    assert!(nm > 1.0, "nominal mean {nm} mm");
    assert!(cm < 1.5 * vm + 0.005, "compensated {cm} vs validation {vm}");
}

#[test]
fn unreachable_rows_get_their_status_and_the_others_are_reached() {
    let twin = SerialTwin::irb120(1);
    let mut file = twin.file.clone();
    file.joints[0].limits = [-30.0, 30.0];
    let nominal = file.to_chain().unwrap();
    let mut rng = Rng::new(4);
    let mut qs: Vec<Vec<f64>> = (0..5)
        .map(|_| {
            let mut q = twin.random_q(&mut rng);
            q[0] = rng.range(-25.0, 25.0).to_radians();
            q
        })
        .collect();
    let mut rows: Vec<Value> = qs
        .iter()
        .map(|q| row(&nominal.tcp(q, None), Some(q)))
        .collect();
    // Far away; then joint 1 at 60 deg (its other branch at -120 deg is outside too).
    let mut far = nominal.tcp(&qs[0], None);
    far.p.z += 5000.0;
    rows.insert(2, row(&far, Some(&qs[0])));
    let mut beyond = qs[1].clone();
    beyond[0] = 60f64.to_radians();
    rows.insert(4, row(&nominal.tcp(&beyond, None), Some(&beyond)));
    let done = run(&json!({
        "kind": "serial.compensate",
        "model": serde_json::to_value(&file).unwrap(),
        "targets": rows,
    }));
    let t = done.main_table.unwrap();
    assert_eq!(
        t.columns[6..],
        ["residual_mm", "residual_deg", "status_code"]
    );
    let codes: Vec<f64> = t.rows.iter().map(|r| r[8]).collect();
    assert_eq!(codes, [0.0, 0.0, 2.0, 0.0, 1.0, 0.0, 0.0]);
    let statuses = done.result["rows"].as_array().unwrap();
    assert_eq!(statuses[2]["status"], "out_of_reach");
    assert!(
        statuses[2]["reason"]
            .as_str()
            .unwrap()
            .contains("out of reach")
    );
    assert_eq!(statuses[4]["status"], "out_of_joint_limits");
    assert!(
        statuses[4]["reason"]
            .as_str()
            .unwrap()
            .starts_with("q1 = 60")
    );
    assert_eq!(done.result["summary"]["reached"], 5);
    // Reached rows: the generating joints, within 1 um of the target.
    qs.insert(2, vec![]);
    qs.insert(4, vec![]);
    for (i, r) in t.rows.iter().enumerate() {
        if r[8] != 0.0 {
            continue;
        }
        assert!(r[6] < 1e-3, "row {}: {} mm", i + 1, r[6]);
        for k in 0..6 {
            assert!(
                (r[k].to_radians() - qs[i][k]).abs() < 1e-9,
                "row {} q{}",
                i + 1,
                k + 1
            );
        }
    }
    // The CSV artefact names each status.
    let csv = String::from_utf8(done.artefacts[0].content.clone()).unwrap();
    assert!(
        csv.lines()
            .nth(3)
            .unwrap()
            .contains(",out_of_reach,\"out of reach"),
        "{csv}"
    );
}

#[test]
fn bad_targets_are_refused_naming_the_column() {
    let twin = SerialTwin::irb120(1);
    let model = serde_json::to_value(&twin.file).unwrap();
    let doc = json!({"kind": "serial.compensate", "model": model,
        "targets": [{"x": 1.0, "y": 2.0, "z": 3.0, "a": 0.0, "b": 0.0}]});
    let e = prepare_job(&doc, &NoReferences).unwrap_err().to_string();
    assert!(e.contains("targets") && e.contains("`c`"), "{e}");
    let doc = json!({"kind": "serial.compensate", "model": model,
        "targets": [{"x": 1.0, "y": 2.0, "z": 3.0, "a": 0.0, "b": 0.0, "c": 0.0, "q1": 0.0}]});
    let e = prepare_job(&doc, &NoReferences).unwrap_err().to_string();
    assert!(e.contains("reference joints need every column"), "{e}");
    let doc = json!({"kind": "serial.compensate", "model": model, "options": {"reference": [0.0]},
        "targets": [{"x": 1.0, "y": 2.0, "z": 3.0, "a": 0.0, "b": 0.0, "c": 0.0}]});
    let e = prepare_job(&doc, &NoReferences).unwrap_err().to_string();
    assert!(e.contains("options.reference"), "{e}");
}
