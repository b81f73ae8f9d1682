//! Health, version, job kinds, example jobs, device status, `/metrics` and `/openapi.yaml`.

use axum::extract::State;
use axum::http::header;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use serde_json::{Value, json};

use super::{ApiError, ApiPath, AppState, Caller, OPENAPI_YAML};
use crate::jobs::{KINDS, envelope::VERSION, examples};

pub(super) fn router() -> Router<AppState> {
    Router::new()
        .route("/v1/health", get(health))
        .route("/v1/version", get(version))
        .route("/v1/kinds", get(kinds))
        .route("/v1/examples", get(example_list))
        .route("/v1/examples/{name}", get(example))
        .route("/v1/devices", get(devices))
        .route("/v1/cells", get(cells))
        .route("/v1/cells/{name}/indicators", get(indicators))
        .route("/v1/cells/{name}/drift", get(drift))
        .route("/v1/lab", get(lab))
}

pub(super) fn root_router() -> Router<AppState> {
    Router::new()
        .route("/openapi.yaml", get(openapi))
        .route("/metrics", get(metrics))
}

async fn health(State(s): State<AppState>) -> Json<Value> {
    Json(json!({
        "status": "ok",
        "queue_depth": s.service.queue_depth(),
        "running": s.service.running_count(),
    }))
}

async fn version() -> Json<Value> {
    Json(json!({
        "calibd_version": VERSION,
        "api": "v1",
        "schema_version": crate::store::SCHEMA_VERSION,
    }))
}

async fn kinds(caller: Caller) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    let k: Vec<Value> = KINDS
        .iter()
        .map(|k| json!({"kind": k.name, "description": k.description}))
        .collect();
    Ok(Json(json!({"kinds": k})))
}

async fn example_list(caller: Caller) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    let e: Vec<Value> = examples::EXAMPLES
        .iter()
        .map(|(name, d)| json!({"name": name, "description": d}))
        .collect();
    Ok(Json(json!({"examples": e})))
}

async fn example(caller: Caller, ApiPath(name): ApiPath<String>) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    let doc = tokio::task::spawn_blocking(move || examples::example(&name).ok_or(name))
        .await
        .map_err(|e| ApiError::Internal(e.to_string()))?
        .map_err(|name| ApiError::NotFound(format!("no example named `{name}`")))?;
    Ok(Json(doc))
}

async fn devices(State(s): State<AppState>, caller: Caller) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    Ok(Json(json!({"devices": s.service.devices()})))
}

async fn cells(State(s): State<AppState>, caller: Caller) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    Ok(Json(json!({"cells": s.service.cells().await?})))
}

/// A ball-centring cell's verifications (AP, RP) against its last calibration, with the
/// drift chart as SVG.
async fn drift(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(name): ApiPath<String>,
) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    s.service
        .lab()
        .trical(&name)
        .map_err(|e| ApiError::NotFound(e.to_string()))?;
    let h = s.service.drift_history(&name).await?;
    let svg = h.chart();
    let mut v = serde_json::to_value(&h).map_err(|e| ApiError::Internal(e.to_string()))?;
    v["svg"] = Value::String(svg);
    Ok(Json(v))
}

/// One fresh reading of a ball-centring cell's three indicators (mm, or why there is
/// none): the page shows them live while a commissioning step waits for the operator.
async fn indicators(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(name): ApiPath<String>,
) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    let cell = s
        .service
        .lab()
        .trical(&name)
        .map_err(|e| ApiError::NotFound(e.to_string()))?;
    let read = tokio::time::timeout(std::time::Duration::from_secs(1), cell.indicators.read());
    let (reading, error) = match read.await {
        Ok(Ok(v)) => (Some(v), None),
        Ok(Err(e)) => (None, Some(e.to_string())),
        Err(_) => (None, Some("no reading within 1 s".to_string())),
    };
    Ok(Json(
        json!({"cell": name, "reading_mm": reading, "error": error}),
    ))
}

/// `GET /v1/lab` query: `refresh=true` probes every device now instead of returning the
/// background check's last results.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct LabQuery {
    #[serde(default)]
    refresh: bool,
}

async fn lab(
    State(s): State<AppState>,
    caller: Caller,
    q: Result<axum::extract::Query<LabQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    let axum::extract::Query(q) = q?;
    let lab = s.service.lab();
    let devices = if q.refresh {
        lab.check(std::time::Duration::from_secs(3)).await
    } else {
        lab.reports()
    };
    let cells: Vec<Value> = lab
        .cells()
        .map(|c| {
            json!({
                "name": c.name(),
                "kind": c.kind(),
                "available": lab.unavailable(c.name()).is_none(),
                "reason": lab.unavailable(c.name()),
            })
        })
        .collect();
    Ok(Json(
        json!({"simulated": lab.is_simulated(), "cells": cells, "devices": devices}),
    ))
}

async fn openapi() -> Response {
    ([(header::CONTENT_TYPE, "application/yaml")], OPENAPI_YAML).into_response()
}

async fn metrics(State(s): State<AppState>, caller: Caller) -> Result<Response, ApiError> {
    caller.require_read()?;
    // Refresh the device gauges.
    s.service.devices();
    let text =
        s.metrics.as_ref().map(|h| h.render()).ok_or_else(|| {
            ApiError::Unavailable("metrics are not enabled in this process".into())
        })?;
    Ok(([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], text).into_response())
}
