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

/// Durable storage of one campaign's measurements.
pub trait Journal: Send + Sync {
    /// Everything appended so far, in index order.
    fn entries(&self) -> Result<Vec<JournalEntry>, String>;
    /// Append one entry; returns only once it is committed. Appending an index twice is an
    /// error (a configuration is never measured twice).
    fn append(&self, e: &JournalEntry) -> Result<(), String>;
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
    fn entries(&self) -> Result<Vec<JournalEntry>, String> {
        let mut v = self
            .entries
            .lock()
            .map_err(|_| "journal poisoned".to_string())?
            .clone();
        v.sort_by_key(|e| e.index);
        Ok(v)
    }

    fn append(&self, e: &JournalEntry) -> Result<(), String> {
        let mut v = self
            .entries
            .lock()
            .map_err(|_| "journal poisoned".to_string())?;
        if self.fail_after.is_some_and(|n| v.len() >= n) {
            return Err("journal storage failed".into());
        }
        if v.iter().any(|x| x.index == e.index) {
            return Err(format!(
                "configuration {} is already in the journal",
                e.index
            ));
        }
        v.push(e.clone());
        Ok(())
    }
}
