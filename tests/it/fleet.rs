//! Three `calibd serve` processes on one throw-away PostgreSQL cluster (skipped, and saying
//! so, when PostgreSQL is not installed): 300 small numerical jobs submitted through
//! different daemons each finish exactly once (with the throughput of 1, 2 and 3 daemons);
//! an SSE client on daemon A sees jobs that the others run; a daemon killed with SIGKILL
//! mid-job loses its lease and its job finishes on another daemon; a cancel sent to one
//! daemon stops the job another runs; a campaign whose cell's daemon was killed waits for
//! that daemon and resumes from its journal.

use std::process::Command;
use std::time::{Duration, Instant};

use calibd::store::testpg::Cluster;
use futures_util::StreamExt;
use serde_json::Value;

use crate::common::daemon;
use daemon::{Daemon, journal};

const TOKEN: &str = "fleet-operator-secret";

/// Daemon `name` of the fleet on `store`, with `lab` (`none`, or `sim` for the simulated
/// cells) and its data folder under `data`.
fn spawn_with(name: &str, store: &str, data: &std::path::Path, lab: &str) -> Daemon {
    let tokens = format!(
        "op:operator:{}",
        calibd::run::input::sha256_hex(TOKEN.as_bytes())
    );
    let env = [
        ("CALIBD_STORE", store),
        ("CALIBD_NAME", name),
        ("CALIBD_LAB", lab),
        ("CALIBD_WORKERS", "2"),
        ("CALIBD_FLEET_LEASE_S", "3"),
        ("CALIBD_TOKENS", &tokens),
        ("CALIBD_ANONYMOUS_READ", "true"),
    ];
    Daemon::start(&data.join(name), &env, false)
}

fn spawn(name: &str, store: &str, data: &std::path::Path) -> Daemon {
    spawn_with(name, store, data, "none")
}

async fn submit(http: &reqwest::Client, d: &Daemon, doc: &Value) -> i64 {
    daemon::submit(http, d, TOKEN, doc).await
}

fn db(url: &str) -> postgres::Client {
    postgres::Client::connect(url, postgres::NoTls).unwrap()
}

fn count(url: &str, sql: &str) -> i64 {
    tokio::task::block_in_place(|| db(url).query_one(sql, &[]).unwrap().get(0))
}

/// Submit `n` jobs round-robin through `ds` and wait until all succeeded; returns the time.
async fn batch(http: &reqwest::Client, ds: &[&Daemon], url: &str, n: usize) -> Duration {
    let before = count(url, "SELECT COUNT(*) FROM jobs WHERE state = 'succeeded'");
    let doc = calibd::jobs::examples::twin_fk(20);
    let t0 = Instant::now();
    for k in 0..n {
        submit(http, ds[k % ds.len()], &doc).await;
    }
    loop {
        let done = count(url, "SELECT COUNT(*) FROM jobs WHERE state = 'succeeded'");
        if done - before >= n as i64 {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(240),
            "{} of {n} done",
            done - before
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    t0.elapsed()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_daemons_share_one_queue() {
    let cluster = match tokio::task::block_in_place(Cluster::start) {
        Ok(Some(c)) => c,
        Ok(None) => {
            eprintln!("skipped: PostgreSQL not installed");
            return;
        }
        Err(e) => panic!("{e}"),
    };
    let store = tokio::task::block_in_place(|| cluster.fresh_db()).unwrap();
    let data = tempfile::tempdir().unwrap();
    let http = reqwest::Client::new();

    // Throughput of 1, 2 and 3 daemons on 300 small jobs each.
    let a = spawn("a", &store, data.path());
    let t1 = batch(&http, &[&a], &store, 300).await;
    let b = spawn("b", &store, data.path());
    let t2 = batch(&http, &[&a, &b], &store, 300).await;
    let c = spawn("c", &store, data.path());
    // An SSE client on A, for the jobs of the 3-daemon batch.
    let sse = http
        .get(format!("{}/v1/events", a.url))
        .send()
        .await
        .unwrap();
    let mut sse = sse.bytes_stream();
    let t3 = batch(&http, &[&a, &b, &c], &store, 300).await;
    for (n, t) in [(1, t1), (2, t2), (3, t3)] {
        eprintln!(
            "fleet throughput: {n} daemon(s) x 2 workers, 300 jobs in {:.2} s = {:.0} jobs/s",
            t.as_secs_f64(),
            300.0 / t.as_secs_f64()
        );
    }
    // Exactly once: 900 jobs, each started once, each with one result.
    assert_eq!(
        count(
            &store,
            "SELECT COUNT(*) FROM jobs WHERE state = 'succeeded'"
        ),
        900
    );
    assert_eq!(count(&store, "SELECT COUNT(*) FROM results"), 900);
    assert_eq!(
        count(
            &store,
            "SELECT COUNT(*) FROM logs WHERE message LIKE 'started on %'"
        ),
        900
    );
    let by_daemon = tokio::task::block_in_place(|| {
        db(&store)
            .query(
                "SELECT message, COUNT(*) FROM logs WHERE message LIKE 'started on %' GROUP BY message ORDER BY message",
                &[],
            )
            .unwrap()
            .iter()
            .map(|r| format!("{}: {}", r.get::<_, String>(0), r.get::<_, i64>(1)))
            .collect::<Vec<_>>()
    });
    eprintln!("jobs per daemon: {by_daemon:?}");
    // A saw the succeeded state of jobs that B and C ran.
    let ran_elsewhere: Vec<i64> = tokio::task::block_in_place(|| {
        db(&store)
            .query(
                "SELECT job_id FROM logs WHERE message IN ('started on b', 'started on c')",
                &[],
            )
            .unwrap()
            .iter()
            .map(|r| r.get::<_, Option<i64>>(0).unwrap())
            .collect()
    });
    let mut text = String::new();
    let mut seen_elsewhere = false;
    let t0 = Instant::now();
    while !seen_elsewhere && t0.elapsed() < Duration::from_secs(20) {
        let Ok(Some(Ok(chunk))) = tokio::time::timeout(Duration::from_secs(5), sse.next()).await
        else {
            break;
        };
        text.push_str(&String::from_utf8_lossy(&chunk));
        for line in text.lines().filter_map(|l| l.strip_prefix("data:")) {
            if let Ok(v) = serde_json::from_str::<Value>(line.trim())
                && v["state"] == "succeeded"
                && ran_elsewhere.contains(&v["id"].as_i64().unwrap_or(0))
            {
                seen_elsewhere = true;
            }
        }
    }
    assert!(
        seen_elsewhere,
        "the SSE client on A saw no job that B or C ran"
    );

    // SIGKILL mid-job: the job finishes on another daemon.
    let slow = calibd::jobs::examples::twin_dispersion(&[30, 60, 90], 300);
    let id = submit(&http, &c, &slow).await;
    let owner = until_owner(&store, id).await;
    let victim = match owner.as_str() {
        "a" => &a.child,
        "b" => &b.child,
        _ => &c.child,
    };
    let pid = victim.id();
    assert!(
        Command::new("kill")
            .args(["-9", &pid.to_string()])
            .status()
            .unwrap()
            .success()
    );
    eprintln!("killed daemon {owner} (pid {pid}) while it ran job {id}");
    until_state(&store, id, "succeeded", Duration::from_secs(120)).await;
    let logs = logs(&store, id);
    eprintln!("job {id}: {logs:?}");
    assert!(logs.contains(&"re-queued: its daemon's lease expired".to_string()));
    let starts: Vec<&String> = logs
        .iter()
        .filter(|m| m.starts_with("started on"))
        .collect();
    assert_eq!(starts.len(), 2, "{logs:?}");
    assert_ne!(starts[1], &format!("started on {owner}"));

    drop((a, b, c));
    tokio::task::block_in_place(|| drop(cluster));
}

/// A job's state, straight from the database.
fn state(url: &str, id: i64) -> String {
    tokio::task::block_in_place(|| {
        db(url)
            .query_one("SELECT state FROM jobs WHERE id = $1", &[&id])
            .unwrap()
            .get(0)
    })
}

/// A job's log messages, oldest first.
fn logs(url: &str, id: i64) -> Vec<String> {
    tokio::task::block_in_place(|| {
        db(url)
            .query(
                "SELECT message FROM logs WHERE job_id = $1 ORDER BY id",
                &[&id],
            )
            .unwrap()
            .iter()
            .map(|r| r.get(0))
            .collect()
    })
}

/// Wait until job `id` is in state `want` (within `limit`).
async fn until_state(url: &str, id: i64, want: &str, limit: Duration) {
    let t0 = Instant::now();
    loop {
        let s = state(url, id);
        if s == want {
            return;
        }
        assert!(
            t0.elapsed() < limit,
            "job {id} is {s}, not {want}: {:?}",
            logs(url, id)
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// Wait until a daemon holds job `id`; returns its name.
async fn until_owner(url: &str, id: i64) -> String {
    let t0 = Instant::now();
    loop {
        let o: Option<String> = tokio::task::block_in_place(|| {
            db(url)
                .query_one("SELECT owner FROM jobs WHERE id = $1", &[&id])
                .unwrap()
                .get(0)
        });
        if let Some(o) = o {
            return o;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "nobody claimed job {id}"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

/// A fresh database on the process's throw-away cluster (None, saying so, without
/// PostgreSQL).
fn fresh_store() -> Option<String> {
    let Some(cluster) = tokio::task::block_in_place(Cluster::shared) else {
        eprintln!("skipped: PostgreSQL not installed");
        return None;
    };
    Some(tokio::task::block_in_place(|| cluster.fresh_db()).unwrap())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cancel_on_one_daemon_stops_the_job_on_another() {
    let Some(store) = fresh_store() else { return };
    let data = tempfile::tempdir().unwrap();
    let http = reqwest::Client::new();
    let a = spawn("a", &store, data.path());
    let b = spawn("b", &store, data.path());
    // Minutes of work if nobody stops it; it polls for cancellation.
    let slow = calibd::jobs::examples::twin_dispersion(&[30, 60, 90], 3000);
    let id = submit(&http, &a, &slow).await;
    let owner = until_owner(&store, id).await;
    until_state(&store, id, "running", Duration::from_secs(10)).await;
    // Cancel through the daemon that does not run it.
    let other = if owner == "a" { &b } else { &a };
    let t0 = Instant::now();
    let r = http
        .post(format!("{}/v1/jobs/{id}/cancel", other.url))
        .bearer_auth(TOKEN)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 200);
    let v: Value = r.json().await.unwrap();
    assert_eq!(
        v["state"], "running",
        "the job winds down on its own daemon"
    );
    // Only the running daemon's worker writes `cancelled` (the request sets a flag).
    until_state(&store, id, "cancelled", Duration::from_secs(20)).await;
    eprintln!(
        "cancel on the other daemon: job {id} on {owner} stopped in {:.0} ms",
        t0.elapsed().as_secs_f64() * 1e3
    );
    let l = logs(&store, id);
    let asked = l.iter().position(|m| m == "cancel requested");
    let ended = l.iter().position(|m| m == "cancelled");
    assert!(
        matches!((asked, ended), (Some(x), Some(y)) if x < y),
        "{l:?}"
    );
    assert!(
        !l.iter().any(|m| m.starts_with("re-queued")),
        "the job stopped by its lease, not by the cancel: {l:?}"
    );
    assert_eq!(
        count(
            &store,
            &format!("SELECT COUNT(*) FROM results WHERE job_id = {id}")
        ),
        0
    );
    // The daemon that ran it is free again: it runs the next job.
    let fast = calibd::jobs::examples::twin_fk(20);
    let next = submit(&http, other, &fast).await;
    until_state(&store, next, "succeeded", Duration::from_secs(60)).await;
}

/// A campaign belongs to its cell's daemon: when that daemon is killed with SIGKILL, the
/// lease expires and the job goes back to the queue, but no other daemon runs it; when
/// the daemon comes back it claims it and resumes from its journal.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_campaign_waits_for_its_cells_daemon_and_resumes_from_its_journal() {
    let Some(store) = fresh_store() else { return };
    let data = tempfile::tempdir().unwrap();
    let http = reqwest::Client::new();
    let mut cell = spawn_with("cell", &store, data.path(), "sim");
    let other = spawn("other", &store, data.path());
    let doc = serde_json::json!({
        "kind": "cell.trical_campaign",
        "design": {"pool_per_ball": 16, "per_ball": 6, "seed": 5},
        "validation": {"per_ball": 2, "seed": 6},
        "options": {"centring": {"settle_ms": 40}}
    });
    let id = submit(&http, &cell, &doc).await;
    let t0 = Instant::now();
    while journal(&http, &cell, id).await.len() < 6 {
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "the campaign did not start"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    cell.kill9();
    let held = journal(&http, &other, id).await;
    assert!(held.len() >= 6 && held.len() < 24, "{}", held.len());
    // The other daemon's heartbeat re-queues it when the lease (3 s) expires...
    until_state(&store, id, "queued", Duration::from_secs(30)).await;
    assert!(logs(&store, id).contains(&"re-queued: its daemon's lease expired".to_string()));
    // ... but does not run it: a numerical job submitted after it (same priority, so the
    // campaign comes first in the queue) runs on the other daemon while the campaign waits.
    let fk = submit(&http, &other, &calibd::jobs::examples::twin_fk(20)).await;
    until_state(&store, fk, "succeeded", Duration::from_secs(60)).await;
    assert_eq!(state(&store, id), "queued");
    assert_eq!(journal(&http, &other, id).await, held);
    // The cell's daemon comes back under its name: it claims the campaign and resumes.
    let cell = spawn_with("cell", &store, data.path(), "sim");
    let t0 = Instant::now();
    until_state(&store, id, "succeeded", Duration::from_secs(240)).await;
    eprintln!(
        "campaign {id}: its daemon killed after {} of 24 measurements; it waited queued \
         while another daemon ran job {fk}; resumed and finished {:.1} s after the restart",
        held.len(),
        t0.elapsed().as_secs_f64()
    );
    let got = journal(&http, &cell, id).await;
    assert_eq!(got.len(), 24, "every configuration measured once");
    assert_eq!(
        &got[..held.len()],
        &held[..],
        "the journal kept what was measured"
    );
    let indices: std::collections::BTreeSet<i64> =
        got.iter().map(|e| e["index"].as_i64().unwrap()).collect();
    assert_eq!(indices.len(), 24, "no configuration measured twice");
    let l = logs(&store, id);
    let starts: Vec<&String> = l.iter().filter(|m| m.starts_with("started on")).collect();
    assert_eq!(starts, ["started on cell", "started on cell"], "{l:?}");
    drop((cell, other));
}
