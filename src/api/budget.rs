//! The bytes of request bodies in flight, bounded: each request that carries a body reserves
//! its declared length (or the largest body allowed, when it declares none) before the
//! body is read, and gives it back when answered. Beyond the budget the request is refused
//! at once with 503 and `Retry-After`, so twenty parallel 15 MB uploads cannot take the
//! host's memory; memory freed by a large body goes back to the system. Only a submitter's
//! token may send a body: anyone else is refused before a byte of it is read.

use std::sync::Arc;

use std::convert::Infallible;

use axum::extract::Request;
use axum::http::{HeaderValue, Method, header};
use axum::response::{IntoResponse, Response};
use tokio::sync::Semaphore;
use tower_service::Service;

use super::{ApiError, AppState, Caller, Role};
use axum::extract::FromRequestParts;

/// Budget unit: the semaphore counts KiB.
const UNIT: u64 = 1024;

/// Bodies at least this large give their memory back to the system when answered (bytes).
const RELEASE_ABOVE: u64 = 1 << 20;

/// The shared budget of body bytes in flight.
#[derive(Debug, Clone)]
pub struct BodyBudget {
    permits: Arc<Semaphore>,
    total_units: u32,
}

impl BodyBudget {
    /// A budget of `bytes` (at least one unit).
    pub fn new(bytes: u64) -> Self {
        let units = (bytes / UNIT).clamp(1, u64::from(u32::MAX >> 4)) as u32;
        Self {
            permits: Arc::new(Semaphore::new(units as usize)),
            total_units: units,
        }
    }

    /// Units free now (for tests and metrics).
    pub fn available_bytes(&self) -> u64 {
        self.permits.available_permits() as u64 * UNIT
    }
}

/// The body bytes a request may bring: its Content-Length, none for a method without a
/// body, else (a streamed body of unknown length) the largest body allowed.
pub(super) fn declared_bytes(s: &AppState, req: &Request) -> u64 {
    let declared = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.trim().parse::<u64>().ok());
    match declared {
        Some(n) => n,
        None if matches!(
            *req.method(),
            Method::GET | Method::HEAD | Method::DELETE | Method::OPTIONS
        ) =>
        {
            0
        }
        None => s.max_body_bytes as u64,
    }
}

/// Reserve the request's `bytes` of body ([`declared_bytes`], more than none), let `next`
/// answer, give them back (called by [`super::guard::Guard`] once the request is admitted;
/// a request without a body goes to its route directly).
pub(super) async fn within<S>(s: &AppState, req: Request, mut next: S, bytes: u64) -> Response
where
    S: Service<Request, Response = Response, Error = Infallible>,
{
    // Only a submitter may send a body: anyone else is refused before it is read.
    let (mut parts, body) = req.into_parts();
    match Caller::from_request_parts(&mut parts, s).await {
        Ok(c) => {
            if let Err(e) = c.require(Role::Submitter) {
                return e.into_response();
            }
        }
        Err(e) => return e.into_response(),
    }
    let req = Request::from_parts(parts, body);
    // Larger than the body limit: the limit refuses it (413) without reading it all.
    let units = bytes
        .min(s.max_body_bytes as u64)
        .div_ceil(UNIT)
        .clamp(1, u64::from(s.body_budget.total_units)) as u32;
    let Ok(permit) = s.body_budget.permits.clone().try_acquire_many_owned(units) else {
        let mut r = ApiError::Unavailable(format!(
            "too many request bodies in flight (at most {} MiB at once, the \
             `max_body_bytes_in_flight` setting): retry in a moment",
            u64::from(s.body_budget.total_units) * UNIT >> 20
        ))
        .into_response();
        r.headers_mut()
            .insert(header::RETRY_AFTER, HeaderValue::from_static("1"));
        return r;
    };
    metrics::gauge!("calibd_body_bytes_in_flight").increment(f64::from(units) * UNIT as f64);
    let r = answer(next.call(req).await);
    drop(permit);
    metrics::gauge!("calibd_body_bytes_in_flight").decrement(f64::from(units) * UNIT as f64);
    if bytes >= RELEASE_ABOVE {
        crate::util::release_memory();
    }
    r
}

/// The response of a service that cannot fail.
fn answer(r: Result<Response, Infallible>) -> Response {
    match r {
        Ok(r) => r,
        Err(never) => match never {},
    }
}
