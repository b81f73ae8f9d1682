//! `serial.identify`: elasto-geometric identification of a serial arm from ball-centring
//! (or Cartesian) measurements, with rank detection, standard deviations, residual and
//! per-ball statistics, optional validation, and the calibrated model file.
//!
//! Which measurement a table holds is decided by its columns: `L_mm` (a distance from the
//! TCP to an unknown fixed anchor, with an unknown length offset: draw-wire sensors,
//! interferometers, laser trackers in distance-only mode) takes precedence; otherwise `ball`
//! (ball-centring); otherwise `x, y, z` (Cartesian). With `L_mm` present, `x, y, z` are not
//! measurements (a controller's own positions are the nominal model, not data) and are
//! reported as unused; `L_mm` together with `ball` is refused as ambiguous. Every column a
//! table has and the job does not read is named in the result's `warnings`.

use std::sync::Arc;

use serde::Deserialize;
use serde_json::{Value, json};

use super::plots::{ResidualPlots, axis_rms, residual_artefacts};
use super::{ChainSpec, PlateSpec, SerialModel};
use crate::identify::Solution;
use crate::identify::verdict::Assessment;
use crate::measure::distance::distance_errors;
use crate::measure::{BallPlate, PointMeasurement, PointProblem, Target};
use crate::model::Chain;
use crate::model::dh::DhFile;
use crate::run::Run;
use crate::run::{Artefact, Cx, Inputs, JobError, Kind, RunFuture, computed, parse_spec};
use crate::util::{Monitor, Summary};

pub use super::identify_inputs::*;
pub use super::identify_result::*;

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    #[schemars(schema_with = "crate::run::schema::serial_model")]
    model: Value,
    #[serde(default)]
    chain: Option<ChainSpec>,
    #[schemars(schema_with = "crate::run::schema::table")]
    measurements: Value,
    #[serde(default)]
    ball_plate: Option<PlateSpec>,
    #[serde(default)]
    #[schemars(schema_with = "crate::run::schema::table_opt")]
    validation: Option<Value>,
    #[serde(default)]
    options: IdentifyOptions,
}

/// Absolute position errors of a model against Cartesian measurements (each model with its
/// own static deflection).
pub fn position_errors(chain: &Chain, meas: &[PointMeasurement]) -> Vec<f64> {
    meas.iter()
        .filter_map(|m| match m.target {
            Target::Point(p) => {
                Some((chain.tcp(&m.q, Some(&chain.static_torques(&m.q))).p - p).norm())
            }
            Target::Ball(_) => None,
        })
        .collect()
}

/// `{mean, median, std, max, unit}` (plus count, min, rms) of errors.
pub fn stats(v: &[f64], unit: &str) -> Value {
    serde_json::to_value(Summary::of(v, unit)).unwrap_or(Value::Null)
}

/// A validated `serial.identify` job.
#[derive(Debug)]
pub struct IdentifyJob {
    inputs: IdentifyInputs,
}

/// Validate a `serial.identify` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<IdentifyJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    Ok(IdentifyJob {
        inputs: parse_inputs(
            inputs,
            &s.model,
            s.chain.as_ref(),
            &s.measurements,
            s.ball_plate.as_ref(),
            s.validation.as_ref(),
            s.options,
        )?,
    })
}

/// Known distance between balls i and j of a plate, if the plate fixes it.
fn known_distance(
    plate: &BallPlate,
    centres: &[nalgebra::Vector3<f64>],
    i: usize,
    j: usize,
) -> Option<f64> {
    match (plate.centres[i], plate.centres[j]) {
        (Some(a), Some(b)) => Some((a - b).norm()),
        _ => plate
            .distances
            .iter()
            .find(|d| (d.0, d.1) == (i, j) || (d.0, d.1) == (j, i))
            .map(|d| d.2)
            .or_else(|| Some((centres[i] - centres[j]).norm())),
    }
}

/// Point-coincidence statistics of two models on ball measurements: per ball the RMS
/// distance of the model TCP positions from their mean (spread), and per pair of balls the
/// distance between those means minus the known distance. Torques from the start model.
pub fn coincidence_report(
    meas: &[PointMeasurement],
    start: &Chain,
    end: &Chain,
    plate: &BallPlate,
    centres: &[nalgebra::Vector3<f64>],
    unit: &str,
) -> CoincidenceReport {
    let mut balls = Vec::new();
    let mut means: Vec<Option<[nalgebra::Vector3<f64>; 2]>> = Vec::new();
    for b in 0..plate.len() {
        let qs: Vec<&Vec<f64>> = meas
            .iter()
            .filter(|m| m.target == Target::Ball(b))
            .map(|m| &m.q)
            .collect();
        if qs.is_empty() {
            means.push(None);
            continue;
        }
        let mut m2 = [nalgebra::Vector3::zeros(); 2];
        let mut spread2 = [0.0; 2];
        for (slot, chain) in [start, end].into_iter().enumerate() {
            let pts: Vec<_> = qs
                .iter()
                .map(|q| chain.tcp(q, Some(&start.static_torques(q))).p)
                .collect();
            let mean = pts.iter().fold(nalgebra::Vector3::zeros(), |a, p| a + p) / pts.len() as f64;
            spread2[slot] = (pts.iter().map(|p| (p - mean).norm_squared()).sum::<f64>()
                / pts.len() as f64)
                .sqrt();
            m2[slot] = mean;
        }
        balls.push(BallCoincidence {
            ball: b + 1,
            count: qs.len(),
            spread_rms_before: spread2[0],
            mean_position_before: [m2[0].x, m2[0].y, m2[0].z],
            spread_rms_after: spread2[1],
            mean_position_after: [m2[1].x, m2[1].y, m2[1].z],
            unit: unit.to_string(),
        });
        means.push(Some(m2));
    }
    let mut ball_distances = Vec::new();
    for i in 0..plate.len() {
        for j in i + 1..plate.len() {
            let (Some(a), Some(b), Some(known)) =
                (means[i], means[j], known_distance(plate, centres, i, j))
            else {
                continue;
            };
            ball_distances.push(BallDistanceError {
                balls: [i + 1, j + 1],
                known,
                error_before: (a[0] - b[0]).norm() - known,
                error_after: (a[1] - b[1]).norm() - known,
                unit: unit.to_string(),
            });
        }
    }
    CoincidenceReport {
        balls,
        ball_distances,
    }
}

/// Identification report fields shared by point and distance problems.
fn solution_result(
    sol: &Solution,
    unit: &str,
    tolerance: f64,
    residuals: BeforeAfter,
    calibrated_model: SerialModelFile,
) -> SerialCalibration {
    SerialCalibration {
        assessment: Assessment::of(Vec::new()),
        dof: sol.uncertainty.dof,
        measurement_type: None,
        parameters: sol.params.clone(),
        unidentifiable: sol.unidentifiable.clone(),
        dependencies: sol.dependencies.clone(),
        weakly_observable: sol.weakly_observable.clone(),
        unobservable: sol.unobservable.clone(),
        observability: Observability {
            condition_number: sol.condition_number,
            near_dependent: sol.near_dependent.clone(),
            scaling: "physical: lengths 1 mm, angles 0.5 deg, compliances 0.005 deg/(N*m)",
        },
        convergence: Convergence {
            stop_reason: sol.stop,
            converged: sol.converged(),
            status: sol.status().into(),
            degenerate: sol.degenerate.clone(),
            iterations: sol.iterations,
            cost_before: sol.cost_before,
            cost_after: sol.cost_after,
            cost_nuisance_only: sol.nuisance_cost,
            cost_unit: format!("{unit}^2"),
        },
        rank: Rank {
            rank: sol.free.len(),
            unknowns: sol.params.len(),
            tolerance,
        },
        condition_number: sol.uncertainty.condition_number,
        residual_std: ResidualStd {
            value: Some(sol.uncertainty.sigma).filter(|s| s.is_finite()),
            unit: unit.to_string(),
            dof: sol.uncertainty.dof,
        },
        prior: None,
        gauge_freedom: None,
        gauge_held: sol.held_gauge.clone(),
        residuals,
        coincidence: None,
        anchor: None,
        length_offset: None,
        validation: None,
        coverage: None,
        validation_coincidence: None,
        calibrated_model,
        warnings: None,
    }
}

/// The calibrated model as a typed file and its artefact.
fn calibrated_file(
    model: &SerialModel,
    chain: &Chain,
    provenance: Value,
) -> Result<(SerialModelFile, Artefact), JobError> {
    let (value, art) = model.calibrated(chain, provenance)?;
    let file = match value {
        Value::String(text) => SerialModelFile::Urdf(text),
        v => SerialModelFile::Dh(
            serde_json::from_value(v)
                .map_err(|e| JobError::internal("reading back the calibrated model", e))?,
        ),
    };
    Ok((file, art))
}

impl IdentifyJob {
    /// A `serial.identify` job from typed inputs (the campaigns' entry point; the JSON
    /// path parses its tables and calls this too): model, point measurements (radians),
    /// ball plate (required for ball targets), optional validation, options.
    pub fn new(
        model: SerialModel,
        measurements: Vec<PointMeasurement>,
        plate: Option<BallPlate>,
        validation: Option<Vec<PointMeasurement>>,
        options: IdentifyOptions,
    ) -> Result<IdentifyJob, JobError> {
        Ok(IdentifyJob {
            inputs: point_inputs(model, measurements, plate, validation, Vec::new(), options)?,
        })
    }

    /// A `serial.identify` job on a DH model with a three-ball plate given by its ball-bar
    /// distances `[d12, d13, d23]` (the TriCal campaign's case).
    pub fn from_dh(
        model: DhFile,
        measurements: Vec<PointMeasurement>,
        ballbar: [f64; 3],
        validation: Option<Vec<PointMeasurement>>,
        options: IdentifyOptions,
    ) -> Result<IdentifyJob, JobError> {
        let plate = BallPlate::from_ballbar(ballbar[0], ballbar[1], ballbar[2])
            .map_err(|e| JobError::invalid("ball_plate", e.to_string()))?;
        IdentifyJob::new(
            SerialModel::from_dh(model)?,
            measurements,
            Some(plate),
            validation,
            options,
        )
    }

    /// The validated inputs.
    pub fn inputs(&self) -> &IdentifyInputs {
        &self.inputs
    }

    /// Run the identification: the typed result and its artefacts (calibrated model,
    /// `residuals.csv`, error plots); no main table.
    pub fn calibrate(&self, monitor: &dyn Monitor) -> Result<Run<SerialCalibration>, JobError> {
        if !self.inputs.distances.is_empty() {
            return self.calibrate_distance(monitor);
        }
        let inp = &self.inputs;
        let (problem, sol, prior) = super::prior::identify::<PointProblem>(inp, None, monitor)?;
        let calibrated = problem.model(&sol.x);
        let unit = inp.model.length_unit();
        let norms = |r: &nalgebra::DVector<f64>| -> Vec<f64> {
            (0..problem.measurements().len())
                .map(|i| r.rows(3 * i, 3).norm())
                .collect()
        };
        let (before, after) = (norms(&sol.residuals_before), norms(&sol.residuals));
        let provenance = json!({"method": "serial.identify", "calibd_version": crate::run::VERSION, "measurements": problem.measurements().len()});
        let (model_file, model_art) = calibrated_file(&inp.model, &calibrated, provenance)?;
        let mut r = solution_result(
            &sol,
            unit,
            inp.solve_options(&problem).rank_tolerance,
            BeforeAfter {
                before: Summary::of(&before, unit),
                after: Summary::of(&after, unit),
                meaning: None,
            },
            model_file,
        );
        r.prior = Some(prior);
        r.gauge_freedom = Some(inp.plate.gauge.clone());
        let centres = problem.centres(&sol.x);
        if !inp.plate.is_empty() {
            r.coincidence = Some(coincidence_report(
                problem.measurements(),
                &inp.model.chain,
                &calibrated,
                &inp.plate,
                &centres,
                unit,
            ));
        }
        let mut held_out = None;
        if let Some(v) = &inp.validation {
            let cartesian: Vec<PointMeasurement> = v
                .iter()
                .filter(|m| matches!(m.target, Target::Point(_)))
                .cloned()
                .collect();
            if !cartesian.is_empty() {
                let (vb, va) = (
                    position_errors(&inp.model.chain, &cartesian),
                    position_errors(&calibrated, &cartesian),
                );
                r.validation = Some(BeforeAfter {
                    before: Summary::of(&vb, unit),
                    after: Summary::of(&va, unit),
                    meaning: None,
                });
                held_out = Some((vb, va));
            }
            if v.iter().any(|m| matches!(m.target, Target::Ball(_))) {
                r.validation_coincidence = Some(coincidence_report(
                    v,
                    &inp.model.chain,
                    &calibrated,
                    &inp.plate,
                    &centres,
                    unit,
                ));
            }
        }
        if !inp.warnings.is_empty() {
            r.warnings = Some(inp.warnings.clone());
        }
        let weight = r.prior.as_ref().and_then(|p| p.weight);
        super::verdict::judge(
            inp,
            &sol,
            &problem.unknowns(),
            &problem.nuisance(),
            weight,
            Some(&calibrated),
            &mut r,
        );
        let mut artefacts = vec![model_art];
        artefacts.extend(inp.model.urdf_artefact(&calibrated));
        if let Some(c) = &r.coverage {
            artefacts.push(crate::report::svg_artefact(
                "predicted_accuracy.svg",
                crate::report::coverage::predicted_accuracy(c),
            ));
        }
        // The first 3 rows per measurement are its x, y, z residuals (a prior adds rows).
        let n3 = 3 * problem.measurements().len();
        let rb: Vec<f64> = sol.residuals_before.iter().take(n3).copied().collect();
        let ra: Vec<f64> = sol.residuals.iter().take(n3).copied().collect();
        artefacts.extend(residual_artefacts(&ResidualPlots {
            before: &before,
            after: &after,
            unit,
            what: "Position error",
            validation: held_out,
            per_axis: Some((axis_rms(&rb), axis_rms(&ra))),
        }));
        Ok(Run {
            result: r,
            main_table: None,
            artefacts,
        })
    }

    /// Distance (`L_mm`) identification: parameters, anchor and length offset, signed
    /// distance residuals, validation before (nominal model with its own fitted anchor and
    /// offset) and after, the calibrated model.
    fn calibrate_distance(
        &self,
        monitor: &dyn Monitor,
    ) -> Result<Run<SerialCalibration>, JobError> {
        let inp = &self.inputs;
        let (problem, sol, prior) = inp.identify_distance(monitor)?;
        let calibrated = problem.model(&sol.x);
        let unit = inp.model.length_unit();
        let (anchor, offset) = problem.anchor(&sol.x);
        let x0 = problem.initial();
        let (anchor0, offset0) = problem.anchor(&x0);
        let o = problem.chain_unknowns();
        let std_of = |k: usize| sol.params.get(o + k).and_then(|p| p.std);
        let abs = |r: &nalgebra::DVector<f64>| -> Vec<f64> { r.iter().map(|v| v.abs()).collect() };
        let provenance = json!({"method": "serial.identify", "measurement_type": "distance", "calibd_version": crate::run::VERSION, "measurements": problem.measurements().len()});
        let (model_file, model_art) = calibrated_file(&inp.model, &calibrated, provenance)?;
        let mut r = solution_result(
            &sol,
            unit,
            inp.distance_solve_options(&problem).rank_tolerance,
            BeforeAfter {
                before: Summary::of(&abs(&sol.residuals_before), unit),
                after: Summary::of(&abs(&sol.residuals), unit),
                meaning: Some(
                    "absolute distance residuals | |TCP - anchor| + length_offset - L |".into(),
                ),
            },
            model_file,
        );
        r.measurement_type = Some("distance".into());
        r.prior = Some(prior);
        r.anchor = Some(Anchor {
            x: anchor.x,
            y: anchor.y,
            z: anchor.z,
            std: [std_of(0), std_of(1), std_of(2)],
            nominal_fit: [anchor0.x, anchor0.y, anchor0.z],
            frame: "W",
            unit: unit.to_string(),
        });
        r.length_offset = Some(LengthOffset {
            value: offset,
            std: std_of(3),
            nominal_fit: offset0,
            unit: unit.to_string(),
            meaning: "measured length = |TCP - anchor| + length_offset",
        });
        let mut held_out = None;
        if let Some(v) = &inp.validation_distances {
            let before: Vec<f64> = distance_errors(&inp.model.chain, &anchor0, offset0, v)
                .iter()
                .map(|e| e.abs())
                .collect();
            let after: Vec<f64> = distance_errors(&calibrated, &anchor, offset, v)
                .iter()
                .map(|e| e.abs())
                .collect();
            held_out = Some((before.clone(), after.clone()));
            r.validation = Some(BeforeAfter {
                before: Summary::of(&before, unit),
                after: Summary::of(&after, unit),
                meaning: Some(
                    "absolute held-out distance errors; before: the starting model with the anchor and offset fitted to it"
                        .into(),
                ),
            });
        }
        if !inp.warnings.is_empty() {
            r.warnings = Some(inp.warnings.clone());
        }
        let weight = r.prior.as_ref().and_then(|p| p.weight);
        super::verdict::judge(
            inp,
            &sol,
            &problem.unknowns(),
            &problem.nuisance(),
            weight,
            None,
            &mut r,
        );
        let before: Vec<f64> = sol.residuals_before.iter().copied().collect();
        let after: Vec<f64> = sol.residuals.iter().copied().collect();
        let mut artefacts = vec![model_art];
        artefacts.extend(inp.model.urdf_artefact(&calibrated));
        artefacts.extend(residual_artefacts(&ResidualPlots {
            before: &before,
            after: &after,
            unit,
            what: "Distance error",
            validation: held_out,
            per_axis: None,
        }));
        Ok(Run {
            result: r,
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
    use crate::run::{DirResolver, Inputs};
    use crate::util::monitor::NoMonitor;

    /// The result fields of `examples/serial_identify.json` (ball plate, Cartesian
    /// validation) as the hand-built map of 7e62456 had them.
    const FIELDS: &[&str] = &[
        "ball_distances",
        "balls",
        "calibrated_model",
        "condition_number",
        "convergence",
        "coverage",
        "dependencies",
        "dof",
        "gauge_freedom",
        "observability",
        "parameters",
        "prior",
        "rank",
        "reasons",
        "residual_std",
        "residuals",
        "unidentifiable",
        "unobservable",
        "validation",
        "verdict",
        "weakly_observable",
    ];

    fn example() -> IdentifyJob {
        let dir = std::path::PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/examples"));
        let doc: Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join("serial_identify.json")).unwrap(),
        )
        .unwrap();
        prepare(&doc, &Inputs::new(&DirResolver { dir })).unwrap()
    }

    #[test]
    fn the_typed_result_serialises_to_the_fields_of_before() {
        let run = example().calibrate(&NoMonitor).unwrap();
        let out = run.clone().into_output().unwrap();
        let mut keys: Vec<&str> = out.fields.keys().map(String::as_str).collect();
        keys.sort_unstable();
        assert_eq!(keys, FIELDS);
        let conv = out.fields["convergence"].as_object().unwrap();
        let mut ck: Vec<&str> = conv.keys().map(String::as_str).collect();
        ck.sort_unstable();
        assert_eq!(
            ck,
            [
                "converged",
                "cost_after",
                "cost_before",
                "cost_nuisance_only",
                "cost_unit",
                "degenerate",
                "iterations",
                "status",
                "stop_reason"
            ]
        );
        // The typed fields the campaigns read.
        let v = run.result.validation.as_ref().unwrap();
        assert_eq!(
            out.fields["validation"]["after"]["mean"],
            json!(v.after.mean)
        );
        assert!(v.after.mean < v.before.mean);
        assert!(matches!(
            run.result.calibrated_model,
            SerialModelFile::Dh(_)
        ));
        // The kind draws its own plots.
        let names: Vec<&str> = run.artefacts.iter().map(|a| a.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "calibrated_model.json",
                "calibrated_model.urdf",
                "predicted_accuracy.svg",
                "residuals.csv",
                "errors_per_configuration.svg",
                "error_histogram.svg",
                "error_cdf.svg",
                "validation_errors.svg",
                "validation_cdf.svg",
                "errors_per_axis.svg"
            ]
        );
    }

    #[test]
    fn the_typed_constructor_gives_the_result_of_the_json_path() {
        let json = example();
        let inp = json.inputs();
        let crate::jobs::serial::Source::Dh(file) = &inp.model.source else {
            panic!("a DH model")
        };
        let typed = IdentifyJob::from_dh(
            file.clone(),
            inp.meas.clone(),
            [200.012, 199.987, 200.003],
            inp.validation.clone(),
            inp.options.clone(),
        )
        .unwrap();
        let a = json.calibrate(&NoMonitor).unwrap().into_output().unwrap();
        let b = typed.calibrate(&NoMonitor).unwrap().into_output().unwrap();
        assert_eq!(a.fields, b.fields);
    }
}
