use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::*;
use crate::lab::StageBackend;

/// A folder with the files a lab file names: the three models, a password file and a
/// stand-in for the receiver's serial port.
struct Fixture {
    dir: tempfile::TempDir,
}

impl Fixture {
    fn new() -> Fixture {
        let dir = tempfile::tempdir().expect("temp dir");
        let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/robots");
        for (from, to) in [
            ("irb120.json", "irb120.json"),
            ("pcr3pf.json", "pcr3pf.json"),
            ("talos/talos_reduced.urdf", "talos.urdf"),
        ] {
            std::fs::copy(data.join(from), dir.path().join(to)).expect("copy model");
        }
        std::fs::write(dir.path().join("rws-password"), "s3cret-rws\n").expect("secret");
        std::fs::write(dir.path().join("ttyUWAVE"), "").expect("port stand-in");
        Fixture { dir }
    }

    fn path(&self) -> PathBuf {
        self.dir.path().join("lab.toml")
    }

    fn parse(&self, text: &str) -> Result<Vec<CellLink>, LabConfigError> {
        let env: BTreeMap<String, String> = [("QTM_PW".to_string(), "unused".to_string())].into();
        let text = text.replace("@DIR@", &self.dir.path().display().to_string());
        parse(&text, &self.path(), &env)
    }
}

const TRICAL: &str = r#"
[[cell]]
name = "irb120"
kind = "ball_centring"
model = "irb120.json"
ballbar_mm = { d12 = 200.0, d13 = 210.0, d23 = 220.0 }

[cell.controller]
address = "192.168.125.1:80"
password_file = "rws-password"

[cell.indicators]
port = "@DIR@/ttyUWAVE"
axes = [
  { channel = 0, zero_mm = 6.0, range_mm = [0.0, 12.7] },
  { channel = 1, sign = -1, zero_mm = 6.1 },
  { channel = 2, zero_mm = 6.2 },
]

[cell.envelope]
max_tool_step_mm = 1.5
workspace_mm = { min = [100.0, -400.0, 0.0], max = [600.0, 400.0, 700.0] }
"#;

const PCR: &str = r#"
[[cell]]
name = "pcr3pf"
kind = "pcr"
model = "pcr3pf.json"
[cell.stages]
controller = "cia402"
address = "127.0.0.1:29536"
channels = [3, 4, 5]
[cell.microscope]
address = "127.0.0.1:5050"
"#;

const HUMANOID: &str = r#"
[[cell]]
name = "talos"
kind = "humanoid"
model = "talos.urdf"
[cell.mocap]
address = "127.0.0.1:22223"
labels = { "LH1" = "w1" }
[cell.joints]
address = "127.0.0.1:7070"
root_link = "base_link"
names = ["torso_1_joint", "arm_left_1_joint"]
markers = [{ name = "w1", link = "arm_left_7_link", initial_m = [0.0, 0.05, -0.1] }]
[cell.envelope]
joint_limits_deg = [[-10, 10], [-400, 400]]
"#;

#[test]
fn a_lab_of_three_cells_reads_into_their_descriptions() {
    let f = Fixture::new();
    let cells = f
        .parse(&format!("{TRICAL}{PCR}{HUMANOID}"))
        .expect("valid lab");
    assert_eq!(cells.len(), 3);
    let CellLink::BallCentring(t) = &cells[0] else {
        panic!("not a ball-centring cell: {:?}", cells[0]);
    };
    assert_eq!(t.name, "irb120");
    assert_eq!(t.rws.address, "192.168.125.1:80");
    assert_eq!(t.rws.user, "Default User");
    // The password file's line, without its newline.
    assert_eq!(t.rws.password, "s3cret-rws");
    assert_eq!(t.rws.module, "CalibServer");
    assert_eq!(t.ballbar, [200.0, 210.0, 220.0]);
    assert_eq!(t.uwave.baud, 57_600);
    assert_eq!(t.uwave.axes[1].sign, -1.0);
    assert_eq!(t.uwave.axes[2].zero_mm, 6.2);
    assert_eq!(t.max_tool_step_mm, 1.5);
    assert_eq!(t.max_joint_step_deg, 10.0);
    assert_eq!(
        t.workspace_mm,
        Some([[100.0, -400.0, 0.0], [600.0, 400.0, 700.0]])
    );
    let CellLink::Pcr(p) = &cells[1] else {
        panic!("not a 3-PF cell");
    };
    assert_eq!(
        p.stages.backend,
        StageBackend::Socketcand {
            address: "127.0.0.1:29536".into(),
            bus: "can0".into()
        }
    );
    assert_eq!(p.stages.channels, [3, 4, 5]);
    let CellLink::Mocap(m) = &cells[2] else {
        panic!("not a humanoid cell");
    };
    assert_eq!(m.joints.address, "127.0.0.1:7070");
    assert_eq!(m.labels.get("LH1").map(String::as_str), Some("w1"));
    // The envelope narrows the URDF's limits: torso_1 to +-10 deg; arm_left_1 keeps the
    // URDF's own limits (the configured +-400 deg is wider).
    assert!((m.limits[0][0] + 10f64.to_radians()).abs() < 1e-12);
    assert!((m.limits[0][1] - 10f64.to_radians()).abs() < 1e-12);
    assert!(m.limits[1][1] < 400f64.to_radians() && m.limits[1][1] > 0.5);
    assert_eq!(m.markers[0].initial.z, -0.1);
}

#[test]
fn an_unknown_key_is_refused_with_its_line_and_name() {
    let f = Fixture::new();
    let text = TRICAL.replace("max_tool_step_mm = 1.5", "max_tool_stepmm = 1.5");
    let e = f.parse(&text).unwrap_err();
    let line = text
        .lines()
        .position(|l| l.contains("max_tool_stepmm"))
        .expect("line")
        + 1;
    assert_eq!(e.line, line, "{e}");
    assert!(e.message.contains("max_tool_stepmm"), "{e}");
    assert!(
        e.to_string().starts_with(&f.path().display().to_string()),
        "{e}"
    );
}

#[test]
fn an_inline_password_is_refused_and_never_echoed() {
    let f = Fixture::new();
    let text = TRICAL.replace(
        "password_file = \"rws-password\"",
        "password = \"hunter2-inline\"",
    );
    let e = f.parse(&text).unwrap_err();
    assert!(e.message.contains("password_file"), "{e}");
    assert!(!e.to_string().contains("hunter2"), "{e}");
    let line = text
        .lines()
        .position(|l| l.contains("hunter2"))
        .expect("line")
        + 1;
    assert_eq!(e.line, line);
}

#[test]
fn secrets_come_from_the_environment_or_are_named_missing() {
    let f = Fixture::new();
    let text = TRICAL.replace(
        "password_file = \"rws-password\"",
        "password_env = \"CALIBD_TEST_RWS_PW\"",
    );
    let e = f.parse(&text).unwrap_err();
    assert!(
        e.message.contains("CALIBD_TEST_RWS_PW") && e.message.contains("not set"),
        "{e}"
    );
    let env: BTreeMap<String, String> =
        [("CALIBD_TEST_RWS_PW".to_string(), "from-env".to_string())].into();
    let text = text.replace("@DIR@", &f.dir.path().display().to_string());
    let cells = parse(&text, &f.path(), &env).expect("valid");
    let CellLink::BallCentring(t) = &cells[0] else {
        panic!("kind");
    };
    assert_eq!(t.rws.password, "from-env");
}

#[test]
fn a_password_file_can_be_a_systemd_credential() {
    let f = Fixture::new();
    let text = TRICAL
        .replace(
            "password_file = \"rws-password\"",
            "password_file = \"${CREDENTIALS_DIRECTORY}/rws\"",
        )
        .replace("@DIR@", &f.dir.path().display().to_string());
    let creds = tempfile::tempdir().expect("dir");
    std::fs::write(creds.path().join("rws"), "from-credential").expect("write");
    let env: BTreeMap<String, String> = [(
        "CREDENTIALS_DIRECTORY".to_string(),
        creds.path().display().to_string(),
    )]
    .into();
    let cells = parse(&text, &f.path(), &env).expect("valid");
    let CellLink::BallCentring(t) = &cells[0] else {
        panic!("kind");
    };
    assert_eq!(t.rws.password, "from-credential");
    let e = parse(&text, &f.path(), &BTreeMap::new()).unwrap_err();
    assert!(e.message.contains("LoadCredential"), "{e}");
}

#[test]
fn a_missing_device_section_and_model_are_named_but_an_absent_port_is_no_file_error() {
    let f = Fixture::new();
    // An unplugged receiver is the lab's state, not the file's: the cell reads, and the
    // lab marks it unavailable when it connects (tests/it/hil.rs).
    let cells = f
        .parse(&TRICAL.replace("@DIR@/ttyUWAVE", "/dev/ttyCALIBD-NOT-THERE"))
        .expect("an absent port is no file error");
    let [CellLink::BallCentring(t)] = cells.as_slice() else {
        panic!("one ball-centring cell: {cells:?}");
    };
    assert_eq!(t.uwave.path, "/dev/ttyCALIBD-NOT-THERE");
    let e = f
        .parse(&PCR.replace("[cell.microscope]\naddress = \"127.0.0.1:5050\"\n", ""))
        .unwrap_err();
    assert!(e.message.contains("[cell.microscope]"), "{e}");
    let e = f
        .parse(&PCR.replace("pcr3pf.json", "nope.json"))
        .unwrap_err();
    assert!(e.message.contains("nope.json"), "{e}");
    assert_eq!(e.line, 5, "{e}");
    let e = f
        .parse(&PCR.replace("127.0.0.1:5050", "127.0.0.1"))
        .unwrap_err();
    assert!(
        e.message.contains("microscope.address") && e.message.contains("host:port"),
        "{e}"
    );
}

#[test]
fn a_section_of_another_kind_and_a_second_cell_of_the_same_name_are_refused() {
    let f = Fixture::new();
    let e = f
        .parse(&format!(
            "{PCR}[cell.indicators]\nport = \"x\"\naxes = []\n"
        ))
        .unwrap_err();
    assert!(
        e.message.contains("[cell.indicators] does not belong"),
        "{e}"
    );
    let e = f.parse(&format!("{PCR}{PCR}")).unwrap_err();
    assert!(e.message.contains("already described at line 3"), "{e}");
    let e = f.parse("").unwrap_err();
    assert!(e.message.contains("[[cell]]"), "{e}");
}

#[test]
fn the_example_lab_file_parses_up_to_its_absent_secret() {
    // deploy/lab.example.toml finds its models beside it (deploy/models/); on a machine
    // without the RWS password file it names, that is the first thing missing, with its line.
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/lab.example.toml");
    let e = load(&path, &ProcessEnv).unwrap_err();
    assert!(
        e.message.contains("/etc/calibd/secrets/rws-password"),
        "{e}"
    );
    assert_eq!(e.line, 28, "{e}");
}

#[test]
fn the_example_lab_file_describes_three_cells_once_its_files_exist() {
    let f = Fixture::new();
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/lab.example.toml");
    let text = std::fs::read_to_string(path).expect("example");
    let text = text
        .replace("models/irb120.json", "irb120.json")
        .replace("models/pcr3pf.json", "pcr3pf.json")
        .replace("models/talos_reduced.urdf", "talos.urdf")
        .replace("/etc/calibd/secrets/rws-password", "rws-password")
        .replace(
            "/dev/serial/by-id/usb-Mitutoyo_U-WAVE-R-if00-port0",
            "@DIR@/ttyUWAVE",
        );
    let cells = f.parse(&text).expect("the example is valid");
    let kinds: Vec<&str> = cells
        .iter()
        .map(|c| match c {
            CellLink::BallCentring(_) => "ball_centring",
            CellLink::Pcr(_) => "pcr",
            CellLink::Mocap(_) => "humanoid",
        })
        .collect();
    assert_eq!(kinds, ["ball_centring", "pcr", "humanoid"]);
}

#[test]
fn a_camera_instead_of_the_pose_server_reads_with_its_settings_and_is_checked() {
    let f = Fixture::new();
    let camera = r#"[cell.camera]
source = "folder"
folder = "frames"
exposure_us = 800.0
frame_rate_hz = 50.0
pixel_um = 1.25
period_um = 10.0
"#;
    let server = "[cell.microscope]\naddress = \"127.0.0.1:5050\"\n";
    let cells = f
        .parse(&PCR.replace(server, camera))
        .expect("a camera cell");
    let [CellLink::Pcr(p)] = cells.as_slice() else {
        panic!("one pcr cell: {cells:?}");
    };
    let PoseSourceLink::Camera(c) = &p.microscope else {
        panic!("a camera: {:?}", p.microscope);
    };
    // The folder is relative to the lab file; the pattern defaults to the encoded one.
    assert_eq!(
        c.source,
        FrameSourceLink::Folder(f.dir.path().join("frames"))
    );
    assert_eq!((c.exposure_us, c.frame_rate_hz), (800.0, 50.0));
    assert_eq!(
        c.pattern.kind,
        crate::measure::pattern::PatternKind::Encoded
    );
    assert_eq!((c.pattern.pixel_um, c.pattern.period_um), (1.25, 10.0));
    let e = f
        .parse(&PCR.replace(server, &format!("{server}{camera}")))
        .unwrap_err();
    assert!(e.message.contains("not both"), "{e}");
    let e = f
        .parse(&PCR.replace(
            server,
            &camera.replace("folder = \"frames\"", "address = \"h:1\""),
        ))
        .unwrap_err();
    assert!(
        e.message.contains("source = \"folder\" needs folder"),
        "{e}"
    );
    let e = f
        .parse(&PCR.replace(server, &camera.replace("pixel_um = 1.25", "pixel_um = 0")))
        .unwrap_err();
    assert!(e.message.contains("camera.pixel_um"), "{e}");
    let e = f
        .parse(&TRICAL.replace("[cell.indicators]", &format!("{camera}[cell.indicators]")))
        .unwrap_err();
    assert!(
        e.message.contains("[cell.camera]") && e.message.contains("does not belong"),
        "{e}"
    );
}
