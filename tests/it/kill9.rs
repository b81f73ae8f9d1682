//! A result is never lost: the real `calibd serve` binary is killed with SIGKILL at seeded
//! random moments while jobs run, and restarted on the same data folder. Every result
//! that existed before the kill is intact, every job that was running is `interrupted`,
//! and no job is `succeeded` without its result.

use std::time::Duration;

use calibd::util::Rng;
use serde_json::Value;

use crate::common::daemon;
use daemon::{Daemon, get, journal};

fn spawn(data: &std::path::Path) -> Daemon {
    // The test reads jobs and results without a token; writes use the operator token.
    let env = [("CALIBD_WORKERS", "2"), ("CALIBD_ANONYMOUS_READ", "true")];
    Daemon::start(data, &env, true)
}

async fn all_jobs(c: &reqwest::Client, d: &Daemon) -> Vec<Value> {
    get(c, &format!("{}/v1/jobs?limit=500", d.url)).await["jobs"]
        .as_array()
        .unwrap()
        .clone()
}

async fn result(c: &reqwest::Client, d: &Daemon, id: i64) -> (u16, Value) {
    let r = c
        .get(format!("{}/v1/jobs/{id}/result", d.url))
        .send()
        .await
        .unwrap();
    let s = r.status().as_u16();
    (s, r.json().await.unwrap_or(Value::Null))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigkill_at_random_moments_loses_no_result() {
    let data = tempfile::tempdir().unwrap();
    let http = reqwest::Client::new();
    let mut rng = Rng::new(20261122);
    let fast = calibd::jobs::examples::twin_fk(50);
    // Seconds of work that polls for cancellation: it is running when the kill comes.
    let slow = calibd::jobs::examples::twin_dispersion(&[30, 60, 90], 300);
    let mut kept: Vec<(i64, Value)> = Vec::new();
    let mut d = spawn(data.path());
    for round in 0..3 {
        let token = std::fs::read_to_string(data.path().join("operator.token")).unwrap();
        let token = token.trim().to_string();
        for k in 0..6 {
            let doc = if k % 3 == 0 { &slow } else { &fast };
            let r = http
                .post(format!("{}/v1/jobs", d.url))
                .bearer_auth(&token)
                .json(doc)
                .send()
                .await
                .unwrap();
            assert_eq!(r.status().as_u16(), 201);
        }
        for _ in 0..500 {
            if all_jobs(&http, &d)
                .await
                .iter()
                .any(|j| j["state"] == "running")
            {
                break;
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        tokio::time::sleep(Duration::from_millis(rng.range(0.0, 400.0) as u64)).await;
        // What the daemon says just before the kill.
        let before = all_jobs(&http, &d).await;
        for j in &before {
            let id = j["id"].as_i64().unwrap();
            if j["state"] == "succeeded" && !kept.iter().any(|(k, _)| *k == id) {
                let (s, r) = result(&http, &d, id).await;
                assert_eq!(s, 200);
                kept.push((id, r));
            }
        }
        d.kill9();
        drop(d);
        d = spawn(data.path());
        // Every result seen before any kill is intact, byte for byte.
        for (id, r) in &kept {
            let j = get(&http, &format!("{}/v1/jobs/{id}", d.url)).await;
            assert_eq!(j["state"], "succeeded", "round {round}: job {id}");
            assert_eq!(
                &result(&http, &d, *id).await.1,
                r,
                "round {round}: result of job {id} changed"
            );
        }
        let after = all_jobs(&http, &d).await;
        let mut interrupted = 0;
        for j in &after {
            let id = j["id"].as_i64().unwrap();
            let state = j["state"].as_str().unwrap();
            let was = before
                .iter()
                .find(|b| b["id"] == j["id"])
                .map(|b| b["state"].clone());
            if was == Some(Value::from("running")) {
                // It either finished in the instant before the kill or is interrupted.
                assert!(
                    state == "interrupted" || state == "succeeded",
                    "job {id} was running, now {state}"
                );
            }
            if state == "interrupted" {
                interrupted += 1;
                assert!(j["error"].as_str().unwrap().contains("daemon stopped"));
                assert!(j["finished_at"].is_string());
            }
            // The restarted daemon keeps working: a job listed as queued may have a
            // result by now, but then it must be succeeded.
            let (status, r) = result(&http, &d, id).await;
            if status == 200 {
                assert_eq!(r["kind"], j["kind"]);
                let now = get(&http, &format!("{}/v1/jobs/{id}", d.url)).await;
                assert_eq!(
                    now["state"], "succeeded",
                    "job {id} has a result but is {}",
                    now["state"]
                );
            } else {
                assert_eq!(status, 409);
                assert_ne!(state, "succeeded", "job {id} succeeded without a result");
            }
        }
        assert!(
            interrupted >= 1,
            "round {round}: the kill interrupted no job: {after:?}"
        );
        // Cancel what the restarted daemon picked up, before the next round.
        for j in &after {
            if j["state"] == "queued" || j["state"] == "running" {
                http.post(format!("{}/v1/jobs/{}/cancel", d.url, j["id"]))
                    .bearer_auth(&token)
                    .send()
                    .await
                    .unwrap();
            }
        }
        for _ in 0..3000 {
            let js = all_jobs(&http, &d).await;
            if js
                .iter()
                .all(|j| j["state"] != "queued" && j["state"] != "running")
            {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }
    assert!(
        kept.len() >= 3,
        "only {} results were seen before the kills",
        kept.len()
    );
}

/// Submit a document with the data folder's operator token; returns the job id.
async fn submit(c: &reqwest::Client, d: &Daemon, data: &std::path::Path, doc: &Value) -> i64 {
    let token = std::fs::read_to_string(data.join("operator.token")).unwrap();
    daemon::submit(c, d, token.trim(), doc).await
}

async fn until_done(c: &reqwest::Client, d: &Daemon, id: i64) -> Value {
    for _ in 0..1200 {
        let j = get(c, &format!("{}/v1/jobs/{id}", d.url)).await;
        if j["state"] == "succeeded" {
            return j;
        }
        assert!(
            j["state"] == "queued" || j["state"] == "running",
            "campaign {id} is {}: {}",
            j["state"],
            j["error"]
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("campaign {id} did not finish");
}

/// A TriCal campaign on the simulated lab (over RWS and U-WAVE), killed with SIGKILL after
/// a seeded number of measurements: the restarted daemon resumes it from its journal and
/// ends with exactly the measurement set of an uninterrupted run of the same seed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_campaign_killed_mid_way_resumes_and_measures_what_an_uninterrupted_one_does() {
    let http = reqwest::Client::new();
    let doc = serde_json::json!({
        "kind": "cell.trical_campaign",
        "design": {"pool_per_ball": 16, "per_ball": 6, "seed": 5},
        "validation": {"per_ball": 2, "seed": 6},
        "options": {"centring": {"settle_ms": 40}}
    });
    // Uninterrupted reference.
    let ref_dir = tempfile::tempdir().unwrap();
    let r = spawn(ref_dir.path());
    let id = submit(&http, &r, ref_dir.path(), &doc).await;
    until_done(&http, &r, id).await;
    let reference = journal(&http, &r, id).await;
    let ref_result = get(&http, &format!("{}/v1/jobs/{id}/result", r.url)).await;
    drop(r);
    assert_eq!(reference.len(), 24);

    let data = tempfile::tempdir().unwrap();
    let mut d = spawn(data.path());
    let id = submit(&http, &d, data.path(), &doc).await;
    let mut rng = Rng::new(7);
    for kill in 0..2 {
        let at = 4 + 8 * kill + rng.range(0.0, 5.0) as usize;
        for _ in 0..1200 {
            if journal(&http, &d, id).await.len() >= at {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        let held = journal(&http, &d, id).await;
        d.kill9(); // mid-campaign
        drop(d);
        d = spawn(data.path());
        // What was committed before the kill is all there.
        let now = journal(&http, &d, id).await;
        assert!(
            now.len() >= held.len() && now[..held.len()] == held[..],
            "kill {kill}"
        );
        assert!(
            now.len() < 24,
            "kill {kill} came after the campaign finished"
        );
    }
    until_done(&http, &d, id).await;
    let got = journal(&http, &d, id).await;
    assert_eq!(got, reference, "no configuration measured twice or lost");
    let logs = get(&http, &format!("{}/v1/jobs/{id}/logs", d.url)).await;
    assert!(logs.to_string().contains("resumed"), "{logs}");
    let result = get(&http, &format!("{}/v1/jobs/{id}/result", d.url)).await;
    assert_eq!(result["calibrated_model"], ref_result["calibrated_model"]);
    assert!(result["validation"]["after"]["mean"].as_f64().unwrap() < 0.010);
}
