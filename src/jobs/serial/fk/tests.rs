use serde_json::json;

use super::*;
use crate::run::DirResolver;
use crate::twin::SerialTwin;
use crate::util::{NoMonitor, Rng};

/// A `serial.fk` job over a joints CSV file of `rows` random IRB 120 configurations (deg).
fn job_dir(rows: usize) -> (tempfile::TempDir, Value) {
    let dir = tempfile::tempdir().expect("temporary folder");
    let twin = SerialTwin::irb120(1);
    let model = serde_json::to_string(&twin.file).expect("model JSON");
    std::fs::write(dir.path().join("irb120.json"), model).expect("model written");
    let mut rng = Rng::new(3);
    let mut csv = String::from("q1,q2,q3,q4,q5,q6\n");
    for _ in 0..rows {
        let q: Vec<String> = twin
            .random_q(&mut rng)
            .iter()
            .map(|v| v.to_degrees().to_string())
            .collect();
        csv.push_str(&q.join(","));
        csv.push('\n');
    }
    std::fs::write(dir.path().join("joints.csv"), csv).expect("joints written");
    let doc = json!({"kind": "serial.fk", "model": "irb120.json", "joints": "joints.csv"});
    (dir, doc)
}

fn poses_csv(job: &FkJob) -> Result<String, JobError> {
    let mut out = Vec::new();
    job.write_csv(&mut out, &NoMonitor)?;
    Ok(String::from_utf8(out).expect("UTF-8 CSV"))
}

#[test]
fn kept_rows_and_a_second_reading_give_the_same_bytes() {
    let (dir, doc) = job_dir(300);
    let resolver = DirResolver {
        dir: dir.path().into(),
    };
    let kept = prepare_keeping(&doc, &Inputs::new(&resolver), KEPT_VALUES).expect("valid");
    let reread = prepare_keeping(&doc, &Inputs::new(&resolver), 0).expect("valid");
    assert!(matches!(kept.joints, Joints::File { kept: Some(ref v), .. } if v.len() == 300 * 6));
    assert!(matches!(reread.joints, Joints::File { kept: None, .. }));
    let a = poses_csv(&kept).expect("kept rows run");
    assert_eq!(a.lines().count(), 301);
    assert_eq!(a, poses_csv(&reread).expect("re-read rows run"));
    // A cap between rows drops what was kept rather than keep a part.
    let part = prepare_keeping(&doc, &Inputs::new(&resolver), 100).expect("valid");
    assert!(matches!(part.joints, Joints::File { kept: None, .. }));
}

#[test]
fn kept_rows_still_fail_when_the_file_changed() {
    let (dir, doc) = job_dir(20);
    let resolver = DirResolver {
        dir: dir.path().into(),
    };
    let job = prepare_keeping(&doc, &Inputs::new(&resolver), KEPT_VALUES).expect("valid");
    let joints = dir.path().join("joints.csv");
    let mut text = std::fs::read_to_string(&joints).expect("joints read");
    text.push_str("1,2,3,4,5,6\n");
    std::fs::write(&joints, text).expect("joints changed");
    let e = poses_csv(&job)
        .expect_err("a changed file fails")
        .to_string();
    assert!(e.contains("changed after the job was validated"), "{e}");
}
