//! The humanoid job kinds (`humanoid.identify`, `humanoid.validate`, `humanoid.design`) and
//! what they share: the model fields of `../shared/spec/humanoid.md` (URDF, root link, joints,
//! markers, base mode, elasticity) and the samples table (joint columns by URDF name,
//! `tau_<joint>`, `<marker>_x/_y/_z` with occlusions as empty/NaN/null cells, an optional
//! `column_map`, optional mocap pre-processing of a raw recording).

mod auto_prior;
mod coverage;
pub mod design;
pub mod identify;
mod identify_report;
mod identify_result;
mod plots;
pub mod samples;
pub mod validate;
pub mod verdict;

use std::collections::BTreeMap;

use serde::Deserialize;
use serde_json::{Value, json};

use crate::identify::prior::{PriorSpec, PriorWeight};
use crate::identify::{ParamReport, Robust, RobustKind};
use crate::measure::marker_fit::{FitOptions, Groups, MapOptions};
use crate::measure::mocap::MocapOptions;
use crate::model::humanoid::{BaseMode, Elasticity, HParam, Humanoid, MarkerDef};
use crate::model::urdf::UrdfModel;
use crate::run::{Inputs, JobError};

/// One entry of `markers`.
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct MarkerSpec {
    /// Marker name (columns `<name>_x`, `_y`, `_z`).
    pub name: String,
    /// URDF link carrying it.
    pub link: String,
    /// Initial guess in the link frame (m).
    #[serde(default)]
    pub initial: [f64; 3],
}

/// `base`: how the root link's pose in the mocap frame is obtained.
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(tag = "mode", rename_all = "snake_case", deny_unknown_fields)]
pub enum BaseSpec {
    /// Six constant unknowns (a struct variant so that unknown fields are refused).
    Identify {},
    /// Per sample from a cluster of at least three markers on the root link.
    Cluster {
        /// The cluster's marker names (columns `<name>_x` ...).
        markers: Vec<String>,
    },
    /// From a support foot that stays still (leg problems).
    SupportFoot {
        /// The support foot (sole) link.
        link: String,
    },
}

impl Default for BaseSpec {
    fn default() -> Self {
        BaseSpec::Identify {}
    }
}

/// `options.elastic`.
#[derive(Debug, Clone, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ElasticSpec {
    /// Joints whose compliance is identified from measured torques (`tau_<joint>`).
    #[serde(default)]
    pub joints: Vec<String>,
    /// Identify the base Cartesian compliance (support leg).
    #[serde(default)]
    pub base: bool,
    /// Support foot link for the base compliance (default: the support-foot base mode's).
    #[serde(default)]
    pub support_link: Option<String>,
}

/// `options.robust`.
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct RobustSpec {
    /// `huber` or `cauchy`.
    pub loss: RobustKind,
    /// Scale on the 3-D marker error (m); default: estimated from the residuals (MAD).
    #[serde(default)]
    pub scale_m: Option<f64>,
}

/// `options.preprocess`: the samples are a raw recording to filter and cut into postures.
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PreprocessSpec {
    /// Butterworth order (default 5).
    #[serde(default)]
    pub order: Option<usize>,
    /// Cutoff (Hz, default 5).
    #[serde(default)]
    pub cutoff_hz: Option<f64>,
    /// Sampling rate (Hz, default: from `t`).
    #[serde(default)]
    pub rate_hz: Option<f64>,
    /// Stable when every visible marker is slower than this (m/s, default 0.02).
    #[serde(default)]
    pub velocity_threshold_m_s: Option<f64>,
    /// ... and every joint slower than this (rad/s, default 0.02).
    #[serde(default)]
    pub joint_velocity_threshold_rad_s: Option<f64>,
    /// Shortest stable run that is a posture (samples, default 20).
    #[serde(default)]
    pub min_stable_samples: Option<usize>,
    /// Samples kept per posture and marker (default 10).
    #[serde(default)]
    pub samples_per_posture: Option<usize>,
}

impl PreprocessSpec {
    /// The pre-processing settings.
    pub fn options(&self) -> MocapOptions {
        let d = MocapOptions::default();
        MocapOptions {
            order: self.order.unwrap_or(d.order),
            cutoff_hz: self.cutoff_hz.unwrap_or(d.cutoff_hz),
            rate_hz: self.rate_hz,
            velocity_threshold: self.velocity_threshold_m_s.unwrap_or(d.velocity_threshold),
            joint_velocity_threshold: self
                .joint_velocity_threshold_rad_s
                .unwrap_or(d.joint_velocity_threshold),
            min_stable: self.min_stable_samples.unwrap_or(d.min_stable),
            samples_per_posture: self.samples_per_posture.unwrap_or(d.samples_per_posture),
        }
    }
}

/// `options` of `humanoid.identify` and `humanoid.validate`.
#[derive(Debug, Clone, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FitSpec {
    /// Elasticity.
    #[serde(default)]
    pub elastic: ElasticSpec,
    /// Robust loss (null: least squares).
    #[serde(default)]
    pub robust: Option<RobustSpec>,
    /// Seed of random choices (cross-validation folds).
    #[serde(default)]
    pub seed: u64,
    /// Joint parameter groups to identify: `offsets`, `translations`, `angles` (default all).
    #[serde(default)]
    pub parameters: Option<Vec<String>>,
    /// Relative tolerance of the rank detection (default 1e-2, see [`FitOptions`]).
    #[serde(default)]
    pub rank_tolerance: Option<f64>,
    /// Levenberg-Marquardt iteration limit (default 200).
    #[serde(default)]
    pub max_iterations: Option<usize>,
    /// Treat the samples as a raw recording.
    #[serde(default)]
    pub preprocess: Option<PreprocessSpec>,
    /// k-fold cross-validation of the calibration (identify only).
    #[serde(default)]
    pub cross_validation: Option<CrossValidationSpec>,
    /// Gaussian prior on the joint parameters: MAP identification (identify only);
    /// `{"scale": "auto"}` lets the data choose the length and angle stds.
    #[serde(default)]
    pub prior: Option<PriorSpec>,
    /// Weight of the prior: a positive number (default 1) or `"cv"` (K-fold on the
    /// training samples).
    #[serde(default)]
    pub prior_weight: Option<PriorWeight>,
    /// Marker noise (m) dividing the data in the MAP problem (default: the residual sigma
    /// of the least-squares fit).
    #[serde(default)]
    pub noise_m: Option<f64>,
}

/// `options.cross_validation`.
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CrossValidationSpec {
    /// Number of folds (each sample is held out once).
    pub folds: usize,
}

impl FitSpec {
    /// Parse `options` given as JSON (a campaign's `options.identify`), naming the field.
    pub fn from_value(v: &Value) -> Result<FitSpec, JobError> {
        serde_path_to_error::deserialize(v).map_err(|e| {
            JobError::invalid(format!("options.{}", e.path()), e.into_inner().to_string())
        })
    }

    /// Groups of joint parameters to identify (geometric part).
    pub fn groups(&self) -> Result<Groups, JobError> {
        let mut g = Groups::ALL;
        if let Some(list) = &self.parameters {
            g = Groups {
                offsets: false,
                translations: false,
                angles: false,
                ..Groups::ALL
            };
            for (i, name) in list.iter().enumerate() {
                match name.as_str() {
                    "offsets" => g.offsets = true,
                    "translations" => g.translations = true,
                    "angles" => g.angles = true,
                    other => {
                        return Err(JobError::invalid(
                            format!("options.parameters[{i}]"),
                            format!("`{other}`: use offsets, translations, angles"),
                        ));
                    }
                }
            }
        }
        Ok(g)
    }

    /// Solver settings.
    pub fn fit_options(&self) -> Result<FitOptions, JobError> {
        let mut o = FitOptions::default();
        if let Some(t) = self.rank_tolerance {
            if !(t > 0.0 && t < 1.0) {
                return Err(JobError::invalid(
                    "options.rank_tolerance",
                    format!("{t} must be in (0, 1)"),
                ));
            }
            o.rank_tolerance = t;
        }
        if let Some(n) = self.max_iterations {
            o.max_iterations = n.max(1);
        }
        if let Some(n) = self.noise_m
            && !(n > 0.0 && n.is_finite())
        {
            return Err(JobError::invalid(
                "options.noise_m",
                format!("{n} must be positive"),
            ));
        }
        o.prior = match (&self.prior, &self.prior_weight) {
            (None, Some(_)) => {
                return Err(JobError::invalid(
                    "options.prior_weight",
                    "needs options.prior",
                ));
            }
            (None, None) => None,
            (Some(spec), w) => {
                if self.robust.is_some() {
                    return Err(JobError::invalid(
                        "options.prior",
                        "a prior and a robust loss cannot be combined: choose one",
                    ));
                }
                spec.check_auto()
                    .map_err(|m| JobError::invalid("options.prior", m))?;
                if spec.scale.is_some() && w.is_some() {
                    return Err(JobError::invalid(
                        "options.prior_weight",
                        "with prior.scale \"auto\" the weight is folded into the chosen \
                         stds (weight 1): leave it out",
                    ));
                }
                let weight = match w {
                    Some(w) => w
                        .fixed()
                        .map_err(|m| JobError::invalid("options.prior_weight", m))?,
                    None => Some(1.0),
                };
                Some(MapOptions {
                    spec: spec.clone(),
                    // "cv": the job chooses the weight before the fit (1 until then).
                    weight: weight.unwrap_or(1.0),
                    noise_m: self.noise_m,
                })
            }
        };
        if let Some(r) = &self.robust {
            if let Some(s) = r.scale_m
                && !(s > 0.0 && s.is_finite())
            {
                return Err(JobError::invalid(
                    "options.robust.scale_m",
                    format!("{s} must be positive"),
                ));
            }
            o.robust = Some(Robust {
                kind: r.loss,
                scale: r.scale_m,
                group: 3,
            });
        }
        Ok(o)
    }
}

/// A loaded model with the URDF it came from.
#[derive(Debug, Clone)]
pub struct LoadedModel {
    /// The URDF.
    pub urdf: UrdfModel,
    /// The model at its starting values.
    pub model: Humanoid,
    /// Names of the root cluster markers (cluster mode).
    pub cluster: Vec<String>,
}

/// Build the model from the shared fields.
pub fn load_model(
    inputs: &Inputs<'_>,
    urdf: &Value,
    root_link: &str,
    joints: &[String],
    markers: &[MarkerSpec],
    base: &BaseSpec,
    elastic: &ElasticSpec,
) -> Result<LoadedModel, JobError> {
    let text = inputs.text("urdf", urdf)?;
    load_model_text(&text, root_link, joints, markers, base, elastic)
}

/// [`load_model`] from URDF text: the typed entry point of the humanoid kinds.
pub fn load_model_text(
    text: &str,
    root_link: &str,
    joints: &[String],
    markers: &[MarkerSpec],
    base: &BaseSpec,
    elastic: &ElasticSpec,
) -> Result<LoadedModel, JobError> {
    let urdf = UrdfModel::parse(text)?;
    if joints.is_empty() {
        return Err(JobError::invalid("joints", "at least one joint is needed"));
    }
    for (i, m) in markers.iter().enumerate() {
        if m.initial.iter().any(|v| !v.is_finite()) {
            return Err(JobError::invalid(
                format!("markers[{i}].initial"),
                "must be finite (m)",
            ));
        }
    }
    let defs: Vec<MarkerDef> = markers
        .iter()
        .map(|m| MarkerDef {
            name: m.name.clone(),
            link: m.link.clone(),
            initial: m.initial.into(),
        })
        .collect();
    let (mode, cluster) = match base {
        BaseSpec::Identify {} => (BaseMode::Identify, Vec::new()),
        BaseSpec::Cluster { markers: c } => {
            if c.len() < 3 {
                return Err(JobError::invalid(
                    "base.markers",
                    format!("a cluster needs at least three markers, got {}", c.len()),
                ));
            }
            if let Some(m) = c.iter().find(|n| defs.iter().any(|d| &&d.name == n)) {
                return Err(JobError::invalid(
                    "base.markers",
                    format!(
                        "`{m}` is also a model marker: cluster markers only define the root frame"
                    ),
                ));
            }
            (BaseMode::Cluster, c.clone())
        }
        BaseSpec::SupportFoot { link } => {
            (BaseMode::SupportFoot { link: link.clone() }, Vec::new())
        }
    };
    let el = Elasticity {
        joints: elastic.joints.clone(),
        base: elastic.base,
        support_link: elastic.support_link.clone(),
    };
    let model = Humanoid::new(&urdf, root_link, joints, &defs, mode, &el)?;
    Ok(LoadedModel {
        urdf,
        model,
        cluster,
    })
}

/// The `markers` part of a result: per marker name, RMSE values in mm.
pub fn marker_table(model: &Humanoid, columns: &[(&str, &[Option<f64>])]) -> Value {
    Value::Array(
        model
            .markers
            .iter()
            .enumerate()
            .map(|(m, d)| {
                let mut o = serde_json::Map::new();
                o.insert("name".into(), json!(d.name));
                o.insert("link".into(), json!(d.link));
                for (key, vals) in columns {
                    o.insert(key.to_string(), json!(vals[m].map(|v| v * 1e3)));
                }
                Value::Object(o)
            })
            .collect(),
    )
}

/// Apply a result's `parameters` (name -> value, SI) to a model; names must exist.
pub fn apply_parameters(
    model: &mut Humanoid,
    field: &str,
    params: &Value,
    keep: &dyn Fn(HParam) -> bool,
) -> Result<usize, JobError> {
    let list: Vec<ParamLine> = serde_json::from_value(params.clone())
        .map_err(|e| JobError::invalid(field, format!("expected [{{name, value, ...}}]: {e}")))?;
    let mut idx = Vec::new();
    let mut vals = Vec::new();
    for (i, p) in list.iter().enumerate() {
        let g = model.param_by_name(&p.name).ok_or_else(|| {
            JobError::invalid(
                format!("{field}[{i}]"),
                format!(
                    "`{}` is not a parameter of this model (different joints or markers?)",
                    p.name
                ),
            )
        })?;
        if !keep(model.params[g]) {
            continue;
        }
        if !p.value.is_finite() {
            return Err(JobError::invalid(
                format!("{field}[{i}].value"),
                "is not finite",
            ));
        }
        idx.push(g);
        vals.push(p.value);
    }
    model.set_values(&idx, &vals);
    Ok(idx.len())
}

/// A parameter line of a result, as read back.
#[derive(Debug, Clone, Deserialize)]
struct ParamLine {
    name: String,
    value: f64,
}

/// Parameter reports as JSON.
pub fn params_json(p: &[ParamReport]) -> Value {
    serde_json::to_value(p).unwrap_or(Value::Null)
}

/// `column_map` as given.
pub type ColumnMap = BTreeMap<String, String>;
