//! The ROS 2 joint bridge's protocol half (`deploy/ros2/calibd_joint_bridge.py`, fake
//! backend) against the Rust `calibd-joints/1` driver: the bridge runs as a process on a
//! free loopback port; hello, read, moves, refusals, busy and stop go through `JointsHandle`,
//! bad lines through a raw socket.

use std::collections::BTreeMap;
use std::process::Stdio;
use std::time::{Duration, Instant};

use calibd_drivers::joints::{JointsConfig, JointsHandle, PROTOCOL};
use calibd_drivers::{Backoff, DriverError, TcpConnector};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::process::{Child, Command};

/// Longest wait for the bridge to start (Python start-up on a loaded machine).
const START: Duration = Duration::from_secs(20);

/// The running bridge (killed when dropped, passed or not) and its address.
async fn bridge() -> (Child, String) {
    let script = format!(
        "{}/../deploy/ros2/calibd_joint_bridge.py",
        env!("CARGO_MANIFEST_DIR")
    );
    let mut child = Command::new("python3")
        .arg(&script)
        .args(["--backend", "fake", "--listen", "127.0.0.1:0"])
        .args([
            "--joints",
            "arm_left_1_joint,arm_left_2_joint,arm_left_3_joint",
        ])
        .arg("--limits=-1.57:0.79,0.0087:2.88,-2.44:2.44")
        .args(["--robot", "talos-fake"])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .kill_on_drop(true)
        .spawn()
        .expect("python3 runs the bridge");
    let out = child.stdout.take().expect("piped stdout");
    let mut lines = BufReader::new(out).lines();
    let line = tokio::time::timeout(START, lines.next_line())
        .await
        .expect("the bridge says it listens in time")
        .expect("stdout readable")
        .expect("a ready line");
    let addr = line
        .strip_prefix("listening on ")
        .unwrap_or_else(|| panic!("unexpected ready line {line:?}"))
        .to_string();
    (child, addr)
}

fn handle(addr: &str) -> JointsHandle {
    JointsHandle::connect(
        TcpConnector::new(addr),
        JointsConfig {
            timeout: Duration::from_secs(2),
            move_slack: 1.5,
            backoff: Backoff {
                initial: Duration::from_millis(20),
                max: Duration::from_millis(200),
                attempts: 4,
            },
        },
    )
}

fn posture(p: &[(&str, f64)]) -> BTreeMap<String, f64> {
    p.iter().map(|(k, v)| (k.to_string(), *v)).collect()
}

#[tokio::test]
async fn the_bridge_serves_the_protocol_to_the_rust_driver() {
    let (mut child, addr) = bridge().await;
    let h = handle(&addr);
    let id = h.hello().await.expect("hello");
    assert_eq!(id.protocol, PROTOCOL);
    assert_eq!(id.robot, "talos-fake");
    assert_eq!(
        id.joints,
        vec!["arm_left_1_joint", "arm_left_2_joint", "arm_left_3_joint"]
    );
    assert_eq!(
        id.limits_rad,
        vec![[-1.57, 0.79], [0.0087, 2.88], [-2.44, 2.44]]
    );
    let r = h.read().await.expect("read");
    assert!(!r.moving);
    // At rest at 0 clamped into the limits.
    assert_eq!(
        r.positions_rad,
        posture(&[
            ("arm_left_1_joint", 0.0),
            ("arm_left_2_joint", 0.0087),
            ("arm_left_3_joint", 0.0)
        ])
    );

    let t0 = Instant::now();
    let reached = h
        .move_to(
            posture(&[("arm_left_1_joint", -0.5), ("arm_left_3_joint", 1.0)]),
            Duration::from_millis(200),
        )
        .await
        .expect("move");
    assert!(
        t0.elapsed() >= Duration::from_millis(200),
        "{:?}",
        t0.elapsed()
    );
    let want = posture(&[
        ("arm_left_1_joint", -0.5),
        ("arm_left_2_joint", 0.0087),
        ("arm_left_3_joint", 1.0),
    ]);
    assert_eq!(reached, want);
    assert_eq!(h.read().await.expect("read").positions_rad, want);

    let e = h
        .move_to(posture(&[("arm_left_1_joint", 1.0)]), Duration::ZERO)
        .await
        .expect_err("out of limits");
    assert!(
        matches!(&e, DriverError::Device { code: 2, message, .. } if message.starts_with("out_of_limits")),
        "{e}"
    );
    let e = h
        .move_to(posture(&[("leg_left_1_joint", 0.0)]), Duration::ZERO)
        .await
        .expect_err("unknown joint");
    assert!(
        matches!(&e, DriverError::Device { code: 1, message, .. } if message.starts_with("unknown_joint")),
        "{e}"
    );
    assert_eq!(h.read().await.expect("read").positions_rad, want);

    // A long move from one client: another sees it moving, is refused as busy, and stops it.
    let other = handle(&addr);
    let long = tokio::spawn({
        let h = h.clone();
        async move {
            h.move_to(
                posture(&[("arm_left_3_joint", -2.0)]),
                Duration::from_secs(10),
            )
            .await
        }
    });
    let seen = loop {
        let r = other.read().await.expect("read while moving");
        if r.moving && r.positions_rad["arm_left_3_joint"] < 1.0 {
            break r.positions_rad["arm_left_3_joint"];
        }
        tokio::task::yield_now().await;
    };
    let e = other
        .move_to(posture(&[("arm_left_2_joint", 1.0)]), Duration::ZERO)
        .await
        .expect_err("busy");
    assert!(matches!(e, DriverError::Device { code: 3, .. }), "{e}");
    other.stop().await.expect("stop");
    let e = long.await.expect("task").expect_err("stopped");
    assert!(
        matches!(&e, DriverError::Device { code: 4, message, .. } if message.contains("stopped")),
        "{e}"
    );
    let r = h.read().await.expect("read after the stop");
    assert!(!r.moving);
    let q = r.positions_rad["arm_left_3_joint"];
    assert!(q <= seen && q > -2.0, "{q} vs {seen}");

    // A stop from the moving client itself is sent at once, ahead of its move's reply.
    let long = tokio::spawn({
        let h = h.clone();
        async move {
            h.move_to(
                posture(&[("arm_left_1_joint", 0.7)]),
                Duration::from_secs(10),
            )
            .await
        }
    });
    loop {
        let r = other.read().await.expect("read while moving");
        if r.moving && r.positions_rad["arm_left_1_joint"] > -0.5 {
            break;
        }
        tokio::task::yield_now().await;
    }
    h.stop().await.expect("own stop");
    let e = long.await.expect("task").expect_err("stopped");
    assert!(matches!(e, DriverError::Device { code: 4, .. }), "{e}");

    child.kill().await.expect("kill the bridge");
}

#[tokio::test]
async fn the_bridge_answers_bad_lines_with_bad_request_and_reads_on() {
    let (mut child, addr) = bridge().await;
    let mut s = tokio::net::TcpStream::connect(&addr)
        .await
        .expect("connect");
    let (r, mut w) = s.split();
    let mut lines = BufReader::new(r).lines();
    let mut long = vec![b'x'; 70_000];
    long.push(b'\n');
    let mut sent = Vec::new();
    sent.extend_from_slice(b"not json\n{\"op\":\"dance\"}\n");
    sent.extend_from_slice(&long);
    sent.extend_from_slice(
        b"{\"op\":\"move\",\"positions_rad\":{\"arm_left_1_joint\":0}}\n{\"op\":\"read\"}\r\n",
    );
    w.write_all(&sent).await.expect("write");
    let mut replies = Vec::new();
    for _ in 0..5 {
        let l = tokio::time::timeout(Duration::from_secs(5), lines.next_line())
            .await
            .expect("a reply in time")
            .expect("readable")
            .expect("a line");
        replies.push(serde_json::from_str::<serde_json::Value>(&l).expect("JSON reply"));
    }
    for (r, what) in replies[..4]
        .iter()
        .zip(["JSON", "dance", "longer", "duration_s"])
    {
        assert_eq!(r["ok"], false, "{r}");
        assert_eq!(r["error"]["code"], "bad_request", "{r}");
        let m = r["error"]["message"].as_str().unwrap_or_default();
        assert!(m.contains(what), "{m:?} lacks {what:?}");
    }
    assert_eq!(replies[4]["ok"], true);
    assert_eq!(replies[4]["moving"], false);
    child.kill().await.expect("kill the bridge");
}

/// The bridge's ros2 backend (goal status, goal tolerances, arrival confirmed from the joint
/// states, limits from the URDF, sim time) against a fake of the rclpy API: its Python tests
/// (`deploy/ros2/test_calibd_joint_bridge.py`) pass.
#[test]
fn ros2_backend_passes_its_tests_against_a_fake_rclpy() {
    let root = format!("{}/..", env!("CARGO_MANIFEST_DIR"));
    let out = std::process::Command::new("python3")
        .args([
            "-B",
            "-m",
            "unittest",
            "-v",
            "deploy/ros2/test_calibd_joint_bridge.py",
        ])
        .current_dir(&root)
        .output()
        .expect("python3 runs the bridge's tests");
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{log}");
    assert!(log.contains("Ran 7 tests"), "{log}");
}
