//! U-WAVE driver against the U-WAVE mock over a real pty and over TCP, with faults.

use std::time::Duration;

use calibd_drivers::mock::{self, FaultSpec, MockArgs, MockDevice};
use calibd_drivers::uwave::{AxisMap, SerialConnector, UwaveConfig, UwaveHandle};
use calibd_drivers::{Backoff, DriverError, Recorder, TcpConnector, Transcript};

fn cfg() -> UwaveConfig {
    UwaveConfig {
        timeout: Duration::from_millis(1500),
        backoff: Backoff {
            initial: Duration::from_millis(10),
            max: Duration::from_millis(50),
            attempts: 3,
        },
        ..UwaveConfig::default()
    }
}

fn model_mm(c: u8) -> f64 {
    6.35 + 0.1 * f64::from(c)
}

#[tokio::test]
async fn reads_three_indicators_over_a_pty() {
    let mut args = MockArgs::new(MockDevice::Uwave);
    args.pty = true;
    args.rate_hz = 50.0;
    let m = mock::start(args).await.unwrap();
    assert!(m.addr.starts_with("/dev/pts/"), "{}", m.addr);
    let mut c = cfg();
    c.axes = [
        AxisMap {
            channel: 0,
            sign: 1.0,
            zero_mm: 6.0,
        },
        AxisMap {
            channel: 1,
            sign: -1.0,
            zero_mm: 6.0,
        },
        AxisMap {
            channel: 2,
            sign: 1.0,
            zero_mm: 0.0,
        },
    ];
    let conn = SerialConnector {
        path: m.addr.clone(),
        baud: 57600,
        recorder: None,
    };
    let h = UwaveHandle::connect(conn, c);
    let r = h.fresh(1).await.unwrap();
    assert_eq!(r.channel, 1);
    assert!((r.value_mm() - model_mm(1)).abs() < 0.0025, "{r:?}");
    let l = h.latest(1).await.unwrap();
    assert!(l.received_at >= r.received_at);
    let ax = h.tool_axes_mm().await.unwrap();
    assert!((ax[0] - 0.35).abs() < 0.0025, "{ax:?}");
    assert!((ax[1] + 0.45).abs() < 0.0025, "{ax:?}");
    assert!((ax[2] - 6.55).abs() < 0.0025, "{ax:?}");
    assert!(h.state().borrow().connected);
    m.stop().await;
}

#[tokio::test]
async fn configured_request_gets_an_immediate_reading_and_unknown_requests_a_device_error() {
    let mut args = MockArgs::new(MockDevice::Uwave);
    args.rate_hz = 0.1; // practically no spontaneous readings
    args.uwave_request = "RQ{cc}{gg}".into();
    let m = mock::start(args).await.unwrap();
    let mut c = cfg();
    c.request_template = "RQ{cc}{gg}".into();
    let h = UwaveHandle::connect(TcpConnector::new(m.addr.clone()), c.clone());
    // The first tick of the mock's interval fires at once; wait it out.
    let _ = h.fresh(2).await;
    let t0 = tokio::time::Instant::now();
    let r = h.fresh(2).await.unwrap();
    assert!(t0.elapsed() < Duration::from_secs(3), "{:?}", t0.elapsed());
    assert!((r.value_mm() - model_mm(2)).abs() < 0.0025);
    // A request the receiver does not know: ST1 ... 50 (request packet error).
    c.request_template = "XX{cc}".into();
    let h2 = UwaveHandle::connect(TcpConnector::new(m.addr.clone()), c);
    match h2.fresh(0).await {
        Err(DriverError::Device { code: 50, .. }) => {}
        other => panic!("expected device error 50, got {other:?}"),
    }
    // Nothing cached on channel 7: stale.
    assert!(matches!(
        h.latest(7).await,
        Err(DriverError::Stale { channel: 7, .. })
    ));
    m.stop().await;
}

async fn with_fault(fault: &str) -> (mock::RunningMock, UwaveHandle) {
    let mut args = MockArgs::new(MockDevice::Uwave);
    args.rate_hz = 20.0;
    args.faults = vec![fault.parse::<FaultSpec>().unwrap()];
    let m = mock::start(args).await.unwrap();
    let h = UwaveHandle::connect(TcpConnector::new(m.addr.clone()), cfg());
    (m, h)
}

#[tokio::test]
async fn device_error_is_typed() {
    let (m, h) = with_fault("device-error@1").await;
    match h.fresh(0).await {
        Err(e @ DriverError::Device { code: 1, .. }) => assert!(e.is_device_error()),
        other => panic!("{other:?}"),
    }
    assert!(h.fresh(0).await.is_ok());
    m.stop().await;
}

#[tokio::test]
async fn garbage_drop_and_truncation_reconnect() {
    for (fault, want_protocol) in [
        ("garbage@2", true),
        ("drop@2", false),
        ("truncate@2", false),
    ] {
        let (m, h) = with_fault(fault).await;
        let mut errors = 0;
        let mut ok_after = false;
        for _ in 0..6 {
            match h.fresh(1).await {
                Ok(r) => {
                    assert!((r.value_mm() - model_mm(1)).abs() < 0.0025);
                    if errors > 0 {
                        ok_after = true;
                        break;
                    }
                }
                Err(DriverError::Protocol { .. }) if want_protocol => errors += 1,
                Err(DriverError::Closed { .. }) if !want_protocol => errors += 1,
                Err(e) => panic!("{fault}: unexpected {e:?}"),
            }
        }
        assert!(
            errors >= 1 && ok_after,
            "{fault}: errors {errors}, recovered {ok_after}"
        );
        assert_eq!(h.state().borrow().connects, 2, "{fault}");
        m.stop().await;
    }
}

#[tokio::test]
async fn stall_times_out() {
    let (m, h) = with_fault("stall@1").await;
    match h.fresh(0).await {
        Err(DriverError::Timeout { after_ms: 1500, .. }) => {}
        other => panic!("{other:?}"),
    }
    m.stop().await;
}

#[tokio::test]
async fn recorded_session_replays_to_the_same_values() {
    let dir = std::env::temp_dir().join(format!("uwave-rec-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("session.jsonl");
    let m = mock::start(MockArgs::new(MockDevice::Uwave)).await.unwrap();
    let rec = Recorder::create(&path, "uwave", "test session").unwrap();
    let conn = TcpConnector {
        addr: m.addr.clone(),
        recorder: Some(rec),
    };
    let h = UwaveHandle::connect(conn, cfg());
    let first = h.fresh(0).await.unwrap();
    drop(h);
    m.stop().await;
    let t = Transcript::load(&path).unwrap();
    assert!(!t.chunks.is_empty());
    let mut args = MockArgs::new(MockDevice::Uwave);
    args.replay = Some(path);
    let m = mock::start(args).await.unwrap();
    let h = UwaveHandle::connect(TcpConnector::new(m.addr.clone()), cfg());
    let again = h.fresh(0).await.unwrap();
    assert_eq!(again.value, first.value);
    m.stop().await;
}

#[tokio::test]
async fn checked_in_transcript_of_real_lines() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../tests/data/transcripts/uwave.jsonl"
    );
    let mut args = MockArgs::new(MockDevice::Uwave);
    args.replay = Some(path.into());
    let m = mock::start(args).await.unwrap();
    let h = UwaveHandle::connect(TcpConnector::new(m.addr.clone()), cfg());
    let (a, b) = tokio::join!(h.fresh(0), h.fresh(2));
    assert_eq!(a.unwrap().value, 11.88);
    assert_eq!(b.unwrap().value, -0.001);
    m.stop().await;
}

#[tokio::test]
async fn transmitter_search_lists_the_three_indicators() {
    let mut args = MockArgs::new(MockDevice::Uwave);
    args.pty = true;
    let m = mock::start(args).await.unwrap();
    let conn = SerialConnector {
        path: m.addr.clone(),
        baud: 57600,
        recorder: None,
    };
    let h = UwaveHandle::connect(conn, cfg());
    let t = h.transmitters().await.unwrap();
    let channels: Vec<u8> = t.iter().map(|t| t.channel).collect();
    assert_eq!(channels, vec![0, 1, 2]);
    assert_eq!(t[1].id, "0009233801");
    assert!(
        t.iter()
            .all(|t| t.state == 2 && t.band == 15 && t.mode == 1)
    );
    // Readings keep flowing during and after the search.
    assert!(h.fresh(2).await.is_ok());
    m.stop().await;
}
