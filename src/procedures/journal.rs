//! The measurement journal of a campaign: every measurement is appended durably before the
//! next move, and a resumed campaign reads back what is already there.

use std::sync::Mutex;

use serde::{Deserialize, Serialize};
use serde_json::Value;

/// What became of one planned configuration.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EntryStatus {
    /// Measured: `data` holds the measurement.
    Measured,
    /// Given up for a reason that is not a device fault (`data` holds the reason).
    Skipped,
}

/// One journal line.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JournalEntry {
    /// Index of the configuration in the campaign's plan (a campaign may have several
    /// phases; each uses its own index range).
    pub index: usize,
    /// Measured or skipped.
    pub status: EntryStatus,
    /// The measurement (or the reason of a skip), as the campaign defines it.
    pub data: Value,
}

/// Why a journal could not read or record an entry.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum JournalError {
    /// The storage under the journal failed (database, disk, a lock poisoned by a panic):
    /// what is already journalled stays, nothing more can be recorded.
    #[error("{message}")]
    Storage {
        /// The storage's own error.
        message: String,
    },
    /// The index is already in the journal: a configuration is never measured twice (two
    /// runs of one job wrote to it).
    #[error("configuration {index} is already in the journal")]
    Duplicate {
        /// The journal index appended twice.
        index: usize,
    },
    /// A measurement could not be turned into a journal entry.
    #[error("measurement {index} cannot be journalled: {message}")]
    Unwritable {
        /// The journal index.
        index: usize,
        /// The serialiser's error.
        message: String,
    },
    /// A stored entry is not what the campaign recorded (edited, or from another version).
    #[error("journal entry {index} is unreadable: {message}")]
    Unreadable {
        /// The journal index.
        index: usize,
        /// The parser's error.
        message: String,
    },
}

impl JournalError {
    /// A storage fault with the storage's message.
    pub fn storage(message: impl std::fmt::Display) -> Self {
        JournalError::Storage {
            message: message.to_string(),
        }
    }
}

/// Durable storage of one campaign's measurements.
pub trait Journal: Send + Sync {
    /// Everything appended so far, in index order.
    fn entries(&self) -> Result<Vec<JournalEntry>, JournalError>;
    /// Append one entry; returns only once it is committed. Appending an index twice is
    /// [`JournalError::Duplicate`] (a configuration is never measured twice).
    fn append(&self, e: &JournalEntry) -> Result<(), JournalError>;
}

/// A journal in memory (offline runs and tests).
#[derive(Debug, Default)]
pub struct MemoryJournal {
    entries: Mutex<Vec<JournalEntry>>,
    /// Fail every append after this many entries (simulates a crash or a full disk).
    pub fail_after: Option<usize>,
}

impl MemoryJournal {
    /// An empty journal whose appends fail after `n` entries.
    pub fn failing_after(n: usize) -> Self {
        Self {
            entries: Mutex::new(Vec::new()),
            fail_after: Some(n),
        }
    }

    /// A journal that already holds `entries` (a restart).
    pub fn with(entries: Vec<JournalEntry>) -> Self {
        Self {
            entries: Mutex::new(entries),
            fail_after: None,
        }
    }
}

impl Journal for MemoryJournal {
    fn entries(&self) -> Result<Vec<JournalEntry>, JournalError> {
        let mut v = self
            .entries
            .lock()
            .map_err(|_| JournalError::storage("journal poisoned"))?
            .clone();
        v.sort_by_key(|e| e.index);
        Ok(v)
    }

    fn append(&self, e: &JournalEntry) -> Result<(), JournalError> {
        let mut v = self
            .entries
            .lock()
            .map_err(|_| JournalError::storage("journal poisoned"))?;
        if self.fail_after.is_some_and(|n| v.len() >= n) {
            return Err(JournalError::storage("journal storage failed"));
        }
        if v.iter().any(|x| x.index == e.index) {
            return Err(JournalError::Duplicate { index: e.index });
        }
        v.push(e.clone());
        Ok(())
    }
}
