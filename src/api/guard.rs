//! The API's per-request checks as one tower layer over every route and the fallback:
//! admission on the operators' reserved connections, the Host check, the body budget, then
//! the security headers on whatever answers, and the request metrics ([`super::track`]).
//! One shared state is borrowed, not cloned, and the next service is not boxed again per
//! request (`middleware::from_fn` does both); a request without a body is called on the
//! route polled ready, not on a copy of it.

use std::convert::Infallible;
use std::future::Future;
use std::pin::Pin;
use std::task::{Context, Poll};

use axum::extract::Request;
use axum::http::{HeaderValue, header};
use axum::response::{IntoResponse, Response};
use tower_service::Service;

use super::track::Tracker;
use super::{ApiError, AppState, CSP, Peer, Role, auth, budget, host_part};

/// Makes a [`Guard`] around each route (and the fallback) of the router.
#[derive(Debug, Clone)]
pub(super) struct GuardLayer {
    state: AppState,
}

impl GuardLayer {
    pub(super) fn new(state: AppState) -> Self {
        Self { state }
    }
}

impl<S> tower_layer::Layer<S> for GuardLayer {
    type Service = Guard<S>;

    fn layer(&self, inner: S) -> Guard<S> {
        Guard {
            inner,
            state: self.state.clone(),
            tracker: Tracker::default(),
        }
    }
}

/// The checks in front of one route.
#[derive(Debug, Clone)]
pub(super) struct Guard<S> {
    inner: S,
    state: AppState,
    /// The route's request metrics.
    tracker: Tracker,
}

/// The boxed response future of the guard.
type Answer = Pin<Box<dyn Future<Output = Result<Response, Infallible>> + Send>>;

impl<S> Service<Request> for Guard<S>
where
    S: Service<Request, Response = Response, Error = Infallible> + Clone + Send + 'static,
    S::Future: Send + 'static,
{
    type Response = Response;
    type Error = Infallible;
    type Future = Answer;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Infallible>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, req: Request) -> Answer {
        if let Some(mut res) = refusal(&self.state, &req) {
            secure(&mut res);
            return Box::pin(std::future::ready(Ok(res)));
        }
        // Counted from here: a refused request is not a request of the route.
        let timing = self.tracker.start(&req);
        // A request without a body is called on the service polled ready, here (no copy of
        // the route); one with a body waits for its share of the body budget first, on the
        // service's copy.
        let bytes = budget::declared_bytes(&self.state, &req);
        if bytes == 0 {
            let answer = self.inner.call(req);
            return Box::pin(async move {
                let mut res = answer.await?;
                secure(&mut res);
                timing.finish(&res);
                Ok(res)
            });
        }
        // The service polled ready serves this request; its clone waits for the next one.
        let fresh = self.inner.clone();
        let inner = std::mem::replace(&mut self.inner, fresh);
        let state = self.state.clone();
        Box::pin(async move {
            let mut res = budget::within(&state, req, inner, bytes).await;
            secure(&mut res);
            timing.finish(&res);
            Ok(res)
        })
    }
}

/// The answer to a request refused before its route runs: on a reserved connection
/// without an operator token, or addressed to a host name this daemon is not.
fn refusal(s: &AppState, req: &Request) -> Option<Response> {
    admit(s, req).or_else(|| check_host(s, req))
}

/// On a connection holding one of the operators' reserved slots (the others are taken),
/// only a request with an operator token is served; any other is answered 503 and the
/// connection closed, so the slot is free again for an operator.
fn admit(s: &AppState, req: &Request) -> Option<Response> {
    let peer = req.extensions().get::<Peer>().copied()?;
    if !peer.reserved {
        return None;
    }
    let operator = req
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|h| h.to_str().ok())
        .and_then(auth::bearer_token)
        .and_then(|t| s.auth.check(t))
        .is_some_and(|(_, role)| role == Role::Operator);
    if operator {
        return None;
    }
    metrics::counter!("calibd_http_connections_refused_total", "reason" => "reserve").increment(1);
    tracing::debug!(peer = %peer.addr, "request refused: only operators may use the reserved connections");
    let mut r = ApiError::Unavailable(format!(
        "the daemon is at its connection limit ({}); the remaining connections are kept \
         for operators: try again later",
        s.limits.max_connections
    ))
    .into_response();
    let h = r.headers_mut();
    h.insert(header::CONNECTION, HeaderValue::from_static("close"));
    h.insert(header::RETRY_AFTER, HeaderValue::from_static("5"));
    Some(r)
}

/// Refuse requests addressed to a host name this daemon is not configured to be: a page
/// on another origin that rebinds its DNS name to the lab PC cannot read the API through a
/// browser, because the browser still sends the page's name.
fn check_host(s: &AppState, req: &Request) -> Option<Response> {
    // RFC 9112 section 3.2: more than one Host field line is a 400, whatever is allowed.
    let hosts = req.headers().get_all(header::HOST).iter().count();
    if hosts > 1 {
        return Some(
            ApiError::BadRequest(format!(
                "the request has {hosts} Host headers; HTTP/1.1 allows exactly one"
            ))
            .into_response(),
        );
    }
    if s.allowed_hosts.iter().any(|h| h == "*") {
        return None;
    }
    let given = req.uri().authority().map(|a| a.as_str()).or_else(|| {
        req.headers()
            .get(header::HOST)
            .and_then(|h| h.to_str().ok())
    });
    let Some(given) = given else {
        return Some(ApiError::BadRequest("the request has no Host header".into()).into_response());
    };
    let host = host_part(given);
    if s.allowed_hosts.iter().any(|h| h.eq_ignore_ascii_case(host)) {
        return None;
    }
    let name = host.to_ascii_lowercase();
    let mut shown: String = name.chars().take(100).collect();
    if shown.len() < name.len() {
        shown.push_str("...");
    }
    Some(ApiError::MisdirectedHost(shown).into_response())
}

/// Headers on every response: nothing is sniffed into an active type, the page runs only
/// its own script (no inline code, no framing), and nothing with a token is cached.
fn secure(res: &mut Response) {
    let h = res.headers_mut();
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    // A handler may set a stricter policy of its own (the report document).
    h.entry(header::CONTENT_SECURITY_POLICY)
        .or_insert(HeaderValue::from_static(CSP));
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    h.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    h.entry(header::CACHE_CONTROL)
        .or_insert(HeaderValue::from_static("no-store"));
}
