//! The campaign engine: what every measurement campaign repeats, written once. For each
//! planned step not yet in the journal: check for cancellation, report progress and ETA,
//! measure it (the campaign's [`Step`]), retry device faults with doubling back-off and
//! pause with the reason when they persist, and append the measurement (or the reason of a
//! skip) to the [`Journal`] before the next move. A resumed campaign skips what the
//! journal holds, so a configuration is never measured twice.

use std::collections::HashSet;
use std::future::Future;
use std::time::{Duration, Instant};

use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::procedures::{EntryStatus, Journal, JournalEntry, JournalError};
use crate::run::JobError;
use crate::util::Monitor;

/// Retry policy for device faults.
#[derive(Debug, Clone, PartialEq)]
pub struct Retry {
    /// Attempts per step before pausing.
    pub attempts: usize,
    /// First back-off delay, doubled after each failure.
    pub backoff: Duration,
}

impl Default for Retry {
    fn default() -> Self {
        Self {
            attempts: 3,
            backoff: Duration::from_millis(500),
        }
    }
}

/// How a campaign's measuring ended early.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CampaignError {
    /// Device faults persisted: the campaign is paused at `index` and can be resumed.
    #[error("paused at configuration {index}: {reason}")]
    Paused {
        /// First step not measured (journal index).
        index: usize,
        /// The last fault.
        reason: String,
    },
    /// The journal could not store a measurement: nothing more may be measured.
    #[error("journal: {0}")]
    Journal(JournalError),
    /// Cancelled by the operator.
    #[error("cancelled")]
    Cancelled,
    /// The campaign waits for the operator at `index` (a prompt, not a fault): paused, and
    /// the operator's resume is the confirmation.
    #[error("waiting for the operator at step {index}: {prompt}")]
    Waiting {
        /// The step that waits (journal index).
        index: usize,
        /// What the operator must do before continuing.
        prompt: String,
    },
}

impl From<CampaignError> for JobError {
    fn from(e: CampaignError) -> Self {
        match e {
            CampaignError::Paused { index, reason } => JobError::Paused { index, reason },
            CampaignError::Cancelled => JobError::Cancelled,
            CampaignError::Waiting { index, prompt } => JobError::Waiting { index, prompt },
            CampaignError::Journal(e) => JobError::Journal(e),
        }
    }
}

/// Counts of one phase, including earlier runs of a resumed campaign.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Summary {
    /// Steps measured.
    pub recorded: usize,
    /// Steps skipped (ball lost, outside the envelope, ...).
    pub skipped: usize,
    /// Steps in the plan.
    pub planned: usize,
}

/// Why one step gave no measurement.
#[derive(Debug, Clone, PartialEq)]
pub enum StepError {
    /// A device fault: retried, then the campaign pauses with this reason.
    Fault(String),
    /// Not measurable for a reason retrying cannot change: journalled as skipped.
    Skip(String),
    /// Cancelled by the operator while measuring.
    Cancelled,
    /// The operator must act first (see [`crate::campaigns::operator`]): the campaign
    /// pauses at once with this prompt, without retries and without a journal entry.
    Wait(String),
}

/// One kind of measurement step: how a campaign measures one planned item.
pub trait Step: Sync {
    /// What the plan holds per step (a configuration, a joint set, a posture).
    type Plan: Sync;
    /// What the journal holds per measured step.
    type Sample: Serialize + DeserializeOwned + Send;

    /// Stage name in progress reports (`centring`, `measuring`, `postures`).
    const STAGE: &'static str;

    /// The operator's line for step `k` of `n` (1-based in the text).
    fn describe(&self, k: usize, n: usize, plan: &Self::Plan) -> String;

    /// Measure one planned step; `index` is its journal index.
    fn measure(
        &self,
        index: usize,
        plan: &Self::Plan,
        monitor: &dyn Monitor,
    ) -> impl Future<Output = Result<Self::Sample, StepError>> + Send;
}

/// The measured samples of a journal whose indices are in `offset..offset + len`.
pub fn recorded<T: DeserializeOwned>(
    journal: &dyn Journal,
    offset: usize,
    len: usize,
) -> Result<Vec<T>, JobError> {
    let entries = journal.entries()?;
    let mut out = Vec::new();
    for e in entries {
        if e.status == EntryStatus::Measured && e.index >= offset && e.index < offset + len {
            out.push(
                serde_json::from_value(e.data).map_err(|err| JournalError::Unreadable {
                    index: e.index,
                    message: err.to_string(),
                })?,
            );
        }
    }
    Ok(out)
}

fn append(
    journal: &dyn Journal,
    index: usize,
    status: EntryStatus,
    data: serde_json::Value,
) -> Result<(), CampaignError> {
    journal
        .append(&JournalEntry {
            index,
            status,
            data,
        })
        .map_err(CampaignError::Journal)
}

/// Measure every step of `plan` not yet in the journal; plan entry `k` is journal index
/// `offset + k` (a campaign's phases use disjoint ranges).
pub async fn run<S: Step>(
    step: &S,
    plan: &[S::Plan],
    offset: usize,
    journal: &dyn Journal,
    retry: &Retry,
    monitor: &dyn Monitor,
) -> Result<Summary, CampaignError> {
    let entries = journal.entries().map_err(CampaignError::Journal)?;
    let mine = |s: EntryStatus| {
        entries
            .iter()
            .filter(|e| e.status == s && e.index >= offset && e.index < offset + plan.len())
            .count()
    };
    let (mut recorded, mut skipped) = (mine(EntryStatus::Measured), mine(EntryStatus::Skipped));
    let done: HashSet<usize> = entries.iter().map(|e| e.index).collect();
    let todo = plan.len() - recorded - skipped;
    let t0 = Instant::now();
    let mut this_run = 0usize;
    for (k, p) in plan.iter().enumerate() {
        let index = offset + k;
        if done.contains(&index) {
            continue;
        }
        if monitor.is_cancelled() {
            return Err(CampaignError::Cancelled);
        }
        let eta = match this_run {
            0 => "unknown".to_string(),
            n => format!(
                "{:.0} s",
                t0.elapsed().as_secs_f64() / n as f64 * (todo - n) as f64
            ),
        };
        monitor.report(
            k as f64 / plan.len() as f64,
            S::STAGE,
            &format!(
                "{}: {recorded} recorded, {skipped} skipped, ETA {eta}",
                step.describe(k + 1, plan.len(), p)
            ),
        );
        this_run += 1;
        let mut delay = retry.backoff;
        let mut attempt = 0;
        loop {
            attempt += 1;
            match step.measure(index, p, monitor).await {
                Ok(sample) => {
                    let data = serde_json::to_value(&sample).map_err(|e| {
                        CampaignError::Journal(JournalError::Unwritable {
                            index,
                            message: e.to_string(),
                        })
                    })?;
                    append(journal, index, EntryStatus::Measured, data)?;
                    recorded += 1;
                    tracing::info!(index, stage = S::STAGE, attempt, "measured");
                    break;
                }
                Err(StepError::Skip(reason)) => {
                    append(
                        journal,
                        index,
                        EntryStatus::Skipped,
                        serde_json::json!({ "reason": reason }),
                    )?;
                    tracing::warn!(index, %reason, "step skipped");
                    skipped += 1;
                    break;
                }
                Err(StepError::Cancelled) => return Err(CampaignError::Cancelled),
                Err(StepError::Wait(prompt)) => {
                    tracing::info!(index, %prompt, "waiting for the operator");
                    return Err(CampaignError::Waiting { index, prompt });
                }
                Err(StepError::Fault(reason)) => {
                    if attempt >= retry.attempts {
                        return Err(CampaignError::Paused { index, reason });
                    }
                    tracing::warn!(index, attempt, error = %reason, "device fault, retrying");
                    tokio::time::sleep(delay).await;
                    delay *= 2;
                    if monitor.is_cancelled() {
                        return Err(CampaignError::Cancelled);
                    }
                }
            }
        }
    }
    monitor.progress(1.0, S::STAGE);
    Ok(Summary {
        recorded,
        skipped,
        planned: plan.len(),
    })
}

/// Wrap up a campaign: its typed result as the output, the identification's artefacts, the
/// measurement table (main table and `measurements.csv`), one more table if any, and the
/// model it proposes for its cell.
pub fn conclude<R: Serialize>(
    result: &R,
    artefacts: Vec<crate::run::Artefact>,
    measurements: crate::run::Table,
    more: Option<(&str, crate::run::Table)>,
    candidate: crate::lab::Candidate,
) -> Result<crate::run::Produced, JobError> {
    use crate::run::Artefact;
    let mut output = crate::run::Output::typed(result)?;
    output.artefacts = artefacts;
    output
        .artefacts
        .push(Artefact::csv("measurements.csv", &measurements));
    if let Some((name, t)) = more {
        output.artefacts.push(Artefact::csv(name, &t));
    }
    output.main_table = Some(measurements);
    Ok(crate::run::Produced {
        output,
        candidate: Some(candidate),
    })
}
