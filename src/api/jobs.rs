//! `/v1/jobs`: submit, list, get, cancel, re-run, result, report, main table, artefacts,
//! logs.

use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::{Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use serde::Deserialize;
use serde_json::{Value, json};

use super::{ApiError, ApiPath, AppState, Caller, Role, attachment, json_body};
use crate::service::{Origin, Submitter};
use crate::store::{JobFilter, JobRecord, JobState};

pub(super) fn router() -> Router<AppState> {
    Router::new()
        .route("/v1/jobs", post(submit).get(list))
        .route("/v1/jobs/{id}", get(one))
        .route("/v1/jobs/{id}/cancel", post(cancel))
        .route("/v1/jobs/{id}/resume", post(resume))
        .route("/v1/jobs/{id}/measurements", get(measurements))
        .route("/v1/jobs/{id}/rerun", post(rerun))
        .route("/v1/jobs/{id}/result", get(result))
        .route("/v1/jobs/{id}/report", get(super::report::report))
        .route("/v1/jobs/{id}/table", get(table))
        .route("/v1/jobs/{id}/artefacts", get(artefacts))
        .route("/v1/jobs/{id}/artefacts/{name}", get(artefact))
        .route("/v1/jobs/{id}/logs", get(logs))
}

fn submitter(c: &Caller, role: Role) -> Submitter {
    Submitter {
        name: c.name.as_deref().map(str::to_owned),
        may_drive_devices: role >= Role::Operator,
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SubmitQuery {
    #[serde(default)]
    priority: i64,
    /// Validate and plan only: the plan, its envelope check and the estimated duration;
    /// nothing is stored, queued or moved.
    #[serde(default)]
    dry_run: bool,
}

async fn submit(
    State(s): State<AppState>,
    caller: Caller,
    headers: HeaderMap,
    q: Result<Query<SubmitQuery>, axum::extract::rejection::QueryRejection>,
    b: Result<Bytes, BytesRejection>,
) -> Result<Response, ApiError> {
    let role = caller.require(Role::Submitter)?;
    let Query(q) = q?;
    let key = idempotency_key(&headers)?;
    let doc = json_body(&s, b)?;
    if q.dry_run {
        let r = s.service.dry_run(doc).await?;
        return Ok((StatusCode::OK, Json(r)).into_response());
    }
    let origin = Origin {
        idempotency_key: key,
        ..Default::default()
    };
    let (id, new) = s
        .service
        .submit_once(doc, q.priority, submitter(&caller, role), origin)
        .await?;
    if new {
        return Ok(created(id));
    }
    // A retry of a submission that was committed: the first job, not a second one.
    let j = s.service.job(id).await?;
    Ok((
        StatusCode::OK,
        [
            (header::LOCATION, format!("/v1/jobs/{id}")),
            (
                header::HeaderName::from_static(IDEMPOTENT_REPLAYED),
                "true".to_string(),
            ),
        ],
        Json(json!({"id": id, "state": j.state})),
    )
        .into_response())
}

/// Header naming a response that answers an earlier submission with the same key.
const IDEMPOTENT_REPLAYED: &str = "idempotent-replayed";

/// The `Idempotency-Key` header: 1 to 200 visible ASCII characters.
fn idempotency_key(h: &HeaderMap) -> Result<Option<String>, ApiError> {
    let Some(v) = h.get("idempotency-key") else {
        return Ok(None);
    };
    let bad = || {
        ApiError::BadRequest(
            "Idempotency-Key must be 1 to 200 visible ASCII characters (e.g. a UUID)".into(),
        )
    };
    let k = v.to_str().map_err(|_| bad())?.trim();
    if k.is_empty() || k.len() > 200 || !k.bytes().all(|b| b.is_ascii_graphic()) {
        return Err(bad());
    }
    Ok(Some(k.to_string()))
}

fn created(id: i64) -> Response {
    (
        StatusCode::CREATED,
        [(header::LOCATION, format!("/v1/jobs/{id}"))],
        Json(json!({"id": id, "state": "queued"})),
    )
        .into_response()
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ListQuery {
    state: Option<String>,
    kind: Option<String>,
    before: Option<i64>,
    limit: Option<usize>,
}

async fn list(
    State(s): State<AppState>,
    caller: Caller,
    q: Result<Query<ListQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    let Query(q) = q?;
    let state = match q.state.as_deref() {
        None => None,
        Some(x) => Some(JobState::parse(x).ok_or_else(|| {
            ApiError::BadRequest(format!(
                "state `{x}` is not one of queued, running, paused, succeeded, failed, cancelled, interrupted"
            ))
        })?),
    };
    let limit = q.limit.unwrap_or(50);
    if !(1..=500).contains(&limit) {
        return Err(ApiError::BadRequest(format!(
            "limit {limit} is out of range: 1 to 500"
        )));
    }
    let jobs = s
        .service
        .jobs(JobFilter {
            state,
            kind: q.kind.filter(|k| !k.is_empty()),
            before: q.before,
            limit,
        })
        .await?;
    let next = (jobs.len() == limit)
        .then(|| jobs.last().map(|j| j.id))
        .flatten();
    Ok(Json(json!({"jobs": jobs, "next_before": next})))
}

async fn one(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<i64>,
) -> Result<Json<JobRecord>, ApiError> {
    caller.require_read()?;
    // Serialised straight from the record (no JSON tree in between: the hot read).
    Ok(Json(s.service.job(id).await?))
}

async fn cancel(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<i64>,
) -> Result<Json<Value>, ApiError> {
    let role = caller.require(Role::Submitter)?;
    let state = s.service.cancel(id, &submitter(&caller, role)).await?;
    Ok(Json(json!({"id": id, "state": state})))
}

async fn resume(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<i64>,
) -> Result<Json<Value>, ApiError> {
    caller.require(Role::Operator)?;
    let state = s.service.resume(id).await?;
    Ok(Json(json!({"id": id, "state": state})))
}

async fn measurements(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<i64>,
) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    Ok(Json(s.service.measurements(id).await?))
}

async fn rerun(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<i64>,
) -> Result<Response, ApiError> {
    let role = caller.require(Role::Submitter)?;
    let new = s.service.rerun(id, submitter(&caller, role)).await?;
    Ok(created(new))
}

/// 404 for no job, 409 for a job without a result.
async fn no_result(s: &AppState, id: i64) -> ApiError {
    match s.service.job(id).await {
        Ok(j) => ApiError::Conflict(format!(
            "job {id} is {} and has no result{}",
            j.state.as_str(),
            j.error.map(|e| format!(": {e}")).unwrap_or_default()
        )),
        Err(e) => e.into(),
    }
}

async fn result(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<i64>,
) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    match s.service.result(id).await? {
        Some(r) => Ok(Json(r)),
        None => Err(no_result(&s, id).await),
    }
}

async fn table(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<i64>,
) -> Result<Response, ApiError> {
    caller.require_read()?;
    match s.service.main_table_csv(id).await? {
        Some(csv) => Ok(([(header::CONTENT_TYPE, "text/csv; charset=utf-8")], csv).into_response()),
        None => Err(match s.service.job(id).await {
            Ok(j) if j.state == JobState::Succeeded => {
                ApiError::NotFound(format!("job {id} ({}) has no main table", j.kind))
            }
            _ => no_result(&s, id).await,
        }),
    }
}

async fn artefacts(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<i64>,
) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    s.service.job(id).await?;
    let list = s.service.artefacts(id).await?;
    Ok(Json(json!({"artefacts": list})))
}

async fn artefact(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath((id, name)): ApiPath<(i64, String)>,
) -> Result<Response, ApiError> {
    caller.require_read()?;
    let a = s
        .service
        .artefact(id, name.clone())
        .await?
        .ok_or_else(|| ApiError::NotFound(format!("job {id} has no artefact `{name}`")))?;
    let disposition = attachment(&a.name);
    Ok((
        [
            (header::CONTENT_TYPE, a.media_type),
            (header::CONTENT_DISPOSITION, disposition),
        ],
        a.content,
    )
        .into_response())
}

async fn logs(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<i64>,
) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    s.service.job(id).await?;
    let (logs, progress) = s.service.logs(id).await?;
    Ok(Json(json!({"logs": logs, "progress": progress})))
}
