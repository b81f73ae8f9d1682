//! `calibd bench api`: the daemon under many concurrent HTTP clients, in one process on
//! loopback, without a lab. Phase 1 sends status reads (`GET /v1/jobs/{id}`) at a fixed
//! rate (open loop, the target: p99 under 2 ms at 1,000 requests per second), with
//! the server's CPU and context switches per read beside the process's at rest; phase 2
//! runs closed-loop clients that mix small job submissions (`serial.fk`, 1 configuration)
//! with status reads, for throughput. Clients and server share the machine's cores.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::{Value, json};
use tokio_util::sync::CancellationToken;

use super::Switches;
use crate::client::{Client, ClientError};
use crate::config::Config;

/// Benchmark settings.
#[derive(Debug, Clone)]
pub struct ApiBenchOptions {
    /// Status reads per second in phase 1.
    pub rate: u32,
    /// Duration of each phase.
    pub seconds: u64,
    /// Concurrent clients in phase 2.
    pub clients: usize,
    /// Fraction of phase-2 requests that are submissions.
    pub submit_fraction: f64,
}

impl Default for ApiBenchOptions {
    fn default() -> Self {
        Self {
            rate: 1000,
            seconds: 5,
            clients: 32,
            submit_fraction: 0.1,
        }
    }
}

/// Why the benchmark could not run.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ApiBenchError {
    /// The daemon did not start.
    #[error("bench api: {0}")]
    Serve(#[from] crate::server::ServeError),
    /// A request failed.
    #[error("bench api: {0}")]
    Client(#[from] ClientError),
    /// A status read through the service failed.
    #[error("bench api: status read: {0}")]
    Service(String),
    /// Socket setup.
    #[error("bench api: {0}")]
    Io(#[from] std::io::Error),
}

/// CPU time of the process since `start`, per operation, in microseconds.
fn cpu_per(start: Option<Duration>, ops: u64) -> String {
    match (start, super::cpu_time()) {
        (Some(a), Some(b)) if ops > 0 => {
            format!("{:.1} us", (b - a).as_secs_f64() * 1e6 / ops as f64)
        }
        _ => "n/a".into(),
    }
}

fn percentile(sorted: &[Duration], p: f64) -> Duration {
    if sorted.is_empty() {
        return Duration::ZERO;
    }
    let k = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[k]
}

fn line(name: &str, mut lat: Vec<Duration>, errors: usize, wall: Duration) -> String {
    lat.sort();
    format!(
        "{name:<44} {:>7} req {:>8.0} req/s   p50 {:>7.3} ms   p99 {:>7.3} ms   max {:>7.3} ms   errors {errors}",
        lat.len(),
        lat.len() as f64 / wall.as_secs_f64(),
        percentile(&lat, 0.5).as_secs_f64() * 1e3,
        percentile(&lat, 0.99).as_secs_f64() * 1e3,
        lat.last().copied().unwrap_or_default().as_secs_f64() * 1e3,
    )
}

/// A small FK job (one configuration of the IRB 120).
fn small_job() -> Value {
    let mut doc = crate::jobs::examples::twin_fk(1);
    doc["options"] = json!({});
    doc
}

/// What phase 1's client saw and spent.
struct Phase1 {
    /// Latencies of the successful reads.
    latencies: Vec<Duration>,
    /// Reads that failed.
    errors: usize,
    /// The client thread's CPU time.
    cpu: Option<Duration>,
    /// The client thread's context switches.
    switches: Option<Switches>,
}

/// The CPU time between two readings, when both were taken.
fn delta(a: Option<Duration>, b: Option<Duration>) -> Option<Duration> {
    Some(b?.saturating_sub(a?))
}

/// The context switches between two readings, when both were taken.
fn switched(a: Option<Switches>, b: Option<Switches>) -> Option<Switches> {
    Some(b?.since(a?))
}

/// Phase 1's client: `n` status reads of job `id` at `rate` per second (open loop), on a
/// single-threaded runtime owned by the calling thread.
fn open_loop_reads(
    base: &str,
    token: Option<String>,
    id: i64,
    rate: u32,
    n: u64,
) -> Result<Phase1, ApiBenchError> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let (cpu0, switches0) = (super::thread_cpu_time(), super::thread_context_switches());
    let client = Client::new(base, token);
    let (lat, errors) = rt.block_on(async move {
        let period = Duration::from_secs_f64(1.0 / rate.max(1) as f64);
        let lat = Arc::new(Mutex::new(Vec::with_capacity(n as usize)));
        let errors = Arc::new(Mutex::new(0usize));
        let mut tasks = Vec::new();
        let mut tick = tokio::time::interval(period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
        for _ in 0..n {
            tick.tick().await;
            let (c, lat, errors) = (client.clone(), lat.clone(), errors.clone());
            tasks.push(tokio::spawn(async move {
                let t = Instant::now();
                let ok = c.get(&format!("/v1/jobs/{id}")).await.is_ok();
                let d = t.elapsed();
                if ok {
                    lat.lock().map(|mut v| v.push(d)).ok();
                } else {
                    errors.lock().map(|mut e| *e += 1).ok();
                }
            }));
        }
        for t in tasks {
            let _ = t.await;
        }
        let l = lat.lock().map(|v| v.clone()).unwrap_or_default();
        let e = errors.lock().map(|e| *e).unwrap_or(0);
        (l, e)
    });
    Ok(Phase1 {
        latencies: lat,
        errors,
        cpu: delta(cpu0, super::thread_cpu_time()),
        switches: switched(switches0, super::thread_context_switches()),
    })
}

/// A phase of status reads at a fixed rate, as the whole process and its client saw it.
struct Measured {
    client: Phase1,
    wall: Duration,
    /// The process's CPU time and context switches over the phase.
    whole: Option<Duration>,
    whole_switches: Option<Switches>,
}

impl Measured {
    /// The server's CPU time: the process's less the client thread's.
    fn server_cpu(&self) -> Option<Duration> {
        Some(self.whole?.saturating_sub(self.client.cpu?))
    }

    /// The report lines: latencies, CPU and context switches per read.
    fn lines(&self, name: &str, n: u64) -> Vec<String> {
        let per = |d: Duration| format!("{:.1} us", d.as_secs_f64() * 1e6 / n.max(1) as f64);
        let per_read = |k: u64| k as f64 / n.max(1) as f64;
        let cpu = match (self.whole, self.client.cpu) {
            (Some(w), Some(c)) => format!(
                "  CPU per status read: server {} (the process less the client thread), client {}, both {}",
                per(w.saturating_sub(c)),
                per(c),
                per(w)
            ),
            (Some(w), None) => format!(
                "  CPU per status read (whole process: HTTP client and server): {}",
                per(w)
            ),
            _ => "  CPU per status read: n/a".into(),
        };
        let switches = match (self.whole_switches, self.client.switches) {
            (Some(w), Some(c)) => {
                let server = w.since(c);
                format!(
                    "  context switches per status read: server {:.2} waiting + {:.2} preempted, \
                     client {:.2} + {:.2}",
                    per_read(server.voluntary),
                    per_read(server.involuntary),
                    per_read(c.voluntary),
                    per_read(c.involuntary)
                )
            }
            _ => "  context switches per status read: n/a".into(),
        };
        vec![
            line(
                name,
                self.client.latencies.clone(),
                self.client.errors,
                self.wall,
            ),
            cpu,
            switches,
        ]
    }
}

/// `n` status reads of job `id` at `base`, `rate` per second, from a client thread of its
/// own; the process's CPU and context switches over the phase beside the client's.
async fn reads_at_rate(
    base: &str,
    token: Option<String>,
    id: i64,
    rate: u32,
    n: u64,
) -> Result<Measured, ApiBenchError> {
    let base = base.to_string();
    let (cpu0, switches0) = (super::cpu_time(), super::context_switches());
    let t0 = Instant::now();
    let client = tokio::task::spawn_blocking(move || open_loop_reads(&base, token, id, rate, n))
        .await
        .map_err(|e| ApiBenchError::Service(format!("the phase-1 client thread: {e}")))??;
    Ok(Measured {
        client,
        wall: t0.elapsed(),
        whole: delta(cpu0, super::cpu_time()),
        whole_switches: switched(switches0, super::context_switches()),
    })
}

/// The HTTP floor of a status read: a bare hyper server (HTTP/1, on this runtime, no
/// routing, checks, store or JSON) answering every request with the status, headers and
/// body the daemon at `base` answered a read of job `id` with (Date left to hyper, as for
/// the daemon). Returns its address and its accept loop, to abort.
async fn floor_server(
    base: &str,
    token: Option<&str>,
    id: i64,
) -> Result<(std::net::SocketAddr, tokio::task::JoinHandle<()>), ApiBenchError> {
    let mut req = reqwest::Client::new().get(format!("{base}/v1/jobs/{id}"));
    if let Some(t) = token {
        req = req.bearer_auth(t);
    }
    let res = req
        .send()
        .await
        .map_err(|e| ApiBenchError::Service(format!("the floor's template read: {e}")))?;
    let status = res.status();
    let mut headers = res.headers().clone();
    headers.remove(axum::http::header::DATE);
    let body = res
        .bytes()
        .await
        .map_err(|e| ApiBenchError::Service(format!("the floor's template body: {e}")))?;
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let addr = listener.local_addr()?;
    let answer = Arc::new((status, headers, body));
    let task = tokio::spawn(async move {
        while let Ok((stream, _)) = listener.accept().await {
            let _ = stream.set_nodelay(true);
            let answer = answer.clone();
            tokio::spawn(async move {
                let service = hyper::service::service_fn(move |_req| {
                    let (status, headers, body) = &*answer;
                    let mut r = axum::http::Response::new(axum::body::Body::from(body.clone()));
                    *r.status_mut() = *status;
                    *r.headers_mut() = headers.clone();
                    std::future::ready(Ok::<_, std::convert::Infallible>(r))
                });
                let io = hyper_util::rt::TokioIo::new(stream);
                let _ = hyper::server::conn::http1::Builder::new()
                    .serve_connection(io, service)
                    .await;
            });
        }
    });
    Ok((addr, task))
}

/// Run the benchmark against a fresh daemon in a temporary folder; returns the report.
pub async fn run(o: ApiBenchOptions) -> Result<String, ApiBenchError> {
    let dir = std::env::temp_dir().join(format!("calibd-bench-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    // No simulated lab: its device servers would run in this process, and their CPU
    // would be counted as the API's.
    let config = Config {
        data: dir.clone(),
        lab: "none".into(),
        ..Config::default()
    };
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let addr = listener.local_addr()?;
    let stop = CancellationToken::new();
    let (state, workers, _) =
        crate::server::start(&config, crate::schedule::Clock::system(), stop.clone()).await?;
    let service = state.service.clone();
    let t = stop.clone();
    let server = tokio::spawn(crate::api::run(listener, state, async move {
        t.cancelled().await
    }));
    let token = Client::find_token(None, &dir);
    let client = Client::new(&format!("http://{addr}"), token);
    let job = small_job();
    let first = client.submit(&job, 0).await?;
    let mut report = vec![format!(
        "calibd bench api: in-process daemon on {addr}, {} workers, {} cores shared by clients and server",
        config.worker_count(),
        std::thread::available_parallelism().map_or(0, |n| n.get())
    )];

    // Phase 0: the status read's service and store path alone (no HTTP), one at a time.
    let reads = 20_000u32;
    let (cpu0, t0) = (super::cpu_time(), Instant::now());
    for _ in 0..reads {
        service
            .job(first)
            .await
            .map_err(|e| ApiBenchError::Service(e.to_string()))?;
    }
    let wall = t0.elapsed();
    report.push(format!(
        "phase 0: {reads} status reads through the service (no HTTP): {:.1} us wall, {} CPU per read",
        wall.as_secs_f64() * 1e6 / f64::from(reads),
        cpu_per(cpu0, u64::from(reads)),
    ));

    // The daemon at rest: what the process spends with no request, to read beside phase 1.
    let quiet = Duration::from_millis(500);
    let (cpu0, switches0) = (super::cpu_time(), super::context_switches());
    tokio::time::sleep(quiet).await;
    report.push(format!(
        "at rest: {} CPU per second, {} context switches per second",
        delta(cpu0, super::cpu_time()).map_or("n/a".into(), |c| format!(
            "{:.0} us",
            c.as_secs_f64() * 1e6 / quiet.as_secs_f64()
        )),
        switched(switches0, super::context_switches()).map_or("n/a".into(), |n| format!(
            "{:.0}",
            (n.voluntary + n.involuntary) as f64 / quiet.as_secs_f64()
        )),
    ));

    // Phase 1: open loop, fixed rate of status reads, the client on a thread of its own so
    // that the server's CPU and context switches (the process's less the client thread's)
    // can be told apart.
    let n = o.rate as u64 * o.seconds;
    let base = format!("http://{addr}");
    let token = Client::find_token(None, &dir);
    let daemon = reads_at_rate(&base, token.clone(), first, o.rate, n).await?;
    report.extend(daemon.lines(
        &format!("phase 1: status reads at {} req/s (open loop)", o.rate),
        n,
    ));
    // The floor: the same reads from a bare hyper server that answers the daemon's bytes.
    let (floor_addr, floor) = floor_server(&base, token.as_deref(), first).await?;
    let bare = reads_at_rate(&format!("http://{floor_addr}"), None, first, o.rate, n).await;
    floor.abort();
    let bare = bare?;
    report.extend(bare.lines("phase 1, floor: the same reads, bare hyper server", n));
    if let (Some(d), Some(b)) = (daemon.server_cpu(), bare.server_cpu()) {
        report.push(format!(
            "  calibd's status read over the HTTP floor: {:.2} x ({:.1} us more server CPU per read)",
            d.as_secs_f64() / b.as_secs_f64().max(1e-12),
            (d.as_secs_f64() - b.as_secs_f64()) * 1e6 / n.max(1) as f64
        ));
    }

    // Phase 2: closed loop, mixed submissions and reads.
    let reads = Arc::new(Mutex::new(Vec::new()));
    let subs = Arc::new(Mutex::new(Vec::new()));
    let errs = Arc::new(Mutex::new(0usize));
    let deadline = Instant::now() + Duration::from_secs(o.seconds);
    let t0 = Instant::now();
    let mut tasks = Vec::new();
    for k in 0..o.clients {
        let (c, reads, subs, errs, job) = (
            client.clone(),
            reads.clone(),
            subs.clone(),
            errs.clone(),
            job.clone(),
        );
        let frac = o.submit_fraction;
        tasks.push(tokio::spawn(async move {
            let mut rng = crate::util::Rng::new(k as u64 + 1);
            let mut last = first;
            while Instant::now() < deadline {
                let t = Instant::now();
                if rng.uniform() < frac {
                    match c.submit(&job, 0).await {
                        Ok(id) => {
                            last = id;
                            subs.lock().map(|mut v| v.push(t.elapsed())).ok();
                        }
                        Err(_) => {
                            errs.lock().map(|mut e| *e += 1).ok();
                        }
                    }
                } else if c.get(&format!("/v1/jobs/{last}")).await.is_ok() {
                    reads.lock().map(|mut v| v.push(t.elapsed())).ok();
                } else {
                    errs.lock().map(|mut e| *e += 1).ok();
                }
            }
        }));
    }
    for t in tasks {
        let _ = t.await;
    }
    let wall = t0.elapsed();
    let r = reads.lock().map(|v| v.clone()).unwrap_or_default();
    let s = subs.lock().map(|v| v.clone()).unwrap_or_default();
    let e = errs.lock().map(|e| *e).unwrap_or(0);
    let total = r.len() + s.len();
    report.push(format!(
        "phase 2: {} closed-loop clients, {:.0} % submissions: {total} requests, {:.0} req/s",
        o.clients,
        100.0 * o.submit_fraction,
        total as f64 / wall.as_secs_f64()
    ));
    report.push(line("  status reads", r, e, wall));
    report.push(line(
        "  submissions (serial.fk, 1 configuration)",
        s,
        0,
        wall,
    ));
    let v = client.get("/v1/health").await?;
    report.push(format!(
        "queue after phase 2: {} waiting, {} running",
        v["queue_depth"], v["running"]
    ));
    stop.cancel();
    let _ = server.await;
    workers.join().await;
    let _ = std::fs::remove_dir_all(&dir);
    Ok(report.join("\n"))
}
