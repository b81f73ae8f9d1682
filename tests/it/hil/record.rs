//! A lab's first run gives the tests real traffic: `calibd serve --record DIR` runs a TriCal
//! campaign against `calibd mock lab` (RWS over TCP, the U-WAVE receiver on a pty) and
//! writes each device's traffic as a transcript; then `calibd mock <device> --replay --strict`
//! serves those transcripts in place of the mock lab, at the lab file's addresses, and the
//! same campaign measures the same journal to the last digit. A campaign that sends another
//! target makes the replay stop with an error naming the recorded request and both bytes.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use calibd::lab::CellLink;
use calibd_drivers::transcript::{Direction, Transcript};
use serde_json::{Value, json};

use super::{BIN, Daemon, Proc, WAIT, free_port, lab_dir, mock, trical_doc};

/// Settings of both daemons: no periodic lab check during the campaign (its probes would
/// interleave with the campaign's requests at times that differ between runs).
const SETTINGS: &str = "lab_check_interval_s = 3600\n";

/// The hil lab file cut to its TriCal cell, with the indicators read on request (a
/// receiver that streams is read at times that depend on the clock, not on the bytes).
fn trical_lab(dir: &Path) -> PathBuf {
    let lab = lab_dir(dir, free_port());
    let text = std::fs::read_to_string(&lab).expect("lab file");
    let cut = text
        .find("\n[[cell]]\nname = \"pcr3pf\"")
        .expect("pcr cell");
    let trical = text[..cut].replacen(
        "[cell.indicators]\n",
        "[cell.indicators]\nrequest = \"RQ{cc}{gg}\"\n",
        1,
    );
    assert!(trical.contains("request = "), "{trical}");
    std::fs::write(&lab, trical).expect("write");
    lab
}

/// The RWS address and U-WAVE port the lab file names.
fn addresses(lab: &Path) -> (String, String) {
    let cells = calibd::lab::config::load(lab, &calibd::lab::config::ProcessEnv).expect("lab file");
    match &cells[0] {
        CellLink::BallCentring(c) => (c.rws.address.clone(), c.uwave.path.clone()),
        _ => panic!("the first cell is the TriCal cell"),
    }
}

/// Waits for the daemon's first lab check to pass (so no probe runs during the campaign).
async fn until_lab_ok(d: &Daemon) {
    let t0 = Instant::now();
    loop {
        let l = d.get("/v1/lab").await;
        let ok = l["devices"]
            .as_array()
            .is_some_and(|r| !r.is_empty() && r.iter().all(|x| x["state"] == "ok"));
        if ok {
            return;
        }
        assert!(t0.elapsed() < WAIT, "lab check: {l}");
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
}

/// A journal without its times: index, status and measured data.
fn strip(e: &[Value]) -> Vec<Value> {
    e.iter()
        .map(|x| json!({"index": x["index"], "status": x["status"], "data": x["data"]}))
        .collect()
}

/// The replay mocks of `session`'s transcripts at the lab file's addresses.
fn replays(session: &Path, rws: &str, port: &str) -> [Proc; 2] {
    let start = |device: &str, listen: &str, file: &str| {
        let p = Proc::spawn_logged(
            Command::new(BIN)
                .args(["mock", device, "--strict", "--listen", listen, "--replay"])
                .arg(session.join(file)),
        );
        p.until(&format!("mock {device} ready (replay) on "));
        p
    };
    [
        start("abb", rws, "irb120.abb.jsonl"),
        start("uwave", port, "irb120.uwave.jsonl"),
    ]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_recorded_campaign_replays_to_the_same_journal_and_a_changed_target_fails_clearly() {
    let _one = crate::hil::OUT_OF_PROCESS.lock().await;
    let dir = tempfile::tempdir().expect("temp dir");
    let lab = trical_lab(dir.path());
    let (rws, port) = addresses(&lab);
    let record = dir.path().join("recordings");

    // Live, recording: the mock lab's twins behind the real protocols.
    let recorded = {
        let _cell = mock(&lab, "irb120");
        let run = dir.path().join("live");
        let d = Daemon::start_with(
            &run,
            &lab,
            SETTINGS,
            &["--record", &record.display().to_string()],
        );
        until_lab_ok(&d).await;
        let (id, _, t) = d.run(&trical_doc()).await;
        let journal = d.journal(id).await;
        eprintln!(
            "live, recording: {} measurements in {t:.1} s",
            journal.len()
        );
        journal
    };
    assert_eq!(recorded.len(), 24);

    // One session folder, one transcript per device, named by cell and device.
    let sessions: Vec<PathBuf> = std::fs::read_dir(&record)
        .expect("recording folder")
        .map(|e| e.expect("entry").path())
        .collect();
    assert_eq!(sessions.len(), 1, "{sessions:?}");
    let session = &sessions[0];
    let mut files: Vec<String> = std::fs::read_dir(session)
        .expect("session")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    files.sort();
    assert_eq!(files, ["irb120.abb.jsonl", "irb120.uwave.jsonl"]);
    // The controller's credentials are not in it: every Authorization value is masked
    // (and replay skips those bytes), the password file's content appears nowhere.
    let abb = Transcript::load(&session.join("irb120.abb.jsonl")).expect("transcript");
    let text = std::fs::read_to_string(session.join("irb120.abb.jsonl")).expect("read");
    assert!(!text.contains("hil-secret"));
    let mut masked = 0;
    for c in abb.chunks.iter().filter(|c| c.dir == Direction::ToDevice) {
        let b = c.bytes().expect("hex");
        let s = String::from_utf8_lossy(&b);
        if let Some(at) = s.find("Authorization: ") {
            let value = s[at + 15..].split("\r\n").next().unwrap_or_default();
            assert!(!value.is_empty() && value.bytes().all(|x| x == b'*'), "{s}");
            assert!(!c.redacted.is_empty());
            masked += 1;
        }
    }
    assert!(masked > 20, "{masked} authorised requests");
    eprintln!(
        "recorded: {} RWS chunks ({masked} with a masked Authorization)",
        abb.chunks.len()
    );

    // Replayed: the transcripts in place of the mock lab, the same campaign.
    let replayed = {
        let _mocks = replays(session, &rws, &port);
        let d = Daemon::start_with(&dir.path().join("replay"), &lab, SETTINGS, &[]);
        until_lab_ok(&d).await;
        let (id, _, t) = d.run(&trical_doc()).await;
        let journal = d.journal(id).await;
        eprintln!("replayed: {} measurements in {t:.1} s", journal.len());
        journal
    };
    assert_eq!(strip(&replayed), strip(&recorded));
    eprintln!(
        "first measurement, live and replayed: {}",
        recorded[0]["data"]
    );

    // Another design seed: other targets; the replay stops at the first one with an error
    // naming the recorded request and both versions of its bytes.
    let mocks = replays(session, &rws, &port);
    let d = Daemon::start_with(&dir.path().join("changed"), &lab, SETTINGS, &[]);
    until_lab_ok(&d).await;
    let mut doc = trical_doc();
    doc["design"]["seed"] = json!(5);
    let id = d.submit(&doc).await;
    let line = mocks[0].until_containing("differ from the recording");
    eprintln!("{line}");
    assert!(line.contains("irb120.abb.jsonl"), "{line}");
    assert!(line.contains("calib_q"), "{line}");
    assert!(
        line.contains("recorded \"") && line.contains("the client sent \""),
        "{line}"
    );
    let j = d.until_state(id, &["paused", "failed", "succeeded"]).await;
    assert_ne!(j["state"], "succeeded", "{j}");
}

/// A cell's own `record` folder (relative to the lab file) takes its traffic, before the
/// lab-wide folder; files are named by cell and device and start with their header.
#[tokio::test]
async fn a_cells_record_setting_takes_its_traffic() {
    let dir = tempfile::tempdir().expect("temp dir");
    let lab = trical_lab(dir.path());
    let text = std::fs::read_to_string(&lab).expect("lab file");
    let with = text.replacen(
        "kind = \"ball_centring\"\n",
        "kind = \"ball_centring\"\nrecord = \"cell-recordings\"\n",
        1,
    );
    std::fs::write(&lab, with).expect("write");
    let cells =
        calibd::lab::config::load(&lab, &calibd::lab::config::ProcessEnv).expect("lab file");
    let own = dir.path().join("cell-recordings");
    match &cells[0] {
        CellLink::BallCentring(c) => assert_eq!(c.record.as_deref(), Some(own.as_path())),
        _ => panic!("the first cell is the TriCal cell"),
    }
    let everyone = dir.path().join("lab-wide");
    let l = calibd::lab::Lab::connect_recording(cells, Some(&everyone)).expect("lab");
    for device in ["abb", "uwave"] {
        let t = Transcript::load(&own.join(format!("irb120.{device}.jsonl"))).expect("transcript");
        let h = t.header.expect("header");
        assert_eq!(
            (h.format.as_str(), h.device.as_str()),
            ("calibd-transcript/1", device)
        );
    }
    assert!(
        !everyone.exists(),
        "the cell's own folder is used, not the lab-wide one"
    );
    l.stop().await;
}
