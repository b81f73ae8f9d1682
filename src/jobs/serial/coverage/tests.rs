//! Coverage of the IRB 120 twin's held-out tracker points (`examples/serial_identify.json`).

use serde_json::{Value, json};

use crate::jobs::serial::identify::{SerialCalibration, prepare};
use crate::run::{DirResolver, Inputs};
use crate::util::monitor::NoMonitor;

fn example(noise: f64) -> SerialCalibration {
    let dir = std::path::PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/examples"));
    let text = std::fs::read_to_string(dir.join("serial_identify.json")).expect("example job");
    let mut doc: Value = serde_json::from_str(&text).expect("json");
    doc["options"]["noise"] = json!(noise);
    let job = prepare(&doc, &Inputs::new(&DirResolver { dir })).expect("a valid job");
    job.calibrate(&NoMonitor)
        .expect("the identification runs")
        .result
}

/// With the twin's noise (0.010 mm) at least 90 % of the 200 tracker points lie within
/// their predicted 2 sigma, and the prediction is the model's covariance plus the noise.
#[test]
fn the_twin_tracker_points_are_covered_by_their_predicted_two_sigma() {
    let r = example(0.010);
    let c = r.coverage.as_ref().expect("coverage");
    println!(
        "IRB 120 twin: {:.3} of {} within 2 sigma, mean predicted RMS {:.4} mm (model {:.4}), mean error {:.4} mm",
        c.fraction_within_2sigma,
        c.n,
        c.points.iter().map(|p| p.predicted_rms).sum::<f64>() / c.n as f64,
        c.points.iter().map(|p| p.model_rms).sum::<f64>() / c.n as f64,
        c.points.iter().map(|p| p.error).sum::<f64>() / c.n as f64,
    );
    assert_eq!(c.n, 200);
    assert_eq!(c.noise_from, "options.noise");
    assert!(
        c.fraction_within_2sigma >= 0.9,
        "{}",
        c.fraction_within_2sigma
    );
    assert!(
        !r.assessment.has("noise_model_optimistic"),
        "{:?}",
        r.assessment
    );
    // The errors are the validation's.
    let v = r.validation.as_ref().expect("validation");
    let mean = c.points.iter().map(|p| p.error).sum::<f64>() / c.n as f64;
    assert!(
        (mean - v.after.mean).abs() < 1e-9,
        "{mean} vs {}",
        v.after.mean
    );
    // Predicted RMS^2 = model part + 3 noise^2.
    for p in &c.points {
        let expect = (p.model_rms.powi(2) + 3.0 * 0.010f64.powi(2)).sqrt();
        assert!((p.predicted_rms - expect).abs() < 1e-12);
    }
}

/// A noise stated 10 times too small (0.001 mm) covers far fewer held-out errors: the
/// verdict says the noise model is too optimistic.
#[test]
fn a_noise_ten_times_too_small_is_flagged_as_optimistic() {
    let r = example(0.001);
    let c = r.coverage.as_ref().expect("coverage");
    println!(
        "noise 0.001 mm: {:.3} within 2 sigma",
        c.fraction_within_2sigma
    );
    assert!(
        c.fraction_within_2sigma < 0.9,
        "{}",
        c.fraction_within_2sigma
    );
    assert!(
        r.assessment.has("noise_model_optimistic"),
        "{:?}",
        r.assessment
    );
    assert_ne!(r.assessment.verdict, crate::identify::Verdict::Accepted);
}
