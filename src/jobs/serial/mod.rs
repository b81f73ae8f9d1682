//! The serial-arm job kinds (`serial.fk`, `serial.identify`, `serial.design`,
//! `serial.dispersion`, `serial.compensate`, `serial.compensate_program`) and what they share: loading a DH or URDF model, joint columns in
//! the model's units with limit checks, ball plates and measurement tables. A DH tree file
//! (`"kind": "tree"`) is used through one named chain, as the serial DH file of that path.

pub mod compensate;
pub mod compensate_program;
mod coverage;
pub mod design;
mod design_report;
pub mod dispersion;
pub mod fk;
mod gauge;
pub mod identify;
mod identify_inputs;
mod identify_report;
mod identify_result;
pub mod joints;
mod plots;
pub mod prior;
pub mod verdict;

use serde::Deserialize;
use serde_json::{Value, json};

use crate::measure::{BallPlate, PointMeasurement, Target};
use crate::model::dh::DhFile;
use crate::model::urdf::UrdfModel;
use crate::model::{Chain, ParamId, Quantity};
use crate::run::{Inputs, JobError, Table};

/// `"chain": {"root": .., "tip": ..}` for URDF models, `{"name": ..}` for DH tree files.
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ChainSpec {
    /// Root link (the robot frame {0}); URDF only.
    #[serde(default)]
    pub root: String,
    /// Tip link (the TCP frame); URDF only.
    #[serde(default)]
    pub tip: String,
    /// A named chain of a DH tree file.
    #[serde(default)]
    pub name: Option<String>,
}

/// Where a serial model came from, to write a calibrated file of the same kind.
#[derive(Debug, Clone)]
pub enum Source {
    /// A DH model file.
    Dh(DhFile),
    /// A URDF and the chain used.
    Urdf {
        /// The URDF.
        model: UrdfModel,
        /// Root link.
        root: String,
        /// Tip link.
        tip: String,
    },
}

/// A loaded serial model.
#[derive(Debug, Clone)]
pub struct SerialModel {
    /// The chain.
    pub chain: Chain,
    /// Its file.
    pub source: Source,
}

/// A serial model input read once: URDF text or a JSON document.
#[derive(Debug)]
pub enum ModelInput {
    /// URDF text.
    Urdf(String),
    /// A DH file, DH tree file or result document.
    Json(Value),
}

/// Whether `model` names URDF by itself: inline XML or a `.urdf` file name.
pub(crate) fn named_urdf(model: &Value) -> bool {
    matches!(model, Value::String(s)
        if s.trim_start().starts_with('<') || s.to_ascii_lowercase().ends_with(".urdf"))
}

/// Read `model`: inline JSON, inline URDF, or a reference (file or dataset id) whose name
/// ends in `.urdf` or whose text starts with `<` (an uploaded dataset keeps no file name),
/// else a JSON document.
pub fn read_model(inputs: &Inputs<'_>, model: &Value) -> Result<ModelInput, JobError> {
    let Value::String(s) = model else {
        return Ok(ModelInput::Json(inputs.json("model", model)?));
    };
    let text = inputs.text("model", model)?;
    if named_urdf(model)
        || text
            .trim_start_matches('\u{feff}')
            .trim_start()
            .starts_with('<')
    {
        return Ok(ModelInput::Urdf(text));
    }
    serde_json::from_str(&text)
        .map(ModelInput::Json)
        .map_err(|e| JobError::invalid("model", format!("`{s}` is not valid JSON: {e}")))
}

/// Load `model` (DH JSON object or file, or URDF file/text/dataset with `chain`).
pub fn load_model(
    inputs: &Inputs<'_>,
    model: &Value,
    chain: Option<&ChainSpec>,
) -> Result<SerialModel, JobError> {
    let urdf_chain = || {
        let spec = chain.ok_or_else(|| {
            JobError::invalid(
                "chain",
                "a URDF model needs \"chain\": {\"root\": .., \"tip\": ..}",
            )
        })?;
        if spec.name.is_some() || spec.root.is_empty() || spec.tip.is_empty() {
            return Err(JobError::invalid(
                "chain",
                "a URDF model needs \"chain\": {\"root\": .., \"tip\": ..} (no name)",
            ));
        }
        Ok(spec)
    };
    if named_urdf(model) {
        // The chain is checked before the file is read, as the name already says URDF.
        urdf_chain()?;
    }
    let value = match read_model(inputs, model)? {
        ModelInput::Urdf(text) => {
            let spec = urdf_chain()?;
            let urdf = UrdfModel::parse(&text)?;
            let c = urdf.chain(&spec.root, &spec.tip)?;
            return Ok(SerialModel {
                chain: c,
                source: Source::Urdf {
                    model: urdf,
                    root: spec.root.clone(),
                    tip: spec.tip.clone(),
                },
            });
        }
        ModelInput::Json(v) => v,
    };
    if value.get("kind").and_then(Value::as_str) == Some("tree") {
        // A DH tree file: the named chain, as the serial DH file of that path.
        let name = chain.and_then(|c| c.name.as_deref()).ok_or_else(|| {
            JobError::invalid("chain", "a DH tree model needs \"chain\": {\"name\": ..}")
        })?;
        let label = model.as_str().unwrap_or("model");
        let text = value.to_string();
        let tree = crate::model::dh_tree::DhTreeFile::parse(&text, label)?;
        let file = tree.serial_file(name, label)?;
        return Ok(SerialModel {
            chain: file.to_chain()?,
            source: Source::Dh(file),
        });
    }
    if chain.is_some() {
        return Err(JobError::invalid(
            "chain",
            "only URDF models and DH tree files take a chain",
        ));
    }
    let file = DhFile::from_value(value)?;
    Ok(SerialModel {
        chain: file.to_chain()?,
        source: Source::Dh(file),
    })
}

impl SerialModel {
    /// A serial model from a parsed DH file (the typed constructors' entry point).
    pub fn from_dh(file: DhFile) -> Result<SerialModel, JobError> {
        Ok(SerialModel {
            chain: file.to_chain()?,
            source: Source::Dh(file),
        })
    }

    /// Default parameters to identify: the DH file's list; for URDF every placement error,
    /// the offsets of the moving joints (mimic joints included, not their multipliers: a
    /// gear ratio is named explicitly), and the base (rank detection prunes the rest).
    pub fn default_identify(&self) -> Vec<ParamId> {
        match &self.source {
            Source::Dh(f) => f
                .identify
                .iter()
                .filter_map(|n| self.chain.param_by_name(n).ok())
                .collect(),
            Source::Urdf { .. } => self
                .chain
                .param_ids()
                .into_iter()
                .filter(|id| {
                    !matches!(
                        id,
                        ParamId::Tool(_)
                            | ParamId::Joint(
                                _,
                                crate::model::JointField::Compliance
                                    | crate::model::JointField::Multiplier
                            )
                    )
                })
                .collect(),
        }
    }

    /// Parameters named in `names` (error names the unknown one).
    pub fn params(&self, field: &str, names: &[String]) -> Result<Vec<ParamId>, JobError> {
        names
            .iter()
            .map(|n| {
                self.chain
                    .param_by_name(n)
                    .map_err(|_| JobError::invalid(field, format!("unknown parameter name `{n}`")))
            })
            .collect()
    }

    /// Names of the joint columns: q1..qN.
    pub fn joint_columns(&self) -> Vec<String> {
        (1..=self.chain.dof()).map(|k| format!("q{k}")).collect()
    }

    /// Angle unit of joint columns and file angles.
    pub fn angle_unit(&self) -> &'static str {
        self.chain.units.name(Quantity::Angle)
    }

    /// Length unit.
    pub fn length_unit(&self) -> &'static str {
        self.chain.units.name(Quantity::Length)
    }

    /// Unit of joint column `k` (0-based): the angle unit, or the length unit of a prismatic
    /// joint. A mimic joint has no column.
    pub fn joint_unit(&self, k: usize) -> &'static str {
        self.chain.units.name(self.chain.variable_quantity(k))
    }

    /// Joint values of every row of `t` (radians, or the length unit of prismatic joints),
    /// checked against the limits.
    pub fn joints(&self, field: &str, t: &Table) -> Result<Vec<Vec<f64>>, JobError> {
        let cols = joints::JointColumns::new(self, field, &t.columns)?;
        let mut out = Vec::with_capacity(t.rows.len());
        for (i, row) in t.rows.iter().enumerate() {
            let mut q = Vec::new();
            cols.read(self, i + 1, row, &mut q)?;
            out.push(q);
        }
        Ok(out)
    }

    /// Distance measurements from a table with joint columns and `L_mm` (model length unit).
    pub fn distances(
        &self,
        field: &str,
        t: &Table,
    ) -> Result<Vec<crate::measure::DistanceMeasurement>, JobError> {
        let q = self.joints(field, t)?;
        let c = t.col(field, "L_mm")?;
        // L_mm is in mm whatever the model's length unit.
        let k = 1e-3 / self.chain.units.metre();
        q.into_iter()
            .zip(&t.rows)
            .enumerate()
            .map(|(i, (q, row))| {
                let l = row[c];
                if !l.is_finite() {
                    return Err(JobError::row(
                        field,
                        i + 1,
                        format!("L_mm = {l} is not finite"),
                    ));
                }
                Ok(crate::measure::DistanceMeasurement { q, length: l * k })
            })
            .collect()
    }

    /// Measurements from a table with joint columns and either `ball` (1-based) or x, y, z.
    pub fn measurements(
        &self,
        field: &str,
        t: &Table,
        balls: usize,
    ) -> Result<Vec<PointMeasurement>, JobError> {
        let q = self.joints(field, t)?;
        if t.has("ball") {
            let c = t.col(field, "ball")?;
            q.into_iter()
                .zip(&t.rows)
                .enumerate()
                .map(|(i, (q, row))| {
                    let b = row[c];
                    if b.fract() != 0.0 || b < 1.0 || b > balls as f64 {
                        return Err(JobError::row(
                            field,
                            i + 1,
                            format!("ball = {b}: the ball plate has balls 1..={balls}"),
                        ));
                    }
                    Ok(PointMeasurement {
                        q,
                        target: Target::Ball(b as usize - 1),
                    })
                })
                .collect()
        } else if t.has("x") {
            let xyz = t.cols(field, &["x".into(), "y".into(), "z".into()])?;
            Ok(q.into_iter()
                .zip(&t.rows)
                .map(|(q, row)| PointMeasurement {
                    q,
                    target: Target::Point([row[xyz[0]], row[xyz[1]], row[xyz[2]]].into()),
                })
                .collect())
        } else {
            Err(JobError::invalid(
                field,
                "needs a `ball` column (ball-centring) or `x`, `y`, `z` columns (Cartesian)",
            ))
        }
    }

    /// The calibrated model as a file of the same kind: the DH JSON object, or URDF text.
    pub fn calibrated(
        &self,
        chain: &Chain,
        provenance: Value,
    ) -> Result<(Value, crate::run::Artefact), JobError> {
        match &self.source {
            Source::Dh(f) => {
                let mut out = f.with_chain(chain);
                out.calibration = Some(provenance);
                let v = serde_json::to_value(&out)
                    .map_err(|e| JobError::internal("serialising the calibrated model", e))?;
                let bytes = serde_json::to_vec_pretty(&v).unwrap_or_default();
                Ok((
                    v,
                    crate::run::Artefact {
                        name: "calibrated_model.json".into(),
                        media_type: "application/json".into(),
                        content: bytes,
                    },
                ))
            }
            Source::Urdf { model, .. } => {
                let text = model.write_calibrated(chain)?;
                let art = crate::run::Artefact {
                    name: "calibrated_model.urdf".into(),
                    media_type: "application/xml".into(),
                    content: text.clone().into_bytes(),
                };
                Ok((json!(text), art))
            }
        }
    }
}

impl SerialModel {
    /// The calibrated model for ROS tools, beside the file of its own kind: a DH model as
    /// URDF (`calibrated_model.urdf`, see [`crate::model::urdf_export`]; `None` for rows URDF
    /// cannot express), a URDF chain's joint offsets as `ros2_control` parameters
    /// (`joint_offsets.yaml`).
    pub fn urdf_artefact(&self, chain: &Chain) -> Option<crate::run::Artefact> {
        let (name, text) = match &self.source {
            Source::Dh(f) => (
                "calibrated_model.urdf",
                crate::model::urdf_export::to_urdf(chain, &f.name).ok()?,
            ),
            Source::Urdf { .. } => (
                "joint_offsets.yaml",
                crate::model::urdf_export::ros2_control_offsets(chain, "calibration"),
            ),
        };
        let media_type = if name.ends_with(".yaml") {
            "application/yaml"
        } else {
            "application/xml"
        };
        Some(crate::run::Artefact {
            name: name.into(),
            media_type: media_type.into(),
            content: text.into_bytes(),
        })
    }
}

/// The `ball_plate` field: `{d12, d13, d23}`, `{positions}` or `{balls, distances}`.
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
#[schemars(extend("oneOf" = [
    {"required": ["d12", "d13", "d23"]},
    {"required": ["positions"]},
    {"required": ["balls", "distances"]}
]))]
pub struct PlateSpec {
    d12: Option<f64>,
    d13: Option<f64>,
    d23: Option<f64>,
    positions: Option<Vec<[f64; 3]>>,
    balls: Option<usize>,
    distances: Option<Vec<(usize, usize, f64)>>,
}

impl PlateSpec {
    /// The plate this describes.
    pub fn plate(&self) -> Result<BallPlate, JobError> {
        let err = |m: String| JobError::invalid("ball_plate", m);
        match (
            self.d12,
            self.d13,
            self.d23,
            &self.positions,
            self.balls,
            &self.distances,
        ) {
            (Some(a), Some(b), Some(c), None, None, None) => {
                BallPlate::from_ballbar(a, b, c).map_err(|e| err(e.to_string()))
            }
            (None, None, None, Some(p), None, None) => {
                BallPlate::from_positions(p).map_err(|e| err(e.to_string()))
            }
            (None, None, None, None, Some(n), Some(d)) => {
                BallPlate::from_distances(n, d).map_err(|e| err(e.to_string()))
            }
            _ => Err(err(
                "give exactly one of {d12, d13, d23}, {positions}, or {balls, distances}".into(),
            )),
        }
    }
}

/// Tables of twin data in the job-file format: joints in degrees and `ball` (1-based) or
/// `x, y, z` (mm).
pub fn measurement_table(meas: &[PointMeasurement], dof: usize) -> Table {
    let mut cols: Vec<String> = (1..=dof).map(|k| format!("q{k}")).collect();
    let ball = meas
        .first()
        .is_some_and(|m| matches!(m.target, Target::Ball(_)));
    if ball {
        cols.push("ball".into());
    } else {
        cols.extend(["x".into(), "y".into(), "z".into()]);
    }
    let mut t = Table {
        columns: cols,
        rows: vec![],
    };
    for m in meas {
        let mut row: Vec<f64> = m.q.iter().map(|v| v.to_degrees()).collect();
        match m.target {
            Target::Ball(b) => row.push((b + 1) as f64),
            Target::Point(p) => row.extend([p.x, p.y, p.z]),
        }
        t.push(row);
    }
    t
}
