//! The HTTP API under `/v1` (axum): one router per resource, merged by [`app`]; bearer
//! authentication ([`auth`]); Server-Sent Events for live progress ([`events`]); the web
//! page ([`web`]); `/openapi.yaml` (the contract, `openapi.yaml` at the repository root)
//! and `/metrics`. The API knows the job service and the store, not models.

pub mod auth;
mod datasets;
mod error;
pub mod events;
mod jobs;
mod schedules;
mod system;
pub mod web;

use std::future::Future;
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use axum::Router;
use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::{DefaultBodyLimit, MatchedPath, Request};
use axum::middleware::{self, Next};
use axum::response::Response;
use metrics_exporter_prometheus::{PrometheusBuilder, PrometheusHandle};
use tokio::net::TcpListener;
use tower_http::timeout::TimeoutLayer;
use tower_http::trace::TraceLayer;

pub use auth::{Auth, Caller, Role};
pub use error::ApiError;

use crate::schedule::Scheduler;
use crate::service::Service;

/// The contract, served at `/openapi.yaml`.
pub const OPENAPI_YAML: &str = include_str!("../../openapi.yaml");

/// Everything handlers need; cheap to clone.
#[derive(Debug, Clone)]
pub struct AppState {
    /// The job service.
    pub service: Service,
    /// The scheduler (schedules CRUD tells it to reload).
    pub scheduler: Scheduler,
    /// Known tokens.
    pub auth: Arc<Auth>,
    /// Largest request body.
    pub max_body_bytes: usize,
    /// Time limit for a response.
    pub request_timeout: Duration,
    /// Prometheus text renderer.
    pub metrics: Option<PrometheusHandle>,
    /// Cancelled at shutdown: ends event streams so the server can drain.
    pub shutdown: tokio_util::sync::CancellationToken,
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
    let v1 = Router::new()
        .merge(jobs::router())
        .merge(datasets::router())
        .merge(schedules::router())
        .merge(events::router())
        .merge(system::router());
    Router::new()
        .nest("/v1", v1)
        .merge(system::root_router())
        .merge(web::router())
        .route_layer(middleware::from_fn(track))
        .layer(DefaultBodyLimit::max(limit))
        .layer(TimeoutLayer::with_status_code(
            axum::http::StatusCode::SERVICE_UNAVAILABLE,
            timeout,
        ))
        .layer(TraceLayer::new_for_http())
        .with_state(state)
}

/// Request metrics by route template (never by raw path).
async fn track(req: Request, next: Next) -> Response {
    let t0 = Instant::now();
    let path = req
        .extensions()
        .get::<MatchedPath>()
        .map(|p| p.as_str().to_owned())
        .unwrap_or_else(|| "unmatched".into());
    let method = req.method().to_string();
    let res = next.run(req).await;
    let status = res.status().as_u16().to_string();
    metrics::counter!("calibd_http_requests_total", "method" => method.clone(), "path" => path.clone(), "status" => status).increment(1);
    metrics::histogram!("calibd_http_request_duration_seconds", "method" => method, "path" => path)
        .record(t0.elapsed().as_secs_f64());
    res
}

/// Serve `app` on an already-bound listener until `shutdown` completes.
pub async fn run(
    listener: TcpListener,
    router: Router,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    axum::serve(listener, router)
        .with_graceful_shutdown(shutdown)
        .await
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

/// Run blocking store work off the runtime.
pub(crate) async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> Result<T, crate::store::StoreError> + Send + 'static,
) -> Result<T, ApiError> {
    tokio::task::spawn_blocking(f)
        .await
        .map_err(|e| ApiError::Internal(e.to_string()))?
        .map_err(ApiError::from)
}
