//! The operator's commands against a real daemon, each the real `calibd` binary in another
//! process: `submit --watch` prints the summary, `rerun --watch` runs the same document
//! as a new job, `report` writes the printable report, and a wrong token says where
//! tokens come from.

use std::process::{Command, Output};

use crate::common::daemon::Daemon;

const BIN: &str = env!("CARGO_BIN_EXE_calibd");

/// `calibd ARGS --server URL --data DATA` (the token is found in DATA/operator.token).
fn calibd(d: &Daemon, data: &std::path::Path, args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .args(["--server", &d.url, "--data"])
        .arg(data)
        .env_remove("CALIBD_TOKEN")
        .output()
        .expect("calibd runs")
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

#[test]
fn submit_rerun_and_report_from_the_command_line() {
    let data = tempfile::tempdir().unwrap();
    let d = Daemon::start(data.path(), &[("CALIBD_LAB", "none")], true);
    let job = data.path().join("fk.json");
    std::fs::write(&job, calibd::jobs::examples::twin_fk(3).to_string()).unwrap();
    let job = job.display().to_string();

    let o = calibd(&d, data.path(), &["submit", &job, "--watch"]);
    let out = text(&o);
    assert!(o.status.success(), "{out}");
    assert!(
        out.contains("job 1 submitted") && out.contains("3 poses"),
        "{out}"
    );

    let o = calibd(&d, data.path(), &["rerun", "1", "--watch"]);
    let out = text(&o);
    assert!(o.status.success(), "{out}");
    assert!(
        out.contains("job 2 submitted (a re-run of job 1)") && out.contains("3 poses"),
        "{out}"
    );

    let html = data.path().join("r.html");
    let o = calibd(
        &d,
        data.path(),
        &["report", "2", "--out", &html.display().to_string()],
    );
    assert!(o.status.success(), "{}", text(&o));
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(
        page.contains("<html") && page.contains("serial.fk"),
        "{page:.300}"
    );

    // A wrong token: the message says where a valid one comes from.
    let o = Command::new(BIN)
        .args(["jobs", "--server", &d.url, "--token", "not-a-token"])
        .output()
        .unwrap();
    let out = text(&o);
    assert!(!o.status.success());
    assert!(
        out.contains("refused the token") && out.contains("operator.token"),
        "{out}"
    );
}
