//! What the report shows of a result, as typed pieces: each kind's result type implements
//! [`Reportable`] over its own fields, so a renamed field fails to compile instead of
//! silently dropping a row. Every number keeps its JSON pointer in the result
//! (`data-pointer`), so tests and readers can check the report against the result JSON.

use serde::Serialize;
use serde_json::Value;

use crate::identify::ParamReport;
use crate::identify::verdict::Assessment;
use crate::util::Summary;

/// A number of the result and its JSON pointer.
#[derive(Debug, Clone, PartialEq)]
pub struct Num {
    /// The value (non-finite shows as a dash, without pointer).
    pub value: f64,
    /// Where it is in the result JSON, e.g. `/residuals/after/mean`.
    pub pointer: String,
}

impl Num {
    /// `value` found at `pointer`.
    pub fn at(value: f64, pointer: impl Into<String>) -> Self {
        Self {
            value,
            pointer: pointer.into(),
        }
    }
}

/// One cell of a report table.
#[derive(Debug, Clone, PartialEq)]
pub enum Cell {
    /// A row heading (`<th>`).
    Head(String),
    /// Text (escaped when rendered).
    Text(String),
    /// A number of the result.
    Num(Num),
    /// A number the result does not have (a dash).
    Missing,
}

/// A table of the validation section: title, column headings, rows, an optional note.
#[derive(Debug, Clone, PartialEq)]
pub struct NumTable {
    /// Title (`<h3>`).
    pub title: String,
    /// Column headings.
    pub head: Vec<String>,
    /// Rows of cells.
    pub rows: Vec<Vec<Cell>>,
    /// A note under the table.
    pub note: Option<String>,
}

impl NumTable {
    /// Before/after statistics (count, mean, median, std, min, max, rms) of `base`
    /// (e.g. `/validation`), titled `title` followed by the unit.
    pub fn before_after(
        title: &str,
        base: &str,
        before: &Summary,
        after: &Summary,
        note: Option<&str>,
    ) -> Self {
        let side = |name: &str, s: &Summary| {
            let p = |k: &str| format!("{base}/{name}/{k}");
            vec![
                Cell::Head(name.into()),
                Cell::Num(Num::at(s.count as f64, p("count"))),
                Cell::Num(Num::at(s.mean, p("mean"))),
                Cell::Num(Num::at(s.median, p("median"))),
                Cell::Num(Num::at(s.std, p("std"))),
                Cell::Num(Num::at(s.min, p("min"))),
                Cell::Num(Num::at(s.max, p("max"))),
                Cell::Num(Num::at(s.rms, p("rms"))),
            ]
        };
        let head = ["", "count", "mean", "median", "std", "min", "max", "rms"];
        Self {
            title: format!("{title} ({})", after.unit),
            head: head.iter().map(|h| h.to_string()).collect(),
            rows: vec![side("before", before), side("after", after)],
            note: note.map(str::to_string),
        }
    }
}

/// One headline line: the same quantity before and after calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct HeadlineRow {
    /// What it is, e.g. `Residual mean, calibration set`.
    pub label: String,
    /// Before calibration.
    pub before: Num,
    /// After calibration.
    pub after: Num,
    /// Unit of both.
    pub unit: String,
}

impl HeadlineRow {
    /// A line from two numbers of the result.
    pub fn new(label: &str, before: Num, after: Num, unit: &str) -> Self {
        Self {
            label: label.into(),
            before,
            after,
            unit: unit.into(),
        }
    }

    /// Mean and max lines of a before/after statistic at `base` (`label` e.g. `Residual`,
    /// `set` e.g. `calibration set`).
    pub fn mean_max(label: &str, set: &str, base: &str, b: &Summary, a: &Summary) -> Vec<Self> {
        ["mean", "max"]
            .iter()
            .map(|k| {
                let (bv, av) = if *k == "mean" {
                    (b.mean, a.mean)
                } else {
                    (b.max, a.max)
                };
                Self::new(
                    &format!("{label} {k}, {set}"),
                    Num::at(bv, format!("{base}/before/{k}")),
                    Num::at(av, format!("{base}/after/{k}")),
                    &a.unit,
                )
            })
            .collect()
    }
}

/// The verdict of an identification and its residual degrees of freedom.
#[derive(Debug, Clone, PartialEq)]
pub struct VerdictBlock {
    /// Verdict and reasons, worst first.
    pub assessment: Assessment,
    /// Residual degrees of freedom.
    pub dof: Option<usize>,
}

/// One row of the parameter table.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamRow {
    /// Parameter name.
    pub name: String,
    /// Unit of nominal, value and std.
    pub unit: String,
    /// Nominal value.
    pub nominal: Num,
    /// Identified value.
    pub value: Num,
    /// Standard deviation (none when held).
    pub std: Option<Num>,
    /// Whether the data determine it.
    pub identifiable: bool,
    /// `lower` or `upper` when the estimate sits on a bound.
    pub at_bound: Option<String>,
    /// Effect size (residual unit).
    pub effect_size: Num,
}

impl ParamRow {
    /// The row of a solver's parameter report found at `pointer` (e.g. `/parameters/3`).
    pub fn of(p: &ParamReport, pointer: &str) -> Self {
        Self {
            name: p.name.clone(),
            unit: p.unit.clone(),
            nominal: Num::at(p.nominal, format!("{pointer}/nominal")),
            value: Num::at(p.value, format!("{pointer}/value")),
            std: p.std.map(|s| Num::at(s, format!("{pointer}/std"))),
            identifiable: p.identifiable,
            at_bound: p.at_bound.as_deref().map(str::to_string),
            effect_size: Num::at(p.effect_size, format!("{pointer}/effect_size")),
        }
    }
}

/// The parameter table and the figures the report states with it.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ParamTable {
    /// One row per unknown, in result order.
    pub rows: Vec<ParamRow>,
    /// Condition number of the identified unknowns.
    pub condition_number: Option<f64>,
    /// Unit of the effect sizes (the residual unit).
    pub effect_unit: String,
}

impl ParamTable {
    /// The table of `params` stored at `/parameters`.
    pub fn of<'a>(
        params: impl IntoIterator<Item = &'a ParamReport>,
        condition_number: Option<f64>,
        effect_unit: &str,
    ) -> Self {
        Self {
            rows: params
                .into_iter()
                .enumerate()
                .map(|(i, p)| ParamRow::of(p, &format!("/parameters/{i}")))
                .collect(),
            condition_number: condition_number.filter(|c| c.is_finite()),
            effect_unit: effect_unit.into(),
        }
    }
}

/// Parameters the identification held or found weak, by name.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Held {
    /// Held at nominal: not identifiable from these data.
    pub unidentifiable: Vec<String>,
    /// Identified but weakly observable.
    pub weakly_observable: Vec<String>,
    /// Held at nominal: effect below the noise.
    pub unobservable: Vec<String>,
}

/// How the solver ended.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ConvergenceView {
    /// Status word (`converged`, `degenerate`, `not_converged`).
    pub status: Option<String>,
    /// Whether it converged.
    pub converged: Option<bool>,
    /// Iterations used.
    pub iterations: Option<usize>,
    /// Why the solution is degenerate (as text).
    pub degenerate: Option<String>,
}

/// A block of scalar figures (a campaign's counts and times), one row per field.
#[derive(Debug, Clone, PartialEq)]
pub struct Facts {
    /// Its field name in the result, e.g. `campaign`.
    pub name: String,
    /// (field, value) rows.
    pub rows: Vec<(String, Cell)>,
}

impl Facts {
    /// The scalar fields of `value` (a typed struct) stored at `/{name}`, in serialised
    /// order: numbers with their pointers, anything else as text.
    pub fn of(name: &str, value: &impl Serialize) -> Option<Self> {
        match serde_json::to_value(value) {
            Ok(Value::Object(o)) => Some(Self::of_object(name, &o)),
            _ => None,
        }
    }

    /// The scalar fields of a JSON object stored at `/{name}`.
    pub fn of_object(name: &str, o: &serde_json::Map<String, Value>) -> Self {
        let rows = o
            .iter()
            .filter(|(_, v)| !v.is_object() && !v.is_array())
            .map(|(k, v)| {
                let cell = match v {
                    Value::Number(n) => n
                        .as_f64()
                        .map(|x| Cell::Num(Num::at(x, format!("/{name}/{k}"))))
                        .unwrap_or(Cell::Missing),
                    Value::String(s) => Cell::Text(s.clone()),
                    Value::Null => Cell::Text("—".into()),
                    other => Cell::Text(other.to_string()),
                };
                (k.clone(), cell)
            })
            .collect();
        Self {
            name: name.into(),
            rows,
        }
    }
}

/// A design of experiments (`serial.design`): the configurations chosen and how well they
/// observe the parameters, shown instead of before/after errors and a parameter table.
#[derive(Debug, Clone, PartialEq)]
pub struct DesignView {
    /// What was chosen from what, by which search (one sentence).
    pub summary: String,
    /// The selected configurations, one row each (the job's main table).
    pub selected: NumTable,
    /// O1..O5 of the selection against the pool.
    pub observability: NumTable,
    /// The search's history (criterion after each improving step).
    pub history: NumTable,
}

/// A result as the report reads it. Every method defaults to the embedded result's (a
/// campaign embeds its identification), else to nothing: a kind implements what it has.
pub trait Reportable: std::fmt::Debug {
    /// The result this one embeds and reports through (a campaign's identification).
    fn embedded(&self) -> Option<&dyn Reportable> {
        None
    }
    /// The verdict and its reasons (identifications).
    fn verdict(&self) -> Option<VerdictBlock> {
        self.embedded().and_then(|e| e.verdict())
    }
    /// Before/after figures, first in the report.
    fn headline(&self) -> Vec<HeadlineRow> {
        self.embedded().map(|e| e.headline()).unwrap_or_default()
    }
    /// The parameter table.
    fn parameters(&self) -> Option<ParamTable> {
        self.embedded().and_then(|e| e.parameters())
    }
    /// Held and weakly observable parameters.
    fn held(&self) -> Held {
        self.embedded().map(|e| e.held()).unwrap_or_default()
    }
    /// How the solver ended.
    fn convergence(&self) -> Option<ConvergenceView> {
        self.embedded().and_then(|e| e.convergence())
    }
    /// Blocks of figures shown under the data sets (a campaign's counts).
    fn facts(&self) -> Vec<Facts> {
        self.embedded().map(|e| e.facts()).unwrap_or_default()
    }
    /// The validation section's tables: held-out errors, residuals, Table 3, folds.
    fn tables(&self) -> Vec<NumTable> {
        self.embedded().map(|e| e.tables()).unwrap_or_default()
    }
    /// The result's own warnings (plain text).
    fn warnings(&self) -> Vec<String> {
        self.embedded().map(|e| e.warnings()).unwrap_or_default()
    }
    /// The gauge freedom the data leave, if any.
    fn gauge_freedom(&self) -> Option<String> {
        self.embedded().and_then(|e| e.gauge_freedom())
    }
    /// A design of experiments' view (designs only).
    fn design(&self) -> Option<DesignView> {
        self.embedded().and_then(|e| e.design())
    }
    /// What the "before" column is, when not the nominal model the job started from (a
    /// campaign that started from the cell's current calibration).
    fn before_label(&self) -> Option<String> {
        self.embedded().and_then(|e| e.before_label())
    }
}

/// The PCR Table 3 (rows: set, error, model, max, mean, min, unit).
pub fn model_error_table(rows: Vec<Vec<Cell>>) -> NumTable {
    let head = ["set", "error", "model", "max", "mean", "min", "unit"];
    NumTable {
        title: "Model error (Table 3)".into(),
        head: head.iter().map(|h| h.to_string()).collect(),
        rows,
        note: None,
    }
}

/// The cross-validation folds (rows: fold, held-out samples, nominal, calibrated RMSE).
pub fn folds_table(rows: Vec<Vec<Cell>>) -> NumTable {
    let head = ["fold", "held-out samples", "nominal", "calibrated"];
    NumTable {
        title: "Cross-validation (held-out marker RMSE, mm)".into(),
        head: head.iter().map(|h| h.to_string()).collect(),
        rows,
        note: None,
    }
}
