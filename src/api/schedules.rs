//! `/v1/schedules`: cron schedules that submit a job (operators create and change them;
//! anyone who may read sees them and the record of their occurrences).

use axum::body::Bytes;
use axum::extract::State;
use axum::extract::rejection::BytesRejection;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use serde_json::{Value, json};

use super::{ApiError, ApiPath, AppState, Caller, Role, check_name, json_body};
use crate::schedule::Rule;
use crate::store::{NewSchedule, ScheduleRecord, format_time};

pub(super) fn router() -> Router<AppState> {
    Router::new()
        .route("/v1/schedules", get(list).post(create))
        .route("/v1/schedules/{id}", get(one).put(replace).delete(remove))
        .route("/v1/schedules/{id}/runs", get(runs))
}

/// A schedule as the API shows it: the record plus its next occurrence.
fn view(s: &AppState, r: ScheduleRecord) -> Value {
    let next = Rule::parse(&r.spec)
        .ok()
        .filter(|_| r.spec.enabled)
        .and_then(|rule| rule.next_after(s.scheduler.now()))
        .map(format_time);
    let mut v = serde_json::to_value(&r).unwrap_or(Value::Null);
    if let Value::Object(m) = &mut v {
        m.insert("next_run_at".into(), json!(next));
    }
    v
}

async fn parse(s: &AppState, b: Result<Bytes, BytesRejection>) -> Result<NewSchedule, ApiError> {
    let v = json_body(s, b)?;
    let spec: NewSchedule = serde_path_to_error::deserialize(&v)
        .map_err(|e| ApiError::Invalid(format!("`{}`: {}", e.path(), e.inner())))?;
    check_name("name", &spec.name).map_err(|e| ApiError::Invalid(e.to_string()))?;
    let rule = Rule::parse(&spec).map_err(|e| ApiError::Invalid(e.to_string()))?;
    let min = s.min_schedule_interval;
    if let Some(gap) = rule.shortest_interval(s.scheduler.now(), 1000)
        && gap < min
    {
        return Err(ApiError::Invalid(format!(
            "`cron`: `{}` fires every {} s; the shortest interval allowed is {} s \
             (min_schedule_interval_s)",
            spec.cron,
            gap.as_secs(),
            min.as_secs()
        )));
    }
    s.service
        .validate(spec.job.clone())
        .await
        .map_err(|e| ApiError::Invalid(format!("`job`: {e}")))?;
    Ok(spec)
}

async fn create(
    State(s): State<AppState>,
    caller: Caller,
    b: Result<Bytes, BytesRejection>,
) -> Result<Response, ApiError> {
    caller.require(Role::Operator)?;
    let spec = parse(&s, b).await?;
    let now = format_time(s.scheduler.now());
    let id = s
        .service
        .insert_schedule(spec, caller.name.as_deref().map(str::to_owned), now)
        .await?;
    s.scheduler.reload();
    let rec = s.service.schedule(id).await?;
    let rec = rec.ok_or_else(|| ApiError::Internal("schedule vanished".into()))?;
    Ok((StatusCode::CREATED, Json(view(&s, rec))).into_response())
}

async fn list(State(s): State<AppState>, caller: Caller) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    let all = s.service.schedules().await?;
    let v: Vec<Value> = all.into_iter().map(|r| view(&s, r)).collect();
    Ok(Json(json!({"schedules": v})))
}

async fn get_one(s: &AppState, id: i64) -> Result<ScheduleRecord, ApiError> {
    s.service
        .schedule(id)
        .await?
        .ok_or_else(|| ApiError::NotFound(format!("no schedule with id {id}")))
}

async fn one(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<i64>,
) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    let r = get_one(&s, id).await?;
    Ok(Json(view(&s, r)))
}

async fn replace(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<i64>,
    b: Result<Bytes, BytesRejection>,
) -> Result<Json<Value>, ApiError> {
    caller.require(Role::Operator)?;
    let spec = parse(&s, b).await?;
    let now = format_time(s.scheduler.now());
    if !s.service.update_schedule(id, spec, now).await? {
        return Err(ApiError::NotFound(format!("no schedule with id {id}")));
    }
    s.scheduler.reload();
    let r = get_one(&s, id).await?;
    Ok(Json(view(&s, r)))
}

async fn remove(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<i64>,
) -> Result<StatusCode, ApiError> {
    caller.require(Role::Operator)?;
    if !s.service.delete_schedule(id).await? {
        return Err(ApiError::NotFound(format!("no schedule with id {id}")));
    }
    s.scheduler.reload();
    Ok(StatusCode::NO_CONTENT)
}

async fn runs(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<i64>,
) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    get_one(&s, id).await?;
    let r = s.service.schedule_runs(id, 100).await?;
    Ok(Json(json!({"runs": r})))
}
