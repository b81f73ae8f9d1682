use std::time::Duration;

use chrono::TimeZone;
use serde_json::json;

use super::*;
use crate::service::{Service, ServiceConfig};
use crate::store::{Store, format_time};

fn spec(cron: &str, missed: MissedPolicy) -> NewSchedule {
    NewSchedule {
        name: format!("s-{cron}-{}", missed.as_str()),
        cron: cron.into(),
        timezone: "Europe/Berlin".into(),
        job: crate::jobs::examples::twin_fk(2),
        priority: 0,
        missed,
        enabled: true,
    }
}

fn utc(y: i32, mo: u32, d: u32, h: u32, mi: u32) -> DateTime<Utc> {
    Utc.with_ymd_and_hms(y, mo, d, h, mi, 0).unwrap()
}

#[test]
fn rules_read_the_expression_in_their_time_zone() {
    let r = Rule::parse(&spec("0 2 * * *", MissedPolicy::Skip)).unwrap();
    // 02:00 in Berlin is 01:00 UTC in winter (CET) and 00:00 UTC in summer (CEST).
    assert_eq!(
        r.next_after(utc(2026, 1, 10, 0, 0)),
        Some(utc(2026, 1, 10, 1, 0))
    );
    assert_eq!(
        r.next_after(utc(2026, 7, 10, 0, 30)),
        Some(utc(2026, 7, 11, 0, 0))
    );
    assert_eq!(
        r.between(utc(2026, 1, 1, 0, 0), utc(2026, 1, 4, 0, 0), 100)
            .len(),
        3
    );
    let mut bad = spec("0 25 * * *", MissedPolicy::Skip);
    assert!(matches!(Rule::parse(&bad), Err(ScheduleError::Cron { .. })));
    bad.cron = "0 2 * * *".into();
    bad.timezone = "Mars/Olympus".into();
    assert!(
        Rule::parse(&bad)
            .unwrap_err()
            .to_string()
            .contains("Mars/Olympus")
    );
}

async fn start(clock: Clock) -> (tempfile::TempDir, Service, Scheduler, CancellationToken) {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path()).unwrap();
    let stop = CancellationToken::new();
    let cfg = ServiceConfig {
        workers: 1,
        ..Default::default()
    };
    let (svc, _workers) = Service::start(store, cfg, stop.clone()).await.unwrap();
    let sched = Scheduler::new(clock);
    (dir, svc, sched, stop)
}

/// Wait (in paused time) until `f` holds.
async fn until(mut f: impl FnMut() -> bool) {
    for _ in 0..20_000 {
        if f() {
            return;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
        std::thread::sleep(Duration::from_millis(1));
    }
    panic!("condition not reached");
}

#[tokio::test(start_paused = true)]
async fn the_overnight_schedule_fires_at_two_in_paused_time() {
    let clock = Clock::starting_at(utc(2026, 1, 10, 0, 30));
    let (_dir, svc, sched, stop) = start(clock).await;
    let store = svc.store().clone();
    let id = store
        .insert_schedule(
            &spec("0 2 * * *", MissedPolicy::RunOnce),
            Some("op"),
            &format_time(clock.now()),
        )
        .unwrap();
    tokio::spawn(sched.clone().run(svc.clone(), stop.clone()));
    // Nothing before 02:00 Berlin.
    tokio::time::sleep(Duration::from_secs(20 * 60)).await;
    assert!(store.schedule_runs(id, 10).unwrap().is_empty());
    // 02:00 Berlin = 01:00 UTC, then the next night.
    tokio::time::sleep(Duration::from_secs(25 * 3600)).await;
    until(|| store.schedule_runs(id, 10).unwrap().len() == 2).await;
    let runs = store.schedule_runs(id, 10).unwrap();
    assert_eq!(runs[1].due_at, "2026-01-10T01:00:00.000Z");
    assert_eq!(runs[0].due_at, "2026-01-11T01:00:00.000Z");
    assert!(runs.iter().all(|r| r.outcome == "submitted"));
    let job = store.job(runs[1].job_id.unwrap()).unwrap().unwrap();
    assert_eq!(
        (job.kind.as_str(), job.schedule_id),
        ("serial.fk", Some(id))
    );
    assert_eq!(
        job.submitted_by.as_deref(),
        Some("schedule:s-0 2 * * *-run_once")
    );
    stop.cancel();
}

#[tokio::test(start_paused = true)]
async fn missed_runs_follow_the_stated_policy() {
    // The daemon was down for three nights: 03:00 Berlin on 2026-01-13, last checked
    // 2026-01-10 00:00 UTC, so 02:00 on the 10th, 11th and 12th... and 13th were missed.
    let clock = Clock::starting_at(utc(2026, 1, 13, 2, 0));
    let (_dir, svc, sched, stop) = start(clock).await;
    let store = svc.store().clone();
    let from = "2026-01-10T00:00:00.000Z";
    let once = store
        .insert_schedule(&spec("0 2 * * *", MissedPolicy::RunOnce), None, from)
        .unwrap();
    let skip = store
        .insert_schedule(&spec("0 2 * * *", MissedPolicy::Skip), None, from)
        .unwrap();
    tokio::spawn(sched.clone().run(svc.clone(), stop.clone()));
    until(|| {
        !store.schedule_runs(once, 10).unwrap().is_empty()
            && !store.schedule_runs(skip, 10).unwrap().is_empty()
    })
    .await;
    let r = &store.schedule_runs(once, 10).unwrap()[0];
    assert_eq!(r.outcome, "missed_run_once");
    assert!(r.job_id.is_some());
    let m = r.message.clone().unwrap();
    assert!(
        m.contains(
            "4 occurrence(s) missed from 2026-01-10T01:00:00.000Z to 2026-01-13T01:00:00.000Z"
        ),
        "{m}"
    );
    let s = &store.schedule_runs(skip, 10).unwrap()[0];
    assert_eq!((s.outcome.as_str(), s.job_id), ("missed_skipped", None));
    // Exactly one job was submitted, and nothing more happens before the next night.
    tokio::time::sleep(Duration::from_secs(3600)).await;
    let jobs = store
        .jobs(&crate::store::JobFilter {
            limit: 10,
            ..Default::default()
        })
        .unwrap();
    assert_eq!(jobs.len(), 1);
    assert_eq!(store.schedule_runs(once, 10).unwrap().len(), 1);
    let _ = json!({});
    stop.cancel();
}
