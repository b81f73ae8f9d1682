//! `calibd bench fleet`: 1, 2 and 4 `calibd serve` processes on one PostgreSQL store.
//! For each fleet size: the throughput of a batch of small jobs (bound by the claim and
//! the store), of a batch of compute jobs (bound by the cores), and the claim latency of
//! an idle fleet (one job at a time: `started_at - submitted_at`). Each daemon runs a fixed
//! number of workers, so on a machine with more cores the compute batch scales with the
//! fleet; on 2 cores it cannot.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

use crate::client::{Client, ClientError};
use crate::store::testpg::Cluster;

/// Benchmark settings.
#[derive(Debug, Clone)]
pub struct FleetBenchOptions {
    /// The `calibd` executable the daemons run.
    pub exe: PathBuf,
    /// A PostgreSQL URL; none: a throw-away cluster (PostgreSQL's binaries must be installed).
    pub store: Option<String>,
    /// Fleet sizes.
    pub daemons: Vec<usize>,
    /// Workers per daemon.
    pub workers: usize,
    /// Jobs in the small batch.
    pub small_jobs: usize,
    /// Jobs in the compute batch.
    pub compute_jobs: usize,
    /// Jobs submitted one at a time for the claim latency.
    pub probes: usize,
}

impl FleetBenchOptions {
    /// The defaults for `exe`: 1, 2, 4 daemons of 2 workers; 300 small, 40 compute jobs.
    pub fn new(exe: PathBuf) -> Self {
        Self {
            exe,
            store: None,
            daemons: vec![1, 2, 4],
            workers: 2,
            small_jobs: 300,
            compute_jobs: 40,
            probes: 20,
        }
    }
}

/// Why the benchmark could not run.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FleetBenchError {
    /// No store given and no PostgreSQL to start one.
    #[error(
        "bench fleet: no --store given and PostgreSQL is not installed (set CALIBD_PG_BIN to its bin folder, or pass --store postgres://...)"
    )]
    NoPostgres,
    /// The throw-away cluster did not start.
    #[error("bench fleet: PostgreSQL: {0}")]
    Cluster(String),
    /// A daemon did not start or said something unexpected.
    #[error("bench fleet: daemon {name}: {what}")]
    Daemon {
        /// The daemon's name.
        name: String,
        /// What went wrong.
        what: String,
    },
    /// A request failed.
    #[error("bench fleet: {0}")]
    Client(#[from] ClientError),
    /// A job did not succeed or the batch took too long.
    #[error("bench fleet: {0}")]
    Job(String),
    /// Runtime or folders.
    #[error("bench fleet: {0}")]
    Io(#[from] std::io::Error),
}

/// One daemon process, killed when dropped.
struct Daemon {
    child: Child,
    client: Client,
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Start daemon `name` on `store` with `workers` and the bench's token; wait for its address.
fn spawn(
    o: &FleetBenchOptions,
    store: &str,
    name: &str,
    data: &std::path::Path,
    token: &str,
) -> Result<Daemon, FleetBenchError> {
    let tokens = format!(
        "bench:operator:{}",
        crate::run::input::sha256_hex(token.as_bytes())
    );
    let fail = |what: String| FleetBenchError::Daemon {
        name: name.into(),
        what,
    };
    let mut child = Command::new(&o.exe)
        .args(["serve", "--listen", "127.0.0.1:0", "--data"])
        .arg(data.join(name))
        .env("CALIBD_STORE", store)
        .env("CALIBD_NAME", name)
        .env("CALIBD_LAB", "none")
        .env("CALIBD_WORKERS", o.workers.to_string())
        .env("CALIBD_TOKENS", tokens)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| fail(format!("cannot start {}: {e}", o.exe.display())))?;
    let mut line = String::new();
    if let Some(out) = child.stdout.take() {
        BufReader::new(out).read_line(&mut line)?;
    }
    let url = match line.trim().strip_prefix("calibd listening on ") {
        Some(u) => u.to_string(),
        None => {
            let _ = child.kill();
            let _ = child.wait();
            return Err(fail(format!("printed {line:?} instead of its address")));
        }
    };
    Ok(Daemon {
        child,
        client: Client::new(&url, Some(token.to_string())),
    })
}

/// The daemons' data folders, removed when dropped.
struct Scratch(PathBuf);

impl Scratch {
    fn new() -> std::io::Result<Self> {
        let dir = std::env::temp_dir().join(format!("calibd-bench-fleet-{}", std::process::id()));
        std::fs::create_dir_all(&dir)?;
        Ok(Self(dir))
    }

    fn path(&self) -> &std::path::Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Milliseconds between two store timestamps (RFC 3339, ms).
fn ms_between(a: &str, b: &str) -> Option<f64> {
    let a = chrono::DateTime::parse_from_rfc3339(a).ok()?;
    let b = chrono::DateTime::parse_from_rfc3339(b).ok()?;
    Some((b - a).num_microseconds()? as f64 / 1000.0)
}

/// Wait until every job of `ids` succeeded (any other final state is an error).
async fn wait_all(c: &Client, ids: &[i64], deadline: Duration) -> Result<(), FleetBenchError> {
    let t0 = Instant::now();
    for &id in ids {
        loop {
            let j = c.get(&format!("/v1/jobs/{id}")).await?;
            match j.get("state").and_then(Value::as_str) {
                Some("succeeded") => break,
                Some("queued" | "running") => {}
                other => {
                    return Err(FleetBenchError::Job(format!(
                        "job {id} ended {other:?}: {}",
                        j.get("error").and_then(Value::as_str).unwrap_or("")
                    )));
                }
            }
            if t0.elapsed() > deadline {
                return Err(FleetBenchError::Job(format!(
                    "job {id} not done after {deadline:?}"
                )));
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    }
    Ok(())
}

/// Submit `n` copies of `doc` round-robin through `fleet`, wait for all; jobs per second.
async fn batch(fleet: &[Daemon], doc: &Value, n: usize) -> Result<f64, FleetBenchError> {
    let t0 = Instant::now();
    let mut ids = Vec::with_capacity(n);
    for k in 0..n {
        ids.push(fleet[k % fleet.len()].client.submit(doc, 0).await?);
    }
    wait_all(&fleet[0].client, &ids, Duration::from_secs(600)).await?;
    Ok(n as f64 / t0.elapsed().as_secs_f64())
}

/// Claim latencies (ms) of `n` jobs submitted one at a time to an idle fleet, sorted.
async fn probes(fleet: &[Daemon], doc: &Value, n: usize) -> Result<Vec<f64>, FleetBenchError> {
    let mut lat = Vec::with_capacity(n);
    for k in 0..n {
        let c = &fleet[k % fleet.len()].client;
        let id = c.submit(doc, 0).await?;
        wait_all(c, &[id], Duration::from_secs(60)).await?;
        let j = c.get(&format!("/v1/jobs/{id}")).await?;
        let t = |f: &str| j.get(f).and_then(Value::as_str).unwrap_or("").to_string();
        if let Some(ms) = ms_between(&t("submitted_at"), &t("started_at")) {
            lat.push(ms);
        }
    }
    lat.sort_by(f64::total_cmp);
    Ok(lat)
}

/// The figures of one fleet size.
#[derive(Debug, Clone)]
pub struct FleetFigures {
    /// Daemons.
    pub daemons: usize,
    /// Small jobs per second.
    pub small_jobs_per_s: f64,
    /// Compute jobs per second.
    pub compute_jobs_per_s: f64,
    /// Idle claim latency, median (ms).
    pub claim_median_ms: f64,
    /// Idle claim latency, largest (ms).
    pub claim_max_ms: f64,
}

/// Run the benchmark; the figures per fleet size.
pub fn run(o: &FleetBenchOptions) -> Result<Vec<FleetFigures>, FleetBenchError> {
    let cluster = match &o.store {
        Some(_) => None,
        None => Some(
            Cluster::start()
                .map_err(FleetBenchError::Cluster)?
                .ok_or(FleetBenchError::NoPostgres)?,
        ),
    };
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let data = Scratch::new()?;
    let token = format!("bench-{}", std::process::id());
    let small = crate::jobs::examples::twin_fk(20);
    let compute = crate::jobs::examples::twin_fk(20_000);
    let mut out = Vec::new();
    for &n in &o.daemons {
        // A fresh database per fleet size when the cluster is ours.
        let store = match (&cluster, &o.store) {
            (Some(c), _) => c.fresh_db().map_err(FleetBenchError::Cluster)?,
            (None, Some(url)) => url.clone(),
            (None, None) => return Err(FleetBenchError::NoPostgres),
        };
        let fleet = (0..n)
            .map(|k| spawn(o, &store, &format!("bench-{n}-{k}"), data.path(), &token))
            .collect::<Result<Vec<_>, _>>()?;
        let fig = rt.block_on(async {
            // Warm up every daemon (connections, statement caches).
            batch(&fleet, &small, 2 * n).await?;
            let claims = probes(&fleet, &small, o.probes).await?;
            Ok::<_, FleetBenchError>(FleetFigures {
                daemons: n,
                small_jobs_per_s: batch(&fleet, &small, o.small_jobs).await?,
                compute_jobs_per_s: batch(&fleet, &compute, o.compute_jobs).await?,
                claim_median_ms: claims.get(claims.len() / 2).copied().unwrap_or(f64::NAN),
                claim_max_ms: claims.last().copied().unwrap_or(f64::NAN),
            })
        })?;
        out.push(fig);
    }
    Ok(out)
}

/// The figures as a table, with each size's throughput against the first size's times the
/// fleet's growth (1.00 = perfect scaling).
pub fn render(o: &FleetBenchOptions, figs: &[FleetFigures]) -> String {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut s = format!(
        "fleet on one PostgreSQL: {} worker(s) per daemon, {cores} core(s) on this machine; small = serial.fk of 20 rows x {}, compute = serial.fk of 20,000 rows x {}\n",
        o.workers, o.small_jobs, o.compute_jobs
    );
    s.push_str(
        "daemons  small jobs/s  compute jobs/s  compute scaling  idle claim median / max (ms)\n",
    );
    let base = figs.first();
    for f in figs {
        let scaling = base.map_or(f64::NAN, |b| {
            f.compute_jobs_per_s / (b.compute_jobs_per_s * f.daemons as f64 / b.daemons as f64)
        });
        s.push_str(&format!(
            "{:>7}  {:>12.0}  {:>14.1}  {:>15.2}  {:>8.1} / {:.1}\n",
            f.daemons,
            f.small_jobs_per_s,
            f.compute_jobs_per_s,
            scaling,
            f.claim_median_ms,
            f.claim_max_ms
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn timestamps_of_the_store_give_milliseconds() {
        let ms = ms_between("2026-11-28T12:00:00.125Z", "2026-11-28T12:00:01.250Z");
        assert_eq!(ms, Some(1125.0));
        assert_eq!(ms_between("yesterday", "2026-11-28T12:00:01.250Z"), None);
    }

    #[test]
    fn scaling_is_throughput_against_the_first_size_times_the_growth() {
        let f = |daemons, compute| FleetFigures {
            daemons,
            small_jobs_per_s: 100.0,
            compute_jobs_per_s: compute,
            claim_median_ms: 3.0,
            claim_max_ms: 9.0,
        };
        let o = FleetBenchOptions::new("calibd".into());
        let text = render(&o, &[f(1, 10.0), f(2, 20.0), f(4, 20.0)]);
        let lines: Vec<&str> = text.lines().collect();
        assert!(lines[2].contains("1.00"), "{text}");
        assert!(lines[3].contains("1.00"), "{text}");
        assert!(lines[4].contains("0.50"), "{text}");
    }
}
