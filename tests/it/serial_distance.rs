//! Distance (`L_mm`) measurements in `serial.identify`: the IRB 120 twin with a known anchor
//! and length offset, unused-column warnings, and the draw-wire acceptance on the RobotCali
//! data (read from `../shared/data/real/...` when present; that file has no licence and is
//! never copied into the repository).

use crate::common;

use calibd::identify::{Robust, RobustKind, SolveOptions, solve, solve_robust};
use calibd::jobs::{DirResolver, prepare};
use calibd::measure::distance::distance_errors;
use calibd::measure::{DistanceMeasurement, DistanceProblem};
use calibd::model::dh::DhFile;
use calibd::twin::SerialTwin;
use calibd::util::{NoMonitor, Rng};
use nalgebra::Vector3;
use serde_json::{Map, Value, json};

const ANCHOR: [f64; 3] = [650.0, -350.0, 1100.0];
const OFFSET: f64 = -412.5;
const NOISE_MM: f64 = 0.010;

fn identify_names(file: &DhFile) -> Vec<String> {
    let mut names = file.identify.clone();
    names.extend(["tool.x", "tool.y", "tool.z"].map(String::from));
    names
}

/// Rows {q1..q6 (deg), L_mm} of the twin with a fixed anchor and offset, plus noise.
fn twin_rows(twin: &SerialTwin, n: usize, seed: u64) -> Vec<Value> {
    let mut rng = Rng::new(seed);
    let a = Vector3::from(ANCHOR);
    (0..n)
        .map(|_| {
            let q = twin.random_q(&mut rng);
            let l = (twin.true_tcp(&q) - a).norm() + OFFSET + NOISE_MM * rng.normal();
            let mut row = Map::new();
            for (k, v) in q.iter().enumerate() {
                row.insert(format!("q{}", k + 1), json!(v.to_degrees()));
            }
            row.insert("L_mm".into(), json!(l));
            Value::Object(row)
        })
        .collect()
}

fn run(doc: &Value) -> Value {
    let dir = common::data();
    prepare(doc, &DirResolver { dir })
        .unwrap()
        .run(&NoMonitor)
        .unwrap()
        .result
}

#[test]
fn twin_recovers_anchor_and_offset_and_validates_at_noise_level() {
    let twin = SerialTwin::irb120(7);
    let doc = json!({
        "kind": "serial.identify",
        "model": "robots/irb120.json",
        "measurements": twin_rows(&twin, 200, 1),
        "validation": twin_rows(&twin, 100, 2),
        "options": {"identify": identify_names(&twin.file)},
    });
    let r = run(&doc);
    assert_eq!(r["measurement_type"], "distance");
    assert_eq!(r["convergence"]["converged"], true, "{}", r["convergence"]);
    assert!(r.get("warnings").is_none(), "{}", r["warnings"]);
    // The anchor is found in {W} of the model, whose base frame is held (a distance cannot
    // see it): compare it in the robot frame {0}, where it is invariant.
    let a = &r["anchor"];
    let fit = Vector3::new(
        a["x"].as_f64().unwrap(),
        a["y"].as_f64().unwrap(),
        a["z"].as_f64().unwrap(),
    );
    let fit0 = twin.nominal.base_frame().inverse().apply(&fit);
    let true0 = twin
        .truth
        .base_frame()
        .inverse()
        .apply(&Vector3::from(ANCHOR));
    let anchor_err = (fit0 - true0).norm();
    let offset = r["length_offset"]["value"].as_f64().unwrap();
    let offset_std = r["length_offset"]["std"].as_f64().unwrap();
    let offset_err = offset - OFFSET;
    let before = r["validation"]["before"]["rms"].as_f64().unwrap();
    let after = r["validation"]["after"]["rms"].as_f64().unwrap();
    println!(
        "twin: anchor error in {{0}} {anchor_err:.4} mm, offset error {offset_err:.4} mm \
         (std {offset_std:.4}), held-out RMS before {before:.3} mm after {after:.4} mm, \
         unidentifiable {}",
        r["unidentifiable"]
    );
    let held: Vec<&str> = r["unidentifiable"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_str)
        .collect();
    // Base parameters act only through the anchor: six of them and three anchor
    // coordinates give three seen combinations, so at least six of the nine are held.
    let held_frame = held
        .iter()
        .filter(|n| n.starts_with("base.") || n.starts_with("anchor."))
        .count();
    assert!(held_frame >= 6, "{held:?}");
    assert!(
        offset_err.abs() < 4.0 * offset_std + 1e-3,
        "{offset_err} vs {offset_std}"
    );
    assert!(anchor_err < 0.5, "{anchor_err}");
    // Noise 0.010 mm: the held-out RMS is at the noise level.
    assert!(after < 2.0 * NOISE_MM, "after {after}");
    assert!(before > 10.0 * after, "before {before} after {after}");

    // MAP on the same data: a prior far wider than the errors leaves the least-squares
    // result; a 1 nm prior on a2 holds it where least squares moves it.
    let map = |prior: Value| {
        let mut d = doc.clone();
        d["options"]["prior"] = prior;
        d["options"]["noise"] = json!(NOISE_MM);
        run(&d)
    };
    let value = |r: &Value, name: &str| {
        r["parameters"]
            .as_array()
            .and_then(|ps| ps.iter().find(|p| p["name"] == name))
            .map(|p| p["value"].as_f64().unwrap() - p["nominal"].as_f64().unwrap())
            .unwrap()
    };
    let wide = map(json!({"default_std": {"length_mm": 1e4, "angle_deg": 1e3}}));
    assert_eq!(wide["prior"]["mode"], "map");
    let after_wide = wide["validation"]["after"]["rms"].as_f64().unwrap();
    assert!(
        (after_wide - after).abs() < 0.02 * after,
        "{after_wide} vs {after}"
    );
    let pinned = map(json!({"std": {"a2": 1e-6}}));
    assert!(
        value(&r, "a2").abs() > 1e-3,
        "least squares moved a2 by {}",
        value(&r, "a2")
    );
    assert!(
        value(&pinned, "a2").abs() < 1e-5,
        "{}",
        value(&pinned, "a2")
    );
}

#[test]
fn unused_columns_are_warned_and_l_mm_takes_precedence_over_x_y_z() {
    let twin = SerialTwin::irb120(7);
    let mut rows = twin_rows(&twin, 40, 3);
    for row in &mut rows {
        let o = row.as_object_mut().unwrap();
        o.insert("x".into(), json!(1.0));
        o.insert("y".into(), json!(2.0));
        o.insert("z".into(), json!(3.0));
        o.insert("note".into(), json!(0.0));
    }
    let doc = json!({
        "kind": "serial.identify",
        "model": "robots/irb120.json",
        "measurements": rows,
        "options": {"identify": identify_names(&twin.file)},
    });
    let r = run(&doc);
    assert_eq!(r["measurement_type"], "distance");
    let w = r["warnings"].as_array().unwrap();
    assert_eq!(w.len(), 1, "{w:?}");
    let w = w[0].as_str().unwrap();
    assert!(
        w.starts_with("measurements: columns") && w.contains("x, y, z") && w.contains("note"),
        "{w}"
    );
    // A length column named `L` is not read: Cartesian x, y, z are, and `L` is reported.
    let rows: Vec<Value> = twin
        .tracker(20, 4)
        .iter()
        .map(|m| {
            let mut o = Map::new();
            for (k, v) in m.q.iter().enumerate() {
                o.insert(format!("q{}", k + 1), json!(v.to_degrees()));
            }
            let calibd::measure::Target::Point(p) = m.target else {
                unreachable!()
            };
            o.insert("x".into(), json!(p.x));
            o.insert("y".into(), json!(p.y));
            o.insert("z".into(), json!(p.z));
            o.insert("L".into(), json!(500.0));
            Value::Object(o)
        })
        .collect();
    let doc = json!({
        "kind": "serial.identify",
        "model": "robots/irb120.json",
        "measurements": rows,
    });
    let r = run(&doc);
    let w = r["warnings"][0].as_str().unwrap();
    assert!(w.starts_with("measurements: column L is not used"), "{w}");
    assert!(w.contains("L_mm"), "{w}");
}

/// The RobotCali draw-wire table: header and rows (all numeric).
fn drawwire() -> Option<(Vec<String>, Vec<Vec<f64>>)> {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/real/abb_irb120_drawwire/robotcali_new.csv");
    let Ok(text) = std::fs::read_to_string(&path) else {
        println!("skipped: draw-wire data {} not found", path.display());
        return None;
    };
    let mut lines = text.lines();
    let header: Vec<String> = lines
        .next()?
        .split(',')
        .map(|s| s.trim().to_string())
        .collect();
    let rows = lines
        .filter(|l| !l.trim().is_empty())
        .map(|l| l.split(',').map(|v| v.trim().parse().unwrap()).collect())
        .collect();
    Some((header, rows))
}

fn to_json_rows(header: &[String], rows: &[&Vec<f64>]) -> Vec<Value> {
    rows.iter()
        .map(|r| {
            let mut o = Map::new();
            for (h, v) in header.iter().zip(r.iter()) {
                let name = if h == "L" { "L_mm" } else { h.as_str() };
                o.insert(name.into(), json!(v));
            }
            Value::Object(o)
        })
        .collect()
}

#[test]
fn drawwire_acceptance() {
    let Some((header, rows)) = drawwire() else {
        return;
    };
    assert_eq!(rows.len(), 1042);
    // Seeded 70/30 split.
    let mut rng = Rng::new(2021);
    let mut idx: Vec<usize> = (0..rows.len()).collect();
    for i in (1..idx.len()).rev() {
        let j = ((rng.uniform() * (i + 1) as f64) as usize).min(i);
        idx.swap(i, j);
    }
    let n_cal = rows.len() * 7 / 10;
    let cal: Vec<&Vec<f64>> = idx[..n_cal].iter().map(|&i| &rows[i]).collect();
    let val: Vec<&Vec<f64>> = idx[n_cal..].iter().map(|&i| &rows[i]).collect();
    let file = DhFile::parse(calibd::twin::serial::IRB120_JSON).unwrap();
    let fit = |names: Vec<String>| -> Value {
        run(&json!({
            "kind": "serial.identify",
            "model": "robots/irb120.json",
            "measurements": to_json_rows(&header, &cal),
            "validation": to_json_rows(&header, &val),
            "options": {"identify": names},
        }))
    };
    let tool = ["tool.x", "tool.y", "tool.z"].map(String::from).to_vec();
    let reduced: Vec<String> = [
        "theta_offset2",
        "theta_offset3",
        "a2",
        "a3",
        "d4",
        "alpha2",
        "alpha3",
        "beta2",
    ]
    .map(String::from)
    .into_iter()
    .chain(tool.clone())
    .collect();
    let mut held_out = Vec::new();
    for (label, names) in [
        ("tool only (nuisance)", tool.clone()),
        ("reduced geometric + tool", reduced),
        ("model list + tool", identify_names(&file)),
        ("model list + tool, MAP", identify_names(&file)),
    ] {
        let r = if label.ends_with("MAP") {
            run(&json!({
                "kind": "serial.identify",
                "model": "robots/irb120.json",
                "measurements": to_json_rows(&header, &cal),
                "validation": to_json_rows(&header, &val),
                "options": {"identify": names, "prior_weight": "cv", "prior": {"default_std":
                    {"length_mm": 1.0, "angle_deg": 0.5, "compliance": 0.005}}},
            }))
        } else {
            fit(names)
        };
        println!("draw-wire [{label}] prior: {}", r["prior"]);
        let before = r["validation"]["before"]["rms"].as_f64().unwrap();
        let after = r["validation"]["after"]["rms"].as_f64().unwrap();
        println!(
            "draw-wire [{label}]: {} calibration / {} held-out rows; held-out distance RMS \
             nominal {before:.3} mm (median {:.3}), calibrated {after:.3} mm (median {:.3}); \
             calibration residual RMS {:.3} -> {:.3} mm; status {}; unidentifiable {}; \
             anchor {}; length_offset {}",
            cal.len(),
            val.len(),
            r["validation"]["before"]["median"].as_f64().unwrap(),
            r["validation"]["after"]["median"].as_f64().unwrap(),
            r["residuals"]["before"]["rms"].as_f64().unwrap(),
            r["residuals"]["after"]["rms"].as_f64().unwrap(),
            r["convergence"]["status"],
            r["unidentifiable"],
            r["anchor"],
            r["length_offset"],
        );
        let w = r["warnings"][0].as_str().unwrap();
        assert!(w.contains("x, y, z"), "{w}");
        held_out.push((before, after, r["convergence"]["status"].clone()));
    }
    // The nuisance-only fit (tool translation, anchor, offset) and the reduced geometric set
    // both improve on the nominal model; the model's full list (31 parameters + tool) is
    // not determined by these data (q4, q5 barely move) and runs away in least squares
    // (reported, not asserted); with a prior (1 mm, 0.5 deg, weight by 5-fold) the same
    // list converges and gives the best held-out figure of the four.
    for i in [0, 1, 3] {
        let (before, after, status) = &held_out[i];
        assert!(after < before, "before {before} after {after}");
        assert_eq!(status, "converged");
    }
    assert!(
        held_out[3].1 < held_out[1].1,
        "MAP {} vs reduced {}",
        held_out[3].1,
        held_out[1].1
    );

    // Row 951 (1-based data row, the header not counted): does a robust loss flag it?
    let chain = file.to_chain().unwrap();
    let ids = [
        "theta_offset2",
        "theta_offset3",
        "a2",
        "a3",
        "d4",
        "alpha2",
        "alpha3",
        "beta2",
        "tool.x",
        "tool.y",
        "tool.z",
    ]
    .iter()
    .map(|n| chain.param_by_name(n).unwrap())
    .collect();
    let col = |n: &str| header.iter().position(|h| h == n).unwrap();
    let (l, qc) = (
        col("L"),
        (1..=6).map(|k| col(&format!("q{k}"))).collect::<Vec<_>>(),
    );
    let meas: Vec<DistanceMeasurement> = rows
        .iter()
        .map(|r| DistanceMeasurement {
            q: qc.iter().map(|&c| r[c].to_radians()).collect(),
            length: r[l],
        })
        .collect();
    let p = DistanceProblem::new(chain, ids, meas.clone()).unwrap();
    let x0 = p.initial();
    let opts = SolveOptions {
        nuisance: Some(p.nuisance()),
        pivoting: calibd::identify::Pivoting::Priority(p.priority_order()),
        ..Default::default()
    };
    let ls = solve(&p, &p.unknowns(), &x0, &opts, &NoMonitor).unwrap();
    let robust = Robust {
        kind: RobustKind::Cauchy,
        scale: None,
        group: 1,
    };
    let rs = solve_robust(&p, &p.unknowns(), &x0, &opts, &robust, &NoMonitor).unwrap();
    let rep = rs.robust.clone().unwrap();
    let (a, l0) = p.anchor(&rs.x);
    let e = distance_errors(&p.model(&rs.x), &a, l0, &meas);
    let mut worst: Vec<(usize, f64)> = e.iter().map(|v| v.abs()).enumerate().collect();
    worst.sort_by(|x, y| y.1.total_cmp(&x.1));
    let ls_abs: Vec<f64> = ls.residuals.iter().map(|v| v.abs()).collect();
    println!(
        "robust (Cauchy, all rows): scale {:.3} mm, {} of {} rows down-weighted below 0.5; \
         worst rows (1-based, |e| mm): {:?}; row 951 |e| robust {:.3} mm, least squares {:.3} mm",
        rep.scale,
        rep.downweighted,
        rep.groups,
        worst[..5]
            .iter()
            .map(|(i, v)| (i + 1, (v * 1000.0).round() / 1000.0))
            .collect::<Vec<_>>(),
        e[950].abs(),
        ls_abs[950],
    );
    // Row 951 is fine as a distance measurement: not down-weighted by the robust loss.
    assert!(e[950].abs() < rep.scale, "{}", e[950]);
    // Its bad value is in the controller's x, y, z (z jumps by ~100 mm while the joints
    // move by a degree): the same anchor fit on those columns as TCP positions makes it the
    // largest residual by far.
    let (xc, yc, zc) = (col("x"), col("y"), col("z"));
    let pts: Vec<Vector3<f64>> = rows
        .iter()
        .map(|r| Vector3::new(r[xc], r[yc], r[zc]))
        .collect();
    let ls_len: Vec<f64> = rows.iter().map(|r| r[l]).collect();
    let (a, l0) = calibd::measure::distance::fit_anchor(&pts, &ls_len);
    let ec: Vec<f64> = pts
        .iter()
        .zip(&ls_len)
        .map(|(p, l)| ((p - a).norm() + l0 - l).abs())
        .collect();
    let mut sorted = ec.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    let argmax = (0..ec.len())
        .max_by(|&i, &j| ec[i].total_cmp(&ec[j]))
        .unwrap();
    println!(
        "controller x, y, z as TCP: median |e| {median:.3} mm; largest at row {} ({:.3} mm); row 951 {:.3} mm",
        argmax + 1,
        ec[argmax],
        ec[950]
    );
    assert_eq!(argmax, 950);
}
