//! Hardware in the loop, with the hardware played by mock processes: `calibd mock lab`
//! serves each cell's devices from the digital twins in a process of its own (RWS on TCP,
//! the U-WAVE receiver on a pseudo-terminal behind the configured port path, MCS2 and the
//! microscope on TCP); a lab file points at them; `calibd serve --config` runs as its own
//! process and is driven over HTTP. Nothing is shared but sockets and serial ports.

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use serde_json::{Value, json};

pub(crate) const BIN: &str = env!("CARGO_BIN_EXE_calibd");
const WAIT: Duration = Duration::from_secs(120);

/// A child process killed on drop, with its stdout lines on a channel.
pub(crate) struct Proc {
    child: Child,
    stdin: Option<ChildStdin>,
    lines: mpsc::Receiver<String>,
}

impl Proc {
    pub(crate) fn spawn(cmd: &mut Command) -> Proc {
        Proc::spawn_with(cmd, false)
    }

    /// [`Proc::spawn`] with the process's log (stderr) on the same channel as its stdout.
    pub(crate) fn spawn_logged(cmd: &mut Command) -> Proc {
        Proc::spawn_with(cmd, true)
    }

    fn spawn_with(cmd: &mut Command, log: bool) -> Proc {
        cmd.stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(if log {
                Stdio::piped()
            } else {
                Stdio::inherit()
            });
        if !cmd.get_envs().any(|(k, _)| k == "RUST_LOG") {
            cmd.env("RUST_LOG", "warn");
        }
        let mut child = cmd.spawn().expect("process starts");
        let out = child.stdout.take().expect("stdout");
        let stdin = child.stdin.take();
        let (tx, lines) = mpsc::channel();
        let forward = |r: Box<dyn std::io::Read + Send>, tx: mpsc::Sender<String>| {
            std::thread::spawn(move || {
                for l in BufReader::new(r).lines() {
                    let Ok(l) = l else { break };
                    if tx.send(l).is_err() {
                        break;
                    }
                }
            });
        };
        if let Some(err) = child.stderr.take() {
            forward(Box::new(err), tx.clone());
        }
        forward(Box::new(out), tx);
        Proc {
            child,
            stdin,
            lines,
        }
    }

    /// Write one line to the process's standard input (the mock lab's operator hands).
    pub(crate) fn send(&mut self, line: &str) {
        let stdin = self.stdin.as_mut().expect("stdin");
        writeln!(stdin, "{line}").expect("write to stdin");
        stdin.flush().expect("flush stdin");
    }

    /// Lines until one starts with `prefix` (that line), or panic after `WAIT`.
    pub(crate) fn until(&self, prefix: &str) -> String {
        self.until_line(prefix, |l| l.starts_with(prefix))
    }

    /// Lines until one contains `part` (that line), or panic after `WAIT`.
    pub(crate) fn until_containing(&self, part: &str) -> String {
        self.until_line(part, |l| l.contains(part))
    }

    fn until_line(&self, what: &str, found: impl Fn(&str) -> bool) -> String {
        let t0 = Instant::now();
        loop {
            let left = WAIT.saturating_sub(t0.elapsed());
            match self.lines.recv_timeout(left) {
                Ok(l) if found(&l) => return l,
                Ok(_) => {}
                Err(e) => panic!("no line with {what:?}: {e}"),
            }
        }
    }

    fn kill(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        self.kill();
    }
}

pub(crate) fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

/// The lab folder: the twins' nominal models, the RWS password file and the lab file.
/// Out-of-process campaigns run one at a time: each starts a daemon and mock processes whose
/// device timeouts are real time, and two of them (or the camera campaign's rendering) at
/// once on a 2-core machine starve each other's drivers into timeouts.
pub(crate) static OUT_OF_PROCESS: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

fn lab_dir(dir: &Path, microscope_port: u16) -> PathBuf {
    let (dh, ballbar) = calibd::sim::trical::twin_cell(7);
    std::fs::write(
        dir.join("irb120.json"),
        serde_json::to_string_pretty(&dh).expect("json"),
    )
    .expect("write");
    let pcr = calibd::sim::pcr::twin_model(7).expect("pcr twin");
    std::fs::write(
        dir.join("pcr3pf.json"),
        serde_json::to_string_pretty(&pcr).expect("json"),
    )
    .expect("write");
    std::fs::write(dir.join("rws-password"), "hil-secret\n").expect("write");
    std::fs::write(dir.join("talos.urdf"), calibd::twin::humanoid::TALOS_URDF).expect("write");
    let (root, joints, markers) = calibd::sim::mocap::twin_cell(7).expect("talos twin");
    let markers: Vec<String> = markers
        .iter()
        .map(|m| {
            format!(
                "{{ name = \"{}\", link = \"{}\", initial_m = [{}, {}, {}] }}",
                m.name, m.link, m.initial.x, m.initial.y, m.initial.z
            )
        })
        .collect();
    let humanoid = format!(
        r#"
[[cell]]
name = "talos"
kind = "humanoid"
model = "talos.urdf"
[cell.mocap]
address = "127.0.0.1:{}"
[cell.joints]
address = "127.0.0.1:{}"
root_link = "{root}"
names = {:?}
speed_rad_s = 2.0
markers = [{}]
"#,
        free_port(),
        free_port(),
        joints,
        markers.join(", ")
    );
    let z = calibd::sim::INDICATOR_ZERO_MM;
    let text = format!(
        r#"
[[cell]]
name = "irb120"
kind = "ball_centring"
model = "irb120.json"
ballbar_mm = {{ d12 = {}, d13 = {}, d23 = {} }}
[cell.controller]
address = "127.0.0.1:{}"
user = "calibd"
password_file = "rws-password"
[cell.indicators]
port = "{}"
axes = [{{ channel = 0, zero_mm = {z} }}, {{ channel = 1, zero_mm = {z} }}, {{ channel = 2, zero_mm = {z} }}]
[cell.envelope]
max_joint_step_deg = 30.0
max_tool_step_mm = 6.5

[[cell]]
name = "pcr3pf"
kind = "pcr"
model = "pcr3pf.json"
[cell.stages]
controller = "mcs2"
address = "127.0.0.1:{}"
channels = [0, 1, 2]
[cell.microscope]
address = "127.0.0.1:{microscope_port}"
[cell.envelope]
max_stage_step_m = 0.05
"#,
        ballbar[0],
        ballbar[1],
        ballbar[2],
        free_port(),
        dir.join("ttyUWAVE").display(),
        free_port(),
    );
    let lab = dir.join("lab.toml");
    std::fs::write(&lab, text + &humanoid).expect("write");
    lab
}

fn mock(lab: &Path, cell: &str) -> Proc {
    let p = Proc::spawn(
        Command::new(BIN)
            .args(["mock", "lab", "--config"])
            .arg(lab)
            .args(["--cell", cell]),
    );
    p.until("mock lab ready");
    p
}

pub(crate) fn lab_check(lab: &Path) -> (bool, String) {
    let out = Command::new(BIN)
        .args(["lab", "check", "--timeout-s", "5", "--config"])
        .arg(lab)
        .env("RUST_BACKTRACE", "0")
        .output()
        .expect("lab check runs");
    (
        out.status.success(),
        format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        ),
    )
}

pub(crate) struct Daemon {
    _proc: Proc,
    url: String,
    token: String,
    http: reqwest::Client,
}

impl Daemon {
    pub(crate) fn start(dir: &Path, lab: &Path) -> Daemon {
        Daemon::start_with(dir, lab, "", &[])
    }

    /// [`Daemon::start`] with more settings lines and `calibd serve` arguments.
    pub(crate) fn start_with(dir: &Path, lab: &Path, settings: &str, args: &[&str]) -> Daemon {
        let data = dir.join("data");
        let cfg = dir.join("calibd.toml");
        std::fs::create_dir_all(dir).expect("daemon folder");
        std::fs::write(
            &cfg,
            format!("workers = 2\nlab = \"{}\"\n{settings}", lab.display()),
        )
        .expect("write");
        let p = Proc::spawn(
            Command::new(BIN)
                .args(["serve", "--listen", "127.0.0.1:0", "--config"])
                .arg(&cfg)
                .arg("--data")
                .arg(&data)
                .args(args),
        );
        let url = p
            .until("calibd listening on ")
            .trim_start_matches("calibd listening on ")
            .to_string();
        let token = std::fs::read_to_string(data.join("operator.token"))
            .expect("operator token")
            .trim()
            .to_string();
        Daemon {
            _proc: p,
            url,
            token,
            http: reqwest::Client::new(),
        }
    }

    pub(crate) async fn get(&self, path: &str) -> Value {
        self.http
            .get(format!("{}{path}", self.url))
            .bearer_auth(&self.token)
            .send()
            .await
            .expect("GET")
            .json()
            .await
            .expect("json")
    }

    pub(crate) async fn post(&self, path: &str, body: &Value) -> (u16, Value) {
        let r = self
            .http
            .post(format!("{}{path}", self.url))
            .bearer_auth(&self.token)
            .json(body)
            .send()
            .await
            .expect("POST");
        let s = r.status().as_u16();
        (s, r.json().await.unwrap_or(Value::Null))
    }

    pub(crate) async fn submit(&self, doc: &Value) -> i64 {
        let (s, r) = self.post("/v1/jobs", doc).await;
        assert_eq!(s, 201, "{r}");
        r["id"].as_i64().expect("id")
    }

    /// The job once its state is one of `states`.
    pub(crate) async fn until_state(&self, id: i64, states: &[&str]) -> Value {
        let t0 = Instant::now();
        loop {
            let j = self.get(&format!("/v1/jobs/{id}")).await;
            if states.iter().any(|s| j["state"] == *s) {
                return j;
            }
            assert!(t0.elapsed() < WAIT * 3, "job {id} stuck: {j}");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    async fn journal(&self, id: i64) -> Vec<Value> {
        self.get(&format!("/v1/jobs/{id}/measurements")).await["entries"]
            .as_array()
            .cloned()
            .unwrap_or_default()
    }

    /// Run `doc` to success: its result and wall time.
    pub(crate) async fn run(&self, doc: &Value) -> (i64, Value, f64) {
        let t0 = Instant::now();
        let id = self.submit(doc).await;
        let j = self
            .until_state(id, &["succeeded", "failed", "paused", "cancelled"])
            .await;
        assert_eq!(j["state"], "succeeded", "{j}");
        let r = self.get(&format!("/v1/jobs/{id}/result")).await;
        (id, r, t0.elapsed().as_secs_f64())
    }
}

/// The campaign of `tests/campaign.rs`, from the nominal model (given, so that the second
/// run plans as the first did although the first made its calibration the cell's model).
fn trical_doc() -> Value {
    let (nominal, _) = calibd::sim::trical::twin_cell(7);
    json!({
        "kind": "cell.trical_campaign",
        "cell": "irb120",
        "model": nominal,
        "design": {"pool_per_ball": 16, "per_ball": 6, "seed": 3},
        "validation": {"per_ball": 2, "seed": 4},
        "options": {
            "centring": {"settle_ms": 40, "reading_timeout_ms": 400},
            "retry": {"attempts": 3, "backoff_ms": 100}
        }
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn campaigns_run_over_mock_processes_and_a_killed_device_pauses_and_resumes() {
    let _one = OUT_OF_PROCESS.lock().await;
    let dir = tempfile::tempdir().expect("temp dir");
    let lab = lab_dir(dir.path(), free_port());
    let trical_mock = mock(&lab, "irb120");
    let _pcr_mock = mock(&lab, "pcr3pf");
    let _talos_mock = mock(&lab, "talos");

    // The preflight against the mock processes: every device answers with its identity.
    let (ok, out) = lab_check(&lab);
    eprintln!("{out}");
    assert!(ok, "{out}");
    for want in [
        "irb120.rws",
        "ABB IRC5",
        "CalibServer loaded",
        "irb120.uwave",
        "3 transmitters",
        "RobotWare 6.",
        "MCS2-sim",
        "pcr3pf.stages",
        "SmarAct MCS2",
        "pcr3pf.microscope",
        "calibd-pose/1",
        "talos.joints",
        "talos.qtm",
    ] {
        assert!(out.contains(want), "{want} missing from\n{out}");
    }

    let d = Daemon::start(dir.path(), &lab);
    let l = d.get("/v1/lab?refresh=true").await;
    let states: Vec<&str> = l["devices"]
        .as_array()
        .expect("devices")
        .iter()
        .map(|r| r["state"].as_str().unwrap_or(""))
        .collect();
    assert_eq!(states, ["ok"; 6], "{l}");
    // The password never leaves the daemon.
    assert!(!l.to_string().contains("hil-secret"));

    // A 3-PF campaign over MCS2 and the microscope, to the twin's noise.
    let (_, r, t) = d
        .run(&json!({
            "kind": "cell.pcr_campaign", "cell": "pcr3pf", "poses": 32, "seed": 1,
            "validation_fraction": 0.25,
        }))
        .await;
    let after = r["validation"]["after"]["mean"].as_f64().expect("mean");
    eprintln!(
        "pcr campaign over processes: {t:.1} s, validation {} -> {after:e} m",
        r["validation"]["before"]["mean"]
    );
    assert!(after > 3e-9 && after < 40e-9, "{}", r["validation"]);

    // A motion-capture campaign over QTM and the joint interface: NOCP postures, recorded,
    // identified to the mocap noise.
    let (_, r, t) = d
        .run(&json!({
            "kind": "cell.mocap_campaign", "cell": "talos",
            "postures": {"nocp": {"constraints": {"collision": false}, "seed": 3,
                                  "options": {"base_pool": 200, "max_postures": 40}}},
            "options": {"settle_s": 0.05, "record_s": 0.5}
        }))
        .await;
    let (before, after) = (
        r["rmse_before_mm"].as_f64().expect("rmse"),
        r["rmse_after_mm"].as_f64().expect("rmse"),
    );
    eprintln!(
        "mocap campaign over processes: {t:.1} s, {} postures, marker rmse {before:.3} -> {after:.3} mm",
        r["campaign"]["recorded"]
    );
    assert!(
        after < 1.0 && before > 10.0 * after,
        "{before} -> {after} mm"
    );

    // A TriCal campaign, uninterrupted: the reference journal.
    let (first, r, t) = d.run(&trical_doc()).await;
    let (before, after) = (
        r["validation"]["before"]["mean"].as_f64().expect("mean"),
        r["validation"]["after"]["mean"].as_f64().expect("mean"),
    );
    eprintln!("trical campaign over processes: {t:.1} s, validation {before} -> {after} mm");
    assert!(after < 0.010 && before > 0.3, "{before} -> {after}");
    // `calibd submit --watch` ends with the cell's decision, read from the job's log.
    let client = calibd::client::Client::new(&d.url, Some(d.token.clone()));
    let decision = calibd::client::commands::cell_decision(&client, first)
        .await
        .unwrap()
        .expect("the campaign's decision");
    assert!(
        decision.starts_with("decision: cell irb120: model accepted"),
        "{decision}"
    );
    let reference = d.journal(first).await;
    assert_eq!(reference.len(), 24);

    // The same campaign; the cell's mock process is killed after a few measurements.
    let mut trical_mock = trical_mock;
    let id = d.submit(&trical_doc()).await;
    let t0 = Instant::now();
    while d.journal(id).await.len() < 5 {
        assert!(t0.elapsed() < WAIT, "no measurement");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    trical_mock.kill();
    let j = d.until_state(id, &["paused", "failed", "succeeded"]).await;
    assert_eq!(j["state"], "paused", "{j}");
    let why = j["error"].as_str().unwrap_or_default().to_string();
    eprintln!("paused: {why}");
    assert!(
        why.contains("irb120.rws at 127.0.0.1:") || why.contains("irb120.uwave at "),
        "{why}"
    );
    // The daemon's lab check names the cell unavailable, and a new campaign is refused.
    let t0 = Instant::now();
    loop {
        let l = d.get("/v1/lab?refresh=true").await;
        let cell = &l["cells"][0];
        if cell["available"] == false {
            assert!(
                cell["reason"].as_str().unwrap_or("").contains("irb120."),
                "{l}"
            );
            break;
        }
        assert!(t0.elapsed() < WAIT, "{l}");
    }
    let (s, e) = d.post("/v1/jobs", &trical_doc()).await;
    assert_eq!(s, 409, "{e}");
    assert!(e.to_string().contains("unavailable"), "{e}");

    // The device comes back; the campaign resumes and ends with the uninterrupted journal.
    let _trical_mock = mock(&lab, "irb120");
    let (s, r) = d.post(&format!("/v1/jobs/{id}/resume"), &json!({})).await;
    assert_eq!(s, 200, "{r}");
    let j = d.until_state(id, &["succeeded", "failed", "paused"]).await;
    assert_eq!(j["state"], "succeeded", "{j}");
    let resumed = d.journal(id).await;
    let strip = |e: &[Value]| -> Vec<Value> {
        e.iter()
            .map(|x| json!({"index": x["index"], "status": x["status"], "data": x["data"]}))
            .collect()
    };
    assert_eq!(strip(&resumed), strip(&reference));
}

#[test]
fn lab_check_fails_clearly_where_nothing_listens() {
    let dir = tempfile::tempdir().expect("temp dir");
    // Nothing serves this lab's devices (the serial port exists but is a plain file).
    let lab = lab_dir(dir.path(), free_port());
    std::fs::write(dir.path().join("ttyUWAVE"), "").expect("write");
    let (ok, out) = lab_check(&lab);
    eprintln!("{out}");
    assert!(!ok);
    assert!(out.contains("FAILED"), "{out}");
    assert!(out.contains("nothing listens at 127.0.0.1:"), "{out}");
    assert!(out.contains("devices failed the check"), "{out}");
    // The example lab file names an absent secret: refused with the file and line.
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/lab.example.toml");
    let (ok, out) = lab_check(&example);
    assert!(!ok);
    assert!(
        out.contains("lab.example.toml:28") && out.contains("/etc/calibd/secrets/rws-password"),
        "{out}"
    );
}

/// Commissioning over the mock processes: `cell.identify_tcp` waits for the operator, who
/// jogs the robot (`cell.jog` over RWS) near the ball, sees the live indicator readings and
/// continues; with the nominal geometry of the lab file the TCP is recovered to the
/// kinematic model error (about a millimetre) and the spread improves.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn commissioning_the_tcp_over_mock_processes() {
    let _one = OUT_OF_PROCESS.lock().await;
    let dir = tempfile::tempdir().expect("temp dir");
    let lab = lab_dir(dir.path(), free_port());
    let _trical_mock = mock(&lab, "irb120");
    let d = Daemon::start(dir.path(), &lab);
    let twin = calibd::twin::SerialTwin::irb120(7);
    let ball = twin.plate.centres[0].expect("ball 1");
    let mut rng = calibd::util::Rng::new(2);
    let mut qs: Vec<Vec<f64>> = Vec::new();
    while qs.len() < 4 {
        let q0 = twin.random_q(&mut rng);
        let off = nalgebra::Vector3::from(rng.in_ball(1.0)).normalize() * 2.0;
        if let Some(q) = twin.reach(&q0, &(ball + off)) {
            let r = twin.truth.tcp(&q, None);
            if qs
                .iter()
                .all(|p| twin.truth.tcp(p, None).angle_to(&r).to_degrees() > 35.0)
            {
                qs.push(q);
            }
        }
    }
    let id = d
        .submit(&json!({"kind": "cell.identify_tcp", "cell": "irb120",
                        "options": {"centring": {"settle_ms": 40, "reading_timeout_ms": 400}}}))
        .await;
    for (k, q) in qs.iter().enumerate() {
        let j = d.until_state(id, &["paused", "failed", "succeeded"]).await;
        let why = j["error"].as_str().unwrap_or_default();
        assert!(
            why.starts_with("waiting for the operator: configuration"),
            "{j}"
        );
        let q_deg: Vec<f64> = q.iter().map(|v| v.to_degrees()).collect();
        d.run(&json!({"kind": "cell.jog", "cell": "irb120", "q_deg": q_deg}))
            .await;
        let live = d.get("/v1/cells/irb120/indicators").await;
        let r = &live["reading_mm"];
        let n = (0..3)
            .map(|i| r[i].as_f64().unwrap_or(f64::NAN).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!((n - 2.0).abs() < 0.2, "configuration {}: {live}", k + 1);
        let (s, r) = d.post(&format!("/v1/jobs/{id}/resume"), &json!({})).await;
        assert_eq!(s, 200, "{r}");
    }
    let j = d.until_state(id, &["succeeded", "failed"]).await;
    assert_eq!(j["state"], "succeeded", "{j}");
    let r = d.get(&format!("/v1/jobs/{id}/result")).await;
    let t: Vec<f64> = (0..3)
        .map(|i| r["tcp_mm"][i].as_f64().unwrap_or(f64::NAN))
        .collect();
    let err = ((t[0] - twin.truth.tool[0]).powi(2)
        + (t[1] - twin.truth.tool[1]).powi(2)
        + (t[2] - twin.truth.tool[2]).powi(2))
    .sqrt();
    eprintln!(
        "TCP over processes (nominal geometry): {t:?}, {err:.3} mm from the truth; spread {} -> {} mm",
        r["previous_spread_rms_mm"], r["spread_rms_mm"]
    );
    assert!(err < 3.0, "{r}");
}

mod absent;
mod auto_resume;
mod mock_process;
mod record;
