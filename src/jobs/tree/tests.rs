use serde_json::{Map, json};

use super::*;
use crate::identify::coverage::TWO_SIGMA_PROBABILITY;
use crate::model::elastic::{ElasticOptions, GEOMETRY};
use crate::run::NoReferences;
use crate::twin::elastic::{ElasticTwin, revolute_rows};
use crate::util::NoMonitor;

/// The twin's tree as a `tree.identify` document with inline samples.
fn twin_job(twin: &ElasticTwin, elastic: Value, folds: Option<usize>) -> Value {
    let m = &twin.nominal;
    let vars: Vec<String> = (0..m.variables).map(|k| format!("q{k}")).collect();
    let rows: Vec<Value> = m
        .rows
        .iter()
        .map(|r| {
            let parent = r.parent.map(|p| m.rows[p].name.clone());
            match &r.kind {
                RowKind::Fixed { frame, .. } => {
                    let v = frame.to_xyzabc();
                    json!({"name": r.name, "parent": parent, "fixed": {
                        "xyz_m": [v[0], v[1], v[2]],
                        "abc_deg": [v[3].to_degrees(), v[4].to_degrees(), v[5].to_degrees()]}})
                }
                RowKind::Revolute { geometry: g, drive } => {
                    let mut o = json!({"name": r.name, "parent": parent, "mdh": {
                        "alpha_deg": g[0].to_degrees(), "a_m": g[1], "beta_deg": g[2].to_degrees(),
                        "theta_deg": g[3].to_degrees(), "d_m": g[4]}});
                    match drive {
                        Drive::Variable(k) => o["variable"] = json!(vars[*k]),
                        Drive::Coupled(c) => {
                            o["coupled"] = json!(
                                c.iter()
                                    .map(|(k, f)| json!([vars[*k], f]))
                                    .collect::<Vec<_>>()
                            )
                        }
                    }
                    o
                }
            }
        })
        .collect();
    let samples: Vec<Value> = twin
        .observations
        .iter()
        .map(|o| {
            let mut row = Map::new();
            for (k, v) in vars.iter().enumerate() {
                row.insert(v.clone(), json!(o.sample.q[k]));
            }
            for (mk, p) in m.markers.iter().zip(&o.points) {
                let p = p.unwrap_or_default();
                for (a, c) in ["x", "y", "z"].iter().enumerate() {
                    row.insert(format!("{}_{c}", mk.name), json!(p[a]));
                }
            }
            row.insert("t_s".into(), json!(0.0));
            Value::Object(row)
        })
        .collect();
    let b = m.base;
    json!({
        "kind": "tree.identify",
        "tree": {"convention": "modified_dh", "rows": rows},
        "variables": vars,
        "markers": m.markers.iter().map(|k| json!({"name": k.name, "row": m.rows[k.row].name,
            "initial_m": [k.local.x, k.local.y, k.local.z]})).collect::<Vec<_>>(),
        "base": {"xyz_m": [b[0], b[1], b[2]], "abc_deg": [b[3].to_degrees(), b[4].to_degrees(), b[5].to_degrees()]},
        "samples": samples,
        "options": {"elastic": elastic, "folds": folds, "seed": 3},
    })
}

/// Prepare and run a `tree.identify` document.
fn calibrate(doc: &Value) -> Run<TreeCalibration> {
    prepare(doc, &Inputs::new(&NoReferences))
        .expect("prepares")
        .calibrate(&NoMonitor)
        .expect("runs")
}

fn all() -> ElasticOptions {
    ElasticOptions {
        joint: revolute_rows(),
        lateral: revolute_rows(),
        ..Default::default()
    }
}

#[test]
fn tree_identify_runs_the_cumulative_steps_with_lumped_and_lateral_elasticity() {
    let twin = ElasticTwin::new(&all(), 150, 1e-4, 5);
    let doc = twin_job(
        &twin,
        json!({"joint": ["*"], "lateral": ["*"], "lumping": "subtree"}),
        Some(3),
    );
    let r = calibrate(&doc).result;
    let means: Vec<f64> = r.steps.iter().map(|s| s.error_mm.mean).collect();
    assert_eq!(r.steps.len(), 5, "{means:?}");
    assert!(means[4] < 0.2 && means[2] > 1.0, "{means:?}");
    assert_eq!(r.status, "converged");
    assert!(
        r.held_out
            .as_ref()
            .is_some_and(|h| h.folds == 3 && h.error_mm.mean < 0.3)
    );
    assert!(
        r.warnings.iter().any(|w| w.contains("t_s")),
        "{:?}",
        r.warnings
    );
    let p = r
        .parameters
        .iter()
        .find(|p| p.name == "r1.kx_gz")
        .expect("a lateral coefficient");
    assert_eq!(p.unit, "rad");
    assert!(
        r.parameters
            .iter()
            .any(|p| p.name == format!("r2.{}", GEOMETRY[4]) && p.unit == "m")
    );
    let fields = serde_json::to_value(&r).expect("serialises");
    for f in [
        "steps",
        "parameters",
        "unidentifiable",
        "held_out",
        "error_after_mean_mm",
        "elasticity_note",
    ] {
        assert!(fields.get(f).is_some(), "{f}");
    }
}

#[test]
fn bad_tree_documents_name_the_field() {
    let twin = ElasticTwin::new(&all(), 4, 1e-4, 5);
    let bad = |edit: &dyn Fn(&mut Value), want: &str| {
        let mut doc = twin_job(&twin, json!({}), None);
        edit(&mut doc);
        let e = prepare(&doc, &Inputs::new(&NoReferences))
            .expect_err("refused")
            .to_string();
        assert!(e.contains(want), "{e} should name {want}");
    };
    bad(
        &|d| d["tree"]["convention"] = json!("classic_dh"),
        "tree.convention",
    );
    bad(
        &|d| d["tree"]["rows"][2]["variable"] = json!("q99"),
        "tree.rows[2].variable",
    );
    bad(
        &|d| d["tree"]["rows"][2]["parent"] = json!("nowhere"),
        "tree.rows[2].parent",
    );
    bad(
        &|d| d["options"]["elastic"] = json!({"lateral": ["r_mount"]}),
        "elastic.lateral",
    );
    bad(
        &|d| d["markers"][0]["row"] = json!("elbow"),
        "markers[0].row",
    );
    bad(&|d| d["options"]["folds"] = json!(1), "options.folds");
}

/// The user's prior: a 1 nm prior holds a geometry parameter at nominal (least squares
/// moves it), a 1 km prior changes nothing, K-fold reports its candidates and picks the
/// best, and bad prior options name the field.
#[test]
fn tree_identify_takes_a_user_prior() {
    let twin = ElasticTwin::new(&all(), 60, 1e-4, 5);
    let run = |options: Value| {
        let mut doc = twin_job(&twin, json!({}), None);
        for (k, v) in options.as_object().into_iter().flatten() {
            doc["options"][k] = v.clone();
        }
        calibrate(&doc).result
    };
    let name = format!("r2.{}", GEOMETRY[1]);
    let moved = |r: &TreeCalibration| {
        let p = r
            .parameters
            .iter()
            .find(|p| p.name == name)
            .expect("r2.a is identified");
        p.value - p.nominal
    };
    let ls = run(json!({}));
    assert_eq!(ls.prior.mode, "least_squares");
    assert!(
        moved(&ls).abs() > 1e-5,
        "least squares moved {name} by {}",
        moved(&ls)
    );
    let pinned = run(json!({"prior": {"std": {name.clone(): 1e-9}}, "noise_m": 1e-4}));
    assert_eq!(pinned.prior.mode, "map");
    assert_eq!(pinned.prior.noise, Some(1e-4));
    assert!(moved(&pinned).abs() < 1e-8, "{}", moved(&pinned));
    assert_eq!(pinned.status, "converged");
    // A prior far wider than anything the data leave open: the least-squares fit.
    let wide = run(json!({"prior": {"default_std": {"length_mm": 1e6, "angle_deg": 1e4}}}));
    assert!(wide.prior.count > 0);
    let (a, b) = (ls.error_after_mean_mm, wide.error_after_mean_mm);
    assert!((a - b).abs() < 1e-3 * a, "{a} vs {b} mm");
    let cv = run(
        json!({"prior": {"default_std": {"length_mm": 1.0, "angle_deg": 0.5}},
        "prior_weight": "cv"}),
    );
    assert_eq!(cv.prior.mode, "map_cv");
    let folds = cv.prior.k_fold_errors.as_ref().expect("candidates");
    assert_eq!(folds.len(), 5);
    let best = folds
        .iter()
        .min_by(|x, y| x.rms.total_cmp(&y.rms))
        .expect("five");
    assert_eq!(cv.prior.weight, Some(best.weight));
    println!(
        "{name}: least squares moved {:.3e} m, pinned {:.3e} m; errors LS {a:.4} / wide {b:.4} / cv {:.4} mm; K-fold {:?}",
        moved(&ls),
        moved(&pinned),
        cv.error_after_mean_mm,
        folds.iter().map(|f| (f.weight, f.rms)).collect::<Vec<_>>()
    );
    let refused = |options: Value, want: &str| {
        let mut doc = twin_job(&twin, json!({}), None);
        for (k, v) in options.as_object().into_iter().flatten() {
            doc["options"][k] = v.clone();
        }
        let e = prepare(&doc, &Inputs::new(&NoReferences))
            .expect_err("refused")
            .to_string();
        assert!(e.contains(want), "{e} should name {want}");
    };
    refused(json!({"prior": {"std": {"nope": 1.0}}}), "std.nope");
    refused(json!({"prior": {"std": {name.clone(): -1.0}}}), "-1");
    refused(json!({"prior_weight": 3.0}), "options.prior_weight");
    refused(json!({"prior": {}, "prior_weight": "auto"}), "auto");
    refused(json!({"prior": {}, "noise_m": -2.0}), "options.noise_m");
}

/// The K-fold's coverage on a geometric twin (truth and model without elasticity, 0.1 mm
/// noise per coordinate): with each fold's residual std as the noise, the held-out errors
/// lie within 2 predicted sigma at the expected 0.9545 (400 held-out markers: binomial std
/// 0.010, bound 0.035) and their RMS is the predicted RMS (to 10 %); with a
/// prior far wider than the data and `noise_m` 10 times too small, the coverage falls far
/// below 0.90 and the verdict says the noise model is too optimistic.
#[test]
fn tree_k_fold_coverage_matches_the_noise_model() {
    let twin = ElasticTwin::new(&ElasticOptions::default(), 200, 1e-4, 9);
    let run = |options: Value| {
        let mut doc = twin_job(&twin, json!({}), Some(4));
        for (k, v) in options.as_object().into_iter().flatten() {
            doc["options"][k] = v.clone();
        }
        calibrate(&doc)
    };
    let optimistic = |r: &TreeCalibration| {
        r.assessment
            .reasons
            .iter()
            .any(|x| x.code == "noise_model_optimistic")
    };
    let out = run(json!({}));
    let r = &out.result;
    let c = r.coverage.as_ref().expect("coverage with folds");
    let held = r.held_out.as_ref().expect("held out");
    assert_eq!(c.n, held.error_mm.count);
    assert_eq!(c.unit, "mm");
    assert!((c.noise_std - 0.1).abs() < 0.01, "noise {} mm", c.noise_std);
    println!(
        "correct noise: coverage {:.3} of {}, rms error {:.4} mm, predicted {:.4} mm",
        c.fraction_within_2sigma, c.n, c.rms_error, c.rms_predicted
    );
    assert!(
        (c.fraction_within_2sigma - TWO_SIGMA_PROBABILITY).abs() < 0.035,
        "{}",
        c.fraction_within_2sigma
    );
    assert!((c.rms_predicted / c.rms_error - 1.0).abs() < 0.1);
    assert!(!optimistic(r));
    assert!(
        out.artefacts
            .iter()
            .any(|a| a.name == "predicted_accuracy.svg")
    );
    let small = run(json!({
        "prior": {"default_std": {"length_mm": 1e6, "angle_deg": 1e4}},
        "noise_m": 1e-5
    }))
    .result;
    let c = small.coverage.as_ref().expect("coverage");
    println!(
        "noise 10x too small: coverage {:.3}, predicted rms {:.4} mm",
        c.fraction_within_2sigma, c.rms_predicted
    );
    assert_eq!(c.noise_from, "options.noise_m");
    assert!(
        c.fraction_within_2sigma < 0.3,
        "{}",
        c.fraction_within_2sigma
    );
    assert!(optimistic(&small), "{:?}", small.assessment.reasons);
}

/// `options.robust` on a geometric twin (0.1 mm noise per coordinate) with one gross
/// outlier (a marker 20 mm off in x): the Cauchy refit lists that marker first and only
/// it far down (weight below 0.05), and its 3-fold held-out error (each fold refitted
/// robustly) is below the plain fit's on the same data, which the outlier pulls.
#[test]
fn tree_robust_loss_down_weights_an_outlier_in_the_fit_and_in_every_fold() {
    let twin = ElasticTwin::new(&ElasticOptions::default(), 120, 1e-4, 4);
    let mut doc = twin_job(&twin, json!({}), Some(3));
    let marker = twin.nominal.markers[0].name.clone();
    let x = format!("{marker}_x");
    let v = doc["samples"][17][&x].as_f64().expect("marker x");
    doc["samples"][17][&x] = json!(v + 0.02);
    let plain = calibrate(&doc).result;
    doc["options"]["robust"] = json!({"loss": "cauchy"});
    let robust = calibrate(&doc).result;
    let rob = robust.robust.as_ref().expect("robust outcome");
    let first = &rob.downweighted[0];
    assert_eq!(
        (first.sample, first.marker),
        (17, 0),
        "{:?}",
        rob.downweighted
    );
    assert!(first.weight < 0.05, "weight {}", first.weight);
    assert!(first.error_mm > 15.0, "error {} mm", first.error_mm);
    assert!(
        rob.downweighted.iter().skip(1).all(|d| d.weight > 0.05),
        "{:?}",
        rob.downweighted
    );
    assert_eq!(robust.steps.len(), plain.steps.len() + 1);
    let held = |r: &TreeCalibration| r.held_out.as_ref().expect("held out").error_mm.median;
    println!(
        "held-out median: plain {:.4} mm, cauchy {:.4} mm",
        held(&plain),
        held(&robust)
    );
    assert!(held(&robust) < held(&plain));
}
