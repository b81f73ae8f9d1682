//! Schedules: cron expressions with a time zone that submit a job, and the record of every
//! occurrence (submitted, missed and run once, missed and skipped, refused).

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::{Store, StoreError};

/// What to do with occurrences missed while the daemon was down.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum MissedPolicy {
    /// Submit one job at start for all missed occurrences together.
    #[default]
    RunOnce,
    /// Record the missed occurrences and wait for the next one.
    Skip,
}

impl MissedPolicy {
    /// The name used in the API and the database.
    pub fn as_str(self) -> &'static str {
        match self {
            MissedPolicy::RunOnce => "run_once",
            MissedPolicy::Skip => "skip",
        }
    }
}

/// A schedule to create or replace.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NewSchedule {
    /// Unique name.
    pub name: String,
    /// Cron expression (5 or 6 fields, croner syntax), e.g. `0 2 * * *`.
    pub cron: String,
    /// IANA time zone the expression is read in, e.g. `Europe/Berlin`.
    #[serde(default = "utc")]
    pub timezone: String,
    /// The job document to submit.
    pub job: Value,
    /// Priority of the submitted jobs.
    #[serde(default)]
    pub priority: i64,
    /// Missed-run policy.
    #[serde(default)]
    pub missed: MissedPolicy,
    /// Disabled schedules submit nothing.
    #[serde(default = "yes")]
    pub enabled: bool,
}

fn utc() -> String {
    "UTC".into()
}
fn yes() -> bool {
    true
}

/// A stored schedule.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScheduleRecord {
    /// Id.
    pub id: i64,
    /// The definition.
    #[serde(flatten)]
    pub spec: NewSchedule,
    /// When it was created.
    pub created_at: String,
    /// Token name that created it.
    pub created_by: Option<String>,
    /// Occurrences up to this instant (RFC 3339) have been handled.
    pub checked_until: String,
}

/// One occurrence of a schedule and what happened.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScheduleRun {
    /// The occurrence (RFC 3339).
    pub due_at: String,
    /// When it was handled.
    pub at: String,
    /// `submitted`, `missed_run_once`, `missed_skipped` or `refused`.
    pub outcome: String,
    /// The job submitted.
    pub job_id: Option<i64>,
    /// Details (e.g. how many occurrences were missed, why the job was refused).
    pub message: Option<String>,
}

impl Store {
    /// Create a schedule; occurrences count from `checked_until` (normally now).
    pub fn insert_schedule(
        &self,
        s: &NewSchedule,
        created_by: Option<&str>,
        checked_until: &str,
    ) -> Result<i64, StoreError> {
        self.backend.insert_schedule(s, created_by, checked_until)
    }

    /// Replace a schedule's definition; false if there is none with this id.
    pub fn update_schedule(
        &self,
        id: i64,
        s: &NewSchedule,
        checked_until: &str,
    ) -> Result<bool, StoreError> {
        self.backend.update_schedule(id, s, checked_until)
    }

    /// Delete a schedule (its run records stay); false if there is none.
    pub fn delete_schedule(&self, id: i64) -> Result<bool, StoreError> {
        self.backend.delete_schedule(id)
    }

    /// One schedule.
    pub fn schedule(&self, id: i64) -> Result<Option<ScheduleRecord>, StoreError> {
        self.backend.schedule(id)
    }

    /// Every schedule, by id.
    pub fn schedules(&self) -> Result<Vec<ScheduleRecord>, StoreError> {
        self.backend.schedules()
    }

    /// Record an occurrence that submitted no job (missed and skipped, or refused) and
    /// move the schedule's `checked_until` to it.
    pub fn record_schedule_run(
        &self,
        schedule: i64,
        due: &str,
        outcome: &str,
        message: Option<&str>,
    ) -> Result<(), StoreError> {
        self.backend
            .record_schedule_run(schedule, due, outcome, message)
    }

    /// A schedule's occurrences, newest first.
    pub fn schedule_runs(&self, id: i64, limit: usize) -> Result<Vec<ScheduleRun>, StoreError> {
        self.backend.schedule_runs(id, limit)
    }
}
