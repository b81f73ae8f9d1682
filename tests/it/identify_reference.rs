//! The identification examples give the same parameters as before the faer kernels (issue
//! 17, item 4): values and standard deviations unchanged to 1e-9 relative, the same
//! parameters identifiable. The reference values in `tests/data/identify_reference.json`
//! were computed by calibd at commit ad98d36 (nalgebra kernels only, release build; the serial
//! example again when serial fits became nearly linear LM fits, issue 35). The
//! PCR example is checked on release builds only (`calibd run`): its shooting model gives
//! values 2.7e-7 apart between the dev and release profiles, with or without faer.

use crate::common;

use serde_json::Value;

/// `|a - b| <= tol * max(|a|, |b|)`, or both exactly zero.
fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol * a.abs().max(b.abs())
}

#[test]
fn example_identifications_are_unchanged_to_1e_9() {
    let text = std::fs::read_to_string(common::data().join("identify_reference.json"))
        .expect("reference file");
    let reference: Value = serde_json::from_str(&text).expect("reference JSON");
    let examples = reference["examples"].as_object().expect("examples");
    assert_eq!(examples.len(), 4);
    let mut worst = (0.0_f64, String::new());
    let mut failures = Vec::new();
    for (file, params) in examples {
        let result = common::run_in_examples(&common::example(file))
            .unwrap_or_else(|e| panic!("{file}: {e}"))
            .result;
        let got = result["parameters"].as_array().expect("parameters");
        let want = params.as_array().expect("reference parameters");
        assert_eq!(got.len(), want.len(), "{file}");
        for (g, w) in got.iter().zip(want) {
            let name = w["name"].as_str().expect("name");
            assert_eq!(g["name"].as_str(), Some(name), "{file}");
            assert_eq!(g["identifiable"], w["identifiable"], "{file} {name}");
            for field in ["value", "std"] {
                match (g[field].as_f64(), w[field].as_f64()) {
                    (Some(a), Some(b)) => {
                        let rel = (a - b).abs() / a.abs().max(b.abs()).max(f64::MIN_POSITIVE);
                        if rel > worst.0 {
                            worst = (rel, format!("{file} {name}.{field}"));
                        }
                        if !close(a, b, 1e-9) {
                            failures.push(format!("{file} {name}.{field}: {a} vs {b} ({rel:.1e})"));
                        }
                    }
                    (None, None) => {}
                    (a, b) => panic!("{file} {name}.{field}: {a:?} vs {b:?}"),
                }
            }
        }
    }
    eprintln!("largest relative change: {:.2e} ({})", worst.0, worst.1);
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
