//! The CLI client commands (`calibd submit`, `watch`, `jobs`, `cancel`, `result`,
//! `health`): each prints what a person wants to see and returns an error for the binary to
//! report.

use std::io::Write;
use std::path::Path;

use serde_json::Value;

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

/// Follow a job with a progress bar on stderr until it ends; print its summary.
pub async fn watch(c: &Client, id: i64) -> Result<Value, ClientError> {
    let mut err = std::io::stderr();
    let tty = std::io::IsTerminal::is_terminal(&err);
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
                    let line = match v["message"].as_str() {
                        Some(m) => format!("{}: {m}", progress_line(f, stage)),
                        None => progress_line(f, stage),
                    };
                    if tty {
                        // One line, redrawn: cut to the terminal's width, asked at each
                        // redraw (a wrapped line cannot be returned to with `\r`), and
                        // clear what was there.
                        let _ = write!(err, "\r\x1b[2K{}", fit(&line, terminal_width()));
                        let _ = err.flush();
                    } else if stage != last_stage || v["message"].is_string() {
                        let _ = writeln!(err, "{line}");
                    }
                    last_stage = stage.to_string();
                }
                "state" => {
                    if tty {
                        let _ = writeln!(err);
                    }
                    let _ = writeln!(err, "job {id}: {}", v["state"].as_str().unwrap_or("?"));
                }
                _ => {}
            }
        })
        .await?;
    let state = job["state"].as_str().unwrap_or("?");
    if state == "succeeded" {
        let r = c.get(&format!("/v1/jobs/{id}/result")).await?;
        print_summary(&r);
        if let Some(line) = cell_decision(c, id).await? {
            println!("{line}");
        }
    } else if let Some(e) = job["error"].as_str() {
        println!("job {id} {state}: {e}");
    }
    Ok(job)
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

/// The width in columns of the terminal stderr writes to, asked of the terminal itself
/// (at each redraw, so a resized window is followed); 80 when it does not say.
fn terminal_width() -> usize {
    terminal_size::terminal_size_of(std::io::stderr())
        .map(|(terminal_size::Width(w), _)| usize::from(w))
        .filter(|w| *w >= 20)
        .unwrap_or(80)
}

/// `line` cut to fit in `width - 1` columns (characters), with an ellipsis when cut.
pub fn fit(line: &str, width: usize) -> String {
    let max = width.saturating_sub(1).max(1);
    if line.chars().count() <= max {
        return line.to_string();
    }
    let mut s: String = line.chars().take(max.saturating_sub(1)).collect();
    s.push('…');
    s
}

fn stats_line(name: &str, v: &Value) -> Option<String> {
    let b = v.get("before")?;
    let a = v.get("after")?;
    let unit = a.get("unit").and_then(Value::as_str).unwrap_or("");
    let f = |x: &Value, k: &str| {
        x.get(k)
            .and_then(Value::as_f64)
            .map_or("-".into(), |v| format!("{v:.4}"))
    };
    Some(format!(
        "{name:<11} mean {} -> {} {unit}, max {} -> {} {unit}",
        f(b, "mean"),
        f(a, "mean"),
        f(b, "max"),
        f(a, "max")
    ))
}

/// Print the headline figures of a result.
pub fn print_summary(r: &Value) {
    println!(
        "{} finished in {:.2} s",
        r["kind"].as_str().unwrap_or("?"),
        r["duration_s"].as_f64().unwrap_or(0.0)
    );
    if let Some(p) = r["parameters"].as_array() {
        let identified = p
            .iter()
            .filter(|x| x["identifiable"].as_bool().unwrap_or(true))
            .count();
        println!(
            "{identified} of {} parameters identified ({} held)",
            p.len(),
            p.len() - identified
        );
    }
    let mm = |k: &str| r[k].as_f64().map(|v| format!("{v:.4}"));
    if let (Some(b), Some(a)) = (mm("rmse_before_mm"), mm("rmse_after_mm")) {
        println!("marker RMSE {b} -> {a} mm");
    }
    let cv = &r["cross_validation"];
    if let (Some(b), Some(a)) = (
        cv["rmse_nominal_mm"].as_f64(),
        cv["rmse_calibrated_mm"].as_f64(),
    ) {
        println!("held-out marker RMSE (cross-validation) {b:.4} -> {a:.4} mm");
    }
    for set in ["calibration", "validation"] {
        let e = &r["model_error"][set]["e_P"];
        if let (Some(b), Some(a)) = (
            e["nominal"]["mean"].as_f64(),
            e["identified"]["mean"].as_f64(),
        ) {
            println!(
                "{set} e_P mean {b:.2} -> {a:.2} {}",
                e["unit"].as_str().unwrap_or("um")
            );
        }
    }
    if let Some(u) = r["unidentifiable"].as_array().filter(|u| !u.is_empty()) {
        println!(
            "unidentifiable: {}",
            u.iter()
                .filter_map(Value::as_str)
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    for key in ["residuals", "validation"] {
        if let Some(l) = stats_line(key, &r[key]) {
            println!("{l}");
        }
    }
    if let Some(rows) = r["poses"].as_array() {
        println!("{} poses", rows.len());
    }
    for w in r["warnings"].as_array().into_iter().flatten() {
        println!("warning: {}", w.as_str().unwrap_or_default());
    }
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
