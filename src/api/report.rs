//! `GET /v1/jobs/{id}/report`: the printable HTML report of a finished job
//! ([`crate::report::html`]), served as a document that can run nothing: its own
//! Content-Security-Policy allows the inline style and nothing else (no script, no
//! fetch, a sandboxed origin), `nosniff` as every response.

use axum::extract::State;
use axum::http::header;
use axum::response::{IntoResponse, Response};
use serde_json::Value;

use super::{ApiError, ApiPath, AppState, Caller};
use crate::jobs::report_view::typed_result;
use crate::report::html::{Envelope, ReportInput, cell_name, render};
use crate::run::VERSION;

/// The policy of the report document: inline CSS and inline SVG only.
pub(super) const REPORT_CSP: &str = "default-src 'none'; style-src 'unsafe-inline'; img-src data:; \
base-uri 'none'; form-action 'none'; frame-ancestors 'none'; sandbox";

/// The handler of `GET /v1/jobs/{id}/report` (routed with the other job routes).
pub(super) async fn report(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<i64>,
) -> Result<Response, ApiError> {
    caller.require_read()?;
    let job = s.service.job(id).await?;
    let job = serde_json::to_value(&job).map_err(|e| ApiError::Internal(e.to_string()))?;
    let Some(result) = s.service.result(id).await? else {
        return Err(ApiError::Conflict(format!(
            "job {id} is {} and has no result to report",
            job.get("state")
                .and_then(Value::as_str)
                .unwrap_or("unfinished")
        )));
    };
    let envelope = Envelope::read(&result);
    let cell = cell_name(&job, &envelope);
    let journal = s.service.journal(id).await?;
    let artefacts = s.service.svg_artefacts(id).await?;
    let history = match cell {
        Some(c) => s.service.cell_models(c).await?,
        None => Vec::new(),
    };
    let journal: Vec<Value> = journal
        .iter()
        .map(|e| serde_json::to_value(e).unwrap_or(Value::Null))
        .collect();
    let history: Vec<Value> = history
        .iter()
        .map(|m| {
            // The model files are large and not shown: the decision and when.
            let mut v = serde_json::to_value(m).unwrap_or(Value::Null);
            if let Some(o) = v.as_object_mut() {
                o.remove("model");
            }
            v
        })
        .collect();
    let now = chrono::Utc::now().to_rfc3339_opts(chrono::SecondsFormat::Secs, true);
    let html = render(&ReportInput {
        job: &job,
        envelope: &envelope,
        result: typed_result(&result).as_ref(),
        artefacts: &artefacts,
        cell_history: &history,
        journal: &journal,
        generator_version: VERSION,
        generated_at: &now,
    });
    Ok((
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8".to_string()),
            (header::CONTENT_SECURITY_POLICY, REPORT_CSP.to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("inline; filename=\"job-{id}-report.html\""),
            ),
        ],
        html,
    )
        .into_response())
}
