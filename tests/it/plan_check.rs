//! A campaign's whole plan against its cell's envelope before anything moves: a cell whose
//! lab narrows joints 4 and 6 and boxes the TCP (the simulated IRB 120 devices, recorded
//! on the wire); the design draws only inside, a dry run answers the plan, its check and
//! the estimated duration while nothing is stored or sent to the controller, and a plan
//! with offending configurations is refused at submit with every one of them listed.

use std::sync::Arc;

use calibd::lab::{CellLink, Lab};
use calibd::service::{Origin, Service, ServiceConfig, ServiceError, Submitter};
use calibd::sim::trical::Served;
use calibd::store::{JobFilter, JobState, Store};
use serde_json::{Value, json};
use tokio_util::sync::CancellationToken;

const LIMITS_DEG: [[f64; 2]; 6] = [
    [-165.0, 165.0],
    [-110.0, 110.0],
    [-110.0, 70.0],
    [-100.0, 100.0],
    [-120.0, 120.0],
    [-120.0, 120.0],
];
const MARGIN_MM: f64 = 250.0;
const MAX_STEP_DEG: f64 = 30.0;

fn operator() -> Submitter {
    Submitter {
        name: Some("test".into()),
        may_drive_devices: true,
    }
}

/// The workspace box: the plate's ball centres +- the margin (mm), in the robot's base
/// frame (where the lab file's box is).
fn workspace() -> [[f64; 3]; 2] {
    let twin = calibd::twin::SerialTwin::irb120(7);
    let to_base = twin.nominal.base_frame().inverse();
    let c: Vec<_> = twin
        .plate
        .centres
        .iter()
        .flatten()
        .map(|p| to_base.apply(p))
        .collect();
    let lo = |k: usize| c.iter().map(|p| p[k]).fold(f64::INFINITY, f64::min) - MARGIN_MM;
    let hi = |k: usize| c.iter().map(|p| p[k]).fold(f64::NEG_INFINITY, f64::max) + MARGIN_MM;
    [[lo(0), lo(1), lo(2)], [hi(0), hi(1), hi(2)]]
}

/// The TCP (mm, robot base frame) of the nominal model at `q_deg`.
fn tcp_mm(q_deg: &[f64]) -> [f64; 3] {
    let twin = calibd::twin::SerialTwin::irb120(7);
    let q: Vec<f64> = q_deg.iter().map(|v| v.to_radians()).collect();
    let p = twin.nominal.tcp_in_base(&q, None).p * if twin.nominal.units.mm { 1.0 } else { 1000.0 };
    [p.x, p.y, p.z]
}

fn inside(p: [f64; 3], b: [[f64; 3]; 2]) -> bool {
    (0..3).all(|k| p[k] >= b[0][k] && p[k] <= b[1][k])
}

fn q_deg(t: &Value) -> Vec<f64> {
    t["q_deg"]
        .as_array()
        .expect("q_deg")
        .iter()
        .map(|v| v.as_f64().expect("number"))
        .collect()
}

fn design() -> Value {
    json!({
        "kind": "cell.trical_campaign", "cell": "irb120",
        "design": {"pool_per_ball": 16, "per_ball": 6, "seed": 3},
        "validation": {"per_ball": 2, "seed": 4},
        "options": {"centring": {"settle_ms": 40, "reading_timeout_ms": 400}}
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn plans_are_checked_against_the_envelope_before_anything_moves() {
    let dir = tempfile::tempdir().expect("dir");
    let wire = dir.path().join("wire");
    std::fs::create_dir(&wire).expect("dir");
    let (mut cell, mocks) = calibd::sim::trical::start_at(
        7,
        &calibd::sim::SimTricalOptions::default(),
        &Served {
            rws: "127.0.0.1:0".into(),
            uwave: None,
            user: "Default User".into(),
            password: "robotics".into(),
        },
    )
    .await
    .expect("trical twin");
    let bounds = workspace();
    cell.joint_limits_deg = Some(LIMITS_DEG.to_vec());
    cell.workspace_mm = Some(bounds);
    cell.max_joint_step_deg = MAX_STEP_DEG;
    let speed = cell.joint_speed_deg_s;
    let lab = Arc::new(
        Lab::connect_recording(vec![CellLink::BallCentring(cell)], Some(&wire)).expect("lab"),
    );
    let stop = CancellationToken::new();
    let store = Store::open(&dir.path().join("data")).expect("store");
    let cfg = ServiceConfig {
        workers: 1,
        ..Default::default()
    };
    let (svc, _w) = Service::start_with_lab(store, cfg, Some(lab.clone()), stop.clone())
        .await
        .expect("service");

    // The dry run: 18 + 6 targets, every one inside the narrowed joints and the box (checked
    // here on the nominal model), each move split within the 30 deg step, and the duration.
    let d = serde_json::to_value(svc.dry_run(design()).await.expect("dry run")).expect("json");
    eprintln!("dry run: {}", d["envelope"]);
    assert_eq!(d["dry_run"], true);
    assert_eq!(d["envelope"]["ok"], true, "{}", d["envelope"]);
    let plan = d["plan"].as_array().expect("plan");
    assert_eq!(plan.len(), 24);
    assert_eq!(d["envelope"]["checked"], 24);
    let mut travel_deg = 0.0;
    let mut prev: Option<Vec<f64>> = None;
    for t in plan {
        let q = q_deg(t);
        for (k, (v, l)) in q.iter().zip(LIMITS_DEG).enumerate() {
            assert!(*v >= l[0] && *v <= l[1], "q{} = {v} outside {l:?}", k + 1);
        }
        assert!(inside(tcp_mm(&q), bounds), "{t}");
        let want_moves = match &prev {
            Some(p) => {
                let dq = p
                    .iter()
                    .zip(&q)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max);
                travel_deg += dq;
                ((dq / (0.99 * MAX_STEP_DEG)).ceil() as u64).max(1)
            }
            None => 1,
        };
        assert_eq!(t["moves"].as_u64(), Some(want_moves), "{t}");
        prev = Some(q);
    }
    // Joint travel at the cell's speed plus 4 settled corrective moves per configuration.
    let want_s = travel_deg / speed + 24.0 * 4.0 * 0.040;
    let got_s = d["estimated_duration_s"]
        .as_f64()
        .expect("estimated_duration_s");
    assert!(
        (got_s - want_s).abs() < 1e-6 * want_s,
        "{got_s} vs {want_s}"
    );

    // A plan with two offending configurations: refused at submit, both listed.
    let good = q_deg(&plan[0]);
    let mut wrist = good.clone();
    wrist[5] = 150.0;
    // The arm turned 150 deg about joint 1: the TCP behind the robot, far from the balls.
    let mut high = good.clone();
    high[0] += if high[0] > 0.0 { -150.0 } else { 150.0 };
    assert!(
        !inside(tcp_mm(&high), bounds),
        "the test's configuration must leave the box"
    );
    let row = |q: &[f64]| json!({"q1": q[0], "q2": q[1], "q3": q[2], "q4": q[3], "q5": q[4], "q6": q[5], "ball": 1});
    let bad = json!({
        "kind": "cell.trical_campaign", "cell": "irb120",
        "configurations": [row(&good), row(&wrist), row(&high), row(&good)],
    });
    let e = svc
        .submit(bad.clone(), 0, operator(), Origin::default())
        .await
        .expect_err("refused");
    let msg = e.to_string();
    eprintln!("refused: {msg}");
    assert!(matches!(e, ServiceError::Invalid(_)), "{msg}");
    assert!(
        msg.contains("2 of 4 configurations leave cell `irb120`'s envelope"),
        "{msg}"
    );
    assert!(
        msg.contains("measurement 2 (at")
            && msg.contains("joint 6 target 150.000 deg outside [-120.000, 120.000] deg"),
        "{msg}"
    );
    assert!(
        msg.contains("measurement 3 (at") && msg.contains("outside the workspace"),
        "{msg}"
    );
    assert!(
        !msg.contains("measurement 1 ") && !msg.contains("measurement 4 "),
        "{msg}"
    );
    // The dry run of the same plan lists them without refusing.
    let d = serde_json::to_value(svc.dry_run(bad).await.expect("dry run")).expect("json");
    let off: Vec<(u64, &str)> = d["envelope"]["offending"]
        .as_array()
        .expect("offending")
        .iter()
        .map(|o| {
            (
                o["index"].as_u64().unwrap_or(99),
                o["at"].as_str().unwrap_or(""),
            )
        })
        .collect();
    assert_eq!(off, [(1, "target"), (2, "target")], "{}", d["envelope"]);

    // Nothing was stored, and not one request reached the controller.
    let jobs = svc
        .jobs(JobFilter {
            limit: 10,
            ..Default::default()
        })
        .await
        .expect("jobs");
    assert!(jobs.is_empty(), "{jobs:?}");
    let rws = || std::fs::read_to_string(wire.join("irb120.abb.jsonl")).unwrap_or_default();
    assert!(!rws().contains("calib_cmd"), "{}", rws());

    // A jog inside the envelope does reach it (the transcript sees moves).
    let id = svc
        .submit(
            json!({"kind": "cell.jog", "cell": "irb120", "q_deg": good}),
            0,
            operator(),
            Origin::default(),
        )
        .await
        .expect("jog");
    loop {
        let j = svc.job(id).await.expect("job");
        if j.state.is_final() {
            assert_eq!(j.state, JobState::Succeeded, "{:?}", j.error);
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
    }
    assert!(rws().contains("calib_cmd"), "{}", rws());
    stop.cancel();
    lab.stop().await;
    for m in mocks {
        m.stop().await;
    }
}

/// A motion-capture campaign's postures table checked before the first move: a posture
/// outside the cell's narrowed limits is listed (and the plan refused at submit), long
/// posture moves are split within the cell's joint step, and the estimated duration is the
/// joint travel at the interface's speed plus settling and recording per posture.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mocap_postures_are_checked_against_the_cell_before_anything_moves() {
    let (mut link, mocks) = calibd::sim::mocap::start_at(
        5,
        &calibd::sim::mocap::SimMocapOptions::default(),
        "127.0.0.1:0",
        "127.0.0.1:0",
    )
    .await
    .expect("mocap twin");
    let step = 20f64.to_radians();
    link.joints.max_step_rad = step;
    // Narrow the first joint to [-0.5, 0.5] rad.
    link.limits[0] = [link.limits[0][0].max(-0.5), link.limits[0][1].min(0.5)];
    let names = link.joint_names.clone();
    let mid: Vec<f64> = link.limits.iter().map(|l| 0.5 * (l[0] + l[1])).collect();
    let speed = link.joints.speed_rad_s;
    let lab = Lab::connect(vec![CellLink::Mocap(link)]).expect("lab");
    // Three postures: the middle, the first joint 0.8 rad away (outside), then 0.3 rad off.
    let mut rows = vec![mid.clone(), mid.clone(), mid.clone()];
    rows[1][0] = mid[0] + 0.8;
    rows[2][0] = mid[0] + 0.3;
    let table: Vec<Value> = rows
        .iter()
        .map(|r| {
            Value::Object(
                names
                    .iter()
                    .zip(r)
                    .map(|(n, v)| (n.clone(), json!(v)))
                    .collect(),
            )
        })
        .collect();
    let doc = json!({"kind": "cell.mocap_campaign", "cell": "talos", "postures": table,
        "options": {"settle_s": 0.5, "record_s": 2.0}});
    let job = calibd::jobs::prepare(&doc, &calibd::jobs::NoReferences).expect("job");
    let p = job
        .preflight(&lab, &calibd::util::NoMonitor)
        .expect("a campaign on this lab's cell")
        .expect("a plan");
    let v = serde_json::to_value(&p).expect("json");
    eprintln!("mocap dry run: {}", v["envelope"]);
    assert_eq!(p.joints, names);
    assert_eq!(v["envelope"]["checked"], 3);
    let off = v["envelope"]["offending"].as_array().expect("offending");
    assert_eq!(off.len(), 1, "{off:?}");
    assert_eq!(off[0]["index"], 1);
    assert_eq!(off[0]["at"], "target");
    assert!(
        off[0]["reason"].as_str().unwrap().contains("joint 1"),
        "{off:?}"
    );
    // Moves: 1 to the first posture (where the robot stands is unknown), then the 0.8 rad
    // and 0.5 rad changes of joint 1 in steps of at most 0.99 x 20 deg.
    let moves: Vec<u64> = v["plan"]
        .as_array()
        .unwrap()
        .iter()
        .map(|t| t["moves"].as_u64().unwrap())
        .collect();
    let split = |d: f64| (d / (0.99 * step)).ceil() as u64;
    assert_eq!(moves, vec![1, split(0.8), split(0.5)]);
    assert_eq!(moves[1], 3);
    let expect_s = (0.8 + 0.5) / speed + 3.0 * 2.5;
    assert!(
        (p.estimated_duration_s - expect_s).abs() < 1e-9,
        "{} vs {expect_s}",
        p.estimated_duration_s
    );
    let refused = p.refusal().expect("refused").to_string();
    assert!(refused.contains("measurement 2"), "{refused}");
    for m in mocks {
        m.stop().await;
    }
}
