//! Job records read since the last write: a status read answered from memory, not by a
//! SQLite read transaction (two lock syscalls and the pager, ~15 us of a ~50 us request).
//! One daemon owns the file and every write goes through the one writer connection, so a
//! write counter bumped after each write says when the records may have changed.

use std::collections::HashMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

use crate::store::JobRecord;

/// Records kept at most (a bound on memory: about 1 kB each).
const CAPACITY: usize = 1024;

/// The write counter and the records read at its current value.
#[derive(Debug, Default)]
pub(super) struct Recent {
    /// Writes finished so far (bumped after each, its commit included).
    writes: AtomicU64,
    records: Mutex<Records>,
}

/// Records read while `writes` was `at`.
#[derive(Debug, Default)]
struct Records {
    at: u64,
    by_id: HashMap<i64, JobRecord>,
}

impl Recent {
    /// The write counter now: read it before a read transaction and hand it to
    /// [`Recent::keep`] with what the transaction read.
    pub(super) fn now(&self) -> u64 {
        self.writes.load(Ordering::Acquire)
    }

    /// A write finished (committed or rolled back): every record kept may be stale.
    pub(super) fn wrote(&self) {
        self.writes.fetch_add(1, Ordering::AcqRel);
    }

    /// Job `id` as read since the last write, if it was.
    pub(super) fn get(&self, id: i64) -> Option<JobRecord> {
        let now = self.now();
        let r = self.records.lock().ok()?;
        (r.at == now).then(|| r.by_id.get(&id).cloned()).flatten()
    }

    /// Keep `rec`, read by a transaction begun when the counter was `at` (from
    /// [`Recent::now`]): dropped if a write has finished since, as it may predate it.
    pub(super) fn keep(&self, at: u64, rec: &JobRecord) {
        let Ok(mut r) = self.records.lock() else {
            return;
        };
        if at != self.now() {
            return;
        }
        if r.at != at || r.by_id.len() >= CAPACITY {
            r.by_id.clear();
            r.at = at;
        }
        r.by_id.insert(rec.id, rec.clone());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::store::JobState;

    fn rec(id: i64, state: JobState) -> JobRecord {
        JobRecord {
            id,
            kind: "serial.fk".into(),
            state,
            priority: 0,
            devices: vec![],
            inputs_sha256: Default::default(),
            submitted_at: "2026-11-29T12:00:00Z".into(),
            started_at: None,
            resumed_at: None,
            finished_at: None,
            progress: 0.0,
            stage: None,
            message: None,
            error: None,
            submitted_by: None,
            schedule_id: None,
            rerun_of: None,
        }
    }

    #[test]
    fn a_write_drops_what_was_read_before_it() {
        let r = Recent::default();
        let at = r.now();
        r.keep(at, &rec(1, JobState::Queued));
        assert_eq!(r.get(1).map(|j| j.state), Some(JobState::Queued));
        assert!(r.get(2).is_none());
        r.wrote();
        assert!(
            r.get(1).is_none(),
            "a record read before a write is not served after it"
        );
        // A read begun before the write, kept after it, is not kept.
        r.keep(at, &rec(1, JobState::Queued));
        assert!(r.get(1).is_none());
        let at = r.now();
        r.keep(at, &rec(1, JobState::Running));
        assert_eq!(r.get(1).map(|j| j.state), Some(JobState::Running));
    }

    #[test]
    fn the_records_kept_are_bounded() {
        let r = Recent::default();
        let at = r.now();
        for id in 0..(CAPACITY as i64 + 10) {
            r.keep(at, &rec(id, JobState::Succeeded));
        }
        let n = r.records.lock().map(|x| x.by_id.len()).unwrap_or(0);
        assert!(n <= CAPACITY, "{n} records kept");
        assert!(
            r.get(CAPACITY as i64 + 9).is_some(),
            "the last read is kept"
        );
    }
}
