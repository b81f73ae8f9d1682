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
}
