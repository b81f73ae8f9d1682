//! The verification against the simulated cell: per-pose AP through both models equals the
//! twin's true TCP error at the commanded joints; the compensated AP matches the calibrated
//! model's validation error and the nominal AP the nominal model's.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use serde_json::json;

use super::*;
use crate::campaigns::engine::Retry;
use crate::jobs::serial::identify::IdentifyJob;
use crate::measure::{PointMeasurement, Target};
use crate::procedures::MemoryJournal;
use crate::procedures::fakes::{FakeIndicators, FakeRobot, SharedCell};
use crate::run::{Inputs, NoReferences};
use crate::twin::SerialTwin;
use crate::twin::cell::SimulatedCell;
use crate::util::NoMonitor;

fn job(cycles: usize) -> VerifyJob {
    let doc = json!({"kind": "cell.verify", "poses": {"per_ball": 3}, "cycles": cycles});
    plan::prepare(&doc, &Inputs::new(&NoReferences)).unwrap()
}

/// Run the visits of `poses` on the simulated cell; the readings.
pub(crate) async fn read_all(
    cell: &SharedCell,
    poses: &[VerifyPose],
    cycles: usize,
) -> Vec<Reading> {
    let opts = CentringOptions {
        settle: Duration::ZERO,
        ..Default::default()
    };
    let step = Reader {
        robot: &FakeRobot(cell.clone()),
        indicators: &FakeIndicators(cell.clone()),
        options: &opts,
        range_mm: crate::twin::cell::INDICATOR_HALF_RANGE_MM,
    };
    let retry = Retry {
        attempts: 2,
        backoff: Duration::from_millis(1),
    };
    let v = visits(poses, cycles);
    let journal = MemoryJournal::default();
    let s = engine::run(&step, &v, 0, &journal, &retry, &NoMonitor)
        .await
        .unwrap();
    assert_eq!((s.recorded, s.skipped), (v.len(), 0));
    engine::recorded(&journal, 0, v.len()).unwrap()
}

/// A calibration of `twin` from 60 centrings, validated on 15 held-out ball centres.
pub(crate) fn calibrate(twin: &SerialTwin) -> (crate::model::dh::DhFile, f64, f64) {
    let meas = twin.centring(20, 11);
    let val: Vec<PointMeasurement> = twin
        .centring(5, 12)
        .into_iter()
        .map(|m| {
            let Target::Ball(b) = m.target else {
                unreachable!()
            };
            PointMeasurement {
                q: m.q,
                target: Target::Point(twin.plate.centres[b].unwrap()),
            }
        })
        .collect();
    let cal = IdentifyJob::from_dh(
        twin.file.clone(),
        meas,
        twin.ballbar,
        Some(val),
        Default::default(),
    )
    .unwrap()
    .calibrate(&NoMonitor)
    .unwrap()
    .result;
    let v = cal.validation.clone().unwrap();
    (
        cal.calibrated_model.dh().unwrap().clone(),
        v.before.mean,
        v.after.mean,
    )
}

/// The twin's envelope: its model's joint limits, no workspace box.
fn joint_limits(twin: &SerialTwin) -> crate::procedures::Envelope {
    crate::procedures::Envelope {
        limits: twin.nominal.variable_limits(),
        max_joint_step: std::f64::consts::PI,
        max_tool_step_mm: 6.5,
        workspace_mm: None,
    }
}

#[tokio::test]
async fn compensated_ap_is_the_calibrated_validation_error_and_nominal_ap_the_nominal_one() {
    let twin = SerialTwin::irb120(1);
    let (model, before, after) = calibrate(&twin);
    let job = job(3);
    let plan = job
        .plan(
            &model,
            &twin.file,
            twin.ballbar,
            &joint_limits(&twin),
            &NoMonitor,
        )
        .unwrap();
    assert_eq!(plan.poses.len(), 9, "dropped: {:?}", plan.dropped);
    let cell: SharedCell = Arc::new(Mutex::new(SimulatedCell::new(twin.clone(), 9)));
    let rec = read_all(&cell, &plan.poses, 3).await;
    let (per, dist, [nom, comp]) = figures::evaluate(&plan.poses, &rec, 3);
    // Per pose: AP is the twin's true TCP error at the commanded joints (indicator noise
    // 0.0005 mm, resolution 0.001 mm), RP the noise only (the same pose reads the same).
    let truth = |q: &[f64], p: &VerifyPose| (twin.true_tcp(q) - p.target.p).norm();
    for (f, p) in per.iter().zip(&plan.poses) {
        let (n, c) = (truth(&p.nominal[0], p), truth(&p.compensated[0], p));
        let (ap_n, ap_c) = (f.nominal.ap_mm.unwrap(), f.compensated.ap_mm.unwrap());
        assert!(
            (ap_n - n).abs() < 0.002,
            "pose {}: {ap_n} vs true {n}",
            f.pose
        );
        assert!(
            (ap_c - c).abs() < 0.002,
            "pose {}: {ap_c} vs true {c}",
            f.pose
        );
        assert!(f.compensated.rp_mm.unwrap() < 0.003 && f.nominal.out_of_range == 0);
    }
    // AD: commanded distance against the true TCPs' distance.
    for d in &dist {
        let [a, b] = d.poses.map(|k| &plan.poses[k - 1]);
        let true_d = (twin.true_tcp(&a.compensated[0]) - twin.true_tcp(&b.compensated[0])).norm();
        let want = true_d - (a.target.p - b.target.p).norm();
        let got = d.compensated_ad_mm.unwrap();
        assert!(
            (got - want).abs() < 0.003,
            "AD {:?}: {got} vs {want}",
            d.poses
        );
    }
    // Over the poses: the calibrated model's held-out error, and the nominal model's.
    let (ap_c, ap_n) = (comp.ap_mean_mm.unwrap(), nom.ap_mean_mm.unwrap());
    println!(
        "AP mean nominal {ap_n:.4} mm (validation before {before:.4}), compensated {ap_c:.4} mm \
         (validation after {after:.4}); RP max {:.4} / {:.4} mm; |AD| max {:.4} / {:.4} mm",
        nom.rp_max_mm.unwrap(),
        comp.rp_max_mm.unwrap(),
        nom.ad_max_abs_mm.unwrap(),
        comp.ad_max_abs_mm.unwrap()
    );
    assert!(
        ap_c < 0.05 && ap_c < 3.0 * after + 0.005 && ap_c > after / 3.0,
        "compensated AP {ap_c} mm, validation {after} mm"
    );
    assert!(
        ap_n > 0.5 * before && ap_n < 2.0 * before && ap_n > 20.0 * ap_c,
        "nominal AP {ap_n} mm, nominal validation {before} mm"
    );
    assert!(nom.ad_max_abs_mm.unwrap() > comp.ad_max_abs_mm.unwrap());
}

#[test]
fn saturated_readings_are_out_of_range_not_errors_of_that_size() {
    let twin = SerialTwin::irb120(1);
    let job = job(2);
    let plan = job
        .plan(
            &twin.file,
            &twin.file,
            twin.ballbar,
            &joint_limits(&twin),
            &NoMonitor,
        )
        .unwrap();
    let reading = |cycle, r: [f64; 3], out| Reading {
        index: 0,
        cycle,
        pose: 0,
        commanded: Commanded::Nominal,
        r_mm: r,
        out_of_range: out,
    };
    let rec = vec![
        reading(0, [0.3, 0.4, 0.0], false),
        reading(1, [6.35, 0.4, 0.0], true),
    ];
    let (per, _, [nom, _]) = figures::evaluate(&plan.poses, &rec, 2);
    let f = &per[0].nominal;
    assert_eq!((f.cycles, f.out_of_range), (1, 1));
    assert!((f.ap_mm.unwrap() - 0.5).abs() < 1e-12 && nom.out_of_range_poses == 1);
    // A pose without readings in range has no AP.
    assert_eq!(per[1].nominal.ap_mm, None);
}

#[test]
fn bad_documents_name_the_field() {
    let e = |doc: serde_json::Value| {
        plan::prepare(&doc, &Inputs::new(&NoReferences))
            .unwrap_err()
            .to_string()
    };
    assert!(e(json!({"kind": "cell.verify", "poses": {"per_ball": 0}})).contains("poses.per_ball"));
    assert!(
        e(json!({"kind": "cell.verify", "poses": {"per_ball": 1}, "cycles": 0})).contains("cycles")
    );
    assert!(
        e(json!({"kind": "cell.verify", "poses": {"per_ball": 1}, "indicator_range_mm": -1}))
            .contains("indicator_range_mm")
    );
}
