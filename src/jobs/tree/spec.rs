//! The `tree.identify` job document: its keys, the rows, markers and base it describes,
//! checked and built into a [`TreeIdentifyJob`].

use super::*;

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    /// The tree's rows (required unless `justin` is given).
    #[serde(default)]
    tree: Option<TreeSpec>,
    /// DLR Agile Justin: the model from the data set's own files instead of `tree`,
    /// `variables`, `markers` and `base`.
    #[serde(default)]
    pub(super) justin: Option<super::justin::JustinSpec>,
    #[schemars(schema_with = "crate::run::schema::table")]
    samples: Value,
    /// Joint columns of `samples` (required unless `justin` is given).
    #[serde(default)]
    variables: Option<Vec<String>>,
    /// Markers (required unless `justin` is given).
    #[serde(default)]
    markers: Option<Vec<MarkerSpec>>,
    #[serde(default)]
    base: Option<BaseSpec>,
    #[serde(default)]
    pub(super) options: Options,
}

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct TreeSpec {
    /// Only `modified_dh` (Craig + Hayati beta) is accepted: the convention is stated.
    convention: String,
    rows: Vec<RowSpec>,
}

/// A row: `mdh` (a revolute joint) or `fixed` (a mount, a flange).
#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct RowSpec {
    name: String,
    #[serde(default)]
    parent: Option<String>,
    #[serde(default)]
    mdh: Option<MdhSpec>,
    #[serde(default)]
    fixed: Option<FixedSpec>,
    /// The measured variable (a column of `variables`).
    #[serde(default)]
    variable: Option<String>,
    /// A passive joint: `[[variable, coefficient], ...]`.
    #[serde(default)]
    coupled: Option<Vec<(String, f64)>>,
}

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct MdhSpec {
    alpha_deg: f64,
    a_m: f64,
    #[serde(default)]
    beta_deg: f64,
    theta_deg: f64,
    d_m: f64,
}

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct FixedSpec {
    xyz_m: [f64; 3],
    /// `Rz(a) Ry(b) Rx(c)`.
    #[serde(default)]
    abc_deg: [f64; 3],
}

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct MarkerSpec {
    name: String,
    row: String,
    #[serde(default)]
    initial_m: [f64; 3],
}

/// Starting root pose in the measurement frame.
#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct BaseSpec {
    xyz_m: [f64; 3],
    #[serde(default)]
    abc_deg: [f64; 3],
}

/// `options`.
#[derive(Debug, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct Options {
    #[serde(default)]
    pub(super) elastic: ElasticSpec,
    /// K of a K-fold held-out figure of the last model (none if absent).
    #[serde(default)]
    folds: Option<usize>,
    #[serde(default)]
    seed: u64,
    #[serde(default)]
    max_iterations: Option<usize>,
    /// A Gaussian prior (MAP): std per parameter name (SI units: m, rad, rad/(N*m), N,
    /// N*m) and/or defaults by unit (`length_mm`, `angle_deg`, `compliance` in deg/(N*m)).
    #[serde(default)]
    prior: Option<PriorSpec>,
    /// Its weight: a positive number (default 1) or `"cv"` (5-fold on the samples).
    #[serde(default)]
    prior_weight: Option<PriorWeight>,
    /// Measurement noise of the MAP objective (m per coordinate); default the residual RMS
    /// of the fit without the prior.
    #[serde(default)]
    noise_m: Option<f64>,
    /// A robust loss on each marker's 3-D error (per-sample weights by reweighting): the
    /// last step is refitted with the weights of its own residuals.
    #[serde(default)]
    robust: Option<crate::measure::tree_robust::TreeRobust>,
}

/// Rows with lumped elasticity; `"*"` means every revolute row.
#[derive(Debug, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct ElasticSpec {
    #[serde(default)]
    joint: Vec<String>,
    #[serde(default)]
    lateral: Vec<String>,
    /// `bodies` (default: link weights shared by the joints that carry them, bilinear) or
    /// `subtree` (linear coefficients of a mass moment constant in each joint frame).
    #[serde(default)]
    lumping: LumpingSpec,
}

#[derive(Debug, Default, Clone, Copy, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
enum LumpingSpec {
    Subtree,
    #[default]
    Bodies,
}

fn finite(field: &str, v: &[f64]) -> Result<(), JobError> {
    match v.iter().find(|x| !x.is_finite()) {
        Some(x) => Err(JobError::invalid(field, format!("{x} is not finite"))),
        None => Ok(()),
    }
}

fn rows(s: &Spec, tree: &TreeSpec, variables: &[String]) -> Result<Vec<TreeRow>, JobError> {
    if tree.convention != "modified_dh" {
        return Err(JobError::invalid(
            "tree.convention",
            format!(
                "`{}`: only `modified_dh` (Rx(alpha) Dx(a) Ry(beta) Rz(theta + q) Dz(d)) is accepted",
                tree.convention
            ),
        ));
    }
    let _ = s;
    let var = |field: &str, v: &str| {
        variables
            .iter()
            .position(|x| x == v)
            .ok_or_else(|| JobError::invalid(field, format!("`{v}` is not one of `variables`")))
    };
    let mut out: Vec<TreeRow> = Vec::new();
    for (i, r) in tree.rows.iter().enumerate() {
        let f = format!("tree.rows[{i}]");
        let parent = match &r.parent {
            None => None,
            Some(p) => Some(out.iter().position(|o| &o.name == p).ok_or_else(|| {
                JobError::invalid(
                    format!("{f}.parent"),
                    format!("`{p}` is not a row defined before it"),
                )
            })?),
        };
        let kind = match (&r.mdh, &r.fixed) {
            (Some(m), None) => {
                finite(
                    &format!("{f}.mdh"),
                    &[m.alpha_deg, m.a_m, m.beta_deg, m.theta_deg, m.d_m],
                )?;
                let drive = match (&r.variable, &r.coupled) {
                    (Some(v), None) => Drive::Variable(var(&format!("{f}.variable"), v)?),
                    (None, Some(c)) if !c.is_empty() => Drive::Coupled(
                        c.iter()
                            .map(|(v, k)| Ok((var(&format!("{f}.coupled"), v)?, *k)))
                            .collect::<Result<_, JobError>>()?,
                    ),
                    _ => {
                        return Err(JobError::invalid(
                            f,
                            "an `mdh` row needs exactly one of `variable` and `coupled`",
                        ));
                    }
                };
                RowKind::Revolute {
                    geometry: [
                        m.alpha_deg.to_radians(),
                        m.a_m,
                        m.beta_deg.to_radians(),
                        m.theta_deg.to_radians(),
                        m.d_m,
                    ],
                    drive,
                }
            }
            (None, Some(x)) => {
                finite(&format!("{f}.fixed"), &[x.xyz_m, x.abc_deg].concat())?;
                let a = x.abc_deg.map(f64::to_radians);
                RowKind::Fixed {
                    frame: Frame::from_xyzabc(&[
                        x.xyz_m[0], x.xyz_m[1], x.xyz_m[2], a[0], a[1], a[2],
                    ]),
                    errors: [0.0; 6],
                }
            }
            _ => return Err(JobError::invalid(f, "a row is either `mdh` or `fixed`")),
        };
        out.push(TreeRow {
            name: r.name.clone(),
            parent,
            kind,
        });
    }
    Ok(out)
}

impl Spec {
    pub(super) fn has_tree(&self) -> bool {
        self.tree.is_some()
    }
    pub(super) fn has_variables(&self) -> bool {
        self.variables.is_some()
    }
    pub(super) fn has_markers(&self) -> bool {
        self.markers.is_some()
    }
    pub(super) fn has_base(&self) -> bool {
        self.base.is_some()
    }
}

/// A model built from the document: the tree, its joint columns, each marker's column
/// prefix (`<prefix>_x/_y/_z`) and the elasticity asked for.
pub(super) struct Built {
    pub(super) model: ElasticTree,
    pub(super) variables: Vec<String>,
    pub(super) columns: Vec<String>,
    pub(super) elastic: ElasticOptions,
}

/// `options.elastic` with `"*"` expanded to the rows `revolute`.
pub(super) fn elastic_options(e: &ElasticSpec, revolute: &[String]) -> ElasticOptions {
    let expand = |v: &[String]| -> Vec<String> {
        if v.iter().any(|x| x == "*") {
            revolute.to_vec()
        } else {
            v.to_vec()
        }
    };
    ElasticOptions {
        joint: expand(&e.joint),
        lateral: expand(&e.lateral),
        lumping: match e.lumping {
            LumpingSpec::Subtree => Lumping::Subtree,
            LumpingSpec::Bodies => Lumping::Bodies,
        },
    }
}

/// The model the document describes row by row (`tree`, `variables`, `markers`, `base`).
fn described(s: &Spec) -> Result<Built, JobError> {
    let need = |field: &str| JobError::invalid(field, "required (or give `justin`)");
    let tree = s.tree.as_ref().ok_or_else(|| need("tree"))?;
    let variables = s.variables.clone().ok_or_else(|| need("variables"))?;
    let marker_specs = s.markers.as_ref().ok_or_else(|| need("markers"))?;
    let tree_rows = rows(s, tree, &variables)?;
    let revolute: Vec<String> = tree_rows
        .iter()
        .filter(|r| matches!(r.kind, RowKind::Revolute { .. }))
        .map(|r| r.name.clone())
        .collect();
    let elastic = elastic_options(&s.options.elastic, &revolute);
    let mut markers = Vec::new();
    for (i, m) in marker_specs.iter().enumerate() {
        finite(&format!("markers[{i}].initial_m"), &m.initial_m)?;
        let row = tree_rows
            .iter()
            .position(|r| r.name == m.row)
            .ok_or_else(|| {
                JobError::invalid(format!("markers[{i}].row"), format!("no row `{}`", m.row))
            })?;
        markers.push(TreeMarker {
            name: m.name.clone(),
            row,
            local: m.initial_m.into(),
        });
    }
    let mut model = ElasticTree::new(tree_rows, markers, variables.len(), &elastic)
        .map_err(|e| JobError::invalid("tree", e.to_string()))?;
    if let Some(b) = &s.base {
        finite("base", &[b.xyz_m, b.abc_deg].concat())?;
        let a = b.abc_deg.map(f64::to_radians);
        model.base = [b.xyz_m[0], b.xyz_m[1], b.xyz_m[2], a[0], a[1], a[2]];
    }
    let columns = model.markers.iter().map(|m| m.name.clone()).collect();
    Ok(Built {
        model,
        variables,
        columns,
        elastic,
    })
}

/// Validate a `tree.identify` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<TreeIdentifyJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    let Built {
        model,
        variables,
        columns,
        elastic,
    } = match &s.justin {
        Some(j) => super::justin::build(&s, j, inputs)?,
        None => described(&s)?,
    };
    let justin = s.justin.is_some();
    let table = inputs.table("samples", &s.samples)?;
    let q_cols = table.cols("samples", &variables)?;
    let mut used: BTreeSet<usize> = q_cols.iter().copied().collect();
    let mut m_cols = Vec::new();
    for prefix in &columns {
        let names: Vec<String> = ["x", "y", "z"]
            .iter()
            .map(|a| format!("{prefix}_{a}"))
            .collect();
        let c = table.cols("samples", &names)?;
        used.extend(c.iter().copied());
        m_cols.push(c);
    }
    let warnings = table
        .columns
        .iter()
        .enumerate()
        .filter(|(i, _)| !used.contains(i))
        .map(|(_, c)| format!("samples: column {c} is not used by tree.identify"))
        .collect();
    let obs: Vec<TreeObservation> = table
        .rows
        .iter()
        .map(|row| TreeObservation {
            sample: model.sample(q_cols.iter().map(|&c| row[c]).collect()),
            points: m_cols
                .iter()
                .map(|c| Some(nalgebra::Vector3::new(row[c[0]], row[c[1]], row[c[2]])))
                .collect(),
        })
        .collect();
    if obs.len() < 2 {
        return Err(JobError::invalid(
            "samples",
            "at least two samples are needed",
        ));
    }
    if let Some(k) = s.options.folds
        && !(2..=obs.len()).contains(&k)
    {
        return Err(JobError::invalid(
            "options.folds",
            format!("{k}: between 2 and the number of samples"),
        ));
    }
    let last = if !elastic.lateral.is_empty() {
        4
    } else if !elastic.joint.is_empty() {
        3
    } else {
        2
    };
    let (prior, cv_weight) = tree_prior(&s.options, &model, last)?;
    Ok(TreeIdentifyJob {
        model,
        obs,
        last,
        folds: s.options.folds,
        seed: s.options.seed,
        max_iterations: s.options.max_iterations.unwrap_or(200),
        prior,
        cv_weight,
        warnings,
        justin,
        robust: s.options.robust.clone(),
    })
}

/// The user's prior from `options`, checked against the last step's unknowns; and whether
/// its weight is to be chosen by K-fold.
fn tree_prior(
    o: &Options,
    model: &ElasticTree,
    last: usize,
) -> Result<(TreePrior, bool), JobError> {
    let weight = check_map_options(o.prior.is_some(), o.prior_weight.as_ref(), o.noise_m)?;
    let Some(spec) = &o.prior else {
        return Ok((TreePrior::default(), false));
    };
    let groups = STEPS[last.min(STEPS.len() - 1)].1;
    let unknowns =
        TreeProblem::new(model.clone(), model.free_params(groups), Vec::new()).unknowns();
    check_names(spec, &unknowns).map_err(|m| JobError::invalid("options.prior", m))?;
    // The std values themselves (and the defaults) are checked by the same code that uses them.
    spec.sigmas(&unknowns, |_| true)
        .map_err(|m| JobError::invalid("options.prior", m))?;
    Ok((
        TreePrior {
            spec: Some(spec.clone()),
            weight: match weight {
                MapWeight::Fixed(w) => w,
                _ => 1.0,
            },
            noise_m: o.noise_m,
        },
        weight == MapWeight::CrossValidated,
    ))
}
