//! The Agile Justin acceptance run (issue 13, item 5): the data set's texts in, the
//! cumulative table of Tenhumberg and Baeuml (Humanoids 2021) and a K-fold held-out figure
//! out, with the published figures beside ours. The data stay outside the repository; the
//! caller reads the files (`examples/justin_elastic.rs`, `tests/it/justin_elastic.rs`).

use nalgebra::Vector3;
use serde::Serialize;

use super::MeasureError;
use super::tree_markers::{Step, TreeObservation, cumulative, k_fold};
use super::tree_prior::TreePrior;
use crate::model::elastic::justin::{self, JOINT_COLUMNS};
use crate::model::elastic::{ElasticOptions, ElasticTree, Lumping};
use crate::util::{Monitor, Summary};

/// Published mean / std / max marker errors (mm) of the five cumulative models
/// (`published_results.yaml`, transcribed from the paper's results figure).
pub const PUBLISHED_MM: [[f64; 3]; 5] = [
    [21.33, 9.71, 63.41],
    [18.18, 7.80, 45.90],
    [10.50, 5.74, 36.37],
    [5.64, 2.57, 12.83],
    [3.12, 1.71, 8.23],
];

/// Parse `measurements_flat.csv`: columns `q00..q18` (rad), `m1_x..m2_z` (m, camera frame;
/// `m1` the right hand, `m2` the left). Returns joint vectors and the two marker positions.
pub fn parse_measurements(text: &str) -> Result<Vec<(Vec<f64>, [Vector3<f64>; 2])>, MeasureError> {
    let mut lines = text.lines().enumerate();
    let header: Vec<&str> = match lines.next() {
        Some((_, h)) => h.split(',').map(str::trim).collect(),
        None => {
            return Err(MeasureError::Row {
                row: 0,
                reason: "empty table".into(),
            });
        }
    };
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .ok_or_else(|| MeasureError::Row {
                row: 0,
                reason: format!("no column `{name}` in the header"),
            })
    };
    let q_cols = (0..JOINT_COLUMNS)
        .map(|k| col(&format!("q{k:02}")))
        .collect::<Result<Vec<_>, _>>()?;
    let m_cols = ["m1_x", "m1_y", "m1_z", "m2_x", "m2_y", "m2_z"]
        .map(col)
        .into_iter()
        .collect::<Result<Vec<_>, _>>()?;
    let mut out = Vec::new();
    for (n, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        let num = |c: usize| -> Result<f64, MeasureError> {
            let v = cells.get(c).and_then(|s| s.parse::<f64>().ok());
            match v {
                Some(v) if v.is_finite() => Ok(v),
                _ => Err(MeasureError::Row {
                    row: n,
                    reason: format!("column `{}` is not a finite number", header[c]),
                }),
            }
        };
        let q = q_cols
            .iter()
            .map(|&c| num(c))
            .collect::<Result<Vec<_>, _>>()?;
        let m = m_cols
            .iter()
            .map(|&c| num(c))
            .collect::<Result<Vec<_>, _>>()?;
        out.push((
            q,
            [
                Vector3::new(m[0], m[1], m[2]),
                Vector3::new(m[3], m[4], m[5]),
            ],
        ));
    }
    Ok(out)
}

/// The Justin model (every revolute row with joint and lateral elasticity, lumped as
/// `lumping` says) and its observations.
pub fn setup(
    nominal_dh: &str,
    initial_guess: &str,
    measurements: &str,
    lumping: Lumping,
) -> Result<(ElasticTree, Vec<TreeObservation>), JustinError> {
    let dh = justin::parse_nominal_dh(nominal_dh)?;
    let guess = justin::parse_initial_guess(initial_guess)?;
    let rows = justin::revolute_rows();
    let opts = ElasticOptions {
        joint: rows.clone(),
        lateral: rows,
        lumping,
    };
    let model = justin::model(&dh, &guess, &opts)?;
    let obs = parse_measurements(measurements)?
        .into_iter()
        .map(|(q, m)| TreeObservation {
            sample: model.sample(q),
            points: vec![Some(m[0]), Some(m[1])],
        })
        .collect();
    Ok((model, obs))
}

/// What the Justin run failed on.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum JustinError {
    /// A model text (`nominal_dh.yaml`, `initial_guess.yaml`).
    #[error("Justin model: {0}")]
    Model(#[from] crate::model::ModelError),
    /// The measurement table.
    #[error("Justin measurements_flat.csv: {0}")]
    Data(#[from] MeasureError),
    /// The identification.
    #[error("Justin identification: {0}")]
    Identify(#[from] crate::identify::IdentifyError),
}

/// The acceptance report.
#[derive(Debug, Clone, Serialize)]
pub struct JustinReport {
    /// The five cumulative steps over all samples.
    pub steps: Vec<Step>,
    /// Held-out errors (mm) of the full model, K-fold.
    pub held_out_mm: Summary,
    /// K of the K-fold.
    pub folds: usize,
    /// Samples used.
    pub samples: usize,
}

/// Run the cumulative table and the K-fold held-out figure of the full model.
pub fn run(
    model: &ElasticTree,
    obs: &[TreeObservation],
    folds: usize,
    seed: u64,
    monitor: &dyn Monitor,
) -> Result<JustinReport, JustinError> {
    let steps = cumulative(model, obs, 4, 200, &TreePrior::default(), monitor)?.steps;
    let held = k_fold(
        model,
        obs,
        4,
        folds,
        seed,
        200,
        &TreePrior::default(),
        monitor,
    )?;
    Ok(JustinReport {
        steps,
        held_out_mm: Summary::of(&held, "mm"),
        folds,
        samples: obs.len(),
    })
}

/// The table as text, published figures beside ours.
pub fn table(r: &JustinReport) -> String {
    let mut s = format!(
        "Agile Justin, {} samples x 2 markers: marker position error (mm)\n{:<46} {:>20} {:>20} {:>6} {:>5}  {}\n",
        r.samples,
        "model (cumulative)",
        "calibd mean/std/max",
        "published",
        "unkn.",
        "held",
        "status"
    );
    for (k, st) in r.steps.iter().enumerate() {
        let p = PUBLISHED_MM[k.min(4)];
        s += &format!(
            "{:<46} {:>6.2} {:>6.2} {:>6.2} {:>6.2} {:>6.2} {:>6.2} {:>6} {:>5}  {}\n",
            st.name,
            st.error_mm.mean,
            st.error_mm.std,
            st.error_mm.max,
            p[0],
            p[1],
            p[2],
            st.unknowns,
            st.held.len(),
            st.status
        );
    }
    s += &format!(
        "full model, {}-fold held-out: mean {:.2} std {:.2} max {:.2} mm (published: none)\n",
        r.folds, r.held_out_mm.mean, r.held_out_mm.std, r.held_out_mm.max
    );
    s
}
