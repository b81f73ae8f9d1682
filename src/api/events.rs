//! Server-Sent Events: `/v1/events` streams every job's state and progress events;
//! `/v1/jobs/{id}/events` starts with the job's current state (so a late subscriber
//! misses nothing that matters) and ends after its final state. A subscriber that falls
//! behind gets a `lagged` event and should re-read the job.

use std::convert::Infallible;
use std::time::Duration;

use axum::Router;
use axum::extract::State;
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::routing::get;
use futures_util::stream::{self, Stream, StreamExt};
use serde_json::json;
use tokio::sync::broadcast::error::RecvError;
use tokio_stream::wrappers::BroadcastStream;
use tokio_stream::wrappers::errors::BroadcastStreamRecvError;

use super::{ApiError, ApiPath, AppState, Caller};
use crate::service::Event;

pub(super) fn router() -> Router<AppState> {
    Router::new()
        .route("/events", get(all))
        .route("/jobs/{id}/events", get(job))
}

fn sse(e: &Event) -> SseEvent {
    SseEvent::default()
        .event(e.name())
        .json_data(e)
        .unwrap_or_else(|_| SseEvent::default().comment("unserialisable event"))
}

fn lagged(n: u64) -> SseEvent {
    SseEvent::default()
        .event("lagged")
        .data(json!({"missed": n}).to_string())
}

fn keep_alive() -> KeepAlive {
    KeepAlive::new().interval(Duration::from_secs(15))
}

async fn all(
    State(s): State<AppState>,
    caller: Caller,
) -> Result<Sse<impl Stream<Item = Result<SseEvent, Infallible>>>, ApiError> {
    caller.require_read()?;
    let rx = BroadcastStream::new(s.service.subscribe());
    let stream = rx
        .map(|r| {
            Ok(match r {
                Ok(e) => sse(&e),
                Err(BroadcastStreamRecvError::Lagged(n)) => lagged(n),
            })
        })
        .take_until(s.shutdown.clone().cancelled_owned());
    Ok(Sse::new(stream).keep_alive(keep_alive()))
}

async fn job(
    State(s): State<AppState>,
    caller: Caller,
    ApiPath(id): ApiPath<i64>,
) -> Result<Sse<impl Stream<Item = Result<SseEvent, Infallible>>>, ApiError> {
    caller.require_read()?;
    // Subscribe first, then read the state: nothing falls between the two.
    let rx = s.service.subscribe();
    let rec = s.service.job(id).await?;
    let first = Event::State {
        id,
        kind: rec.kind.clone(),
        state: rec.state,
        error: rec.error.clone(),
    };
    let mut head = vec![sse(&first)];
    if rec.state == crate::store::JobState::Running
        && let Some(stage) = &rec.stage
    {
        head.push(sse(&Event::Progress {
            id,
            fraction: rec.progress,
            stage: stage.clone(),
            message: rec.message.clone(),
        }));
    }
    let live = stream::unfold(
        (rx, rec.state.is_final()),
        move |(mut rx, finished)| async move {
            if finished {
                return None;
            }
            loop {
                match rx.recv().await {
                    Ok(e) if e.job_id() == id => {
                        let fin = matches!(&e, Event::State { state, .. } if state.is_final());
                        return Some((sse(&e), (rx, fin)));
                    }
                    Ok(_) => continue,
                    Err(RecvError::Lagged(n)) => return Some((lagged(n), (rx, false))),
                    Err(RecvError::Closed) => return None,
                }
            }
        },
    );
    let stream = stream::iter(head)
        .chain(live)
        .map(Ok)
        .take_until(s.shutdown.clone().cancelled_owned());
    Ok(Sse::new(stream).keep_alive(keep_alive()))
}
