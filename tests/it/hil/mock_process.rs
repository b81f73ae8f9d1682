//! `calibd mock <device>` as its own process: it logs every request it receives at debug
//! level, and SIGTERM (what systemd and `kill` send) stops it cleanly, removing the symlink
//! it made to its pseudo-terminal (a dangling link would look like a vanished serial port).

use std::io::Write;
use std::process::Command;

use super::{BIN, Proc};

#[test]
fn a_mock_logs_its_requests_and_removes_its_pty_link_on_sigterm() {
    let dir = tempfile::tempdir().expect("temp dir");
    let link = dir.path().join("ttyUWAVE");
    let mut p = Proc::spawn_logged(
        Command::new(BIN)
            .args([
                "mock",
                "uwave",
                "--rate-hz",
                "0",
                "--uwave-request",
                "RQ{cc}{gg}",
            ])
            .arg("--listen")
            .arg(&link)
            .env("RUST_LOG", "debug"),
    );
    p.until("mock uwave ready (simulate) on ");
    assert!(link.symlink_metadata().is_ok(), "the pty link is made");
    let mut port = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .open(&link)
        .expect("open the pty");
    port.write_all(b"RQ0100\r").expect("write a request");
    let line = p.until_containing("mock received");
    assert!(line.contains("RQ0100"), "{line}");
    drop(port);

    let pid = p.child.id().to_string();
    let killed = Command::new("kill").args(["-TERM", &pid]).status();
    assert!(killed.is_ok_and(|s| s.success()));
    let status = p.child.wait().expect("the mock exits");
    assert!(status.success(), "{status}");
    assert!(
        link.symlink_metadata().is_err(),
        "{} still exists after SIGTERM",
        link.display()
    );
}
