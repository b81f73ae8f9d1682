//! QTM driver against the QTM mock over loopback TCP/UDP, faults, transcripts, and the
//! third-party `qualisys` 0.2.1 client against the mock.

use std::time::Duration;

use calibd_drivers::mock::{self, FaultSpec, MockArgs, MockDevice};
use calibd_drivers::qtm::{QtmConfig, QtmHandle, StreamTransport};
use calibd_drivers::{Backoff, DriverError, Recorder, TcpConnector};

fn cfg() -> QtmConfig {
    QtmConfig {
        timeout: Duration::from_millis(1500),
        backoff: Backoff {
            initial: Duration::from_millis(10),
            max: Duration::from_millis(50),
            attempts: 3,
        },
        udp_bind: "127.0.0.1:0".into(),
        ..QtmConfig::default()
    }
}

async fn start(faults: &[&str]) -> (mock::RunningMock, QtmHandle) {
    let mut args = MockArgs::new(MockDevice::Qtm);
    args.rate_hz = 200.0;
    args.faults = faults
        .iter()
        .map(|f| f.parse::<FaultSpec>().unwrap())
        .collect();
    let m = mock::start(args).await.unwrap();
    let h = QtmHandle::connect(TcpConnector::new(m.addr.clone()), cfg());
    (m, h)
}

#[tokio::test]
async fn state_parameters_and_tcp_stream() {
    let (m, h) = start(&[]).await;
    assert_eq!(h.get_state().await.unwrap(), 1);
    assert_eq!(h.state().borrow().version, Some((1, 25)));
    let p = h.parameters_3d().await.unwrap();
    assert_eq!(p.labels, vec!["tool_a", "tool_b", "tool_c", "base"]);
    assert_eq!(p.axis_upwards, "+Z");
    let mut rx = h.frames();
    h.stream("3D", StreamTransport::Tcp).await.unwrap();
    let mut last = None;
    for _ in 0..40 {
        let f = tokio::time::timeout(Duration::from_secs(2), rx.recv())
            .await
            .unwrap()
            .unwrap();
        let mk = f.markers_3d().unwrap();
        assert_eq!(mk.len(), 4);
        // Marker 0 runs on a 50 mm circle around (500, 200) at z = 1000.
        let r = ((mk[0][0] - 500.0).powi(2) + (mk[0][1] - 200.0).powi(2)).sqrt();
        assert!((r - 50.0).abs() < 1e-3, "radius {r}");
        assert_eq!(mk[0][2], 1000.0);
        // Timestamp = frame / 200 Hz.
        assert_eq!(f.timestamp_us, i64::from(f.frame_number) * 5000);
        if let Some(l) = last {
            assert_eq!(f.frame_number, l + 1);
        }
        last = Some(f.frame_number);
    }
    h.stop_stream().await.unwrap();
    // Commands still work after stopping the stream (frames in flight are skipped).
    assert_eq!(
        h.command("QTMVersion").await.unwrap(),
        "QTM Version is 2.3 (build 464)"
    );
    let s = h.state().borrow().clone();
    assert_eq!(s.missed_frames, 0);
    assert!(s.frames >= 40);
    m.stop().await;
}

#[tokio::test]
async fn udp_stream_with_unlabelled_markers_and_occlusion() {
    let mut args = MockArgs::new(MockDevice::Qtm);
    args.rate_hz = 200.0;
    let m = mock::start(args).await.unwrap();
    let path = std::env::temp_dir().join(format!("qtm-udp-{}.jsonl", std::process::id()));
    let mut c = cfg();
    c.udp_recorder = Some(Recorder::create(&path, "qtm", "udp test").unwrap());
    let h = QtmHandle::connect(TcpConnector::new(m.addr.clone()), c);
    let mut rx = h.frames();
    h.stream("3D 3DNoLabels", StreamTransport::Udp)
        .await
        .unwrap();
    let mut occluded = 0;
    for _ in 0..60 {
        let f = tokio::time::timeout(Duration::from_secs(2), rx.recv())
            .await
            .unwrap()
            .unwrap();
        assert_eq!(f.components.len(), 2);
        let mk = f.markers_3d().unwrap();
        // Marker "base" is occluded for the first 0.1 s of every second: NaN, not zero.
        let t = f.frame_number as f64 / 200.0;
        if t.fract() < 0.1 {
            assert!(mk[3].iter().all(|v| v.is_nan()), "frame {}", f.frame_number);
            occluded += 1;
        } else {
            assert!(mk[3].iter().all(|v| v.is_finite()));
        }
    }
    assert!(occluded > 0);
    h.stop_stream().await.unwrap();
    // Every datagram was recorded as one `udp` chunk that decodes to a data packet.
    let t = calibd_drivers::Transcript::load(&path).unwrap();
    assert!(t.chunks.len() >= 60 && t.chunks.iter().all(|c| c.udp));
    let p = calibd_drivers::qtm::packet::decode_whole(&t.chunks[0].bytes().unwrap()).unwrap();
    assert!(matches!(p, calibd_drivers::qtm::Packet::Data(_)));
    m.stop().await;
}

#[tokio::test]
async fn device_errors_are_typed() {
    let (m, h) = start(&[]).await;
    match h.command("FlyToTheMoon").await {
        Err(DriverError::Device { message, .. }) => assert_eq!(message, "Parse Error"),
        other => panic!("{other:?}"),
    }
    // Asked for 1.28, the driver negotiates down to the mock's 1.25 ...
    let mut c = cfg();
    c.version = (1, 28);
    let h1 = QtmHandle::connect(TcpConnector::new(m.addr.clone()), c.clone());
    assert_eq!(h1.get_state().await.unwrap(), 1);
    assert_eq!(h1.state().borrow().version, Some((1, 25)));
    // ... but not below its configured minimum.
    c.min_version = (1, 26);
    let h2 = QtmHandle::connect(TcpConnector::new(m.addr.clone()), c);
    match h2.get_state().await {
        Err(DriverError::Device { message, .. }) => assert_eq!(message, "Version NOT supported"),
        other => panic!("{other:?}"),
    }
    m.stop().await;
    let (m, h) = start(&["device-error@2"]).await;
    assert!(h.get_state().await.unwrap_err().is_device_error());
    assert_eq!(h.get_state().await.unwrap(), 1);
    m.stop().await;
}

#[tokio::test]
async fn link_faults_give_typed_errors_then_reconnect() {
    for fault in ["garbage@2", "drop@2", "truncate@2", "stall@2"] {
        let (m, h) = start(&[fault]).await;
        let e = h.get_state().await.unwrap_err();
        let ok = match fault {
            "garbage@2" => matches!(e, DriverError::Protocol { .. }),
            "drop@2" => matches!(e, DriverError::Closed { .. }),
            "truncate@2" => matches!(
                e,
                DriverError::Closed { .. } | DriverError::Transport { .. }
            ),
            _ => matches!(e, DriverError::Timeout { after_ms: 1500, .. }),
        };
        assert!(ok, "{fault}: {e:?}");
        assert_eq!(h.get_state().await.unwrap(), 1, "{fault}");
        assert_eq!(h.state().borrow().connects, 2, "{fault}");
        m.stop().await;
    }
}

#[tokio::test]
async fn stream_resumes_after_the_connection_drops() {
    // Reply 1 = version, 2..: frames; the 30th packet closes the connection.
    let (m, h) = start(&["drop@30"]).await;
    let mut rx = h.frames();
    h.stream("3D", StreamTransport::Tcp).await.unwrap();
    let mut n = 0;
    while n < 60 {
        match tokio::time::timeout(Duration::from_secs(3), rx.recv()).await {
            Ok(Ok(_)) => n += 1,
            other => panic!("after {n} frames: {other:?}"),
        }
    }
    let s = h.state().borrow().clone();
    assert_eq!(s.connects, 2);
    assert!(s.streaming);
    m.stop().await;
}

#[tokio::test]
async fn checked_in_transcript_replays_the_spec_exchange() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../tests/data/transcripts/qtm.jsonl"
    );
    let mut args = MockArgs::new(MockDevice::Qtm);
    args.replay = Some(path.into());
    let m = mock::start(args).await.unwrap();
    let h = QtmHandle::connect(TcpConnector::new(m.addr.clone()), cfg());
    assert_eq!(h.get_state().await.unwrap(), 1);
    let mut rx = h.frames();
    h.stream("3D", StreamTransport::Tcp).await.unwrap();
    let f = tokio::time::timeout(Duration::from_secs(2), rx.recv())
        .await
        .unwrap()
        .unwrap();
    assert_eq!((f.frame_number, f.timestamp_us), (42, 1_234_567));
    let mk = f.markers_3d().unwrap();
    assert_eq!(mk[0], [100.5, -20.25, 300.0]);
    assert!(mk[1][0].is_nan());
    m.stop().await;
}

/// Conformance: the third-party `qualisys` crate (sync, std::net) against our mock.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn qualisys_crate_client_against_the_mock() {
    let mut args = MockArgs::new(MockDevice::Qtm);
    args.rate_hz = 100.0;
    let m = mock::start(args).await.unwrap();
    let port: u16 = m.addr.rsplit(':').next().unwrap().parse().unwrap();
    let r = tokio::task::spawn_blocking(
        move || -> Result<(String, Vec<u32>, usize), qualisys::Error> {
            use qualisys::{
                ComponentOptions, ComponentType, Packet, Parameter, Protocol, StreamRate,
            };
            // The crate connects to base + 1: our mock plays the little-endian port.
            let mut p = Protocol::connect("127.0.0.1", port - 1)?;
            assert_eq!(p.version(), (1, 25), "negotiated down from 1.28");
            let state = format!("{:?}", p.state()?);
            let xml = p.get_parameters(&[Parameter::ThreeD])?;
            assert!(xml.contains("<Name>tool_a</Name>"));
            p.stream_frames(
                StreamRate::AllFrames,
                &[ComponentType::Markers3d],
                &ComponentOptions::default(),
            )?;
            let mut frames = Vec::new();
            let mut markers = 0;
            while frames.len() < 10 {
                if let Packet::Data(f) = p.receive()? {
                    if let Some(qualisys::Component::Markers3d(m)) = f.components.first() {
                        markers = m.markers.len();
                    }
                    frames.push(f.frame_number);
                }
            }
            p.stream_frames_stop()?;
            Ok((state, frames, markers))
        },
    )
    .await
    .unwrap()
    .unwrap();
    assert_eq!(r.0, "Connected");
    assert!(r.1.windows(2).all(|w| w[1] == w[0] + 1), "{:?}", r.1);
    assert_eq!(r.2, 4);
    m.stop().await;
}

#[tokio::test]
async fn a_lost_udp_datagram_is_counted_as_a_frame_gap() {
    // Reply 1 = the version reply; then datagrams: the 5th reply (4th frame) is not sent.
    let (m, h) = start(&["drop@5"]).await;
    let mut rx = h.frames();
    h.stream("3D", StreamTransport::Udp).await.unwrap();
    let mut numbers = Vec::new();
    while numbers.len() < 20 {
        let f = tokio::time::timeout(Duration::from_secs(2), rx.recv())
            .await
            .unwrap()
            .unwrap();
        numbers.push(f.frame_number);
    }
    assert!(!numbers.contains(&4), "{numbers:?}");
    let s = h.state().borrow().clone();
    assert_eq!(s.missed_frames, 1);
    assert_eq!(s.connects, 1);
    m.stop().await;
}

#[tokio::test]
async fn identity_reports_versions_frequency_and_labelled_markers() {
    use calibd_drivers::Identity;
    let (m, h) = start(&[]).await;
    let id = h.identity().await.unwrap();
    assert_eq!(id.protocol_version, "1.25");
    assert_eq!(id.qtm_version, "2.3 (build 464)");
    assert_eq!(id.frequency_hz, 200);
    assert_eq!(id.axis_upwards, "+Z");
    assert_eq!(id.labels, ["tool_a", "tool_b", "tool_c", "base"]);
    assert_eq!(id.labelled_marker_count, 4);
    assert!(id.problems().is_empty());
    assert_eq!(
        id.summary(),
        "QTM 2.3 (build 464), RT protocol 1.25, 200 Hz, 4 labelled markers (tool_a, tool_b, tool_c, base)"
    );
    assert_eq!(h.parameters_general().await.unwrap().frequency_hz, 200);
    // `GetParameters General 3D` is one document with both sections.
    let both = h.command("GetParameters General 3D").await;
    assert!(
        both.is_err(),
        "an XML reply is not a command reply: {both:?}"
    );
    m.stop().await;
}
