//! U-WAVE driver against the U-WAVE mock over a real pty and over TCP, with faults.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use calibd_drivers::mock::{self, FaultSpec, Faults, MockArgs, MockDevice};
use calibd_drivers::uwave::mock::IndicatorModel;
use calibd_drivers::uwave::{AxisMap, SerialConnector, UwaveConfig, UwaveHandle, UwaveState};
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

/// One indicator on channel 0 whose reading the test sets.
struct Settable(Arc<Mutex<f64>>);

impl IndicatorModel for Settable {
    fn channels(&self) -> Vec<u8> {
        vec![0]
    }
    fn read_mm(&mut self, _: u8, _: f64) -> Option<f64> {
        self.0.lock().ok().map(|v| *v)
    }
}

/// Waits (bounded) until the driver state satisfies `f`.
async fn wait_state(h: &UwaveHandle, what: &str, f: impl FnMut(&UwaveState) -> bool) {
    let mut rx = h.state();
    match tokio::time::timeout(Duration::from_secs(10), rx.wait_for(f)).await {
        Ok(Ok(_)) => {}
        _ => panic!(
            "state never reached: {what}; last {:?}",
            *h.state().borrow()
        ),
    }
}

#[tokio::test]
async fn late_reply_to_a_timed_out_request_is_not_the_next_reading() {
    let value = Arc::new(Mutex::new(1.0));
    let mut args = MockArgs::new(MockDevice::Uwave);
    args.rate_hz = 0.1; // one spontaneous reading at connect, the next 10 s later
    args.uwave_request = "RQ{cc}{gg}".into();
    // Reply 1 = the spontaneous reading at connect; reply 2 = the answer to the first
    // request, sent one second late (after the driver's timeout).
    let faults = Faults::new(vec!["delay@2".parse::<FaultSpec>().unwrap()]);
    let model: Arc<Mutex<dyn IndicatorModel>> = Arc::new(Mutex::new(Settable(value.clone())));
    let handler = calibd_drivers::uwave::mock::handler_with(model, &args, faults);
    let m = mock::start_with("127.0.0.1:0", handler).await.unwrap();
    let mut c = cfg();
    c.request_template = "RQ{cc}{gg}".into();
    // Shorter than the delay, longer than what is left of it after the first timeout: the
    // late reply arrives while the second request waits.
    c.timeout = Duration::from_millis(700);
    let h = UwaveHandle::connect(TcpConnector::new(m.addr.clone()), c);
    wait_state(&h, "the reading sent at connect", |s| s.lines >= 1).await;
    match h.fresh(0).await {
        Err(DriverError::Timeout { after_ms: 700, .. }) => {}
        other => panic!("expected a timeout, got {other:?}"),
    }
    // The fixture moves: the indicator now reads 2 mm; the 1 mm reply is still on its way.
    if let Ok(mut v) = value.lock() {
        *v = 2.0;
    }
    let asked = tokio::time::Instant::now();
    let r = h.fresh(0).await.unwrap();
    assert_eq!(r.value, 2.0, "stale reading returned: {r:?}");
    assert!(r.received_at >= asked);
    assert_eq!(h.state().borrow().late_replies_discarded, 1);
    m.stop().await;
}

#[tokio::test]
async fn consecutive_timeouts_reopen_the_link() {
    let mut args = MockArgs::new(MockDevice::Uwave);
    args.rate_hz = 20.0;
    // The first tick sends channels 0 and 1, then the mock stops answering on this link.
    args.faults = vec!["stall@3".parse::<FaultSpec>().unwrap()];
    let m = mock::start(args).await.unwrap();
    let mut c = cfg();
    c.timeout = Duration::from_millis(200);
    c.reopen_after_timeouts = 2;
    let h = UwaveHandle::connect(TcpConnector::new(m.addr.clone()), c);
    wait_state(&h, "two readings before the stall", |s| s.lines >= 2).await;
    for _ in 0..2 {
        match h.fresh(0).await {
            Err(DriverError::Timeout { .. }) => {}
            other => panic!("expected a timeout, got {other:?}"),
        }
    }
    wait_state(&h, "link reopened", |s| s.reopens == 1 && s.connected).await;
    assert_eq!(h.state().borrow().connects, 2);
    let r = h.fresh(0).await.unwrap();
    assert!((r.value_mm() - model_mm(0)).abs() < 0.0025, "{r:?}");
    assert_eq!(h.state().borrow().consecutive_timeouts, 0);
    m.stop().await;
}

#[tokio::test]
async fn identity_reads_receiver_transmitters_and_cached_readings() {
    use calibd_drivers::Identity;
    let mut args = MockArgs::new(MockDevice::Uwave);
    args.pty = true;
    args.rate_hz = 50.0;
    let m = mock::start(args).await.unwrap();
    let conn = SerialConnector {
        path: m.addr.clone(),
        baud: 57600,
        recorder: None,
    };
    let h = UwaveHandle::connect(conn, cfg());
    // One reading in: the mock sends every channel per tick, so all three are cached.
    h.fresh(2).await.unwrap();
    let id = h.identity().await.unwrap();
    assert_eq!(id.receiver.group, 0);
    assert_eq!(id.receiver.receiver_id, "0000123456");
    assert_eq!(id.receiver.band, 15);
    assert_eq!(id.receiver.noise_raw.len(), 16);
    assert_eq!(&id.receiver.noise_raw[..4], &[12, 8, 15, 3]);
    let ids: Vec<&str> = id.transmitters.iter().map(|t| t.id.as_str()).collect();
    assert_eq!(ids, ["0009233800", "0009233801", "0009233802"]);
    assert_eq!(id.channels.len(), 3);
    for (c, r) in id.channels.iter().enumerate() {
        assert_eq!(usize::from(r.channel), c);
        assert_eq!(r.transmitter_state, Some("connected"));
        assert_eq!(r.transmitter_id.as_deref(), Some(ids[c]));
        let v = r.value_mm.unwrap();
        assert!((v - model_mm(r.channel)).abs() < 0.0025, "{r:?}");
        assert!(r.age_ms.unwrap() < 2000, "{r:?}");
    }
    assert!(id.problems().is_empty(), "{:?}", id.problems());
    let row = id.device_identity();
    assert_eq!(row.device_kind, "uwave");
    assert!(
        row.summary
            .starts_with("U-WAVE-R 0000123456 group 00 band 15, 3 transmitters; ch00 6.35"),
        "{}",
        row.summary
    );
    assert_eq!(row.details["receiver"]["receiver_id"], "0000123456");
    m.stop().await;
}
