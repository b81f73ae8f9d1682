//! SmarAct MCS and MCS2 drivers against their mocks over loopback TCP, via the common
//! `Stage` trait, with faults and the documented exchanges as transcripts.

use std::sync::Arc;
use std::time::Duration;

use calibd_drivers::mock::{self, FaultSpec, Faults, MockArgs, MockDevice};
use calibd_drivers::smaract::mock::{Mcs2ErrorQueue, Slc1730x3, mcs2_handler_with_queue};
use calibd_drivers::smaract::{Mcs2Handle, McsHandle, Stage, StageConfig};
use calibd_drivers::{Backoff, DriverError, TcpConnector};

fn cfg() -> StageConfig {
    StageConfig {
        timeout: Duration::from_millis(1500),
        move_timeout: Duration::from_secs(3),
        poll: Duration::from_millis(5),
        backoff: Backoff {
            initial: Duration::from_millis(10),
            max: Duration::from_millis(50),
            attempts: 3,
        },
    }
}

async fn start(
    dev: MockDevice,
    faults: &[&str],
    replay: Option<&str>,
) -> (mock::RunningMock, Arc<dyn Stage>, String) {
    let mut args = MockArgs::new(dev);
    args.faults = faults
        .iter()
        .map(|f| f.parse::<FaultSpec>().unwrap())
        .collect();
    args.replay = replay.map(|r| {
        format!(
            "{}/../tests/data/transcripts/{r}",
            env!("CARGO_MANIFEST_DIR")
        )
        .into()
    });
    let m = mock::start(args).await.unwrap();
    let c = TcpConnector::new(m.addr.clone());
    let s: Arc<dyn Stage> = match dev {
        MockDevice::Mcs => Arc::new(McsHandle::connect(c, cfg())),
        _ => Arc::new(Mcs2Handle::connect(c, cfg())),
    };
    let addr = m.addr.clone();
    (m, s, addr)
}

/// The same scenario for both controllers through `dyn Stage`.
async fn scenario(dev: MockDevice) {
    let (m, s, _) = start(dev, &[], None).await;
    let st = s.status(1).await.unwrap();
    assert!(!st.referenced && !st.moving && !st.fault, "{st:?}");
    s.reference(1).await.unwrap();
    assert!(s.status(1).await.unwrap().referenced);
    assert_eq!(s.position(1).await.unwrap(), 0);
    // 1.5 mm; the simulated closed loop stops 2 nm short (as in the documented MCS log).
    assert_eq!(
        s.move_absolute(1, 1_500_000_000).await.unwrap(),
        1_499_998_000
    );
    assert_eq!(
        s.move_absolute(1, -250_000_000).await.unwrap(),
        -250_002_000
    );
    match s.move_absolute(1, 99_000_000_000_000).await {
        Err(DriverError::Device { code, .. }) => {
            assert_eq!(code, if dev == MockDevice::Mcs { 147 } else { -222 })
        }
        other => panic!("{other:?}"),
    }
    assert!(s.position(7).await.unwrap_err().is_device_error());
    m.stop().await;
}

#[tokio::test]
async fn mcs_moves_references_and_reports_errors() {
    scenario(MockDevice::Mcs).await;
}

#[tokio::test]
async fn mcs2_moves_references_and_reports_errors() {
    scenario(MockDevice::Mcs2).await;
}

#[tokio::test]
async fn mcs_raw_command_errors_are_device_errors() {
    let (m, _, addr) = start(MockDevice::Mcs, &[], None).await;
    let h = McsHandle::connect(TcpConnector::new(addr), cfg());
    match h.command(":XYZ0").await {
        Err(DriverError::Device {
            code: 2, message, ..
        }) => assert!(message.contains("invalid command")),
        other => panic!("{other:?}"),
    }
    m.stop().await;
}

#[tokio::test]
async fn mcs2_positioner_fault_is_a_device_error() {
    // Reply 1 = the error-queue count read on connect; the mock then latches a positioner
    // fault on ch 0 (and queues its error, drained as not ours before the next command).
    let (m, s, _) = start(MockDevice::Mcs2, &["device-error@1"], None).await;
    s.status(0).await.unwrap();
    assert!(s.status(0).await.unwrap().fault);
    assert!(
        s.move_absolute(0, 1_000_000)
            .await
            .unwrap_err()
            .is_device_error()
    );
    m.stop().await;
}

#[tokio::test]
async fn link_faults_give_typed_errors_then_reconnect() {
    for dev in [MockDevice::Mcs, MockDevice::Mcs2] {
        for fault in ["garbage@3", "drop@3", "truncate@3", "stall@3"] {
            let planned = if dev == MockDevice::Mcs2 {
                // Reply 1 = the count on connect; each position read is a line of three
                // replies (count, position, count): the second position is reply 6.
                fault.replace("@3", "@6")
            } else {
                fault.to_string()
            };
            let (m, s, _) = start(dev, &[planned.as_str()], None).await;
            s.position(0).await.unwrap();
            let e = s.position(0).await.unwrap_err();
            let ok = match fault {
                "garbage@3" => matches!(e, DriverError::Protocol { .. }),
                "drop@3" => matches!(e, DriverError::Closed { .. }),
                "truncate@3" => matches!(
                    e,
                    DriverError::Closed { .. } | DriverError::Transport { .. }
                ),
                _ => matches!(e, DriverError::Timeout { after_ms: 1500, .. }),
            };
            assert!(ok, "{dev:?} {fault}: {e:?}");
            assert_eq!(s.position(0).await.unwrap(), 0, "{dev:?} {fault}");
            m.stop().await;
        }
    }
}

#[tokio::test]
async fn documented_exchanges_replay() {
    for (dev, file) in [
        (MockDevice::Mcs, "mcs.jsonl"),
        (MockDevice::Mcs2, "mcs2.jsonl"),
    ] {
        let (m, s, _) = start(dev, &[], Some(file)).await;
        if dev == MockDevice::Mcs2 {
            assert_eq!(s.status(0).await.unwrap().raw, 96);
        }
        s.reference(0).await.unwrap();
        let want = if dev == MockDevice::Mcs {
            1_499_998_000
        } else {
            1_499_999_871
        };
        assert_eq!(s.move_absolute(0, 1_500_000_000).await.unwrap(), want);
        let far = if dev == MockDevice::Mcs {
            99_999_999_000
        } else {
            99_000_000_000_000
        };
        match s.move_absolute(0, far).await {
            Err(DriverError::Device { code, .. }) => {
                assert_eq!(code, if dev == MockDevice::Mcs { 147 } else { -222 })
            }
            other => panic!("{dev:?}: {other:?}"),
        }
        m.stop().await;
    }
}

/// An MCS2 mock whose error queue already holds `stale` (left by another client), and a
/// driver connected to it.
async fn mcs2_with_queue(stale: &[(i64, &str)]) -> (mock::RunningMock, Mcs2Handle, Mcs2ErrorQueue) {
    let (handler, queue) = mcs2_handler_with_queue(Box::new(Slc1730x3), Faults::default());
    for (code, text) in stale {
        queue.push(*code, text);
    }
    let m = mock::start_with("127.0.0.1:0", handler).await.unwrap();
    let h = Mcs2Handle::connect(TcpConnector::new(m.addr.clone()), cfg());
    (m, h, queue)
}

#[tokio::test]
async fn mcs2_errors_left_by_another_client_are_drained_on_connect_not_blamed() {
    let (m, h, q) = mcs2_with_queue(&[
        (-200, "Execution error (another client)"),
        (-113, "Undefined header (another client)"),
    ])
    .await;
    h.set(":CHAN0:MMOD 0").await.unwrap();
    assert!(q.pending().is_empty(), "{:?}", q.pending());
    assert_eq!(h.state().borrow().stale_errors_drained, 2);
    assert_eq!(h.position(0).await.unwrap(), 0);
    m.stop().await;
}

#[tokio::test]
async fn mcs2_no_error_reply_is_not_a_fault() {
    // A queue entry that reads back as 0,"No error", before connect and between commands.
    let (m, h, q) = mcs2_with_queue(&[(0, "No error")]).await;
    h.set(":CHAN0:MMOD 0").await.unwrap();
    q.push(0, "No error");
    h.set(":CHAN0:VEL 1000000000").await.unwrap();
    assert!(q.pending().is_empty(), "{:?}", q.pending());
    assert_eq!(h.state().borrow().stale_errors_drained, 0);
    m.stop().await;
}

#[tokio::test]
async fn mcs2_error_is_attributed_to_the_command_that_caused_it() {
    let (m, h, q) = mcs2_with_queue(&[(-200, "Execution error (another client)")]).await;
    match h.set(":CHAN0:BOGUS 1").await {
        Err(DriverError::Device {
            code: -113,
            message,
            ..
        }) => {
            assert!(message.contains(":CHAN0:BOGUS 1"), "{message}");
            assert!(!message.contains("another client"), "{message}");
        }
        other => panic!("expected the invalid command's own error, got {other:?}"),
    }
    // An unchecked query that queues an error (no channel 9) is not blamed on the next
    // command either.
    h.query(":CHAN9:STAT?").await.unwrap();
    h.set(":CHAN0:MMOD 0").await.unwrap();
    assert!(q.pending().is_empty(), "{:?}", q.pending());
    assert_eq!(h.state().borrow().stale_errors_drained, 2);
    m.stop().await;
}

#[tokio::test]
async fn mcs2_identity_reports_serial_name_channels_and_referencing() {
    use calibd_drivers::Identity;
    let (m, _, addr) = start(MockDevice::Mcs2, &[], None).await;
    let h = Mcs2Handle::connect(TcpConnector::new(addr), cfg());
    h.reference(1).await.unwrap();
    h.move_absolute(1, 1_500_000_000).await.unwrap();
    let id = h.identity(&[0, 1, 7]).await.unwrap();
    assert_eq!(id.controller, "mcs2");
    assert_eq!(id.serial_number, "MCS2-00001234");
    assert_eq!(id.device_name.as_deref(), Some("MCS2-sim"));
    assert_eq!(id.channel_count, 3);
    assert_eq!(id.missing_channels, [7]);
    assert_eq!(id.channels.len(), 2);
    let (c0, c1) = (&id.channels[0], &id.channels[1]);
    assert_eq!(
        (c0.channel, c0.referenced, c0.fault, c0.position_pm),
        (0, false, false, 0)
    );
    // Sensor present + calibrated + closed loop + amplifier + in position: 0x4_0062 + bit 19.
    assert_eq!(
        c0.state_raw,
        (1 << 1) | (1 << 5) | (1 << 6) | (1 << 18) | (1 << 19)
    );
    assert!(c1.referenced);
    assert_eq!(c1.state_raw & (1 << 7), 1 << 7);
    assert_eq!(c1.position_pm, 1_500_000_000 - 2000);
    let p = id.problems();
    assert_eq!(p.len(), 2, "{p:?}");
    assert!(
        p[0].starts_with("channel 7 is configured but the controller has only 3"),
        "{p:?}"
    );
    assert!(p[1].starts_with("channel 0 is not referenced"), "{p:?}");
    let row = id.device_identity();
    assert_eq!(row.device_kind, "mcs2");
    assert_eq!(
        row.summary,
        "SmarAct MCS2 MCS2-00001234 \"MCS2-sim\", 3 channels; ch0 NOT ref 0.000 mm, ch1 ref 1.500 mm"
    );
    m.stop().await;
}

#[tokio::test]
async fn mcs_identity_reports_system_id_channels_and_position_known() {
    let (m, _, addr) = start(MockDevice::Mcs, &[], None).await;
    let h = McsHandle::connect(TcpConnector::new(addr), cfg());
    h.reference(2).await.unwrap();
    let id = h.identity(&[0, 2]).await.unwrap();
    assert_eq!(id.controller, "mcs");
    assert_eq!(id.serial_number, "3118167526");
    assert_eq!(id.device_name, None);
    assert_eq!(id.channel_count, 3);
    assert!(id.missing_channels.is_empty());
    assert_eq!(
        id.channels
            .iter()
            .map(|c| (c.channel, c.referenced, c.state_raw))
            .collect::<Vec<_>>(),
        [(0, false, 3), (2, true, 3)]
    );
    m.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mcs2_errors_another_client_causes_meanwhile_are_not_pinned_on_ours() {
    use tokio::io::AsyncWriteExt;
    let (m, h, q) = mcs2_with_queue(&[]).await;
    // The other client: one bad line every 10 ms on its own connection to the same port.
    let (stop, mut stopped) = tokio::sync::watch::channel(false);
    let addr = m.addr.clone();
    let flood = tokio::spawn(async move {
        let mut c = tokio::net::TcpStream::connect(&addr).await.unwrap();
        let mut tick = tokio::time::interval(Duration::from_millis(10));
        let mut sent = 0u64;
        loop {
            tokio::select! {
                _ = stopped.changed() => return sent,
                _ = tick.tick() => {}
            }
            if c.write_all(b":BOGUS:HEADER 1\n").await.is_err() {
                return sent;
            }
            sent += 1;
        }
    });
    // Until its errors reach the shared queue.
    let mut seen = false;
    for _ in 0..1000 {
        if !q.pending().is_empty() {
            seen = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    assert!(seen, "the other client's errors never reached the queue");
    h.reference(1).await.unwrap();
    // Moves (mode, move, state polls, position) and position reads while the errors land.
    for i in 0..40i64 {
        let target = (i % 8 - 4) * 250_000_000;
        let at = h
            .move_absolute(1, target)
            .await
            .unwrap_or_else(|e| panic!("move {i} to {target} pm: {e}"));
        assert_eq!(at, target - 2000, "move {i}");
        assert_eq!(h.position(1).await.unwrap(), target - 2000, "read {i}");
    }
    // A bad command of our own is still reported, as ours, with its own error only.
    match h.set(":CHAN1:BOGUS 1").await {
        Err(DriverError::Device { code, message, .. }) => {
            assert_eq!(code, -113);
            assert!(message.contains(":CHAN1:BOGUS 1"), "{message}");
            assert!(!message.contains("also queued"), "{message}");
        }
        other => panic!("expected our own error, got {other:?}"),
    }
    match h.move_absolute(1, 99_000_000_000_000).await {
        Err(DriverError::Device { code: -222, .. }) => {}
        other => panic!("expected the range limit, got {other:?}"),
    }
    let _ = stop.send(true);
    let sent = flood.await.unwrap();
    let drained = h.state().borrow().stale_errors_drained;
    eprintln!("other client: {sent} bad lines; drained as not ours: {drained}");
    // The other client's errors really were in the queue around our commands.
    assert!(drained > 0, "no foreign error was drained (sent {sent})");
    m.stop().await;
}

#[tokio::test]
async fn mcs2_a_long_queue_of_foreign_errors_is_drained_and_not_blamed() {
    let (m, h, q) = mcs2_with_queue(&[]).await;
    h.set(":CHAN0:MMOD 0").await.unwrap();
    // More than one drain reads: the rest stays queued, still before our next command.
    for i in 0..300 {
        q.push(-113, &format!("Undefined header (another client, {i})"));
    }
    h.set(":CHAN0:MMOD 0").await.unwrap();
    match h.set(":CHAN0:BOGUS 1").await {
        Err(DriverError::Device { code, message, .. }) => {
            assert_eq!(code, -113);
            assert!(message.contains(":CHAN0:BOGUS 1"), "{message}");
            assert!(!message.contains("another client"), "{message}");
        }
        other => panic!("expected our own error, got {other:?}"),
    }
    assert!(q.pending().is_empty(), "{} left", q.pending().len());
    assert_eq!(h.state().borrow().stale_errors_drained, 300);
    m.stop().await;
}
