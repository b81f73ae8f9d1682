use std::time::Duration;

use super::*;
use crate::bench::{Area, Figure, Report};

fn figure(name: &str, median_us: u64, spread_us: u64) -> Figure {
    let us = Duration::from_micros;
    Figure {
        name: name.into(),
        per_op: us(median_us),
        min: us(median_us - spread_us / 2),
        max: us(median_us + spread_us / 2),
        runs: 9,
        ops: 1,
        target: None,
        peak_rss_bytes: Some(100 << 20),
        cpu: Some(us(median_us)),
        cpu_target: None,
    }
}

/// A run as `calibd bench --json` writes it, read back as `compare` reads it.
fn saved(figures: Vec<Figure>) -> SavedReport {
    let r = Report::new(vec![Area {
        area: "pcr".into(),
        figures,
    }]);
    let text = serde_json::to_string(&r).expect("json");
    SavedReport::parse("run.json", &text).expect("parses")
}

#[test]
fn a_run_compared_with_itself_changes_nothing() {
    let a = saved(vec![figure("fk", 1900, 100), figure("ik", 2300, 200)]);
    let rows = compare(&a, &a);
    assert_eq!(rows.len(), 2);
    for r in &rows {
        assert_eq!(r.change, Change::Same, "{r:?}");
        assert!((r.ratio.expect("ratio") - 1.0).abs() < 1e-12);
        assert_eq!(r.memory_ratio, Some(1.0));
    }
}

#[test]
fn a_change_counts_only_beyond_the_spread_of_the_runs() {
    let old = saved(vec![
        figure("fk", 1000, 20),  // 2 % spread: the 5 % floor applies
        figure("ik", 1000, 400), // 40 % spread
        figure("gone", 500, 10),
    ]);
    let new = saved(vec![
        figure("fk", 2000, 20),  // 2.0x: slower
        figure("ik", 1300, 400), // 1.3x within a 40 % noise: same
        figure("added", 10, 1),
    ]);
    let rows = compare(&old, &new);
    let by = |n: &str| rows.iter().find(|r| r.name == n).expect("row").clone();
    assert_eq!(by("fk").change, Change::Regression);
    assert!((by("fk").ratio.expect("ratio") - 2.0).abs() < 1e-9);
    assert!((by("fk").noise - MIN_NOISE).abs() < 1e-12);
    assert_eq!(by("ik").change, Change::Same);
    assert!(
        (by("ik").noise - 0.4).abs() < 1e-9,
        "the larger of the two spreads"
    );
    assert_eq!(by("added").change, Change::New);
    assert_eq!(by("gone").change, Change::Gone);
    // The other way round the same figures are faster.
    let back = compare(&new, &old);
    let fk = back.iter().find(|r| r.name == "fk").expect("row");
    assert_eq!(fk.change, Change::Improvement);
    let text = render(&old, &new, &rows);
    assert!(text.contains("pcr/fk"), "{text}");
    assert!(text.contains("2.00x"), "{text}");
    assert!(
        text.contains("1 slower, 0 faster, 1 within the noise, 1 new, 1 gone"),
        "{text}"
    );
}

#[test]
fn a_file_that_is_not_a_saved_run_is_refused_with_its_name() {
    let e = SavedReport::parse("old.json", "{\"areas\": 3}").unwrap_err();
    assert!(
        e.to_string()
            .starts_with("old.json: not a `calibd bench --json` file"),
        "{e}"
    );
    let bad = r#"{"version":"0.1.0","finished_at":"t","cpus":2,"areas":[{"area":"pcr","figures":[
        {"name":"fk","median_per_op_s":-1.0,"min_per_op_s":0.0,"max_per_op_s":0.0}]}]}"#;
    let e = SavedReport::parse("new.json", bad).unwrap_err();
    assert!(e.to_string().contains("figure `fk` of area `pcr`"), "{e}");
}

#[test]
fn a_rate_carried_in_the_name_does_not_split_a_figure() {
    let old = saved(vec![figure(
        "pattern_pose 1024x1024: 198 images/s",
        5050,
        100,
    )]);
    let new = saved(vec![figure(
        "pattern_pose 1024x1024: 99 images/s",
        10100,
        100,
    )]);
    let rows = compare(&old, &new);
    assert_eq!(rows.len(), 1, "{rows:?}");
    assert_eq!(rows[0].change, Change::Regression);
    assert!((rows[0].ratio.expect("ratio") - 2.0).abs() < 1e-9);
}
