//! `serial.design`: choose `n` configurations of a pool by DETMAX on the identification
//! Jacobian of the nominal model, and report O1..O5 of the selection and of the pool.

use std::sync::Arc;

use serde::Deserialize;
use serde_json::{Map, Value, json};

use super::identify::{IdentifyInputs, IdentifyOptions, parse_inputs};
use super::{ChainSpec, PlateSpec};
use crate::design::{DetmaxOptions, Indices, Pool, detmax, indices};
use crate::identify::{Problem, rank_revealing};
use crate::jobs::{Cx, Inputs, JobError, Kind, Output, RunFuture, Table, computed, parse_spec};
use crate::measure::PointProblem;
use crate::util::Monitor;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Spec {
    #[allow(dead_code)]
    kind: String,
    model: Value,
    #[serde(default)]
    chain: Option<ChainSpec>,
    pool: Value,
    n: usize,
    #[serde(default)]
    ball_plate: Option<PlateSpec>,
    #[serde(default)]
    options: DesignOptions,
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct DesignOptions {
    #[serde(default)]
    seed: u64,
    #[serde(default)]
    identify: Option<Vec<String>>,
    #[serde(default)]
    rank_tolerance: Option<f64>,
    #[serde(default)]
    max_excursion: Option<usize>,
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
            kept: kept.iter().map(|&k| names[k].clone()).collect(),
            unidentifiable: rank.dropped.iter().map(|&k| names[k].clone()).collect(),
        })
    }

    /// O1..O5 of a subset.
    pub fn indices(&self, subset: &[usize]) -> Indices {
        indices(&self.pool.stacked(subset), subset.len())
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
    let opts = IdentifyOptions {
        identify: s.options.identify.clone(),
        rank_tolerance: s.options.rank_tolerance,
        ..Default::default()
    };
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
    inp.require_points("serial.design")?;
    if s.n == 0 || s.n > inp.meas.len() {
        return Err(JobError::invalid(
            "n",
            format!(
                "{} must be between 1 and the pool size {}",
                s.n,
                inp.meas.len()
            ),
        ));
    }
    Ok(DesignJob {
        inputs: inp,
        pool_table: table,
        n: s.n,
        seed: s.options.seed,
        max_excursion: s.options.max_excursion.unwrap_or(6),
    })
}

impl Kind for DesignJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::execute)
    }
}

impl DesignJob {
    /// Compute the job's output (on the blocking pool, see [`Kind::run`]).
    pub fn execute(&self, monitor: &dyn Monitor) -> Result<Output, JobError> {
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
        let mut f = Map::new();
        f.insert("selected".into(), json!(sel.selected));
        f.insert("row_index_base".into(), json!(0));
        f.insert("n".into(), json!(self.n));
        f.insert("seed".into(), json!(self.seed));
        f.insert(
            "observability".into(),
            json!({"selection": dp.indices(&sel.selected), "pool": dp.indices(&all)}),
        );
        f.insert(
            "log_det".into(),
            json!({"start": sel.log_det_start, "selection": sel.log_det}),
        );
        f.insert("exchanges".into(), json!(sel.exchanges));
        f.insert("parameters".into(), json!(dp.kept));
        f.insert("unidentifiable".into(), json!(dp.unidentifiable));
        f.insert("rows".into(), rows.to_json_rows());
        Ok(Output {
            fields: f,
            main_table: Some(rows),
            artefacts: vec![],
        })
    }
}
