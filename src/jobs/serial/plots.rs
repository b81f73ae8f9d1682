//! The artefacts a serial identification draws from its own errors: `residuals.csv` and
//! the plots of [`crate::report`] (per configuration, histogram, distribution, per axis,
//! held-out validation).

use crate::report::{ErrorSet, calibration_plots, plots, svg_artefact};
use crate::run::{Artefact, Table};

/// What a serial identification hands to its plots.
#[derive(Debug, Default)]
pub(crate) struct ResidualPlots<'a> {
    /// Error magnitude per calibration measurement, nominal model.
    pub before: &'a [f64],
    /// Error magnitude per calibration measurement, calibrated model.
    pub after: &'a [f64],
    /// Length unit.
    pub unit: &'a str,
    /// What the errors are ("Position error", "Distance error").
    pub what: &'a str,
    /// Held-out validation errors (nominal, calibrated), when there was a validation set.
    pub validation: Option<(Vec<f64>, Vec<f64>)>,
    /// RMS of the x, y, z residual components (nominal, calibrated).
    pub per_axis: Option<([f64; 3], [f64; 3])>,
}

/// RMS of the x, y, z components of stacked 3-vectors.
pub(crate) fn axis_rms(r: &[f64]) -> [f64; 3] {
    let n = (r.len() / 3).max(1) as f64;
    let mut s = [0.0; 3];
    for (k, v) in r.iter().enumerate() {
        s[k % 3] += v * v;
    }
    s.map(|v| (v / n).sqrt())
}

/// `residuals.csv` (measurement, before, after) and the plots drawn from the same columns.
pub(crate) fn residual_artefacts(p: &ResidualPlots<'_>) -> Vec<Artefact> {
    let mut res = Table::new(&["measurement", "before", "after"]);
    for (i, (a, b)) in p.before.iter().zip(p.after).enumerate() {
        res.push(vec![(i + 1) as f64, *a, *b]);
    }
    let mut out = vec![Artefact {
        name: "residuals.csv".into(),
        media_type: "text/csv".into(),
        content: res.to_csv().into_bytes(),
    }];
    // The plots read the CSV's columns: equal lengths, magnitudes (a log axis).
    let n = p.before.len().min(p.after.len());
    let abs = |v: &[f64]| -> Vec<f64> { v.iter().map(|x| x.abs()).collect() };
    let (b, a) = (abs(&p.before[..n]), abs(&p.after[..n]));
    let cal_label = format!("calibration set: {n} measurements (the residuals of the fit)");
    let cal = ErrorSet {
        before: &b,
        after: &a,
        unit: p.unit,
        dataset: &cal_label,
    };
    let val_label;
    let val = match &p.validation {
        Some((vb, va)) => {
            val_label = format!(
                "validation set: {} held-out measurements (not used in the fit)",
                vb.len()
            );
            Some(ErrorSet {
                before: vb,
                after: va,
                unit: p.unit,
                dataset: &val_label,
            })
        }
        None => None,
    };
    out.extend(calibration_plots(p.what, &cal, val.as_ref()));
    if let Some((rb, ra)) = p.per_axis {
        let axes = ["x".to_string(), "y".into(), "z".into()];
        out.push(svg_artefact(
            "errors_per_axis.svg",
            plots::before_after_bars(
                "RMS residual per axis of {W} (log scale)",
                &cal_label,
                &format!("RMS residual ({})", p.unit),
                &axes,
                &rb.map(Some),
                &ra.map(Some),
            ),
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_rms_takes_every_third_component() {
        let r = [3.0, 0.0, 1.0, 4.0, 0.0, 1.0];
        let [x, y, z] = axis_rms(&r);
        assert!((x - 12.5f64.sqrt()).abs() < 1e-12);
        assert_eq!((y, z), (0.0, 1.0));
    }
}
