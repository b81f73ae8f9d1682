//! Request metrics by route template (never by raw path): `calibd_http_requests_total`
//! {method, path, status} and `calibd_http_request_duration_seconds` {method, path}. Each
//! route keeps the handles it registered, so a request makes no label strings and no
//! registry lookup (the recorder is the one installed when the route first answers).

use std::convert::Infallible;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Instant;

use axum::extract::{MatchedPath, Request};
use axum::http::Method;
use axum::response::Response;
use metrics::{Counter, Histogram};
use tower_service::Service;

use super::guard::Answer;

/// Makes a [`Track`] around each route of the router (not the fallback).
#[derive(Debug, Clone, Default)]
pub(super) struct TrackLayer;

impl<S> tower_layer::Layer<S> for TrackLayer {
    type Service = Track<S>;

    fn layer(&self, inner: S) -> Track<S> {
        Track {
            inner,
            handles: Arc::default(),
        }
    }
}

/// One route, counted and timed.
#[derive(Debug, Clone)]
pub(super) struct Track<S> {
    inner: S,
    handles: Arc<Mutex<Handles>>,
}

/// The metric handles a route has used, by method (and status).
#[derive(Default)]
struct Handles {
    durations: Vec<(Method, String, Histogram)>,
    counts: Vec<(Method, String, u16, Counter)>,
}

impl std::fmt::Debug for Handles {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Handles")
            .field("durations", &self.durations.len())
            .field("counts", &self.counts.len())
            .finish()
    }
}

impl Handles {
    fn duration(&mut self, method: &Method, path: &str) -> Histogram {
        if let Some((.., h)) = self
            .durations
            .iter()
            .find(|(m, p, _)| m == method && p == path)
        {
            return h.clone();
        }
        let h = metrics::histogram!("calibd_http_request_duration_seconds",
            "method" => method.to_string(), "path" => path.to_owned());
        self.durations
            .push((method.clone(), path.to_owned(), h.clone()));
        h
    }

    fn count(&mut self, method: &Method, path: &str, status: u16) -> Counter {
        if let Some((.., c)) = self
            .counts
            .iter()
            .find(|(m, p, s, _)| *s == status && m == method && p == path)
        {
            return c.clone();
        }
        let c = metrics::counter!("calibd_http_requests_total",
            "method" => method.to_string(), "path" => path.to_owned(), "status" => status.to_string());
        self.counts
            .push((method.clone(), path.to_owned(), status, c.clone()));
        c
    }
}

impl<S> Service<Request> for Track<S>
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
        let t0 = Instant::now();
        let path = req.extensions().get::<MatchedPath>().cloned();
        let method = req.method().clone();
        let fresh = self.inner.clone();
        let mut inner = std::mem::replace(&mut self.inner, fresh);
        let handles = self.handles.clone();
        Box::pin(async move {
            let res = inner.call(req).await?;
            let path = path.as_ref().map_or("unmatched", MatchedPath::as_str);
            let status = res.status().as_u16();
            let (count, duration) = {
                let mut h = handles.lock().unwrap_or_else(|p| p.into_inner());
                (h.count(&method, path, status), h.duration(&method, path))
            };
            count.increment(1);
            duration.record(t0.elapsed().as_secs_f64());
            Ok(res)
        })
    }
}
