//! `serial.compensate_program`: an ABB RAPID module filtered through a calibrated model.
//! Every literal robtarget is rewritten so that the controller's *nominal* kinematics reach
//! the pose the *calibrated* model predicts (t' = nominal FK(calibrated IK(t)), cf data of
//! those joints); optionally jointtargets for `MoveAbsJ`; optionally the module uploaded to
//! a cell's controller and loaded into its task. A new kind rather than an option of
//! `serial.compensate`: its input is a program, not a targets table, its output a program,
//! and with `upload` it drives a device (operators only). The maths is
//! [`crate::model::rapid`].

use std::collections::BTreeMap;
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::compensate::{resolve_model, set_payload};
use super::{ChainSpec, SerialModel};
use crate::model::compensate::Tolerances;
use crate::model::dh::Payload;
use crate::model::rapid::correct::Filter;
use crate::model::rapid::parse;
use crate::model::rapid::program::{self, Filtered, Outcome, TargetReport};
use crate::run::Run;
use crate::run::{
    Artefact, Cx, Inputs, JobError, Kind, Produced, RunFuture, Table, computed, parse_spec,
};
use crate::util::Monitor;

/// A `serial.compensate_program` job document.
#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    /// The calibrated model (DH file in mm), or a `serial.identify` result whose
    /// `calibrated_model` is used.
    #[schemars(schema_with = "crate::run::schema::serial_model")]
    model: Value,
    /// The controller's nominal model (DH file in mm, same joints).
    #[schemars(schema_with = "crate::run::schema::serial_model")]
    nominal: Value,
    #[serde(default)]
    chain: Option<ChainSpec>,
    /// The RAPID module: a file name (`.mod`, `.modx`) or the module text inline.
    module: String,
    /// Replaces the calibrated model's payload (changes the static deflection).
    #[serde(default)]
    payload: Option<Payload>,
    #[serde(default)]
    options: Options,
    /// Upload the filtered module to a cell's controller and load it (operators only).
    #[serde(default)]
    upload: Option<Upload>,
}

/// `options` of a `serial.compensate_program` job.
#[derive(Debug, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct Options {
    /// `tooldata` RAPID literals by name (tools declared in another module), over the
    /// module's.
    #[serde(default)]
    tooldata: BTreeMap<String, String>,
    /// `wobjdata` RAPID literals by name, over the module's.
    #[serde(default)]
    wobjdata: BTreeMap<String, String>,
    /// Tool of targets no move instruction uses (default `tool0`).
    #[serde(default)]
    tool: Option<String>,
    /// Work object of targets no move instruction uses (default `wobj0`).
    #[serde(default)]
    wobj: Option<String>,
    /// The program's world frame: `base` (default: the robot frame {0} of each model) or
    /// `world` (each model's {W}, their `base` frames used).
    #[serde(default)]
    frame: WorldFrame,
    /// Also declare `<name>_jt` jointtargets (calibrated joints) for `MoveAbsJ`.
    #[serde(default)]
    jointtargets: bool,
    /// Largest position residual of the calibrated solution (mm, default 1e-4).
    #[serde(default)]
    tolerance_mm: Option<f64>,
    /// Largest orientation residual (deg, default 1e-5).
    #[serde(default)]
    tolerance_deg: Option<f64>,
}

/// The program's world frame.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
enum WorldFrame {
    /// The robot frame {0}.
    #[default]
    Base,
    /// The models' {W}.
    World,
}

/// `upload` of a `serial.compensate_program` job.
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct Upload {
    /// The ball-centring cell whose controller takes the module.
    cell: String,
    /// File name on the controller (default: the module's name + `.mod`).
    #[serde(default)]
    file: Option<String>,
    /// Stop the RAPID program first (a controller does not load into a running task).
    #[serde(default)]
    stop_program: bool,
}

/// A validated `serial.compensate_program` job.
#[derive(Debug)]
pub struct ProgramJob {
    filter: Filter,
    text: String,
    file: String,
    options: program::Options,
    upload: Option<Upload>,
}

/// The controller's side of an upload.
#[derive(Debug, Clone, Serialize)]
pub struct Uploaded {
    /// The cell.
    pub cell: String,
    /// The file's path on the controller.
    pub path: String,
    /// The module loaded into the task.
    pub module: String,
    /// Whether the program was stopped first.
    pub program_stopped: bool,
}

/// Counts per outcome and the largest correction.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Summary {
    /// Robtargets (array elements each).
    pub targets: usize,
    /// Rewritten.
    pub corrected: usize,
    /// Correction below the printed resolution.
    pub unchanged: usize,
    /// Not corrected (every other outcome).
    pub not_corrected: usize,
    /// Mean position correction of the corrected targets (mm).
    pub mean_correction_mm: f64,
    /// Largest position correction (mm).
    pub max_correction_mm: f64,
    /// Largest orientation correction (deg).
    pub max_correction_deg: f64,
}

/// The result of `serial.compensate_program`.
#[derive(Debug, Clone, Serialize)]
pub struct ProgramResult {
    /// Module name.
    pub module: String,
    /// The filtered module's file name (an artefact).
    pub file: String,
    /// Counts and largest corrections.
    pub summary: Summary,
    /// One row per robtarget.
    pub targets: Vec<TargetReport>,
    /// The upload, when asked.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub upload: Option<Uploaded>,
}

/// Validate a `serial.compensate_program` job: models, module (a module that does not
/// parse is refused naming the line), options.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<ProgramJob, JobError> {
    let spec: Spec = parse_spec(doc)?;
    let mut cal = resolve_model(inputs, &spec.model, spec.chain.as_ref())?;
    if let Some(p) = &spec.payload {
        set_payload(&mut cal, p)?;
    }
    let nominal = resolve_model(inputs, &spec.nominal, spec.chain.as_ref())?;
    for (field, m) in [("model", &cal), ("nominal", &nominal)] {
        millimetres(field, m)?;
    }
    let positive = |field: &str, v: Option<f64>, default: f64| match v {
        None => Ok(default),
        Some(v) if v.is_finite() && v > 0.0 => Ok(v),
        Some(v) => Err(JobError::invalid(
            field,
            format!("{v} is not a positive number"),
        )),
    };
    let tol = Tolerances {
        position: positive("options.tolerance_mm", spec.options.tolerance_mm, 1e-4)?,
        angle: positive("options.tolerance_deg", spec.options.tolerance_deg, 1e-5)?.to_radians(),
        singular_sin: 1e-3,
        singular_shoulder: 1.0,
    };
    let world = spec.options.frame == WorldFrame::World;
    let filter = Filter::new(&cal.chain, &nominal.chain, world, tol, 5.0)
        .map_err(|e| JobError::invalid("model", e.to_string()))?;
    let text = inputs.text_or_inline("module", &Value::String(spec.module.clone()))?;
    let m = parse(&text).map_err(|e| JobError::invalid("module", e.to_string()))?;
    let file = if spec.module.contains('\n') {
        format!("{}.mod", m.name)
    } else {
        std::path::Path::new(&spec.module)
            .file_name()
            .map(|f| f.to_string_lossy().into_owned())
            .unwrap_or_else(|| format!("{}.mod", m.name))
    };
    let o = spec.options;
    let options = program::Options {
        tooldata: o.tooldata,
        wobjdata: o.wobjdata,
        default_tool: o.tool.unwrap_or_default(),
        default_wobj: o.wobj.unwrap_or_default(),
        jointtargets: o.jointtargets,
    };
    // Everything the filter reads (given tooldata and wobjdata too) is checked here.
    let checked = program::filter_module("MODULE x\nENDMODULE\n", &filter, &options);
    if let Err(e) = checked {
        return Err(JobError::invalid("options", e.message));
    }
    let upload = spec.upload;
    if let Some(u) = &upload
        && u.cell.trim().is_empty()
    {
        return Err(JobError::invalid("upload.cell", "names no cell"));
    }
    Ok(ProgramJob {
        filter,
        text,
        file,
        options,
        upload,
    })
}

/// The RAPID module is in mm: so must the models be.
fn millimetres(field: &str, m: &SerialModel) -> Result<(), JobError> {
    if (m.chain.units.metre() - 1e-3).abs() > 1e-12 {
        return Err(JobError::invalid(
            field,
            "RAPID positions are in mm: give a DH model file whose length unit is mm",
        ));
    }
    Ok(())
}

impl ProgramJob {
    /// Filter the module: the result, the corrections table and the module artefact.
    pub fn filter(&self, _monitor: &dyn Monitor) -> Result<Run<ProgramResult>, JobError> {
        let Filtered {
            module,
            text,
            targets,
        } = program::filter_module(&self.text, &self.filter, &self.options)
            .map_err(|e| JobError::invalid("module", e.to_string()))?;
        let mut s = Summary {
            targets: targets.len(),
            ..Default::default()
        };
        let mut table = Table::new(&[
            "line",
            "outcome_code",
            "dx_mm",
            "dy_mm",
            "dz_mm",
            "correction_mm",
            "correction_deg",
            "cf1",
            "cf4",
            "cf6",
            "cfx",
        ]);
        let mut csv = String::from(
            "target,line,tool,wobj,outcome,dx_mm,dy_mm,dz_mm,correction_mm,correction_deg,cf_before,cf_after,q1,q2,q3,q4,q5,q6,reason\n",
        );
        for t in &targets {
            match t.outcome {
                Outcome::Corrected => s.corrected += 1,
                Outcome::Unchanged => s.unchanged += 1,
                _ => s.not_corrected += 1,
            }
            if matches!(t.outcome, Outcome::Corrected | Outcome::Unchanged) {
                s.mean_correction_mm += t.correction_mm;
                s.max_correction_mm = s.max_correction_mm.max(t.correction_mm);
                s.max_correction_deg = s.max_correction_deg.max(t.correction_deg);
            }
            let cf = t.conf_after.or(t.conf_before).unwrap_or_default();
            table.push(vec![
                t.line as f64,
                outcome_code(t.outcome),
                t.dx_mm,
                t.dy_mm,
                t.dz_mm,
                t.correction_mm,
                t.correction_deg,
                cf[0] as f64,
                cf[1] as f64,
                cf[2] as f64,
                cf[3] as f64,
            ]);
            csv.push_str(&csv_row(t));
        }
        let done = s.corrected + s.unchanged;
        if done > 0 {
            s.mean_correction_mm /= done as f64;
        }
        let artefacts = vec![
            Artefact {
                name: self.file.clone(),
                media_type: "text/plain".into(),
                content: text.into_bytes(),
            },
            Artefact {
                name: "corrections.csv".into(),
                media_type: "text/csv".into(),
                content: csv.into_bytes(),
            },
        ];
        Ok(Run {
            result: ProgramResult {
                module,
                file: self.file.clone(),
                summary: s,
                targets,
                upload: None,
            },
            main_table: Some(table),
            artefacts,
        })
    }

    /// Upload the filtered module to the cell's controller and load it.
    async fn upload(
        &self,
        cx: &Cx,
        u: &Upload,
        run: &Run<ProgramResult>,
    ) -> Result<Uploaded, JobError> {
        let r = &run.result;
        if r.summary.not_corrected > 0 {
            let names: Vec<&str> = r
                .targets
                .iter()
                .filter(|t| !matches!(t.outcome, Outcome::Corrected | Outcome::Unchanged))
                .map(|t| t.target.as_str())
                .collect();
            return Err(JobError::Failed(format!(
                "{} target(s) could not be corrected ({}): the module was not uploaded",
                names.len(),
                names.join(", ")
            )));
        }
        let text = run
            .artefacts
            .iter()
            .find(|a| a.name == self.file)
            .map(|a| String::from_utf8_lossy(&a.content).into_owned())
            .unwrap_or_default();
        let file = u
            .file
            .clone()
            .unwrap_or_else(|| format!("{}.mod", r.module));
        let cell = cx.lab().trical(&u.cell)?;
        let path = cell
            .modules
            .load_module(&file, &text, u.stop_program)
            .await
            .map_err(|e| JobError::Upload {
                cell: u.cell.clone(),
                message: e.to_string(),
            })?;
        Ok(Uploaded {
            cell: u.cell.clone(),
            path,
            module: r.module.clone(),
            program_stopped: u.stop_program,
        })
    }
}

fn outcome_code(o: Outcome) -> f64 {
    match o {
        Outcome::Corrected => 0.0,
        Outcome::Unchanged => 1.0,
        Outcome::NotReached => 2.0,
        Outcome::Configuration => 3.0,
        Outcome::Ambiguous => 4.0,
        Outcome::Data => 5.0,
        Outcome::NotLiteral => 6.0,
    }
}

fn csv_row(t: &TargetReport) -> String {
    let cf = |c: Option<[i64; 4]>| {
        c.map(|c| format!("\"[{},{},{},{}]\"", c[0], c[1], c[2], c[3]))
            .unwrap_or_default()
    };
    let q = t
        .q_deg
        .map(|q| q.map(|v| v.to_string()).join(","))
        .unwrap_or_else(|| ",,,,,".into());
    let outcome = serde_json::to_value(t.outcome)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default();
    format!(
        "{},{},{},{},{},{},{},{},{},{},{},{},{},\"{}\"\n",
        t.target,
        t.line,
        t.tool,
        t.wobj,
        outcome,
        t.dx_mm,
        t.dy_mm,
        t.dz_mm,
        t.correction_mm,
        t.correction_deg,
        cf(t.conf_before),
        cf(t.conf_after),
        q,
        t.reason.replace('"', "\"\"")
    )
}

impl Kind for ProgramJob {
    fn devices(&self) -> Vec<String> {
        self.upload
            .iter()
            .map(|u| format!("{}.rws", u.cell))
            .collect()
    }

    fn run(self: Arc<Self>, cx: Cx) -> RunFuture {
        let Some(u) = self.upload.clone() else {
            return computed(self, cx, Self::filter);
        };
        Box::pin(async move {
            let me = self.clone();
            let mut run = cx.compute(move |m| me.filter(m)).await?;
            run.result.upload = Some(self.upload(&cx, &u, &run).await?);
            run.into_output().map(Produced::from)
        })
    }
}

#[cfg(test)]
mod tests;
