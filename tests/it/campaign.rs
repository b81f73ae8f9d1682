//! TriCal campaigns in the daemon's service against the simulated lab, over the real RWS
//! and U-WAVE protocols: device faults are retried, persistent ones pause the campaign, and
//! a resumed campaign ends with exactly the measurement set of an uninterrupted one; the
//! overnight schedule runs a campaign and the cell's model is replaced only when validation
//! improves.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use calibd::lab::Lab;
use calibd::procedures::JournalEntry;
use calibd::schedule::{Clock, Scheduler};
use calibd::service::{Origin, Service, ServiceConfig, Submitter};
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
        "options": {
            "centring": {"settle_ms": 40, "reading_timeout_ms": 400},
            "retry": {"attempts": 4, "backoff_ms": 50}
        }
    })
}

struct Daemon {
    _dir: tempfile::TempDir,
    svc: Service,
    lab: Arc<Lab>,
    stop: CancellationToken,
}

async fn daemon(opts: SimOptions) -> Daemon {
    let dir = tempfile::tempdir().unwrap();
    let store = Store::open(dir.path()).unwrap();
    let lab = Arc::new(Lab::simulated(&opts).await.unwrap());
    let stop = CancellationToken::new();
    let cfg = ServiceConfig {
        workers: 1,
        ..Default::default()
    };
    let (svc, _w) = Service::start_with_lab(store, cfg, Some(lab.clone()), stop.clone())
        .await
        .unwrap();
    Daemon {
        _dir: dir,
        svc,
        lab,
        stop,
    }
}

fn operator() -> Submitter {
    Submitter {
        name: Some("test".into()),
        may_drive_devices: true,
    }
}

/// Wait until job `id` is in one of `states` (or fail after two minutes).
async fn until_state(svc: &Service, id: i64, states: &[JobState]) -> calibd::store::JobRecord {
    for _ in 0..1200 {
        let j = svc.job(id).await.unwrap();
        if states.contains(&j.state) {
            return j;
        }
        assert!(
            !j.state.is_final() || states.contains(&j.state),
            "job {id} ended {:?}: {:?}",
            j.state,
            j.error
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("job {id} never reached {states:?}");
}

async fn journal(svc: &Service, id: i64) -> Vec<JournalEntry> {
    let v = svc.measurements(id).await.unwrap();
    serde_json::from_value(v["entries"].clone()).unwrap()
}

async fn uninterrupted() -> (Vec<JournalEntry>, Value) {
    let d = daemon(SimOptions::default()).await;
    let id = d
        .svc
        .submit(campaign(), 0, operator(), Origin::default())
        .await
        .unwrap();
    until_state(&d.svc, id, &[JobState::Succeeded]).await;
    let r = d.svc.store().result(id).unwrap().unwrap();
    let j = journal(&d.svc, id).await;
    d.stop.cancel();
    (j, r)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn faults_are_retried_a_stall_pauses_and_resume_ends_with_the_uninterrupted_set() {
    let (reference, r0) = uninterrupted().await;
    assert_eq!(
        reference.len(),
        24,
        "18 campaign + 6 validation configurations"
    );
    // Validation at the noise level of the twin (centring tolerance 0.010 mm), against
    // millimetres for the nominal model.
    let after = r0["validation"]["after"]["mean"].as_f64().unwrap();
    let before = r0["validation"]["before"]["mean"].as_f64().unwrap();
    assert!(after < 0.010 && before > 0.3, "{before} -> {after}");

    // The same cell with transient RWS faults (garbage, a dropped connection, a device
    // error) and, after a few measurements, an indicator receiver that stops sending.
    let mut opts = SimOptions::default();
    opts.trical.rws_faults = ["garbage@60", "drop@140", "device-error@230"]
        .iter()
        .map(|s| s.parse().unwrap())
        .collect();
    let stall = opts.trical.indicator_stall.clone();
    let d = daemon(opts).await;
    let id = d
        .svc
        .submit(campaign(), 0, operator(), Origin::default())
        .await
        .unwrap();
    for _ in 0..600 {
        if journal(&d.svc, id).await.len() >= 6 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    stall.store(true, Ordering::SeqCst);
    let paused = until_state(&d.svc, id, &[JobState::Paused]).await;
    let started = paused.started_at.clone().expect("a paused job has started");
    assert_eq!(paused.resumed_at, None, "not resumed yet");
    let reason = paused.error.unwrap_or_default();
    assert!(reason.contains("paused at configuration"), "{reason}");
    let held = journal(&d.svc, id).await.len();
    assert!(
        (6..24).contains(&held),
        "{held} measurements held when paused: {reason}"
    );
    // Nothing moves while paused; the operator clears the fault and resumes.
    stall.store(false, Ordering::SeqCst);
    assert_eq!(d.svc.resume(id).await.unwrap(), JobState::Queued);
    let done = until_state(&d.svc, id, &[JobState::Succeeded]).await;
    // The first start stays; `resumed_at` says when the operator resumed it (issue 32.10).
    let resumed = done
        .resumed_at
        .clone()
        .expect("resumed_at of a resumed job");
    assert_eq!(done.started_at.as_deref(), Some(started.as_str()));
    assert!(
        started < resumed && resumed < done.finished_at.clone().unwrap(),
        "started {started}, resumed {resumed}, finished {:?}",
        done.finished_at
    );
    let status = serde_json::to_value(&done).unwrap();
    assert_eq!(status["started_at"], serde_json::json!(started));
    assert_eq!(status["resumed_at"], serde_json::json!(resumed));
    let got = journal(&d.svc, id).await;
    assert_eq!(
        got, reference,
        "the resumed campaign measured exactly the uninterrupted set"
    );
    let logs = d.svc.store().logs(id).unwrap();
    assert!(logs.iter().any(|l| l.message.starts_with("paused:")));
    assert!(logs.iter().any(|l| l.message.starts_with("resumed:")));
    // A finished campaign cannot be resumed.
    assert!(d.svc.resume(id).await.is_err());
    let _ = &d.lab;
    d.stop.cancel();
}

/// The printable report of stored job `id` (result `r`) with its cell's history.
fn report_of_stored(store: &Store, id: i64, r: &Value) -> String {
    use calibd::report::html::{Envelope, ReportInput, render};
    let job = json!({"id": id, "kind": r["kind"], "state": "succeeded", "devices": []});
    let history: Vec<Value> = store
        .cell_models("irb120")
        .unwrap()
        .iter()
        .map(|m| serde_json::to_value(m).unwrap())
        .collect();
    let envelope = Envelope::read(r);
    render(&ReportInput {
        job: &job,
        envelope: &envelope,
        result: calibd::jobs::report_view::typed_result(r).as_ref(),
        artefacts: &[],
        cell_history: &history,
        journal: &[],
        generator_version: "test",
        generated_at: "2026-01-10T03:00:00Z",
    })
}

/// The TriCal cell's model history once it holds `n` entries (the decision on a campaign's
/// model is recorded just after the job is stored as succeeded).
async fn history(svc: &Service, n: usize) -> Vec<Value> {
    for _ in 0..200 {
        let cells = svc.cells().await.unwrap();
        let models = cells[0]["models"].as_array().unwrap().clone();
        if models.len() >= n {
            assert_eq!(models.len(), n);
            return models;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    panic!("the cell's model history never reached {n} entries");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_overnight_schedule_calibrates_and_only_an_improvement_replaces_the_model() {
    // 01:59:58 in Berlin (CET): the 02:00 schedule fires two seconds from now.
    let clock = Clock::starting_at(
        chrono::Utc
            .with_ymd_and_hms(2026, 1, 10, 0, 59, 58)
            .unwrap(),
    );
    let d = daemon(SimOptions::default()).await;
    let store = d.svc.store().clone();
    let sid = store
        .insert_schedule(
            &NewSchedule {
                name: "overnight-trical".into(),
                cron: "0 2 * * *".into(),
                timezone: "Europe/Berlin".into(),
                job: campaign(),
                priority: 0,
                missed: MissedPolicy::Skip,
                enabled: true,
            },
            Some("operator"),
            &calibd::store::format_time(clock.now()),
        )
        .unwrap();
    tokio::spawn(Scheduler::new(clock).run(d.svc.clone(), d.stop.clone()));
    let mut job = None;
    for _ in 0..200 {
        if let Some(r) = store.schedule_runs(sid, 5).unwrap().first() {
            job = r.job_id;
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let night1 = job.expect("the schedule submitted the campaign at 02:00");
    until_state(&d.svc, night1, &[JobState::Succeeded]).await;
    let models = history(&d.svc, 1).await;
    assert_eq!(models.len(), 1);
    assert_eq!(models[0]["state"], "current", "{}", models[0]["reason"]);
    assert_eq!(models[0]["job_id"], night1);
    // The cell now runs on the calibrated model: the next campaign starts from it, its
    // validation is already at the noise level, and its candidate is kept as rejected.
    let calibrated = d
        .lab
        .trical("irb120")
        .unwrap()
        .current_model()
        .to_chain()
        .unwrap();
    let stored: calibd::model::dh::DhFile =
        serde_json::from_value(models[0]["model"].clone()).unwrap();
    let stored = stored.to_chain().unwrap();
    let q = [0.3, 0.2, -0.1, 0.5, 0.8, -0.4];
    let gap = (calibrated.tcp(&q, None).p - stored.tcp(&q, None).p).norm();
    assert!(
        gap < 1e-9,
        "the cell's model is the stored current model ({gap} mm)"
    );
    let night2 = d
        .svc
        .submit(campaign(), 0, operator(), Origin::default())
        .await
        .unwrap();
    until_state(&d.svc, night2, &[JobState::Succeeded]).await;
    let r2 = store.result(night2).unwrap().unwrap();
    assert!(r2["validation"]["before"]["mean"].as_f64().unwrap() < 0.010);
    // The first campaign's "before" was the lab file's model; the second's is the cell's
    // calibration #1 (from night 1, at the time the cell's history records), and says so.
    let r1 = store.result(night1).unwrap().unwrap();
    assert_eq!(r1["started_from"], "nominal (the lab file's model)");
    let at = models[0]["at"].as_str().unwrap();
    let label = format!(
        "calibration #1 of {} {} UTC (job {night1})",
        &at[..10],
        &at[11..16]
    );
    assert_eq!(r2["started_from"], label.as_str());
    let html = report_of_stored(&store, night2, &r2);
    assert!(
        html.contains(&format!("<th data-before>before: {label}</th>")),
        "{}",
        &html[html.find("<h2>Result").unwrap_or(0)..][..400]
    );
    assert!(!html.contains("before calibration</th>"));
    let models = history(&d.svc, 2).await;
    assert_eq!(models[0]["state"], "rejected");
    assert!(
        models[0]["reason"]
            .as_str()
            .unwrap()
            .contains("did not improve")
    );
    assert_eq!(models[1]["state"], "current");
    d.stop.cancel();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cell_centre_centres_on_a_ball_and_every_abort_says_why() {
    let opts = SimOptions::default();
    let stall = opts.trical.indicator_stall.clone();
    let lab = Lab::simulated(&opts).await.unwrap();
    let cell = lab.trical("irb120").unwrap();
    let chain = cell.current_model().to_chain().unwrap();
    let plate =
        calibd::measure::BallPlate::from_ballbar(cell.ballbar[0], cell.ballbar[1], cell.ballbar[2])
            .unwrap();
    let centres: Vec<_> = plate.centres.iter().flatten().copied().collect();
    // A start configuration on ball 2 by the nominal model (the true arm is mm away).
    let (q, _) = calibd::design::balls::ball_pool(
        &chain,
        &centres[1..2],
        1,
        9,
        |r| {
            vec![
                r.range(-1.0, 1.5),
                r.range(-0.5, 1.0),
                r.range(-1.0, 0.7),
                r.range(-2.5, 2.5),
                r.range(-1.9, 1.9),
                r.range(-5.0, 5.0),
            ]
        },
        |q| q[4].abs() > 0.2,
    )
    .remove(0);
    let lab = Arc::new(lab);
    let run = |doc: Value| {
        let lab = lab.clone();
        async move {
            let job = calibd::jobs::prepare(&doc, &calibd::jobs::NoReferences).unwrap();
            assert_eq!(job.devices(), ["irb120.rws", "irb120.uwave"]);
            let cx = calibd::jobs::Cx::new(
                lab,
                Arc::new(calibd::procedures::MemoryJournal::default()),
                Arc::new(calibd::util::NoMonitor),
            );
            job.run_in(cx).await
        }
    };
    let q_deg: Vec<f64> = q.iter().map(|v| v.to_degrees()).collect();
    let doc = json!({"kind": "cell.centre", "q_deg": q_deg, "options": {"settle_ms": 20}});
    let done = run(doc.clone()).await.unwrap();
    let r = &done.result;
    assert!(r["residual_mm"].as_f64().unwrap() < 0.010, "{r}");
    let first = &r["readings"][0];
    assert!(
        first["norm_mm"].as_f64().unwrap() > 0.1,
        "the nominal start is off the ball"
    );
    // Far from every ball: the plungers are fully extended and the loop refuses to chase.
    let home = json!({"kind": "cell.centre", "q_deg": [0.0, 0.0, 0.0, 0.0, 30.0, 0.0]});
    let e = run(home).await.unwrap_err().to_string();
    assert!(e.contains("ball lost") && e.contains("6 mm limit"), "{e}");
    // A silent receiver: the reading timeout names itself.
    stall.store(true, Ordering::SeqCst);
    let mut slow = doc.clone();
    slow["options"]["reading_timeout_ms"] = json!(300);
    let e = run(slow).await.unwrap_err().to_string();
    assert!(e.contains("no indicator reading within 300 ms"), "{e}");
    // Outside the envelope: refused before anything moves.
    let e = calibd::jobs::prepare(
        &json!({"kind": "cell.centre", "q_deg": [0.0, "x"]}),
        &calibd::jobs::NoReferences,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("q_deg"), "{e}");
}
