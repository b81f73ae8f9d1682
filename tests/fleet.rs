//! Three `calibd serve` processes on one throw-away PostgreSQL cluster (skipped, and saying
//! so, when PostgreSQL is not installed): 300 small numerical jobs submitted through
//! different daemons each finish exactly once (with the throughput of 1, 2 and 3 daemons);
//! an SSE client on daemon A sees jobs that the others run; a daemon killed with SIGKILL
//! mid-job loses its lease and its job finishes on another daemon.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use calibd::store::testpg::Cluster;
use futures_util::StreamExt;
use serde_json::Value;

const TOKEN: &str = "fleet-operator-secret";

struct Daemon {
    child: Child,
    url: String,
}

fn spawn(name: &str, store: &str, data: &std::path::Path) -> Daemon {
    let tokens = format!(
        "op:operator:{}",
        calibd::jobs::input::sha256_hex(TOKEN.as_bytes())
    );
    let mut child = Command::new(env!("CARGO_BIN_EXE_calibd"))
        .args(["serve", "--listen", "127.0.0.1:0", "--data"])
        .arg(data.join(name))
        .env("CALIBD_STORE", store)
        .env("CALIBD_NAME", name)
        .env("CALIBD_LAB", "none")
        .env("CALIBD_WORKERS", "2")
        .env("CALIBD_FLEET_LEASE_S", "3")
        .env("CALIBD_TOKENS", tokens)
        .env("CALIBD_ANONYMOUS_READ", "true")
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
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

async fn submit(http: &reqwest::Client, d: &Daemon, doc: &Value) -> i64 {
    let r = http
        .post(format!("{}/v1/jobs", d.url))
        .bearer_auth(TOKEN)
        .json(doc)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 201);
    let v: Value = r.json().await.unwrap();
    v["id"].as_i64().unwrap()
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
    let owner_sql = format!("SELECT owner FROM jobs WHERE id = {id}");
    let t0 = Instant::now();
    let owner = loop {
        let o: Option<String> =
            tokio::task::block_in_place(|| db(&store).query_one(&owner_sql, &[]).unwrap().get(0));
        if let Some(o) = o {
            break o;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "nobody claimed the slow job"
        );
        tokio::time::sleep(Duration::from_millis(10)).await;
    };
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
    let t0 = Instant::now();
    loop {
        let state: String = tokio::task::block_in_place(|| {
            db(&store)
                .query_one(&format!("SELECT state FROM jobs WHERE id = {id}"), &[])
                .unwrap()
                .get(0)
        });
        if state == "succeeded" {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "job {id} is {state}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let logs: Vec<String> = tokio::task::block_in_place(|| {
        db(&store)
            .query(
                &format!("SELECT message FROM logs WHERE job_id = {id} ORDER BY id"),
                &[],
            )
            .unwrap()
            .iter()
            .map(|r| r.get(0))
            .collect()
    });
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
