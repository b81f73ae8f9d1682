//! `serial.fk` with its tables streamed: a joints CSV file read row by row and the poses CSV
//! written row by row give the same bytes as the whole result (the path before streaming);
//! bad rows are refused naming the row, column and value; a failed run leaves nothing
//! half-written.

use std::path::Path;

use calibd::bench::serial::{WholeFiles, run_fk_job, write_fk_job};
use calibd::jobs::{DirResolver, Table, prepare};
use calibd::util::NoMonitor;
use serde_json::json;

/// `Table::to_csv` as it was before streaming: the reference formatting.
fn joined_csv(t: &Table) -> String {
    let mut s = t.columns.join(",");
    s.push('\n');
    for r in &t.rows {
        let cells: Vec<String> = r.iter().map(|v| format!("{v}")).collect();
        s.push_str(&cells.join(","));
        s.push('\n');
    }
    s
}

fn job_doc(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("fk.json")).unwrap()).unwrap()
}

#[test]
fn streamed_poses_csv_equals_the_whole_result_to_the_byte() {
    let dir = tempfile::tempdir().unwrap();
    let job = write_fk_job(dir.path(), 2_000).unwrap();
    let streamed = dir.path().join("streamed.csv");
    assert_eq!(run_fk_job(&job, &streamed, false).unwrap(), 2_000);
    let streamed = std::fs::read_to_string(&streamed).unwrap();

    // The path before streaming: the table read whole, the poses table and its JSON rows.
    let doc = job_doc(dir.path());
    let whole = prepare(
        &doc,
        &WholeFiles(DirResolver {
            dir: dir.path().into(),
        }),
    )
    .unwrap()
    .run(&NoMonitor)
    .unwrap();
    let table = whole.main_table.unwrap();
    assert_eq!(table.rows.len(), 2_000);
    assert_eq!(streamed, joined_csv(&table));

    // The run of the job over the file (re-read row by row) gives the same result JSON,
    // with the joints file's hash computed as it streamed.
    let over_file = prepare(
        &doc,
        &DirResolver {
            dir: dir.path().into(),
        },
    )
    .unwrap()
    .run(&NoMonitor)
    .unwrap();
    assert_eq!(over_file.result["poses"], whole.result["poses"]);
    let bytes = std::fs::read(dir.path().join("joints.csv")).unwrap();
    assert_eq!(
        over_file.result["inputs_sha256"]["joints"],
        json!(calibd::run::input::sha256_hex(&bytes))
    );
    assert_eq!(
        over_file.result["inputs_sha256"]["joints"],
        whole.result["inputs_sha256"]["joints"]
    );
    // Every streamed number is the result JSON's number, exactly.
    let back = Table::from_csv("poses", &streamed).unwrap();
    let poses = whole.result["poses"].as_array().unwrap();
    for (r, row) in back.rows.iter().zip(poses) {
        for (c, v) in back.columns.iter().zip(r) {
            assert_eq!(row[c].as_f64(), Some(*v));
        }
    }
}

#[test]
fn bad_rows_of_a_streamed_file_are_refused_naming_row_column_and_value() {
    let dir = tempfile::tempdir().unwrap();
    write_fk_job(dir.path(), 3_000).unwrap();
    let joints = dir.path().join("joints.csv");
    let good = std::fs::read_to_string(&joints).unwrap();
    let lines: Vec<&str> = good.lines().collect();
    let resolver = DirResolver {
        dir: dir.path().into(),
    };
    let with_row = |row: usize, text: &str| {
        let mut l = lines.clone();
        l[row] = text;
        std::fs::write(&joints, l.join("\n") + "\n").unwrap();
        prepare(&job_doc(dir.path()), &resolver)
            .unwrap_err()
            .to_string()
    };
    let e = with_row(2_001, "1,2,abc,4,5,6");
    assert!(
        e.contains("joints") && e.contains("row 2001") && e.contains("`q3`: `abc`"),
        "{e}"
    );
    let e = with_row(17, "1,170,3,4,5,6");
    assert!(
        e.contains("row 17") && e.contains("q2 = 170") && e.contains("outside the joint limits"),
        "{e}"
    );
    let e = with_row(2_999, "1,2,3,4,5");
    assert!(
        e.contains("row 2999") && e.contains("5 values for 6 columns"),
        "{e}"
    );
    let e = with_row(0, "q1,q2,q3,q4,q5,q7");
    assert!(e.contains("missing column `q6`"), "{e}");
}

#[test]
fn a_file_changed_after_validation_fails_and_leaves_the_old_output() {
    let dir = tempfile::tempdir().unwrap();
    write_fk_job(dir.path(), 500).unwrap();
    let prepared = prepare(
        &job_doc(dir.path()),
        &DirResolver {
            dir: dir.path().into(),
        },
    )
    .unwrap();
    let joints = dir.path().join("joints.csv");
    let mut text = std::fs::read_to_string(&joints).unwrap();
    text.push_str("1,2,3,4,5,6\n");
    std::fs::write(&joints, text).unwrap();
    let out = dir.path().join("poses.csv");
    std::fs::write(&out, "old\n").unwrap();
    let e = calibd::offline::write_main_csv(&prepared, &out, &NoMonitor)
        .unwrap_err()
        .to_string();
    assert!(e.contains("changed after the job was validated"), "{e}");
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "old\n");
    assert!(!dir.path().join("poses.csv.partial").exists());
    // The unchanged-file run replaces it.
    write_fk_job(dir.path(), 500).unwrap();
    let prepared = prepare(
        &job_doc(dir.path()),
        &DirResolver {
            dir: dir.path().into(),
        },
    )
    .unwrap();
    assert_eq!(
        calibd::offline::write_main_csv(&prepared, &out, &NoMonitor).unwrap(),
        500
    );
    assert_eq!(std::fs::read_to_string(&out).unwrap().lines().count(), 501);
}

#[test]
fn an_unwritable_poses_file_is_an_io_error_naming_it_and_calibd_run_exits_1() {
    let dir = tempfile::tempdir().unwrap();
    let job = write_fk_job(dir.path(), 50).unwrap();
    let out = dir.path().join("poses.csv");
    // The `.partial` file the rows go to is a folder: it cannot be created.
    std::fs::create_dir(dir.path().join("poses.csv.partial")).unwrap();
    let prepared = prepare(
        &job_doc(dir.path()),
        &DirResolver {
            dir: dir.path().into(),
        },
    )
    .unwrap();
    let e = calibd::offline::write_main_csv(&prepared, &out, &NoMonitor).unwrap_err();
    let calibd::jobs::JobError::Io { what, path, .. } = &e else {
        panic!("{e:?}");
    };
    assert_eq!(
        (what.as_str(), path.as_deref()),
        ("writing", Some(out.as_path()))
    );
    let named = format!("writing {}: ", out.display());
    assert!(e.to_string().starts_with(&named), "{e}");
    assert!(e.is_internal() && !e.is_invalid_input());
    // `calibd run` fails the same way, with exit code 1 (every failed run's).
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_calibd"))
        .args(["run", &job.display().to_string(), "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains(&named), "{err}");
    assert!(!out.exists());
}
