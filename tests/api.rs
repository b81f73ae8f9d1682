//! The HTTP API: the OpenAPI contract (routes both ways, responses validated against the
//! schemas), authentication and roles, body size limits, Server-Sent Events, an
//! identification end to end with its artefacts, dataset references, and the sample
//! configs of deploy/.

mod server;

use std::collections::BTreeSet;
use std::time::Duration;

use futures_util::StreamExt;
use reqwest::Method;
use serde_json::{Value, json};
use server::schema::{assert_response, contract};
use server::{OPERATOR, SUBMITTER, VIEWER, start};

/// (method, path template) of every `.route(...)` in src/api, with the `/v1` prefix for
/// routers nested under it (all but `root_router` and the web page).
fn implemented_routes() -> BTreeSet<(String, String)> {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/src/api");
    let mut out = BTreeSet::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let p = entry.unwrap().path();
        if p.extension().and_then(|e| e.to_str()) != Some("rs") {
            continue;
        }
        let file = p.file_name().unwrap().to_str().unwrap().to_string();
        let text = std::fs::read_to_string(&p).unwrap();
        let mut func = String::new();
        let mut pending: Option<String> = None;
        for line in text.lines() {
            let t = line.trim();
            if let Some(rest) = t
                .strip_prefix("pub(super) fn ")
                .or_else(|| t.strip_prefix("fn "))
            {
                func = rest.split('(').next().unwrap_or("").to_string();
            }
            let stmt = match (pending.take(), t.starts_with(".route(")) {
                (Some(mut acc), _) => {
                    acc.push_str(t);
                    acc
                }
                (None, true) => t.to_string(),
                (None, false) => continue,
            };
            if !stmt.contains(')') || stmt.matches('(').count() > stmt.matches(')').count() {
                pending = Some(stmt);
                continue;
            }
            let path = stmt.split('"').nth(1).unwrap().to_string();
            let prefix = if file == "web.rs" || func == "root_router" || file == "mod.rs" {
                ""
            } else {
                "/v1"
            };
            for m in ["get", "post", "put", "delete"] {
                let pat = format!("{m}(");
                let called = stmt
                    .match_indices(&pat)
                    .any(|(i, _)| !stmt[..i].ends_with(|c: char| c.is_alphanumeric() || c == '_'));
                if called {
                    out.insert((m.to_string(), format!("{prefix}{path}")));
                }
            }
        }
    }
    out
}

fn documented_routes(c: &Value) -> BTreeSet<(String, String)> {
    let mut out = BTreeSet::new();
    for (path, ops) in c["paths"].as_object().unwrap() {
        for m in ops.as_object().unwrap().keys() {
            if ["get", "post", "put", "delete", "patch"].contains(&m.as_str()) {
                out.insert((m.clone(), path.clone()));
            }
        }
    }
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_route_is_documented_and_every_documented_route_is_served() {
    let c = contract();
    let implemented = implemented_routes();
    let documented = documented_routes(&c);
    assert!(
        implemented.len() >= 25,
        "route scan found only {implemented:?}"
    );
    let missing: Vec<_> = implemented.difference(&documented).collect();
    assert!(
        missing.is_empty(),
        "routes missing from openapi.yaml: {missing:?}"
    );
    let extra: Vec<_> = documented.difference(&implemented).collect();
    assert!(
        extra.is_empty(),
        "openapi.yaml documents routes the code lacks: {extra:?}"
    );
    // And the running router really serves each documented (method, path): an unrouted
    // request gets axum's empty 404 or a 405, never our JSON error body.
    let s = start(|_| {}).await;
    for (m, p) in &documented {
        if p.ends_with("/events") {
            continue; // streams; covered by the SSE test
        }
        let path = p.replace("{id}", "999999").replace("{name}", "nothing");
        let method = Method::from_bytes(m.to_uppercase().as_bytes()).unwrap();
        let r = s
            .req(method, &path, Some(OPERATOR))
            .body("{}")
            .send()
            .await
            .unwrap();
        let status = r.status().as_u16();
        let body = r.text().await.unwrap();
        assert_ne!(status, 405, "{m} {p}: method not routed");
        if status == 404 {
            assert!(
                body.contains("\"not_found\""),
                "{m} {p}: not routed (plain 404)"
            );
        }
    }
    // The served document is the file.
    let served = s
        .http
        .get(format!("{}/openapi.yaml", s.url))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert_eq!(
        served,
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/openapi.yaml")).unwrap()
    );
}

async fn call(
    s: &server::TestServer,
    c: &Value,
    m: Method,
    template: &str,
    path: &str,
    token: Option<&str>,
    body: Option<Value>,
) -> (u16, Value) {
    let mut r = s.req(m.clone(), path, token);
    if let Some(b) = body {
        r = r.json(&b);
    }
    let r = r.send().await.unwrap();
    let status = r.status().as_u16();
    let v: Value = r.json().await.unwrap_or(Value::Null);
    assert_response(c, &m.as_str().to_lowercase(), template, status, &v);
    (status, v)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn responses_match_the_contract() {
    let c = contract();
    let s = start(|_| {}).await;
    use Method as M;
    let (st, _) = call(&s, &c, M::GET, "/v1/health", "/v1/health", None, None).await;
    assert_eq!(st, 200);
    call(&s, &c, M::GET, "/v1/version", "/v1/version", None, None).await;
    call(&s, &c, M::GET, "/v1/kinds", "/v1/kinds", None, None).await;
    let (_, ex) = call(&s, &c, M::GET, "/v1/examples", "/v1/examples", None, None).await;
    assert!(ex["examples"].as_array().unwrap().len() >= 3);
    call(&s, &c, M::GET, "/v1/devices", "/v1/devices", None, None).await;
    let (st, created) = call(
        &s,
        &c,
        M::POST,
        "/v1/jobs",
        "/v1/jobs",
        Some(SUBMITTER),
        Some(calibd::jobs::examples::twin_fk(3)),
    )
    .await;
    assert_eq!(st, 201);
    let id = created["id"].as_i64().unwrap();
    s.wait(id).await;
    let p = format!("/v1/jobs/{id}");
    let (_, j) = call(&s, &c, M::GET, "/v1/jobs/{id}", &p, None, None).await;
    assert_eq!(
        (j["state"].as_str(), j["progress"].as_f64()),
        (Some("succeeded"), Some(1.0))
    );
    call(
        &s,
        &c,
        M::GET,
        "/v1/jobs",
        "/v1/jobs?state=succeeded&limit=1",
        None,
        None,
    )
    .await;
    let (_, r) = call(
        &s,
        &c,
        M::GET,
        "/v1/jobs/{id}/result",
        &format!("{p}/result"),
        None,
        None,
    )
    .await;
    assert_eq!(r["poses"].as_array().unwrap().len(), 3);
    call(
        &s,
        &c,
        M::GET,
        "/v1/jobs/{id}/artefacts",
        &format!("{p}/artefacts"),
        None,
        None,
    )
    .await;
    call(
        &s,
        &c,
        M::GET,
        "/v1/jobs/{id}/logs",
        &format!("{p}/logs"),
        None,
        None,
    )
    .await;
    let (st, _) = call(
        &s,
        &c,
        M::POST,
        "/v1/jobs/{id}/cancel",
        &format!("{p}/cancel"),
        Some(SUBMITTER),
        None,
    )
    .await;
    assert_eq!(st, 409);
    let (st, re) = call(
        &s,
        &c,
        M::POST,
        "/v1/jobs/{id}/rerun",
        &format!("{p}/rerun"),
        Some(SUBMITTER),
        None,
    )
    .await;
    assert_eq!(st, 201);
    let rerun = s.wait(re["id"].as_i64().unwrap()).await;
    assert_eq!(rerun["rerun_of"], json!(id));
    let csv = s
        .http
        .get(format!("{}{p}/table", s.url))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert_eq!(csv.lines().next(), Some("x,y,z,a,b,c"));
    // Errors have the documented shape.
    let (st, e) = call(
        &s,
        &c,
        M::GET,
        "/v1/jobs/{id}",
        "/v1/jobs/424242",
        None,
        None,
    )
    .await;
    assert_eq!((st, e["error"]["code"].as_str()), (404, Some("not_found")));
    let (st, e) = call(
        &s,
        &c,
        M::POST,
        "/v1/jobs",
        "/v1/jobs",
        Some(SUBMITTER),
        Some(json!({"kind": "serial.fk", "joints": []})),
    )
    .await;
    assert_eq!(st, 422);
    assert!(
        e["error"]["message"].as_str().unwrap().contains("model"),
        "{e}"
    );
    // Schedules.
    let sched = json!({"name": "nightly", "cron": "0 2 * * *", "timezone": "Europe/Berlin", "job": calibd::jobs::examples::twin_fk(2), "missed": "skip"});
    let (st, sc) = call(
        &s,
        &c,
        M::POST,
        "/v1/schedules",
        "/v1/schedules",
        Some(OPERATOR),
        Some(sched.clone()),
    )
    .await;
    assert_eq!(st, 201);
    let sp = format!("/v1/schedules/{}", sc["id"]);
    assert!(sc["next_run_at"].as_str().unwrap().ends_with(":00:00.000Z"));
    call(&s, &c, M::GET, "/v1/schedules", "/v1/schedules", None, None).await;
    call(&s, &c, M::GET, "/v1/schedules/{id}", &sp, None, None).await;
    call(
        &s,
        &c,
        M::GET,
        "/v1/schedules/{id}/runs",
        &format!("{sp}/runs"),
        None,
        None,
    )
    .await;
    let mut changed = sched.clone();
    changed["enabled"] = json!(false);
    let (st, sc2) = call(
        &s,
        &c,
        M::PUT,
        "/v1/schedules/{id}",
        &sp,
        Some(OPERATOR),
        Some(changed),
    )
    .await;
    assert_eq!((st, sc2["next_run_at"].clone()), (200, Value::Null));
    let (st, _) = call(
        &s,
        &c,
        M::POST,
        "/v1/schedules",
        "/v1/schedules",
        Some(OPERATOR),
        Some(sched),
    )
    .await;
    assert_eq!(st, 409, "duplicate schedule names are a conflict");
    let bad = json!({"name": "x", "cron": "61 * * * *", "job": {"kind": "serial.fk"}});
    let (st, e) = call(
        &s,
        &c,
        M::POST,
        "/v1/schedules",
        "/v1/schedules",
        Some(OPERATOR),
        Some(bad),
    )
    .await;
    assert_eq!(st, 422);
    assert!(
        e["error"]["message"].as_str().unwrap().contains("cron"),
        "{e}"
    );
    let r = s.req(M::DELETE, &sp, Some(OPERATOR)).send().await.unwrap();
    assert_eq!(r.status().as_u16(), 204);
    // Datasets.
    let r = s
        .req(M::POST, "/v1/datasets?name=j.csv", Some(SUBMITTER))
        .header("content-type", "text/csv")
        .body("q1,q2,q3,q4,q5,q6\n0,0,0,0,0,0\n")
        .send()
        .await
        .unwrap();
    let st = r.status().as_u16();
    let d: Value = r.json().await.unwrap();
    assert_response(&c, "post", "/v1/datasets", st, &d);
    call(&s, &c, M::GET, "/v1/datasets", "/v1/datasets", None, None).await;
}

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
    assert_eq!(
        s.req(Method::GET, "/v1/jobs", None)
            .send()
            .await
            .unwrap()
            .status()
            .as_u16(),
        200
    );
    assert_eq!(
        s.req(Method::GET, "/v1/jobs", Some("wrong"))
            .send()
            .await
            .unwrap()
            .status()
            .as_u16(),
        401
    );

    let closed = start(|c| c.auth.anonymous_read = false).await;
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
    let all = s.req(Method::GET, "/v1/events", None).send().await.unwrap();
    assert_eq!(all.headers()["content-type"], "text/event-stream");
    let id = s
        .submit(&calibd::jobs::examples::example("irb120-identify").unwrap())
        .await;
    let r = s
        .req(Method::GET, &format!("/v1/jobs/{id}/events"), None)
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
            None,
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
            None,
        )
        .send()
        .await
        .unwrap();
    let model: Value = model.json().await.unwrap();
    assert_eq!(model, r["calibrated_model"]);
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
        let c = calibd::config::Config::load(Some(&p), &|_| None).unwrap_or_else(|e| panic!("{e}"));
        calibd::api::Auth::new(&c.auth.tokens, c.auth.anonymous_read).unwrap();
        let again = calibd::config::Config::from_toml(&p, &toml::to_string(&c).unwrap()).unwrap();
        assert_eq!(c, again, "{}", p.display());
        n += 1;
    }
    assert!(n >= 1, "no sample config in deploy/");
}
