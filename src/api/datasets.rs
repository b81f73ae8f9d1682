//! `/v1/datasets`: upload an input (CSV table, model file) once and reference it by id in
//! jobs. The id is the SHA-256 of the content, so uploading twice gives the same id.
//! What a user uploads comes back only as inert data: `application/octet-stream`, as an
//! attachment, never sniffed (the declared media type is data in the listing, not a
//! header a browser acts on).

use axum::body::Bytes;
use axum::extract::rejection::BytesRejection;
use axum::extract::{Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use serde::Deserialize;
use serde_json::{Value, json};

use super::{ApiError, ApiPath, AppState, Caller, Role, attachment, body, check_name};

pub(super) fn router() -> Router<AppState> {
    Router::new()
        .route("/v1/datasets", get(list).post(upload))
        .route("/v1/datasets/{id}", get(one))
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
    let media_type = media_type(headers.get(header::CONTENT_TYPE))?;
    let name = q.name.unwrap_or_else(|| "dataset".into());
    check_name("name", &name)?;
    let info = s
        .service
        .put_dataset(name.clone(), media_type, Vec::from(b))
        .await?;
    if info.name == name {
        return Ok((StatusCode::CREATED, Json(info)).into_response());
    }
    // The id is the content's hash: the same bytes under a second name are the first
    // dataset, and the new name is not recorded. Say so instead of answering as if stored.
    let message = format!(
        "the same content is already stored as `{}` (id {}); the name `{name}` was not \
         recorded: refer to the dataset by its id",
        info.name, info.id
    );
    let mut body = serde_json::to_value(&info)
        .map_err(|e| ApiError::Internal(format!("dataset description: {e}")))?;
    body["already_stored"] = Value::Bool(true);
    body["message"] = Value::String(message);
    Ok((StatusCode::OK, Json(body)).into_response())
}

async fn list(State(s): State<AppState>, caller: Caller) -> Result<Json<Value>, ApiError> {
    caller.require_read()?;
    let all = s.service.datasets().await?;
    Ok(Json(json!({"datasets": all})))
}

async fn one(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<String>,
) -> Result<Response, ApiError> {
    caller.require_read()?;
    match s.service.dataset(id.clone()).await? {
        Some((info, c)) => Ok((
            [
                (header::CONTENT_TYPE, "application/octet-stream".to_string()),
                (header::CONTENT_DISPOSITION, attachment(&info.name)),
            ],
            c,
        )
            .into_response()),
        None => Err(ApiError::NotFound(format!("no dataset with id {id}"))),
    }
}

/// Longest stored media type, bytes (RFC 6838: 127 for type and subtype each).
const MAX_MEDIA_TYPE_BYTES: usize = 255;

/// The declared media type, reduced to `type/subtype` in lowercase (parameters dropped),
/// or `application/octet-stream` when none is given.
fn media_type(h: Option<&axum::http::HeaderValue>) -> Result<String, ApiError> {
    let Some(h) = h else {
        return Ok("application/octet-stream".into());
    };
    let bad = |why: &str| ApiError::BadRequest(format!("Content-Type: {why}"));
    if h.len() > MAX_MEDIA_TYPE_BYTES {
        return Err(bad(&format!(
            "{} bytes; at most {MAX_MEDIA_TYPE_BYTES} are allowed",
            h.len()
        )));
    }
    let v = h.to_str().map_err(|_| bad("not ASCII"))?;
    let essence = v
        .split(';')
        .next()
        .unwrap_or("")
        .trim()
        .to_ascii_lowercase();
    let token = |t: &str| {
        !t.is_empty()
            && t.len() <= 127
            && t.bytes()
                .all(|b| b.is_ascii_alphanumeric() || b"!#$&-^_.+".contains(&b))
    };
    match essence.split_once('/') {
        Some((t, sub)) if token(t) && token(sub) => Ok(essence),
        _ => Err(bad(&format!(
            "`{essence}` is not a media type (type/subtype)"
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::super::MAX_NAME_CHARS;
    use super::*;
    use axum::http::HeaderValue;

    #[test]
    fn media_types_are_reduced_to_their_essence_and_bounded() {
        let m = |s: &str| media_type(Some(&HeaderValue::from_str(s).unwrap()));
        assert_eq!(m("text/CSV; charset=utf-8").unwrap(), "text/csv");
        assert_eq!(media_type(None).unwrap(), "application/octet-stream");
        assert!(m("text").is_err());
        assert!(m("text/html<script>").is_err());
        assert!(m(&format!("text/{}", "x".repeat(300))).is_err());
    }

    #[test]
    fn attachment_names_cannot_break_the_header() {
        assert_eq!(
            attachment("a\"; b.html\r\nX: y"),
            "attachment; filename=\"a___b.html__X__y\""
        );
        assert!(check_name("name", &"n".repeat(MAX_NAME_CHARS)).is_ok());
        assert!(check_name("name", &"n".repeat(MAX_NAME_CHARS + 1)).is_err());
        assert!(check_name("name", "a\u{7}b").is_err());
    }
}
