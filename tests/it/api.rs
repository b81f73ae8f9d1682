//! The HTTP API: authentication and roles, body size limits, Server-Sent Events, an
//! identification end to end with its artefacts, dataset references, and the sample
//! configs of deploy/. (The OpenAPI contract is tests/api_contract.rs.)

use crate::server;

use std::time::Duration;

use futures_util::StreamExt;
use reqwest::Method;
use serde_json::Value;
use server::{OPERATOR, SUBMITTER, VIEWER, start};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tokens_and_roles_guard_every_mutation() {
    let s = start(|_| {}).await;
    let job = calibd::jobs::examples::twin_fk(1);
    let post = |t: Option<&'static str>| s.req(Method::POST, "/v1/jobs", t).json(&job).send();
    let r = post(None).await.unwrap();
    assert_eq!(r.status().as_u16(), 401);
    assert_eq!(r.headers()["www-authenticate"], "Bearer");
    assert_eq!(
        post(Some("not-a-token")).await.unwrap().status().as_u16(),
        401
    );
    assert_eq!(post(Some(VIEWER)).await.unwrap().status().as_u16(), 403);
    assert_eq!(post(Some(SUBMITTER)).await.unwrap().status().as_u16(), 201);
    assert_eq!(post(Some(OPERATOR)).await.unwrap().status().as_u16(), 201);
    // Cancel, re-run and uploads need a submitter; schedules an operator.
    for (m, p, who, want) in [
        (Method::POST, "/v1/jobs/1/cancel", VIEWER, 403),
        (Method::POST, "/v1/jobs/1/rerun", VIEWER, 403),
        (Method::POST, "/v1/datasets", VIEWER, 403),
        (Method::POST, "/v1/schedules", SUBMITTER, 403),
        (Method::PUT, "/v1/schedules/1", SUBMITTER, 403),
        (Method::DELETE, "/v1/schedules/1", SUBMITTER, 403),
        (Method::DELETE, "/v1/schedules/1", "wrong", 401),
    ] {
        let r = s
            .req(m.clone(), p, Some(who))
            .body("x")
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), want, "{m} {p} as {who}");
        let e: Value = r.json().await.unwrap();
        assert!(e["error"]["message"].is_string());
    }
    // Reads are open by default, but a wrong token is refused even there.
    // Reads need a token unless anonymous reads are switched on.
    let open = start(|c| c.auth.anonymous_read = true).await;
    assert_eq!(
        open.req(Method::GET, "/v1/jobs", None)
            .send()
            .await
            .unwrap()
            .status()
            .as_u16(),
        200
    );
    assert_eq!(
        open.req(Method::GET, "/v1/jobs", Some("wrong"))
            .send()
            .await
            .unwrap()
            .status()
            .as_u16(),
        401
    );

    let closed = s;
    assert_eq!(
        closed
            .req(Method::GET, "/v1/jobs", None)
            .send()
            .await
            .unwrap()
            .status()
            .as_u16(),
        401
    );
    assert_eq!(
        closed
            .req(Method::GET, "/v1/jobs", Some(VIEWER))
            .send()
            .await
            .unwrap()
            .status()
            .as_u16(),
        200
    );
    assert_eq!(
        closed
            .req(Method::GET, "/v1/events", None)
            .send()
            .await
            .unwrap()
            .status()
            .as_u16(),
        401
    );
    assert_eq!(
        closed
            .req(Method::GET, "/v1/health", None)
            .send()
            .await
            .unwrap()
            .status()
            .as_u16(),
        200
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bodies_over_the_limit_get_413_and_bad_json_400() {
    let s = start(|c| c.max_body_bytes = 64 * 1024).await;
    let big = "x".repeat(100 * 1024);
    for p in ["/v1/jobs", "/v1/datasets"] {
        let r = s
            .req(Method::POST, p, Some(SUBMITTER))
            .body(big.clone())
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 413, "{p}");
        let e: Value = r.json().await.unwrap();
        assert!(
            e["error"]["message"].as_str().unwrap().contains("65536"),
            "{e}"
        );
    }
    let r = s
        .req(Method::POST, "/v1/jobs", Some(SUBMITTER))
        .body("{\"kind\": ")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 400);
    let e: Value = r.json().await.unwrap();
    assert!(
        e["error"]["message"].as_str().unwrap().contains("line 1"),
        "{e}"
    );
}

/// Read SSE messages from a response until `stop` says so or the stream ends.
async fn read_events(
    r: reqwest::Response,
    mut stop: impl FnMut(&calibd::client::SseMessage) -> bool,
) -> Vec<calibd::client::SseMessage> {
    let mut parser = calibd::client::SseParser::default();
    let mut out = vec![];
    let mut stream = r.bytes_stream();
    while let Ok(Some(chunk)) = tokio::time::timeout(Duration::from_secs(60), stream.next()).await {
        for m in parser.push(&chunk.unwrap()) {
            let done = stop(&m);
            out.push(m);
            if done {
                return out;
            }
        }
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn progress_streams_live_and_an_identification_ends_with_its_artefacts() {
    let s = start(|_| {}).await;
    let all = s
        .req(Method::GET, "/v1/events", Some(VIEWER))
        .send()
        .await
        .unwrap();
    assert_eq!(all.headers()["content-type"], "text/event-stream");
    let id = s
        .submit(&calibd::jobs::examples::example("irb120-identify").unwrap())
        .await;
    let r = s
        .req(Method::GET, &format!("/v1/jobs/{id}/events"), Some(VIEWER))
        .send()
        .await
        .unwrap();
    // The per-job stream ends by itself after the final state.
    let evs = read_events(r, |_| false).await;
    let states: Vec<String> = evs
        .iter()
        .filter(|m| m.event == "state")
        .map(|m| {
            serde_json::from_str::<Value>(&m.data).unwrap()["state"]
                .as_str()
                .unwrap()
                .to_string()
        })
        .collect();
    assert_eq!(
        states.last().map(String::as_str),
        Some("succeeded"),
        "{evs:?}"
    );
    let fractions: Vec<f64> = evs
        .iter()
        .filter(|m| m.event == "progress")
        .map(|m| {
            serde_json::from_str::<Value>(&m.data).unwrap()["fraction"]
                .as_f64()
                .unwrap()
        })
        .collect();
    assert!(fractions.iter().all(|f| (0.0..=1.0).contains(f)));
    // The global stream saw the job queued and finished.
    let seen = read_events(all, |m| {
        m.event == "state"
            && m.data.contains("\"succeeded\"")
            && m.data.contains(&format!("\"id\":{id}"))
    })
    .await;
    assert!(seen.iter().any(|m| m.data.contains("\"queued\"")));
    // Result, calibrated model and plots.
    let (_, r) = s.get(&format!("/v1/jobs/{id}/result")).await;
    assert!(r["parameters"].as_array().unwrap().len() > 20);
    assert!(
        r["validation"]["after"]["mean"].as_f64().unwrap()
            < r["validation"]["before"]["mean"].as_f64().unwrap()
    );
    let (_, a) = s.get(&format!("/v1/jobs/{id}/artefacts")).await;
    let names: Vec<&str> = a["artefacts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x["name"].as_str().unwrap())
        .collect();
    for n in [
        "calibrated_model.json",
        "residuals.csv",
        "errors_per_configuration.svg",
        "error_histogram.svg",
    ] {
        assert!(names.contains(&n), "{n} missing from {names:?}");
    }
    let svg = s
        .req(
            Method::GET,
            &format!("/v1/jobs/{id}/artefacts/error_histogram.svg"),
            Some(VIEWER),
        )
        .send()
        .await
        .unwrap();
    assert_eq!(svg.headers()["content-type"], "image/svg+xml");
    assert!(svg.text().await.unwrap().starts_with("<svg"));
    let model = s
        .req(
            Method::GET,
            &format!("/v1/jobs/{id}/artefacts/calibrated_model.json"),
            Some(VIEWER),
        )
        .send()
        .await
        .unwrap();
    let model: Value = model.json().await.unwrap();
    assert_eq!(model, r["calibrated_model"]);
    // The printable report: HTML that runs nothing, with the result's numbers and plots.
    let rep = s
        .req(Method::GET, &format!("/v1/jobs/{id}/report"), Some(VIEWER))
        .send()
        .await
        .unwrap();
    assert_eq!(rep.status().as_u16(), 200);
    assert_eq!(rep.headers()["content-type"], "text/html; charset=utf-8");
    assert_eq!(rep.headers()["x-content-type-options"], "nosniff");
    let csp = rep.headers()["content-security-policy"]
        .to_str()
        .unwrap()
        .to_string();
    assert!(
        csp.contains("sandbox") && !csp.contains("script-src"),
        "{csp}"
    );
    let html = rep.text().await.unwrap();
    let after = calibd::report::html::number(r["validation"]["after"]["mean"].as_f64().unwrap());
    assert!(html.contains(&format!("data-pointer=\"/validation/after/mean\">{after}<")));
    assert!(html.contains("<figure data-name=\"errors_per_configuration.svg\"><svg"));
    assert!(!html.contains("<script"));
    // Errors are the API's JSON: no such job, and a job without a result.
    let (st, e) = s.get("/v1/jobs/999999/report").await;
    assert_eq!((st, e["error"]["code"].as_str()), (404, Some("not_found")));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_file_naming_a_missing_file_is_refused_with_its_name() {
    let s = start(|_| {}).await;
    let dir = tempfile::tempdir().unwrap();
    let job = dir.path().join("job.json");
    std::fs::write(
        &job,
        r#"{"kind": "serial.fk", "model": "model.json", "joints": "data/joints.csv"}"#,
    )
    .unwrap();
    let client = calibd::client::Client::new(&s.url, Some(SUBMITTER.into()));
    let e = client.load_job_file(&job).await.unwrap_err().to_string();
    assert!(
        e.contains("model.json") && e.contains("data/joints.csv") && e.contains("do not exist"),
        "{e}"
    );
    // Without a token, a refusal says where the CLI looked for one.
    let places = calibd::client::Client::token_places(dir.path());
    let anon = calibd::client::Client::new(&s.url, None).with_token_search(places);
    let e = anon.get("/v1/jobs").await.unwrap_err().to_string();
    assert!(
        e.contains("operator.token") && e.contains("CALIBD_TOKEN"),
        "{e}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn job_files_naming_local_files_are_sent_as_datasets() {
    let s = start(|_| {}).await;
    // A job file with the model and the joints table as files next to it.
    let dir = tempfile::tempdir().unwrap();
    let ex = calibd::jobs::examples::twin_fk(4);
    std::fs::write(
        dir.path().join("model.json"),
        serde_json::to_string(&ex["model"]).unwrap(),
    )
    .unwrap();
    let mut csv = String::from("q1,q2,q3,q4,q5,q6\n");
    for r in ex["joints"].as_array().unwrap() {
        let q: Vec<String> = (1..=6).map(|k| r[format!("q{k}")].to_string()).collect();
        csv.push_str(&q.join(","));
        csv.push('\n');
    }
    std::fs::write(dir.path().join("joints.csv"), csv).unwrap();
    let job = dir.path().join("job.json");
    std::fs::write(
        &job,
        r#"{"kind": "serial.fk", "model": "model.json", "joints": "joints.csv"}"#,
    )
    .unwrap();
    let client = calibd::client::Client::new(&s.url, Some(SUBMITTER.into()));
    let doc = client.load_job_file(&job).await.unwrap();
    assert_eq!(
        doc["joints"].as_str().unwrap().len(),
        64,
        "replaced by the dataset id"
    );
    let id = client.submit(&doc, 0).await.unwrap();
    assert_eq!(s.wait(id).await["state"], "succeeded");
    // Same poses as the inline job (to the last bits of JSON number parsing).
    let inline = s.submit(&ex).await;
    s.wait(inline).await;
    let (_, a) = s.get(&format!("/v1/jobs/{id}/result")).await;
    let (_, b) = s.get(&format!("/v1/jobs/{inline}/result")).await;
    let (pa, pb) = (
        a["poses"].as_array().unwrap(),
        b["poses"].as_array().unwrap(),
    );
    assert_eq!(pa.len(), 4);
    for (x, y) in pa.iter().zip(pb) {
        for k in ["x", "y", "z", "a", "b", "c"] {
            assert!(
                (x[k].as_f64().unwrap() - y[k].as_f64().unwrap()).abs() < 1e-9,
                "{k}: {x} vs {y}"
            );
        }
    }
    assert_eq!(
        s.get("/v1/datasets").await.1["datasets"]
            .as_array()
            .unwrap()
            .len(),
        2
    );
}

#[test]
fn every_sample_config_in_deploy_loads_and_round_trips() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/deploy");
    let mut n = 0;
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().and_then(|e| e.to_str()) != Some("toml") {
            continue;
        }
        // Lab files (lab.*.toml) describe cells, not the daemon: src/lab/config_tests.rs.
        if p.file_name()
            .and_then(|n| n.to_str())
            .is_some_and(|n| n.starts_with("lab."))
        {
            continue;
        }
        let c = calibd::config::Config::load(Some(&p), &|_| None).unwrap_or_else(|e| panic!("{e}"));
        calibd::api::Auth::new(&c.auth.tokens, c.auth.anonymous_read).unwrap();
        let again = calibd::config::Config::from_toml(&p, &toml::to_string(&c).unwrap()).unwrap();
        assert_eq!(c, again, "{}", p.display());
        n += 1;
    }
    assert!(n >= 1, "no sample config in deploy/");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_command_answers_without_a_token_and_fails_when_down() {
    let s = start(|c| c.auth.anonymous_read = false).await;
    let timeout = Duration::from_secs(10);
    let c = calibd::client::Client::new(&s.url, None);
    let (line, ok) = calibd::client::commands::health(&c, timeout).await;
    assert!(ok, "{line}");
    assert!(line.starts_with("healthy: "), "{line}");
    // A port nothing listens on: bind one, then drop it.
    let free = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://{}", free.local_addr().unwrap());
    drop(free);
    let down = calibd::client::Client::new(&url, None);
    let (line, ok) = calibd::client::commands::health(&down, timeout).await;
    assert!(!ok, "{line}");
    assert!(line.starts_with("unhealthy: "), "{line}");
    assert_eq!(line.lines().count(), 1, "{line}");
}

#[test]
fn the_example_config_generates_the_operator_token() {
    // Preset hashes nobody has the tokens of would leave every request 401 (deploy/OPERATIONS.md).
    let p = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/deploy/calibd.toml"));
    let c = calibd::config::Config::load(Some(p), &|_| None).unwrap();
    assert!(c.auth.tokens.is_empty(), "{:?}", c.auth.tokens);
    assert!(!c.auth.anonymous_read);
}

/// The value of the `/metrics` sample `name` whose labels include every one of `labels`
/// (0 when there is none yet).
fn sample(text: &str, name: &str, labels: &[&str]) -> f64 {
    text.lines()
        .filter(|l| l.starts_with(&format!("{name}{{")))
        .find(|l| labels.iter().all(|want| l.contains(want)))
        .and_then(|l| l.rsplit(' ').next())
        .map_or(0.0, |v| v.parse().unwrap())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn request_metrics_count_answered_requests_by_route_template_and_status() {
    let s = start(|_| {}).await;
    let metrics = || async {
        let r = s
            .req(Method::GET, "/metrics", Some(VIEWER))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 200);
        r.text().await.unwrap()
    };
    // A route and status no other test uses: reads with a wrong token (401 from the handler).
    let route = [r#"method="GET""#, r#"path="/v1/jobs/{id}/measurements""#];
    let refused = [route[0], route[1], r#"status="401""#];
    let count = "calibd_http_requests_total";
    let timed = "calibd_http_request_duration_seconds_count";
    // Paths no route has: one label, however many paths (the raw path is never a label).
    let unmatched = [r#"method="GET""#, r#"path="unmatched""#, r#"status="404""#];
    let before = metrics().await;
    let (n0, t0, u0) = (
        sample(&before, count, &refused),
        sample(&before, timed, &route),
        sample(&before, count, &unmatched),
    );
    for path in ["/v1/no-such-thing", "/v1/jobs/1/nope", "/nope/at/all"] {
        let r = s.req(Method::GET, path, Some(VIEWER)).send().await.unwrap();
        assert_eq!(r.status().as_u16(), 404, "{path}");
    }
    for id in [1, 22, 333] {
        let path = format!("/v1/jobs/{id}/measurements");
        let r = s
            .req(Method::GET, &path, Some("wrong"))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 401, "{path}");
    }
    // Refused before the route (another host name): not a request of the route.
    for _ in 0..2 {
        let r = s
            .req(Method::GET, "/v1/jobs/1/measurements", Some("wrong"))
            .header("host", "attacker.example")
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 421);
        assert_eq!(r.headers()["x-content-type-options"], "nosniff");
        assert_eq!(r.headers()["cache-control"], "no-store");
    }
    let after = metrics().await;
    assert_eq!(sample(&after, count, &refused) - n0, 3.0, "{after}");
    assert_eq!(sample(&after, timed, &route) - t0, 3.0, "{after}");
    assert_eq!(sample(&after, count, &unmatched) - u0, 3.0, "{after}");
    assert!(!after.contains("no-such-thing"), "{after}");
}

/// One daemon per SQLite data folder (its queue and the job states it answers from memory
/// are its own): a second daemon started on the folder of a running one is refused, and
/// the message names the lock file and the process that holds it.
#[tokio::test]
async fn a_second_daemon_on_the_same_data_folder_is_refused() {
    let s = start(|_| {}).await;
    let config = calibd::config::Config {
        data: s.dir.path().to_path_buf(),
        lab: "none".into(),
        ..calibd::config::Config::default()
    };
    let stop = tokio_util::sync::CancellationToken::new();
    let second = calibd::server::start(&config, calibd::schedule::Clock::system(), stop).await;
    let msg = match second {
        Ok(_) => panic!("a second daemon started on a folder another one serves"),
        Err(e) => e.to_string(),
    };
    assert!(
        msg.contains("another calibd daemon")
            && msg.contains("calibd.lock")
            && msg.contains(&std::process::id().to_string()),
        "{msg}"
    );
    // The first one still answers.
    assert_eq!(s.get("/v1/health").await.0, 200);
}
