//! The OpenAPI contract: every axum route is in `openapi.yaml` and every documented
//! route is served (both ways), the served document is the file, and responses of every
//! endpoint validate against the documented schemas (status codes included).

use crate::server;

use std::collections::BTreeSet;

use reqwest::Method;
use serde_json::{Value, json};
use server::schema::{assert_response, contract};
use server::{OPERATOR, SUBMITTER, VIEWER, start};

/// (method, path template) of every `.route(...)` in src/api (each route is written with
/// its whole path, `/v1` included).
fn implemented_routes() -> BTreeSet<(String, String)> {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/src/api");
    let mut out = BTreeSet::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let p = entry.unwrap().path();
        if p.extension().and_then(|e| e.to_str()) != Some("rs") {
            continue;
        }
        let text = std::fs::read_to_string(&p).unwrap();
        let mut pending: Option<String> = None;
        for line in text.lines() {
            let t = line.trim();
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
            for m in ["get", "post", "put", "delete"] {
                let pat = format!("{m}(");
                let called = stmt
                    .match_indices(&pat)
                    .any(|(i, _)| !stmt[..i].ends_with(|c: char| c.is_alphanumeric() || c == '_'));
                if called {
                    out.insert((m.to_string(), path.clone()));
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
    call(&s, &c, M::GET, "/v1/kinds", "/v1/kinds", Some(VIEWER), None).await;
    let (_, ex) = call(
        &s,
        &c,
        M::GET,
        "/v1/examples",
        "/v1/examples",
        Some(VIEWER),
        None,
    )
    .await;
    assert!(ex["examples"].as_array().unwrap().len() >= 3);
    call(
        &s,
        &c,
        M::GET,
        "/v1/devices",
        "/v1/devices",
        Some(VIEWER),
        None,
    )
    .await;
    let (st, _) = call(
        &s,
        &c,
        M::GET,
        "/v1/cells/{name}/indicators",
        "/v1/cells/irb120/indicators",
        Some(VIEWER),
        None,
    )
    .await;
    assert_eq!(st, 200);
    let (st, _) = call(
        &s,
        &c,
        M::GET,
        "/v1/cells/{name}/indicators",
        "/v1/cells/nope/indicators",
        Some(VIEWER),
        None,
    )
    .await;
    assert_eq!(st, 404);
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
    let (_, j) = call(&s, &c, M::GET, "/v1/jobs/{id}", &p, Some(VIEWER), None).await;
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
        Some(VIEWER),
        None,
    )
    .await;
    let (_, r) = call(
        &s,
        &c,
        M::GET,
        "/v1/jobs/{id}/result",
        &format!("{p}/result"),
        Some(VIEWER),
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
        Some(VIEWER),
        None,
    )
    .await;
    call(
        &s,
        &c,
        M::GET,
        "/v1/jobs/{id}/logs",
        &format!("{p}/logs"),
        Some(VIEWER),
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
        .req(Method::GET, &format!("{p}/table"), Some(VIEWER))
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
        Some(VIEWER),
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
    call(
        &s,
        &c,
        M::GET,
        "/v1/schedules",
        "/v1/schedules",
        Some(VIEWER),
        None,
    )
    .await;
    call(
        &s,
        &c,
        M::GET,
        "/v1/schedules/{id}",
        &sp,
        Some(VIEWER),
        None,
    )
    .await;
    call(
        &s,
        &c,
        M::GET,
        "/v1/schedules/{id}/runs",
        &format!("{sp}/runs"),
        Some(VIEWER),
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
    call(
        &s,
        &c,
        M::GET,
        "/v1/datasets",
        "/v1/datasets",
        Some(VIEWER),
        None,
    )
    .await;
}

/// The user documentation's relative links, `(file, line, target)`: every markdown link
/// `[text](target)` of README.md, deploy/OPERATIONS.md and docs/*.md, outside code spans and
/// fenced code blocks, that is not a URL (`http:`, `https:`, `mailto:`); `#anchor` for a
/// heading of the same page.
fn doc_links() -> Vec<(std::path::PathBuf, usize, String)> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = vec![root.join("README.md"), root.join("deploy/OPERATIONS.md")];
    let mut docs: Vec<_> = std::fs::read_dir(root.join("docs"))
        .expect("the docs/ folder")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().and_then(|e| e.to_str()) == Some("md"))
        .collect();
    docs.sort();
    files.extend(docs);
    let mut out = Vec::new();
    for file in files {
        let text = std::fs::read_to_string(&file).unwrap();
        // The text outside fenced code blocks and code spans (which may run over a line
        // break), with everything else blanked and the line breaks kept.
        let mut plain = String::with_capacity(text.len());
        let (mut fenced, mut in_code) = (false, false);
        for line in text.split_inclusive('\n') {
            if line.trim_start().starts_with("```") {
                fenced = !fenced;
                plain.push('\n');
                continue;
            }
            for c in line.chars() {
                if c == '`' && !fenced {
                    in_code = !in_code;
                }
                plain.push(if fenced || in_code || c == '`' {
                    ' '
                } else {
                    c
                });
            }
        }
        let mut from = 0;
        while let Some(k) = plain[from..].find("](") {
            let start = from + k + 2;
            let after = &plain[start..];
            let end = after.find([')', '\n']).unwrap_or(after.len());
            let target = after[..end].split_whitespace().next().unwrap_or("");
            let target = target.trim_start_matches('<').trim_end_matches('>');
            let external = ["http://", "https://", "mailto:"]
                .iter()
                .any(|s| target.starts_with(s));
            if !target.is_empty() && !external {
                let line = plain[..start].matches('\n').count() + 1;
                out.push((file.clone(), line, target.to_string()));
            }
            from = start + end;
        }
    }
    out
}

/// GitHub's anchors of a markdown file's headings (lowercase, punctuation dropped, spaces to
/// hyphens, `-1`, `-2` for repeats).
fn heading_anchors(text: &str) -> BTreeSet<String> {
    let mut seen: BTreeSet<String> = BTreeSet::new();
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        let Some(h) = line.strip_prefix('#') else {
            continue;
        };
        if fenced || !(h.starts_with('#') || h.starts_with(' ')) {
            continue;
        }
        let title = h.trim_start_matches('#').trim();
        let slug: String = title
            .to_lowercase()
            .chars()
            .filter_map(|c| match c {
                ' ' => Some('-'),
                c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
                _ => None,
            })
            .collect();
        let mut anchor = slug.clone();
        let mut n = 0;
        while seen.contains(&anchor) {
            n += 1;
            anchor = format!("{slug}-{n}");
        }
        seen.insert(anchor);
    }
    seen
}

/// README.md, deploy/OPERATIONS.md and docs/*.md link only to files of this repository (a
/// fresh clone explains itself: no link into `../shared` or to a file that is not there),
/// and a link to a heading of a markdown file names a heading it has.
#[test]
fn documentation_links_resolve_inside_the_repository() {
    let manifest = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let root = manifest.canonicalize().unwrap();
    let links = doc_links();
    assert!(
        links
            .iter()
            .any(|(f, _, t)| f.parent() == Some(manifest) && t == "docs/jobs.md"),
        "the README links the job reference"
    );
    let mut broken = Vec::new();
    for (file, line, target) in &links {
        let (path, fragment) = match target.split_once('#') {
            Some((p, f)) => (p, Some(f)),
            None => (target.as_str(), None),
        };
        let at = format!("{}:{line}: `{target}`", file.display());
        let resolved = if path.is_empty() {
            file.canonicalize()
        } else {
            file.parent().unwrap().join(path).canonicalize()
        };
        match resolved {
            Err(e) => broken.push(format!("{at}: {e}")),
            Ok(p) if !p.starts_with(&root) => {
                broken.push(format!("{at}: outside the repository ({})", p.display()))
            }
            Ok(p) => {
                if let Some(f) = fragment
                    && p.extension().and_then(|e| e.to_str()) == Some("md")
                    && !heading_anchors(&std::fs::read_to_string(&p).unwrap()).contains(f)
                {
                    broken.push(format!("{at}: no heading with the anchor `#{f}`"));
                }
            }
        }
    }
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}
