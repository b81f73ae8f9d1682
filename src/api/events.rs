//! Server-Sent Events: `/v1/events` streams every job's state and progress events;
//! `/v1/jobs/{id}/events` starts with the job's current state (so a late subscriber
//! misses nothing that matters) and ends after its final state. A subscriber that falls
//! behind gets a `lagged` event and should re-read the job. Each token (each address
//! without a token) has a share of open streams (`max_event_streams_per_token`); one more
//! is answered 429.

use std::convert::Infallible;
use std::time::Duration;

use axum::extract::State;
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::routing::get;
use axum::{Extension, Router};
use futures_util::stream::{self, Stream, StreamExt};
use serde_json::json;
use tokio::sync::broadcast::error::RecvError;
use tokio_stream::wrappers::BroadcastStream;
use tokio_stream::wrappers::errors::BroadcastStreamRecvError;

use super::conn::Share;
use super::{ApiError, ApiPath, AppState, Caller, Peer};
use crate::service::Event;

pub(super) fn router() -> Router<AppState> {
    Router::new()
        .route("/v1/events", get(all))
        .route("/v1/jobs/{id}/events", get(job))
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

/// One of the caller's event streams (its token's, or its address's without a token),
/// held while the stream is open; 429 when the caller already holds its share.
fn stream_share(
    s: &AppState,
    caller: &Caller,
    peer: Option<&Peer>,
) -> Result<Share<String>, ApiError> {
    let key = match (&caller.name, peer) {
        (Some(name), _) => format!("token {name}"),
        (None, Some(p)) => format!("address {}", p.addr.ip().to_canonical()),
        (None, None) => "anonymous".to_string(),
    };
    s.event_streams.take(key.clone()).ok_or_else(|| {
        metrics::counter!("calibd_event_streams_refused_total").increment(1);
        tracing::debug!(caller = %key, limit = s.event_streams.limit(), "event stream refused");
        ApiError::TooManyRequests(format!(
            "{key} already has {} event streams open (max_event_streams_per_token): close one \
             first",
            s.event_streams.limit()
        ))
    })
}

async fn all(
    State(s): State<AppState>,
    caller: Caller,
    peer: Option<Extension<Peer>>,
) -> Result<Sse<impl Stream<Item = Result<SseEvent, Infallible>>>, ApiError> {
    caller.require_read()?;
    let share = stream_share(&s, &caller, peer.as_deref())?;
    let rx = BroadcastStream::new(s.service.subscribe());
    let stream = rx
        .map(move |r| {
            let _held = &share;
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
    peer: Option<Extension<Peer>>,
    ApiPath(id): ApiPath<i64>,
) -> Result<Sse<impl Stream<Item = Result<SseEvent, Infallible>>>, ApiError> {
    caller.require_read()?;
    let share = stream_share(&s, &caller, peer.as_deref())?;
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
        .map(move |e| {
            let _held = &share;
            Ok(e)
        })
        .take_until(s.shutdown.clone().cancelled_owned());
    Ok(Sse::new(stream).keep_alive(keep_alive()))
}
