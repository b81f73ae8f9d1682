//! Shared helpers of the daemon's integration tests: an in-process daemon on port 0 with
//! known tokens, and a small JSON-schema checker for the OpenAPI contract.
#![allow(dead_code, unreachable_pub)]

pub mod schema;

use std::time::Duration;

use calibd::api::Role;
use calibd::config::{Config, TokenConfig};
use serde_json::Value;
use tokio_util::sync::CancellationToken;

pub const VIEWER: &str = "viewer-token-0000000000000000";
pub const SUBMITTER: &str = "submitter-token-111111111111";
pub const OPERATOR: &str = "operator-token-22222222222222";

/// A daemon running inside the test process.
pub struct TestServer {
    pub url: String,
    pub dir: tempfile::TempDir,
    pub http: reqwest::Client,
    stop: CancellationToken,
}

impl Drop for TestServer {
    fn drop(&mut self) {
        self.stop.cancel();
    }
}

fn token(name: &str, role: Role, t: &str) -> TokenConfig {
    TokenConfig {
        name: name.into(),
        role,
        sha256: calibd::api::auth::hash_token(t),
    }
}

/// Start a daemon with three tokens (viewer, submitter, operator); `tweak` edits the config.
pub async fn start(tweak: impl FnOnce(&mut Config)) -> TestServer {
    let dir = tempfile::tempdir().unwrap();
    let mut config = Config {
        data: dir.path().to_path_buf(),
        workers: 2,
        ..Config::default()
    };
    config.auth.tokens = vec![
        token("vera", Role::Viewer, VIEWER),
        token("sam", Role::Submitter, SUBMITTER),
        token("olga", Role::Operator, OPERATOR),
    ];
    tweak(&mut config);
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let stop = CancellationToken::new();
    let (state, _workers, _) =
        calibd::server::start(&config, calibd::schedule::Clock::system(), stop.clone())
            .await
            .unwrap();
    let s = stop.clone();
    tokio::spawn(calibd::api::run(listener, state, async move {
        s.cancelled().await
    }));
    TestServer {
        url: format!("http://{addr}"),
        dir,
        http: reqwest::Client::new(),
        stop,
    }
}

impl TestServer {
    pub fn req(
        &self,
        m: reqwest::Method,
        path: &str,
        token: Option<&str>,
    ) -> reqwest::RequestBuilder {
        let r = self.http.request(m, format!("{}{}", self.url, path));
        match token {
            Some(t) => r.bearer_auth(t),
            None => r,
        }
    }

    pub async fn get(&self, path: &str) -> (u16, Value) {
        let r = self
            .req(reqwest::Method::GET, path, Some(VIEWER))
            .send()
            .await
            .unwrap();
        let s = r.status().as_u16();
        (s, r.json().await.unwrap_or(Value::Null))
    }

    pub async fn submit(&self, doc: &Value) -> i64 {
        let r = self
            .req(reqwest::Method::POST, "/v1/jobs", Some(SUBMITTER))
            .json(doc)
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 201);
        r.json::<Value>().await.unwrap()["id"].as_i64().unwrap()
    }

    /// Wait until the job is final; returns the job.
    pub async fn wait(&self, id: i64) -> Value {
        for _ in 0..3000 {
            let (_, j) = self.get(&format!("/v1/jobs/{id}")).await;
            if !matches!(j["state"].as_str(), Some("queued") | Some("running")) {
                return j;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        panic!("job {id} did not finish");
    }
}
