//! The in-memory run queue: highest priority first, then oldest; a job whose devices are
//! held by a running job waits (and does not block jobs behind it that need other
//! devices or none).

use std::collections::HashSet;
use std::sync::Arc;

use crate::jobs::Job;

/// A queued job.
#[derive(Debug, Clone)]
pub struct Entry {
    /// Job id (ids grow with submission time).
    pub id: i64,
    /// Higher runs first.
    pub priority: i64,
    /// Devices it will hold.
    pub devices: Vec<String>,
    /// The validated job, if still in memory (absent after a restart: re-validated then).
    pub job: Option<Arc<Job>>,
}

/// The queue and the set of devices held by running jobs.
#[derive(Debug, Default)]
pub struct Queue {
    waiting: Vec<Entry>,
    held: HashSet<String>,
}

impl Queue {
    /// Add a job.
    pub fn push(&mut self, e: Entry) {
        self.waiting.push(e);
    }

    /// Remove a waiting job; false if it is not waiting.
    pub fn remove(&mut self, id: i64) -> bool {
        let before = self.waiting.len();
        self.waiting.retain(|e| e.id != id);
        self.waiting.len() != before
    }

    /// Number of waiting jobs.
    pub fn len(&self) -> usize {
        self.waiting.len()
    }

    /// True if no job waits.
    pub fn is_empty(&self) -> bool {
        self.waiting.is_empty()
    }

    /// Take the job to run next, and hold its devices.
    pub fn take(&mut self) -> Option<Entry> {
        let best = self
            .waiting
            .iter()
            .enumerate()
            .filter(|(_, e)| e.devices.iter().all(|d| !self.held.contains(d)))
            .max_by(|(_, a), (_, b)| a.priority.cmp(&b.priority).then(b.id.cmp(&a.id)))
            .map(|(i, _)| i)?;
        let e = self.waiting.remove(best);
        self.held.extend(e.devices.iter().cloned());
        Some(e)
    }

    /// Hold devices for a job taken elsewhere (claimed from a shared store).
    pub fn hold(&mut self, devices: &[String]) {
        self.held.extend(devices.iter().cloned());
    }

    /// Release devices held by a finished job.
    pub fn release(&mut self, devices: &[String]) {
        for d in devices {
            self.held.remove(d);
        }
    }

    /// True if `device` is held by a running job.
    pub fn is_held(&self, device: &str) -> bool {
        self.held.contains(device)
    }

    /// Waiting jobs that need `device`.
    pub fn waiting_for(&self, device: &str) -> usize {
        self.waiting
            .iter()
            .filter(|e| e.devices.iter().any(|d| d == device))
            .count()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn e(id: i64, priority: i64, devices: &[&str]) -> Entry {
        Entry {
            id,
            priority,
            devices: devices.iter().map(|s| s.to_string()).collect(),
            job: None,
        }
    }

    #[test]
    fn priority_then_age() {
        let mut q = Queue::default();
        q.push(e(1, 0, &[]));
        q.push(e(2, 5, &[]));
        q.push(e(3, 5, &[]));
        q.push(e(4, -1, &[]));
        let order: Vec<i64> = std::iter::from_fn(|| q.take().map(|e| e.id)).collect();
        assert_eq!(order, vec![2, 3, 1, 4]);
    }

    #[test]
    fn a_device_is_never_held_twice() {
        let mut q = Queue::default();
        q.push(e(1, 0, &["irb120"]));
        q.push(e(2, 9, &["irb120", "uwave"]));
        q.push(e(3, 0, &["uwave"]));
        q.push(e(4, 0, &[]));
        let first = q.take().unwrap();
        assert_eq!(first.id, 2);
        // 1 and 3 need a held device: only the device-free job may run.
        assert_eq!(q.take().unwrap().id, 4);
        assert!(q.take().is_none());
        assert_eq!(q.waiting_for("irb120"), 1);
        q.release(&first.devices);
        assert_eq!(q.take().unwrap().id, 1);
        assert_eq!(q.take().unwrap().id, 3);
        assert!(q.is_held("irb120") && q.is_held("uwave"));
        assert!(!q.remove(99) && q.is_empty());
    }
}
