//! A result is never lost: the real `calibd serve` binary is killed with SIGKILL at seeded
//! random moments while jobs run, and restarted on the same data folder. Every result
//! that existed before the kill is intact, every job that was running is `interrupted`,
//! and no job is `succeeded` without its result.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use calibd::util::Rng;
use serde_json::Value;

struct Daemon {
    child: Child,
    url: String,
}

fn spawn(data: &std::path::Path) -> Daemon {
    let mut child = Command::new(env!("CARGO_BIN_EXE_calibd"))
        .args(["serve", "--listen", "127.0.0.1:0", "--data"])
        .arg(data)
        .env("CALIBD_WORKERS", "2")
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("calibd starts");
    let out = child.stdout.take().unwrap();
    let mut line = String::new();
    BufReader::new(out).read_line(&mut line).unwrap();
    let url = line
        .trim()
        .strip_prefix("calibd listening on ")
        .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
        .to_string();
    Daemon { child, url }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

async fn get(c: &reqwest::Client, url: &str) -> Value {
    c.get(url).send().await.unwrap().json().await.unwrap()
}

async fn all_jobs(c: &reqwest::Client, d: &Daemon) -> Vec<Value> {
    get(c, &format!("{}/v1/jobs?limit=500", d.url)).await["jobs"]
        .as_array()
        .unwrap()
        .clone()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigkill_at_random_moments_loses_no_result() {
    let data = tempfile::tempdir().unwrap();
    let http = reqwest::Client::new();
    let mut rng = Rng::new(20261122);
    let fast = calibd::jobs::examples::twin_fk(50);
    let slow = calibd::jobs::examples::twin_dispersion(&[30, 60], 60);
    let mut kept: Vec<(i64, Value)> = Vec::new();
    let mut interrupted_seen = 0;
    for round in 0..3 {
        let d = spawn(data.path());
        let token = std::fs::read_to_string(data.path().join("operator.token")).unwrap();
        let token = token.trim().to_string();
        // Everything kept so far is still there, byte for byte.
        for (id, result) in &kept {
            let j = get(&http, &format!("{}/v1/jobs/{id}", d.url)).await;
            assert_eq!(j["state"], "succeeded", "round {round}: job {id}");
            let r = get(&http, &format!("{}/v1/jobs/{id}/result", d.url)).await;
            assert_eq!(&r, result, "round {round}: result of job {id} changed");
        }
        // Nothing is running right after a start except what the restarted queue took.
        for j in all_jobs(&http, &d).await {
            if j["state"] == "interrupted" {
                interrupted_seen += 1;
            }
        }
        // Submit a mix, then kill at a random moment while work is under way.
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
        // Wait until a job is running, then a random extra delay.
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
        let mut d = d;
        d.child.kill().unwrap(); // SIGKILL
        d.child.wait().unwrap();
        // What the daemon had said before dying cannot be asked now; read it after restart.
        let d2 = spawn(data.path());
        let jobs = all_jobs(&http, &d2).await;
        for j in &jobs {
            let id = j["id"].as_i64().unwrap();
            let state = j["state"].as_str().unwrap();
            let res = http
                .get(format!("{}/v1/jobs/{id}/result", d2.url))
                .send()
                .await
                .unwrap();
            if state == "succeeded" {
                assert_eq!(
                    res.status().as_u16(),
                    200,
                    "job {id} succeeded without a result"
                );
                let r: Value = res.json().await.unwrap();
                assert_eq!(r["kind"], j["kind"]);
                if !kept.iter().any(|(k, _)| *k == id) {
                    kept.push((id, r));
                }
            } else {
                assert_eq!(
                    res.status().as_u16(),
                    409,
                    "job {id} ({state}) has a result"
                );
            }
            if state == "interrupted" {
                assert!(j["error"].as_str().unwrap().contains("daemon stopped"));
                assert!(j["finished_at"].is_string());
            }
        }
        assert!(
            jobs.iter().any(|j| j["state"] == "interrupted"),
            "round {round}: the kill interrupted no job: {jobs:?}"
        );
        // Let the restarted daemon finish the queue before the next round.
        for _ in 0..3000 {
            let js = all_jobs(&http, &d2).await;
            if js
                .iter()
                .all(|j| j["state"] != "queued" && j["state"] != "running")
            {
                break;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        drop(d2);
    }
    assert!(kept.len() >= 6, "only {} results survived", kept.len());
    assert!(interrupted_seen >= 1);
}
