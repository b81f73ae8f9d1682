//! Running a job from synchronous code (`calibd run`, tests, benches): the one place a job
//! is driven by `block_on`, on a runtime of its own or the caller's. Progress and
//! cancellation cross between the caller's borrowed [`Monitor`] and the job's context
//! through a channel, exactly as the daemon's workers do. Kinds that stream their main
//! table write it as CSV row by row instead ([`write_main_csv`]).

use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use tokio::sync::mpsc;

use crate::jobs::{Completed, Job};
use crate::lab::Lab;
use crate::procedures::{Journal, MemoryJournal};
use crate::run::{Cx, JobError};
use crate::util::Monitor;

/// One progress report crossing to the caller's thread.
struct Report {
    fraction: f64,
    stage: String,
    message: Option<String>,
}

/// The job's side of the caller's monitor.
struct Forward {
    tx: mpsc::UnboundedSender<Report>,
    cancel: Arc<AtomicBool>,
}

impl Monitor for Forward {
    fn progress(&self, fraction: f64, stage: &str) {
        let _ = self.tx.send(Report {
            fraction,
            stage: stage.into(),
            message: None,
        });
    }
    fn is_cancelled(&self) -> bool {
        self.cancel.load(Ordering::Relaxed)
    }
    fn report(&self, fraction: f64, stage: &str, message: &str) {
        let _ = self.tx.send(Report {
            fraction,
            stage: stage.into(),
            message: Some(message.into()),
        });
    }
}

fn deliver(monitor: &dyn Monitor, r: Report) {
    match r.message {
        Some(m) => monitor.report(r.fraction, &r.stage, &m),
        None => monitor.progress(r.fraction, &r.stage),
    }
}

/// Run `job` over `lab` on a private runtime, with a journal in memory.
pub fn run(job: &Job, lab: Arc<Lab>, monitor: &dyn Monitor) -> Result<Completed, JobError> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| JobError::internal("cannot start a runtime", e))?;
    run_on(
        rt.handle(),
        job,
        lab,
        Arc::new(MemoryJournal::default()),
        monitor,
    )
}

/// Run `job` over `lab` on the runtime `rt` (one whose tasks already drive the lab's
/// devices), measuring into `journal`; the calling thread waits and relays progress.
pub fn run_on(
    rt: &tokio::runtime::Handle,
    job: &Job,
    lab: Arc<Lab>,
    journal: Arc<dyn Journal>,
    monitor: &dyn Monitor,
) -> Result<Completed, JobError> {
    let (tx, mut rx) = mpsc::unbounded_channel();
    let cancel = Arc::new(AtomicBool::new(false));
    let cx = Cx::new(
        lab,
        journal,
        Arc::new(Forward {
            tx,
            cancel: cancel.clone(),
        }),
    );
    rt.block_on(async {
        let run = job.run_in(cx);
        tokio::pin!(run);
        let mut tick = tokio::time::interval(Duration::from_millis(50));
        loop {
            tokio::select! {
                done = &mut run => {
                    while let Ok(r) = rx.try_recv() {
                        deliver(monitor, r);
                    }
                    return done;
                }
                Some(r) = rx.recv() => deliver(monitor, r),
                _ = tick.tick() => {
                    if monitor.is_cancelled() {
                        cancel.store(true, Ordering::Relaxed);
                    }
                }
            }
        }
    })
}

/// Write `job`'s main table as CSV to `path` row by row, without running the job into a
/// result (for the kinds that stream: [`Job::streams_main_csv`]); the number of rows. The
/// rows go to a `.partial` file beside `path` that replaces it only when every row is
/// written, so a failed job leaves nothing half-written behind.
pub fn write_main_csv(job: &Job, path: &Path, monitor: &dyn Monitor) -> Result<usize, JobError> {
    let mut partial = path.as_os_str().to_owned();
    partial.push(".partial");
    let partial = std::path::PathBuf::from(partial);
    let io = |e: std::io::Error| JobError::io("writing", Some(path), e);
    let written = (|| {
        let file = std::fs::File::create(&partial).map_err(io)?;
        let mut out = std::io::BufWriter::with_capacity(1 << 16, file);
        let n = job.write_main_csv(&mut out, monitor)?;
        out.into_inner().map_err(|e| io(e.into_error()))?;
        std::fs::rename(&partial, path).map_err(io)?;
        Ok(n)
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&partial);
    }
    written
}

impl Job {
    /// Run the job from synchronous code (`calibd run`, tests, benches) on a private
    /// runtime, with an empty lab and a journal in memory (see [`crate::jobs::offline`]).
    pub fn run(&self, monitor: &dyn Monitor) -> Result<Completed, JobError> {
        run(self, Arc::new(Lab::empty()), monitor)
    }
}
