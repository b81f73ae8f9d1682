//! `humanoid.identify`: the non-calibrated fit (nominal joints; base frame and marker
//! positions only), then the calibration (joint geometry, compliances when asked, base,
//! markers) with rank detection in the spec's priority order, LM (robust if asked),
//! standard deviations, condition number, marker RMSE before/after, a geometric-only fit for
//! comparison when elasticity is modelled, optional k-fold cross-validation, and the
//! calibrated URDF.

use std::sync::Arc;

use serde::Deserialize;
use serde_json::Value;

use super::plots::{Observation, humanoid_plots};
use super::samples::{SampleSet, load_samples, samples_from_table};
use super::{BaseSpec, ColumnMap, FitSpec, LoadedModel, MarkerSpec, load_model, load_model_text};
use crate::identify::IdentifyError;
use crate::identify::duplicates::{duplicate_configurations, shuffled_groups};
use crate::identify::prior::{CV_FOLDS, CV_WEIGHTS, choose_weight_grouped};
use crate::measure::marker_fit::{
    FitOptions, Groups, MarkerFit, fit, fit_frames, structural_count,
};
use crate::measure::markers::{MarkerProblem, MarkerSample, marker_rmse};
use crate::model::JointField;
use crate::model::humanoid::{HParam, Humanoid};
use crate::run::Run;
use crate::run::{Artefact, Cx, Inputs, JobError, Kind, RunFuture, Table, computed, parse_spec};
use crate::util::{Monitor, SubMonitor};

pub use super::identify_result::*;

/// Fit options with the prior's weight or stds as chosen, the weight candidates' K-fold
/// errors (`"cv"`) or the automatic grid (`scale: "auto"`).
type ChosenPrior = (
    FitOptions,
    Option<Vec<crate::identify::prior::FoldError>>,
    Option<crate::identify::prior_grid::AutoPrior>,
);

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[schemars(schema_with = "crate::run::schema::urdf")]
    urdf: Value,
    #[schemars(schema_with = "crate::run::schema::table_with_gaps")]
    samples: Value,
    #[serde(default)]
    column_map: ColumnMap,
    root_link: String,
    joints: Vec<String>,
    markers: Vec<MarkerSpec>,
    #[serde(default)]
    base: BaseSpec,
    #[serde(default)]
    validation: Option<ValidationSpec>,
    #[serde(default)]
    options: FitSpec,
}

/// `validation` of `humanoid.identify`: a held-out session for the `coverage` of the
/// predicted accuracy (its base frame and markers refitted, joints held).
#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct ValidationSpec {
    /// The session's samples (the columns of `samples`, renamed by `column_map`).
    #[schemars(schema_with = "crate::run::schema::table_with_gaps")]
    samples: Value,
    /// Column renames of this table (default: the job's `column_map`).
    #[serde(default)]
    column_map: Option<ColumnMap>,
}

/// A validated `humanoid.identify` job.
#[derive(Debug)]
pub struct IdentifyJob {
    pub(super) loaded: LoadedModel,
    pub(super) set: SampleSet,
    pub(super) options: FitSpec,
    pub(super) groups: Groups,
    pub(super) fit: FitOptions,
    /// A held-out session for the coverage, if given.
    pub(super) validation: Option<SampleSet>,
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
    let validation = match &s.validation {
        Some(v) => Some(load_samples(
            inputs,
            "validation.samples",
            &v.samples,
            v.column_map.as_ref().unwrap_or(&s.column_map),
            &loaded,
            s.options.preprocess.as_ref(),
        )?),
        None => None,
    };
    IdentifyJob::from_samples(loaded, set, s.options, validation)
}

impl IdentifyJob {
    /// A `humanoid.identify` job from typed inputs (the mocap campaign's entry point): URDF
    /// text, root link, joints, markers, base mode, the samples table (joint columns by
    /// URDF name, `<marker>_x/_y/_z` with occlusions as NaN) and the parsed options.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        urdf: &str,
        root_link: &str,
        joints: &[String],
        markers: &[MarkerSpec],
        base: &BaseSpec,
        samples: Table,
        column_map: &ColumnMap,
        options: FitSpec,
    ) -> Result<IdentifyJob, JobError> {
        let loaded = load_model_text(urdf, root_link, joints, markers, base, &options.elastic)?;
        let set = samples_from_table(
            "samples",
            samples,
            column_map,
            &loaded,
            options.preprocess.as_ref(),
        )?;
        IdentifyJob::from_samples(loaded, set, options, None)
    }

    /// The last validation step shared by the JSON and the typed constructors.
    fn from_samples(
        loaded: LoadedModel,
        set: SampleSet,
        options: FitSpec,
        validation: Option<SampleSet>,
    ) -> Result<IdentifyJob, JobError> {
        if let Some(cv) = &options.cross_validation
            && (cv.folds < 2 || cv.folds > set.samples.len())
        {
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
        let groups = options.groups()?;
        let fit = options.fit_options()?;
        if let Some(map) = &fit.prior {
            let free = groups.select(&loaded.model);
            let p = MarkerProblem::new(loaded.model.clone(), free, Vec::new());
            // An automatic scale is checked with unit defaults (the values are the data's).
            let spec = match map.spec.scale {
                Some(_) => map.spec.with_scale(1.0, 1.0),
                None => map.spec.clone(),
            };
            spec.sigmas(&p.unknowns(), |_| true)
                .map_err(|m| JobError::invalid("options.prior", m))?;
        }
        Ok(IdentifyJob {
            groups,
            fit,
            loaded,
            set,
            options,
            validation,
        })
    }
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
fn breakdown(f: &MarkerFit) -> Breakdown {
    let (mut joints, mut compliance, mut base, mut markers) = (0, 0, 0, 0);
    for &k in &f.solution.free {
        match f.model.params[f.problem.free()[k]] {
            HParam::Joint(_, JointField::Compliance) | HParam::BaseCompliance(_) => compliance += 1,
            HParam::Joint(..) => joints += 1,
            HParam::Base(_) => base += 1,
            HParam::Marker(..) => markers += 1,
        }
    }
    Breakdown {
        joint_geometry: joints,
        compliance,
        base,
        markers,
    }
}

fn fit_report(f: &MarkerFit) -> FitReport {
    FitReport {
        parameters: f.solution.params.clone(),
        unidentifiable: f.solution.unidentifiable.clone(),
        base_parameter_count: f.solution.free.len(),
        condition_number: f.solution.uncertainty.condition_number,
        rmse_after_mm: f.rmse * 1e3,
        per_marker_rmse_mm: f.per_marker.iter().map(|v| v.map(|x| x * 1e3)).collect(),
    }
}

/// k-fold cross-validation: each fold's samples are predicted by the models fitted on the
/// others (same session: base frame and markers carry over).
fn cross_validate(
    job: &IdentifyJob,
    folds: usize,
    monitor: &dyn Monitor,
) -> Result<CrossValidation, JobError> {
    // Copies of one configuration stay in one fold.
    let samples = &job.set.samples;
    let dup = duplicate_configurations(samples.iter().map(|s| s.state.q.as_slice()));
    let order = shuffled_groups(&dup.group, job.options.seed);
    let (mut sq_n, mut sq_c, mut count) = (0.0, 0.0, 0usize);
    let mut per_fold = Vec::new();
    for f in 0..folds {
        if monitor.is_cancelled() {
            return Err(JobError::Cancelled);
        }
        let side = |test: bool| -> Vec<usize> {
            order
                .iter()
                .enumerate()
                .filter(|(k, _)| (k % folds == f) == test)
                .flat_map(|(_, m)| m.iter().copied())
                .collect()
        };
        let test_idx = side(true);
        let train: Vec<MarkerSample> = side(false).iter().map(|&i| samples[i].clone()).collect();
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
        per_fold.push(FoldReport {
            held_out_samples: test.len(),
            rmse_nominal_mm: a * 1e3,
            rmse_calibrated_mm: b * 1e3,
        });
    }
    Ok(CrossValidation {
        folds,
        seed: job.options.seed,
        rmse_nominal_mm: (sq_n / count.max(1) as f64).sqrt() * 1e3,
        rmse_calibrated_mm: (sq_c / count.max(1) as f64).sqrt() * 1e3,
        per_fold,
    })
}

impl IdentifyJob {
    /// The fit options with the prior's weight: as given, or (`prior_weight: "cv"`) the
    /// candidate of [`CV_WEIGHTS`] with the smallest held-out marker RMS over
    /// [`CV_FOLDS`] seeded folds of the training samples (base frame and markers carry over
    /// within the session). Also the candidates' errors when chosen; with `scale: "auto"`
    /// the stds chosen by [`IdentifyJob::auto_prior`] and their grid.
    fn prior_weight(&self, monitor: &dyn Monitor) -> Result<ChosenPrior, JobError> {
        if self
            .fit
            .prior
            .as_ref()
            .is_some_and(|m| m.spec.scale.is_some())
        {
            let (o, auto) = self.auto_prior(monitor)?;
            return Ok((o, None, Some(auto)));
        }
        let cv = matches!(
            self.options.prior_weight.as_ref().map(|w| w.fixed()),
            Some(Ok(None))
        );
        if !cv || self.fit.prior.is_none() {
            return Ok((self.fit.clone(), None, None));
        }
        let samples = &self.set.samples;
        let mut done = 0usize;
        let total = CV_WEIGHTS.len() * CV_FOLDS;
        // Copies of one configuration stay in one fold.
        let group = duplicate_configurations(samples.iter().map(|s| s.state.q.as_slice())).group;
        let (w, errors) = choose_weight_grouped(
            &CV_WEIGHTS,
            &group,
            CV_FOLDS,
            self.options.seed,
            |w, train, test| {
                if monitor.is_cancelled() {
                    return Err(IdentifyError::Cancelled);
                }
                let sub = SubMonitor::new(
                    monitor,
                    done as f64 / total as f64,
                    (done + 1) as f64 / total as f64,
                );
                done += 1;
                let mut o = self.fit.clone();
                if let Some(map) = &mut o.prior {
                    map.weight = w;
                }
                let tr: Vec<MarkerSample> = train.iter().map(|&i| samples[i].clone()).collect();
                let te: Vec<MarkerSample> = test.iter().map(|&i| samples[i].clone()).collect();
                let cal = calibrate(&self.loaded.model, &tr, self.groups, &o, &sub)
                    .map_err(|e| IdentifyError::Model(e.to_string()))?;
                let (rmse, _) = marker_rmse(&cal.full.model, &te);
                let m: usize = te.iter().map(|s| s.points.iter().flatten().count()).sum();
                Ok((rmse * rmse * m as f64, m))
            },
        )
        .map_err(|e| match e {
            IdentifyError::Cancelled => JobError::Cancelled,
            e => JobError::from(e),
        })?;
        let mut o = self.fit.clone();
        if let Some(map) = &mut o.prior {
            map.weight = w;
        }
        Ok((o, Some(errors), None))
    }

    /// Run the calibration: the typed result and its artefacts (calibrated URDF,
    /// `marker_residuals.csv`); no main table.
    pub fn calibrate(&self, monitor: &dyn Monitor) -> Result<Run<HumanoidCalibration>, JobError> {
        let samples = &self.set.samples;
        let cv_share = if self.options.cross_validation.is_some() {
            0.5
        } else {
            1.0
        };
        let (fit_opts, weight_errors, auto) =
            self.prior_weight(&SubMonitor::new(monitor, 0.0, 0.5 * cv_share))?;
        let cal = calibrate(
            &self.loaded.model,
            samples,
            self.groups,
            &fit_opts,
            &SubMonitor::new(monitor, 0.5 * cv_share, cv_share),
        )?;
        let mut prior = cal.full.prior.clone();
        if weight_errors.is_some() {
            prior.mode = "map_cv";
            prior.k_fold_errors = weight_errors;
        }
        if auto.is_some() {
            prior.mode = "map_auto";
            prior.auto = auto;
        }
        let full = &cal.full;
        let sol = &full.solution;
        let markers = full
            .model
            .markers
            .iter()
            .enumerate()
            .map(|(m, d)| MarkerRmse {
                name: d.name.clone(),
                link: d.link.clone(),
                rmse_before_mm: cal.frames.per_marker[m].map(|v| v * 1e3),
                rmse_after_mm: full.per_marker[m].map(|v| v * 1e3),
            })
            .collect();
        let cross_validation = match &self.options.cross_validation {
            Some(cv) => {
                let sub = SubMonitor::new(monitor, 0.5, 1.0);
                Some(cross_validate(self, cv.folds, &sub)?)
            }
            None => None,
        };
        let text = self
            .loaded
            .urdf
            .write_calibrated_chains(full.model.chains())?;
        let mut csv = String::from("row,marker,error_before_mm,error_after_mm\n");
        let mut observations = Vec::new();
        let before = cal.frames.model.clone();
        for (k, s) in samples.iter().enumerate() {
            let (pb, pa) = (
                before.marker_positions(&s.state),
                full.model.marker_positions(&s.state),
            );
            for (m, p) in s.points.iter().enumerate() {
                if let Some(y) = p {
                    let o = Observation {
                        row: self.set.rows[k],
                        before_mm: (pb[m] - y).norm() * 1e3,
                        after_mm: (pa[m] - y).norm() * 1e3,
                    };
                    csv.push_str(&format!(
                        "{},{},{},{}\n",
                        o.row, full.model.markers[m].name, o.before_mm, o.after_mm
                    ));
                    observations.push(o);
                }
            }
        }
        let mut result = HumanoidCalibration {
            assessment: crate::identify::verdict::Assessment::of(Vec::new()),
            dof: sol.uncertainty.dof,
            parameters: sol.params.clone(),
            unidentifiable: sol.unidentifiable.clone(),
            base_parameter_count: sol.free.len(),
            base_parameter_breakdown: breakdown(full),
            identifiability: Identifiability {
                rank_tolerance: self.fit.rank_tolerance,
                identified: sol.free.len(),
                structural_rank: structural_count(full, 1e-8)?,
                unknowns: full.problem.free().len(),
            },
            condition_number: sol.uncertainty.condition_number,
            rmse_before_mm: cal.frames.rmse * 1e3,
            rmse_after_mm: full.rmse * 1e3,
            markers,
            dependencies: sol.dependencies.clone(),
            weakly_observable: sol.weakly_observable.clone(),
            convergence: HumanoidConvergence {
                stop_reason: sol.stop,
                converged: sol.converged(),
                status: sol.status().into(),
                degenerate: sol.degenerate.clone(),
                iterations: sol.iterations,
                cost_before: sol.cost_before,
                cost_after: sol.cost_after,
                cost_unit: "m^2",
                rank_tolerance: self.fit.rank_tolerance,
            },
            residual_std_mm: None,
            prior,
            robust: sol.robust.as_ref().map(|r| RobustSummary {
                loss: r.kind,
                scale_mm: r.scale * 1e3,
                rounds: r.rounds,
                downweighted_markers: r.downweighted,
                marker_measurements: r.groups,
            }),
            frames_only: fit_report(&cal.frames),
            geometric_only: cal.geometric.as_ref().map(fit_report),
            samples: self.set.report(),
            cross_validation,
            coverage: None,
            calibrated_urdf: text.clone(),
            calibrated_model: text.clone(),
            calibrated_urdf_note: "placement errors and offsets are folded into each joint's <origin>; compliances, the base frame and the marker positions are in `parameters`",
        };
        let cv = result.cross_validation.clone();
        let held_out = |variance_factor: f64, noise_m: Option<f64>| {
            let (Some(v), Some(noise_m)) = (&self.validation, noise_m) else {
                return Ok(None);
            };
            super::coverage::held_out_coverage(
                full,
                &v.samples,
                &fit_opts,
                variance_factor,
                noise_m,
                monitor,
            )
            .map_err(JobError::from)
        };
        super::verdict::judge(
            samples,
            full,
            &fit_opts,
            cv.as_ref(),
            &held_out,
            &mut result,
        )?;
        let mut artefacts = vec![
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
        ];
        artefacts.extend(humanoid_plots(&result, &observations));
        if let Some(c) = &result.coverage {
            artefacts.push(crate::report::svg_artefact(
                "predicted_accuracy.svg",
                crate::report::coverage::predicted_accuracy(c),
            ));
        }
        Ok(Run {
            result,
            main_table: None,
            artefacts,
        })
    }
}

impl Kind for IdentifyJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::calibrate)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::run::DirResolver;
    use crate::util::monitor::NoMonitor;
    use serde_json::json;

    /// The result fields of `examples/humanoid_identify_twin.json` (elastic, no robust
    /// loss, no cross-validation) as the hand-built map of 7e62456 had them, plus `prior`
    /// (issue 13: which mode ran).
    const FIELDS: &[&str] = &[
        "base_parameter_breakdown",
        "base_parameter_count",
        "calibrated_model",
        "calibrated_urdf",
        "calibrated_urdf_note",
        "condition_number",
        "convergence",
        "dependencies",
        "dof",
        "frames_only",
        "geometric_only",
        "identifiability",
        "markers",
        "parameters",
        "prior",
        "reasons",
        "residual_std_mm",
        "rmse_after_mm",
        "rmse_before_mm",
        "samples",
        "unidentifiable",
        "verdict",
        "weakly_observable",
    ];

    #[test]
    fn the_typed_result_serialises_to_the_fields_of_before() {
        let dir = std::path::PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/examples"));
        let doc: Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join("humanoid_identify_twin.json")).unwrap(),
        )
        .unwrap();
        let job = prepare(&doc, &Inputs::new(&DirResolver { dir: dir.clone() })).unwrap();
        let run = job.calibrate(&NoMonitor).unwrap();
        let out = run.clone().into_output().unwrap();
        let mut keys: Vec<&str> = out.fields.keys().map(String::as_str).collect();
        keys.sort_unstable();
        assert_eq!(keys, FIELDS);
        assert!(
            out.fields["identifiability"]
                .as_object()
                .unwrap()
                .contains_key("structural_rank_1e-8")
        );
        assert_eq!(
            out.fields["calibrated_model"],
            json!(run.result.calibrated_model)
        );
        // The typed constructor (URDF text, a samples table) gives the same result.
        let s: Spec = parse_spec(&doc).unwrap();
        let urdf = std::fs::read_to_string(dir.join(s.urdf.as_str().unwrap())).unwrap();
        let csv = std::fs::read_to_string(dir.join(s.samples.as_str().unwrap())).unwrap();
        // Occlusions are empty cells: NaN in a typed table.
        let mut lines = csv.lines();
        let columns: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
        let rows = lines
            .filter(|l| !l.trim().is_empty())
            .map(|l| {
                l.split(',')
                    .map(|c| c.trim().parse().unwrap_or(f64::NAN))
                    .collect()
            })
            .collect();
        let table = Table { columns, rows };
        let typed = IdentifyJob::new(
            &urdf,
            &s.root_link,
            &s.joints,
            &s.markers,
            &s.base,
            table,
            &s.column_map,
            s.options,
        )
        .unwrap();
        let b = typed.calibrate(&NoMonitor).unwrap().into_output().unwrap();
        assert_eq!(out.fields["parameters"], b.fields["parameters"]);
        assert_eq!(out.fields["rmse_after_mm"], b.fields["rmse_after_mm"]);
    }
}
