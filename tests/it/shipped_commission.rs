//! Commissioning rehearsed on the shipped lab: `deploy/lab.example.toml` served by
//! `calibd mock lab` (twins around the file's nominal), a daemon on the same file, and the
//! three commissioning examples submitted unchanged, in order. The test is the operator:
//! its hands on the device go to the mock lab's standard input (`mate`, `set`, `unmate`),
//! its jogs are `cell.jog` jobs, and it continues each prompt with `POST .../resume`.

use std::process::Command;

use nalgebra::Vector3;
use serde_json::{Value, json};

use crate::hil::{BIN, Daemon, Proc, lab_check};
use crate::shipped_lab::{example, repo, scratch_lab};

const SEED: u64 = 11;

/// Continue job `id` once it waits for the operator with a prompt containing `want`,
/// after `act` (what the operator does).
async fn answer(d: &Daemon, id: i64, want: &str) -> Value {
    let j = d.until_state(id, &["paused", "failed", "succeeded"]).await;
    let why = j["error"].as_str().unwrap_or_default();
    assert!(
        why.starts_with("waiting for the operator") && why.contains(want),
        "{j}"
    );
    j
}

async fn resume(d: &Daemon, id: i64) {
    let (s, r) = d.post(&format!("/v1/jobs/{id}/resume"), &json!({})).await;
    assert_eq!(s, 200, "{r}");
}

async fn finished(d: &Daemon, id: i64) -> Value {
    let j = d
        .until_state(id, &["succeeded", "failed", "cancelled"])
        .await;
    assert_eq!(j["state"], "succeeded", "{j}");
    d.get(&format!("/v1/jobs/{id}/result")).await
}

/// Jog the robot (as the teach pendant would) to `q` (rad).
async fn jog(d: &Daemon, q: &[f64]) {
    let q_deg: Vec<f64> = q.iter().map(|v| v.to_degrees()).collect();
    d.run(&json!({"kind": "cell.jog", "cell": "irb120", "q_deg": q_deg}))
        .await;
}

/// Joint values putting the true TCP 1.5 mm from `ball` (within the lab's 2 mm centring step), each orientation at least
/// `apart_deg` from the others'.
fn near(
    twin: &calibd::twin::SerialTwin,
    ball: Vector3<f64>,
    n: usize,
    apart_deg: f64,
    seed: u64,
) -> Vec<Vec<f64>> {
    let mut rng = calibd::util::Rng::new(seed);
    let mut qs: Vec<Vec<f64>> = Vec::new();
    for _ in 0..5000 {
        if qs.len() == n {
            break;
        }
        let q0 = twin.random_q(&mut rng);
        let off = Vector3::from(rng.in_ball(1.0)).normalize() * 1.5;
        if let Some(q) = twin.reach(&q0, &(ball + off)) {
            let r = twin.truth.tcp(&q, None);
            if qs
                .iter()
                .all(|p| twin.truth.tcp(p, None).angle_to(&r).to_degrees() > apart_deg)
            {
                qs.push(q);
            }
        }
    }
    assert_eq!(qs.len(), n, "configurations near the ball");
    qs
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_commissioning_examples_run_in_order_on_the_example_lab() {
    let _one = crate::hil::OUT_OF_PROCESS.lock().await;
    let dir = tempfile::tempdir().expect("temp dir");
    let lab = scratch_lab(dir.path());
    let mut mock = Proc::spawn(
        Command::new(BIN)
            .args([
                "mock",
                "lab",
                "--seed",
                &SEED.to_string(),
                "--cell",
                "irb120",
            ])
            .arg("--config")
            .arg(&lab),
    );
    mock.until("mock lab ready");
    let text = std::fs::read_to_string(repo("deploy/models/irb120.json")).expect("model");
    let nominal = calibd::model::dh::DhFile::parse(&text).expect("nominal");
    let twin = calibd::twin::SerialTwin::around(nominal, [200.0; 3], SEED).expect("twin");
    let coupling = calibd::sim::bench::coupling_offset_mm(SEED);
    let (_, out) = lab_check(&lab);
    assert!(out.contains("irb120.uwave"), "{out}");
    let d = Daemon::start(dir.path(), &lab);

    // 1. Zero check, the device mated but the set buttons not pressed: the coupling's
    // master ball is off the tool centre, and the check says so per indicator.
    let zero = example("commission_zero_check.json");
    let id = d.submit(&zero).await;
    answer(&d, id, "coupling platform").await;
    mock.send("mate irb120");
    mock.until("mock irb120: device mated on its coupling");
    resume(&d, id).await;
    let r = finished(&d, id).await;
    eprintln!("zero check before the set buttons: {r}");
    assert_eq!(r["passed"], false, "{r}");
    for k in 0..3 {
        let m = r["mean_mm"][k].as_f64().expect("mean");
        assert!(
            (m - coupling[k]).abs() < 0.002,
            "indicator {}: {m} vs the coupling's {}",
            k + 1,
            coupling[k]
        );
    }
    let named: Vec<u64> = r["out_of_tolerance"]
        .as_array()
        .expect("list")
        .iter()
        .filter_map(|o| o["indicator"].as_u64())
        .collect();
    let expected: Vec<u64> = (0..3)
        .filter(|&k| coupling[k].abs() > 0.005 + 0.002)
        .map(|k| k as u64 + 1)
        .collect();
    assert!(
        expected.iter().all(|k| named.contains(k)),
        "{named:?} vs {expected:?}"
    );

    // 2. The operator presses the set buttons on the coupling: the check passes.
    let id = d.submit(&zero).await;
    answer(&d, id, "set button").await;
    mock.send("set irb120");
    mock.until("mock irb120: set buttons pressed");
    resume(&d, id).await;
    let r = finished(&d, id).await;
    eprintln!("zero check after the set buttons: {r}");
    assert_eq!(r["passed"], true, "{r}");
    for k in 0..3 {
        assert!(r["max_abs_mm"][k].as_f64().expect("max") <= 0.002, "{r}");
    }
    mock.send("unmate irb120");
    mock.until("mock irb120: device back on the flange");

    // 3. The TCP from four orientations on ball 1.
    let balls: Vec<Vector3<f64>> = twin
        .plate
        .centres
        .iter()
        .map(|c| c.expect("ball"))
        .collect();
    let doc = example("commission_identify_tcp.json");
    let n = doc["configurations"].as_u64().expect("configurations") as usize;
    let id = d.submit(&doc).await;
    for q in near(&twin, balls[0], n, 35.0, 2) {
        answer(&d, id, "touch ball 1").await;
        jog(&d, &q).await;
        resume(&d, id).await;
    }
    let r = finished(&d, id).await;
    let tcp: Vec<f64> = (0..3)
        .map(|i| r["tcp_mm"][i].as_f64().expect("tcp"))
        .collect();
    let tool_err = (0..3)
        .map(|i| (tcp[i] - twin.truth.tool[i]).powi(2))
        .sum::<f64>()
        .sqrt();
    eprintln!(
        "identify_tcp: {tcp:?}, {tool_err:.3} mm from the twin's true TCP; spread {} -> {} mm",
        r["previous_spread_rms_mm"], r["spread_rms_mm"]
    );
    assert!(tool_err < 1.0, "{r}");
    let spread = r["spread_rms_mm"].as_f64().expect("spread");
    assert!(
        spread < r["previous_spread_rms_mm"].as_f64().expect("spread"),
        "{r}"
    );

    // 4. Each ball, jogged onto and centred; the plate's distances against the ballbar.
    let doc = example("commission_locate_balls.json");
    let id = d.submit(&doc).await;
    for (k, b) in balls.iter().enumerate() {
        answer(&d, id, &format!("touch ball {}", k + 1)).await;
        let q = near(&twin, *b, 1, 0.0, 10 + k as u64);
        jog(&d, &q[0]).await;
        resume(&d, id).await;
    }
    let r = finished(&d, id).await;
    eprintln!(
        "locate_balls: distances {}, fit residual {} mm (before {}), base {}",
        r["distances"], r["fit_residual_rms_mm"], r["previous_residual_rms_mm"], r["base"]
    );
    // The located balls against the ballbar (measured apart from the robot): within the
    // kinematic error of the lab file's nominal geometry, not yet calibrated.
    let pairs = r["distances"].as_array().expect("distances");
    assert_eq!(pairs.len(), 3, "{r}");
    for p in pairs {
        assert_eq!(p["ballbar_mm"], 200.0, "{p}");
        let diff = p["difference_mm"].as_f64().expect("difference");
        assert!(diff.abs() < 0.5, "{p}");
    }
    // The fitted base puts the balls on the plate far better than the lab file's base did.
    let fit = r["fit_residual_rms_mm"].as_f64().expect("fit");
    let before = r["previous_residual_rms_mm"].as_f64().expect("before");
    assert!(fit < 0.5 && fit < before / 5.0, "{r}");
}
