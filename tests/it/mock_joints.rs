//! `calibd mock joints` as a process: the real binary serves the simulated joint interface,
//! and the real `calibd-joints/1` driver moves it (and meets an injected controller fault).

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use calibd_drivers::joints::{JointsConfig, JointsHandle};
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
async fn calibd_mock_joints_serves_the_joint_interface_to_the_driver() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_calibd"))
        .args(["mock", "joints", "--listen", "127.0.0.1:0"])
        .args(["--fault", "device-error@3"])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("calibd starts");
    let out = child.stdout.take().expect("piped stdout");
    let _guard = Mock(child);
    let mut line = String::new();
    BufReader::new(out)
        .read_line(&mut line)
        .expect("a ready line");
    let addr = line
        .trim()
        .strip_prefix("mock joints ready (simulate) on ")
        .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
        .to_string();
    let h = JointsHandle::connect(TcpConnector::new(addr), JointsConfig::default());
    let id = h.hello().await.expect("hello");
    assert_eq!(id.joints.len(), 4);
    let target = BTreeMap::from([(id.joints[0].clone(), 0.25)]);
    let reached = h
        .move_to(target.clone(), Duration::from_millis(50))
        .await
        .expect("move");
    assert_eq!(reached[&id.joints[0]], 0.25);
    let e = h.read().await.expect_err("injected fault");
    assert!(matches!(e, DriverError::Device { code: 4, .. }), "{e}");
    let r = h.read().await.expect("read after the fault");
    assert_eq!(r.positions_rad[&id.joints[0]], 0.25);
}
