//! The microscope driver against `calibd mock microscope` (the registry's start function)
//! over loopback TCP: simulate mode with seeded noise, faults, and the documented exchange
//! as a transcript.

use std::time::Duration;

use calibd_drivers::microscope::mock::MOCK_ID;
use calibd_drivers::microscope::{MicroscopeConfig, MicroscopeHandle, PoseReading};
use calibd_drivers::mock::{self, FaultSpec, MockArgs, MockDevice, RunningMock};
use calibd_drivers::{Backoff, DriverError, TcpConnector};

fn cfg() -> MicroscopeConfig {
    MicroscopeConfig {
        timeout: Duration::from_millis(500),
        backoff: Backoff {
            initial: Duration::from_millis(10),
            max: Duration::from_millis(50),
            attempts: 3,
        },
    }
}

async fn start(args: MockArgs) -> (RunningMock, MicroscopeHandle) {
    let m = mock::start(args).await.expect("mock microscope starts");
    let h = MicroscopeHandle::connect(TcpConnector::new(m.addr.clone()), cfg());
    (m, h)
}

fn with_faults(faults: &[&str]) -> MockArgs {
    let mut args = MockArgs::new(MockDevice::Microscope);
    args.faults = faults
        .iter()
        .map(|f| f.parse::<FaultSpec>().unwrap())
        .collect();
    args
}

async fn poses(h: &MicroscopeHandle, n: usize) -> Vec<PoseReading> {
    let mut out = Vec::new();
    for _ in 0..n {
        out.push(h.pose().await.expect("pose"));
    }
    out
}

#[tokio::test]
async fn simulate_mode_serves_a_slowly_drifting_noisy_pose_reproducible_by_seed() {
    assert_eq!(MockDevice::Microscope.name(), "microscope");
    let (m, h) = start(MockArgs::new(MockDevice::Microscope)).await;
    assert_eq!(h.id().await.unwrap(), MOCK_ID);
    let a = poses(&h, 5).await;
    for (i, p) in a.iter().enumerate() {
        assert_eq!(p.seq, i as u64 + 1);
        // Near the origin: a 100 µm circle plus sub-µm noise; a small rotation.
        let r = p.x_m.hypot(p.y_m);
        assert!((r - 1e-4).abs() < 1e-6, "{p:?}");
        assert!(p.theta_rad.abs() < 1e-3, "{p:?}");
    }
    // Noisy: successive images differ by more than the drift alone would explain.
    assert!(a.windows(2).all(|w| w[0].x_m != w[1].x_m));
    m.stop().await;

    // The same seed gives the same images; another seed other noise.
    let (m, h) = start(MockArgs::new(MockDevice::Microscope)).await;
    let b = poses(&h, 5).await;
    m.stop().await;
    assert_eq!(a, b);
    let mut args = MockArgs::new(MockDevice::Microscope);
    args.seed = 7;
    let (m, h) = start(args).await;
    let c = poses(&h, 5).await;
    m.stop().await;
    assert_ne!(a, c);
}

#[tokio::test]
async fn faults_are_injected_and_the_driver_recovers() {
    let (m, h) = start(with_faults(&["garbage@1", "device-error@3", "drop@4"])).await;
    let e = h.pose().await.expect_err("garbage");
    assert!(matches!(e, DriverError::Protocol { .. }), "{e}");
    h.pose().await.expect("reconnected");
    let e = h.pose().await.expect_err("busy");
    assert!(matches!(e, DriverError::Device { code: 3, .. }), "{e}");
    // Reply 4 is dropped with the connection; the driver reconnects and reads on.
    let p = match h.pose().await {
        Ok(p) => p,
        Err(_) => h.pose().await.expect("after the drop"),
    };
    assert!(p.seq >= 4, "{p:?}");
    m.stop().await;

    let (m, h) = start(with_faults(&["delay@1"])).await;
    let e = h.pose().await.expect_err("late reply");
    assert!(matches!(e, DriverError::Timeout { .. }), "{e}");
    m.stop().await;

    let (m, h) = start(with_faults(&["stall@1"])).await;
    let e = h.pose().await.expect_err("stalled");
    assert!(matches!(e, DriverError::Timeout { .. }), "{e}");
    m.stop().await;
}

#[tokio::test]
async fn documented_exchange_replays() {
    let mut args = MockArgs::new(MockDevice::Microscope);
    args.replay = Some(
        format!(
            "{}/../tests/data/transcripts/microscope.jsonl",
            env!("CARGO_MANIFEST_DIR")
        )
        .into(),
    );
    let (m, h) = start(args).await;
    assert_eq!(
        h.id().await.unwrap(),
        "calibd-pose/1 vision PC (documented example)"
    );
    let p = h.pose().await.unwrap();
    assert_eq!(p.seq, 17);
    assert_eq!((p.x_m, p.y_m, p.theta_rad), (1.0125e-3, -2.5e-4, 0.00123));
    let e = h.pose().await.expect_err("pattern lost");
    assert!(matches!(e, DriverError::Device { code: 2, .. }), "{e}");
    m.stop().await;
}

#[tokio::test]
async fn identity_is_the_id_line_and_one_fresh_pose() {
    use calibd_drivers::Identity;
    let (m, h) = start(MockArgs::new(MockDevice::Microscope)).await;
    let id = h.identity().await.unwrap();
    assert_eq!(id.id, MOCK_ID);
    let p = id.pose.unwrap();
    assert_eq!(p.seq, 1);
    assert!((p.x_m.hypot(p.y_m) - 1e-4).abs() < 1e-6, "{p:?}");
    assert_eq!(id.pose_error, None);
    assert!(id.problems().is_empty());
    let row = id.device_identity();
    assert_eq!(row.device_kind, "microscope");
    assert!(
        row.summary
            .starts_with("calibd-pose/1 simulated microscope; image 1: x "),
        "{}",
        row.summary
    );
    assert_eq!(row.details["pose"]["seq"], 1);
    m.stop().await;

    // The second reply (the pose) is the fault kit's device error (3 camera busy): kept in
    // the identity, with the fix.
    let (m, h) = start(with_faults(&["device-error@2"])).await;
    let id = h.identity().await.unwrap();
    assert_eq!(id.id, MOCK_ID);
    assert_eq!(id.pose, None);
    let e = id.pose_error.clone().unwrap();
    assert_eq!(e, "error 3: camera busy");
    assert_eq!(id.problems().len(), 1);
    m.stop().await;
}
