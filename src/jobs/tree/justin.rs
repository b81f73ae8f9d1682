//! `tree.identify` over DLR's Agile Justin data set: `justin` names the set's
//! `nominal_dh.yaml` and `initial_guess.yaml`, and the samples are its
//! `measurements_flat.csv` (`q00..q18` in rad, `m1_*` right hand, `m2_*` left hand, m).

use super::spec::{Built, Spec, elastic_options};
use super::*;
use crate::measure::justin::PUBLISHED_MM;
use crate::model::elastic::justin::{
    JOINT_COLUMNS, model, parse_initial_guess, parse_nominal_dh, revolute_rows,
};

/// `justin`: the data set's model files (paths relative to the job file, or inline text).
#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(super) struct JustinSpec {
    /// `nominal_dh.yaml`: the DH rows of torso and arms.
    nominal_dh: String,
    /// `initial_guess.yaml`: camera pose and marker positions.
    initial_guess: String,
}

/// The Justin tree from the data set's files; `tree`, `variables`, `markers` and `base`
/// must be absent (the files and the fixed DLR frames define them).
pub(super) fn build(s: &Spec, j: &JustinSpec, inputs: &Inputs<'_>) -> Result<Built, JobError> {
    for (field, given) in [
        ("tree", s.has_tree()),
        ("variables", s.has_variables()),
        ("markers", s.has_markers()),
        ("base", s.has_base()),
    ] {
        if given {
            return Err(JobError::invalid(
                field,
                "not with `justin` (the data set's files define it)",
            ));
        }
    }
    let bad = |field: &str, e: crate::model::ModelError| JobError::invalid(field, e.to_string());
    let dh = parse_nominal_dh(
        &inputs.text_or_inline("justin.nominal_dh", &Value::from(j.nominal_dh.as_str()))?,
    )
    .map_err(|e| bad("justin.nominal_dh", e))?;
    let guess = parse_initial_guess(&inputs.text_or_inline(
        "justin.initial_guess",
        &Value::from(j.initial_guess.as_str()),
    )?)
    .map_err(|e| bad("justin.initial_guess", e))?;
    let elastic = elastic_options(&s.options.elastic, &revolute_rows());
    let model = model(&dh, &guess, &elastic).map_err(|e| bad("justin", e))?;
    Ok(Built {
        model,
        variables: (0..JOINT_COLUMNS).map(|k| format!("q{k:02}")).collect(),
        // The model's markers are `right` and `left`: columns m1 and m2 of the data set.
        columns: vec!["m1".into(), "m2".into()],
        elastic,
    })
}

/// One line of the published table (Tenhumberg and Baeuml, Humanoids 2021).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Published {
    /// The cumulative step it stands beside.
    pub step: String,
    /// Published mean marker error (mm).
    pub mean_mm: f64,
    /// Published standard deviation (mm).
    pub std_mm: f64,
    /// Published maximum (mm).
    pub max_mm: f64,
}

/// The published figures beside the first five steps.
pub(super) fn published() -> Vec<Published> {
    STEPS
        .iter()
        .zip(PUBLISHED_MM)
        .map(|((name, _), p)| Published {
            step: (*name).into(),
            mean_mm: p[0],
            std_mm: p[1],
            max_mm: p[2],
        })
        .collect()
}
