//! Reports: SVG plots drawn from a finished job's result JSON and artefacts, in the style
//! of the papers' figures: position error per configuration before and after calibration,
//! histograms of those errors, box plots of a dispersion study, the history of a design's
//! observability criterion. Reports read results,
//! never models; a result without the data a plot needs simply gets no plot.

pub mod coverage;
pub mod drift;
pub mod html;
pub mod json_result;
pub mod plots;
pub mod studies;
pub mod svg;
pub mod view;

use serde::{Deserialize, Serialize};

use crate::run::{Artefact, Table};
pub use json_result::JsonResult;
pub use plots::ErrorSet;
pub use view::Reportable;

/// Serialise a table as JSON rows (`{column: value}` objects, non-finite as null): a
/// `serialize_with` helper for typed results that carry a table.
pub fn json_rows<S: serde::Serializer>(t: &Table, s: S) -> Result<S::Ok, S::Error> {
    t.to_json_rows().serialize(s)
}

/// Read a table serialised by [`json_rows`] back (null as a missing value, NaN): a
/// `deserialize_with` helper for typed results the report reads.
pub fn table_of_json_rows<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Table, D::Error> {
    let v = serde_json::Value::deserialize(d)?;
    Table::from_json_rows_with_gaps("rows", &v, &|_: &str| true).map_err(serde::de::Error::custom)
}

/// The error plots of a calibration as SVG artefacts: per configuration, histogram and
/// cumulative distribution of the calibration set's errors (`what`, e.g. "Position
/// error"), and with a held-out validation set its errors per point and their
/// distribution. Kinds with residuals call it on their own errors.
pub fn calibration_plots(
    what: &str,
    calibration: &ErrorSet<'_>,
    validation: Option<&ErrorSet<'_>>,
) -> Vec<Artefact> {
    let mut out = vec![
        svg_artefact(
            "errors_per_configuration.svg",
            plots::per_configuration(what, calibration),
        ),
        svg_artefact("error_histogram.svg", plots::histogram(calibration, 4)),
        svg_artefact("error_cdf.svg", plots::cdf(calibration)),
    ];
    if let Some(v) = validation.filter(|v| !v.before.is_empty() || !v.after.is_empty()) {
        out.push(svg_artefact(
            "validation_errors.svg",
            plots::per_configuration(&format!("Held-out {}", what.to_lowercase()), v),
        ));
        out.push(svg_artefact("validation_cdf.svg", plots::cdf(v)));
    }
    out
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

/// Series names of the dispersion box plots (`data-series`).
pub const DISPERSION_MEAN: &str = "mean_error";
/// Series name of the box plots of the std of the validation error.
pub const DISPERSION_STD: &str = "std_error";

/// Box plots of a dispersion study (mean and std of the validation error per set size, on
/// a log error axis: the TriCal Table 7 view), as SVG artefacts; none when there is no size.
/// `runs` is the number of identifications the boxes summarise.
pub fn dispersion_plots(sizes: &[DispersionBox], unit: &str, runs: usize) -> Vec<Artefact> {
    if sizes.is_empty() {
        return Vec::new();
    }
    let mean: Vec<(f64, [f64; 5])> = sizes.iter().map(|s| (s.n, s.mean_error)).collect();
    let std: Vec<(f64, [f64; 5])> = sizes.iter().map(|s| (s.n, s.std_error)).collect();
    let dataset = format!(
        "validation set errors of {runs} identifications (DETMAX selections from random starts), one box per set size"
    );
    vec![
        svg_artefact(
            "dispersion_mean_error.svg",
            studies::boxplots_log(
                &mean,
                "Mean validation error",
                DISPERSION_MEAN,
                &dataset,
                unit,
            ),
        ),
        svg_artefact(
            "dispersion_std_error.svg",
            studies::boxplots_log(
                &std,
                "Std of validation error",
                DISPERSION_STD,
                &dataset,
                unit,
            ),
        ),
    ]
}

/// An SVG document as an artefact named `name`.
pub fn svg_artefact(name: &str, svg: String) -> Artefact {
    Artefact {
        name: name.into(),
        media_type: "image/svg+xml".into(),
        content: svg.into_bytes(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn calibration_and_dispersion_plots_draw_every_value() {
        let set = ErrorSet {
            before: &[1.5, 2.0],
            after: &[0.05, 0.04],
            unit: "mm",
            dataset: "calibration set",
        };
        let p = calibration_plots("Position error", &set, None);
        let names: Vec<&str> = p.iter().map(|a| a.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "errors_per_configuration.svg",
                "error_histogram.svg",
                "error_cdf.svg"
            ]
        );
        let svg = String::from_utf8(p[0].content.clone()).unwrap_or_default();
        assert_eq!(svg::series_marks(&svg, plots::BEFORE).len(), 2);
        assert_eq!(svg::series_marks(&svg, plots::AFTER).len(), 2);
        let v = ErrorSet {
            dataset: "validation set",
            ..set
        };
        assert_eq!(calibration_plots("Position error", &set, Some(&v)).len(), 5);
        let q = [1.0, 2.0, 3.0, 4.0, 5.0];
        let boxes = [DispersionBox {
            n: 20.0,
            mean_error: q,
            std_error: q,
        }];
        let p = dispersion_plots(&boxes, "mm", 5);
        assert_eq!(p.len(), 2);
        assert!(
            String::from_utf8(p[0].content.clone())
                .unwrap_or_default()
                .contains(">20</text>")
        );
        assert!(dispersion_plots(&[], "mm", 0).is_empty());
    }
}
