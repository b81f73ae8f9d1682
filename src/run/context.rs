//! [`Cx`]: what a running job may use besides its inputs — the lab's cells, its own
//! measurement journal (durable in the daemon, in memory offline) and a progress monitor —
//! and the one way numerical work leaves the async runtime: [`Cx::compute`] runs it on the
//! blocking pool.

use std::sync::Arc;

use super::JobError;
use crate::lab::Lab;
use crate::procedures::Journal;
use crate::util::Monitor;

/// The context of a running job. Cheap to clone; itself a [`Monitor`] that maps progress
/// into the phase it was made for (see [`Cx::phase`]).
#[derive(Clone)]
pub struct Cx {
    lab: Arc<Lab>,
    journal: Arc<dyn Journal>,
    monitor: Arc<dyn Monitor + Send>,
    lo: f64,
    hi: f64,
}

impl std::fmt::Debug for Cx {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Cx")
            .field("lab", &self.lab)
            .field("phase", &(self.lo, self.hi))
            .finish()
    }
}

impl Cx {
    /// A context over `lab`, writing measurements to `journal` and progress to `monitor`.
    pub fn new(lab: Arc<Lab>, journal: Arc<dyn Journal>, monitor: Arc<dyn Monitor + Send>) -> Self {
        Self {
            lab,
            journal,
            monitor,
            lo: 0.0,
            hi: 1.0,
        }
    }

    /// The lab's cells.
    pub fn lab(&self) -> &Lab {
        &self.lab
    }

    /// The job's measurement journal.
    pub fn journal(&self) -> &dyn Journal {
        &*self.journal
    }

    /// A context for a phase covering `[lo, hi]` of this one's progress.
    pub fn phase(&self, lo: f64, hi: f64) -> Cx {
        let w = self.hi - self.lo;
        Cx {
            lo: self.lo + w * lo,
            hi: self.lo + w * hi,
            ..self.clone()
        }
    }

    /// Run CPU-bound work on the blocking pool (never on the async runtime), with this
    /// context as its monitor; cancellation reaches it through [`Monitor::is_cancelled`].
    pub async fn compute<T: Send + 'static>(
        &self,
        f: impl FnOnce(&dyn Monitor) -> Result<T, JobError> + Send + 'static,
    ) -> Result<T, JobError> {
        let cx = self.clone();
        let span = tracing::Span::current();
        tokio::task::spawn_blocking(move || {
            let _g = span.enter();
            f(&cx)
        })
        .await
        .map_err(|e| JobError::internal("a computation panicked", e))?
    }

    fn map(&self, fraction: f64) -> f64 {
        self.lo + (self.hi - self.lo) * fraction.clamp(0.0, 1.0)
    }
}

impl Monitor for Cx {
    fn progress(&self, fraction: f64, stage: &str) {
        self.monitor.progress(self.map(fraction), stage);
    }
    fn is_cancelled(&self) -> bool {
        self.monitor.is_cancelled()
    }
    fn report(&self, fraction: f64, stage: &str, message: &str) {
        self.monitor.report(self.map(fraction), stage, message);
    }
}
