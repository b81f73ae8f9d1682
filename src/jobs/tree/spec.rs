//! The `tree.identify` job document: its keys, the rows, markers and base it describes,
//! checked and built into a [`TreeIdentifyJob`].

use super::*;

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct Spec {
    #[allow(dead_code)]
    kind: String,
    tree: TreeSpec,
    #[schemars(schema_with = "crate::run::schema::table")]
    samples: Value,
    variables: Vec<String>,
    markers: Vec<MarkerSpec>,
    #[serde(default)]
    base: Option<BaseSpec>,
    #[serde(default)]
    options: Options,
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
struct Options {
    #[serde(default)]
    elastic: ElasticSpec,
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
}

/// Rows with lumped elasticity; `"*"` means every revolute row.
#[derive(Debug, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct ElasticSpec {
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

fn rows(s: &Spec) -> Result<Vec<TreeRow>, JobError> {
    if s.tree.convention != "modified_dh" {
        return Err(JobError::invalid(
            "tree.convention",
            format!(
                "`{}`: only `modified_dh` (Rx(alpha) Dx(a) Ry(beta) Rz(theta + q) Dz(d)) is accepted",
                s.tree.convention
            ),
        ));
    }
    let var = |field: &str, v: &str| {
        s.variables
            .iter()
            .position(|x| x == v)
            .ok_or_else(|| JobError::invalid(field, format!("`{v}` is not one of `variables`")))
    };
    let mut out: Vec<TreeRow> = Vec::new();
    for (i, r) in s.tree.rows.iter().enumerate() {
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

/// Validate a `tree.identify` job.
pub fn prepare(doc: &Value, inputs: &Inputs<'_>) -> Result<TreeIdentifyJob, JobError> {
    let s: Spec = parse_spec(doc)?;
    let tree_rows = rows(&s)?;
    let revolute: Vec<String> = tree_rows
        .iter()
        .filter(|r| matches!(r.kind, RowKind::Revolute { .. }))
        .map(|r| r.name.clone())
        .collect();
    let expand = |v: &[String]| -> Vec<String> {
        if v.iter().any(|x| x == "*") {
            revolute.clone()
        } else {
            v.to_vec()
        }
    };
    let elastic = ElasticOptions {
        joint: expand(&s.options.elastic.joint),
        lateral: expand(&s.options.elastic.lateral),
        lumping: match s.options.elastic.lumping {
            LumpingSpec::Subtree => Lumping::Subtree,
            LumpingSpec::Bodies => Lumping::Bodies,
        },
    };
    let mut markers = Vec::new();
    for (i, m) in s.markers.iter().enumerate() {
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
    let mut model = ElasticTree::new(tree_rows, markers, s.variables.len(), &elastic)
        .map_err(|e| JobError::invalid("tree", e.to_string()))?;
    if let Some(b) = &s.base {
        finite("base", &[b.xyz_m, b.abc_deg].concat())?;
        let a = b.abc_deg.map(f64::to_radians);
        model.base = [b.xyz_m[0], b.xyz_m[1], b.xyz_m[2], a[0], a[1], a[2]];
    }
    let table = inputs.table("samples", &s.samples)?;
    let q_cols = table.cols("samples", &s.variables)?;
    let mut used: BTreeSet<usize> = q_cols.iter().copied().collect();
    let mut m_cols = Vec::new();
    for m in &model.markers {
        let names: Vec<String> = ["x", "y", "z"]
            .iter()
            .map(|a| format!("{}_{a}", m.name))
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
