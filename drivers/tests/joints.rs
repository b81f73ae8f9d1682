//! The joint-interface driver against `calibd mock joints` (the registry's start function)
//! over loopback TCP: simulate mode (identity, moves that take their duration, refusals),
//! faults (typed errors, then a reconnect), and the documented exchange as a transcript.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use calibd_drivers::joints::{JointsConfig, JointsHandle, PROTOCOL};
use calibd_drivers::mock::{self, FaultSpec, MockArgs, MockDevice, RunningMock};
use calibd_drivers::{Backoff, DriverError, TcpConnector};

fn cfg() -> JointsConfig {
    JointsConfig {
        timeout: Duration::from_millis(500),
        move_slack: 1.5,
        backoff: Backoff {
            initial: Duration::from_millis(10),
            max: Duration::from_millis(50),
            attempts: 3,
        },
    }
}

async fn start(args: MockArgs) -> (RunningMock, JointsHandle) {
    let m = mock::start(args).await.expect("mock joints starts");
    let h = JointsHandle::connect(TcpConnector::new(m.addr.clone()), cfg());
    (m, h)
}

fn with_faults(faults: &[&str]) -> MockArgs {
    let mut args = MockArgs::new(MockDevice::Joints);
    args.faults = faults
        .iter()
        .map(|f| f.parse::<FaultSpec>().expect("fault spec"))
        .collect();
    args
}

fn posture(p: &[(&str, f64)]) -> BTreeMap<String, f64> {
    p.iter().map(|(k, v)| (k.to_string(), *v)).collect()
}

#[tokio::test]
async fn simulate_mode_moves_the_joints_over_the_duration_and_refuses_bad_targets() {
    assert_eq!(MockDevice::Joints.name(), "joints");
    let (m, h) = start(MockArgs::new(MockDevice::Joints)).await;
    let id = h.hello().await.expect("hello");
    assert_eq!(id.protocol, PROTOCOL);
    assert_eq!(id.joints, vec!["joint_1", "joint_2", "joint_3", "joint_4"]);
    assert_eq!(id.limits_rad[2], [0.0, 2.5]);
    let r = h.read().await.expect("read");
    assert!(!r.moving);
    assert_eq!(r.positions_rad.len(), 4);
    assert!(r.positions_rad.values().all(|v| *v == 0.0), "{r:?}");

    let t0 = Instant::now();
    let reached = h
        .move_to(
            posture(&[("joint_1", 0.5), ("joint_3", 1.25)]),
            Duration::from_millis(200),
        )
        .await
        .expect("move");
    assert!(
        t0.elapsed() >= Duration::from_millis(200),
        "{:?}",
        t0.elapsed()
    );
    assert_eq!(
        reached,
        posture(&[
            ("joint_1", 0.5),
            ("joint_2", 0.0),
            ("joint_3", 1.25),
            ("joint_4", 0.0)
        ])
    );
    assert_eq!(h.read().await.expect("read").positions_rad, reached);
    assert_eq!(h.state().borrow().positions_rad, reached);

    let e = h
        .move_to(posture(&[("elbow", 0.1)]), Duration::ZERO)
        .await
        .expect_err("unknown joint");
    assert!(
        matches!(&e, DriverError::Device { code: 1, message, .. } if message.starts_with("unknown_joint")),
        "{e}"
    );
    let e = h
        .move_to(posture(&[("joint_3", -0.5)]), Duration::ZERO)
        .await
        .expect_err("out of limits");
    assert!(
        matches!(&e, DriverError::Device { code: 2, message, .. } if message.contains("joint_3")),
        "{e}"
    );
    let e = h
        .move_to(posture(&[("joint_1", f64::NAN)]), Duration::ZERO)
        .await
        .expect_err("not a number");
    assert!(matches!(e, DriverError::InvalidRequest { .. }), "{e}");
    // Nothing moved by the refused requests; a stop with nothing moving is fine.
    assert_eq!(h.read().await.expect("read").positions_rad, reached);
    h.stop().await.expect("stop");
    m.stop().await;
}

#[tokio::test]
async fn faults_give_typed_errors_and_the_driver_reconnects() {
    let (m, h) = start(with_faults(&["garbage@1", "device-error@3", "drop@4"])).await;
    let e = h.hello().await.expect_err("garbage");
    assert!(matches!(e, DriverError::Protocol { .. }), "{e}");
    h.hello().await.expect("reconnected");
    assert_eq!(h.state().borrow().connects, 2);
    let e = h
        .move_to(posture(&[("joint_2", 0.3)]), Duration::from_millis(20))
        .await
        .expect_err("device error");
    assert!(
        matches!(&e, DriverError::Device { code: 4, message, .. } if message.contains("injected")),
        "{e}"
    );
    // Reply 4 is dropped with the connection: the peer closed; the next request reconnects.
    let e = h.read().await.expect_err("dropped");
    assert!(matches!(e, DriverError::Closed { .. }), "{e}");
    assert!(!h.state().borrow().connected);
    let r = h.read().await.expect("after the drop");
    assert_eq!(r.positions_rad["joint_2"], 0.3);
    assert_eq!(h.state().borrow().connects, 3);
    m.stop().await;

    let (m, h) = start(with_faults(&["delay@1"])).await;
    let e = h.read().await.expect_err("late reply");
    assert!(matches!(e, DriverError::Timeout { .. }), "{e}");
    h.read().await.expect("read after the late reply");
    m.stop().await;

    let (m, h) = start(with_faults(&["truncate@1"])).await;
    let e = h.hello().await.expect_err("truncated");
    assert!(
        matches!(
            e,
            DriverError::Closed { .. }
                | DriverError::Protocol { .. }
                | DriverError::Transport { .. }
        ),
        "{e}"
    );
    h.hello().await.expect("hello after the truncated reply");
    m.stop().await;

    let (m, h) = start(with_faults(&["stall@1"])).await;
    let e = h
        .move_to(posture(&[("joint_4", 1.0)]), Duration::from_millis(10))
        .await
        .expect_err("stalled");
    assert!(matches!(e, DriverError::Timeout { .. }), "{e}");
    m.stop().await;
}

#[tokio::test]
async fn documented_exchange_replays() {
    let mut args = MockArgs::new(MockDevice::Joints);
    args.replay = Some(
        format!(
            "{}/../tests/data/transcripts/joints.jsonl",
            env!("CARGO_MANIFEST_DIR")
        )
        .into(),
    );
    let (m, h) = start(args).await;
    let id = h.hello().await.expect("hello");
    assert_eq!(id.robot, "talos");
    assert_eq!(id.joints, vec!["arm_left_1_joint", "arm_left_2_joint"]);
    assert_eq!(id.limits_rad, vec![[-1.57, 0.79], [0.0087, 2.88]]);
    let r = h.read().await.expect("read");
    assert!(!r.moving);
    assert_eq!(r.positions_rad["arm_left_2_joint"], 0.0087);
    let reached = h
        .move_to(
            posture(&[("arm_left_2_joint", 0.5)]),
            Duration::from_millis(250),
        )
        .await
        .expect("move");
    assert_eq!(
        reached,
        posture(&[("arm_left_1_joint", 0.0), ("arm_left_2_joint", 0.5)])
    );
    let e = h
        .move_to(
            posture(&[("arm_left_1_joint", 2.0)]),
            Duration::from_secs(1),
        )
        .await
        .expect_err("out of limits");
    assert!(matches!(e, DriverError::Device { code: 2, .. }), "{e}");
    m.stop().await;
}
