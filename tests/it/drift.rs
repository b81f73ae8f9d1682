//! Drift watch on the simulated lab: a TriCal campaign calibrates the cell, a nightly
//! `cell.verify` with a drift policy records "within tolerance" on the first night; the
//! twin's true parameters drift before the second night, whose AP crosses the threshold:
//! the recalibration is submitted, a `drift` event and the decision metric fire, and the
//! cell's history (with its chart) holds both nights against the calibration.

use std::sync::Arc;
use std::time::Duration;

use calibd::lab::Lab;
use calibd::schedule::{Clock, Scheduler};
use calibd::service::{Event, Origin, Service, ServiceConfig, Submitter};
use calibd::sim::SimOptions;
use calibd::store::{JobState, MissedPolicy, NewSchedule, Store};
use chrono::TimeZone;
use serde_json::{Value, json};
use tokio_util::sync::CancellationToken;

fn campaign() -> Value {
    json!({
        "kind": "cell.trical_campaign",
        "cell": "irb120",
        "design": {"pool_per_ball": 16, "per_ball": 6, "seed": 3},
        "validation": {"per_ball": 2, "seed": 4},
        "options": {"centring": {"settle_ms": 40, "reading_timeout_ms": 400},
                    "retry": {"attempts": 4, "backoff_ms": 50}}
    })
}

fn verify() -> Value {
    json!({
        "kind": "cell.verify",
        "cell": "irb120",
        "poses": {"per_ball": 2},
        "cycles": 2,
        "drift": {"ap_threshold_mm": 0.05, "recalibrate": campaign()},
        "options": {"centring": {"settle_ms": 40, "reading_timeout_ms": 400}}
    })
}

async fn until_state(svc: &Service, id: i64, state: JobState) {
    for _ in 0..2400 {
        let j = svc.job(id).await.unwrap();
        if j.state == state {
            return;
        }
        assert!(
            !j.state.is_final(),
            "job {id} ended {:?}: {:?}",
            j.state,
            j.error
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("job {id} never reached {state:?}");
}

/// The schedule's runs once it has `n` of them (newest first).
async fn runs(store: &Store, sid: i64, n: usize) -> Vec<calibd::store::ScheduleRun> {
    for _ in 0..2400 {
        let r = store.schedule_runs(sid, 10).unwrap();
        if r.len() >= n {
            return r;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("schedule {sid} never had {n} runs");
}

/// The next drift event (on a timeout: the jobs' states and errors).
async fn drift_event(
    svc: &Service,
    rx: &mut tokio::sync::broadcast::Receiver<Event>,
) -> calibd::service::DriftEvent {
    loop {
        match tokio::time::timeout(Duration::from_secs(150), rx.recv()).await {
            Ok(Ok(Event::Drift(d))) => return d,
            Ok(Ok(_)) | Ok(Err(tokio::sync::broadcast::error::RecvError::Lagged(_))) => {}
            other => {
                let jobs = svc
                    .jobs(calibd::store::JobFilter {
                        limit: 10,
                        ..Default::default()
                    })
                    .await
                    .unwrap();
                let seen: Vec<_> = jobs
                    .iter()
                    .map(|j| (j.id, &j.kind, j.state, &j.error))
                    .collect();
                let runs = svc.schedules().await.unwrap();
                let h = svc.drift_history("irb120").await;
                panic!(
                    "no drift event: {other:?}; jobs {seen:?}; schedules {runs:?}; history {h:?}"
                )
            }
        }
    }
}

fn decisions(metrics: &str, action: &str) -> f64 {
    metrics
        .lines()
        .find(|l| {
            l.starts_with("calibd_drift_decisions_total")
                && l.contains(&format!("action=\"{action}\""))
                && l.contains("cell=\"irb120\"")
        })
        .and_then(|l| l.rsplit(' ').next())
        .and_then(|v| v.parse().ok())
        .unwrap_or(0.0)
}

/// Start the scheduler on a clock reading `wall`, stopped by the returned token.
fn scheduler(svc: &Service, wall: chrono::DateTime<chrono::Utc>) -> CancellationToken {
    let stop = CancellationToken::new();
    tokio::spawn(Scheduler::new(Clock::starting_at(wall)).run(svc.clone(), stop.clone()));
    stop
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_drifting_twin_triggers_the_recalibration_on_the_night_ap_crosses_the_threshold() {
    let _ = tracing_subscriber::fmt()
        .with_env_filter("calibd=warn")
        .with_test_writer()
        .try_init();
    let metrics = calibd::api::metrics_handle().expect("a metrics recorder");
    let before = |a| decisions(&metrics.render(), a);
    let (within0, recal0) = (before("within_tolerance"), before("recalibrate"));
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path()).unwrap();
    let opts = SimOptions::default();
    let twin = opts.trical.twin.clone();
    let lab = Arc::new(Lab::simulated(&opts).await.unwrap());
    let stop = CancellationToken::new();
    let cfg = ServiceConfig {
        workers: 1,
        ..Default::default()
    };
    let (svc, _w) = Service::start_with_lab(store.clone(), cfg, Some(lab), stop.clone())
        .await
        .unwrap();
    let mut events = svc.subscribe();
    let operator = Submitter {
        name: Some("test".into()),
        may_drive_devices: true,
    };
    // The calibration the nights are measured against.
    let cal = svc
        .submit(campaign(), 0, operator, Origin::default())
        .await
        .unwrap();
    until_state(&svc, cal, JobState::Succeeded).await;

    // Night 1 at 02:00 Berlin (01:00 UTC): the calibrated cell is within tolerance.
    let night = |d| chrono::Utc.with_ymd_and_hms(2026, 1, d, 0, 59, 58).unwrap();
    let sid = store
        .insert_schedule(
            &NewSchedule {
                name: "nightly-verify".into(),
                cron: "0 2 * * *".into(),
                timezone: "Europe/Berlin".into(),
                job: verify(),
                priority: 0,
                missed: MissedPolicy::Skip,
                enabled: true,
            },
            Some("operator"),
            &calibd::store::format_time(night(10)),
        )
        .unwrap();
    let s1 = scheduler(&svc, night(10));
    let d1 = drift_event(&svc, &mut events).await;
    s1.cancel();
    assert_eq!(d1.action, "within_tolerance", "{d1:?}");
    assert!(d1.ap_mm < 0.02 && d1.recalibration.is_none(), "{d1:?}");
    let r = runs(&store, sid, 2).await;
    assert_eq!(r[0].outcome, "within_tolerance", "{r:?}");
    assert_eq!(r[1].outcome, "submitted");

    // The true robot drifts during the day: joint 2 offset +0.05 deg, a2 +0.2 mm.
    {
        let cell = twin.get().expect("the simulated cell published its twin");
        let mut c = cell.lock().unwrap();
        for (name, dv) in [("theta_offset2", 0.05f64.to_radians()), ("a2", 0.2)] {
            let id = c.twin.truth.param_by_name(name).unwrap();
            let v = c.twin.truth.param(id);
            c.twin.truth.set_param(id, v + dv);
        }
    }

    // Night 2: AP crosses 0.05 mm, the recalibration campaign is submitted.
    let s2 = scheduler(&svc, night(11));
    let d2 = drift_event(&svc, &mut events).await;
    s2.cancel();
    assert_eq!(d2.action, "recalibrate", "{d2:?}");
    assert!(d2.ap_mm > 0.05, "{d2:?}");
    let recal = d2.recalibration.expect("the recalibration job");
    let job = svc.job(recal).await.unwrap();
    assert_eq!(job.kind, "cell.trical_campaign");
    assert_eq!(job.submitted_by.as_deref(), Some("drift:irb120"));
    let r = runs(&store, sid, 4).await;
    assert_eq!(r[0].outcome, "recalibration_submitted", "{r:?}");
    assert!(
        r[0].message
            .as_deref()
            .unwrap_or("")
            .contains(&format!("job {recal}"))
    );
    assert_eq!(
        decisions(&metrics.render(), "within_tolerance"),
        within0 + 1.0
    );
    assert_eq!(decisions(&metrics.render(), "recalibrate"), recal0 + 1.0);

    // The history: both nights after the calibration, the AP independently re-read from
    // each stored result, and drawn on the chart.
    let h = svc.drift_history("irb120").await.unwrap();
    assert_eq!(h.points.len(), 2);
    assert_eq!(h.last_calibration_job, Some(cal));
    assert_eq!(h.threshold_mm, Some(0.05));
    for (p, d) in h.points.iter().zip([&d1, &d2]) {
        assert_eq!(p.ap_mm, Some(d.ap_mm));
        assert!(p.nominal_ap_mm.unwrap() > 0.3, "{p:?}");
    }
    let svg = h.chart();
    let drawn: Vec<f64> = calibd::report::svg::series_marks(&svg, "ap")
        .iter()
        .map(|m| m.value)
        .collect();
    assert_eq!(drawn, vec![d1.ap_mm, d2.ap_mm]);
    let out = std::env::temp_dir().join("calibd-drift-chart.svg");
    std::fs::write(&out, &svg).unwrap();
    eprintln!(
        "drift: night 1 AP {:.4} mm ({}), night 2 AP {:.4} mm ({}); chart {}",
        d1.ap_mm,
        d1.action,
        d2.ap_mm,
        d2.action,
        out.display()
    );
    stop.cancel();
}
