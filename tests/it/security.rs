//! The defects of the security review (issue 14), each reproduced against a daemon on a
//! real socket: stored XSS through datasets, reads without a token, DNS rebinding through
//! the `Host` header, idle and half-sent connections, a submitter stopping an operator's
//! campaign, absurd inputs, unbounded names and headers, the bearer scheme's case, retried
//! submissions, and plain-text error bodies; and those of issue 28: connection exhaustion
//! (hostile idle sockets, a viewer's event streams, an event stream nobody reads), two
//! `Host` headers, a CSV column named twice, implausible options, a dataset re-uploaded
//! under a second name.

use crate::server;

use std::time::Duration;

use reqwest::Method;
use serde_json::{Value, json};
use server::{OPERATOR, SUBMITTER, VIEWER, start};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_uploaded_page_comes_back_as_an_inert_attachment() {
    let s = start(|_| {}).await;
    let page = "<html><script>fetch('/steal?t='+localStorage.getItem('calibd-token'))</script>";
    let r = s
        .req(Method::POST, "/v1/datasets?name=x.html", Some(SUBMITTER))
        .header("content-type", "text/html")
        .body(page)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 201);
    let info: Value = r.json().await.unwrap();
    let id = info["id"].as_str().unwrap();
    assert_eq!(
        info["media_type"], "text/html",
        "the declared type is kept as data"
    );
    // Without a token: nothing.
    let anon = s
        .req(Method::GET, &format!("/v1/datasets/{id}"), None)
        .send()
        .await
        .unwrap();
    assert_eq!(anon.status().as_u16(), 401);
    let r = s
        .req(Method::GET, &format!("/v1/datasets/{id}"), Some(VIEWER))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 200);
    let h = r.headers().clone();
    assert_eq!(h["content-type"], "application/octet-stream");
    assert_eq!(h["x-content-type-options"], "nosniff");
    assert_eq!(h["content-disposition"], "attachment; filename=\"x.html\"");
    let csp = h["content-security-policy"].to_str().unwrap();
    assert!(
        csp.contains("script-src 'self'") && csp.contains("default-src 'none'"),
        "{csp}"
    );
    assert_eq!(
        r.text().await.unwrap(),
        page,
        "the bytes come back unchanged"
    );
    // The page itself runs only its own script file.
    let p = s.req(Method::GET, "/", None).send().await.unwrap();
    assert!(
        p.headers()["content-security-policy"]
            .to_str()
            .unwrap()
            .contains("frame-ancestors 'none'")
    );
    let html = p.text().await.unwrap();
    assert!(!html.contains("<script>"), "no inline script in the page");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn only_configured_host_names_are_answered() {
    let s = start(|_| {}).await;
    let port = s.url.rsplit(':').next().unwrap().to_string();
    for host in [
        format!("127.0.0.1:{port}"),
        format!("localhost:{port}"),
        "LOCALHOST".to_string(),
        format!("[::1]:{port}"),
    ] {
        let r = s
            .req(Method::GET, "/v1/jobs", Some(VIEWER))
            .header("host", &host)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 200, "{host}");
    }
    // A rebinding page's name: refused, with a JSON body that says what to configure.
    let r = s
        .req(Method::GET, "/v1/jobs", Some(VIEWER))
        .header("host", format!("attacker.example:{port}"))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 421);
    let e: Value = r.json().await.unwrap();
    let m = e["error"]["message"].as_str().unwrap();
    assert!(
        m.contains("attacker.example") && m.contains("allowed_hosts"),
        "{m}"
    );
    // The health check obeys the same rule (it is reachable from the same browser).
    let r = s
        .req(Method::GET, "/v1/health", None)
        .header("host", "attacker.example")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 421);
    // A configured name is answered.
    let named = start(|c| c.allowed_hosts.push("calib.lab.example".into())).await;
    let r = named
        .req(Method::GET, "/v1/jobs", Some(VIEWER))
        .header("host", "calib.lab.example")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 200);
}

/// Read until the server closes the connection (EOF or reset); false if it stays open.
async fn closed_by_server(c: &mut tokio::net::TcpStream, within: Duration) -> bool {
    let mut buf = [0u8; 512];
    let deadline = tokio::time::Instant::now() + within;
    loop {
        match tokio::time::timeout_at(deadline, c.read(&mut buf)).await {
            Err(_) => return false,
            Ok(Ok(0)) | Ok(Err(_)) => return true,
            Ok(Ok(_)) => {} // a 408/431 answer before the close
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_and_half_sent_connections_are_bounded_and_timed_out() {
    let s = start(|c| {
        c.max_connections = 4;
        c.header_read_timeout_s = 1;
    })
    .await;
    let addr = s.url.trim_start_matches("http://").to_string();
    // Four connections: two idle, two with half a request head.
    let mut held = Vec::new();
    for i in 0..4 {
        let mut c = tokio::net::TcpStream::connect(&addr).await.unwrap();
        if i % 2 == 1 {
            c.write_all(b"GET /v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
                .await
                .unwrap();
        }
        held.push(c);
    }
    // The fifth is over the limit. The server may accept it before the four are
    // registered, so retry until one is refused (each refusal is immediate).
    let mut refused = false;
    for _ in 0..50 {
        let mut extra = tokio::net::TcpStream::connect(&addr).await.unwrap();
        if closed_by_server(&mut extra, Duration::from_millis(500)).await {
            refused = true;
            break;
        }
    }
    assert!(refused, "a connection over the limit was kept open");
    // The header-read timeout closes every held connection, idle or half-sent.
    for (i, c) in held.iter_mut().enumerate() {
        assert!(
            closed_by_server(c, Duration::from_secs(60)).await,
            "connection {i} outlived the header-read timeout"
        );
    }
    // Slots are free again: a normal request is served.
    let (status, _) = s.get("/v1/jobs").await;
    assert_eq!(status, 200);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_submitter_cannot_stop_an_operators_campaign() {
    let s = start(|_| {}).await;
    // A device job (the centring loop on the simulated cell) submitted by the operator.
    let doc = json!({"kind": "cell.centre", "q_deg": [0.0, 0.0, 0.0, 0.0, 30.0, 0.0]});
    let r = s
        .req(Method::POST, "/v1/jobs", Some(OPERATOR))
        .json(&doc)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 201);
    let id = r.json::<Value>().await.unwrap()["id"].as_i64().unwrap();
    let cancel = |t: &'static str| {
        s.req(Method::POST, &format!("/v1/jobs/{id}/cancel"), Some(t))
            .send()
    };
    let r = cancel(SUBMITTER).await.unwrap();
    assert_eq!(r.status().as_u16(), 403);
    let e: Value = r.json().await.unwrap();
    assert!(
        e["error"]["message"]
            .as_str()
            .unwrap()
            .contains("operator role"),
        "{e}"
    );
    // The operator can (200 while it winds down, or 409 if it already ended).
    let r = cancel(OPERATOR).await.unwrap();
    assert!(matches!(r.status().as_u16(), 200 | 409), "{}", r.status());
    // A submitter still cancels its own numerical jobs.
    let mine = s.submit(&calibd::jobs::examples::twin_fk(1)).await;
    let r = cancel_as(&s, mine, SUBMITTER).await;
    assert!(matches!(r, 200 | 409), "{r}");
}

async fn cancel_as(s: &server::TestServer, id: i64, t: &str) -> u16 {
    s.req(Method::POST, &format!("/v1/jobs/{id}/cancel"), Some(t))
        .send()
        .await
        .unwrap()
        .status()
        .as_u16()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn absurd_inputs_are_refused_with_the_field_named() {
    let s = start(|_| {}).await;
    let post =
        |path: &str, body: Value| s.req(Method::POST, path, Some(OPERATOR)).json(&body).send();
    // A parameter that overflows the kinematics: no job of NaN.
    let mut fk = calibd::jobs::examples::twin_fk(3);
    fk["parameters"] = json!({"a2": 1e308});
    let r = post("/v1/jobs", fk).await.unwrap();
    assert_eq!(r.status().as_u16(), 422);
    let e: Value = r.json().await.unwrap();
    assert!(
        e["error"]["message"]
            .as_str()
            .unwrap()
            .contains("parameters.a2"),
        "{e}"
    );
    // A schedule every second: refused, naming the interval and the setting.
    let every_second = json!({"name": "spam", "cron": "* * * * * *", "timezone": "UTC",
        "job": calibd::jobs::examples::twin_fk(1)});
    let r = post("/v1/schedules", every_second).await.unwrap();
    assert_eq!(r.status().as_u16(), 422);
    let e: Value = r.json().await.unwrap();
    let m = e["error"]["message"].as_str().unwrap();
    assert!(
        m.contains("cron") && m.contains("every 1 s") && m.contains("60 s"),
        "{m}"
    );
    // Every minute is allowed.
    let minutely = json!({"name": "minutely", "cron": "* * * * *", "timezone": "UTC",
        "job": calibd::jobs::examples::twin_fk(1), "enabled": false});
    assert_eq!(
        post("/v1/schedules", minutely)
            .await
            .unwrap()
            .status()
            .as_u16(),
        201
    );
    // A 1 MB name is not stored.
    let long = json!({"name": "n".repeat(1 << 20), "cron": "0 2 * * *", "timezone": "UTC",
        "job": calibd::jobs::examples::twin_fk(1)});
    let r = post("/v1/schedules", long).await.unwrap();
    assert_eq!(r.status().as_u16(), 422);
    let r = s
        .req(
            Method::POST,
            &format!("/v1/datasets?name={}", "n".repeat(5000)),
            Some(SUBMITTER),
        )
        .body("x,y\n1,2\n")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 400);
    // A 100 KB Content-Type never reaches a handler; a 1 KB one is refused by name.
    let r = s
        .req(Method::POST, "/v1/datasets", Some(SUBMITTER))
        .header("content-type", format!("text/{}", "x".repeat(100 * 1024)))
        .body("x,y\n1,2\n")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 431);
    let r = s
        .req(Method::POST, "/v1/datasets", Some(SUBMITTER))
        .header("content-type", format!("text/{}", "x".repeat(1024)))
        .body("x,y\n1,2\n")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 400);
    assert!(
        r.text().await.unwrap().contains("Content-Type"),
        "the error names the header"
    );
    assert_eq!(s.get("/v1/datasets").await.1["datasets"], json!([]));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_bearer_scheme_is_case_insensitive() {
    let s = start(|_| {}).await;
    for scheme in ["bearer", "BEARER", "Bearer"] {
        let r = s
            .req(Method::GET, "/v1/jobs", None)
            .header("authorization", format!("{scheme} {VIEWER}"))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 200, "{scheme}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_retried_submission_is_one_job() {
    let s = start(|_| {}).await;
    let job = calibd::jobs::examples::twin_fk(2);
    let send = |key: &'static str, doc: &Value| {
        s.req(Method::POST, "/v1/jobs", Some(SUBMITTER))
            .header("idempotency-key", key)
            .json(doc)
            .send()
    };
    let first = send("k-1", &job).await.unwrap();
    assert_eq!(first.status().as_u16(), 201);
    let id = first.json::<Value>().await.unwrap()["id"].as_i64().unwrap();
    // The client saw a reset and sends again: the same job, not a second one.
    let again = send("k-1", &job).await.unwrap();
    assert_eq!(again.status().as_u16(), 200);
    assert_eq!(again.headers()["idempotent-replayed"], "true");
    assert_eq!(
        again.json::<Value>().await.unwrap()["id"].as_i64(),
        Some(id)
    );
    // The same key for another job is a conflict, not a silent replay.
    let other = calibd::jobs::examples::twin_fk(3);
    assert_eq!(send("k-1", &other).await.unwrap().status().as_u16(), 409);
    // Another token's key space is its own.
    let r = s
        .req(Method::POST, "/v1/jobs", Some(OPERATOR))
        .header("idempotency-key", "k-1")
        .json(&job)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 201);
    let (_, list) = s.get("/v1/jobs").await;
    assert_eq!(list["jobs"].as_array().unwrap().len(), 2);
    // The CLI's client sends a key of its own.
    let c = calibd::client::Client::new(&s.url, Some(SUBMITTER.into()));
    let n = c.submit(&job, 0).await.unwrap();
    assert!(n > id);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_error_body_is_json() {
    let s = start(|_| {}).await;
    for (m, path, want) in [
        (Method::GET, "/v1/jobs/abc", 400),
        (Method::GET, "/v1/jobs/1/artefacts/x", 404),
        (Method::GET, "/v1/schedules/9999999999999999999999", 400),
        (Method::GET, "/v1/nothing-here", 404),
        (Method::DELETE, "/v1/jobs", 405),
        (Method::GET, "/v1/jobs?limit=0", 400),
        (Method::GET, "/v1/jobs?limit=100000", 400),
    ] {
        let r = s.req(m.clone(), path, Some(OPERATOR)).send().await.unwrap();
        assert_eq!(r.status().as_u16(), want, "{m} {path}");
        assert_eq!(
            r.headers()["content-type"],
            "application/json",
            "{m} {path}"
        );
        let e: Value = r.json().await.unwrap();
        assert!(e["error"]["message"].is_string(), "{m} {path}: {e}");
    }
}

/// Send one raw request head on a fresh connection; the status code of the answer.
async fn raw_status(addr: &str, head: &str) -> u16 {
    let mut c = tokio::net::TcpStream::connect(addr).await.unwrap();
    c.write_all(head.as_bytes()).await.unwrap();
    let mut buf = Vec::new();
    let mut chunk = [0u8; 1024];
    // The status line is in the first bytes; bounded by the read timeout.
    while !buf.windows(2).any(|w| w == b"\r\n") {
        match tokio::time::timeout(Duration::from_secs(20), c.read(&mut chunk)).await {
            Ok(Ok(n)) if n > 0 => buf.extend_from_slice(&chunk[..n]),
            other => panic!("no answer to {head:?}: {other:?}"),
        }
    }
    let line = String::from_utf8_lossy(&buf);
    line.split(' ').nth(1).and_then(|c| c.parse().ok()).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_host_headers_are_a_bad_request() {
    for any in [false, true] {
        let s = start(|c| {
            if any {
                c.allowed_hosts = vec!["*".into()];
            }
        })
        .await;
        let addr = s.url.trim_start_matches("http://").to_string();
        let one = "GET /v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n";
        assert_eq!(raw_status(&addr, one).await, 200, "allowed_hosts * = {any}");
        // RFC 9112 section 3.2: not "the first one wins", in either order.
        for (a, b) in [
            ("127.0.0.1", "attacker.example"),
            ("attacker.example", "127.0.0.1"),
        ] {
            let two = format!(
                "GET /v1/health HTTP/1.1\r\nHost: {a}\r\nHost: {b}\r\nConnection: close\r\n\r\n"
            );
            assert_eq!(raw_status(&addr, &two).await, 400, "{a}, {b}; * = {any}");
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_csv_column_named_twice_is_refused_by_name() {
    let s = start(|_| {}).await;
    let r = s
        .req(Method::POST, "/v1/datasets?name=dup.csv", Some(SUBMITTER))
        .header("content-type", "text/csv")
        .body("q1,q2,q3,q4,q1,q6\n0,0,0,0,0,0\n")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 201);
    let id = r.json::<Value>().await.unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string();
    let mut fk = calibd::jobs::examples::twin_fk(1);
    fk["joints"] = json!(id);
    let r = s
        .req(Method::POST, "/v1/jobs", Some(SUBMITTER))
        .json(&fk)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 422);
    let e: Value = r.json().await.unwrap();
    let m = e["error"]["message"].as_str().unwrap();
    assert!(m.contains("joints") && m.contains("`q1` twice"), "{m}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn implausible_identification_options_are_refused_naming_the_option() {
    let s = start(|_| {}).await;
    for (option, value) in [
        ("noise", 1e308),
        ("effect_fraction", 1e308),
        ("noise", 5000.0), // 5 m in the twin's mm
        ("effect_fraction", 2.0),
        ("rank_tolerance", 1.0),
    ] {
        let mut job = calibd::jobs::examples::twin_identify(2, 2);
        job["options"] = json!({ option: value });
        let r = s
            .req(Method::POST, "/v1/jobs", Some(SUBMITTER))
            .json(&job)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 422, "{option} = {value}");
        let e: Value = r.json().await.unwrap();
        let m = e["error"]["message"].as_str().unwrap();
        assert!(
            m.contains(&format!("options.{option}")) && m.contains("plausible range"),
            "{m}"
        );
    }
    // A plausible value is accepted (0.01 mm of noise, the default fraction).
    let mut job = calibd::jobs::examples::twin_identify(2, 2);
    job["options"] = json!({"noise": 0.01, "effect_fraction": 0.01});
    let r = s
        .req(Method::POST, "/v1/jobs", Some(SUBMITTER))
        .json(&job)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 201);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn identical_content_under_a_second_name_says_which_name_it_kept() {
    let s = start(|_| {}).await;
    let up = |name: &str| {
        s.req(
            Method::POST,
            &format!("/v1/datasets?name={name}"),
            Some(SUBMITTER),
        )
        .header("content-type", "text/csv")
        .body("q1\n1\n")
        .send()
    };
    let first = up("m.csv").await.unwrap();
    assert_eq!(first.status().as_u16(), 201);
    let first: Value = first.json().await.unwrap();
    // The same name again: as before, stored (or already there).
    assert_eq!(up("m.csv").await.unwrap().status().as_u16(), 201);
    let again = up("again.csv").await.unwrap();
    assert_eq!(
        again.status().as_u16(),
        200,
        "not answered as a new dataset"
    );
    let again: Value = again.json().await.unwrap();
    assert_eq!(again["id"], first["id"]);
    assert_eq!(again["name"], "m.csv");
    assert_eq!(again["already_stored"], true);
    let m = again["message"].as_str().unwrap();
    assert!(m.contains("`m.csv`") && m.contains("`again.csv`"), "{m}");
    let (_, list) = s.get("/v1/datasets").await;
    assert_eq!(list["datasets"].as_array().unwrap().len(), 1);
}

/// Raise this process's soft limit of open files to at least `want` (CI often starts at
/// 1024; client and server sockets of the exhaustion tests are both in this process).
fn raise_fd_limit(want: u64) {
    let mut r = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: plain getrlimit/setrlimit on a local struct.
    unsafe {
        assert_eq!(libc::getrlimit(libc::RLIMIT_NOFILE, &mut r), 0);
        if r.rlim_cur < want {
            r.rlim_cur = want.min(r.rlim_max);
            assert_eq!(libc::setrlimit(libc::RLIMIT_NOFILE, &r), 0);
        }
    }
    assert!(
        r.rlim_cur >= want,
        "this test needs {want} open files; the hard limit is {}",
        r.rlim_max
    );
}

/// A connection to `to` from the loopback address `from` (the server sees it as the peer).
async fn connect_from(
    from: [u8; 4],
    to: std::net::SocketAddr,
) -> std::io::Result<tokio::net::TcpStream> {
    let s = tokio::net::TcpSocket::new_v4()?;
    s.bind((std::net::Ipv4Addr::from(from), 0).into())?;
    s.connect(to).await
}

/// Send a request head and read the status of the answer; None if the server closed the
/// connection without one.
async fn status_of(c: &mut tokio::net::TcpStream, head: &str) -> Option<u16> {
    c.write_all(head.as_bytes()).await.ok()?;
    let mut buf = Vec::new();
    let mut chunk = [0u8; 512];
    while !buf.windows(2).any(|w| w == b"\r\n") {
        match tokio::time::timeout(Duration::from_secs(30), c.read(&mut chunk)).await {
            Ok(Ok(n)) if n > 0 => buf.extend_from_slice(&chunk[..n]),
            _ => return None,
        }
    }
    String::from_utf8_lossy(&buf)
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
}

fn events_head(token: &str) -> String {
    format!("GET /v1/events HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {token}\r\n\r\n")
}

/// Which of `held` the server has not closed (reads and drops what it sent first).
fn still_open(held: &mut [Option<tokio::net::TcpStream>]) -> usize {
    let mut buf = [0u8; 512];
    let mut open = 0;
    for slot in held.iter_mut() {
        let Some(c) = slot else { continue };
        let closed = loop {
            match c.try_read(&mut buf) {
                Ok(0) => break true,
                Ok(_) => continue,
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => break false,
                Err(_) => break true,
            }
        };
        if closed {
            *slot = None;
        } else {
            open += 1;
        }
    }
    open
}

fn summary(ms: &mut [f64]) -> String {
    ms.sort_by(f64::total_cmp);
    format!(
        "min {:.1} ms, median {:.1} ms, max {:.1} ms ({} requests)",
        ms[0],
        ms[ms.len() / 2],
        ms[ms.len() - 1],
        ms.len()
    )
}

/// 20 `GET /v1/health` and 5 `POST /v1/jobs` as the operator, each asserted to succeed;
/// their times in ms.
async fn operator_requests(operator: &reqwest::Client, url: &str) -> (Vec<f64>, Vec<f64>) {
    let (mut health, mut jobs) = (Vec::new(), Vec::new());
    let job = calibd::jobs::examples::twin_fk(1);
    for i in 0..20 {
        let t0 = std::time::Instant::now();
        let r = operator
            .get(format!("{url}/v1/health"))
            .bearer_auth(OPERATOR)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 200, "health {i}");
        health.push(t0.elapsed().as_secs_f64() * 1e3);
        if i % 4 == 0 {
            let t0 = std::time::Instant::now();
            let r = operator
                .post(format!("{url}/v1/jobs"))
                .bearer_auth(OPERATOR)
                .json(&job)
                .send()
                .await
                .unwrap();
            assert_eq!(r.status().as_u16(), 201, "job {i}");
            jobs.push(t0.elapsed().as_secs_f64() * 1e3);
        }
    }
    (health, jobs)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hostile_sockets_and_viewer_streams_do_not_lock_the_operator_out() {
    raise_fd_limit(4096);
    // The defaults (512 slots, 64 per address, 32 for operators, 16 streams per token);
    // idle connections are kept for the whole test, so everything stays held.
    let s = start(|c| c.header_read_timeout_s = 300).await;
    let addr: std::net::SocketAddr = s.url.trim_start_matches("http://").parse().unwrap();
    // The operator's client: its own address, a new connection for every request.
    let operator = reqwest::Client::builder()
        .local_address(std::net::IpAddr::from([127, 0, 0, 2]))
        .pool_max_idle_per_host(0)
        .build()
        .unwrap();
    let (mut health, mut jobs) = operator_requests(&operator, &s.url).await;
    eprintln!("operator GET /v1/health before: {}", summary(&mut health));
    eprintln!("operator POST /v1/jobs before: {}", summary(&mut jobs));
    // A client without a token: 600 idle sockets from 127.0.0.1, reopened when closed.
    let mut hostile: Vec<Option<tokio::net::TcpStream>> = Vec::new();
    for _ in 0..600 {
        hostile.push(connect_from([127, 0, 0, 1], addr).await.ok());
    }
    // Refused beyond the address's share: at most 64 stay open.
    let mut open = 600;
    for _ in 0..200 {
        open = still_open(&mut hostile);
        if open <= 64 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(open <= 64, "{open} idle sockets from one address are held");
    let (stop, stopped) = tokio::sync::watch::channel(false);
    let reopen = tokio::spawn(async move {
        let mut reopened = 0u64;
        while !*stopped.borrow() {
            still_open(&mut hostile);
            for slot in hostile.iter_mut().filter(|c| c.is_none()) {
                *slot = connect_from([127, 0, 0, 1], addr).await.ok();
                reopened += 1;
            }
            tokio::time::sleep(Duration::from_millis(500)).await;
        }
        reopened
    });
    // A viewer: 520 event streams, from ten addresses (52 each, within their share).
    let mut streams = Vec::new();
    let (mut ok, mut too_many, mut unavailable, mut closed) = (0, 0, 0, 0);
    for i in 0..520u32 {
        let from = [127, 0, 1, 1 + (i % 10) as u8];
        let Ok(mut c) = connect_from(from, addr).await else {
            closed += 1;
            continue;
        };
        match status_of(&mut c, &events_head(VIEWER)).await {
            Some(200) => ok += 1,
            Some(429) => too_many += 1,
            Some(503) => unavailable += 1,
            None => closed += 1,
            Some(other) => panic!("stream {i}: status {other}"),
        }
        streams.push(c);
    }
    eprintln!("viewer: {ok} streams open, {too_many} x 429, {unavailable} x 503, {closed} closed");
    assert_eq!(
        ok, 16,
        "the viewer's token holds its share of streams, no more"
    );
    assert!(too_many > 0 && too_many + unavailable + closed == 520 - 16);
    // Every slot but the operators' is taken: another viewer is turned away...
    let mut other = connect_from([127, 0, 0, 3], addr).await.unwrap();
    let head = format!(
        "GET /v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {VIEWER}\r\n\r\n"
    );
    assert_ne!(
        status_of(&mut other, &head).await,
        Some(200),
        "the general slots should all be held"
    );
    // ...and the operator, on a new connection each time, still gets through.
    let (mut health, mut jobs) = operator_requests(&operator, &s.url).await;
    let _ = stop.send(true);
    let reopened = reopen.await.unwrap();
    let (h, j) = (summary(&mut health), summary(&mut jobs));
    eprintln!("hostile sockets reopened: {reopened}");
    eprintln!("operator GET /v1/health under attack: {h}");
    eprintln!("operator POST /v1/jobs under attack: {j}");
    // A generous bound (the CI machine is shared); the figures are printed above.
    assert!(
        health[health.len() / 2] < 1000.0 && jobs[jobs.len() / 2] < 2000.0,
        "health {h}; jobs {j}"
    );
    drop(streams);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_event_stream_nobody_reads_is_disconnected() {
    let s = start(|c| {
        c.send_timeout_s = 1;
        c.max_event_streams_per_token = 1;
    })
    .await;
    let addr: std::net::SocketAddr = s.url.trim_start_matches("http://").parse().unwrap();
    // A viewer that opens a stream and reads nothing, with a small receive window.
    let sock = tokio::net::TcpSocket::new_v4().unwrap();
    sock.set_recv_buffer_size(2048).unwrap();
    let mut stalled = sock.connect(addr).await.unwrap();
    // Its answer's first bytes only (the stream is open), then nothing.
    assert_eq!(
        status_of(&mut stalled, &events_head(VIEWER)).await,
        Some(200)
    );
    // An operator's stream that is read all along.
    let mut reader = tokio::net::TcpStream::connect(addr).await.unwrap();
    assert_eq!(
        status_of(&mut reader, &events_head(OPERATOR)).await,
        Some(200)
    );
    let (got_tx, mut got) = tokio::sync::mpsc::unbounded_channel::<usize>();
    let read_all = tokio::spawn(async move {
        let mut buf = [0u8; 4096];
        loop {
            match reader.read(&mut buf).await {
                Ok(n) if n > 0 => {
                    let _ = got_tx.send(n);
                }
                _ => return,
            }
        }
    });
    // The viewer's one stream is taken by the unread one.
    let mut second = tokio::net::TcpStream::connect(addr).await.unwrap();
    let mut freed = status_of(&mut second, &events_head(VIEWER)).await == Some(200);
    assert!(
        !freed,
        "the share of 1 stream was not held by the unread stream"
    );
    // Events until the unread stream's buffers are full and it is cut: its share is then
    // free again.
    let mut jobs = 0;
    for _ in 0..200 {
        for _ in 0..5 {
            s.submit(&calibd::jobs::examples::twin_fk(1)).await;
            jobs += 1;
        }
        let mut c = tokio::net::TcpStream::connect(addr).await.unwrap();
        if status_of(&mut c, &events_head(VIEWER)).await == Some(200) {
            freed = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    eprintln!("unread stream cut after {jobs} jobs' events");
    assert!(freed, "the unread stream was never disconnected");
    assert!(
        closed_by_server(&mut stalled, Duration::from_secs(30)).await,
        "the unread stream is still open"
    );
    // The stream that was read is still served: it gets the next job's events.
    while got.try_recv().is_ok() {}
    s.submit(&calibd::jobs::examples::twin_fk(1)).await;
    let n = tokio::time::timeout(Duration::from_secs(30), got.recv()).await;
    assert!(
        matches!(n, Ok(Some(k)) if k > 0),
        "the read stream was cut too"
    );
    read_all.abort();
}

/// A 600-byte URDF whose joints form a cycle (`a -> b -> a`) once walked the graph forever
/// until the allocator aborted the daemon (issue 28). It is refused at submission with the
/// joints named; the daemon stays up; `calibd run` on the same file exits non-zero at once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_model_whose_joints_form_a_cycle_is_refused_not_walked() {
    let urdf = r#"<robot name="loop">
  <link name="base"/><link name="a"/><link name="b"/>
  <joint name="j_ab" type="revolute"><parent link="a"/><child link="b"/>
    <axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="j_ba" type="revolute"><parent link="b"/><child link="a"/>
    <axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>"#;
    let job = json!({"kind": "serial.fk", "model": urdf,
        "chain": {"root": "base", "tip": "b"}, "joints": [{"q1": 0, "q2": 0}]});
    let s = start(|_| {}).await;
    let r = s
        .req(Method::POST, "/v1/jobs", Some(OPERATOR))
        .json(&job)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 422);
    let e: Value = r.json().await.unwrap();
    let m = e["error"]["message"].as_str().unwrap();
    assert!(
        m.contains("cycle") && m.contains("`j_ab`") && m.contains("`j_ba`"),
        "{m}"
    );
    assert_eq!(s.get("/v1/health").await.0, 200, "the daemon is still up");

    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("loop.json");
    std::fs::write(&file, job.to_string()).unwrap();
    let out = tokio::process::Command::new(env!("CARGO_BIN_EXE_calibd"))
        .arg("run")
        .arg(&file)
        .current_dir(dir.path())
        .kill_on_drop(true)
        .output();
    // Bounded so a regression fails the test instead of hanging CI (not a timing assertion).
    let out = tokio::time::timeout(Duration::from_secs(120), out)
        .await
        .expect("calibd run returns")
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("cycle") && err.contains("`j_ab`") && err.contains("`j_ba`"),
        "{err}"
    );
}
