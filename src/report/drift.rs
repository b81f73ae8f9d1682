//! The drift chart of a cell: the compensated AP and RP of each verification in order, the
//! policy's AP threshold, and a marker where the last calibration was adopted.

use super::svg::{COLOURS, Chart};

/// One verification on the chart.
#[derive(Debug, Clone, PartialEq)]
pub struct DriftSample {
    /// Label under the x axis (e.g. the date).
    pub label: String,
    /// Compensated AP (mm).
    pub ap_mm: Option<f64>,
    /// Compensated RP (mm).
    pub rp_mm: Option<f64>,
    /// The first verification after the last calibration.
    pub after_calibration: bool,
}

/// AP and RP per verification (x: verification number) with the threshold (mm) if any.
pub fn drift_chart(cell: &str, samples: &[DriftSample], threshold_mm: Option<f64>) -> String {
    let values = samples
        .iter()
        .flat_map(|s| [s.ap_mm, s.rp_mm])
        .flatten()
        .chain(threshold_mm);
    let top = values.fold(0.0f64, f64::max).max(1e-3) * 1.15;
    let n = samples.len().max(1) as f64;
    let mut c = Chart::new(
        &format!("Drift of {cell}: verifications against the last calibration"),
        "verification",
        "mm",
        (0.5, n + 0.5),
        (0.0, top),
    );
    let series = |f: fn(&DriftSample) -> Option<f64>| -> Vec<(f64, f64)> {
        samples
            .iter()
            .enumerate()
            .filter_map(|(i, s)| f(s).map(|v| ((i + 1) as f64, v)))
            .collect()
    };
    let ap = series(|s| s.ap_mm);
    let rp = series(|s| s.rp_mm);
    c.line("ap", &ap, COLOURS[1]);
    c.points("ap", &ap, COLOURS[1]);
    c.legend("AP (compensated)", COLOURS[1]);
    c.line("rp", &rp, COLOURS[2]);
    c.points("rp", &rp, COLOURS[2]);
    c.legend("RP (compensated)", COLOURS[2]);
    if let Some(t) = threshold_mm {
        c.line("threshold", &[(0.5, t), (n + 0.5, t)], COLOURS[0]);
        c.legend("AP threshold", COLOURS[0]);
    }
    if let Some(i) = samples.iter().position(|s| s.after_calibration) {
        let x = i as f64 + 0.5;
        c.line("calibration", &[(x, 0.0), (x, top)], COLOURS[3]);
        c.legend("last calibration", COLOURS[3]);
    }
    for (i, s) in samples.iter().enumerate() {
        let p = c.px((i + 1) as f64);
        c.x_label_at(p, &s.label);
    }
    c.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_chart_draws_each_value_at_its_verification() {
        let s = |ap: f64, after| DriftSample {
            label: "n".into(),
            ap_mm: Some(ap),
            rp_mm: Some(0.001),
            after_calibration: after,
        };
        let svg = drift_chart(
            "irb120",
            &[s(0.01, false), s(0.02, true), s(0.08, false)],
            Some(0.05),
        );
        let got: Vec<f64> = crate::report::svg::series_marks(&svg, "ap")
            .iter()
            .map(|m| m.value)
            .collect();
        assert_eq!(got, vec![0.01, 0.02, 0.08]);
        assert!(svg.contains(r#"data-series="threshold""#) && svg.contains("last calibration"));
    }
}
