use serde_json::json;

use super::*;

mod journal;
mod shared;

fn job(kind: &str) -> NewJob {
    NewJob {
        kind: kind.into(),
        doc: json!({"kind": kind}),
        priority: 0,
        devices: vec![],
        inputs_sha256: [("job".to_owned(), "00".to_owned())].into(),
        submitted_by: Some("test".into()),
        schedule_id: None,
        rerun_of: None,
        schedule_run: None,
        idempotency: None,
    }
}

/// Where a store test runs: a fresh SQLite folder or a fresh PostgreSQL database.
pub(super) enum Fixture {
    Sqlite(tempfile::TempDir),
    Postgres(Location),
}

impl Fixture {
    /// A fresh SQLite folder.
    pub(super) fn sqlite() -> Fixture {
        Fixture::Sqlite(tempfile::tempdir().unwrap())
    }

    /// A fresh database on the process's throw-away cluster; None (and says so) when
    /// PostgreSQL is not installed.
    pub(super) fn postgres() -> Option<Fixture> {
        match testpg::Cluster::shared() {
            Some(c) => {
                let url = c.fresh_db().unwrap();
                Some(Fixture::Postgres(Location::parse(&url, None).unwrap()))
            }
            None => {
                eprintln!("skipped: PostgreSQL not installed");
                None
            }
        }
    }

    /// Open (again) the store of this fixture.
    pub(super) fn open(&self) -> Store {
        match self {
            Fixture::Sqlite(d) => Store::open(d.path()).unwrap(),
            Fixture::Postgres(l) => Store::open_location(l).unwrap(),
        }
    }
}

/// Each listed test runs once on SQLite (`sqlite::NAME`) and once on PostgreSQL
/// (`postgres::NAME`, which passes with "skipped" when PostgreSQL is not installed).
macro_rules! on_both {
    ($($name:ident),* $(,)?) => {
        mod sqlite {
            $(#[test] fn $name() { super::$name(&super::Fixture::sqlite()) })*
        }
        mod postgres {
            $(#[test] fn $name() {
                if let Some(f) = super::Fixture::postgres() { super::$name(&f) }
            })*
        }
    };
}

on_both!(
    job_life_and_result_in_one_piece,
    a_large_main_table_and_dataset_go_through_files,
    recovery_marks_running_jobs_interrupted_and_returns_queued_ones,
    datasets_are_content_addressed,
    schedules_are_unique_by_name_and_record_runs,
    idempotent_submission_and_campaign_state,
    a_run_whose_job_was_taken_writes_nothing,
    a_resumed_job_keeps_its_first_start_and_says_when_it_resumed,
    a_status_read_after_a_write_sees_the_write,
);

/// The store's clock has moved on from `t` (timestamps have millisecond resolution).
fn after(t: &str) {
    while format_time(chrono::Utc::now()).as_str() <= t {
        std::thread::yield_now();
    }
}

/// Pausing, resuming and starting a job again keeps its first `started_at`; `resumed_at`
/// is null until it is resumed, then the instant of the resume, in the job status JSON too.
fn a_resumed_job_keeps_its_first_start_and_says_when_it_resumed(f: &Fixture) {
    let s = f.open();
    let id = s.insert_job(&job("trical.campaign")).unwrap();
    let run = s.start_job(id).unwrap().unwrap();
    let first = s.job(id).unwrap().unwrap();
    let started = first.started_at.clone().unwrap();
    assert_eq!(first.resumed_at, None);
    let v = serde_json::to_value(&first).unwrap();
    assert!(
        v["resumed_at"].is_null() && v["started_at"] == json!(started),
        "{v}"
    );
    assert!(s.pause_job(run, "indicator stalled").unwrap());
    after(&started);
    let before_resume = format_time(chrono::Utc::now());
    assert!(s.resume_job(id, "operator").unwrap());
    let queued = s.job(id).unwrap().unwrap();
    assert_eq!(queued.state, JobState::Queued);
    assert_eq!(queued.started_at.as_deref(), Some(started.as_str()));
    let resumed = queued.resumed_at.clone().unwrap();
    assert!(
        resumed > started && resumed >= before_resume,
        "{started} {resumed}"
    );
    // Started again (a later attempt): the first start and the resume both stay.
    after(&resumed);
    let again = s.start_job(id).unwrap().unwrap();
    assert_eq!(again.attempt, 2);
    assert!(s.finish_job(again, &json!({}), None, &[], None).unwrap());
    let done = s.job(id).unwrap().unwrap();
    assert_eq!(done.state, JobState::Succeeded);
    assert_eq!(done.started_at.as_deref(), Some(started.as_str()));
    assert_eq!(done.resumed_at.as_deref(), Some(resumed.as_str()));
    assert!(done.finished_at.unwrap() > resumed);
    let v = serde_json::to_value(s.job(id).unwrap().unwrap()).unwrap();
    assert_eq!(
        (&v["started_at"], &v["resumed_at"]),
        (&json!(started), &json!(resumed))
    );
    // A job never resumed keeps a null `resumed_at` through its whole life.
    let other = s.insert_job(&job("serial.fk")).unwrap();
    let r = s.start_job(other).unwrap().unwrap();
    assert!(s.finish_job(r, &json!({}), None, &[], None).unwrap());
    assert_eq!(s.job(other).unwrap().unwrap().resumed_at, None);
}

/// A main table written to a file is stored whole (in chunks on SQLite), and a dataset
/// spools back to a file byte for byte, on both backends.
fn a_large_main_table_and_dataset_go_through_files(f: &Fixture) {
    let s = f.open();
    let dir = tempfile::tempdir().unwrap();
    let mut csv = String::from("x,y\n");
    for i in 0..20_000 {
        csv.push_str(&format!("{i},{}\n", i as f64 * 0.5));
    }
    let path = dir.path().join("main.csv");
    std::fs::write(&path, &csv).unwrap();
    let id = s.insert_job(&job("serial.fk")).unwrap();
    let run = s.start_job(id).unwrap().unwrap();
    assert!(
        s.finish_job(
            run,
            &json!({"rows": 20_000}),
            Some(super::MainTableCsv::File(&path)),
            &[],
            None
        )
        .unwrap()
    );
    assert_eq!(s.main_table_csv(id).unwrap().as_deref(), Some(csv.as_str()));
    let info = s.put_dataset("t.csv", "text/csv", csv.as_bytes()).unwrap();
    let back = dir.path().join("back.csv");
    assert!(s.dataset_to_file(&info.id, &back).unwrap());
    assert_eq!(std::fs::read_to_string(&back).unwrap(), csv);
}

/// Status reads (the in-place `job_now` and the blocking `job`) made between writes
/// answer what a store opened afresh on the same database reads, after every kind of
/// write: SQLite answers repeated reads from memory until the next write.
fn a_status_read_after_a_write_sees_the_write(f: &Fixture) {
    let s = f.open();
    let id = s.insert_job(&job("serial.fk")).unwrap();
    let other = s.insert_job(&job("serial.fk")).unwrap();
    let check = |what: &str| {
        for _ in 0..2 {
            let truth = f.open().job(id).unwrap();
            assert_eq!(s.job(id).unwrap(), truth, "job() after {what}");
            if let Some(now) = s.job_now(id) {
                assert_eq!(now.unwrap(), truth, "job_now() after {what}");
            }
        }
    };
    check("the insert");
    let run = s.start_job(id).unwrap().unwrap();
    check("the start");
    s.record_progress(run, 0.25, "fk", Some("a quarter"), false)
        .unwrap();
    check("a progress write");
    // A write to another job, and a log line, leave this one's record as it was.
    assert!(s.end_job(other, JobState::Cancelled, None).unwrap());
    s.log(Some(id), "info", "a line").unwrap();
    check("writes elsewhere");
    assert!(s.end_job(id, JobState::Failed, Some("it broke")).unwrap());
    check("the end");
    let r = s.job(id).unwrap().unwrap();
    assert_eq!(
        (r.state, r.error.as_deref()),
        (JobState::Failed, Some("it broke"))
    );
    assert_eq!(s.job(other).unwrap().unwrap().state, JobState::Cancelled);
    assert!(s.job(other + 100).unwrap().is_none());
}

fn job_life_and_result_in_one_piece(f: &Fixture) {
    let s = f.open();
    let id = s.insert_job(&job("serial.fk")).unwrap();
    assert_eq!(s.job(id).unwrap().unwrap().state, JobState::Queued);
    let run = s.start_job(id).unwrap().unwrap();
    assert!(
        s.start_job(id).unwrap().is_none(),
        "a running job cannot start twice"
    );
    s.record_progress(run, 0.5, "fk", None, true).unwrap();
    let r = s.job(id).unwrap().unwrap();
    assert_eq!(
        (r.state, r.progress, r.stage.as_deref()),
        (JobState::Running, 0.5, Some("fk"))
    );
    let art = crate::jobs::Artefact {
        name: "poses.csv".into(),
        media_type: "text/csv".into(),
        content: b"x\n1\n".to_vec(),
    };
    assert!(
        s.finish_job(
            run,
            &json!({"kind": "serial.fk", "poses": []}),
            Some(super::MainTableCsv::Text("x\n")),
            &[art.clone()],
            None
        )
        .unwrap()
    );
    let r = s.job(id).unwrap().unwrap();
    assert_eq!((r.state, r.progress), (JobState::Succeeded, 1.0));
    assert_eq!(s.result(id).unwrap().unwrap()["kind"], "serial.fk");
    assert_eq!(s.artefact(id, "poses.csv").unwrap().unwrap(), art);
    assert_eq!(s.artefacts(id).unwrap()[0].size, 4);
    assert_eq!(s.main_table_csv(id).unwrap().as_deref(), Some("x\n"));
    // A final job does not change state again, and a second result is refused.
    assert!(!s.end_job(id, JobState::Failed, Some("late")).unwrap());
    assert!(!s.finish_job(run, &json!({}), None, &[], None).unwrap());
    let logs: Vec<String> = s.logs(id).unwrap().into_iter().map(|l| l.message).collect();
    assert_eq!(logs, ["submitted by test", "started", "succeeded"]);
    assert_eq!(s.progress_history(id).unwrap().len(), 1);
}

fn recovery_marks_running_jobs_interrupted_and_returns_queued_ones(f: &Fixture) {
    let (a, b, c) = {
        let s = f.open();
        let a = s.insert_job(&job("serial.fk")).unwrap();
        let b = s.insert_job(&job("serial.identify")).unwrap();
        let c = s.insert_job(&job("serial.fk")).unwrap();
        s.start_job(a).unwrap();
        let run = s.start_job(c).unwrap().unwrap();
        s.finish_job(run, &json!({"ok": true}), None, &[], None)
            .unwrap();
        (a, b, c)
    };
    let s = f.open();
    let r = s.recover().unwrap();
    assert_eq!(r.interrupted, vec![a]);
    assert_eq!(r.queued.iter().map(|q| q.0).collect::<Vec<_>>(), vec![b]);
    assert_eq!(s.job(a).unwrap().unwrap().state, JobState::Interrupted);
    assert_eq!(s.job(c).unwrap().unwrap().state, JobState::Succeeded);
    assert_eq!(s.result(c).unwrap().unwrap()["ok"], true);
    // Listing with filters and a cursor.
    let all = s
        .jobs(&JobFilter {
            limit: 10,
            ..Default::default()
        })
        .unwrap();
    assert_eq!(all.iter().map(|j| j.id).collect::<Vec<_>>(), vec![c, b, a]);
    let fk = s
        .jobs(&JobFilter {
            kind: Some("serial.fk".into()),
            limit: 10,
            ..Default::default()
        })
        .unwrap();
    assert_eq!(fk.len(), 2);
    let page = s
        .jobs(&JobFilter {
            before: Some(c),
            limit: 1,
            ..Default::default()
        })
        .unwrap();
    assert_eq!(page[0].id, b);
    let q = s
        .jobs(&JobFilter {
            state: Some(JobState::Queued),
            limit: 10,
            ..Default::default()
        })
        .unwrap();
    assert_eq!(q.len(), 1);
}

fn datasets_are_content_addressed(f: &Fixture) {
    let s = f.open();
    let a = s.put_dataset("m.csv", "text/csv", b"q1\n1\n").unwrap();
    let b = s.put_dataset("again.csv", "text/csv", b"q1\n1\n").unwrap();
    assert_eq!(a, b, "the same content is one dataset");
    // Known SHA-256 of "q1\n1\n" (sha256sum).
    assert_eq!(a.id, crate::run::input::sha256_hex(b"q1\n1\n"));
    assert_eq!(s.dataset(&a.id).unwrap().unwrap(), b"q1\n1\n");
    assert_eq!(s.datasets().unwrap().len(), 1);
}

fn schedules_are_unique_by_name_and_record_runs(f: &Fixture) {
    let s = f.open();
    let spec = NewSchedule {
        name: "nightly".into(),
        cron: "0 2 * * *".into(),
        timezone: "Europe/Berlin".into(),
        job: json!({"kind": "serial.fk"}),
        priority: 1,
        missed: MissedPolicy::Skip,
        enabled: true,
    };
    let id = s
        .insert_schedule(&spec, Some("op"), "2026-01-01T00:00:00.000Z")
        .unwrap();
    assert!(matches!(
        s.insert_schedule(&spec, None, "2026-01-01T00:00:00.000Z"),
        Err(StoreError::Conflict(_))
    ));
    assert_eq!(s.schedule(id).unwrap().unwrap().spec, spec);
    s.record_schedule_run(
        id,
        "2026-01-02T01:00:00.000Z",
        "missed_skipped",
        Some("1 missed"),
    )
    .unwrap();
    let mut j = job("serial.fk");
    j.schedule_id = Some(id);
    j.schedule_run = Some(("2026-01-03T01:00:00.000Z".into(), "submitted".into(), None));
    let jid = s.insert_job(&j).unwrap();
    let runs = s.schedule_runs(id, 10).unwrap();
    assert_eq!(runs.len(), 2);
    assert_eq!(
        (runs[0].outcome.as_str(), runs[0].job_id),
        ("submitted", Some(jid))
    );
    assert_eq!(
        s.schedule(id).unwrap().unwrap().checked_until,
        "2026-01-03T01:00:00.000Z"
    );
    assert!(s.delete_schedule(id).unwrap());
    assert!(s.schedule(id).unwrap().is_none());
}

fn idempotent_submission_and_campaign_state(f: &Fixture) {
    use crate::procedures::{EntryStatus, JournalEntry};
    let s = f.open();
    let mut j = job("serial.fk");
    j.idempotency = Some(IdempotencyKey {
        key: "k1".into(),
        request_sha256: "aa".into(),
    });
    let (id, new) = s.insert_job_once(&j).unwrap();
    assert!(new);
    assert_eq!(s.insert_job_once(&j).unwrap(), (id, false));
    j.idempotency = Some(IdempotencyKey {
        key: "k1".into(),
        request_sha256: "bb".into(),
    });
    assert!(matches!(
        s.insert_job_once(&j),
        Err(StoreError::Conflict(_))
    ));
    assert_eq!(s.job_doc(id).unwrap().unwrap()["kind"], "serial.fk");
    // A campaign's journal, pause and resume.
    let run = s.start_job(id).unwrap().unwrap();
    for (index, status) in [(0, EntryStatus::Measured), (1, EntryStatus::Skipped)] {
        let e = JournalEntry {
            index,
            status,
            data: json!({"i": index}),
        };
        s.append_measurement(id, &e).unwrap();
    }
    let dup = JournalEntry {
        index: 1,
        status: EntryStatus::Measured,
        data: json!({}),
    };
    assert!(
        s.append_measurement(id, &dup).is_err(),
        "an index is journalled once"
    );
    let journal = s.measurements(id).unwrap();
    assert_eq!(journal.len(), 2);
    assert_eq!(
        (journal[1].index, journal[1].status),
        (1, EntryStatus::Skipped)
    );
    assert!(s.pause_job(run, "indicator lost").unwrap());
    assert_eq!(s.job(id).unwrap().unwrap().state, JobState::Paused);
    assert!(s.resume_job(id, "operator").unwrap());
    assert!(!s.resume_job(id, "twice").unwrap());
    let run = s.start_job(id).unwrap().unwrap();
    let d = crate::lab::Decision {
        cell: "c1".into(),
        accepted: true,
        reason: "ok".into(),
        validation: json!({"rms": 0.01}),
        model: json!({"dh": []}),
    };
    assert!(s.finish_job(run, &json!({}), None, &[], Some(&d)).unwrap());
    let m = s.current_cell_model("c1").unwrap().unwrap();
    assert_eq!((m.job_id, m.reason.as_str()), (Some(id), "ok"));
    assert_eq!(s.cell_models("c1").unwrap().len(), 1);
    let counts = s.count_by_state().unwrap();
    assert_eq!(counts, vec![(JobState::Succeeded, 1)]);
    s.log(None, "info", "daemon-wide").unwrap();
}

/// A run whose job was taken from it (here: the daemon restarted, the job was resumed and
/// started again) stores neither progress nor result nor end; the run that took it does.
fn a_run_whose_job_was_taken_writes_nothing(f: &Fixture) {
    let s = f.open();
    let id = s.insert_job(&job("serial.fk")).unwrap();
    let old = s.start_job(id).unwrap().unwrap();
    assert_eq!(old.attempt, 1);
    assert_eq!(s.recover().unwrap().interrupted, vec![id]);
    assert!(s.resume_job(id, "restart").unwrap());
    // Queued again: the old run no longer holds it.
    let stale = |r: Result<bool, StoreError>| matches!(r, Err(StoreError::Stale { job, attempt: 1 }) if job == id);
    assert!(stale(
        s.record_progress(old, 0.9, "late", None, true)
            .map(|()| true)
    ));
    let new = s.start_job(id).unwrap().unwrap();
    assert_eq!(new.attempt, 2);
    assert!(stale(
        s.record_progress(old, 0.9, "late", None, true)
            .map(|()| true)
    ));
    assert!(stale(s.finish_job(
        old,
        &json!({"by": "old"}),
        None,
        &[],
        None
    )));
    assert!(stale(s.end_run(old, JobState::Failed, Some("late"))));
    assert!(stale(s.pause_job(old, "late")));
    let r = s.job(id).unwrap().unwrap();
    assert_eq!((r.state, r.progress), (JobState::Running, 0.0));
    s.record_progress(new, 0.5, "fk", None, true).unwrap();
    assert!(
        s.finish_job(new, &json!({"by": "new"}), None, &[], None)
            .unwrap()
    );
    assert_eq!(s.result(id).unwrap().unwrap()["by"], "new");
    assert_eq!(s.progress_history(id).unwrap().len(), 1);
    // Once final, the old run is still refused as stale; the new one just finds it ended.
    assert!(stale(s.finish_job(old, &json!({}), None, &[], None)));
    assert!(!s.end_run(new, JobState::Failed, None).unwrap());
    // An operator's cancel is not a take-over: the run finds its job ended, no error.
    let id2 = s.insert_job(&job("serial.fk")).unwrap();
    let run = s.start_job(id2).unwrap().unwrap();
    assert!(s.end_job(id2, JobState::Cancelled, None).unwrap());
    assert!(!s.finish_job(run, &json!({}), None, &[], None).unwrap());
    s.record_progress(run, 0.5, "fk", None, false).unwrap();
}

#[cfg(unix)]
#[test]
fn the_data_folder_and_database_are_private_whatever_the_umask() {
    use std::os::unix::fs::PermissionsExt;
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    // A folder left world-readable by an earlier version (or a permissive umask).
    std::fs::create_dir(&data).unwrap();
    std::fs::set_permissions(&data, std::fs::Permissions::from_mode(0o755)).unwrap();
    let s = Store::open(&data).unwrap();
    s.insert_job(&job("serial.fk")).unwrap();
    let mode = |p: &Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode(&data), 0o700);
    for entry in std::fs::read_dir(&data).unwrap() {
        let p = entry.unwrap().path();
        assert_eq!(mode(&p), 0o600, "{} is readable by others", p.display());
    }
    assert!(
        data.join("calibd.sqlite3-wal").exists(),
        "WAL file checked too"
    );
}
