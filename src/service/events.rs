//! Events the service publishes (state changes and progress) for SSE subscribers, and the
//! progress hook handed to running jobs.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;
use tokio::sync::mpsc::UnboundedSender;

use crate::store::JobState;
use crate::util::Monitor;

/// Something that happened to a job.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "type", rename_all = "lowercase")]
pub enum Event {
    /// The job changed state.
    State {
        /// Job id.
        id: i64,
        /// Job kind.
        kind: String,
        /// New state.
        state: JobState,
        /// Why (for failures).
        #[serde(skip_serializing_if = "Option::is_none")]
        error: Option<String>,
    },
    /// The job made progress.
    Progress {
        /// Job id.
        id: i64,
        /// Fraction in [0, 1].
        fraction: f64,
        /// Stage.
        stage: String,
        /// Message.
        #[serde(skip_serializing_if = "Option::is_none")]
        message: Option<String>,
    },
    /// A verification's drift decision (see [`DriftEvent`]).
    Drift(DriftEvent),
}

/// What the drift policy decided after verification job `id` on `cell`.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct DriftEvent {
    /// The `cell.verify` job.
    pub id: i64,
    /// The cell.
    pub cell: String,
    /// `recalibrate` or `within_tolerance`.
    pub action: String,
    /// Mean compensated AP of the verification (mm).
    pub ap_mm: f64,
    /// The recalibration job submitted, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub recalibration: Option<i64>,
    /// Why, with the numbers.
    pub reason: String,
}

impl Event {
    /// The job the event is about.
    pub fn job_id(&self) -> i64 {
        match self {
            Event::State { id, .. } | Event::Progress { id, .. } => *id,
            Event::Drift(d) => d.id,
        }
    }

    /// The SSE event name.
    pub fn name(&self) -> &'static str {
        match self {
            Event::State { .. } => "state",
            Event::Progress { .. } => "progress",
            Event::Drift(_) => "drift",
        }
    }
}

/// Minimum interval between two progress reports of the same stage.
const MIN_INTERVAL: Duration = Duration::from_millis(200);

/// The [`Monitor`] a running job gets: throttled progress into a channel, and a
/// cancellation flag set by `cancel` or by shutdown.
#[derive(Debug)]
pub(crate) struct JobMonitor {
    id: i64,
    tx: UnboundedSender<Event>,
    cancel: std::sync::Arc<AtomicBool>,
    last: Mutex<Option<(Instant, String)>>,
}

impl JobMonitor {
    pub(crate) fn new(
        id: i64,
        tx: UnboundedSender<Event>,
        cancel: std::sync::Arc<AtomicBool>,
    ) -> Self {
        Self {
            id,
            tx,
            cancel,
            last: Mutex::new(None),
        }
    }
}

impl Monitor for JobMonitor {
    fn progress(&self, fraction: f64, stage: &str) {
        self.send(fraction, stage, None);
    }

    fn report(&self, fraction: f64, stage: &str, message: &str) {
        self.send(fraction, stage, Some(message));
    }

    fn is_cancelled(&self) -> bool {
        self.cancel.load(Ordering::Relaxed)
    }
}

impl JobMonitor {
    fn send(&self, fraction: f64, stage: &str, message: Option<&str>) {
        let now = Instant::now();
        let Ok(mut last) = self.last.lock() else {
            return;
        };
        let due = match &*last {
            Some((t, s)) => s != stage || now.duration_since(*t) >= MIN_INTERVAL,
            None => true,
        };
        if !due {
            return;
        }
        *last = Some((now, stage.to_string()));
        let fraction = if fraction.is_finite() {
            fraction.clamp(0.0, 1.0)
        } else {
            0.0
        };
        // The receiver only goes away at shutdown; progress is then irrelevant.
        let _ = self.tx.send(Event::Progress {
            id: self.id,
            fraction,
            stage: stage.to_string(),
            message: message.map(str::to_string),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn progress_is_throttled_per_stage_and_cancellation_is_seen() {
        let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
        let flag = std::sync::Arc::new(AtomicBool::new(false));
        let m = JobMonitor::new(7, tx, flag.clone());
        for k in 0..1000 {
            m.progress(k as f64 / 1000.0, "lm");
        }
        m.progress(0.0, "report");
        let mut got = vec![];
        while let Ok(e) = rx.try_recv() {
            got.push(e);
        }
        // The first report of each stage always passes; 1,000 fast reports do not.
        assert!(got.len() >= 2 && got.len() < 10, "{}", got.len());
        assert!(matches!(&got[got.len() - 1], Event::Progress { stage, .. } if stage == "report"));
        assert!(!m.is_cancelled());
        flag.store(true, Ordering::Relaxed);
        assert!(m.is_cancelled());
    }
}
