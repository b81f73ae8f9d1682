//! The plots of a humanoid calibration, drawn with [`crate::report`]: marker RMSE per
//! marker and per posture before and after, the share of the geometric and the elastic
//! model (RMSE of each fit), the distribution of the marker errors and the held-out
//! cross-validation RMSE per fold; for a design, the O1 history of NOCP or COCP.

use super::design::HumanoidDesign;
use super::identify_result::HumanoidCalibration;
use crate::report::plots::{self, Series};
use crate::report::studies::{self, History};
use crate::report::{ErrorSet, svg_artefact};
use crate::run::Artefact;

/// One marker observation's error before and after (mm), with its sample row.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Observation {
    /// Row of the sample in the measurement table.
    pub row: usize,
    /// Error of the nominal model with fitted frames (mm).
    pub before_mm: f64,
    /// Error of the calibrated model (mm).
    pub after_mm: f64,
}

fn rms(v: impl Iterator<Item = f64>) -> Option<f64> {
    let (mut s, mut n) = (0.0, 0usize);
    for x in v {
        s += x * x;
        n += 1;
    }
    (n > 0).then(|| (s / n as f64).sqrt())
}

/// The SVG artefacts of a humanoid calibration.
pub(crate) fn humanoid_plots(r: &HumanoidCalibration, obs: &[Observation]) -> Vec<Artefact> {
    let n_samples = {
        let mut rows: Vec<usize> = obs.iter().map(|o| o.row).collect();
        rows.dedup();
        rows.len()
    };
    let cal = format!(
        "calibration set: {n_samples} postures, {} marker observations",
        obs.len()
    );
    let names: Vec<String> = r.markers.iter().map(|m| m.name.clone()).collect();
    let before: Vec<Option<f64>> = r.markers.iter().map(|m| m.rmse_before_mm).collect();
    let after: Vec<Option<f64>> = r.markers.iter().map(|m| m.rmse_after_mm).collect();
    let mut out = vec![svg_artefact(
        "marker_rmse.svg",
        plots::before_after_bars(
            "RMSE per marker (log scale)",
            &cal,
            "marker RMSE (mm)",
            &names,
            &before,
            &after,
        ),
    )];
    // Per posture, in table order.
    let mut rows: Vec<usize> = obs.iter().map(|o| o.row).collect();
    rows.sort_unstable();
    rows.dedup();
    let per = |f: fn(&Observation) -> f64| -> Vec<Option<f64>> {
        rows.iter()
            .map(|row| rms(obs.iter().filter(|o| o.row == *row).map(f)))
            .collect()
    };
    out.push(svg_artefact(
        "posture_rmse.svg",
        plots::before_after_bars(
            "RMSE per posture (log scale)",
            &cal,
            "marker RMSE over the posture (mm)",
            &rows.iter().map(|r| format!("row {r}")).collect::<Vec<_>>(),
            &per(|o| o.before_mm),
            &per(|o| o.after_mm),
        ),
    ));
    // Geometric vs elastic: the RMSE each model reaches on the same data.
    let mut models = vec!["frames only (nominal)".to_string()];
    let mut rmse = vec![Some(r.frames_only.rmse_after_mm)];
    if let Some(g) = &r.geometric_only {
        models.push("+ joint geometry".into());
        rmse.push(Some(g.rmse_after_mm));
    }
    models.push("+ geometry and elasticity (result)".into());
    rmse.push(Some(r.rmse_after_mm));
    out.push(svg_artefact(
        "rmse_by_model.svg",
        plots::category_bars(
            "Marker RMSE of each model: geometric and elastic share (log scale)",
            &cal,
            "marker RMSE (mm)",
            &models,
            &[Series {
                name: "rmse",
                legend: "RMSE after fitting the model",
                values: &rmse,
            }],
        ),
    ));
    let (b, a): (Vec<f64>, Vec<f64>) = obs.iter().map(|o| (o.before_mm, o.after_mm)).unzip();
    let set = ErrorSet {
        before: &b,
        after: &a,
        unit: "mm",
        dataset: &cal,
    };
    out.push(svg_artefact(
        "error_histogram.svg",
        plots::histogram(&set, 4),
    ));
    out.push(svg_artefact("error_cdf.svg", plots::cdf(&set)));
    if let Some(cv) = &r.cross_validation {
        let folds: Vec<String> = (1..=cv.per_fold.len())
            .map(|k| format!("fold {k}"))
            .collect();
        let nominal: Vec<Option<f64>> = cv
            .per_fold
            .iter()
            .map(|f| Some(f.rmse_nominal_mm))
            .collect();
        let calibrated: Vec<Option<f64>> = cv
            .per_fold
            .iter()
            .map(|f| Some(f.rmse_calibrated_mm))
            .collect();
        out.push(svg_artefact(
            "validation_errors.svg",
            plots::before_after_bars(
                "Held-out marker RMSE per cross-validation fold (log scale)",
                &format!(
                    "validation: {}-fold cross-validation, each fold held out of its fit (seed {})",
                    cv.folds, cv.seed
                ),
                "held-out marker RMSE (mm)",
                &folds,
                &nominal,
                &calibrated,
            ),
        ));
    }
    out
}

/// `design_history.svg` of `humanoid.design`: O1 against the number of postures after each
/// NOCP block (the set kept marked, when the plateau rule dropped the last block), or O1
/// after each posture COCP re-optimised.
pub(crate) fn design_history(d: &HumanoidDesign) -> Artefact {
    let dataset = format!(
        "{} base parameters, {} postures kept, nominal model",
        d.base_parameter_count, d.posture_count
    );
    let svg = match &d.cocp_o1_history {
        Some(h) => {
            let pts: Vec<(f64, f64)> = h.iter().enumerate().map(|(k, v)| (k as f64, *v)).collect();
            studies::history(&History {
                title: "Observability index O1 during COCP",
                dataset: &dataset,
                x_label: "postures re-optimised (0: random start)",
                y_label: "O1 of the posture set (dimensionless)",
                points: &pts,
                chosen: None,
            })
        }
        None => {
            let pts: Vec<(f64, f64)> = d
                .o1_history
                .iter()
                .map(|s| (s.postures as f64, s.o1))
                .collect();
            let chosen = (pts.last().map(|p| p.0) != Some(d.posture_count as f64))
                .then_some((d.posture_count as f64, d.o1));
            studies::history(&History {
                title: "Observability index O1 during NOCP",
                dataset: &dataset,
                x_label: "postures in the set",
                y_label: "O1 of the posture set (dimensionless)",
                points: &pts,
                chosen,
            })
        }
    };
    svg_artefact("design_history.svg", svg)
}
