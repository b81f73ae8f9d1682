use serde_json::json;

use super::*;

fn job(kind: &str) -> NewJob {
    NewJob {
        kind: kind.into(),
        doc: json!({"kind": kind}),
        priority: 0,
        devices: vec![],
        inputs_sha256: json!({"job": "00"}),
        submitted_by: Some("test".into()),
        schedule_id: None,
        rerun_of: None,
        schedule_run: None,
        idempotency: None,
    }
}

#[test]
fn job_life_and_result_in_one_piece() {
    let dir = tempfile::tempdir().unwrap();
    let s = Store::open(dir.path()).unwrap();
    let id = s.insert_job(&job("serial.fk")).unwrap();
    assert_eq!(s.job(id).unwrap().unwrap().state, JobState::Queued);
    assert!(s.start_job(id).unwrap());
    assert!(
        !s.start_job(id).unwrap(),
        "a running job cannot start twice"
    );
    s.record_progress(id, 0.5, "fk", None, true).unwrap();
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
            id,
            &json!({"kind": "serial.fk", "poses": []}),
            Some("x\n"),
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
    assert!(!s.finish_job(id, &json!({}), None, &[], None).unwrap());
    let logs: Vec<String> = s.logs(id).unwrap().into_iter().map(|l| l.message).collect();
    assert_eq!(logs, ["submitted by test", "started", "succeeded"]);
    assert_eq!(s.progress_history(id).unwrap().len(), 1);
}

#[test]
fn recovery_marks_running_jobs_interrupted_and_returns_queued_ones() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b, c) = {
        let s = Store::open(dir.path()).unwrap();
        let a = s.insert_job(&job("serial.fk")).unwrap();
        let b = s.insert_job(&job("serial.identify")).unwrap();
        let c = s.insert_job(&job("serial.fk")).unwrap();
        s.start_job(a).unwrap();
        s.start_job(c).unwrap();
        s.finish_job(c, &json!({"ok": true}), None, &[], None)
            .unwrap();
        (a, b, c)
    };
    let s = Store::open(dir.path()).unwrap();
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

#[test]
fn datasets_are_content_addressed() {
    let dir = tempfile::tempdir().unwrap();
    let s = Store::open(dir.path()).unwrap();
    let a = s.put_dataset("m.csv", "text/csv", b"q1\n1\n").unwrap();
    let b = s.put_dataset("again.csv", "text/csv", b"q1\n1\n").unwrap();
    assert_eq!(a, b, "the same content is one dataset");
    // Known SHA-256 of "q1\n1\n" (sha256sum).
    assert_eq!(a.id, crate::jobs::input::sha256_hex(b"q1\n1\n"));
    assert_eq!(s.dataset(&a.id).unwrap().unwrap(), b"q1\n1\n");
    assert_eq!(s.datasets().unwrap().len(), 1);
}

#[test]
fn schedules_are_unique_by_name_and_record_runs() {
    let dir = tempfile::tempdir().unwrap();
    let s = Store::open(dir.path()).unwrap();
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
