//! `humanoid.identify`: the non-calibrated fit (nominal joints; base frame and marker
//! positions only), then the calibration (joint geometry, compliances when asked, base,
//! markers) with rank detection in the spec's priority order, LM (robust if asked),
//! standard deviations, condition number, marker RMSE before/after, a geometric-only fit for
//! comparison when elasticity is modelled, optional k-fold cross-validation, and the
//! calibrated URDF.

use std::sync::Arc;

use serde::Deserialize;
use serde_json::{Map, Value, json};

use super::samples::{SampleSet, load_samples};
use super::{
    BaseSpec, ColumnMap, FitSpec, LoadedModel, MarkerSpec, load_model, marker_table, params_json,
};
use crate::jobs::{Artefact, Cx, Inputs, JobError, Kind, Output, RunFuture, computed, parse_spec};
use crate::measure::marker_fit::{
    FitOptions, Groups, MarkerFit, fit, fit_frames, structural_count,
};
use crate::measure::markers::{MarkerSample, marker_rmse};
use crate::model::JointField;
use crate::model::humanoid::{HParam, Humanoid};
use crate::util::{Monitor, Rng, SubMonitor};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Spec {
    #[allow(dead_code)]
    kind: String,
    urdf: Value,
    samples: Value,
    #[serde(default)]
    column_map: ColumnMap,
    root_link: String,
    joints: Vec<String>,
    markers: Vec<MarkerSpec>,
    #[serde(default)]
    base: BaseSpec,
    #[serde(default)]
    options: FitSpec,
}

/// A validated `humanoid.identify` job.
#[derive(Debug)]
pub struct IdentifyJob {
    loaded: LoadedModel,
    set: SampleSet,
    options: FitSpec,
    groups: Groups,
    fit: FitOptions,
}

/// Validate a `humanoid.identify` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<IdentifyJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    let loaded = load_model(
        inputs,
        &s.urdf,
        &s.root_link,
        &s.joints,
        &s.markers,
        &s.base,
        &s.options.elastic,
    )?;
    let set = load_samples(
        inputs,
        "samples",
        &s.samples,
        &s.column_map,
        &loaded,
        s.options.preprocess.as_ref(),
    )?;
    if let Some(cv) = &s.options.cross_validation {
        if cv.folds < 2 || cv.folds > set.samples.len() {
            return Err(JobError::invalid(
                "options.cross_validation.folds",
                format!(
                    "{} folds for {} samples: use 2..={}",
                    cv.folds,
                    set.samples.len(),
                    set.samples.len()
                ),
            ));
        }
    }
    Ok(IdentifyJob {
        groups: s.options.groups()?,
        fit: s.options.fit_options()?,
        loaded,
        set,
        options: s.options,
    })
}

/// The three fits of a calibration: frames only, geometric only (when elastic), full.
#[derive(Debug, Clone)]
pub struct Calibration {
    /// Nominal joints, base frame and markers fitted (the paper's non-calibrated model).
    pub frames: MarkerFit,
    /// Joint geometry without elasticity (only when the model has compliances).
    pub geometric: Option<MarkerFit>,
    /// Everything asked for.
    pub full: MarkerFit,
}

/// Run the frames-only, geometric-only (if elastic) and full fits.
pub fn calibrate(
    model: &Humanoid,
    samples: &[MarkerSample],
    groups: Groups,
    opts: &FitOptions,
    monitor: &dyn Monitor,
) -> Result<Calibration, JobError> {
    let frames = fit_frames(model, samples, opts, &SubMonitor::new(monitor, 0.0, 0.2))?;
    let elastic = model.params.iter().any(|p| {
        matches!(
            p,
            HParam::Joint(_, JointField::Compliance) | HParam::BaseCompliance(_)
        )
    });
    let geometric = if elastic {
        let g = Groups {
            compliance: false,
            base_compliance: false,
            ..groups
        };
        Some(fit(
            &frames.model,
            g.select(&frames.model),
            samples,
            opts,
            &SubMonitor::new(monitor, 0.2, 0.5),
        )?)
    } else {
        None
    };
    let full = fit(
        &frames.model,
        groups.select(&frames.model),
        samples,
        opts,
        &SubMonitor::new(monitor, 0.5, 1.0),
    )?;
    Ok(Calibration {
        frames,
        geometric,
        full,
    })
}

/// Number of identified parameters by kind.
fn breakdown(f: &MarkerFit) -> Value {
    let (mut joints, mut compliance, mut base, mut markers) = (0, 0, 0, 0);
    for &k in &f.solution.free {
        match f.model.params[f.problem.free()[k]] {
            HParam::Joint(_, JointField::Compliance) | HParam::BaseCompliance(_) => compliance += 1,
            HParam::Joint(..) => joints += 1,
            HParam::Base(_) => base += 1,
            HParam::Marker(..) => markers += 1,
        }
    }
    json!({"joint_geometry": joints, "compliance": compliance, "base": base, "markers": markers})
}

fn fit_report(f: &MarkerFit) -> Value {
    json!({
        "parameters": params_json(&f.solution.params),
        "unidentifiable": f.solution.unidentifiable,
        "base_parameter_count": f.solution.free.len(),
        "condition_number": f.solution.uncertainty.condition_number,
        "rmse_after_mm": f.rmse * 1e3,
        "per_marker_rmse_mm": f.per_marker.iter().map(|v| v.map(|x| x * 1e3)).collect::<Vec<_>>(),
    })
}

/// k-fold cross-validation: each fold's samples are predicted by the models fitted on the
/// others (same session: base frame and markers carry over).
fn cross_validate(
    job: &IdentifyJob,
    folds: usize,
    monitor: &dyn Monitor,
) -> Result<Value, JobError> {
    let n = job.set.samples.len();
    let mut order: Vec<usize> = (0..n).collect();
    Rng::new(job.options.seed).shuffle(&mut order);
    let (mut sq_n, mut sq_c, mut count) = (0.0, 0.0, 0usize);
    let mut per_fold = Vec::new();
    for f in 0..folds {
        if monitor.is_cancelled() {
            return Err(JobError::Cancelled);
        }
        let test_idx: Vec<usize> = (0..n)
            .filter(|k| k % folds == f)
            .map(|k| order[k])
            .collect();
        let train: Vec<MarkerSample> = (0..n)
            .filter(|k| k % folds != f)
            .map(|k| job.set.samples[order[k]].clone())
            .collect();
        let test: Vec<MarkerSample> = test_idx
            .iter()
            .map(|&i| job.set.samples[i].clone())
            .collect();
        let sub = SubMonitor::new(
            monitor,
            f as f64 / folds as f64,
            (f + 1) as f64 / folds as f64,
        );
        let cal = calibrate(&job.loaded.model, &train, job.groups, &job.fit, &sub)?;
        let (a, _) = marker_rmse(&cal.frames.model, &test);
        let (b, _) = marker_rmse(&cal.full.model, &test);
        let m: usize = test.iter().map(|s| s.points.iter().flatten().count()).sum();
        sq_n += a * a * m as f64;
        sq_c += b * b * m as f64;
        count += m;
        per_fold.push(json!({"held_out_samples": test.len(), "rmse_nominal_mm": a * 1e3, "rmse_calibrated_mm": b * 1e3}));
    }
    Ok(json!({
        "folds": folds,
        "seed": job.options.seed,
        "rmse_nominal_mm": (sq_n / count.max(1) as f64).sqrt() * 1e3,
        "rmse_calibrated_mm": (sq_c / count.max(1) as f64).sqrt() * 1e3,
        "per_fold": per_fold,
    }))
}

impl Kind for IdentifyJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::execute)
    }
}

impl IdentifyJob {
    /// Compute the job's output (on the blocking pool, see [`Kind::run`]).
    pub fn execute(&self, monitor: &dyn Monitor) -> Result<Output, JobError> {
        let samples = &self.set.samples;
        let cv_share = if self.options.cross_validation.is_some() {
            0.5
        } else {
            1.0
        };
        let cal = calibrate(
            &self.loaded.model,
            samples,
            self.groups,
            &self.fit,
            &SubMonitor::new(monitor, 0.0, cv_share),
        )?;
        let full = &cal.full;
        let sol = &full.solution;
        let mut f = Map::new();
        f.insert("parameters".into(), params_json(&sol.params));
        f.insert("unidentifiable".into(), json!(sol.unidentifiable));
        f.insert("base_parameter_count".into(), json!(sol.free.len()));
        f.insert("base_parameter_breakdown".into(), breakdown(full));
        f.insert(
            "identifiability".into(),
            json!({
                "rank_tolerance": self.fit.rank_tolerance,
                "identified": sol.free.len(),
                "structural_rank_1e-8": structural_count(full, 1e-8)?,
                "unknowns": full.problem.free().len(),
            }),
        );
        f.insert(
            "condition_number".into(),
            json!(sol.uncertainty.condition_number),
        );
        f.insert("rmse_before_mm".into(), json!(cal.frames.rmse * 1e3));
        f.insert("rmse_after_mm".into(), json!(full.rmse * 1e3));
        f.insert(
            "markers".into(),
            marker_table(
                &full.model,
                &[
                    ("rmse_before_mm", &cal.frames.per_marker),
                    ("rmse_after_mm", &full.per_marker),
                ],
            ),
        );
        f.insert(
            "dependencies".into(),
            serde_json::to_value(&sol.dependencies).unwrap_or(Value::Null),
        );
        f.insert("weakly_observable".into(), json!(sol.weakly_observable));
        f.insert(
            "convergence".into(),
            json!({
                "stop_reason": sol.stop, "converged": sol.converged(), "status": sol.status(), "degenerate": sol.degenerate, "iterations": sol.iterations,
                "cost_before": sol.cost_before, "cost_after": sol.cost_after, "cost_unit": "m^2",
                "rank_tolerance": self.fit.rank_tolerance,
            }),
        );
        f.insert("residual_std_mm".into(), json!(sol.uncertainty.sigma * 1e3));
        if let Some(r) = &sol.robust {
            f.insert("robust".into(), json!({"loss": r.kind, "scale_mm": r.scale * 1e3, "rounds": r.rounds, "downweighted_markers": r.downweighted, "marker_measurements": r.groups}));
        }
        f.insert("frames_only".into(), fit_report(&cal.frames));
        if let Some(g) = &cal.geometric {
            f.insert("geometric_only".into(), fit_report(g));
        }
        f.insert("samples".into(), self.set.report());
        if let Some(cv) = &self.options.cross_validation {
            let sub = SubMonitor::new(monitor, 0.5, 1.0);
            f.insert(
                "cross_validation".into(),
                cross_validate(self, cv.folds, &sub)?,
            );
        }
        let text = self
            .loaded
            .urdf
            .write_calibrated_chains(full.model.chains())?;
        f.insert("calibrated_urdf".into(), json!(text));
        f.insert("calibrated_model".into(), json!(text));
        f.insert(
            "calibrated_urdf_note".into(),
            json!("placement errors and offsets are folded into each joint's <origin>; compliances, the base frame and the marker positions are in `parameters`"),
        );
        let mut csv = String::from("row,marker,error_before_mm,error_after_mm\n");
        let before = cal.frames.model.clone();
        for (k, s) in samples.iter().enumerate() {
            let (pb, pa) = (
                before.marker_positions(&s.state),
                full.model.marker_positions(&s.state),
            );
            for (m, p) in s.points.iter().enumerate() {
                if let Some(y) = p {
                    csv.push_str(&format!(
                        "{},{},{},{}\n",
                        self.set.rows[k],
                        full.model.markers[m].name,
                        (pb[m] - y).norm() * 1e3,
                        (pa[m] - y).norm() * 1e3
                    ));
                }
            }
        }
        Ok(Output {
            fields: f,
            main_table: None,
            artefacts: vec![
                Artefact {
                    name: "calibrated_model.urdf".into(),
                    media_type: "application/xml".into(),
                    content: text.into_bytes(),
                },
                Artefact {
                    name: "marker_residuals.csv".into(),
                    media_type: "text/csv".into(),
                    content: csv.into_bytes(),
                },
            ],
        })
    }
}
