//! The operator's commands against a real daemon, each the real `calibd` binary in another
//! process: `submit --watch` prints the summary, `rerun --watch` runs the same document
//! as a new job, `report` writes the printable report, a wrong token says where tokens
//! come from, `submit` uploads the files a job names (a URDF model, files named deeper in
//! the document) so the daemon computes what `calibd run` computes over the files, and
//! `calibd run` drives a device kind on the simulated lab.

use std::process::{Command, Output};

use crate::common::daemon::Daemon;

const BIN: &str = env!("CARGO_BIN_EXE_calibd");

/// `calibd ARGS --server URL --data DATA` (the token is found in DATA/operator.token).
fn calibd(d: &Daemon, data: &std::path::Path, args: &[&str]) -> Output {
    Command::new(BIN)
        .args(args)
        .args(["--server", &d.url, "--data"])
        .arg(data)
        .env_remove("CALIBD_TOKEN")
        .output()
        .expect("calibd runs")
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

#[test]
fn submit_rerun_and_report_from_the_command_line() {
    let data = tempfile::tempdir().unwrap();
    let d = Daemon::start(data.path(), &[("CALIBD_LAB", "none")], true);
    let job = data.path().join("fk.json");
    std::fs::write(&job, calibd::jobs::examples::twin_fk(3).to_string()).unwrap();
    let job = job.display().to_string();

    let o = calibd(&d, data.path(), &["submit", &job, "--watch"]);
    let out = text(&o);
    assert!(o.status.success(), "{out}");
    assert!(
        out.contains("job 1 submitted") && out.contains("3 poses"),
        "{out}"
    );

    let o = calibd(&d, data.path(), &["rerun", "1", "--watch"]);
    let out = text(&o);
    assert!(o.status.success(), "{out}");
    assert!(
        out.contains("job 2 submitted (a re-run of job 1)") && out.contains("3 poses"),
        "{out}"
    );

    let html = data.path().join("r.html");
    let o = calibd(
        &d,
        data.path(),
        &["report", "2", "--out", &html.display().to_string()],
    );
    assert!(o.status.success(), "{}", text(&o));
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(
        page.contains("<html") && page.contains("serial.fk"),
        "{page:.300}"
    );

    // `report -o FILE`: the same report of the same job.
    let short = data.path().join("short.html");
    let o = calibd(
        &d,
        data.path(),
        &["report", "2", "-o", &short.display().to_string()],
    );
    assert!(o.status.success(), "{}", text(&o));
    let again = std::fs::read_to_string(&short).unwrap();
    assert_eq!(strip_written_at(&again), strip_written_at(&page));

    // An identification: `--watch` ends with the verdict the result holds, and its reasons.
    let ident = data.path().join("identify.json");
    std::fs::write(
        &ident,
        calibd::jobs::examples::twin_identify(12, 20).to_string(),
    )
    .unwrap();
    let o = calibd(
        &d,
        data.path(),
        &["submit", &ident.display().to_string(), "--watch"],
    );
    let out = text(&o);
    assert!(o.status.success(), "{out}");
    let r = result_json(&d, data.path(), "3");
    let verdict = r["verdict"].as_str().expect("a verdict");
    assert!(out.contains(&format!("\nverdict: {verdict}\n")), "{out}");
    for reason in r["reasons"].as_array().unwrap() {
        assert!(out.contains(reason["code"].as_str().unwrap()), "{out}");
    }

    // An unknown kind: the daemon's refusal lists the kinds.
    let bad = data.path().join("bad.json");
    std::fs::write(&bad, r#"{"kind": "serial.identfy"}"#).unwrap();
    let o = calibd(&d, data.path(), &["submit", &bad.display().to_string()]);
    let out = text(&o);
    assert!(!o.status.success());
    for k in calibd::jobs::KINDS {
        assert!(out.contains(k.name), "{} not listed: {out}", k.name);
    }
    assert!(out.contains("unknown job kind `serial.identfy`"), "{out}");

    // A wrong token: the message says where a valid one comes from, and a token on the
    // command line is called out as visible in `ps`.
    let o = Command::new(BIN)
        .args(["jobs", "--server", &d.url, "--token", "not-a-token"])
        .output()
        .unwrap();
    let out = text(&o);
    assert!(!o.status.success());
    assert!(
        out.contains("refused the token") && out.contains("operator.token"),
        "{out}"
    );
    assert!(
        out.contains("visible to every user of this machine") && out.contains("CALIBD_TOKEN"),
        "{out}"
    );
    // The same token from the variable: no such warning.
    let o = Command::new(BIN)
        .args(["jobs", "--server", &d.url])
        .env("CALIBD_TOKEN", "not-a-token")
        .output()
        .unwrap();
    let out = text(&o);
    assert!(out.contains("refused the token") && !out.contains("visible to every user"));
}

/// A report without its "Written ... by" line (the time it was written).
fn strip_written_at(html: &str) -> String {
    html.lines()
        .map(|l| match (l.find("Written "), l.find(" by calibd")) {
            (Some(a), Some(b)) if a < b => format!("{}{}", &l[..a], &l[b..]),
            _ => l.to_string(),
        })
        .collect()
}

#[test]
fn a_closed_port_asks_whether_the_daemon_runs_there() {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .unwrap();
    let url = format!("http://127.0.0.1:{port}");
    let o = Command::new(BIN)
        .args(["jobs", "--server", &url])
        .env_remove("CALIBD_TOKEN")
        .output()
        .unwrap();
    let out = text(&o);
    assert!(!o.status.success());
    assert!(
        out.contains(&format!("is `calibd serve` running at {url}?")),
        "{out}"
    );
}

/// The `calibd result ID` JSON of a finished job.
fn result_json(d: &Daemon, data: &std::path::Path, id: &str) -> serde_json::Value {
    let o = calibd(d, data, &["result", id]);
    assert!(o.status.success(), "{}", text(&o));
    serde_json::from_slice(&o.stdout).expect("result JSON")
}

/// The same job run in-process over its files (`calibd run`'s path): the expectation.
fn run_offline(job: &std::path::Path) -> serde_json::Value {
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(job).unwrap()).unwrap();
    let dir = job.parent().unwrap().to_path_buf();
    let prepared = calibd::jobs::prepare(&doc, &calibd::jobs::DirResolver { dir }).unwrap();
    prepared.run(&calibd::util::NoMonitor).unwrap().result
}

/// Every number of `a` within `tol` of the same place in `b`, every other value equal.
fn assert_close(a: &serde_json::Value, b: &serde_json::Value, tol: f64, at: &str) {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            assert!((x - y).abs() <= tol, "{at}: {x} against {y}");
        }
        (Value::Array(x), Value::Array(y)) => {
            assert_eq!(x.len(), y.len(), "{at}: lengths");
            for (i, (p, q)) in x.iter().zip(y).enumerate() {
                assert_close(p, q, tol, &format!("{at}[{i}]"));
            }
        }
        (Value::Object(x), Value::Object(y)) => {
            assert_eq!(
                x.keys().collect::<Vec<_>>(),
                y.keys().collect::<Vec<_>>(),
                "{at}: keys"
            );
            for (k, p) in x {
                assert_close(p, &y[k], tol, &format!("{at}.{k}"));
            }
        }
        _ => assert_eq!(a, b, "{at}"),
    }
}

#[test]
fn submit_uploads_a_urdf_model_that_the_daemon_reads_as_urdf() {
    let data = tempfile::tempdir().unwrap();
    let d = Daemon::start(data.path(), &[("CALIBD_LAB", "none")], true);
    let mukca = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/mukca");
    std::fs::copy(
        mukca.join("panda_nominal.urdf"),
        data.path().join("panda.urdf"),
    )
    .unwrap();
    // Three measured configurations of the Panda (rad), inline.
    let csv = std::fs::read_to_string(mukca.join("panda_6_front.csv")).unwrap();
    let rows: Vec<serde_json::Value> = csv
        .lines()
        .skip(1)
        .take(3)
        .map(|l| {
            let q: Vec<f64> = l.split(',').take(7).map(|v| v.parse().unwrap()).collect();
            serde_json::Value::Object(
                (0..7)
                    .map(|k| (format!("q{}", k + 1), serde_json::json!(q[k])))
                    .collect(),
            )
        })
        .collect();
    let job = data.path().join("panda_fk.json");
    let doc = serde_json::json!({
        "kind": "serial.fk",
        "model": "panda.urdf",
        "chain": {"root": "panda_link0", "tip": "ball_link"},
        "joints": rows,
    });
    std::fs::write(&job, doc.to_string()).unwrap();

    let o = calibd(
        &d,
        data.path(),
        &["submit", &job.display().to_string(), "--watch"],
    );
    let out = text(&o);
    assert!(o.status.success(), "{out}");
    assert!(
        out.contains("job 1 submitted")
            && out.contains("job 1: succeeded")
            && out.contains("3 poses"),
        "{out}"
    );
    // The daemon read the uploaded dataset as the URDF the file is: the poses of the
    // in-process run over the file itself.
    let served = result_json(&d, data.path(), "1");
    let offline = run_offline(&job);
    assert_eq!(served["poses"].as_array().map(Vec::len), Some(3));
    assert_close(&served["poses"], &offline["poses"], 1e-9, "poses");
}

#[test]
fn submit_uploads_the_files_named_deeper_in_the_job() {
    let data = tempfile::tempdir().unwrap();
    let d = Daemon::start(data.path(), &[("CALIBD_LAB", "none")], true);
    let twin = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/data/pcr_twin");
    std::fs::create_dir_all(data.path().join("models")).unwrap();
    for f in ["pcr3pf.json", "pcr3pf_calibrated.json"] {
        std::fs::copy(twin.join(f), data.path().join("models").join(f)).unwrap();
    }
    // `twin.model` is a file named inside the `twin` object.
    let job = data.path().join("accuracy.json");
    let doc = serde_json::json!({
        "kind": "pcr.accuracy",
        "model": "models/pcr3pf_calibrated.json",
        "trajectory": {"square": 0.002, "points_per_side": 3},
        "repetitions": 3,
        "twin": {"model": "models/pcr3pf.json", "seed": 3}
    });
    std::fs::write(&job, doc.to_string()).unwrap();
    let o = calibd(
        &d,
        data.path(),
        &["submit", &job.display().to_string(), "--watch"],
    );
    let out = text(&o);
    assert!(o.status.success(), "{out}");
    assert!(out.contains("job 1: succeeded"), "{out}");
    let served = result_json(&d, data.path(), "1");
    let offline = run_offline(&job);
    assert_close(&served["per_pose"], &offline["per_pose"], 1e-9, "per_pose");
    assert_close(&served["summary"], &offline["summary"], 1e-9, "summary");

    // A nested name of a file that is not there: refused before anything is uploaded,
    // naming the field.
    let bad = data.path().join("bad.json");
    let mut doc = doc;
    doc["twin"]["model"] = serde_json::json!("models/nowhere.json");
    std::fs::write(&bad, doc.to_string()).unwrap();
    let o = calibd(&d, data.path(), &["submit", &bad.display().to_string()]);
    let out = text(&o);
    assert!(!o.status.success(), "{out}");
    assert!(
        out.contains("names files that do not exist")
            && out.contains("`twin.model`: models/nowhere.json"),
        "{out}"
    );
}

#[test]
fn run_drives_a_device_kind_on_the_simulated_lab() {
    // What the `NeedsLab` error tells the user to do: `calibd run JOB` (no flag).
    let job = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/cell_jog.json");
    let o = Command::new(BIN)
        .arg("run")
        .arg(&job)
        .env_remove("CALIBD_CONFIG")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("starting the simulated lab"), "{err}");
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).expect("result JSON");
    let q: Vec<f64> = r["q_deg"]
        .as_array()
        .expect("q_deg")
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let commanded = [10.0, 20.0, -10.0, 30.0, 45.0, 0.0];
    assert_eq!(q.len(), 6, "{r}");
    for (k, (got, want)) in q.iter().zip(commanded).enumerate() {
        assert!(
            (got - want).abs() < 0.01,
            "joint {}: {got} deg, commanded {want}",
            k + 1
        );
    }
}
