//! Automatic resume: a campaign paused on a device fault in a cell whose lab file says
//! `resume = "auto"` is watched until every device of the job answers again. The same
//! units (same fingerprints as before the fault) resume it, journalled, at most the cell's
//! `max_auto_resumes` times; another unit, or the limit reached, leaves it paused for the
//! operator with the reason. The watch ends when the job leaves `paused` by other means.

use std::time::Duration;

use crate::campaigns::operator::{AutoResumed, auto_resumes, journal_auto_resume};
use crate::lab::resume::{Fingerprints, ResumeMode, Verdict, compare};
use crate::store::{JobState, StoreError, StoreJournal};

use super::Service;
use super::storage::call;

/// First wait between checks of a paused job's devices; it doubles up to [`MAX_WAIT`].
const FIRST_WAIT: Duration = Duration::from_millis(500);
/// Longest wait between checks.
const MAX_WAIT: Duration = Duration::from_secs(10);
/// How long one probe may take.
const PROBE_TIMEOUT: Duration = Duration::from_secs(10);

/// Watch paused job `id` (paused for `paused_for`) on `devices`, whose identities were
/// `before` when it started, if its cell resumes automatically.
pub(super) fn watch(
    svc: &Service,
    id: i64,
    devices: Vec<String>,
    mut before: Fingerprints,
    paused_for: String,
) {
    let lab = svc.shared.lab.clone();
    let Some(cell) = lab.cell_of(&devices).map(str::to_string) else {
        return;
    };
    let policy = lab.resume_policy(&cell);
    if policy.mode != ResumeMode::Auto {
        return;
    }
    // A device first identified during the run: what it said before the pause.
    let last = lab.fingerprints(&devices);
    for (d, fp) in before.iter_mut() {
        if fp.is_none() {
            *fp = last.get(d).cloned().flatten();
        }
    }
    tracing::info!(job = id, cell = %cell, "paused on a device fault: resumes by itself when its devices are back");
    let svc = svc.clone();
    tokio::spawn(async move {
        let stop = svc.shared.shutdown.clone();
        let mut wait = FIRST_WAIT;
        loop {
            tokio::select! {
                _ = stop.cancelled() => return,
                _ = tokio::time::sleep(wait) => {}
            }
            wait = (wait * 2).min(MAX_WAIT);
            match svc.job(id).await {
                Ok(rec) if rec.state == JobState::Paused => {}
                _ => return,
            }
            let links = lab.links_for(&devices);
            let now = futures_util::future::join_all(
                links
                    .iter()
                    .map(|(_, l)| async { (l.name.clone(), l.check(PROBE_TIMEOUT).await) }),
            )
            .await;
            let verdict = compare(&before, &now);
            if let Verdict::Down { device, error } = &verdict {
                tracing::debug!(job = id, device, error, "paused job: device still down");
                continue;
            }
            let outcome = resume_if_allowed(
                &svc,
                id,
                &verdict,
                &before,
                &paused_for,
                policy.max_auto_resumes,
            )
            .await;
            match outcome {
                Ok(msg) => tracing::info!(job = id, "{msg}"),
                Err(e) => {
                    tracing::error!(job = id, error = %e, "automatic resume failed; the job waits for the operator")
                }
            }
            return;
        }
    });
}

/// With every device answering: resume (journalled) if they are the same units and the
/// limit allows, else say why in the pause reason. What was done, for the log.
async fn resume_if_allowed(
    svc: &Service,
    id: i64,
    verdict: &Verdict,
    before: &Fingerprints,
    paused_for: &str,
    max: u32,
) -> Result<String, String> {
    let store = svc.shared.store.clone();
    if let Some(why) = verdict.operator_reason() {
        let reason = format!("{paused_for}; {why}");
        call(&store, move |st| st.note_pause(id, &reason))
            .await
            .map_err(|e| e.to_string())?;
        return Ok(why);
    }
    let journal = StoreJournal { store, job: id };
    let j = journal.clone();
    let used = call(&j.store.clone(), move |_| {
        auto_resumes(&j).map_err(|e| StoreError::Internal(e.to_string()))
    })
    .await
    .map_err(|e| e.to_string())?;
    if used >= max as usize {
        let reason = format!(
            "{paused_for}; not resumed automatically: the cell's {max} automatic resumes are used (lab file max_auto_resumes): check the cell, then resume by hand"
        );
        let r = reason.clone();
        call(&journal.store, move |st| st.note_pause(id, &r))
            .await
            .map_err(|e| e.to_string())?;
        return Ok(reason);
    }
    let record = AutoResumed {
        auto_resume: used + 1,
        paused_for: paused_for.to_string(),
        devices: before
            .iter()
            .map(|(d, f)| (d.clone(), f.clone().unwrap_or_default()))
            .collect(),
        at: crate::util::format_time(chrono::Utc::now()),
    };
    let names: Vec<&str> = record.devices.keys().map(String::as_str).collect();
    let why = format!(
        "resumed automatically ({} of {max}): {} answer again as the same devices",
        used + 1,
        names.join(", ")
    );
    let j = journal.clone();
    call(&journal.store, move |_| {
        journal_auto_resume(&j, &record).map_err(|e| StoreError::Internal(e.to_string()))
    })
    .await
    .map_err(|e| e.to_string())?;
    svc.resume_as(id, &why).await.map_err(|e| e.to_string())?;
    Ok(why)
}
