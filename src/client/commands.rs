//! The CLI client commands (`calibd submit`, `watch`, `jobs`, `cancel`, `result`,
//! `health`): each prints what a person wants to see and returns an error for the binary to
//! report.

use std::io::Write;
use std::path::Path;

use serde_json::Value;

pub use super::summary::{print_summary, summary_lines};
use super::{Client, ClientError, progress_line};

/// Submit a job file; with `watch`, follow it and print the result summary.
pub async fn submit(
    c: &Client,
    job: &Path,
    priority: i64,
    watch: bool,
) -> Result<i64, ClientError> {
    let doc = c.load_job_file(job).await?;
    let id = c.submit(&doc, priority).await?;
    println!("job {id} submitted");
    if watch {
        self::watch(c, id).await?;
    }
    Ok(id)
}

/// A dry run of a job file: print the plan's size, its envelope check (each offending
/// configuration) and the estimated duration; an error if the plan leaves the envelope.
pub async fn dry_run(c: &Client, job: &Path) -> Result<Value, ClientError> {
    let doc = c.load_job_file(job).await?;
    let v = c.dry_run(&doc).await?;
    println!("{}", dry_run_summary(&v));
    if v["envelope"]["ok"] == false {
        return Err(ClientError::Protocol(
            "the plan leaves the cell's envelope: the daemon would refuse this job".into(),
        ));
    }
    Ok(v)
}

/// The lines `calibd submit --dry-run` prints for a dry-run answer.
pub fn dry_run_summary(v: &Value) -> String {
    let mut out = format!(
        "dry run of {} (nothing submitted)",
        v["kind"].as_str().unwrap_or("?")
    );
    if let Some(why) = v["unavailable"].as_str() {
        out.push_str(&format!("\nnow: {why}"));
    }
    let Some(plan) = v["plan"].as_array() else {
        out.push_str("\nno plan: this kind moves nothing");
        return out;
    };
    let moves: u64 = plan.iter().filter_map(|t| t["moves"].as_u64()).sum();
    out.push_str(&format!(
        "\ncell {}: {} configurations, {moves} joint moves, estimated duration {:.1} s",
        v["cell"].as_str().unwrap_or("?"),
        plan.len(),
        v["estimated_duration_s"].as_f64().unwrap_or(f64::NAN)
    ));
    let off = v["envelope"]["offending"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    if off.is_empty() {
        out.push_str("\nenvelope: every configuration and path inside");
    }
    for o in &off {
        out.push_str(&format!(
            "\noutside the envelope: {} {} ({}): {}",
            o["stage"].as_str().unwrap_or("?"),
            o["index"].as_u64().map_or(0, |i| i + 1),
            o["at"].as_str().unwrap_or("?"),
            o["reason"].as_str().unwrap_or("?")
        ));
    }
    out
}

/// Follow a job with a progress bar on stderr until it ends; print its summary, the
/// verdict and, for a campaign, what its cell decided about the model.
pub async fn watch(c: &Client, id: i64) -> Result<Value, ClientError> {
    let mut err = std::io::stderr();
    // On a terminal: one bar redrawn in place, the message cut to the terminal's width
    // (the ETA first, so it is never what is cut); otherwise a line per stage or message.
    let bar = std::io::IsTerminal::is_terminal(&err).then(progress_bar);
    let mut last_stage = String::new();
    let job = c
        .watch(id, |m| {
            let Ok(v) = serde_json::from_str::<Value>(&m.data) else {
                return;
            };
            match m.event.as_str() {
                "progress" => {
                    let f = v["fraction"].as_f64().unwrap_or(0.0);
                    let stage = v["stage"].as_str().unwrap_or("");
                    match &bar {
                        Some(b) => {
                            b.set_position(bar_position(f));
                            b.set_message(bar_message(stage, v["message"].as_str()));
                        }
                        None if stage != last_stage || v["message"].is_string() => {
                            let line = match v["message"].as_str() {
                                Some(m) => format!("{}: {m}", progress_line(f, stage)),
                                None => progress_line(f, stage),
                            };
                            let _ = writeln!(err, "{line}");
                        }
                        None => {}
                    }
                    last_stage = stage.to_string();
                }
                "state" => {
                    let line = format!("job {id}: {}", v["state"].as_str().unwrap_or("?"));
                    match &bar {
                        Some(b) => b.println(line),
                        None => {
                            let _ = writeln!(err, "{line}");
                        }
                    }
                }
                _ => {}
            }
        })
        .await;
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    let job = job?;
    let state = job["state"].as_str().unwrap_or("?");
    if state == "succeeded" {
        let r = c.get(&format!("/v1/jobs/{id}/result")).await?;
        print_summary(&r);
        match cell_decision(c, id).await? {
            Some(line) => println!("{line}"),
            None if r["cell"].is_string() => println!(
                "decision: none recorded for cell {}",
                r["cell"].as_str().unwrap_or("?")
            ),
            None => {}
        }
    } else if let Some(e) = job["error"].as_str() {
        println!("job {id} {state}: {e}");
    }
    Ok(job)
}

/// Steps of the progress bar (a fraction of 1 in thousandths).
const BAR_STEPS: u64 = 1000;

/// The `--watch` bar on stderr: `[#####.....]  50% ETA 40 s · centring: configuration ...`.
fn progress_bar() -> indicatif::ProgressBar {
    let b = indicatif::ProgressBar::new(BAR_STEPS);
    if let Ok(style) =
        indicatif::ProgressStyle::with_template("[{bar:30}] {percent:>3}% {wide_msg}")
    {
        b.set_style(style.progress_chars("#>."));
    }
    b
}

/// A fraction as a position of the bar.
fn bar_position(fraction: f64) -> u64 {
    let f = if fraction.is_finite() {
        fraction.clamp(0.0, 1.0)
    } else {
        0.0
    };
    (f * BAR_STEPS as f64).round() as u64
}

/// The bar's message: the job's ETA first (a campaign ends its message with `, ETA 40 s`),
/// then the stage and the rest, so a narrow terminal cuts the detail, not the ETA.
pub fn bar_message(stage: &str, message: Option<&str>) -> String {
    let Some(m) = message else {
        return stage.to_string();
    };
    match m.rsplit_once(", ETA ") {
        Some((rest, eta)) => format!("ETA {eta} · {stage}: {rest}"),
        None => format!("{stage}: {m}"),
    }
}

/// What the cell decided about the model a campaign proposed (`cell NAME: model accepted:
/// why` from the job's log), if the job proposed one.
pub async fn cell_decision(c: &Client, id: i64) -> Result<Option<String>, ClientError> {
    let logs = c.get(&format!("/v1/jobs/{id}/logs")).await?;
    Ok(logs["logs"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|l| l["message"].as_str())
        .find(|m| m.starts_with("cell ") && m.contains(": model "))
        .map(|m| format!("decision: {m}")))
}

/// `GET /v1/health` (no token needed) within `timeout`, straight to the daemon (no proxy):
/// the one line to print, and whether the daemon answered 200. For container health
/// checks and scripts waiting for a start.
pub async fn health(c: &Client, timeout: std::time::Duration) -> (String, bool) {
    let url = c.url("/v1/health");
    let http = match reqwest::Client::builder()
        .no_proxy()
        .timeout(timeout)
        .build()
    {
        Ok(h) => h,
        Err(e) => return (format!("unhealthy: {url}: {e}"), false),
    };
    let res = match http.get(&url).send().await {
        Ok(r) => r,
        Err(e) if e.is_timeout() => {
            return (
                format!("unhealthy: {url}: no answer within {timeout:?}"),
                false,
            );
        }
        Err(e) => {
            // reqwest's message names the request; the cause (refused, reset) is below it.
            let mut why = String::new();
            let mut cause: Option<&dyn std::error::Error> = std::error::Error::source(&e);
            while let Some(c) = cause {
                why = c.to_string();
                cause = c.source();
            }
            let why = if why.is_empty() { e.to_string() } else { why };
            return (format!("unhealthy: {url}: {why}"), false);
        }
    };
    let status = res.status();
    if status != reqwest::StatusCode::OK {
        return (format!("unhealthy: {url}: HTTP {}", status.as_u16()), false);
    }
    let v: Value = res.json().await.unwrap_or(Value::Null);
    let n = |k: &str| v[k].as_i64().map_or("?".into(), |n| n.to_string());
    (
        format!(
            "healthy: {url}: queue {}, running {}",
            n("queue_depth"),
            n("running")
        ),
        true,
    )
}

/// Print the job list.
pub async fn jobs(
    c: &Client,
    state: Option<&str>,
    kind: Option<&str>,
    limit: usize,
) -> Result<(), ClientError> {
    let mut q = format!("/v1/jobs?limit={limit}");
    if let Some(s) = state {
        q.push_str(&format!("&state={s}"));
    }
    if let Some(k) = kind {
        q.push_str(&format!("&kind={k}"));
    }
    let v = c.get(&q).await?;
    println!(
        "{:>6}  {:<20} {:<12} {:>6}  submitted",
        "id", "kind", "state", "%"
    );
    for j in v["jobs"].as_array().into_iter().flatten() {
        println!(
            "{:>6}  {:<20} {:<12} {:>6.1}  {}",
            j["id"].as_i64().unwrap_or(0),
            j["kind"].as_str().unwrap_or(""),
            j["state"].as_str().unwrap_or(""),
            100.0 * j["progress"].as_f64().unwrap_or(0.0),
            j["submitted_at"].as_str().unwrap_or("")
        );
    }
    Ok(())
}

/// Cancel a job.
pub async fn cancel(c: &Client, id: i64) -> Result<(), ClientError> {
    let r = c
        .send(c.req(reqwest::Method::POST, &format!("/v1/jobs/{id}/cancel")))
        .await?;
    let v: Value = r
        .json()
        .await
        .map_err(|e| ClientError::Protocol(e.to_string()))?;
    match v["state"].as_str().unwrap_or("?") {
        // A running job cannot be stopped mid-step: it was asked to, and stops at its
        // next cancellation point (a campaign before its next move).
        "running" => println!(
            "job {id}: asked to stop; it is still running and stops at its next step (follow it with `calibd watch {id}`)"
        ),
        state => println!("job {id}: {state}"),
    }
    Ok(())
}

/// Resume a paused or interrupted campaign from its journal (operator role); its id.
pub async fn resume(c: &Client, id: i64) -> Result<i64, ClientError> {
    let r = c
        .send(c.req(reqwest::Method::POST, &format!("/v1/jobs/{id}/resume")))
        .await?;
    let v: Value = r
        .json()
        .await
        .map_err(|e| ClientError::Protocol(e.to_string()))?;
    println!("job {id}: {}", v["state"].as_str().unwrap_or("?"));
    Ok(id)
}

/// Run a job's document again as a new job; the new job's id.
pub async fn rerun(c: &Client, id: i64) -> Result<i64, ClientError> {
    let r = c
        .send(c.req(reqwest::Method::POST, &format!("/v1/jobs/{id}/rerun")))
        .await?;
    let v: Value = r
        .json()
        .await
        .map_err(|e| ClientError::Protocol(e.to_string()))?;
    let new = v["id"]
        .as_i64()
        .ok_or_else(|| ClientError::Protocol(format!("no job id in {v}")))?;
    println!("job {new} submitted (a re-run of job {id})");
    Ok(new)
}

/// Write a job's printable HTML report to `file`.
pub async fn report(c: &Client, id: i64, file: &Path) -> Result<(), ClientError> {
    let html = c.get_bytes(&format!("/v1/jobs/{id}/report")).await?;
    std::fs::write(file, html).map_err(|e| ClientError::File {
        path: file.to_path_buf(),
        message: e.to_string(),
    })?;
    println!("{}", file.display());
    Ok(())
}

/// Print a job's result, or write it and its artefacts into `out`.
pub async fn result(c: &Client, id: i64, out: Option<&Path>) -> Result<(), ClientError> {
    let r = c.get(&format!("/v1/jobs/{id}/result")).await?;
    let Some(dir) = out else {
        println!("{}", serde_json::to_string_pretty(&r).unwrap_or_default());
        return Ok(());
    };
    let file_err = |p: &Path, e: std::io::Error| ClientError::File {
        path: p.to_path_buf(),
        message: e.to_string(),
    };
    std::fs::create_dir_all(dir).map_err(|e| file_err(dir, e))?;
    let p = dir.join("result.json");
    std::fs::write(&p, serde_json::to_string_pretty(&r).unwrap_or_default())
        .map_err(|e| file_err(&p, e))?;
    println!("{}", p.display());
    let list = c.get(&format!("/v1/jobs/{id}/artefacts")).await?;
    for a in list["artefacts"].as_array().into_iter().flatten() {
        let Some(name) = a["name"].as_str() else {
            continue;
        };
        // Artefact names come from the server: keep only the file name.
        let Some(file) = Path::new(name).file_name() else {
            continue;
        };
        let bytes = c
            .get_bytes(&format!("/v1/jobs/{id}/artefacts/{name}"))
            .await?;
        let p = dir.join(file);
        std::fs::write(&p, bytes).map_err(|e| file_err(&p, e))?;
        println!("{}", p.display());
    }
    if let Ok(csv) = c.get_bytes(&format!("/v1/jobs/{id}/table")).await {
        let p = dir.join("table.csv");
        std::fs::write(&p, csv).map_err(|e| file_err(&p, e))?;
        println!("{}", p.display());
    }
    Ok(())
}
