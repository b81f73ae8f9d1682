//! Schedules: cron expressions with a time zone that submit a job, and the record of every
//! occurrence (submitted, missed and run once, missed and skipped, refused).

use rusqlite::{OptionalExtension, Row, params};
use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::{Store, StoreError, now};

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

pub(super) fn record_run_tx(
    c: &rusqlite::Connection,
    schedule: i64,
    due: &str,
    outcome: &str,
    job: Option<i64>,
    message: Option<&str>,
) -> rusqlite::Result<()> {
    c.execute(
        "INSERT INTO schedule_runs (schedule_id, due_at, at, outcome, job_id, message) \
         VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
        params![schedule, due, now(), outcome, job, message],
    )?;
    c.execute(
        "UPDATE schedules SET checked_until = max(checked_until, ?2) WHERE id = ?1",
        params![schedule, due],
    )?;
    Ok(())
}

const COLUMNS: &str = "id, name, cron, timezone, job, priority, missed, enabled, created_at, created_by, checked_until";

fn row(r: &Row<'_>) -> rusqlite::Result<(ScheduleRecord, String, String)> {
    Ok((
        ScheduleRecord {
            id: r.get(0)?,
            spec: NewSchedule {
                name: r.get(1)?,
                cron: r.get(2)?,
                timezone: r.get(3)?,
                job: Value::Null,
                priority: r.get(5)?,
                missed: MissedPolicy::RunOnce,
                enabled: r.get(7)?,
            },
            created_at: r.get(8)?,
            created_by: r.get(9)?,
            checked_until: r.get(10)?,
        },
        r.get(4)?,
        r.get(6)?,
    ))
}

fn finish(raw: (ScheduleRecord, String, String)) -> Result<ScheduleRecord, StoreError> {
    let (mut s, job, missed) = raw;
    s.spec.job = serde_json::from_str(&job)?;
    s.spec.missed = match missed.as_str() {
        "run_once" => MissedPolicy::RunOnce,
        "skip" => MissedPolicy::Skip,
        _ => {
            return Err(StoreError::Corrupt {
                column: "schedules.missed",
                value: missed,
            });
        }
    };
    Ok(s)
}

fn unique(e: rusqlite::Error, name: &str) -> StoreError {
    match e {
        rusqlite::Error::SqliteFailure(f, _)
            if f.code == rusqlite::ErrorCode::ConstraintViolation =>
        {
            StoreError::Conflict(format!("a schedule named `{name}`"))
        }
        other => StoreError::Sqlite(other),
    }
}

impl Store {
    /// Create a schedule; occurrences count from `checked_until` (normally now).
    pub fn insert_schedule(
        &self,
        s: &NewSchedule,
        created_by: Option<&str>,
        checked_until: &str,
    ) -> Result<i64, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.insert_schedule(s, created_by, checked_until);
        }
        let job = serde_json::to_string(&s.job)?;
        self.write(|c| {
            c.execute(
                "INSERT INTO schedules (name, cron, timezone, job, priority, missed, enabled, created_at, \
                 created_by, checked_until) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)",
                params![s.name, s.cron, s.timezone, job, s.priority, s.missed.as_str(), s.enabled, now(), created_by, checked_until],
            )
            .map_err(|e| unique(e, &s.name))?;
            Ok(c.last_insert_rowid())
        })
    }

    /// Replace a schedule's definition; false if there is none with this id.
    pub fn update_schedule(
        &self,
        id: i64,
        s: &NewSchedule,
        checked_until: &str,
    ) -> Result<bool, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.update_schedule(id, s, checked_until);
        }
        let job = serde_json::to_string(&s.job)?;
        self.write(|c| {
            let n = c
                .execute(
                    "UPDATE schedules SET name = ?2, cron = ?3, timezone = ?4, job = ?5, priority = ?6, \
                     missed = ?7, enabled = ?8, checked_until = ?9 WHERE id = ?1",
                    params![id, s.name, s.cron, s.timezone, job, s.priority, s.missed.as_str(), s.enabled, checked_until],
                )
                .map_err(|e| unique(e, &s.name))?;
            Ok(n == 1)
        })
    }

    /// Delete a schedule (its run records stay); false if there is none.
    pub fn delete_schedule(&self, id: i64) -> Result<bool, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.delete_schedule(id);
        }
        self.write(|c| Ok(c.execute("DELETE FROM schedules WHERE id = ?1", [id])? == 1))
    }

    /// One schedule.
    pub fn schedule(&self, id: i64) -> Result<Option<ScheduleRecord>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.schedule(id);
        }
        self.read(|c| {
            c.query_row(
                &format!("SELECT {COLUMNS} FROM schedules WHERE id = ?1"),
                [id],
                row,
            )
            .optional()?
            .map(finish)
            .transpose()
        })
    }

    /// Every schedule, by id.
    pub fn schedules(&self) -> Result<Vec<ScheduleRecord>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.schedules();
        }
        self.read(|c| {
            let mut st =
                c.prepare_cached(&format!("SELECT {COLUMNS} FROM schedules ORDER BY id"))?;
            let rows = st.query_map([], row)?;
            rows.map(|r| finish(r?)).collect()
        })
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
        if let Some(pg) = self.pg() {
            return pg.record_schedule_run(schedule, due, outcome, message);
        }
        self.write(|c| {
            let tx = c.transaction()?;
            record_run_tx(&tx, schedule, due, outcome, None, message)?;
            tx.commit()?;
            Ok(())
        })
    }

    /// A schedule's occurrences, newest first.
    pub fn schedule_runs(&self, id: i64, limit: usize) -> Result<Vec<ScheduleRun>, StoreError> {
        if let Some(pg) = self.pg() {
            return pg.schedule_runs(id, limit);
        }
        self.read(|c| {
            let mut st = c.prepare_cached(
                "SELECT due_at, at, outcome, job_id, message FROM schedule_runs WHERE schedule_id = ?1 \
                 ORDER BY id DESC LIMIT ?2",
            )?;
            let rows = st.query_map(params![id, limit as i64], |r| {
                Ok(ScheduleRun {
                    due_at: r.get(0)?,
                    at: r.get(1)?,
                    outcome: r.get(2)?,
                    job_id: r.get(3)?,
                    message: r.get(4)?,
                })
            })?;
            Ok(rows.collect::<Result<_, _>>()?)
        })
    }
}
