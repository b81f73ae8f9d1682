//! `calibd mock microscope` as a process: the real binary serves the simulated microscope,
//! and the real microscope driver reads poses (and an injected device error) from it.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use calibd_drivers::microscope::mock::MOCK_ID;
use calibd_drivers::microscope::{MicroscopeConfig, MicroscopeHandle};
use calibd_drivers::{DriverError, TcpConnector};

/// Kills the mock when the test ends, passed or not.
struct Mock(Child);

impl Drop for Mock {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[tokio::test]
async fn calibd_mock_microscope_serves_poses_to_the_driver() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_calibd"))
        .args(["mock", "microscope", "--listen", "127.0.0.1:0"])
        .args(["--fault", "device-error@3", "--seed", "3"])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("calibd starts");
    let out = child.stdout.take().unwrap();
    let _guard = Mock(child);
    let mut line = String::new();
    BufReader::new(out).read_line(&mut line).unwrap();
    let addr = line
        .trim()
        .strip_prefix("mock microscope ready (simulate) on ")
        .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
        .to_string();
    let cfg = MicroscopeConfig {
        timeout: Duration::from_secs(2),
        ..MicroscopeConfig::default()
    };
    let h = MicroscopeHandle::connect(TcpConnector::new(addr), cfg);
    assert_eq!(h.id().await.expect("id"), MOCK_ID);
    let p = h.pose().await.expect("pose");
    assert_eq!(p.seq, 1);
    assert!((p.x_m.hypot(p.y_m) - 1e-4).abs() < 1e-6, "{p:?}");
    let e = h.pose().await.expect_err("injected device error");
    assert!(matches!(e, DriverError::Device { code: 3, .. }), "{e}");
    let p2 = h.pose().await.expect("pose after the error");
    assert!(p2.seq > p.seq, "{p2:?}");
}
