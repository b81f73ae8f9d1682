//! `serial.dispersion`: for each set size and repetition, a DETMAX selection from a random
//! start, an identification and the validation errors; quartiles of their mean and std per
//! size, and the spread of every parameter at the largest size (the paper's Figs. 8-9,
//! Table 7). Repetitions run on all cores.

use std::collections::HashMap;
use std::sync::Arc;

use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::design::DesignPool;
use super::identify::{IdentifyInputs, IdentifyOptions, parse_inputs, position_errors};
use super::{ChainSpec, PlateSpec};
use crate::design::{DetmaxOptions, detmax};
use crate::report::{DispersionBox, dispersion_plots};
use crate::run::{Cx, Inputs, JobError, Kind, RunFuture, Table, computed, parse_spec};
use crate::util::stats::{Quartiles, mean};
use crate::util::{Monitor, Summary};

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
    #[schemars(schema_with = "crate::run::schema::table")]
    validation: Value,
    sizes: Vec<usize>,
    repetitions: usize,
    #[serde(default)]
    options: IdentifyOptions,
}

/// A validated `serial.dispersion` job.
#[derive(Debug)]
pub struct DispersionJob {
    inputs: IdentifyInputs,
    sizes: Vec<usize>,
    repetitions: usize,
    seed: u64,
}

/// Validate a `serial.dispersion` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<DispersionJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    let seed = s.options.seed.unwrap_or(0);
    let inp = parse_inputs(
        inputs,
        &s.model,
        s.chain.as_ref(),
        &s.measurements,
        s.ball_plate.as_ref(),
        Some(&s.validation),
        s.options,
    )?;
    inp.require_points("serial.dispersion")?;
    if s.sizes.is_empty() {
        return Err(JobError::invalid("sizes", "give at least one set size"));
    }
    for (k, &n) in s.sizes.iter().enumerate() {
        if n == 0 || n > inp.meas.len() {
            return Err(JobError::invalid(
                format!("sizes[{k}]"),
                format!(
                    "{n} must be between 1 and the {} measurements",
                    inp.meas.len()
                ),
            ));
        }
    }
    if s.repetitions == 0 {
        return Err(JobError::invalid("repetitions", "must be at least 1"));
    }
    Ok(DispersionJob {
        inputs: inp,
        sizes: s.sizes,
        repetitions: s.repetitions,
        seed,
    })
}

/// One identification of the study.
struct Run {
    size: usize,
    repetition: usize,
    mean_error: f64,
    std_error: f64,
    values: Vec<f64>,
}

/// What the study keeps of one identification.
#[derive(Clone)]
struct Fitted {
    mean_error: f64,
    std_error: f64,
    values: Vec<f64>,
}

/// Identifications by selected set (None: failed or not converged), shared by the workers.
#[derive(Default)]
struct Memo(Mutex<HashMap<Vec<usize>, Option<Fitted>>>);

impl Memo {
    /// The fit of `set`, from the memo or by `fit` (outside the lock: two workers may fit
    /// the same set at once, and both get the same result).
    fn get_or_fit(&self, set: &[usize], fit: impl FnOnce() -> Option<Fitted>) -> Option<Fitted> {
        if let Some(f) = self.0.lock().ok().and_then(|m| m.get(set).cloned()) {
            return f;
        }
        let f = fit();
        if let Ok(mut m) = self.0.lock() {
            m.insert(set.to_vec(), f.clone());
        }
        f
    }
}

/// Progress reports per study at most (one per identification would wake the job's
/// runtime 2,007 times).
const PROGRESS_STEPS: usize = 200;

/// The study as a library call: results per (size, repetition), in order.
fn study(
    inp: &IdentifyInputs,
    sizes: &[usize],
    reps: usize,
    seed: u64,
    monitor: &dyn Monitor,
) -> Result<(Vec<Run>, usize), JobError> {
    let dp = DesignPool::new(inp)?;
    let validation = inp.validation.as_deref().unwrap_or(&[]);
    let tasks: Vec<(usize, usize)> = sizes
        .iter()
        .flat_map(|&n| (0..reps).map(move |r| (n, r)))
        .collect();
    let next = AtomicUsize::new(0);
    let done = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<Run>>> = Mutex::new((0..tasks.len()).map(|_| None).collect());
    let failures = AtomicUsize::new(0);
    let cancelled = std::sync::atomic::AtomicBool::new(false);
    // Repetitions from different starts often end on the same set (at 80 of 360, about
    // half do); its identification is the same, so each set is fitted once.
    let memo = Memo::default();
    let fit = |selected: &[usize]| {
        inp.identify_values(Some(selected), &crate::util::NoMonitor)
            .ok()
            .filter(|(_, sol)| sol.converged())
            .map(|(problem, sol)| {
                let e = position_errors(&problem.model(&sol.x), validation);
                let s = Summary::of(&e, "");
                Fitted {
                    mean_error: s.mean,
                    std_error: s.std,
                    values: sol.params.iter().map(|p| p.value).collect(),
                }
            })
    };
    let threads = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(tasks.len().max(1));
    std::thread::scope(|s| {
        for _ in 0..threads {
            s.spawn(|| {
                loop {
                    let t = next.fetch_add(1, Ordering::Relaxed);
                    if t >= tasks.len() || monitor.is_cancelled() {
                        if monitor.is_cancelled() {
                            cancelled.store(true, Ordering::Relaxed);
                        }
                        break;
                    }
                    let (n, r) = tasks[t];
                    let task_seed =
                        seed ^ ((n as u64) << 32) ^ (r as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
                    let run = detmax(
                        &dp.pool,
                        &DetmaxOptions {
                            n,
                            seed: task_seed,
                            max_excursion: 4,
                            path: false,
                        },
                        &crate::util::NoMonitor,
                    )
                    .ok()
                    .and_then(|sel| memo.get_or_fit(&sel.selected, || fit(&sel.selected)))
                    .map(|f| Run {
                        size: n,
                        repetition: r,
                        mean_error: f.mean_error,
                        std_error: f.std_error,
                        values: f.values,
                    });
                    if run.is_none() {
                        failures.fetch_add(1, Ordering::Relaxed);
                    }
                    if let Ok(mut v) = results.lock() {
                        v[t] = run;
                    }
                    // Progress in steps of 1/200 (each report wakes the job's runtime:
                    // one per identification cost ~1.5 % of the study).
                    let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                    if d * PROGRESS_STEPS / tasks.len() != (d - 1) * PROGRESS_STEPS / tasks.len() {
                        monitor.progress(d as f64 / tasks.len() as f64, "identifications");
                    }
                }
            });
        }
    });
    if cancelled.load(Ordering::Relaxed) {
        return Err(JobError::Cancelled);
    }
    let runs = results
        .into_inner()
        .map_err(|_| JobError::internal("the dispersion runs", "a worker panicked"))?
        .into_iter()
        .flatten()
        .collect();
    Ok((runs, failures.load(Ordering::Relaxed)))
}

/// One set size of a dispersion study.
#[derive(Debug, Clone, Serialize)]
pub struct DispersionSize {
    /// Configurations in the calibration set.
    pub n: usize,
    /// Converged identifications.
    pub identifications: usize,
    /// Quartiles of the mean validation error.
    pub mean_error: Quartiles,
    /// Quartiles of the std of the validation error.
    pub std_error: Quartiles,
    /// Length unit.
    pub unit: String,
}

/// Spread of one identified parameter at the largest set size.
#[derive(Debug, Clone, Serialize)]
pub struct ParameterDispersion {
    /// Parameter name.
    pub name: String,
    /// Report unit.
    pub unit: String,
    /// Nominal value.
    pub nominal: f64,
    /// Mean over the identifications.
    pub mean: f64,
    /// Standard deviation.
    pub std: f64,
    /// Smallest.
    pub min: f64,
    /// Largest.
    pub max: f64,
}

/// One converged identification of the study: its validation errors.
#[derive(Debug, Clone, Serialize)]
pub struct DispersionRun {
    /// Configurations in its calibration set.
    pub n: usize,
    /// Repetition (0-based) at that size.
    pub repetition: usize,
    /// Mean validation error (`unit`).
    pub mean_error: f64,
    /// Standard deviation of the validation error (`unit`).
    pub std_error: f64,
    /// Length unit.
    pub unit: String,
}

/// `parameters_at_largest_size` of `serial.dispersion`.
#[derive(Debug, Clone, Serialize)]
pub struct LargestSize {
    /// The largest size.
    pub n: usize,
    /// Per parameter (empty when no identification converged there).
    pub parameters: Vec<ParameterDispersion>,
}

/// The result of `serial.dispersion`: serialises to the job's result fields.
#[derive(Debug, Clone, Serialize)]
pub struct DispersionResult {
    /// Per set size with converged identifications.
    pub sizes: Vec<DispersionSize>,
    /// Every converged identification, by size then repetition: the values the quartiles
    /// of `sizes` (and the box plots) summarise.
    pub runs: Vec<DispersionRun>,
    /// Repetitions per size.
    pub repetitions: usize,
    /// Converged identifications.
    pub identifications: usize,
    /// Failed (or not converged) ones.
    pub failures: usize,
    /// Parameter spread at the largest size.
    pub parameters_at_largest_size: LargestSize,
    /// Seed.
    pub seed: u64,
}

impl DispersionResult {
    /// The box-plot view of the sizes, for [`crate::report::dispersion_plots`].
    pub fn boxes(&self) -> Vec<DispersionBox> {
        let q = |q: &Quartiles| [q.min, q.q1, q.median, q.q3, q.max];
        self.sizes
            .iter()
            .map(|s| DispersionBox {
                n: s.n as f64,
                mean_error: q(&s.mean_error),
                std_error: q(&s.std_error),
            })
            .collect()
    }
}

impl DispersionJob {
    /// Run the study: the typed result, the quartile table as the main table, and the box
    /// plots as SVG artefacts.
    pub fn study(
        &self,
        monitor: &dyn Monitor,
    ) -> Result<crate::run::Run<DispersionResult>, JobError> {
        let inp = &self.inputs;
        let (runs, failures) = study(inp, &self.sizes, self.repetitions, self.seed, monitor)?;
        let unit = inp.model.length_unit();
        let mut per_size = Vec::new();
        let mut table = Table::new(&[
            "n",
            "mean_min",
            "mean_q1",
            "mean_median",
            "mean_q3",
            "mean_max",
            "std_min",
            "std_q1",
            "std_median",
            "std_q3",
            "std_max",
        ]);
        for &n in &self.sizes {
            let rs: Vec<&Run> = runs.iter().filter(|r| r.size == n).collect();
            if rs.is_empty() {
                continue;
            }
            let m = Quartiles::of(&rs.iter().map(|r| r.mean_error).collect::<Vec<_>>());
            let s = Quartiles::of(&rs.iter().map(|r| r.std_error).collect::<Vec<_>>());
            table.push(vec![
                n as f64, m.min, m.q1, m.median, m.q3, m.max, s.min, s.q1, s.median, s.q3, s.max,
            ]);
            per_size.push(DispersionSize {
                n,
                identifications: rs.len(),
                mean_error: m,
                std_error: s,
                unit: unit.to_string(),
            });
        }
        let largest = *self.sizes.iter().max().unwrap_or(&0);
        let last: Vec<&Run> = runs.iter().filter(|r| r.size == largest).collect();
        let names = crate::measure::PointProblem::new(
            inp.model.chain.clone(),
            inp.ids.clone(),
            inp.plate.clone(),
            inp.meas.clone(),
        )?
        .unknowns();
        let params: Vec<ParameterDispersion> = names
            .iter()
            .enumerate()
            .filter(|_| !last.is_empty())
            .map(|(k, u)| {
                let v: Vec<f64> = last.iter().map(|r| r.values[k]).collect();
                let s = Summary::of(&v, &u.unit);
                ParameterDispersion {
                    name: u.name.clone(),
                    unit: u.unit.clone(),
                    nominal: u.nominal * u.to_report,
                    mean: mean(&v),
                    std: s.std,
                    min: s.min,
                    max: s.max,
                }
            })
            .collect();
        let unit_s = unit.to_string();
        let result = DispersionResult {
            sizes: per_size,
            runs: runs
                .iter()
                .map(|r| DispersionRun {
                    n: r.size,
                    repetition: r.repetition,
                    mean_error: r.mean_error,
                    std_error: r.std_error,
                    unit: unit_s.clone(),
                })
                .collect(),
            repetitions: self.repetitions,
            identifications: runs.len(),
            failures,
            parameters_at_largest_size: LargestSize {
                n: largest,
                parameters: params,
            },
            seed: self.seed,
        };
        let artefacts = dispersion_plots(&result.boxes(), unit, result.runs.len());
        Ok(crate::run::Run {
            result,
            main_table: Some(table),
            artefacts,
        })
    }
}

impl Kind for DispersionJob {
    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        computed(self, cx, Self::study)
    }
}

#[cfg(test)]
mod tests {
    use super::{Fitted, Memo};
    use std::cell::Cell;

    /// Each set is fitted once; a repeat gets the stored fit, failures included.
    #[test]
    fn the_memo_fits_each_set_once() {
        let memo = Memo::default();
        let calls = Cell::new(0);
        let fit = |v: f64| {
            calls.set(calls.get() + 1);
            (v > 0.0).then(|| Fitted {
                mean_error: v,
                std_error: 2.0 * v,
                values: vec![v; 3],
            })
        };
        let a = memo.get_or_fit(&[1, 4, 9], || fit(1.5));
        let again = memo.get_or_fit(&[1, 4, 9], || fit(99.0));
        assert_eq!(again.map(|f| f.values), a.map(|f| f.values));
        assert!(memo.get_or_fit(&[2, 3], || fit(-1.0)).is_none());
        assert!(memo.get_or_fit(&[2, 3], || fit(7.0)).is_none());
        let other = memo.get_or_fit(&[1, 4], || fit(7.0));
        assert_eq!(other.map(|f| f.mean_error), Some(7.0));
        assert_eq!(calls.get(), 3);
    }
}
