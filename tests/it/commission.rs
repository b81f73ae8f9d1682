//! Commissioning the simulated TriCal cell through the daemon's service, the test acting as
//! the operator: it answers each prompt by jogging the robot (`cell.jog`) a few mm off the
//! true ball and resuming the job. From a model whose TCP is several millimetres off and
//! whose base frame (hence the balls in the robot frame) is wrong, the zero check passes,
//! the TCP and the balls are recovered within the centring noise, a daemon restart while a
//! step waits changes nothing, and a TriCal campaign on the commissioned cell validates at
//! the noise level.

use std::sync::Arc;
use std::time::Duration;

use calibd::geometry::Frame;
use calibd::lab::{CellModel, Lab};
use calibd::service::{Origin, Service, ServiceConfig, Submitter};
use calibd::sim::SimOptions;
use calibd::store::{JobState, Store};
use calibd::twin::SerialTwin;
use calibd::util::Rng;
use nalgebra::Vector3;
use serde_json::{Value, json};
use tokio_util::sync::CancellationToken;

fn operator() -> Submitter {
    Submitter {
        name: Some("test".into()),
        may_drive_devices: true,
    }
}

async fn start(
    dir: &std::path::Path,
    lab: Arc<Lab>,
) -> (Service, CancellationToken, calibd::service::Workers) {
    let stop = CancellationToken::new();
    let cfg = ServiceConfig {
        workers: 1,
        ..Default::default()
    };
    let (svc, w) = Service::start_with_lab(Store::open(dir).unwrap(), cfg, Some(lab), stop.clone())
        .await
        .unwrap();
    (svc, stop, w)
}

async fn until_state(svc: &Service, id: i64, states: &[JobState]) -> calibd::store::JobRecord {
    for _ in 0..1800 {
        let j = svc.job(id).await.unwrap();
        if states.contains(&j.state) {
            return j;
        }
        assert!(
            !j.state.is_final(),
            "job {id} ended {:?}: {:?}",
            j.state,
            j.error
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("job {id} never reached {states:?}");
}

async fn run(svc: &Service, doc: Value) -> Value {
    let id = svc
        .submit(doc, 0, operator(), Origin::default())
        .await
        .unwrap();
    until_state(svc, id, &[JobState::Succeeded]).await;
    svc.store().result(id).unwrap().unwrap()
}

/// Wait for job `id` to wait for the operator; return the prompt.
async fn prompt(svc: &Service, id: i64) -> String {
    let j = until_state(svc, id, &[JobState::Paused]).await;
    let e = j.error.unwrap_or_default();
    assert!(e.starts_with("waiting for the operator: "), "{e}");
    e
}

/// A zero check, the operator confirming its prompt.
async fn zero_check(svc: &Service) -> Value {
    let doc = json!({"kind": "cell.zero_check", "cell": "irb120", "readings": 4,
                     "options": {"settle_ms": 20}});
    let z = svc
        .submit(doc, 0, operator(), Origin::default())
        .await
        .unwrap();
    assert!(prompt(svc, z).await.contains("coupling platform"));
    svc.resume(z).await.unwrap();
    until_state(svc, z, &[JobState::Succeeded]).await;
    svc.store().result(z).unwrap().unwrap()
}

/// The operator: jog the robot to `q` (rad).
async fn jog(svc: &Service, q: &[f64]) {
    let q_deg: Vec<f64> = q.iter().map(|v| v.to_degrees()).collect();
    run(
        svc,
        json!({"kind": "cell.jog", "cell": "irb120", "q_deg": q_deg}),
    )
    .await;
}

/// `n` joint configurations putting the true TCP `off_mm` from ball `b`, with flange
/// orientations at least `min_deg` apart.
fn near_ball(
    twin: &SerialTwin,
    b: usize,
    n: usize,
    off_mm: f64,
    min_deg: f64,
    seed: u64,
) -> Vec<Vec<f64>> {
    let mut rng = Rng::new(seed);
    let centre = twin.plate.centres[b].unwrap();
    let mut out: Vec<Vec<f64>> = Vec::new();
    for _ in 0..2000 {
        let q0 = twin.random_q(&mut rng);
        let dir = Vector3::from(rng.in_ball(1.0)).normalize();
        let Some(q) = twin.reach(&q0, &(centre + dir * off_mm)) else {
            continue;
        };
        let r = twin.truth.tcp(&q, None);
        if out
            .iter()
            .all(|p| twin.truth.tcp(p, None).angle_to(&r).to_degrees() > min_deg)
        {
            out.push(q);
        }
        if out.len() == n {
            return out;
        }
    }
    panic!("no {n} configurations near ball {b}");
}

fn v3(v: &Value) -> Vector3<f64> {
    Vector3::new(
        v[0].as_f64().unwrap(),
        v[1].as_f64().unwrap(),
        v[2].as_f64().unwrap(),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn commissioning_recovers_the_true_tcp_and_balls_and_a_campaign_then_reaches_the_noise_level()
{
    let opts = SimOptions::default();
    let twin = SerialTwin::irb120(opts.seed);
    let dir = tempfile::tempdir().unwrap();
    let lab = Arc::new(Lab::simulated(&opts).await.unwrap());
    // The arm's joint geometry is known (the twin's), but the TCP is off by several mm and
    // the base frame (the balls in the robot frame) by 6 mm and 0.8 deg.
    let mut start_model = twin.file.with_chain(&twin.truth);
    let true_tool = Vector3::new(start_model.tool.x, start_model.tool.y, start_model.tool.z);
    start_model.tool.x += 3.0;
    start_model.tool.y -= 2.5;
    start_model.tool.z += 4.0;
    start_model.base.x += 6.0;
    start_model.base.y -= 4.0;
    start_model.base.a += 0.8;
    lab.cell("irb120")
        .unwrap()
        .set_model(CellModel::Serial(start_model.clone()))
        .unwrap();
    let (mut svc, mut stop, mut workers) = start(dir.path(), lab.clone()).await;

    // 1. Zero check: the device at its zero (in the simulation: centred on ball 1).
    let ball1 = twin.plate.centres[0].unwrap();
    let q_zero = twin
        .reach(&near_ball(&twin, 0, 1, 2.0, 0.0, 1)[0], &ball1)
        .unwrap();
    jog(&svc, &q_zero).await;
    let zr = zero_check(&svc).await;
    assert_eq!(zr["passed"], true, "{zr}");
    // 0.02 mm off along the world x axis: the check names what is out of tolerance.
    let q_off = twin
        .reach(&q_zero, &(ball1 + Vector3::new(0.02, 0.0, 0.0)))
        .unwrap();
    jog(&svc, &q_off).await;
    let off = zero_check(&svc).await;
    eprintln!("zero check 0.02 mm off: {}", off["message"]);
    assert_eq!(off["passed"], false, "{off}");
    assert!(
        off["message"]
            .as_str()
            .unwrap()
            .contains("beyond the 0.005 mm tolerance")
    );
    jog(&svc, &q_zero).await;
    assert_eq!(zr["readings"], 4);

    // 2. TCP: four configurations on ball 1; the daemon restarts while the second waits.
    let configs = near_ball(&twin, 0, 4, 2.0, 35.0, 2);
    let centring = json!({"settle_ms": 20, "reading_timeout_ms": 400});
    let t = svc
        .submit(
            json!({"kind": "cell.identify_tcp", "cell": "irb120", "ball": 1,
                       "options": {"centring": centring}}),
            0,
            operator(),
            Origin::default(),
        )
        .await
        .unwrap();
    for (k, q) in configs.iter().enumerate() {
        let p = prompt(&svc, t).await;
        assert!(
            p.contains(&format!("configuration {}/4", k + 1)) && p.contains("ball 1"),
            "{p}"
        );
        if k == 1 {
            stop.cancel();
            workers.join().await;
            (svc, stop, workers) = start(dir.path(), lab.clone()).await;
            assert_eq!(prompt(&svc, t).await, p, "the prompt survives the restart");
        }
        jog(&svc, q).await;
        svc.resume(t).await.unwrap();
    }
    until_state(&svc, t, &[JobState::Succeeded]).await;
    let tr = svc.store().result(t).unwrap().unwrap();
    let tcp = v3(&tr["tcp_mm"]);
    let tcp_std = v3(&tr["tcp_std_mm"]);
    let start_off = (Vector3::new(start_model.tool.x, start_model.tool.y, start_model.tool.z)
        - true_tool)
        .norm();
    eprintln!(
        "TCP recovered {tcp:.4?} std {tcp_std:.4?}; true {true_tool:.4?}; error {:.4} mm (start was {start_off:.2} mm off)",
        (tcp - true_tool).norm()
    );
    eprintln!(
        "TCP spread {} mm before, {} mm after; max rotation {} deg",
        tr["previous_spread_rms_mm"], tr["spread_rms_mm"], tr["max_rotation_deg"]
    );
    assert!((tcp - true_tool).norm() < 0.010, "{tcp:?} vs {true_tool:?}");
    let m = lab.trical("irb120").unwrap().current_model();
    assert!(
        (Vector3::new(m.tool.x, m.tool.y, m.tool.z) - tcp).norm() < 1e-9,
        "the TCP was accepted"
    );

    // 3. Balls: one jog per ball, a few mm off, then centred.
    let b = svc
        .submit(
            json!({"kind": "cell.locate_balls", "cell": "irb120",
                       "options": {"centring": centring}}),
            0,
            operator(),
            Origin::default(),
        )
        .await
        .unwrap();
    for k in 0..3 {
        let p = prompt(&svc, b).await;
        assert!(p.contains(&format!("ball {}/3", k + 1)), "{p}");
        jog(&svc, &near_ball(&twin, k, 1, 2.5, 0.0, 10 + k as u64)[0]).await;
        svc.resume(b).await.unwrap();
    }
    until_state(&svc, b, &[JobState::Succeeded]).await;
    let br = svc.store().result(b).unwrap().unwrap();
    let true_base = twin.truth.base_frame();
    for (k, ball) in br["balls"].as_array().unwrap().iter().enumerate() {
        let got = v3(&ball["in_robot_mm"]);
        let truth = true_base.inverse().apply(&twin.plate.centres[k].unwrap());
        eprintln!(
            "ball {}: recovered {got:.4?} (std {}) true {truth:.4?} error {:.4} mm",
            k + 1,
            ball["std_mm"],
            (got - truth).norm()
        );
        assert!(
            (got - truth).norm() < 0.010,
            "ball {k}: {got:?} vs {truth:?}"
        );
    }
    for d in br["distances"].as_array().unwrap() {
        eprintln!(
            "distance {}: {} mm (std {}) ballbar {} mm",
            d["pair"], d["measured_mm"], d["std_mm"], d["ballbar_mm"]
        );
        assert!(d["difference_mm"].as_f64().unwrap().abs() < 0.02, "{d}");
    }
    let m = lab.trical("irb120").unwrap().current_model();
    let base = Frame::from_xyzabc(&m.to_chain().unwrap().base);
    eprintln!(
        "base recovered {:.4?} true {:.4?}; error {:.4} mm, {:.5} deg",
        base.p,
        true_base.p,
        (base.p - true_base.p).norm(),
        base.angle_to(&true_base).to_degrees()
    );
    assert!((base.p - true_base.p).norm() < 0.02 && base.angle_to(&true_base).to_degrees() < 0.005);

    // 4. A TriCal campaign on the commissioned cell.
    let r = run(
        &svc,
        json!({
            "kind": "cell.trical_campaign", "cell": "irb120",
            "design": {"pool_per_ball": 16, "per_ball": 6, "seed": 3},
            "validation": {"per_ball": 2, "seed": 4},
            "options": {"centring": {"settle_ms": 40, "reading_timeout_ms": 400},
                        "retry": {"attempts": 4, "backoff_ms": 50}}
        }),
    )
    .await;
    let after = r["validation"]["after"]["mean"].as_f64().unwrap();
    let before = r["validation"]["before"]["mean"].as_f64().unwrap();
    eprintln!(
        "TriCal campaign on the commissioned cell: validation mean {before:.4} -> {after:.4} mm"
    );
    assert!(after < 0.010, "{before} -> {after}");
    stop.cancel();
}

#[test]
fn the_example_jobs_prepare_and_bad_documents_name_the_field() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples");
    for f in [
        "commission_zero_check.json",
        "commission_identify_tcp.json",
        "commission_locate_balls.json",
        "cell_jog.json",
        "cell_verify.json",
    ] {
        let doc: Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join(f)).unwrap()).unwrap();
        let job = calibd::jobs::prepare(&doc, &calibd::jobs::NoReferences).unwrap();
        assert_eq!(job.resumable(), f != "cell_jog.json", "{f}");
        assert!(!job.devices().is_empty(), "{f}");
    }
    let bad = [
        (
            json!({"kind": "cell.identify_tcp", "configurations": 2}),
            "configurations",
        ),
        (json!({"kind": "cell.identify_tcp", "ball": 4}), "ball"),
        (
            json!({"kind": "cell.zero_check", "options": {"tolerance_mm": -1}}),
            "tolerance_mm",
        ),
        (
            json!({"kind": "cell.locate_balls", "options": {"tcp_std_mm": [0, -1, 0]}}),
            "tcp_std_mm",
        ),
        (json!({"kind": "cell.jog", "q_deg": [0, "x"]}), "q_deg"),
    ];
    for (doc, field) in bad {
        let e = calibd::jobs::prepare(&doc, &calibd::jobs::NoReferences)
            .unwrap_err()
            .to_string();
        assert!(e.contains(field), "{doc}: {e}");
    }
}
