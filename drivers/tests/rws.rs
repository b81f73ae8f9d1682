//! RWS driver against the RWS mock (IRB 120) over loopback HTTP with Digest auth.

use std::time::Duration;

use calibd_drivers::mock::{self, FaultSpec, MockArgs, MockDevice};
use calibd_drivers::rws::{self, RwsConfig, RwsHandle, irb120};
use calibd_drivers::{Backoff, DriverError, Recorder, TcpConnector};

fn cfg() -> RwsConfig {
    RwsConfig {
        timeout: Duration::from_millis(1500),
        poll: Duration::from_millis(10),
        move_timeout: Duration::from_secs(5),
        backoff: Backoff {
            initial: Duration::from_millis(10),
            max: Duration::from_millis(50),
            attempts: 3,
        },
        ..RwsConfig::default()
    }
}

async fn start(faults: &[&str]) -> (mock::RunningMock, RwsHandle) {
    let mut args = MockArgs::new(MockDevice::Abb);
    args.faults = faults
        .iter()
        .map(|f| f.parse::<FaultSpec>().unwrap())
        .collect();
    let m = mock::start(args).await.unwrap();
    let h = RwsHandle::connect(TcpConnector::new(m.addr.clone()), cfg());
    (m, h)
}

fn close(a: &[f64; 6], b: &[f64; 6], tol: f64) -> bool {
    a.iter().zip(b).all(|(x, y)| (x - y).abs() < tol)
}

#[tokio::test]
async fn reads_state_joints_and_rapid_variables() {
    let (m, h) = start(&[]).await;
    assert_eq!(
        h.joints_deg().await.unwrap(),
        [0.0, 0.0, 0.0, 0.0, 30.0, 0.0]
    );
    let s = h.controller_state().await.unwrap();
    assert_eq!(
        (
            s.ctrlstate.as_str(),
            s.opmode.as_str(),
            s.execstate.as_str()
        ),
        ("motoron", "AUTO", "running")
    );
    h.write_rapid("calib_dp", "[1.5,-2,0]").await.unwrap();
    assert_eq!(h.read_rapid("calib_dp").await.unwrap(), "[1.5,-2,0]");
    match h.read_rapid("no_such_var").await {
        Err(DriverError::Device {
            code: -1073445865, ..
        }) => {}
        other => panic!("{other:?}"),
    }
    assert!(
        h.write_rapid("calib_q", "[[1,2,3]]")
            .await
            .unwrap_err()
            .is_device_error()
    );
    assert!(matches!(
        h.read_rapid("a/b").await,
        Err(DriverError::InvalidRequest { .. })
    ));
    // Digest once, then the session cookie: one connection for everything.
    assert_eq!(h.state().borrow().connects, 1);
    m.stop().await;
}

#[tokio::test]
async fn moves_through_the_calib_server_module() {
    let (m, h) = start(&[]).await;
    let target = [10.0, -5.0, 8.0, 0.0, 35.0, 0.0];
    let q = h.move_abs_j(target).await.unwrap();
    assert!(close(&q, &target, 1e-3), "{q:?}");
    let q2 = h.move_rel_tool([1.0, 0.0, -2.0]).await.unwrap();
    // The flange moved 1 mm along its x axis and -2 mm along its z axis, orientation kept.
    let (t0, t1) = (irb120::fk(&q), irb120::fk(&q2));
    for i in 0..3 {
        let want = t0[i][3] + t0[i][0] - 2.0 * t0[i][2];
        assert!(
            (t1[i][3] - want).abs() < 1e-3,
            "axis {i}: {} vs {want}",
            t1[i][3]
        );
    }
    assert_eq!(h.read_rapid("calib_ack").await.unwrap(), "2");
    m.stop().await;
}

#[tokio::test]
async fn safety_limits_refuse_before_sending() {
    let (m, h) = start(&[]).await;
    let home = h.joints_deg().await.unwrap();
    let r = h.move_abs_j([0.0, 0.0, 75.0, 0.0, 30.0, 0.0]).await;
    assert!(
        matches!(&r, Err(DriverError::Safety { reason, .. }) if reason.contains("joint 3")),
        "{r:?}"
    );
    let r = h.move_abs_j([20.0, 0.0, 0.0, 0.0, 30.0, 0.0]).await;
    assert!(
        matches!(&r, Err(DriverError::Safety { reason, .. }) if reason.contains("step")),
        "{r:?}"
    );
    let r = h.move_rel_tool([8.0, 8.0, 0.0]).await;
    assert!(matches!(r, Err(DriverError::Safety { .. })), "{r:?}");
    assert_eq!(h.read_rapid("calib_seq").await.unwrap(), "0");
    assert_eq!(h.joints_deg().await.unwrap(), home);
    m.stop().await;
}

#[tokio::test]
async fn wrong_password_is_a_device_error() {
    let m = mock::start(MockArgs::new(MockDevice::Abb)).await.unwrap();
    let mut c = cfg();
    c.password = "wrong".into();
    let h = RwsHandle::connect(TcpConnector::new(m.addr.clone()), c);
    match h.joints_deg().await {
        Err(DriverError::Device { message, .. }) => assert!(message.contains("401"), "{message}"),
        other => panic!("{other:?}"),
    }
    m.stop().await;
}

#[tokio::test]
async fn faults_give_typed_errors_or_reconnect() {
    // Replies counted after the Digest challenge: 1 = first joints reading.
    let (m, h) = start(&["device-error@1"]).await;
    match h.joints_deg().await {
        Err(DriverError::Device {
            code: -1073414144, ..
        }) => {}
        other => panic!("{other:?}"),
    }
    assert!(h.joints_deg().await.is_ok());
    m.stop().await;
    for fault in ["garbage@2", "truncate@2", "stall@2"] {
        let (m, h) = start(&[fault]).await;
        h.joints_deg().await.unwrap();
        let e = h.joints_deg().await.unwrap_err();
        let ok = match fault {
            "garbage@2" => matches!(e, DriverError::Protocol { .. }),
            "truncate@2" => matches!(
                e,
                DriverError::Transport { .. } | DriverError::Closed { .. }
            ),
            _ => matches!(e, DriverError::Timeout { .. }),
        };
        assert!(ok, "{fault}: {e:?}");
        assert!(h.joints_deg().await.is_ok(), "{fault}");
        assert_eq!(h.state().borrow().connects, 2, "{fault}");
        m.stop().await;
    }
    // A dropped keep-alive connection is retried once on a new one: no error at all.
    let (m, h) = start(&["drop@2"]).await;
    h.joints_deg().await.unwrap();
    h.joints_deg().await.unwrap();
    assert_eq!(h.state().borrow().connects, 2);
    m.stop().await;
}

const FIXTURE: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../tests/data/transcripts/abb.jsonl"
);

async fn fixture_session(h: &RwsHandle) -> (String, [f64; 6], [f64; 6]) {
    let seq = h.read_rapid("calib_seq").await.unwrap();
    let q = h.move_abs_j([5.0, 0.0, 0.0, 0.0, 30.0, 0.0]).await.unwrap();
    let j = h.joints_deg().await.unwrap();
    (seq, q, j)
}

/// Re-records the checked-in transcript: `CALIBD_WRITE_TRANSCRIPTS=1 cargo test ...`.
#[tokio::test]
async fn record_fixture_when_asked() {
    if std::env::var("CALIBD_WRITE_TRANSCRIPTS").is_err() {
        return;
    }
    let m = mock::start(MockArgs::new(MockDevice::Abb)).await.unwrap();
    let rec = Recorder::create(FIXTURE.as_ref(), "abb", "RWS 1.0 session against calibd's IRC5 mock: Digest auth, read calib_seq, MoveAbsJ via the calib server, read joints").unwrap();
    let h = RwsHandle::connect(
        TcpConnector {
            addr: m.addr.clone(),
            recorder: Some(rec),
        },
        cfg(),
    );
    fixture_session(&h).await;
    m.stop().await;
}

#[tokio::test]
async fn checked_in_transcript_replays() {
    let mut args = MockArgs::new(MockDevice::Abb);
    args.replay = Some(FIXTURE.into());
    let m = mock::start(args).await.unwrap();
    let h = RwsHandle::connect(TcpConnector::new(m.addr.clone()), cfg());
    let (seq, q, j) = fixture_session(&h).await;
    assert_eq!(seq, "0");
    assert!(close(&q, &[5.0, 0.0, 0.0, 0.0, 30.0, 0.0], 1e-3));
    assert_eq!(q, j);
    m.stop().await;
}

#[tokio::test]
async fn identity_names_the_controller_and_the_calib_module() {
    use calibd_drivers::Identity;
    let (m, h) = start(&[]).await;
    let id = h.identity(rws::DEFAULT_CALIB_MODULE).await.unwrap();
    assert_eq!(id.controller_name, "IRB120-sim");
    assert_eq!(id.robotware_version, "6.15.1013");
    assert_eq!(id.robotware_version_name, "6.15.01.00");
    assert_eq!(id.rapid_task, "T_ROB1");
    assert_eq!(id.calib_module, "CalibServer");
    assert!(id.calib_module_loaded);
    assert_eq!(id.rapid_modules, ["CalibServer", "BASE", "user"]);
    assert_eq!(
        (
            id.ctrlstate.as_str(),
            id.opmode.as_str(),
            id.execstate.as_str()
        ),
        ("motoron", "AUTO", "running")
    );
    assert!(id.problems().is_empty(), "{:?}", id.problems());
    assert!(id.module_error().is_none());
    let row = id.device_identity();
    assert_eq!(row.device_kind, "rws");
    assert_eq!(
        row.summary,
        "IRB120-sim, RobotWare 6.15.01.00, CalibServer loaded, motoron AUTO running"
    );
    assert_eq!(row.details["robotware_version"], "6.15.1013");
    m.stop().await;
}

#[tokio::test]
async fn identity_reports_a_missing_calib_module_with_the_fix() {
    let mut args = MockArgs::new(MockDevice::Abb);
    args.rapid_module = "SomethingElse".into();
    let m = mock::start(args).await.unwrap();
    let h = RwsHandle::connect(TcpConnector::new(m.addr.clone()), cfg());
    let id = h.identity(rws::DEFAULT_CALIB_MODULE).await.unwrap();
    assert!(!id.calib_module_loaded);
    assert_eq!(id.rapid_modules, ["SomethingElse", "BASE", "user"]);
    let e = id.module_error().unwrap().to_string();
    assert!(
        e.contains(
            "RAPID module CalibServer is not loaded in T_ROB1: load drivers/rapid/CalibServer.mod"
        ),
        "{e}"
    );
    m.stop().await;
}

/// A fault on any request of a move (the reply lost after the controller acted on it) never
/// makes the next move report success without moving: whatever happened to the faulted move,
/// the one after it ends at its own target. The first move (to where the robot stands) leaves
/// the driver with a cached command number, as in a campaign.
#[tokio::test]
async fn a_lost_reply_during_a_move_never_fakes_the_next_move() {
    let home = [0.0, 0.0, 0.0, 0.0, 30.0, 0.0];
    let first = [1.0, -0.5, 0.8, 0.0, 31.0, 0.0];
    let second = [1.5, -0.2, 1.0, 0.5, 30.5, 0.3];
    for n in 1..=24 {
        let (m, h) = start(&[&format!("garbage@{n}")]).await;
        if h.move_abs_j(home).await.is_ok() {
            let _ = h.move_abs_j(first).await;
        }
        // The fault may land in this move instead; it fires once, so a second try is clean.
        let q = match h.move_abs_j(second).await {
            Ok(q) => q,
            Err(_) => h.move_abs_j(second).await.unwrap(),
        };
        assert!(close(&q, &second, 1e-3), "garbage@{n}: reported {q:?}");
        let now = h.joints_deg().await.unwrap();
        assert!(close(&now, &second, 1e-3), "garbage@{n}: robot at {now:?}");
        m.stop().await;
    }
}

#[tokio::test]
async fn a_module_is_uploaded_and_loaded_and_refusals_carry_the_controller_message() {
    let (m, h) = start(&[]).await;
    let text = "MODULE Filtered\n  CONST robtarget p := [[1,2,3],[1,0,0,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];\nENDMODULE\n";
    // The calibd program runs: the controller refuses to load into a running task.
    let e = h
        .load_module("Filtered.mod", text, false)
        .await
        .unwrap_err();
    let msg = e.to_string();
    assert!(
        e.is_device_error() && msg.contains("RAPID program is executing"),
        "{msg}"
    );
    // Stopped first, it loads; the task lists the module.
    let path = h.load_module("Filtered.mod", text, true).await.unwrap();
    assert_eq!(path, "$HOME/Filtered.mod");
    let id = h.identity("CalibServer").await.unwrap();
    assert!(id.rapid_modules.iter().any(|n| n == "Filtered"), "{id:?}");
    assert_eq!(id.execstate, "stopped");
    // Loading it again replaces it (one entry); a syntax error is refused with its line.
    h.load_module("Filtered.mod", text, false).await.unwrap();
    let id = h.identity("CalibServer").await.unwrap();
    assert_eq!(
        id.rapid_modules.iter().filter(|n| *n == "Filtered").count(),
        1
    );
    let bad = "MODULE Bad\n  CONST num a{2} := [1, 2;\nENDMODULE\n";
    let e = h.load_module("Bad.mod", bad, false).await.unwrap_err();
    assert!(e.to_string().contains("line 2"), "{e}");
    assert!(matches!(
        h.load_module("../x.mod", text, false).await,
        Err(DriverError::InvalidRequest { .. })
    ));
    m.stop().await;
}
