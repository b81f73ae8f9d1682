//! The HTTP client behind `calibd submit`, `watch`, `jobs`, `cancel`, `result` and `health`, also
//! used by the integration tests and the load benchmark. Job files are sent as they are,
//! except that a top-level string naming a file next to the job file is uploaded as a
//! dataset and replaced by the dataset's id (over HTTP inputs are inline or dataset ids).

pub mod commands;
pub mod job_file;
pub mod sse;
pub mod summary;

use std::path::{Path, PathBuf};

use futures_util::StreamExt;
use serde_json::Value;

pub use sse::{SseMessage, SseParser};

/// Why a client call failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ClientError {
    /// The daemon could not be reached.
    #[error("client: cannot reach {url}: {message}")]
    Connect {
        /// The URL.
        url: String,
        /// Why.
        message: String,
    },
    /// The daemon answered with an error.
    #[error("client: {status}: {message}")]
    Api {
        /// HTTP status.
        status: u16,
        /// The error message of the body.
        message: String,
    },
    /// A local file could not be read or written.
    #[error("client: {path}: {message}")]
    File {
        /// The path.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// The answer was not what the API promises.
    #[error("client: unexpected answer: {0}")]
    Protocol(String),
}

/// Why a request to `base` got no answer, with the cause and, when nothing listens, the
/// likely fix.
fn connect_message(base: &str, e: &reqwest::Error) -> String {
    let mut text = e.to_string();
    let mut source = std::error::Error::source(e);
    while let Some(s) = source {
        let said = s.to_string();
        if !text.contains(&said) {
            text.push_str(": ");
            text.push_str(&said);
        }
        source = s.source();
    }
    if e.is_connect() {
        format!(
            "is `calibd serve` running at {base}? (start it, or point --server / CALIBD_URL at it; {text})"
        )
    } else {
        text
    }
}

/// How often `submit` sends a submission again when its answer was lost.
const SUBMIT_RETRIES: u32 = 4;

/// Errors after which the request may or may not have been carried out: the daemon was
/// unreachable or went away mid-answer, or was not ready.
fn retryable(e: &ClientError) -> bool {
    matches!(e, ClientError::Connect { .. } | ClientError::Protocol(_))
        || matches!(
            e,
            ClientError::Api {
                status: 502..=504,
                ..
            }
        )
}

/// A connection to a daemon.
#[derive(Debug, Clone)]
pub struct Client {
    base: String,
    token: Option<String>,
    /// Where a token was looked for when none was found (said with a 401).
    token_search: Option<String>,
    http: reqwest::Client,
}

impl Client {
    /// A client for the daemon at `base` (e.g. `http://127.0.0.1:8750`).
    pub fn new(base: &str, token: Option<String>) -> Client {
        Client {
            base: base.trim_end_matches('/').to_string(),
            token,
            token_search: None,
            http: reqwest::Client::new(),
        }
    }

    /// Say where a token was looked for (when none was found): a refused request (401)
    /// then names those places.
    pub fn with_token_search(mut self, places: String) -> Client {
        self.token_search = Some(places);
        self
    }

    /// Where [`Client::find_token`] looks, as a sentence for messages.
    pub fn token_places(data_dir: &Path) -> String {
        format!(
            "--token, the CALIBD_TOKEN variable, and {} (the daemon's data folder: --data or CALIBD_DATA)",
            data_dir.join("operator.token").display()
        )
    }

    /// The token from `CALIBD_TOKEN`-style value or the daemon's `DATA/operator.token`.
    pub fn find_token(explicit: Option<String>, data_dir: &Path) -> Option<String> {
        explicit.filter(|t| !t.trim().is_empty()).or_else(|| {
            std::fs::read_to_string(data_dir.join("operator.token"))
                .ok()
                .map(|t| t.trim().to_string())
                .filter(|t| !t.is_empty())
        })
    }

    pub(crate) fn url(&self, path: &str) -> String {
        format!("{}{}", self.base, path)
    }

    pub(crate) fn req(&self, m: reqwest::Method, path: &str) -> reqwest::RequestBuilder {
        let r = self.http.request(m, self.url(path));
        match &self.token {
            Some(t) => r.bearer_auth(t),
            None => r,
        }
    }

    pub(crate) async fn send(
        &self,
        r: reqwest::RequestBuilder,
    ) -> Result<reqwest::Response, ClientError> {
        let res = r.send().await.map_err(|e| ClientError::Connect {
            url: self.base.clone(),
            message: connect_message(&self.base, &e),
        })?;
        if res.status().is_success() {
            return Ok(res);
        }
        let status = res.status().as_u16();
        let text = res.text().await.unwrap_or_default();
        let message = serde_json::from_str::<Value>(&text)
            .ok()
            .and_then(|v| {
                v.pointer("/error/message")
                    .and_then(Value::as_str)
                    .map(String::from)
            })
            .unwrap_or(text);
        let message = match (&self.token, &self.token_search) {
            (None, Some(places)) if status == 401 => {
                format!("{message}; no token was found: looked in {places}")
            }
            (Some(_), _) if status == 401 => format!(
                "{message}; the daemon refused the token: use its operator token (the file \
                 operator.token in its data folder) or one made by `calibd token` and listed \
                 under [[auth.tokens]] in its settings"
            ),
            _ => message,
        };
        Err(ClientError::Api { status, message })
    }

    async fn json(&self, r: reqwest::RequestBuilder) -> Result<Value, ClientError> {
        self.send(r)
            .await?
            .json()
            .await
            .map_err(|e| ClientError::Protocol(e.to_string()))
    }

    /// GET a JSON document.
    pub async fn get(&self, path: &str) -> Result<Value, ClientError> {
        self.json(self.req(reqwest::Method::GET, path)).await
    }

    /// GET raw bytes.
    pub async fn get_bytes(&self, path: &str) -> Result<Vec<u8>, ClientError> {
        let res = self.send(self.req(reqwest::Method::GET, path)).await?;
        Ok(res
            .bytes()
            .await
            .map_err(|e| ClientError::Protocol(e.to_string()))?
            .to_vec())
    }

    /// Submit a job document; returns the job id. The submission carries a fresh
    /// `Idempotency-Key`, and a submission whose answer was lost (connection reset, daemon
    /// restarting, 503) is sent again with the same key, so the daemon never runs it twice.
    pub async fn submit(&self, doc: &Value, priority: i64) -> Result<i64, ClientError> {
        let key =
            crate::api::auth::new_token().map_err(|e| ClientError::Protocol(e.to_string()))?;
        let mut attempt = 0u32;
        let v = loop {
            let r = self
                .req(
                    reqwest::Method::POST,
                    &format!("/v1/jobs?priority={priority}"),
                )
                .header("Idempotency-Key", &key)
                .json(doc);
            match self.json(r).await {
                Err(e) if attempt < SUBMIT_RETRIES && retryable(&e) => {
                    attempt += 1;
                    tracing::warn!(attempt, error = %e, "submit: no answer; retrying with the same Idempotency-Key");
                    tokio::time::sleep(std::time::Duration::from_millis(250 << attempt)).await;
                }
                other => break other?,
            }
        };
        v["id"]
            .as_i64()
            .ok_or_else(|| ClientError::Protocol(format!("no id in {v}")))
    }

    /// A dry run of a job document (`POST /v1/jobs?dry_run=true`): the daemon's answer with
    /// a campaign's plan, envelope check and estimated duration; nothing is submitted.
    pub async fn dry_run(&self, doc: &Value) -> Result<Value, ClientError> {
        self.json(
            self.req(reqwest::Method::POST, "/v1/jobs?dry_run=true")
                .json(doc),
        )
        .await
    }

    /// Upload a dataset; returns its id.
    pub async fn upload(
        &self,
        name: &str,
        media_type: &str,
        content: Vec<u8>,
    ) -> Result<String, ClientError> {
        let q: String = name
            .bytes()
            .map(|b| {
                if b.is_ascii_alphanumeric() || b"-._~".contains(&b) {
                    (b as char).to_string()
                } else {
                    format!("%{b:02X}")
                }
            })
            .collect();
        let v = self
            .json(
                self.req(reqwest::Method::POST, &format!("/v1/datasets?name={q}"))
                    .header(reqwest::header::CONTENT_TYPE, media_type)
                    .body(content),
            )
            .await?;
        v["id"]
            .as_str()
            .map(String::from)
            .ok_or_else(|| ClientError::Protocol(format!("no id in {v}")))
    }

    /// Read a job file, upload the files it names (at any depth, see
    /// [`job_file::file_references`]), and return the document to submit.
    pub async fn load_job_file(&self, path: &Path) -> Result<Value, ClientError> {
        let file_err = |p: &Path, m: String| ClientError::File {
            path: p.to_path_buf(),
            message: m,
        };
        let text = std::fs::read_to_string(path).map_err(|e| file_err(path, e.to_string()))?;
        let mut doc: Value = serde_json::from_str(&text)
            .map_err(|e| file_err(path, format!("not valid JSON: {e}")))?;
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        let (found, missing) = job_file::file_references(&doc, &dir);
        if !missing.is_empty() {
            return Err(file_err(
                path,
                format!(
                    "names files that do not exist (paths are relative to the job file's folder): {}",
                    missing.join(", ")
                ),
            ));
        }
        // One upload per file, however often the document names it.
        let mut ids: std::collections::HashMap<PathBuf, String> = Default::default();
        for r in found {
            let id = match ids.get(&r.path) {
                Some(id) => id.clone(),
                None => {
                    let p = &r.path;
                    let content = std::fs::read(p).map_err(|e| file_err(p, e.to_string()))?;
                    let name = p.file_name().and_then(|n| n.to_str()).unwrap_or("input");
                    let id = self.upload(name, job_file::media_type(p), content).await?;
                    ids.insert(r.path.clone(), id.clone());
                    id
                }
            };
            if let Some(v) = doc.pointer_mut(&r.pointer) {
                *v = Value::String(id);
            }
        }
        Ok(doc)
    }

    /// Follow a job's events until it reaches a final state; `on_event` sees each one.
    /// Returns the final job record.
    pub async fn watch(
        &self,
        id: i64,
        mut on_event: impl FnMut(&SseMessage),
    ) -> Result<Value, ClientError> {
        let res = self
            .send(self.req(reqwest::Method::GET, &format!("/v1/jobs/{id}/events")))
            .await?;
        let mut stream = res.bytes_stream();
        let mut parser = SseParser::default();
        while let Some(chunk) = stream.next().await {
            let chunk = chunk.map_err(|e| ClientError::Connect {
                url: self.base.clone(),
                message: e.to_string(),
            })?;
            for m in parser.push(&chunk) {
                on_event(&m);
            }
        }
        self.get(&format!("/v1/jobs/{id}")).await
    }
}

/// Whether a job file's string value names a file (a path or a known extension) rather
/// than a dataset id or an inline value.
pub fn looks_like_file(s: &str) -> bool {
    let s = s.trim();
    if s.is_empty() || s.contains('\n') {
        return false;
    }
    let ext = Path::new(s)
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    s.contains('/')
        || s.contains('\\')
        || ext.is_some_and(|e| job_file::FILE_EXTENSIONS.contains(&e.as_str()))
}

/// A text progress bar line: `[#####.....]  50.0 % stage`.
pub fn progress_line(fraction: f64, stage: &str) -> String {
    let f = if fraction.is_finite() {
        fraction.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let n = (f * 30.0).round() as usize;
    format!(
        "[{}{}] {:5.1} % {}",
        "#".repeat(n),
        ".".repeat(30 - n),
        100.0 * f,
        stage
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn an_absent_daemon_is_named_with_the_fix() {
        // A port nothing listens on.
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map(|a| a.port())
            .unwrap();
        let c = Client::new(&format!("http://127.0.0.1:{port}"), None);
        let e = c.get("/v1/health").await.unwrap_err().to_string();
        assert!(
            e.contains(&format!("cannot reach http://127.0.0.1:{port}"))
                && e.contains(&format!(
                    "is `calibd serve` running at http://127.0.0.1:{port}?"
                ))
                && e.to_ascii_lowercase().contains("refused"),
            "{e}"
        );
    }

    #[test]
    fn progress_line_fills_in_proportion() {
        assert_eq!(
            progress_line(0.5, "lm"),
            format!("[{}{}]  50.0 % lm", "#".repeat(15), ".".repeat(15))
        );
        assert!(progress_line(f64::NAN, "x").contains("  0.0 %"));
    }

    #[test]
    fn the_watch_message_puts_the_eta_first() {
        let m = commands::bar_message(
            "centring",
            Some("configuration 12/45 (ball 2): 11 recorded, 0 skipped, ETA 40 s"),
        );
        assert_eq!(
            m,
            "ETA 40 s · centring: configuration 12/45 (ball 2): 11 recorded, 0 skipped"
        );
        // Bar (32 columns), percentage (5) and the ETA fit well inside 80 columns: a
        // narrow terminal cuts the detail after them.
        let head = format!("[{}] 100% {}", "#".repeat(30), &m[..m.find('·').unwrap()]);
        assert!(head.chars().count() < 60, "{head}");
        assert_eq!(commands::bar_message("lm", None), "lm");
        assert_eq!(
            commands::bar_message("lm", Some("iteration 3")),
            "lm: iteration 3"
        );
    }

    #[test]
    fn file_names_are_told_from_dataset_ids() {
        assert!(looks_like_file("measurements.csv"));
        assert!(looks_like_file("../data/robots/irb120.json"));
        assert!(!looks_like_file(&"ab".repeat(32)));
        assert!(!looks_like_file("square"));
        assert!(!looks_like_file("<robot name=\"x\">\n</robot>"));
    }
}
