//! Schedules on SQLite.

use rusqlite::{OptionalExtension, Row, params};
use serde_json::Value;

use super::Sqlite;
use crate::store::backend::Schedules;
use crate::store::{MissedPolicy, NewSchedule, ScheduleRecord, ScheduleRun, StoreError, now};

/// Record a schedule occurrence within `c` and move the schedule's `checked_until`.
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

impl Schedules for Sqlite {
    fn insert_schedule(
        &self,
        s: &NewSchedule,
        created_by: Option<&str>,
        checked_until: &str,
    ) -> Result<i64, StoreError> {
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

    fn update_schedule(
        &self,
        id: i64,
        s: &NewSchedule,
        checked_until: &str,
    ) -> Result<bool, StoreError> {
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

    fn delete_schedule(&self, id: i64) -> Result<bool, StoreError> {
        self.write(|c| Ok(c.execute("DELETE FROM schedules WHERE id = ?1", [id])? == 1))
    }

    fn schedule(&self, id: i64) -> Result<Option<ScheduleRecord>, StoreError> {
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

    fn schedules(&self) -> Result<Vec<ScheduleRecord>, StoreError> {
        self.read(|c| {
            let mut st =
                c.prepare_cached(&format!("SELECT {COLUMNS} FROM schedules ORDER BY id"))?;
            let rows = st.query_map([], row)?;
            rows.map(|r| finish(r?)).collect()
        })
    }

    fn record_schedule_run(
        &self,
        schedule: i64,
        due: &str,
        outcome: &str,
        message: Option<&str>,
    ) -> Result<(), StoreError> {
        self.write(|c| {
            let tx = c.transaction()?;
            record_run_tx(&tx, schedule, due, outcome, None, message)?;
            tx.commit()?;
            Ok(())
        })
    }

    fn schedule_runs(&self, id: i64, limit: usize) -> Result<Vec<ScheduleRun>, StoreError> {
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
