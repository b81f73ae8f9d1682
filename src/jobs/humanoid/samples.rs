//! The samples table of the humanoid kinds: renamed by `column_map`, joint values checked
//! against the URDF limits, torques where elasticity needs them, marker positions with
//! occlusions, the root cluster fitted per sample, and optional mocap pre-processing.

use nalgebra::Vector3;
use serde_json::{Value, json};

use super::{ColumnMap, LoadedModel, PreprocessSpec};
use crate::measure::markers::{MarkerSample, fit_cluster};
use crate::measure::mocap::{MocapReport, preprocess};
use crate::model::humanoid::State;
use crate::run::{Inputs, JobError, Table};

/// Support-leg Jacobian condition number above which a sample's base wrench is not trusted.
pub const MAX_SUPPORT_CONDITION: f64 = 1e3;

/// Validated samples.
#[derive(Debug, Clone)]
pub struct SampleSet {
    /// Samples ready for a fit.
    pub samples: Vec<MarkerSample>,
    /// 1-based rows of the table each sample came from.
    pub rows: Vec<usize>,
    /// Rows left out, with the reason.
    pub dropped: Vec<(usize, String)>,
    /// Pre-processing summary, when the table was a raw recording.
    pub preprocess: Option<MocapReport>,
    /// RMS residual of the root cluster's rigid fit (m), in cluster mode.
    pub cluster_rms: Option<f64>,
    /// Rows in the table.
    pub table_rows: usize,
}

impl SampleSet {
    /// Summary for results.
    pub fn report(&self) -> Value {
        json!({
            "table_rows": self.table_rows,
            "used": self.samples.len(),
            "marker_measurements": self.samples.iter().map(|s| s.points.iter().filter(|p| p.is_some()).count()).sum::<usize>(),
            "dropped": self.dropped.iter().map(|(r, why)| json!({"row": r, "reason": why})).collect::<Vec<_>>(),
            "preprocess": self.preprocess,
            "cluster_fit_rms_mm": self.cluster_rms.map(|v| v * 1e3),
        })
    }
}

fn marker_columns(name: &str) -> [String; 3] {
    [
        format!("{name}_x"),
        format!("{name}_y"),
        format!("{name}_z"),
    ]
}

/// Read and validate the samples of `field`.
pub fn load_samples(
    inputs: &Inputs<'_>,
    field: &str,
    value: &Value,
    column_map: &ColumnMap,
    loaded: &LoadedModel,
    pre: Option<&PreprocessSpec>,
) -> Result<SampleSet, JobError> {
    let model = &loaded.model;
    let point_names: Vec<&str> = model
        .markers
        .iter()
        .map(|m| m.name.as_str())
        .chain(loaded.cluster.iter().map(String::as_str))
        .collect();
    let renamed =
        |c: &str| -> String { column_map.get(c).cloned().unwrap_or_else(|| c.to_string()) };
    let is_point = |c: &str| {
        let c = renamed(c);
        point_names
            .iter()
            .any(|n| marker_columns(n).iter().any(|m| m == &c))
    };
    let table: Table = inputs.table_with_gaps(field, value, &is_point)?;
    samples_from_table(field, table, column_map, loaded, pre)
}

/// Validate the samples of an already parsed table (occlusions as NaN cells): the typed
/// entry point of `humanoid.identify`, and the second half of [`load_samples`].
pub fn samples_from_table(
    field: &str,
    mut table: Table,
    column_map: &ColumnMap,
    loaded: &LoadedModel,
    pre: Option<&PreprocessSpec>,
) -> Result<SampleSet, JobError> {
    let model = &loaded.model;
    let point_names: Vec<&str> = model
        .markers
        .iter()
        .map(|m| m.name.as_str())
        .chain(loaded.cluster.iter().map(String::as_str))
        .collect();
    for (from, to) in column_map {
        let k = table
            .columns
            .iter()
            .position(|c| c == from)
            .ok_or_else(|| {
                JobError::invalid(
                    format!("column_map.{from}"),
                    format!(
                        "no column `{from}` in `{field}` (columns are {:?})",
                        table.columns
                    ),
                )
            })?;
        table.columns[k] = to.clone();
    }
    for (i, c) in table.columns.iter().enumerate() {
        if table.columns[..i].contains(c) {
            return Err(JobError::invalid(
                field,
                format!("column `{c}` appears twice (after column_map)"),
            ));
        }
    }
    let qcols = table.cols(field, &model.variables)?;
    let limits = model.limits();
    // Torque columns: required for elastic joints and a support leg carrying base elasticity.
    let mut needs_tau: Vec<String> = model
        .joints
        .iter()
        .filter(|j| j.elastic)
        .map(|j| j.name.clone())
        .collect();
    if model.base_elastic {
        needs_tau.extend(model.support_variables());
    }
    for j in &needs_tau {
        if !table.has(&format!("tau_{j}")) {
            return Err(JobError::invalid(
                field,
                format!(
                    "missing column `tau_{j}`: the elasticity model needs the measured torque of `{j}` (N*m)"
                ),
            ));
        }
    }
    let taucols: Vec<Option<usize>> = model
        .variables
        .iter()
        .map(|v| table.columns.iter().position(|c| c == &format!("tau_{v}")))
        .collect();
    let pcols: Vec<Vec<usize>> = point_names
        .iter()
        .map(|n| table.cols(field, &marker_columns(n)))
        .collect::<Result<_, _>>()?;
    let n = table.rows.len();
    let mut states = Vec::with_capacity(n);
    for (r, row) in table.rows.iter().enumerate() {
        let mut q = Vec::with_capacity(qcols.len());
        for (k, &c) in qcols.iter().enumerate() {
            let v = row[c];
            if let Some([lo, hi]) = limits[k]
                && !(v >= lo - 1e-9 && v <= hi + 1e-9)
            {
                return Err(JobError::row(
                    field,
                    r + 1,
                    format!(
                        "{} = {v} rad is outside the joint limits [{lo}, {hi}]",
                        model.variables[k]
                    ),
                ));
            }
            q.push(v);
        }
        let tau: Vec<f64> = taucols.iter().map(|c| c.map_or(0.0, |c| row[c])).collect();
        states.push(State {
            q,
            tau,
            cluster: None,
            wrench: [0.0; 6],
        });
    }
    let raw: Vec<Vec<Option<Vector3<f64>>>> = pcols
        .iter()
        .map(|cols| {
            table
                .rows
                .iter()
                .map(|row| {
                    let p = Vector3::new(row[cols[0]], row[cols[1]], row[cols[2]]);
                    p.iter().all(|v| v.is_finite()).then_some(p)
                })
                .collect()
        })
        .collect();
    // Which rows, and the positions to use (raw, or filtered and selected).
    let (rows, points, report): (
        Vec<usize>,
        Vec<Vec<Option<Vector3<f64>>>>,
        Option<MocapReport>,
    ) = match pre {
        None => ((0..n).collect(), raw, None),
        Some(p) => {
            let tcol = table.col(field, "t").map_err(|_| {
                JobError::invalid(field, "pre-processing needs a time column `t` (s)")
            })?;
            let t: Vec<f64> = table.rows.iter().map(|r| r[tcol]).collect();
            let q: Vec<Vec<f64>> = states.iter().map(|s| s.q.clone()).collect();
            let st = preprocess(&t, &raw, Some(&q), &p.options())
                .map_err(|e| JobError::invalid("options.preprocess", e.to_string()))?;
            let mut rows: Vec<usize> = st.postures.iter().flatten().copied().collect();
            rows.sort_unstable();
            let pts = (0..raw.len())
                .map(|m| {
                    (0..n)
                        .map(|i| {
                            if st.keep[m][i] {
                                st.filtered[m][i]
                            } else {
                                None
                            }
                        })
                        .collect()
                })
                .collect();
            (rows, pts, Some(st.report))
        }
    };
    let nm = model.markers.len();
    let mut dropped = Vec::new();
    let mut cluster_rms = None;
    let mut poses: Vec<Option<crate::geometry::Frame>> = vec![None; n];
    if !loaded.cluster.is_empty() {
        let per_sample: Vec<Vec<Option<Vector3<f64>>>> = rows
            .iter()
            .map(|&i| (nm..points.len()).map(|m| points[m][i]).collect())
            .collect();
        let fit = fit_cluster(&per_sample).ok_or_else(|| {
            JobError::invalid(
                "base.markers",
                "no sample shows every cluster marker, or they are collinear: the root cluster cannot be fitted",
            )
        })?;
        cluster_rms = Some(fit.rms);
        for (k, &i) in rows.iter().enumerate() {
            poses[i] = fit.poses[k];
        }
    }
    let mut samples = Vec::new();
    let mut used = Vec::new();
    for &i in &rows {
        if !loaded.cluster.is_empty() && poses[i].is_none() {
            dropped.push((
                i + 1,
                "fewer than three root-cluster markers visible".to_string(),
            ));
            continue;
        }
        let pts: Vec<Option<Vector3<f64>>> = (0..nm).map(|m| points[m][i]).collect();
        if pts.iter().all(Option::is_none) {
            dropped.push((i + 1, "no model marker visible".to_string()));
            continue;
        }
        let mut state = states[i].clone();
        state.cluster = poses[i];
        let cond = model.fill_wrench(&mut state);
        if !(cond < MAX_SUPPORT_CONDITION) {
            dropped.push((
                i + 1,
                format!(
                    "support leg near a singularity (Jacobian condition {cond:.1e}, e.g. a straight knee): its torques do not determine the wrench on the base"
                ),
            ));
            continue;
        }
        samples.push(MarkerSample { state, points: pts });
        used.push(i + 1);
    }
    if samples.is_empty() {
        return Err(JobError::invalid(
            field,
            "no usable sample (every row was dropped)",
        ));
    }
    Ok(SampleSet {
        samples,
        rows: used,
        dropped,
        preprocess: report,
        cluster_rms,
        table_rows: n,
    })
}
