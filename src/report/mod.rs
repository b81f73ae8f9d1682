//! Reports: SVG plots drawn from a finished job's result JSON and artefacts, in the style
//! of the papers' figures: position error per configuration before and after calibration,
//! histograms of those errors, and box plots of a dispersion study. Reports read results,
//! never models; a result without the data a plot needs simply gets no plot.

pub mod svg;

use serde::Serialize;
use serde_json::Value;

use crate::jobs::{Artefact, JobError, Output, Table};
use svg::{COLOURS, Chart};

/// A kind's typed result with its main table and artefacts (plots included): what the
/// campaigns and the service read instead of the JSON fields.
#[derive(Debug, Clone)]
pub struct Run<T> {
    /// The typed result; its serialisation is the job's result fields.
    pub result: T,
    /// The table `calibd run --out FILE.csv` writes.
    pub main_table: Option<Table>,
    /// Artefacts (files, CSV tables, SVG plots).
    pub artefacts: Vec<Artefact>,
}

impl<T: Serialize> Run<T> {
    /// The job output: the result serialised as the fields map, the table and artefacts.
    pub fn into_output(self) -> Result<Output, JobError> {
        let fields = match serde_json::to_value(&self.result)
            .map_err(|e| JobError::Failed(format!("serialising the result: {e}")))?
        {
            Value::Object(m) => m,
            other => {
                return Err(JobError::Failed(format!(
                    "the result serialised to {other}, not an object"
                )));
            }
        };
        Ok(Output {
            fields,
            main_table: self.main_table,
            artefacts: self.artefacts,
        })
    }
}

/// Serialise a table as JSON rows (`{column: value}` objects, non-finite as null): a
/// `serialize_with` helper for typed results that carry a table.
pub fn json_rows<S: serde::Serializer>(t: &Table, s: S) -> Result<S::Ok, S::Error> {
    t.to_json_rows().serialize(s)
}

/// Plots of per-measurement errors before and after calibration (bars per configuration
/// and a histogram), as SVG artefacts; kinds with residuals call it on their own errors.
pub fn calibration_plots(before: &[f64], after: &[f64], unit: &str) -> Vec<Artefact> {
    vec![
        svg_artefact(
            "errors_per_configuration.svg",
            per_configuration(before, after, unit),
        ),
        svg_artefact("error_histogram.svg", histogram(before, after, unit, 20)),
    ]
}

/// One set size of a dispersion study, as the plots read it: quartiles (min, q1, median,
/// q3, max) of the mean and std of the validation error.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DispersionBox {
    /// Configurations in the calibration set.
    pub n: f64,
    /// Quartiles of the mean validation error.
    pub mean_error: [f64; 5],
    /// Quartiles of the std of the validation error.
    pub std_error: [f64; 5],
}

/// Box plots of a dispersion study (mean and std of the validation error per set size),
/// as SVG artefacts; none when there is no size.
pub fn dispersion_plots(sizes: &[DispersionBox], unit: &str) -> Vec<Artefact> {
    if sizes.is_empty() {
        return Vec::new();
    }
    let mean: Vec<(f64, [f64; 5])> = sizes.iter().map(|s| (s.n, s.mean_error)).collect();
    let std: Vec<(f64, [f64; 5])> = sizes.iter().map(|s| (s.n, s.std_error)).collect();
    vec![
        svg_artefact(
            "dispersion_mean_error.svg",
            boxplots(&mean, "Mean validation error", unit),
        ),
        svg_artefact(
            "dispersion_std_error.svg",
            boxplots(&std, "Std of validation error", unit),
        ),
    ]
}

fn svg_artefact(name: &str, svg: String) -> Artefact {
    Artefact {
        name: name.into(),
        media_type: "image/svg+xml".into(),
        content: svg.into_bytes(),
    }
}

fn max_of(v: &[f64]) -> f64 {
    v.iter()
        .copied()
        .filter(|x| x.is_finite())
        .fold(0.0, f64::max)
}

/// Bars of the error of every configuration, before (behind) and after calibration.
pub fn per_configuration(before: &[f64], after: &[f64], unit: &str) -> String {
    let n = before.len().max(after.len());
    let top = max_of(before).max(max_of(after)) * 1.05;
    let mut c = Chart::new(
        "Position error per configuration",
        "configuration",
        &format!("error ({unit})"),
        (0.5, n as f64 + 0.5),
        (0.0, top),
    );
    for (k, v) in before.iter().enumerate() {
        c.bar(k as f64 + 0.6, k as f64 + 1.4, *v, COLOURS[0], 0.8);
    }
    for (k, v) in after.iter().enumerate() {
        c.bar(k as f64 + 0.75, k as f64 + 1.25, *v, COLOURS[1], 1.0);
    }
    c.x_ticks();
    c.legend("before calibration", COLOURS[0]);
    c.legend("after calibration", COLOURS[1]);
    c.finish()
}

/// Counts of `values` in `bins` equal bins over [0, hi).
pub fn bin_counts(values: &[f64], hi: f64, bins: usize) -> Vec<usize> {
    let mut counts = vec![0; bins];
    for v in values.iter().filter(|v| v.is_finite()) {
        let k = ((v / hi) * bins as f64)
            .floor()
            .clamp(0.0, (bins - 1) as f64) as usize;
        counts[k] += 1;
    }
    counts
}

/// Histograms of the errors before and after, on the same bins.
pub fn histogram(before: &[f64], after: &[f64], unit: &str, bins: usize) -> String {
    let hi = max_of(before).max(max_of(after)).max(f64::MIN_POSITIVE);
    let (cb, ca) = (bin_counts(before, hi, bins), bin_counts(after, hi, bins));
    let top = cb.iter().chain(ca.iter()).copied().max().unwrap_or(1) as f64 * 1.1;
    let mut c = Chart::new(
        "Histogram of position errors",
        &format!("error ({unit})"),
        "configurations",
        (0.0, hi),
        (0.0, top),
    );
    let w = hi / bins as f64;
    for (k, n) in cb.iter().enumerate() {
        c.bar(k as f64 * w, (k + 1) as f64 * w, *n as f64, COLOURS[0], 0.6);
    }
    for (k, n) in ca.iter().enumerate() {
        c.bar(k as f64 * w, (k + 1) as f64 * w, *n as f64, COLOURS[1], 0.6);
    }
    c.x_ticks();
    c.legend("before calibration", COLOURS[0]);
    c.legend("after calibration", COLOURS[1]);
    c.finish()
}

/// Box plots (min, q1, median, q3, max) per set size.
pub fn boxplots(boxes: &[(f64, [f64; 5])], title: &str, unit: &str) -> String {
    let top = boxes.iter().map(|b| b.1[4]).fold(0.0, f64::max) * 1.05;
    let k = boxes.len() as f64;
    let mut c = Chart::new(
        &format!("{title} per number of configurations"),
        "configurations in the calibration set",
        &format!("{title} ({unit})"),
        (0.5, k + 0.5),
        (0.0, top),
    );
    for (i, (n, q)) in boxes.iter().enumerate() {
        let x = i as f64 + 1.0;
        c.boxplot(x, 0.5, *q, COLOURS[2]);
        let p = c.px(x);
        c.x_label_at(p, &format!("{n}"));
    }
    c.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_counts_every_value_once() {
        let v = [0.0, 0.1, 0.24, 0.25, 0.99, 1.0];
        // Bins of 0.25 over [0, 1): the maximum falls in the last bin.
        assert_eq!(bin_counts(&v, 1.0, 4), vec![3, 1, 0, 2]);
        assert_eq!(bin_counts(&v, 1.0, 4).iter().sum::<usize>(), v.len());
    }

    #[test]
    fn calibration_and_dispersion_plots_draw_every_value() {
        let p = calibration_plots(&[1.5, 2.0], &[0.05, 0.04], "mm");
        let names: Vec<&str> = p.iter().map(|a| a.name.as_str()).collect();
        assert_eq!(
            names,
            ["errors_per_configuration.svg", "error_histogram.svg"]
        );
        let svg = String::from_utf8(p[0].content.clone()).unwrap();
        // Two before bars and two after bars.
        assert_eq!(svg.matches("<rect x=").count(), 4 + 2, "{svg}");
        let q = [1.0, 2.0, 3.0, 4.0, 5.0];
        let boxes = [DispersionBox {
            n: 20.0,
            mean_error: q,
            std_error: q,
        }];
        let p = dispersion_plots(&boxes, "mm");
        assert_eq!(p.len(), 2);
        assert!(
            String::from_utf8(p[0].content.clone())
                .unwrap()
                .contains(">20</text>")
        );
        assert!(dispersion_plots(&[], "mm").is_empty());
    }
}
