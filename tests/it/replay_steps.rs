//! Replay: a recorded transcript of each device drives one campaign step. Each cell's step
//! runs once against the twins with the lab recording every device's traffic
//! (`Lab::connect_recording`, `calibd-transcript/1`); then each transcript is served by
//! `calibd mock <device> --replay` (in its replay mode, one server per device) and the
//! same step, driven over the recorded bytes alone, measures exactly what it measured live:
//! a centring on a ball (RWS + U-WAVE-R), a 3-PF joint set (MCS2 + microscope), a humanoid
//! posture (joint interface + QTM).
//!
//! The twins are set to answer in a fixed number of exchanges (moves that finish before
//! the first poll, indicators read on request), so a step's exchange does not depend on
//! timing and the recording can be played back byte for byte.

use std::path::Path;
use std::time::Duration;

use calibd::campaigns::engine::{Retry, Step};
use calibd::campaigns::mocap::{Posture, RecordOptions};
use calibd::campaigns::pcr::{PcrOptions, StagesAndScope};
use calibd::campaigns::trical::{Centring, Planned};
use calibd::lab::{CellLink, Lab};
use calibd::procedures::CentringOptions;
use calibd::sim::trical::Served;
use calibd::util::{NoMonitor, Rng};
use calibd_drivers::mock::{MockArgs, MockDevice, RunningMock};
use serde_json::Value;

const SEED: u64 = 7;

fn fast_trical() -> calibd::sim::SimTricalOptions {
    calibd::sim::SimTricalOptions {
        arm_speed_deg_s: 1e7,
        indicator_rate_hz: 0.1,
        uwave_request: "RQ{cc}{gg}".into(),
        ..Default::default()
    }
}

fn fast_pcr() -> calibd::sim::SimPcrOptions {
    calibd::sim::SimPcrOptions {
        stage_speed_mm_s: 1e9,
        ..Default::default()
    }
}

/// One step of each cell on `lab`: the three samples as JSON.
async fn steps(lab: &Lab) -> [Value; 3] {
    // A start 0.2 deg off a true ball-centring configuration of ball 2.
    let twin = calibd::twin::SerialTwin::irb120(SEED);
    let mut rng = Rng::new(11);
    let centre = twin.plate.centres[1].expect("ball 2");
    let q = loop {
        if let Some(q) = twin.reach(&twin.random_q(&mut rng), &centre) {
            break q;
        }
    };
    let q: Vec<f64> = q.iter().map(|v| v + 0.2f64.to_radians()).collect();
    let cell = lab.trical("irb120").expect("trical cell");
    let options = CentringOptions {
        settle: Duration::ZERO,
        ..Default::default()
    };
    let centring = Centring {
        robot: &*cell.robot,
        indicators: &*cell.indicators,
        options: &options,
    };
    let a = centring
        .measure(0, &Planned { q, ball: 1 }, &NoMonitor)
        .await
        .expect("centred");

    let cell = lab.pcr("pcr3pf").expect("pcr cell");
    let options = PcrOptions {
        limits: cell.current_model().limits(),
        settle: Duration::ZERO,
        retry: Retry::default(),
    };
    let step = StagesAndScope {
        stages: &*cell.stages,
        scope: &*cell.microscope,
        options: &options,
    };
    let l = options.limits;
    let q = [
        l[0][0] + 0.3 * (l[0][1] - l[0][0]),
        l[1][0] + 0.5 * (l[1][1] - l[1][0]),
        l[2][0] + 0.6 * (l[2][1] - l[2][0]),
    ];
    let b = step.measure(0, &q, &NoMonitor).await.expect("measured");

    let cell = lab.mocap("talos").expect("mocap cell");
    let options = RecordOptions {
        settle: Duration::from_millis(50),
        window: Duration::from_millis(500),
        preprocess: Default::default(),
    };
    let step = Posture {
        robot: &*cell.robot,
        stream: &*cell.stream,
        options: &options,
    };
    let posture: Vec<(String, f64)> = cell
        .joints
        .iter()
        .zip(&cell.limits)
        .map(|(n, [lo, hi])| (n.clone(), lo + 0.4 * (hi - lo)))
        .collect();
    let c = step
        .measure(0, &posture, &NoMonitor)
        .await
        .expect("recorded");
    let json = |v: Result<Value, serde_json::Error>| v.expect("json");
    [
        json(serde_json::to_value(a)),
        json(serde_json::to_value(b)),
        json(serde_json::to_value(c)),
    ]
}

async fn replay(path: &Path, device: MockDevice) -> RunningMock {
    let mut args = MockArgs::new(device);
    args.replay = Some(path.to_path_buf());
    args.pty = device == MockDevice::Uwave;
    calibd_drivers::mock::start(args)
        .await
        .expect("replay mock")
}

// One thread: the three stage moves of a joint set share one MCS2 connection, and the
// order in which their requests reach it must not depend on thread scheduling, live or
// replayed.
#[tokio::test(flavor = "current_thread")]
async fn a_recorded_transcript_of_each_device_drives_one_campaign_step() {
    let dir = tempfile::tempdir().expect("dir");
    // Live, recording.
    let (tr, mut mocks) = calibd::sim::trical::start_at(
        SEED,
        &fast_trical(),
        &Served {
            rws: "127.0.0.1:0".into(),
            uwave: None,
            user: "Default User".into(),
            password: "robotics".into(),
        },
    )
    .await
    .expect("trical twin");
    let scope_at = calibd::lab::PoseSourceLink::Server("127.0.0.1:0".into());
    let (pc, m) = calibd::sim::pcr::start_at(SEED, &fast_pcr(), "127.0.0.1:0", &scope_at)
        .await
        .expect("pcr twin");
    mocks.extend(m);
    let (mo, m) = calibd::sim::mocap::start_at(
        SEED,
        &calibd::sim::SimMocapOptions {
            rate_hz: 200.0,
            ..Default::default()
        },
        "127.0.0.1:0",
        "127.0.0.1:0",
    )
    .await
    .expect("talos twin");
    mocks.extend(m);
    let links = vec![
        CellLink::BallCentring(tr.clone()),
        CellLink::Pcr(pc.clone()),
        CellLink::Mocap(mo.clone()),
    ];
    let live = Lab::connect_recording(links, Some(dir.path())).expect("lab");
    let recorded = steps(&live).await;
    live.stop().await;
    drop(live);
    for m in mocks {
        m.stop().await;
    }

    // Replayed: each device is a replay server of its own transcript.
    let t = |name: &str| dir.path().join(name);
    let rws = replay(&t("irb120.abb.jsonl"), MockDevice::Abb).await;
    let uwave = replay(&t("irb120.uwave.jsonl"), MockDevice::Uwave).await;
    let mcs2 = replay(&t("pcr3pf.mcs2.jsonl"), MockDevice::Mcs2).await;
    let scope = replay(&t("pcr3pf.microscope.jsonl"), MockDevice::Microscope).await;
    let joints = replay(&t("talos.joints.jsonl"), MockDevice::Joints).await;
    let qtm = replay(&t("talos.qtm.jsonl"), MockDevice::Qtm).await;
    let mut tr = tr;
    tr.rws.address = rws.addr.clone();
    tr.uwave.path = uwave.addr.clone();
    let mut pc = pc;
    pc.stages.backend = calibd::lab::StageBackend::Mcs2(mcs2.addr.clone());
    pc.microscope = calibd::lab::PoseSourceLink::Server(scope.addr.clone());
    let mut mo = mo;
    mo.joints.address = joints.addr.clone();
    mo.qtm = qtm.addr.clone();
    let lab = Lab::connect(vec![
        CellLink::BallCentring(tr),
        CellLink::Pcr(pc),
        CellLink::Mocap(mo),
    ])
    .expect("lab");
    let replayed = steps(&lab).await;
    for (what, (a, b)) in ["centring", "3-PF joint set", "posture"]
        .iter()
        .zip(recorded.iter().zip(&replayed))
    {
        eprintln!("{what}: {a}");
        assert_eq!(a, b, "{what}: replay differs from the live step");
    }
    lab.stop().await;
    for m in [rws, uwave, mcs2, scope, joints, qtm] {
        m.stop().await;
    }
}
