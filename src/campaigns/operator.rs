//! Waiting for the operator inside a campaign, durably. A step that needs the operator
//! first (jog the robot to a ball, mate the device on its coupling) calls [`confirm`]: the
//! first time, it journals a "prompted" marker for the step in the marker range
//! ([`MARKER_OFFSET`] + the step's index) and returns [`StepError::Wait`], so the campaign
//! pauses with the prompt as its reason. The operator's resume is the confirmation: when the
//! resumed campaign reaches the step again, the marker is in the journal and the step
//! proceeds. A daemon restart in between changes nothing (the marker is in the store).

use serde::{Deserialize, Serialize};

use super::engine::StepError;
use crate::procedures::{EntryStatus, Journal, JournalEntry};

/// Journal index of the marker of step `i` is `MARKER_OFFSET + i` (campaign phases use
/// indices far below it).
pub const MARKER_OFFSET: usize = 1_000_000;

/// Journal index of the `n`-th automatic resume (0-based) is `AUTO_RESUME_OFFSET + n`.
pub const AUTO_RESUME_OFFSET: usize = 2_000_000;

/// The journal's record of an automatic resume: the campaign paused on a device fault and
/// the daemon resumed it when the job's devices answered again as the same units.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AutoResumed {
    /// 1 for the first automatic resume of the job.
    pub auto_resume: usize,
    /// Why the campaign had paused (the device fault).
    pub paused_for: String,
    /// The devices checked, each with the identity it answered with (its fingerprint).
    pub devices: std::collections::BTreeMap<String, String>,
    /// When (RFC 3339).
    pub at: String,
}

/// Automatic resumes the journal holds.
pub fn auto_resumes(journal: &dyn Journal) -> Result<usize, crate::procedures::JournalError> {
    Ok(journal
        .entries()?
        .iter()
        .filter(|e| e.index >= AUTO_RESUME_OFFSET && e.index < AUTO_RESUME_OFFSET + MARKER_OFFSET)
        .count())
}

/// Journal the next automatic resume (its number is `r.auto_resume`).
pub fn journal_auto_resume(
    journal: &dyn Journal,
    r: &AutoResumed,
) -> Result<(), crate::procedures::JournalError> {
    let index = AUTO_RESUME_OFFSET + r.auto_resume.saturating_sub(1);
    let data =
        serde_json::to_value(r).map_err(|e| crate::procedures::JournalError::Unwritable {
            index,
            message: e.to_string(),
        })?;
    journal.append(&JournalEntry {
        index,
        status: EntryStatus::Measured,
        data,
    })
}

/// The journal's record of a prompt shown to the operator.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Prompted {
    /// The prompt.
    pub operator_prompt: String,
}

/// Whether step `index` has been prompted already (its marker is in the journal).
pub fn prompted(journal: &dyn Journal, index: usize) -> Result<bool, StepError> {
    let entries = journal
        .entries()
        .map_err(|m| StepError::Fault(format!("journal: {m}")))?;
    Ok(entries.iter().any(|e| e.index == MARKER_OFFSET + index))
}

/// Proceed if the operator has confirmed step `index` (resumed after its prompt); otherwise
/// journal the marker and ask the campaign to pause with `prompt`.
pub fn confirm(journal: &dyn Journal, index: usize, prompt: &str) -> Result<(), StepError> {
    if prompted(journal, index)? {
        return Ok(());
    }
    let data = serde_json::to_value(Prompted {
        operator_prompt: prompt.to_string(),
    })
    .map_err(|e| StepError::Fault(format!("journal: {e}")))?;
    journal
        .append(&JournalEntry {
            index: MARKER_OFFSET + index,
            status: EntryStatus::Measured,
            data,
        })
        .map_err(|m| StepError::Fault(format!("journal: {m}")))?;
    Err(StepError::Wait(prompt.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedures::MemoryJournal;

    #[test]
    fn the_first_visit_prompts_and_the_next_proceeds_from_the_journal() {
        let j = MemoryJournal::default();
        let e = confirm(&j, 3, "jog to ball 1").unwrap_err();
        assert_eq!(e, StepError::Wait("jog to ball 1".into()));
        // A restart: a new journal holding what the store kept.
        let j2 = MemoryJournal::with(j.entries().unwrap());
        assert!(confirm(&j2, 3, "jog to ball 1").is_ok());
        assert!(matches!(confirm(&j2, 4, "next"), Err(StepError::Wait(_))));
    }

    #[test]
    fn automatic_resumes_are_counted_from_their_own_range() {
        let j = MemoryJournal::default();
        confirm(&j, 3, "jog").unwrap_err();
        assert_eq!(auto_resumes(&j).unwrap(), 0);
        for n in 1..=2 {
            let r = AutoResumed {
                auto_resume: n,
                paused_for: "rws: connection refused".into(),
                devices: [("c.rws".to_string(), "IRC5".to_string())].into(),
                at: "2026-11-28T09:00:00Z".into(),
            };
            journal_auto_resume(&j, &r).unwrap();
        }
        assert_eq!(auto_resumes(&j).unwrap(), 2);
        let e = j.entries().unwrap();
        let last = e
            .iter()
            .find(|e| e.index == AUTO_RESUME_OFFSET + 1)
            .unwrap();
        assert_eq!(last.data["auto_resume"], 2);
        // The same number twice is refused by the journal (one entry per resume).
        let again = AutoResumed {
            auto_resume: 2,
            paused_for: String::new(),
            devices: Default::default(),
            at: String::new(),
        };
        assert!(journal_auto_resume(&j, &again).is_err());
    }
}
