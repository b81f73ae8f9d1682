//! One absent device takes down only its cell: the U-WAVE receiver of `irb120` unplugged
//! (its port's link removed while every mock process serves) leaves the lab file valid,
//! `calibd lab check` prints its table with the failing row, the daemon starts, the cell is
//! unavailable with the reason while the 3-PF cell runs a campaign, and plugging the
//! receiver back in makes the cell available again.

use std::time::{Duration, Instant};

use serde_json::json;

use super::{Daemon, WAIT, free_port, lab_check, lab_dir, mock, trical_doc};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unplugged_receiver_takes_down_only_its_cell() {
    let _one = crate::hil::OUT_OF_PROCESS.lock().await;
    let dir = tempfile::tempdir().expect("temp dir");
    let lab = lab_dir(dir.path(), free_port());
    let _trical_mock = mock(&lab, "irb120");
    let _pcr_mock = mock(&lab, "pcr3pf");
    let _talos_mock = mock(&lab, "talos");
    let port = dir.path().join("ttyUWAVE");
    let pty = std::fs::read_link(&port).expect("the mock links the port to its pty");
    std::fs::remove_file(&port).expect("unplug the receiver");

    // The check prints every device's row; only the receiver's fails, with its fix.
    let (ok, out) = lab_check(&lab);
    eprintln!("{out}");
    assert!(!ok, "{out}");
    let row = |device: &str| -> String {
        out.lines()
            .find(|l| l.starts_with(&format!("{device} ")))
            .unwrap_or_else(|| panic!("no row of {device} in\n{out}"))
            .to_string()
    };
    let uwave = row("irb120.uwave");
    assert!(
        uwave.contains("FAILED") && uwave.contains(&port.display().to_string()),
        "{uwave}"
    );
    for device in [
        "irb120.rws",
        "pcr3pf.stages",
        "pcr3pf.microscope",
        "talos.joints",
        "talos.qtm",
    ] {
        let r = row(device);
        assert!(r.contains("  ok  "), "{r}");
    }
    assert!(out.contains("plug the receiver in"), "{out}");
    assert!(out.contains("1 of 6 devices failed the check"), "{out}");

    // The daemon starts on the same file: the cell is unavailable from the start, with the
    // device and the reason; the other cells are available.
    let d = Daemon::start(dir.path(), &lab);
    let l = d.get("/v1/lab").await;
    let cell = |l: &serde_json::Value, name: &str| -> serde_json::Value {
        l["cells"]
            .as_array()
            .and_then(|c| c.iter().find(|c| c["name"] == name).cloned())
            .unwrap_or_else(|| panic!("no cell {name} in {l}"))
    };
    let irb = cell(&l, "irb120");
    assert_eq!(irb["available"], false, "{l}");
    let reason = irb["reason"].as_str().unwrap_or_default();
    assert!(
        reason.contains("irb120.uwave") && reason.contains("ttyUWAVE"),
        "{reason}"
    );
    let l = d.get("/v1/lab?refresh=true").await;
    assert_eq!(cell(&l, "irb120")["available"], false, "{l}");
    for name in ["pcr3pf", "talos"] {
        let c = cell(&l, name);
        assert_eq!(c["available"], true, "{l}");
        assert!(c["reason"].is_null(), "{l}");
    }
    let (s, e) = d.post("/v1/jobs", &trical_doc()).await;
    assert_eq!(s, 409, "{e}");
    assert!(e.to_string().contains("irb120.uwave"), "{e}");

    // The rest serve: a 3-PF campaign runs to the twin's noise.
    let (_, r, _) = d
        .run(&json!({
            "kind": "cell.pcr_campaign", "cell": "pcr3pf", "poses": 16, "seed": 2,
            "validation_fraction": 0.25,
        }))
        .await;
    let after = r["validation"]["after"]["mean"].as_f64().expect("mean");
    assert!(after > 1e-9 && after < 60e-9, "{}", r["validation"]);

    // Plugged back in, the next check finds it and the cell is available again.
    std::os::unix::fs::symlink(&pty, &port).expect("plug the receiver back in");
    let t0 = Instant::now();
    loop {
        let l = d.get("/v1/lab?refresh=true").await;
        if cell(&l, "irb120")["available"] == true {
            break;
        }
        assert!(t0.elapsed() < WAIT, "{l}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}
