//! Schedules on PostgreSQL: the same operations and rules as the SQLite module.

use postgres::Row;
use postgres::error::SqlState;

use super::{Pg, now};
use crate::store::backend::Schedules;
use crate::store::{MissedPolicy, NewSchedule, ScheduleRecord, ScheduleRun, StoreError};

const COLUMNS: &str = "id, name, cron, timezone, job, priority, missed, enabled, created_at, created_by, checked_until";

fn row(r: &Row) -> Result<ScheduleRecord, StoreError> {
    let missed: String = r.try_get(6)?;
    let enabled: i64 = r.try_get(7)?;
    Ok(ScheduleRecord {
        id: r.try_get(0)?,
        spec: NewSchedule {
            name: r.try_get(1)?,
            cron: r.try_get(2)?,
            timezone: r.try_get(3)?,
            job: serde_json::from_str(r.try_get(4)?)?,
            priority: r.try_get(5)?,
            missed: match missed.as_str() {
                "run_once" => MissedPolicy::RunOnce,
                "skip" => MissedPolicy::Skip,
                _ => {
                    return Err(StoreError::Corrupt {
                        column: "schedules.missed",
                        value: missed,
                    });
                }
            },
            enabled: enabled != 0,
        },
        created_at: r.try_get(8)?,
        created_by: r.try_get(9)?,
        checked_until: r.try_get(10)?,
    })
}

fn unique(e: postgres::Error, name: &str) -> StoreError {
    if e.code() == Some(&SqlState::UNIQUE_VIOLATION) {
        StoreError::Conflict(format!("a schedule named `{name}`"))
    } else {
        StoreError::Postgres(e)
    }
}

impl Schedules for Pg {
    fn insert_schedule(
        &self,
        s: &NewSchedule,
        created_by: Option<&str>,
        checked_until: &str,
    ) -> Result<i64, StoreError> {
        let job = serde_json::to_string(&s.job)?;
        let r = self
            .conn()?
            .query_one(
                "INSERT INTO schedules (name, cron, timezone, job, priority, missed, enabled, created_at, \
                 created_by, checked_until) VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10) RETURNING id",
                &[&s.name, &s.cron, &s.timezone, &job, &s.priority, &s.missed.as_str(), &i64::from(s.enabled), &now(), &created_by, &checked_until],
            )
            .map_err(|e| unique(e, &s.name))?;
        Ok(r.try_get(0)?)
    }

    fn update_schedule(
        &self,
        id: i64,
        s: &NewSchedule,
        checked_until: &str,
    ) -> Result<bool, StoreError> {
        let job = serde_json::to_string(&s.job)?;
        let n = self
            .conn()?
            .execute(
                "UPDATE schedules SET name = $2, cron = $3, timezone = $4, job = $5, priority = $6, \
                 missed = $7, enabled = $8, checked_until = $9 WHERE id = $1",
                &[&id, &s.name, &s.cron, &s.timezone, &job, &s.priority, &s.missed.as_str(), &i64::from(s.enabled), &checked_until],
            )
            .map_err(|e| unique(e, &s.name))?;
        Ok(n == 1)
    }

    fn delete_schedule(&self, id: i64) -> Result<bool, StoreError> {
        Ok(self
            .conn()?
            .execute("DELETE FROM schedules WHERE id = $1", &[&id])?
            == 1)
    }

    fn schedule(&self, id: i64) -> Result<Option<ScheduleRecord>, StoreError> {
        let r = self.conn()?.query_opt(
            &format!("SELECT {COLUMNS} FROM schedules WHERE id = $1"),
            &[&id],
        )?;
        r.as_ref().map(row).transpose()
    }

    fn schedules(&self) -> Result<Vec<ScheduleRecord>, StoreError> {
        let rows = self
            .conn()?
            .query(&format!("SELECT {COLUMNS} FROM schedules ORDER BY id"), &[])?;
        rows.iter().map(row).collect()
    }

    fn record_schedule_run(
        &self,
        schedule: i64,
        due: &str,
        outcome: &str,
        message: Option<&str>,
    ) -> Result<(), StoreError> {
        let mut c = self.conn()?;
        let mut tx = c.transaction()?;
        super::other::record_run_tx(&mut tx, schedule, due, outcome, None, message)?;
        tx.commit()?;
        Ok(())
    }

    fn schedule_runs(&self, id: i64, limit: usize) -> Result<Vec<ScheduleRun>, StoreError> {
        let rows = self.conn()?.query(
            "SELECT due_at, at, outcome, job_id, message FROM schedule_runs WHERE schedule_id = $1 \
             ORDER BY id DESC LIMIT $2",
            &[&id, &(limit as i64)],
        )?;
        rows.iter()
            .map(|r| {
                Ok(ScheduleRun {
                    due_at: r.try_get(0)?,
                    at: r.try_get(1)?,
                    outcome: r.try_get(2)?,
                    job_id: r.try_get(3)?,
                    message: r.try_get(4)?,
                })
            })
            .collect()
    }
}
