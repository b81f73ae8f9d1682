//! `serial.design`: choose `n` configurations of a pool by DETMAX on the identification
//! Jacobian of the nominal model, and report O1..O5 of the selection and of the pool.

use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::identify::{IdentifyInputs, IdentifyOptions, parse_inputs, point_inputs};
use super::{ChainSpec, PlateSpec, SerialModel};
use crate::design::{DetmaxOptions, Indices, Pool, detmax, indices};
use crate::identify::{Problem, rank_revealing};
use crate::measure::{BallPlate, PointMeasurement, PointProblem};
use crate::report::{studies, svg_artefact};
use crate::run::Artefact;
use crate::run::Run;
use crate::run::{Cx, Inputs, JobError, Kind, RunFuture, Table, computed, parse_spec};
use crate::util::Monitor;

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
    pool: Value,
    n: usize,
    #[serde(default)]
    ball_plate: Option<PlateSpec>,
    #[serde(default)]
    options: DesignOptions,
}

/// `options` of `serial.design`.
#[derive(Debug, Clone, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct DesignOptions {
    /// Seed of DETMAX's random start.
    #[serde(default)]
    pub seed: u64,
    /// Parameters to identify (default: the model's list).
    #[serde(default)]
    pub identify: Option<Vec<String>>,
    /// Relative tolerance of the rank detection (default 1e-8).
    #[serde(default)]
    pub rank_tolerance: Option<f64>,
    /// DETMAX excursion limit (default 6).
    #[serde(default)]
    pub max_excursion: Option<usize>,
}

/// The design view of a pool: identifiable columns of the nominal Jacobian, scaled.
#[derive(Debug, Clone)]
pub struct DesignPool {
    /// Blocks for DETMAX.
    pub pool: Pool,
    /// Names of the parameters kept.
    pub kept: Vec<String>,
    /// Names of the parameters the whole pool cannot identify.
    pub unidentifiable: Vec<String>,
    /// The scaled Jacobian (3 rows per configuration), for the indices of a subset.
    jacobian: nalgebra::DMatrix<f64>,
}

impl DesignPool {
    /// Build from validated identification inputs (their measurements are the pool).
    pub fn new(inp: &IdentifyInputs) -> Result<Self, JobError> {
        let problem = PointProblem::new(
            inp.model.chain.clone(),
            inp.ids.clone(),
            inp.plate.clone(),
            inp.meas.clone(),
        )?;
        let x0 = problem.initial();
        let mut j = nalgebra::DMatrix::zeros(problem.residual_count(), problem.unknown_count());
        problem.jacobian(&x0, &mut j)?;
        let rows = 3 * inp.meas.len();
        let j = j.rows(0, rows).clone_owned();
        let rank = rank_revealing(
            &j,
            &inp.pivoting(&problem),
            inp.options.rank_tolerance.unwrap_or(1e-8),
        );
        let names: Vec<String> = problem.unknowns().into_iter().map(|u| u.name).collect();
        let mut kept = rank.kept.clone();
        kept.sort_unstable();
        let mut js = nalgebra::DMatrix::zeros(rows, kept.len());
        for (c, &k) in kept.iter().enumerate() {
            let col = j.column(k);
            js.set_column(c, &(col / col.norm()));
        }
        Ok(Self {
            pool: Pool::from_stacked(&js, 3),
            jacobian: js,
            kept: kept.iter().map(|&k| names[k].clone()).collect(),
            unidentifiable: rank.dropped.iter().map(|&k| names[k].clone()).collect(),
        })
    }

    /// O1..O5 of a subset.
    pub fn indices(&self, subset: &[usize]) -> Indices {
        let mut rows = nalgebra::DMatrix::zeros(3 * subset.len(), self.jacobian.ncols());
        for (k, &i) in subset.iter().enumerate() {
            rows.rows_mut(3 * k, 3)
                .copy_from(&self.jacobian.rows(3 * i, 3));
        }
        indices(&rows, subset.len())
    }
}

/// A validated `serial.design` job.
#[derive(Debug)]
pub struct DesignJob {
    inputs: IdentifyInputs,
    pool_table: Table,
    n: usize,
    seed: u64,
    max_excursion: usize,
}

/// Validate a `serial.design` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<DesignJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    let opts = identify_options(&s.options);
    // A pool without targets is treated as Cartesian points: the Jacobian does not depend
    // on where fixed targets are.
    let mut pool_value = s.pool.clone();
    let table = inputs.table("pool", &s.pool)?;
    if !table.has("ball") && !table.has("x") {
        let mut t = table.clone();
        t.columns.extend(["x".into(), "y".into(), "z".into()]);
        for r in &mut t.rows {
            r.extend([0.0, 0.0, 0.0]);
        }
        pool_value = t.to_json_rows();
    }
    let inp = parse_inputs(
        inputs,
        &s.model,
        s.chain.as_ref(),
        &pool_value,
        s.ball_plate.as_ref(),
        None,
        opts,
    )?;
    DesignJob::from_inputs(inp, table, s.n, &s.options)
}

/// Identification options of a design (the parameters and the rank tolerance).
fn identify_options(o: &DesignOptions) -> IdentifyOptions {
    IdentifyOptions {
        identify: o.identify.clone(),
        rank_tolerance: o.rank_tolerance,
        ..Default::default()
    }
}

/// O1..O5 of the selection and of the whole pool.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DesignObservability {
    /// Of the selection.
    pub selection: Indices,
    /// Of the pool.
    pub pool: Indices,
}

/// log det of the information matrix at DETMAX's start and end.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LogDet {
    /// Random start.
    pub start: f64,
    /// Selection.
    pub selection: f64,
}

/// One design on DETMAX's path, as the result reports it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DesignStep {
    /// Improving excursions made before it (0: the random start).
    pub exchanges: usize,
    /// O1 of the design (dimensionless; see [`DesignHistory::index`]).
    pub o1: f64,
    /// log det(J^T J) of the design, the criterion DETMAX maximises (dimensionless).
    pub log_det: f64,
}

/// `history` of `serial.design`: the observability of the design after each improving
/// DETMAX excursion; the last step is the selection.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DesignHistory {
    /// The search.
    pub method: String,
    /// What `o1` is.
    pub index: String,
    /// What `log_det` is.
    pub criterion: String,
    /// From the random start to the selection.
    pub steps: Vec<DesignStep>,
}

/// The result of `serial.design`: serialises to the job's result fields.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SerialDesign {
    /// Selected pool rows (0-based).
    pub selected: Vec<usize>,
    /// Always 0.
    pub row_index_base: usize,
    /// Configurations selected.
    pub n: usize,
    /// DETMAX seed.
    pub seed: u64,
    /// Observability indices.
    pub observability: DesignObservability,
    /// log det at start and end.
    pub log_det: LogDet,
    /// DETMAX exchanges.
    pub exchanges: usize,
    /// O1 and log det after each exchange (the plot `design_history.svg`).
    pub history: DesignHistory,
    /// Identifiable parameters the design optimises for.
    pub parameters: Vec<String>,
    /// Parameters the whole pool cannot identify.
    pub unidentifiable: Vec<String>,
    /// The selected pool rows (also the main table).
    #[serde(
        serialize_with = "crate::report::json_rows",
        deserialize_with = "crate::report::table_of_json_rows"
    )]
    pub rows: Table,
}

impl DesignJob {
    /// A `serial.design` job from typed inputs (the TriCal campaign's entry point): the
    /// model, the pool as point measurements (radians; ball or Cartesian targets), the ball
    /// plate for ball targets, `n` and the options.
    pub fn new(
        model: SerialModel,
        pool: Vec<PointMeasurement>,
        plate: Option<BallPlate>,
        n: usize,
        options: &DesignOptions,
    ) -> Result<DesignJob, JobError> {
        let dof = model.chain.dof();
        let table = super::measurement_table(&pool, dof);
        let inp = point_inputs(
            model,
            pool,
            plate,
            None,
            Vec::new(),
            identify_options(options),
        )?;
        DesignJob::from_inputs(inp, table, n, options)
    }

    /// The checks shared by the JSON and the typed constructors.
    fn from_inputs(
        inp: IdentifyInputs,
        pool_table: Table,
        n: usize,
        options: &DesignOptions,
    ) -> Result<DesignJob, JobError> {
        inp.require_points("serial.design")?;
        if n == 0 || n > inp.meas.len() {
            return Err(JobError::invalid(
                "n",
                format!(
                    "{} must be between 1 and the pool size {}",
                    n,
                    inp.meas.len()
                ),
            ));
        }
        Ok(DesignJob {
            inputs: inp,
            pool_table,
            n,
            seed: options.seed,
            max_excursion: options.max_excursion.unwrap_or(6),
        })
    }

    /// Run DETMAX: the typed result with the selected rows as the main table.
    pub fn design(&self, monitor: &dyn Monitor) -> Result<Run<SerialDesign>, JobError> {
        let dp = DesignPool::new(&self.inputs)?;
        if 3 * self.n < dp.kept.len() {
            return Err(JobError::invalid(
                "n",
                format!(
                    "{} configurations give {} equations for {} identifiable parameters",
                    self.n,
                    3 * self.n,
                    dp.kept.len()
                ),
            ));
        }
        let sel = detmax(
            &dp.pool,
            &DetmaxOptions {
                n: self.n,
                seed: self.seed,
                max_excursion: self.max_excursion,
                path: true,
            },
            monitor,
        )?;
        let all: Vec<usize> = (0..dp.pool.len()).collect();
        let mut rows = Table {
            columns: self.pool_table.columns.clone(),
            rows: vec![],
        };
        for &i in &sel.selected {
            rows.push(self.pool_table.rows[i].clone());
        }
        let history = DesignHistory {
            method: "DETMAX (exchanges with excursions from a seeded random start)".into(),
            index: "O1 = (s1 ... sm)^(1/m) / sqrt(n) of the design's Jacobian, columns scaled to unit norm (dimensionless), as observability.selection.o1".into(),
            criterion: "log det(J^T J), J the pool's identification Jacobian with columns scaled to unit norm over the pool (dimensionless), as log_det.selection".into(),
            steps: sel
                .history
                .iter()
                .map(|h| DesignStep {
                    exchanges: h.exchanges,
                    o1: dp.indices(&h.selected).o1,
                    log_det: h.log_det,
                })
                .collect(),
        };
        let artefacts = vec![history_plot(&history, self.n, dp.pool.len(), dp.kept.len())];
        let result = SerialDesign {
            history,
            observability: DesignObservability {
                selection: dp.indices(&sel.selected),
                pool: dp.indices(&all),
            },
            selected: sel.selected,
            row_index_base: 0,
            n: self.n,
            seed: self.seed,
            log_det: LogDet {
                start: sel.log_det_start,
                selection: sel.log_det,
            },
            exchanges: sel.exchanges,
            parameters: dp.kept,
            unidentifiable: dp.unidentifiable,
            rows: rows.clone(),
        };
        Ok(Run {
            result,
            main_table: Some(rows),
            artefacts,
        })
    }
}

/// `design_history.svg`: O1 of the design after each improving DETMAX excursion.
fn history_plot(h: &DesignHistory, n: usize, pool: usize, params: usize) -> Artefact {
    let pts: Vec<(f64, f64)> = h.steps.iter().map(|s| (s.exchanges as f64, s.o1)).collect();
    svg_artefact(
        "design_history.svg",
        studies::history(&studies::History {
            title: "Observability index O1 during DETMAX",
            dataset: &format!(
                "{n} of {pool} pool configurations, {params} identifiable parameters (nominal model)"
            ),
            x_label: "improving DETMAX excursions (0: random start)",
            y_label: "O1 of the selection (dimensionless)",
            points: &pts,
            chosen: None,
        }),
    )
}

/// DETMAX selection of `n` configurations of `pool` (typed `serial.design`): the selected
/// indices into `pool`, for campaigns that only need the choice.
pub fn select(
    model: SerialModel,
    pool: Vec<PointMeasurement>,
    plate: Option<BallPlate>,
    n: usize,
    options: &DesignOptions,
    monitor: &dyn Monitor,
) -> Result<Vec<usize>, JobError> {
    let job = DesignJob::new(model, pool, plate, n, options)?;
    Ok(job.design(monitor)?.result.selected)
}

impl Kind for DesignJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::design)
    }
}
