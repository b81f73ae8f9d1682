//! The shared queue on PostgreSQL (skipped, and saying so, when it is not installed):
//! claims are exclusive under contention, leases expire and are re-queued, device jobs go
//! only to the daemon holding their devices, a cell belongs to one live daemon.

use std::collections::HashSet;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::{Fixture, job};
use crate::store::{CancelRequest, JobState, Store, StoreError};

fn pg() -> Option<Store> {
    Fixture::postgres().map(|f| f.open())
}

const LEASE: Duration = Duration::from_secs(30);

#[test]
fn concurrent_claims_take_each_job_exactly_once() {
    let Some(s) = pg() else { return };
    let n = 300;
    for _ in 0..n {
        s.insert_job(&job("serial.fk")).unwrap();
    }
    let seen = Arc::new(Mutex::new(Vec::new()));
    let latencies = Arc::new(Mutex::new(Vec::new()));
    let threads: Vec<_> = (0..6)
        .map(|t| {
            let (s, seen, lat) = (s.clone(), seen.clone(), latencies.clone());
            std::thread::spawn(move || {
                let me = format!("d{t}");
                loop {
                    let t0 = Instant::now();
                    let Some(c) = s.claim(&me, &[], LEASE).unwrap() else {
                        break;
                    };
                    lat.lock().unwrap().push(t0.elapsed());
                    assert!(
                        s.finish_job(c.run, &serde_json::json!({}), None, &[], None)
                            .unwrap()
                    );
                    seen.lock().unwrap().push(c.id);
                }
            })
        })
        .collect();
    for t in threads {
        t.join().unwrap();
    }
    let seen = seen.lock().unwrap();
    assert_eq!(seen.len(), n);
    assert_eq!(
        seen.iter().collect::<HashSet<_>>().len(),
        n,
        "a job claimed twice"
    );
    let mut lat = latencies.lock().unwrap().clone();
    lat.sort();
    eprintln!(
        "claim latency with 6 claimers: median {:?}, p95 {:?}",
        lat[lat.len() / 2],
        lat[lat.len() * 95 / 100]
    );
    assert!(s.claim("d0", &[], LEASE).unwrap().is_none());
}

#[test]
fn an_expired_lease_is_requeued_and_finished_elsewhere() {
    let Some(s) = pg() else { return };
    let id = s.insert_job(&job("serial.identify")).unwrap();
    let c = s
        .claim("a", &[], Duration::from_millis(200))
        .unwrap()
        .unwrap();
    assert_eq!((c.id, s.job_owner(id).unwrap().as_deref()), (id, Some("a")));
    assert!(
        s.requeue_expired().unwrap().is_empty(),
        "the lease still runs"
    );
    std::thread::sleep(Duration::from_millis(400));
    assert_eq!(s.requeue_expired().unwrap(), vec![id]);
    assert_eq!(s.job(id).unwrap().unwrap().state, JobState::Queued);
    let on_a = c.run;
    let c = s.claim("b", &[], LEASE).unwrap().unwrap();
    assert_eq!((c.id, c.run.attempt), (id, 2));
    assert_eq!(s.heartbeat("b", LEASE).unwrap(), 1);
    // a comes back and tries to store its result: refused, b's run is untouched.
    assert!(matches!(
        s.finish_job(on_a, &serde_json::json!({"by": "a"}), None, &[], None),
        Err(StoreError::Stale { attempt: 1, .. })
    ));
    assert!(matches!(
        s.record_progress(on_a, 0.9, "late", None, true),
        Err(StoreError::Stale { .. })
    ));
    assert_eq!(s.job_owner(id).unwrap().as_deref(), Some("b"));
    assert!(
        s.finish_job(c.run, &serde_json::json!({"by": "b"}), None, &[], None)
            .unwrap()
    );
    assert_eq!(s.result(id).unwrap().unwrap()["by"], "b");
    let logs: Vec<String> = s.logs(id).unwrap().into_iter().map(|l| l.message).collect();
    assert_eq!(
        logs,
        [
            "submitted by test",
            "started on a",
            "re-queued: its daemon's lease expired",
            "started on b",
            "succeeded"
        ]
    );
}

#[test]
fn device_jobs_go_to_the_daemon_holding_the_cell() {
    let Some(s) = pg() else { return };
    let stale = Duration::from_secs(10);
    s.register_daemon("a", &["cell1".into()], stale).unwrap();
    assert!(matches!(
        s.register_daemon("b", &["cell1".into()], stale),
        Err(StoreError::Conflict(_))
    ));
    s.register_daemon("b", &["cell2".into()], stale).unwrap();
    assert_eq!(
        s.cell_owners().unwrap(),
        [("cell1".into(), "a".into()), ("cell2".into(), "b".into())]
    );
    let mut j = job("cell.trical");
    j.devices = vec!["cell1.robot".into(), "cell1.indicators".into()];
    let dev = s.insert_job(&j).unwrap();
    let num = s.insert_job(&job("serial.fk")).unwrap();
    let b_devices = ["cell2.robot".to_string()];
    let a_devices = ["cell1.robot".to_string(), "cell1.indicators".to_string()];
    assert_eq!(s.claim("b", &b_devices, LEASE).unwrap().unwrap().id, num);
    assert!(
        s.claim("b", &b_devices, LEASE).unwrap().is_none(),
        "not b's cell"
    );
    assert_eq!(s.claim("a", &a_devices, LEASE).unwrap().unwrap().id, dev);
}

#[test]
fn a_cancel_reaches_the_daemon_running_the_job() {
    let Some(s) = pg() else { return };
    let queued = s.insert_job(&job("serial.fk")).unwrap();
    let running = s.insert_job(&job("serial.identify")).unwrap();
    assert_eq!(s.request_cancel(queued).unwrap(), CancelRequest::Ended);
    assert_eq!(s.job(queued).unwrap().unwrap().state, JobState::Cancelled);
    let c = s.claim("b", &[], LEASE).unwrap().unwrap();
    assert_eq!(c.id, running);
    assert!(s.cancel_requests("b").unwrap().is_empty());
    assert_eq!(s.request_cancel(running).unwrap(), CancelRequest::Requested);
    assert_eq!(s.cancel_requests("b").unwrap(), vec![running]);
    assert!(s.cancel_requests("a").unwrap().is_empty());
    // b stops it; a second cancel finds it final.
    assert!(s.end_run(c.run, JobState::Cancelled, None).unwrap());
    assert!(s.cancel_requests("b").unwrap().is_empty());
    assert_eq!(
        s.request_cancel(running).unwrap(),
        CancelRequest::Final(JobState::Cancelled)
    );
    assert_eq!(s.request_cancel(999_999).unwrap(), CancelRequest::Missing);
    // A flagged job whose daemon dies ends cancelled instead of going back to the queue.
    let third = s.insert_job(&job("serial.fk")).unwrap();
    let c = s
        .claim("c", &[], Duration::from_millis(100))
        .unwrap()
        .unwrap();
    assert_eq!(c.id, third);
    assert_eq!(s.request_cancel(third).unwrap(), CancelRequest::Requested);
    let t0 = Instant::now();
    while s.job(third).unwrap().unwrap().state == JobState::Running {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "the lease never expired"
        );
        s.requeue_expired().unwrap();
    }
    assert_eq!(s.job(third).unwrap().unwrap().state, JobState::Cancelled);
}

#[test]
fn sqlite_refuses_the_shared_queue() {
    let f = Fixture::sqlite();
    let s = f.open();
    assert!(!s.is_shared());
    assert!(matches!(
        s.claim("a", &[], LEASE),
        Err(StoreError::Unsupported(_))
    ));
}

#[test]
fn a_sqlite_history_copies_into_postgres() {
    let Some(pgf) = Fixture::postgres() else {
        return;
    };
    let sf = Fixture::sqlite();
    let s = sf.open();
    let a = s.insert_job(&job("serial.fk")).unwrap();
    let run = s.start_job(a).unwrap().unwrap();
    s.record_progress(run, 0.5, "fk", Some("half"), true)
        .unwrap();
    let art = crate::jobs::Artefact {
        name: "poses.csv".into(),
        media_type: "text/csv".into(),
        content: b"x\n1\n".to_vec(),
    };
    s.finish_job(
        run,
        &serde_json::json!({"ok": 1}),
        Some(crate::store::MainTableCsv::Text("x\n")),
        std::slice::from_ref(&art),
        None,
    )
    .unwrap();
    let b = s.insert_job(&job("serial.identify")).unwrap();
    s.put_dataset("m.csv", "text/csv", b"q1\n1\n").unwrap();
    let p = pgf.open();
    let copied = s.copy_to(&p).unwrap();
    assert!(
        copied.contains(&("jobs", 2)) && copied.contains(&("artefacts", 1)),
        "{copied:?}"
    );
    assert_eq!(p.job(a).unwrap(), s.job(a).unwrap());
    assert_eq!(p.job(b).unwrap(), s.job(b).unwrap());
    assert_eq!(p.result(a).unwrap(), s.result(a).unwrap());
    assert_eq!(p.artefact(a, "poses.csv").unwrap(), Some(art));
    assert_eq!(
        p.progress_history(a).unwrap(),
        s.progress_history(a).unwrap()
    );
    assert_eq!(p.logs(a).unwrap(), s.logs(a).unwrap());
    assert_eq!(p.datasets().unwrap(), s.datasets().unwrap());
    // Ids go on after the copied ones; a second copy is refused.
    assert!(p.insert_job(&job("serial.fk")).unwrap() > b);
    assert!(matches!(s.copy_to(&p), Err(StoreError::Conflict(_))));
}

#[test]
fn store_locations_parse_and_never_show_the_password() {
    use crate::store::Location;
    assert_eq!(
        Location::parse("sqlite:/var/lib/calibd", None).unwrap(),
        Location::Sqlite("/var/lib/calibd".into())
    );
    assert!(Location::parse("sqlite:", None).is_err());
    assert!(Location::parse("mysql://u@h/db", None).is_err());
    let e = Location::parse("postgres://u:hunter2@h/db", None).unwrap_err();
    assert!(!e.to_string().contains("hunter2"), "{e}");
    let l = Location::parse(
        "postgres://calibd@db.lab:5432/calibd",
        Some("s3cret".into()),
    )
    .unwrap();
    let shown = format!("{l:?} {}", l.display());
    assert!(
        !shown.contains("s3cret") && shown.contains("password set"),
        "{shown}"
    );
    // The settings: a password file's first line; unset `store` is the SQLite default.
    let dir = tempfile::tempdir().unwrap();
    let pw = dir.path().join("pw");
    std::fs::write(&pw, "s3cret\n").unwrap();
    let mut c = crate::config::Config::default();
    assert_eq!(
        c.store_location(&|_| None).unwrap(),
        Location::Sqlite(c.data.clone())
    );
    c.store = Some("postgres://calibd@db.lab/calibd".into());
    c.password_file = Some(pw);
    let l = c.store_location(&|_| None).unwrap();
    assert!(format!("{l:?}").contains("password set"));
}
