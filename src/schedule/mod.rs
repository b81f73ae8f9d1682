//! Schedules: cron expressions read in a time zone (e.g. the overnight recalibration at
//! `0 2 * * *` in `Europe/Berlin`) that submit a job through the service. Occurrences are
//! handled in order from each schedule's `checked_until`; one that is more than
//! [`GRACE`] late, or several at once, were missed while the daemon was down and follow
//! the schedule's policy: `run_once` submits one job for all of them, `skip` submits none.
//! Either way the store records what happened. The clock is tokio's, so tests run whole
//! nights in paused time.

use std::str::FromStr;
use std::sync::Arc;
use std::time::Duration;

use chrono::{DateTime, Utc};
use chrono_tz::Tz;
use croner::Cron;
use tokio::sync::Notify;
use tokio_util::sync::CancellationToken;

use crate::service::{Origin, ScheduleOrigin, Service, Submitter};
use crate::store::{MissedPolicy, NewSchedule, ScheduleRecord, format_time};

/// An occurrence handled later than this counts as missed.
pub const GRACE: Duration = Duration::from_secs(60);

/// Most missed occurrences counted one by one (beyond this the count is a lower bound).
const MAX_COUNT: usize = 10_000;

/// Why a schedule is invalid.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ScheduleError {
    /// The cron expression does not parse.
    #[error("`cron`: `{expr}` is not a cron expression: {message}")]
    Cron {
        /// The expression.
        expr: String,
        /// Why.
        message: String,
    },
    /// The time zone is unknown.
    #[error("`timezone`: `{0}` is not an IANA time zone name (e.g. Europe/Berlin, UTC)")]
    TimeZone(String),
    /// The expression never fires.
    #[error("`cron`: `{0}` has no future occurrence")]
    Never(String),
    /// The job is not an object with a kind.
    #[error("`job`: {0}")]
    Job(String),
}

/// A parsed schedule: expression and zone.
#[derive(Debug, Clone)]
pub struct Rule {
    cron: Cron,
    tz: Tz,
}

impl Rule {
    /// Parse and check a schedule's expression, zone and job shape.
    pub fn parse(s: &NewSchedule) -> Result<Rule, ScheduleError> {
        let cron = Cron::from_str(&s.cron).map_err(|e| ScheduleError::Cron {
            expr: s.cron.clone(),
            message: e.to_string(),
        })?;
        let tz =
            Tz::from_str(&s.timezone).map_err(|_| ScheduleError::TimeZone(s.timezone.clone()))?;
        if !s.job.get("kind").is_some_and(|k| k.is_string()) {
            return Err(ScheduleError::Job(
                "must be a job document with a `kind`".into(),
            ));
        }
        let r = Rule { cron, tz };
        if r.next_after(Utc::now()).is_none() {
            return Err(ScheduleError::Never(s.cron.clone()));
        }
        Ok(r)
    }

    /// The first occurrence strictly after `t`.
    pub fn next_after(&self, t: DateTime<Utc>) -> Option<DateTime<Utc>> {
        self.cron
            .find_next_occurrence(&t.with_timezone(&self.tz), false)
            .ok()
            .map(|d| d.with_timezone(&Utc))
    }

    /// The shortest gap between consecutive occurrences among the first `count` after
    /// `from` (None if fewer than two occur): how often the schedule really fires, DST
    /// changes included.
    pub fn shortest_interval(&self, from: DateTime<Utc>, count: usize) -> Option<Duration> {
        let mut prev = self.next_after(from)?;
        let mut best: Option<Duration> = None;
        for _ in 1..count {
            let Some(n) = self.next_after(prev) else {
                break;
            };
            let gap = (n - prev).to_std().unwrap_or(Duration::ZERO);
            best = Some(best.map_or(gap, |b| b.min(gap)));
            prev = n;
        }
        best
    }

    /// Occurrences in (`from`, `to`], at most `max`.
    pub fn between(
        &self,
        from: DateTime<Utc>,
        to: DateTime<Utc>,
        max: usize,
    ) -> Vec<DateTime<Utc>> {
        let mut out = Vec::new();
        let mut t = from;
        while out.len() < max {
            match self.next_after(t) {
                Some(n) if n <= to => {
                    out.push(n);
                    t = n;
                }
                _ => break,
            }
        }
        out
    }
}

/// Wall-clock time driven by tokio's clock (so paused time moves it).
#[derive(Debug, Clone, Copy)]
pub struct Clock {
    wall0: DateTime<Utc>,
    inst0: tokio::time::Instant,
}

impl Clock {
    /// The system clock.
    pub fn system() -> Clock {
        Clock::starting_at(Utc::now())
    }

    /// A clock that reads `wall` now and advances with tokio's clock.
    pub fn starting_at(wall: DateTime<Utc>) -> Clock {
        Clock {
            wall0: wall,
            inst0: tokio::time::Instant::now(),
        }
    }

    /// The current time.
    pub fn now(&self) -> DateTime<Utc> {
        let d = tokio::time::Instant::now().duration_since(self.inst0);
        self.wall0 + chrono::Duration::from_std(d).unwrap_or(chrono::TimeDelta::zero())
    }

    /// The tokio instant at which the clock reads `t`.
    pub fn instant_of(&self, t: DateTime<Utc>) -> tokio::time::Instant {
        let d = (t - self.wall0).to_std().unwrap_or(Duration::ZERO);
        self.inst0 + d
    }
}

/// Handle to the scheduler task: lets the API ask for a reload after a change.
#[derive(Debug, Clone)]
pub struct Scheduler {
    reload: Arc<Notify>,
    clock: Clock,
}

impl Scheduler {
    /// A scheduler reading time from `clock`.
    pub fn new(clock: Clock) -> Scheduler {
        Scheduler {
            reload: Arc::new(Notify::new()),
            clock,
        }
    }

    /// The scheduler's current time.
    pub fn now(&self) -> DateTime<Utc> {
        self.clock.now()
    }

    /// Re-read the schedules (after a create, update or delete).
    pub fn reload(&self) {
        self.reload.notify_one();
    }

    /// Run until `shutdown`: submit due jobs, apply the missed-run policy.
    pub async fn run(self, service: Service, shutdown: CancellationToken) {
        loop {
            let now = self.clock.now();
            let mut wake: Option<DateTime<Utc>> = None;
            let schedules = match service.schedules().await {
                Ok(s) => s,
                Err(e) => {
                    tracing::error!(error = %e, "reading schedules failed; retrying in 60 s");
                    wake = Some(now + chrono::TimeDelta::seconds(60));
                    Vec::new()
                }
            };
            for s in schedules.iter().filter(|s| s.spec.enabled) {
                let Ok(rule) = Rule::parse(&s.spec) else {
                    continue;
                };
                let from = DateTime::parse_from_rfc3339(&s.checked_until)
                    .map(|d| d.with_timezone(&Utc))
                    .unwrap_or(now);
                let due = rule.between(from, now, MAX_COUNT);
                if !due.is_empty() {
                    handle(&service, s, &due, now).await;
                }
                if let Some(n) = rule.next_after(now.max(from)) {
                    wake = Some(wake.map_or(n, |w| w.min(n)));
                }
            }
            let sleep_until = match wake {
                Some(w) => self.clock.instant_of(w),
                None => tokio::time::Instant::now() + Duration::from_secs(3600),
            };
            tokio::select! {
                _ = shutdown.cancelled() => return,
                _ = self.reload.notified() => {}
                _ = tokio::time::sleep_until(sleep_until) => {}
            }
        }
    }
}

/// Handle the occurrences `due` (in order, all <= now) of schedule `s`.
async fn handle(service: &Service, s: &ScheduleRecord, due: &[DateTime<Utc>], now: DateTime<Utc>) {
    let last = due[due.len() - 1];
    let on_time = due.len() == 1 && (now - last).to_std().unwrap_or_default() <= GRACE;
    let count = if due.len() >= MAX_COUNT {
        format!("at least {}", due.len())
    } else {
        due.len().to_string()
    };
    let (outcome, message) = if on_time {
        ("submitted", None)
    } else {
        let span = format!(
            "{count} occurrence(s) missed from {} to {}",
            format_time(due[0]),
            format_time(last)
        );
        match s.spec.missed {
            MissedPolicy::RunOnce => ("missed_run_once", Some(format!("{span}; ran once"))),
            MissedPolicy::Skip => ("missed_skipped", Some(format!("{span}; skipped by policy"))),
        }
    };
    let due_s = format_time(last);
    if outcome == "missed_skipped" {
        tracing::warn!(schedule = %s.spec.name, message = message.as_deref().unwrap_or(""), "missed runs skipped");
        let recorded = service
            .record_schedule_run(s.id, due_s, "missed_skipped", message.clone())
            .await;
        if let Err(e) = recorded {
            tracing::error!(schedule = %s.spec.name, error = %e, "recording a skipped run failed");
        }
        return;
    }
    let origin = Origin {
        schedule: Some(ScheduleOrigin {
            id: s.id,
            due: due_s.clone(),
            outcome: outcome.into(),
            message: message.clone(),
        }),
        ..Default::default()
    };
    let who = Submitter {
        name: Some(format!("schedule:{}", s.spec.name)),
        // Only operators create schedules.
        may_drive_devices: true,
    };
    match service
        .submit(s.spec.job.clone(), s.spec.priority, who, origin)
        .await
    {
        Ok(job) => {
            tracing::info!(schedule = %s.spec.name, job, outcome, "schedule submitted a job")
        }
        Err(e) => {
            tracing::error!(schedule = %s.spec.name, error = %e, "schedule's job was refused");
            let recorded = service
                .record_schedule_run(s.id, due_s, "refused", Some(e.to_string()))
                .await;
            if let Err(e) = recorded {
                tracing::error!(schedule = %s.spec.name, error = %e, "recording a refused run failed");
            }
        }
    }
}

#[cfg(test)]
mod tests;
