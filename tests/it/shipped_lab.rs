//! The first real run, as shipped: `deploy/lab.example.toml` with the models beside it,
//! served by `calibd mock lab` (twins built around the file's nominal values), a daemon
//! pointed at the same file, and the three example campaigns of `examples/` submitted
//! unchanged. The only edits to the lab file are the ones a rehearsal needs: device
//! addresses moved to loopback ports, the serial port and the password file to a scratch
//! folder, and the humanoid's planned joint speed raised tenfold (0.3 -> 3 rad/s: the mock
//! plays every move in real time, and the 20 postures then take seconds, not three
//! minutes).

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

use crate::hil::{BIN, Daemon, Proc, free_port, lab_check};

pub(crate) fn repo(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

/// The example lab in `dir`: every `address = "host:port"` on a free loopback port, the
/// U-WAVE port and the RWS password file in `dir`, the humanoid's moves planned at 3 rad/s,
/// the models copied beside it.
pub(crate) fn scratch_lab(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(repo("deploy/lab.example.toml")).expect("example lab");
    let mut out = String::new();
    for line in text.lines() {
        let moved = if let Some(rest) = line.strip_prefix("address = \"") {
            let end = rest.find('"').expect("closing quote");
            format!(
                "address = \"127.0.0.1:{}\"{}",
                free_port(),
                &rest[end + 1..]
            )
        } else if line.starts_with("port = \"/dev/") {
            format!("port = \"{}\"", dir.join("ttyUWAVE").display())
        } else if line.starts_with("password_file = ") {
            "password_file = \"rws-password\"".to_string()
        } else if let Some(rest) = line.strip_prefix("speed_rad_s = 0.3 ") {
            format!("speed_rad_s = 3.0 {rest}")
        } else {
            line.to_string()
        };
        out.push_str(&moved);
        out.push('\n');
    }
    assert!(
        out.contains("speed_rad_s = 3.0"),
        "the example lab's humanoid joints no longer say `speed_rad_s = 0.3`"
    );
    std::fs::create_dir_all(dir.join("models")).expect("models dir");
    for f in ["irb120.json", "pcr3pf.json", "talos_reduced.urdf"] {
        std::fs::copy(
            repo(&format!("deploy/models/{f}")),
            dir.join("models").join(f),
        )
        .expect("copy model");
    }
    std::fs::write(dir.join("rws-password"), "rehearsal\n").expect("password");
    let lab = dir.join("lab.toml");
    std::fs::write(&lab, out).expect("lab file");
    lab
}

pub(crate) fn example(name: &str) -> Value {
    let text = std::fs::read_to_string(repo(&format!("examples/{name}"))).expect("example");
    serde_json::from_str(&text).expect("example JSON")
}

#[test]
fn the_shipped_models_are_the_tested_ones() {
    for (shipped, tested) in [
        ("deploy/models/irb120.json", "tests/data/robots/irb120.json"),
        ("deploy/models/pcr3pf.json", "tests/data/robots/pcr3pf.json"),
        (
            "deploy/models/talos_reduced.urdf",
            "tests/data/robots/talos/talos_reduced.urdf",
        ),
    ] {
        let a = std::fs::read(repo(shipped)).expect("shipped model");
        let b = std::fs::read(repo(tested)).expect("tested model");
        assert!(a == b, "{shipped} differs from {tested}");
    }
}

/// Mean distance (mm) between the TCP of `model` and the TriCal twin's true TCP (with its
/// deflection) over `n` seeded random configurations: an expectation the campaign cannot
/// see, since the truth lives in the mock process.
fn error_against_truth(twin: &calibd::twin::SerialTwin, model: &calibd::model::Chain) -> f64 {
    let mut rng = calibd::util::Rng::new(99);
    let n = 50;
    (0..n)
        .map(|_| {
            let q = twin.random_q(&mut rng);
            let tau = model.static_torques(&q);
            (model.tcp(&q, Some(&tau)).p - twin.true_tcp(&q)).norm()
        })
        .sum::<f64>()
        / n as f64
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_example_campaigns_run_unchanged_on_the_example_lab() {
    let _one = crate::hil::OUT_OF_PROCESS.lock().await;
    const SEED: u64 = 11;
    let dir = tempfile::tempdir().expect("temp dir");
    let lab = scratch_lab(dir.path());
    let mock = Proc::spawn(
        Command::new(BIN)
            .args(["mock", "lab", "--seed", &SEED.to_string(), "--config"])
            .arg(&lab),
    );
    mock.until("mock lab ready");
    let (ok, out) = lab_check(&lab);
    assert!(ok, "lab check on the example lab: {out}");
    assert!(
        !out.contains("SIMULATED LAB"),
        "a lab file's devices: {out}"
    );

    let daemon = Daemon::start(dir.path(), &lab);
    let l = daemon.get("/v1/lab").await;
    assert_eq!(
        l["simulated"], false,
        "a lab file's devices, no banner: {l}"
    );
    for (file, cell) in [
        ("trical_campaign.json", "irb120"),
        ("pcr_campaign.json", "pcr3pf"),
        ("mocap_campaign.json", "talos"),
    ] {
        let doc = example(file);
        assert_eq!(doc["cell"], cell, "{file}");
        let (id, result, wall_s) = daemon.run(&doc).await;
        eprintln!("{file}: job {id} succeeded in {wall_s:.1} s");
        // Each campaign identified its cell and the verdict says to use the model.
        assert_eq!(result["verdict"], "accepted", "{file}: {result}");
        if cell == "irb120" {
            // The twin the mock lab built around the lab file's nominal and ballbar: the
            // calibrated model is far closer to its truth than the shipped nominal.
            let text = std::fs::read_to_string(repo("deploy/models/irb120.json")).expect("model");
            let nominal = calibd::model::dh::DhFile::parse(&text).expect("nominal");
            let twin = calibd::twin::SerialTwin::around(nominal, [200.0; 3], SEED).expect("twin");
            let calibrated =
                calibd::model::dh::DhFile::parse(&result["calibrated_model"].to_string())
                    .and_then(|f| f.to_chain())
                    .expect("calibrated model");
            let before = error_against_truth(&twin, &twin.nominal);
            let after = error_against_truth(&twin, &calibrated);
            eprintln!(
                "irb120 TCP error against the twin's truth: nominal {before:.3} mm, calibrated {after:.4} mm"
            );
            assert!(before > 0.5, "nominal {before} mm");
            assert!(after < 0.05, "calibrated {after} mm (nominal {before} mm)");
        }
    }
    drop(mock);
}

#[test]
fn the_daemon_refuses_to_start_without_its_lab_file_and_says_where_the_example_is() {
    let dir = tempfile::tempdir().expect("temp dir");
    let cfg = dir.path().join("calibd.toml");
    let missing = dir.path().join("lab.toml");
    std::fs::write(&cfg, format!("lab = \"{}\"\n", missing.display())).expect("write");
    let out = Command::new(BIN)
        .args(["serve", "--listen", "127.0.0.1:0", "--config"])
        .arg(&cfg)
        .arg("--data")
        .arg(dir.path().join("data"))
        .env("RUST_LOG", "warn")
        .output()
        .expect("calibd serve runs");
    assert!(!out.status.success(), "started without its lab file");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains(&format!("{} does not exist", missing.display()))
            && err.contains("lab.example.toml")
            && err.contains("lab = \"sim\""),
        "{err}"
    );
}

#[test]
fn lab_check_of_the_simulated_lab_says_so_first() {
    let out = Command::new(BIN)
        .args(["lab", "check", "--timeout-s", "10", "--config", "sim"])
        .env("RUST_LOG", "warn")
        .output()
        .expect("lab check runs");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.starts_with("SIMULATED LAB: digital twins"), "{text}");
    assert!(
        text.contains("irb120.rws") && text.contains("talos.qtm"),
        "{text}"
    );
}
