//! CiA 402 driver over the socketcand hub mock (TCP), with SDO aborts, faults and a
//! transcript of the documented exchange. (SocketCAN itself needs vcan: see `can::frame`.)

use std::time::Duration;

use calibd_drivers::can::{
    CanConnect, CanFrame, Cia402Config, Cia402Handle, FrameTransport, SocketcandConnector,
    canopen::obj,
};
use calibd_drivers::mock::{self, FaultSpec, MockArgs, MockDevice};
use calibd_drivers::smaract::Stage;
use calibd_drivers::{Backoff, DriverError};

fn cfg() -> Cia402Config {
    Cia402Config {
        timeout: Duration::from_millis(1500),
        move_timeout: Duration::from_secs(3),
        poll: Duration::from_millis(2),
        backoff: Backoff {
            initial: Duration::from_millis(10),
            max: Duration::from_millis(50),
            attempts: 3,
        },
        ..Cia402Config::default()
    }
}

fn connector(addr: &str) -> SocketcandConnector {
    SocketcandConnector {
        addr: addr.into(),
        bus: "can0".into(),
        recorder: None,
    }
}

async fn start(faults: &[&str]) -> (mock::RunningMock, Cia402Handle) {
    let mut args = MockArgs::new(MockDevice::Can);
    args.faults = faults
        .iter()
        .map(|f| f.parse::<FaultSpec>().unwrap())
        .collect();
    let m = mock::start(args).await.unwrap();
    let h = Cia402Handle::connect(connector(&m.addr), cfg());
    (m, h)
}

#[tokio::test]
async fn enable_move_and_home_through_the_hub() {
    let (m, h) = start(&[]).await;
    // Switch on disabled + voltage enabled + remote.
    assert_eq!(h.statusword().await.unwrap(), 0x0250);
    h.enable().await.unwrap();
    assert_eq!(h.statusword().await.unwrap() & 0x6F, 0x27);
    assert_eq!(h.move_to_counts(100_000).await.unwrap(), 100_000);
    assert_eq!(h.move_to_counts(-20_000).await.unwrap(), -20_000);
    // Through the Stage trait: 1 count = 1000 pm.
    let s: &dyn Stage = &h;
    assert_eq!(s.move_absolute(0, 5_000_000).await.unwrap(), 5_000_000);
    s.reference(0).await.unwrap();
    let st = s.status(0).await.unwrap();
    assert!(st.referenced && !st.fault, "{st:?}");
    assert_eq!(s.position(0).await.unwrap(), 0);
    assert!(matches!(
        s.position(1).await,
        Err(DriverError::InvalidRequest { .. })
    ));
    m.stop().await;
}

#[tokio::test]
async fn sdo_aborts_are_device_errors() {
    let (m, h) = start(&[]).await;
    let code = |e: DriverError| match e {
        DriverError::Device { code, .. } => code,
        other => panic!("{other:?}"),
    };
    assert_eq!(code(h.read(0x1234, 0).await.unwrap_err()), 0x0602_0000);
    assert_eq!(
        code(h.write(obj::STATUSWORD, 0, &[0, 0]).await.unwrap_err()),
        0x0601_0002
    );
    assert_eq!(
        code(h.write(obj::MODES, 0, &[1, 0]).await.unwrap_err()),
        0x0607_0010
    );
    assert_eq!(
        code(h.read(obj::STATUSWORD, 3).await.unwrap_err()),
        0x0609_0011
    );
    assert_eq!(
        h.read(0x1000, 0).await.unwrap(),
        0x0002_0192u32.to_le_bytes()
    );
    m.stop().await;
}

#[tokio::test]
async fn the_hub_forwards_to_every_other_client() {
    let (m, h) = start(&[]).await;
    let mut sniffer = connector(&m.addr).connect().await.unwrap();
    h.statusword().await.unwrap();
    let req = sniffer.recv().await.unwrap();
    assert_eq!(
        req,
        CanFrame::new(0x601, &[0x40, 0x41, 0x60, 0, 0, 0, 0, 0])
    );
    let resp = sniffer.recv().await.unwrap();
    assert_eq!(
        resp,
        CanFrame::new(0x581, &[0x4B, 0x41, 0x60, 0, 0x50, 0x02, 0, 0])
    );
    m.stop().await;
}

#[tokio::test]
async fn faults_give_typed_errors_then_reconnect() {
    let (m, h) = start(&["device-error@1"]).await;
    match h.statusword().await {
        Err(DriverError::Device {
            code: 0x0800_0022, ..
        }) => {}
        other => panic!("{other:?}"),
    }
    assert!(h.statusword().await.is_ok());
    m.stop().await;
    for fault in ["garbage@2", "drop@2", "truncate@2", "stall@2"] {
        let (m, h) = start(&[fault]).await;
        h.statusword().await.unwrap();
        let e = h.statusword().await.unwrap_err();
        let ok = match fault {
            "garbage@2" => matches!(e, DriverError::Protocol { .. }),
            "drop@2" => matches!(e, DriverError::Closed { .. }),
            "truncate@2" => matches!(
                e,
                DriverError::Closed { .. } | DriverError::Transport { .. }
            ),
            _ => matches!(e, DriverError::Timeout { .. }),
        };
        assert!(ok, "{fault}: {e:?}");
        assert_eq!(h.statusword().await.unwrap(), 0x0250, "{fault}");
        assert_eq!(h.state().borrow().connects, 2, "{fault}");
        m.stop().await;
    }
}

#[tokio::test]
async fn documented_exchange_replays() {
    let mut args = MockArgs::new(MockDevice::Can);
    args.replay = Some(
        concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../tests/data/transcripts/can.jsonl"
        )
        .into(),
    );
    let m = mock::start(args).await.unwrap();
    let h = Cia402Handle::connect(connector(&m.addr), cfg());
    assert_eq!(h.statusword().await.unwrap(), 0x0237);
    m.stop().await;
}

#[tokio::test]
async fn identity_reads_0x1018_and_the_segmented_device_name() {
    use calibd_drivers::Identity;
    use calibd_drivers::can::node::{
        MOCK_DEVICE_NAME, MOCK_PRODUCT_CODE, MOCK_REVISION, MOCK_SERIAL, MOCK_VENDOR_ID,
    };
    let (m, h) = start(&[]).await;
    let id = h.identity().await.unwrap();
    assert_eq!(id.node_id, 1);
    assert_eq!(id.device_type, 0x0002_0192);
    assert_eq!(id.vendor_id, MOCK_VENDOR_ID);
    assert_eq!(id.vendor_id, 0x00CA_1BD0);
    assert_eq!(id.product_code, MOCK_PRODUCT_CODE);
    assert_eq!(id.revision_number, MOCK_REVISION);
    assert_eq!(id.serial_number, Some(MOCK_SERIAL));
    // 17 bytes: a segmented upload of three segments.
    assert_eq!(id.device_name.as_deref(), Some(MOCK_DEVICE_NAME));
    assert_eq!(id.device_name.as_deref(), Some("calibd CiA402 sim"));
    assert_eq!(id.statusword, 0x0250);
    assert_eq!(id.power_state, "switch on disabled");
    assert!(id.problems().is_empty());
    assert_eq!(
        id.summary(),
        "node 1 \"calibd CiA402 sim\": vendor 0x00ca1bd0 product 0x00000402 rev 1.3, switch on disabled"
    );
    // The identity objects are read-only; a missing sub-index is an SDO abort.
    assert!(
        h.write(0x1018, 1, &[0, 0, 0, 0])
            .await
            .unwrap_err()
            .is_device_error()
    );
    match h.read(0x1018, 9).await {
        Err(DriverError::Device {
            code: 0x0609_0011, ..
        }) => {}
        other => panic!("{other:?}"),
    }
    // Expedited reads still work after the segmented one.
    assert_eq!(h.statusword().await.unwrap(), 0x0250);
    m.stop().await;
}
