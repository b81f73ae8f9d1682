//! The predicted-accuracy plot of an identification: per held-out point, the measured error
//! against its predicted RMS length (parameter covariance and noise), points beyond their
//! predicted 2-sigma region marked apart.

use super::svg::{Frame, Scale, log_range};
use crate::identify::coverage::Coverage;

/// Series of the points within their predicted 2 sigma.
pub const WITHIN: &str = "within_2sigma";
/// Series of the points beyond it.
pub const BEYOND: &str = "beyond_2sigma";
/// Series of the line `measured = predicted`.
pub const EQUAL: &str = "measured_equals_predicted";

/// `predicted_accuracy.svg`: measured held-out error (y) against predicted RMS error (x),
/// both log scale, with the line where they are equal.
pub fn predicted_accuracy(c: &Coverage) -> String {
    let xs: Vec<f64> = c.points.iter().map(|p| p.predicted_rms).collect();
    let ys: Vec<f64> = c.points.iter().map(|p| p.error.max(1e-12)).collect();
    let range = log_range(xs.iter().chain(&ys));
    let dataset = format!(
        "{} held-out points: {:.1} % within 2 predicted sigma (expected {:.1} %, noise std {:.4} {} from {})",
        c.n,
        100.0 * c.fraction_within_2sigma,
        100.0 * c.expected,
        c.noise_std,
        c.unit,
        c.noise_from
    );
    let mut ch = Frame::new(
        "Predicted accuracy: measured against predicted error per held-out point",
        &dataset,
        &format!("predicted RMS error ({})", c.unit),
        &format!("measured error ({})", c.unit),
    )
    .x(range, Scale::Log)
    .y(range, Scale::Log)
    .chart();
    ch.line(EQUAL, &[(range.0, range.0), (range.1, range.1)], "#888888");
    ch.legend("measured = predicted RMS", "#888888");
    let pick = |within: bool| -> Vec<(f64, f64)> {
        c.points
            .iter()
            .zip(xs.iter().zip(&ys))
            .filter(|(p, _)| p.within_2sigma == within)
            .map(|(_, (x, y))| (*x, *y))
            .collect()
    };
    ch.points(WITHIN, &pick(true), "#1f77b4");
    ch.legend("within 2 predicted sigma", "#1f77b4");
    ch.points(BEYOND, &pick(false), "#d62728");
    ch.legend("beyond 2 predicted sigma", "#d62728");
    ch.finish()
}
