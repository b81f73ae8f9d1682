//! The 3-PF cell measuring for itself: `calibd mock lab` serves the twin's MCS2 stages and a
//! camera (`calibd-frames/1`) rendering the encoded pattern at the platform's pose with 1 %
//! image noise, in a process of its own; calibd computes every pose from the frames (phase
//! method, code bias removed) and runs `cell.pcr_campaign` over the sockets. The same twin
//! (same seed, same lab file's model) behind the `calibd-pose/1` server gives the reference:
//! the campaign from images must identify the robot as well as the one from the server.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::time::{Duration, Instant};

use calibd::jobs::{NoReferences, prepare};
use calibd::lab::Lab;
use calibd::procedures::{Journal, MemoryJournal};
use calibd::util::NoMonitor;
use serde_json::{Value, json};

use crate::hil::{BIN, Proc, free_port};

const SEED: u64 = 7;

/// A lab folder with the twin's model and one 3-PF cell whose microscope is `scope` (a
/// TOML section); the stages on a free port.
fn lab(dir: &Path, scope: &str) -> PathBuf {
    let model = calibd::sim::pcr::twin_model(SEED).expect("pcr twin");
    std::fs::write(
        dir.join("pcr3pf.json"),
        serde_json::to_string_pretty(&model).expect("json"),
    )
    .expect("write");
    let text = format!(
        r#"
[[cell]]
name = "pcr3pf"
kind = "pcr"
model = "pcr3pf.json"
[cell.stages]
controller = "mcs2"
address = "127.0.0.1:{}"
channels = [0, 1, 2]
{scope}
[cell.envelope]
max_stage_step_m = 0.05
"#,
        free_port()
    );
    let path = dir.join("lab.toml");
    std::fs::write(&path, text).expect("write");
    path
}

fn camera_section(port: u16) -> String {
    format!(
        r#"[cell.camera]
source = "network"
address = "127.0.0.1:{port}"
exposure_us = 800.0
frame_rate_hz = 50.0
pixel_um = 1.25
pattern = "encoded"
period_um = 10.0"#
    )
}

/// The campaign on the lab file `path` served by a mock lab process: its result and wall
/// time (s).
fn campaign(path: &Path, doc: &Value) -> (Value, f64) {
    let mock = Proc::spawn(
        Command::new(BIN)
            .args(["mock", "lab", "--seed", &SEED.to_string(), "--config"])
            .arg(path),
    );
    mock.until("mock lab ready");
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    let cells =
        calibd::lab::config::load(path, &calibd::lab::config::ProcessEnv).expect("lab file");
    let lab = {
        let _g = rt.enter();
        Arc::new(Lab::connect(cells).expect("lab"))
    };
    let job = prepare(doc, &NoReferences).expect("valid job");
    assert_eq!(job.devices(), vec!["pcr3pf.stages", "pcr3pf.microscope"]);
    let journal: Arc<dyn Journal> = Arc::new(MemoryJournal::default());
    let t0 = Instant::now();
    let r = calibd::offline::run_on(rt.handle(), &job, lab.clone(), journal, &NoMonitor)
        .map(|c| c.result)
        .expect("campaign");
    let wall = t0.elapsed().as_secs_f64();
    rt.block_on(lab.stop());
    drop(mock);
    (r, wall)
}

fn num(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

#[test]
fn the_campaign_from_rendered_images_identifies_as_well_as_from_the_pose_server() {
    let _one = crate::hil::OUT_OF_PROCESS.blocking_lock();
    let doc = json!({
        "kind": "cell.pcr_campaign", "cell": "pcr3pf", "poses": 48, "seed": 1,
        "validation_fraction": 0.25, "options": {"settle_ms": 0},
    });
    let dir = tempfile::tempdir().expect("dir");
    let server_dir = dir.path().join("server");
    let camera_dir = dir.path().join("camera");
    std::fs::create_dir_all(&server_dir).expect("dir");
    std::fs::create_dir_all(&camera_dir).expect("dir");
    let server_lab = lab(
        &server_dir,
        &format!("[cell.microscope]\naddress = \"127.0.0.1:{}\"", free_port()),
    );
    let camera_lab = lab(&camera_dir, &camera_section(free_port()));
    let (server, t_server) = campaign(&server_lab, &doc);
    let (camera, t_camera) = campaign(&camera_lab, &doc);
    let fig = |r: &Value| {
        (
            num(&r["validation"]["before"]["mean"]),
            num(&r["validation"]["after"]["mean"]),
            num(&r["validation"]["after"]["max"]),
            num(&r["residual_std"]["value"]),
        )
    };
    let (s, c) = (fig(&server), fig(&camera));
    eprintln!(
        "pose server: validation mean {:.2} um nominal -> {:.2} nm identified (max {:.2} nm), residual std {:.2} nm, {t_server:.1} s",
        s.0 * 1e6,
        s.1 * 1e9,
        s.2 * 1e9,
        s.3 * 1e9
    );
    eprintln!(
        "camera:      validation mean {:.2} um nominal -> {:.2} nm identified (max {:.2} nm), residual std {:.2} nm, {t_camera:.1} s",
        c.0 * 1e6,
        c.1 * 1e9,
        c.2 * 1e9,
        c.3 * 1e9
    );
    assert_eq!(camera["campaign"]["calibration"], 36);
    assert_eq!(camera["campaign"]["validation"], 12);
    // Same twin, same joint sets: the nominal model is as far off in both.
    assert!(
        c.0 > 1e-6 && (c.0 / s.0 - 1.0).abs() < 0.05,
        "{c:?} vs {s:?}"
    );
    // Held-out readings predicted at the twin's noise (9.13 nm per coordinate), and the
    // images add little to it.
    assert!(s.1 < 30e-9, "pose server: {s:?}");
    assert!(c.1 < 30e-9, "camera: {c:?}");
    assert!(
        c.1 < 1.25 * s.1,
        "camera {:.2} nm vs pose server {:.2} nm",
        c.1 * 1e9,
        s.1 * 1e9
    );
    eprintln!(
        "verdicts: pose server {} {}, camera {} {}",
        server["verdict"], server["reasons"], camera["verdict"], camera["reasons"]
    );
}

/// Frames per second the mock camera serves over its socket, and poses per second calibd
/// computes from them (printed for the report; not a timed assertion).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frames_are_served_and_measured_at_a_printed_rate() {
    let _one = crate::hil::OUT_OF_PROCESS.lock().await;
    use calibd_drivers::camera::{CameraConfig, CameraHandle, FrameSource};
    let dir = tempfile::tempdir().expect("dir");
    let port = free_port();
    let path = lab(dir.path(), &camera_section(port));
    let mock = Proc::spawn(
        Command::new(BIN)
            .args(["mock", "lab", "--seed", &SEED.to_string(), "--config"])
            .arg(&path),
    );
    mock.until("mock lab ready");
    let h = CameraHandle::connect(
        calibd_drivers::TcpConnector::new(format!("127.0.0.1:{port}")),
        CameraConfig {
            timeout: Duration::from_secs(5),
            exposure_us: 800.0,
            frame_rate_hz: 50.0,
            ..CameraConfig::default()
        },
    );
    let n = 10;
    let t0 = Instant::now();
    let mut frames = Vec::new();
    for _ in 0..n {
        frames.push(h.grab().await.expect("frame"));
    }
    let grab_s = t0.elapsed().as_secs_f64();
    let mut reader =
        calibd::measure::pattern::PoseReader::new(calibd::measure::pattern::PatternSetup {
            kind: calibd::measure::pattern::PatternKind::Encoded,
            period_um: 10.0,
            pixel_um: 1.25,
        })
        .expect("reader");
    let t0 = Instant::now();
    let mut poses = Vec::new();
    for f in frames {
        let img = calibd::lab::adapters::camera::to_image(f).expect("image");
        assert_eq!((img.width, img.height, img.full_scale), (1024, 1024, 65535));
        poses.push(reader.read(&img).expect("pose"));
    }
    let pose_s = t0.elapsed().as_secs_f64();
    eprintln!(
        "mock camera 1024 x 1024 x 16 bit: {:.1} frames/s served; poses computed at {:.1} /s",
        n as f64 / grab_s,
        n as f64 / pose_s
    );
    // The stages never moved: every frame shows the platform at home, within the twin's
    // repeatability (9.13 nm per coordinate) and the image noise.
    for p in &poses[1..] {
        let d = (p.x - poses[0].x).hypot(p.y - poses[0].y);
        assert!(d < 0.1, "{p:?} vs {:?}: {d} um", poses[0]);
    }
    drop(mock);
}
