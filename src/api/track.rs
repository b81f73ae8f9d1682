//! Request metrics by route template (never by raw path; `unmatched` for a path no route
//! has): `calibd_http_requests_total` {method, path, status} and
//! `calibd_http_request_duration_seconds` {method, path}, taken by
//! [`super::guard::Guard`] around each route. Each route keeps the handles it registered, so
//! a request makes no label strings and no registry lookup (the recorder is the one
//! installed when the route first answers).

use std::sync::{Arc, Mutex};
use std::time::Instant;

use axum::extract::{MatchedPath, Request};
use axum::http::Method;
use axum::response::Response;
use metrics::{Counter, Histogram};

/// The metric handles of one route, shared by its copies.
#[derive(Debug, Clone, Default)]
pub(super) struct Tracker {
    handles: Arc<Mutex<Handles>>,
}

/// One request being counted and timed.
pub(super) struct Timing {
    t0: Instant,
    method: Method,
    path: Option<MatchedPath>,
    handles: Arc<Mutex<Handles>>,
}

impl Tracker {
    /// Start timing `req`.
    pub(super) fn start(&self, req: &Request) -> Timing {
        Timing {
            t0: Instant::now(),
            method: req.method().clone(),
            path: req.extensions().get::<MatchedPath>().cloned(),
            handles: self.handles.clone(),
        }
    }
}

impl Timing {
    /// Count the request with the response's status and record its duration.
    pub(super) fn finish(self, res: &Response) {
        let path = self.path.as_ref().map_or("unmatched", MatchedPath::as_str);
        let status = res.status().as_u16();
        let (count, duration) = {
            let mut h = self.handles.lock().unwrap_or_else(|p| p.into_inner());
            (
                h.count(&self.method, path, status),
                h.duration(&self.method, path),
            )
        };
        count.increment(1);
        duration.record(self.t0.elapsed().as_secs_f64());
    }
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
