//! `pcr.identify` with a Gaussian prior (MAP) on the example twin, whose true parameters
//! were drawn from the model file's standard uncertainties: the MAP fit converges and keeps
//! the least-squares accuracy; a very tight prior reproduces the nominal model with fitted
//! frames (a second computation in the same result); the reported prior term equals the one
//! recomputed from the reported parameters; the K-fold weight is the candidate with the
//! smallest held-out error; bad prior options are refused by name.

use crate::common;

use common::{example, prepare_in_examples, run_in_examples};
use serde_json::{Value, json};

fn num(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

fn identify(options: Value) -> Value {
    let mut doc = example("pcr_identify.json");
    if let (Some(o), Some(extra)) = (doc["options"].as_object_mut(), options.as_object()) {
        for (k, v) in extra {
            o.insert(k.clone(), v.clone());
        }
    }
    run_in_examples(&doc).expect("identify").result
}

fn param<'a>(r: &'a Value, name: &str) -> &'a Value {
    r["parameters"]
        .as_array()
        .and_then(|ps| ps.iter().find(|p| p["name"] == name))
        .unwrap_or_else(|| panic!("no parameter {name}"))
}

#[test]
fn map_with_the_file_uncertainty_converges_and_keeps_the_accuracy() {
    let ls = identify(json!({}));
    let map = identify(json!({"prior": {}}));
    assert_eq!(ls["prior"]["mode"], "least_squares");
    assert_eq!(map["prior"]["mode"], "map");
    assert_eq!(map["prior"]["weight"], 1.0);
    // Every robot parameter with a non-zero file uncertainty carries the prior (28 of 28
    // in this file); the extrinsics are nuisance unknowns without one.
    assert_eq!(map["prior"]["count"], 28);
    assert_eq!(map["convergence"]["converged"], true, "{}", map["steps"]);
    let (v_ls, v_map) = (
        num(&ls["validation"]["after"]["mean"]),
        num(&map["validation"]["after"]["mean"]),
    );
    println!(
        "validation mean: least squares {:.2} nm, MAP {:.2} nm",
        v_ls * 1e9,
        v_map * 1e9
    );
    assert!(v_map < 20e-9 && v_map <= 1.05 * v_ls, "{v_map} vs {v_ls}");
    // The prior term as reported equals the one recomputed from the reported parameters:
    // sigma = (upper - lower) / (2 * 3) (bounds are nominal +/- 3 sigma).
    let mut recomputed = 0.0;
    for p in map["parameters"].as_array().expect("parameters") {
        let name = p["name"].as_str().unwrap_or("");
        if ["sx", "sy", "stheta", "mx", "my", "mtheta"].contains(&name) {
            continue;
        }
        let sigma = (num(&p["upper"]) - num(&p["lower"])) / 6.0;
        recomputed += ((num(&p["value"]) - num(&p["nominal"])) / sigma).powi(2);
    }
    let reported = num(&map["prior"]["prior_cost"]);
    assert!(
        (reported - recomputed).abs() < 1e-9 * recomputed.max(1.0),
        "{reported} vs {recomputed}"
    );
    assert!(num(&map["prior"]["objective"]) > reported);
}

#[test]
fn a_tight_prior_holds_parameters_at_nominal() {
    let ls = identify(json!({}));
    // One parameter pinned: l_1 moves in least squares, not under a 1 pm prior.
    let pinned = identify(json!({"prior": {"std": {"l_1": 1e-12}}}));
    let moved = |r: &Value| num(&param(r, "l_1")["value"]) - num(&param(r, "l_1")["nominal"]);
    assert!(
        moved(&ls).abs() > 1e-7,
        "least squares moved l_1 by {}",
        moved(&ls)
    );
    assert!(moved(&pinned).abs() < 1e-11, "{}", moved(&pinned));
    assert_eq!(pinned["convergence"]["converged"], true);
    // Every robot parameter pinned (weight 1e16: the prior row of one standard uncertainty is 1e8 times the noise): the fit is
    // the nominal model with its frames fitted, which the result also computes on its own.
    let all = identify(json!({"prior": {}, "prior_weight": 1e16}));
    let e = &all["model_error"]["calibration"]["e_P"];
    let (nominal, identified) = (num(&e["nominal"]["mean"]), num(&e["identified"]["mean"]));
    assert!(
        (identified - nominal).abs() < 1e-3 * nominal,
        "{identified} vs {nominal} um"
    );
}

#[test]
fn k_fold_picks_the_candidate_with_the_smallest_held_out_error() {
    let r = identify(json!({"prior": {}, "prior_weight": "cv"}));
    assert_eq!(r["prior"]["mode"], "map_cv");
    let folds = r["prior"]["k_fold_errors"]
        .as_array()
        .expect("k_fold_errors");
    assert_eq!(folds.len(), 5);
    let best = folds
        .iter()
        .min_by(|a, b| num(&a["rms"]).total_cmp(&num(&b["rms"])))
        .expect("candidates");
    assert_eq!(r["prior"]["weight"], best["weight"]);
    // Held out, the errors are at the noise level (nanometres), not the nominal model's.
    assert!(folds.iter().all(|f| num(&f["rms"]) < 50e-9), "{folds:?}");
    assert_eq!(r["convergence"]["converged"], true);
}

#[test]
fn bad_prior_options_are_refused_by_name() {
    let refused = |options: Value| {
        let mut doc = example("pcr_identify.json");
        doc["options"] = options;
        prepare_in_examples(&doc).expect_err("refused").to_string()
    };
    let e = refused(json!({"prior_weight": 2.0}));
    assert!(
        e.contains("options.prior_weight") && e.contains("needs options.prior"),
        "{e}"
    );
    let e = refused(json!({"prior": {"std": {"l_9": 1e-6}}}));
    assert!(
        e.contains("options.prior.std.l_9") && e.contains("no such unknown"),
        "{e}"
    );
    let e = refused(json!({"prior": {"std": {"l_1": -1.0}}}));
    assert!(
        e.contains("options.prior.std.l_1") && e.contains("-1"),
        "{e}"
    );
    let e = refused(json!({"prior": {}, "prior_weight": "auto"}));
    assert!(
        e.contains("options.prior_weight") && e.contains("auto"),
        "{e}"
    );
    let e = refused(json!({"prior": {}, "noise_m": 0.0}));
    assert!(e.contains("options.noise_m"), "{e}");
    let e = refused(json!({"prior": {"mean": {}}}));
    assert!(e.contains("mean"), "{e}");
}
