//! An overnight run survives a controller reboot with nobody awake: the cell's lab file says
//! `resume = "auto"`; the cell's mock process (controller and receiver) is killed in the
//! middle of a TriCal campaign and started again on the same ports; the campaign pauses on
//! the fault, resumes by itself once both devices answer as the same units, journals the
//! resume and succeeds, without any operator call.

use std::time::{Duration, Instant};

use serde_json::Value;

use super::{Daemon, WAIT, free_port, lab_dir, mock, trical_doc};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_campaign_paused_by_a_controller_reboot_resumes_by_itself() {
    let _one = crate::hil::OUT_OF_PROCESS.lock().await;
    let dir = tempfile::tempdir().expect("temp dir");
    let lab = lab_dir(dir.path(), free_port());
    let text = std::fs::read_to_string(&lab).expect("lab file");
    let auto = text.replacen(
        "kind = \"ball_centring\"\n",
        "kind = \"ball_centring\"\nresume = \"auto\"\nmax_auto_resumes = 2\n",
        1,
    );
    assert_ne!(auto, text, "the cell's resume setting is in the lab file");
    std::fs::write(&lab, auto).expect("write");
    let mut cell = mock(&lab, "irb120");
    let d = Daemon::start(dir.path(), &lab);

    let id = d.submit(&trical_doc()).await;
    let t0 = Instant::now();
    while d.journal(id).await.len() < 5 {
        assert!(t0.elapsed() < WAIT, "no measurement");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let started_at = d.get(&format!("/v1/jobs/{id}")).await["started_at"].clone();
    // The controller reboots (the whole cell's mock process goes, and comes back as the
    // same units: same seed, same controller, same receiver).
    cell.kill();
    let t_kill = Instant::now();
    let j = d.until_state(id, &["paused", "failed", "succeeded"]).await;
    assert_eq!(j["state"], "paused", "{j}");
    let paused_for = j["error"].as_str().unwrap_or_default().to_string();
    let t_paused = t_kill.elapsed().as_secs_f64();
    // Still down: the job stays paused (checked twice, a device probe apart).
    let l = d.get("/v1/lab?refresh=true").await;
    assert!(l.to_string().contains("failed"), "{l}");
    assert_eq!(d.get(&format!("/v1/jobs/{id}")).await["state"], "paused");
    let _cell = mock(&lab, "irb120");
    let t_back = Instant::now();
    let j = d
        .until_state(id, &["succeeded", "failed", "cancelled"])
        .await;
    assert_eq!(j["state"], "succeeded", "{j}");
    // Resumed, not restarted: the first start is kept, the resume is dated.
    assert_eq!(j["started_at"], started_at, "{j}");
    assert!(j["resumed_at"].is_string(), "{j}");
    let journal = d.journal(id).await;
    let resumes: Vec<&Value> = journal
        .iter()
        .filter(|e| e["index"].as_u64().is_some_and(|i| i >= 2_000_000))
        .collect();
    assert_eq!(resumes.len(), 1, "one automatic resume: {resumes:?}");
    let r = &resumes[0]["data"];
    assert_eq!(r["auto_resume"], 1, "{r}");
    assert_eq!(r["paused_for"].as_str(), Some(paused_for.as_str()), "{r}");
    for dev in ["irb120.rws", "irb120.uwave"] {
        assert!(
            r["devices"][dev].as_str().is_some_and(|f| !f.is_empty()),
            "{r}"
        );
    }
    assert!(
        r["devices"]["irb120.rws"]
            .as_str()
            .is_some_and(|f| f.contains("RobotWare")),
        "{r}"
    );
    // The job's log says who resumed it and why.
    let logs = d.get(&format!("/v1/jobs/{id}/logs")).await.to_string();
    assert!(logs.contains("resumed automatically (1 of 2)"), "{logs}");
    assert!(!logs.contains("resumed by the operator"), "{logs}");
    let result = d.get(&format!("/v1/jobs/{id}/result")).await;
    let after = result["validation"]["after"]["mean"]
        .as_f64()
        .expect("mean");
    assert!(after < 0.010, "{}", result["validation"]);
    eprintln!(
        "job {id}: paused {t_paused:.1} s after the kill ({paused_for}); succeeded {:.1} s after the mock came back; {} journal entries; resume entry {r}; validation after {after:.4} mm",
        t_back.elapsed().as_secs_f64(),
        journal.len()
    );
}
