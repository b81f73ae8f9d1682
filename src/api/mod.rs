//! The HTTP API under `/v1` (axum): one router per resource, merged by [`app`]; bearer
//! authentication ([`auth`]); Server-Sent Events for live progress ([`events`]); the web
//! page ([`web`]); `/openapi.yaml` (the contract, `openapi.yaml` at the repository root)
//! and `/metrics`. The API knows the job service and the store, not models.

pub mod auth;
pub mod budget;
mod conn;
mod datasets;
mod error;
pub mod events;
mod guard;
mod jobs;
mod report;
mod schedules;
mod system;
mod track;
pub mod web;

use std::future::Future;
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use axum::Router;
use axum::body::Bytes;
use axum::extract::DefaultBodyLimit;
use axum::extract::rejection::BytesRejection;
use metrics_exporter_prometheus::{PrometheusBuilder, PrometheusHandle};
use tokio::net::TcpListener;
use tower_http::timeout::TimeoutLayer;
use tower_http::trace::TraceLayer;

pub use auth::{Auth, Caller, Role};
pub use conn::{Peer, ServeLimits};
pub use error::ApiError;

use crate::schedule::Scheduler;
use crate::service::Service;

/// The contract, served at `/openapi.yaml`.
pub const OPENAPI_YAML: &str = include_str!("../../openapi.yaml");

/// Everything handlers need, behind one `Arc`: axum clones the router's state for every
/// request, so a clone is one reference count, not one per field.
#[derive(Debug, Clone)]
pub struct AppState(Arc<AppShared>);

impl AppState {
    /// The state handlers share.
    pub fn new(shared: AppShared) -> Self {
        Self(Arc::new(shared))
    }
}

impl std::ops::Deref for AppState {
    type Target = AppShared;

    fn deref(&self) -> &AppShared {
        &self.0
    }
}

/// What [`AppState`] holds.
#[derive(Debug)]
pub struct AppShared {
    /// The job service.
    pub service: Service,
    /// The scheduler (schedules CRUD tells it to reload).
    pub scheduler: Scheduler,
    /// Known tokens.
    pub auth: Arc<Auth>,
    /// Largest request body.
    pub max_body_bytes: usize,
    /// Bytes of request bodies in flight at once, over all clients.
    pub body_budget: budget::BodyBudget,
    /// Time limit for a response.
    pub request_timeout: Duration,
    /// Connection limits of the server.
    pub limits: ServeLimits,
    /// Event streams open per token (per address without a token).
    pub(crate) event_streams: Arc<conn::Shares<String>>,
    /// Host names the API answers to (normalised: lowercase, no brackets; `*` = any).
    pub allowed_hosts: Arc<[String]>,
    /// Shortest interval between two occurrences of a schedule.
    pub min_schedule_interval: Duration,
    /// Prometheus text renderer.
    pub metrics: Option<PrometheusHandle>,
    /// Cancelled at shutdown: ends event streams so the server can drain.
    pub shutdown: tokio_util::sync::CancellationToken,
    /// The daemon's lock on its SQLite data folder, held while the server runs.
    pub(crate) _data_lock: Option<crate::store::DataLock>,
}

/// The process-wide Prometheus recorder (installed once; later calls reuse it).
pub fn metrics_handle() -> Option<PrometheusHandle> {
    static HANDLE: OnceLock<Option<PrometheusHandle>> = OnceLock::new();
    HANDLE
        .get_or_init(|| PrometheusBuilder::new().install_recorder().ok())
        .clone()
}

/// The whole application.
pub fn app(state: AppState) -> Router {
    let limit = state.max_body_bytes;
    let timeout = state.request_timeout;
    // The resources' routes carry their `/v1` prefix (a `nest` would rebuild every
    // request's URI to strip it).
    Router::new()
        .merge(jobs::router())
        .merge(datasets::router())
        .merge(schedules::router())
        .merge(events::router())
        .merge(system::router())
        .merge(system::root_router())
        .merge(web::router())
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
        // One layer of four (outermost first), so a request clones one boxed stack per
        // route, not one per layer.
        .layer((
            TraceLayer::new_for_http(),
            TimeoutLayer::with_status_code(axum::http::StatusCode::SERVICE_UNAVAILABLE, timeout),
            DefaultBodyLimit::max(limit),
            guard::GuardLayer::new(state.clone()),
        ))
        .with_state(state)
}

/// A path no route matches: the JSON error body, like every other error.
async fn not_found(uri: axum::http::Uri) -> ApiError {
    ApiError::NotFound(format!("no resource at {}", uri.path()))
}

/// A method the route does not have.
async fn method_not_allowed(method: axum::http::Method, uri: axum::http::Uri) -> ApiError {
    ApiError::MethodNotAllowed(format!("{method} is not allowed on {}", uri.path()))
}

/// The host name of a `Host` header or URI authority: lowercase, without port, brackets or
/// a trailing dot.
pub fn host_name(authority: &str) -> String {
    host_part(authority).to_ascii_lowercase()
}

/// The host name of an authority as written (any case), without port, brackets or a
/// trailing dot: [`host_name`] without the copy, for the per-request Host check.
fn host_part(authority: &str) -> &str {
    let a = authority.trim();
    let host = if let Some(rest) = a.strip_prefix('[') {
        rest.split(']').next().unwrap_or(rest)
    } else {
        match a.rsplit_once(':') {
            Some((h, port)) if port.bytes().all(|b| b.is_ascii_digit()) && !h.contains(':') => h,
            _ => a,
        }
    };
    host.trim_end_matches('.')
}

/// The Content-Security-Policy of every response: the page's own script and style only;
/// plots are shown from `blob:` URLs the script makes; API calls go to the same origin.
pub const CSP: &str = "default-src 'none'; script-src 'self'; style-src 'self'; \
img-src 'self' blob: data:; connect-src 'self'; base-uri 'none'; form-action 'none'; \
frame-ancestors 'none'";

/// The per-token event stream counts for `limits`.
pub(crate) fn event_stream_shares(limits: &ServeLimits) -> Arc<conn::Shares<String>> {
    conn::Shares::new(limits.max_event_streams_per_token.max(1))
}

/// Serve the application on an already-bound listener, with the state's connection
/// limits, until `shutdown` completes.
pub async fn run(
    listener: TcpListener,
    state: AppState,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let limits = state.limits;
    conn::serve(listener, app(state), limits, shutdown).await
}

/// The body of a request, with the size limit turned into a clear 413.
pub(crate) fn body(state: &AppState, b: Result<Bytes, BytesRejection>) -> Result<Bytes, ApiError> {
    b.map_err(|r| match ApiError::from(r) {
        ApiError::TooLarge(_) => ApiError::TooLarge(state.max_body_bytes),
        other => other,
    })
}

/// A JSON body, with parse errors naming line and column.
pub(crate) fn json_body(
    state: &AppState,
    b: Result<Bytes, BytesRejection>,
) -> Result<serde_json::Value, ApiError> {
    let b = body(state, b)?;
    serde_json::from_slice(&b)
        .map_err(|e| ApiError::BadRequest(format!("the body is not valid JSON: {e}")))
}

/// A path parameter whose rejection is the API's JSON error (axum's own is plain text).
#[derive(Debug)]
pub(crate) struct ApiPath<T>(pub T);

impl<T, S> axum::extract::FromRequestParts<S> for ApiPath<T>
where
    T: serde::de::DeserializeOwned + Send,
    S: Send + Sync,
{
    type Rejection = ApiError;

    async fn from_request_parts(
        parts: &mut axum::http::request::Parts,
        state: &S,
    ) -> Result<Self, ApiError> {
        axum::extract::Path::<T>::from_request_parts(parts, state)
            .await
            .map(|axum::extract::Path(t)| ApiPath(t))
            .map_err(ApiError::from)
    }
}

/// `attachment; filename="..."` with the name reduced to safe characters.
pub(crate) fn attachment(name: &str) -> String {
    let safe: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "._-".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect();
    format!("attachment; filename=\"{safe}\"")
}

/// Longest dataset or schedule name, in characters.
pub(crate) const MAX_NAME_CHARS: usize = 200;

/// A name (`field` names it in the error): non-empty, bounded, printable.
pub(crate) fn check_name(field: &str, name: &str) -> Result<(), ApiError> {
    let n = name.chars().count();
    if n > MAX_NAME_CHARS {
        return Err(ApiError::BadRequest(format!(
            "`{field}` has {n} characters; at most {MAX_NAME_CHARS} are allowed"
        )));
    }
    if name.is_empty() || name.chars().any(char::is_control) {
        return Err(ApiError::BadRequest(format!(
            "`{field}` must be non-empty and hold no control characters"
        )));
    }
    Ok(())
}
