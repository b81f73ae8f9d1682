use std::time::Duration;

use serde_json::json;
use tokio_util::sync::CancellationToken;

use super::*;
use crate::store::Store;

async fn service(workers: usize) -> (tempfile::TempDir, Service, Workers, CancellationToken) {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path()).unwrap();
    let stop = CancellationToken::new();
    let cfg = ServiceConfig {
        workers,
        ..Default::default()
    };
    let (svc, w) = Service::start(store, cfg, stop.clone()).await.unwrap();
    (dir, svc, w, stop)
}

async fn wait_final(svc: &Service, id: i64) -> JobRecord {
    for _ in 0..6000 {
        let j = svc.job(id).await.unwrap();
        if j.state.is_final() {
            return j;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    panic!("job {id} did not finish");
}

fn who() -> Submitter {
    Submitter {
        name: Some("test".into()),
        may_drive_devices: false,
    }
}

/// A job that cannot finish within a test (80,000 identifications: minutes on two cores)
/// and polls for cancellation between them, so a test that waits for it to run never sees
/// it end first.
fn slow_job() -> Value {
    crate::jobs::examples::twin_dispersion(&[30, 60, 90, 120], 20_000)
}

/// Wait (on the state events, however loaded the machine) until job `id` is `state`.
async fn wait_state(svc: &Service, id: i64, state: JobState) {
    let mut events = svc.subscribe();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(600);
    loop {
        // Checked after subscribing, so a change between the check and the wait is seen.
        let now = svc.job(id).await.unwrap().state;
        if now == state {
            return;
        }
        assert!(
            !now.is_final(),
            "job {id} ended {now:?} while waiting for {state:?}"
        );
        match tokio::time::timeout_at(deadline, events.recv()).await {
            Ok(Err(tokio::sync::broadcast::error::RecvError::Closed)) => {
                panic!("the service stopped while job {id} waited for {state:?}")
            }
            Ok(_) => {}
            Err(_) => panic!("job {id} did not become {state:?}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_job_runs_to_a_stored_result_with_events_in_order() {
    let (_d, svc, _w, stop) = service(1).await;
    let mut events = svc.subscribe();
    let id = svc
        .submit(
            crate::jobs::examples::twin_fk(5),
            0,
            who(),
            Origin::default(),
        )
        .await
        .unwrap();
    let j = wait_final(&svc, id).await;
    assert_eq!(j.state, JobState::Succeeded, "{:?}", j.error);
    let r = svc.store().result(id).unwrap().unwrap();
    assert_eq!(r["kind"], "serial.fk");
    assert_eq!(r["poses"].as_array().unwrap().len(), 5);
    assert_eq!(
        svc.store()
            .main_table_csv(id)
            .unwrap()
            .unwrap()
            .lines()
            .count(),
        6
    );
    let mut states = vec![];
    while let Ok(e) = events.try_recv() {
        if let Event::State { state, .. } = e {
            states.push(state);
        }
    }
    assert_eq!(
        states,
        [JobState::Queued, JobState::Running, JobState::Succeeded]
    );
    stop.cancel();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn invalid_jobs_are_refused_with_the_field() {
    let (_d, svc, _w, stop) = service(1).await;
    let mut doc = crate::jobs::examples::twin_fk(2);
    doc["joints"][1]["q3"] = json!("x");
    let e = svc
        .submit(doc, 0, who(), Origin::default())
        .await
        .unwrap_err();
    assert!(matches!(e, ServiceError::Invalid(_)), "{e}");
    assert!(e.to_string().contains("joints"), "{e}");
    let e = svc
        .submit(
            json!({"kind": "serial.fk", "model": "0123", "joints": []}),
            0,
            who(),
            Origin::default(),
        )
        .await
        .unwrap_err();
    assert!(e.to_string().contains("no uploaded dataset"), "{e}");
    assert!(
        svc.store()
            .jobs(&JobFilter {
                limit: 5,
                ..Default::default()
            })
            .unwrap()
            .is_empty()
    );
    stop.cancel();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn queued_and_running_jobs_can_be_cancelled() {
    let (_d, svc, _w, stop) = service(1).await;
    let slow = svc
        .submit(slow_job(), 0, who(), Origin::default())
        .await
        .unwrap();
    let queued = svc
        .submit(
            crate::jobs::examples::twin_fk(1),
            0,
            who(),
            Origin::default(),
        )
        .await
        .unwrap();
    // Wait until the slow job runs, then cancel both.
    wait_state(&svc, slow, JobState::Running).await;
    assert_eq!(
        svc.cancel(queued, &who()).await.unwrap(),
        JobState::Cancelled
    );
    assert_eq!(svc.cancel(slow, &who()).await.unwrap(), JobState::Running);
    let j = wait_final(&svc, slow).await;
    assert_eq!(j.state, JobState::Cancelled);
    assert!(svc.store().result(slow).unwrap().is_none());
    assert!(matches!(
        svc.cancel(slow, &who()).await,
        Err(ServiceError::Conflict(_))
    ));
    assert!(matches!(
        svc.cancel(999, &who()).await,
        Err(ServiceError::NotFound(999))
    ));
    stop.cancel();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_marks_a_running_job_interrupted_and_queued_jobs_survive() {
    let (d, svc, w, stop) = service(1).await;
    let slow = svc
        .submit(slow_job(), 0, who(), Origin::default())
        .await
        .unwrap();
    wait_state(&svc, slow, JobState::Running).await;
    // Queued behind the running job (the only worker is busy).
    let next = svc
        .submit(
            crate::jobs::examples::twin_fk(1),
            5,
            who(),
            Origin::default(),
        )
        .await;
    let next = next.unwrap();
    stop.cancel();
    w.join().await;
    let j = svc.store().job(slow).unwrap().unwrap();
    assert_eq!(j.state, JobState::Interrupted);
    assert_eq!(
        svc.store().job(next).unwrap().unwrap().state,
        JobState::Queued
    );
    drop(svc);
    // A new service picks the queued job up again.
    let store = Store::open(d.path()).unwrap();
    let stop = CancellationToken::new();
    let (svc, _w) = Service::start(
        store,
        ServiceConfig {
            workers: 1,
            ..Default::default()
        },
        stop.clone(),
    )
    .await
    .unwrap();
    assert_eq!(wait_final(&svc, next).await.state, JobState::Succeeded);
    assert_eq!(
        svc.store().job(slow).unwrap().unwrap().state,
        JobState::Interrupted
    );
    stop.cancel();
}
