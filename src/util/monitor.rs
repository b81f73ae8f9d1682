//! `Monitor`: how long numerical work reports progress and learns it was cancelled, without
//! knowing about jobs, channels or tokio.

/// Progress sink and cancellation flag for long computations (LM iterations, DETMAX
/// exchanges, NOCP blocks). Implementations must be cheap to call.
pub trait Monitor: Sync {
    /// Report progress: `fraction` in [0, 1] of the current `stage`.
    fn progress(&self, fraction: f64, stage: &str);
    /// True once the work should stop as soon as possible.
    fn is_cancelled(&self) -> bool;
    /// Progress with a line for the operator (e.g. "configuration 12/60, ETA 40 s").
    fn report(&self, fraction: f64, stage: &str, message: &str) {
        let _ = message;
        self.progress(fraction, stage);
    }
}

/// A monitor that ignores progress and never cancels.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoMonitor;

impl Monitor for NoMonitor {
    fn progress(&self, _fraction: f64, _stage: &str) {}
    fn is_cancelled(&self) -> bool {
        false
    }
}

/// A monitor that maps the [0, 1] progress of a sub-task into [lo, hi] of its parent.
pub struct SubMonitor<'a> {
    parent: &'a dyn Monitor,
    lo: f64,
    hi: f64,
}

impl std::fmt::Debug for SubMonitor<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SubMonitor")
            .field("lo", &self.lo)
            .field("hi", &self.hi)
            .finish()
    }
}

impl<'a> SubMonitor<'a> {
    /// A child covering [lo, hi] of `parent`'s progress.
    pub fn new(parent: &'a dyn Monitor, lo: f64, hi: f64) -> Self {
        Self { parent, lo, hi }
    }
}

impl Monitor for SubMonitor<'_> {
    fn progress(&self, fraction: f64, stage: &str) {
        self.parent.progress(
            self.lo + (self.hi - self.lo) * fraction.clamp(0.0, 1.0),
            stage,
        );
    }
    fn is_cancelled(&self) -> bool {
        self.parent.is_cancelled()
    }
    fn report(&self, fraction: f64, stage: &str, message: &str) {
        self.parent.report(
            self.lo + (self.hi - self.lo) * fraction.clamp(0.0, 1.0),
            stage,
            message,
        );
    }
}
