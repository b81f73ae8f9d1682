//! `/v1/datasets`: upload an input (CSV table, model file) once and reference it by id in
//! jobs. The id is the SHA-256 of the content, so uploading twice gives the same id.

use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::{Path, Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use serde::Deserialize;
use serde_json::{Value, json};

use super::{ApiError, AppState, Caller, Role, blocking, body};

pub(super) fn router() -> Router<AppState> {
    Router::new()
        .route("/datasets", get(list).post(upload))
        .route("/datasets/{id}", get(one))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct UploadQuery {
    name: Option<String>,
}

async fn upload(
    State(s): State<AppState>,
    caller: Caller,
    headers: HeaderMap,
    q: Result<Query<UploadQuery>, axum::extract::rejection::QueryRejection>,
    b: Result<Bytes, BytesRejection>,
) -> Result<Response, ApiError> {
    caller.require(Role::Submitter)?;
    let Query(q) = q?;
    let b = body(&s, b)?;
    if b.is_empty() {
        return Err(ApiError::BadRequest("the dataset is empty".into()));
    }
    let media_type = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("application/octet-stream")
        .to_string();
    let name = q.name.unwrap_or_else(|| "dataset".into());
    let st = s.service.store().clone();
    let info = blocking(move || st.put_dataset(&name, &media_type, &b)).await?;
    Ok((StatusCode::CREATED, Json(info)).into_response())
}

async fn list(State(s): State<AppState>, caller: Caller) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    let st = s.service.store().clone();
    let all = blocking(move || st.datasets()).await?;
    Ok(Json(json!({"datasets": all})))
}

async fn one(
    State(s): State<AppState>,
    caller: Caller,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    caller.require_read()?;
    let st = s.service.store().clone();
    let i = id.clone();
    let (info, content) = blocking(move || Ok((st.dataset_info(&i)?, st.dataset(&i)?))).await?;
    match (info, content) {
        (Some(info), Some(c)) => Ok(([(header::CONTENT_TYPE, info.media_type)], c).into_response()),
        _ => Err(ApiError::NotFound(format!("no dataset with id {id}"))),
    }
}
