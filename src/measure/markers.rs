//! Motion-capture markers on a humanoid: residual = model marker position - measured position,
//! three rows per visible (sample, marker); an occluded marker drops only its own rows. Also
//! the rigid fit of a root cluster per sample, a closed-form starting base pose, and marker
//! RMSE reports.

use nalgebra::{DMatrix, Vector3};

use crate::geometry::{Frame, kabsch};
use crate::identify::{IdentifyError, Problem, Unknown};
use crate::model::JointField;
use crate::model::humanoid::{BaseMode, HParam, Humanoid, State};

/// One sample: the robot state and each marker's measured position (None = occluded).
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerSample {
    /// Joint values, torques, cluster pose.
    pub state: State,
    /// Measured position of every model marker (m, measurement frame), in model order.
    pub points: Vec<Option<Vector3<f64>>>,
}

/// The identification problem over a chosen subset of the model's parameters.
#[derive(Debug, Clone)]
pub struct MarkerProblem {
    model: Humanoid,
    free: Vec<usize>,
    samples: Vec<MarkerSample>,
    rows: Vec<(usize, usize)>,
}

/// Plausible size of a parameter's error, for effect sizes: 1 mm, 0.5 deg, 1e-3 rad/(N*m),
/// 1e-5 m/N.
pub fn plausible_range(p: HParam) -> f64 {
    match p {
        HParam::Joint(_, JointField::Err(k)) | HParam::Base(k) if k < 3 => 1e-3,
        HParam::Marker(..) => 1e-3,
        HParam::Joint(_, JointField::Compliance) => 1e-3,
        HParam::BaseCompliance(k) if k < 3 => 1e-5,
        HParam::BaseCompliance(_) => 1e-4,
        _ => 0.5f64.to_radians(),
    }
}

impl MarkerProblem {
    /// The problem with unknowns `free` (indices into `model.params`), starting from the
    /// model's current values.
    pub fn new(model: Humanoid, free: Vec<usize>, samples: Vec<MarkerSample>) -> Self {
        let rows = samples
            .iter()
            .enumerate()
            .flat_map(|(i, s)| {
                s.points
                    .iter()
                    .enumerate()
                    .filter(|(_, p)| p.is_some())
                    .map(move |(m, _)| (i, m))
            })
            .collect();
        Self {
            model,
            free,
            samples,
            rows,
        }
    }

    /// The visible (sample, marker) pairs, one per three residual rows.
    pub fn rows(&self) -> &[(usize, usize)] {
        &self.rows
    }

    /// The samples.
    pub fn samples(&self) -> &[MarkerSample] {
        &self.samples
    }

    /// The unknowns (indices into the model's parameters).
    pub fn free(&self) -> &[usize] {
        &self.free
    }

    /// The starting model.
    pub fn base_model(&self) -> &Humanoid {
        &self.model
    }

    /// Starting unknowns.
    pub fn initial(&self) -> Vec<f64> {
        self.free
            .iter()
            .map(|&g| self.model.value(self.model.params[g]))
            .collect()
    }

    /// The model with the unknowns set to `x`.
    pub fn model(&self, x: &[f64]) -> Humanoid {
        let mut m = self.model.clone();
        m.set_values(&self.free, x);
        m
    }

    /// Names, units and ranges of the unknowns.
    pub fn unknowns(&self) -> Vec<Unknown> {
        self.free
            .iter()
            .map(|&g| {
                let p = self.model.params[g];
                Unknown {
                    name: self.model.param_name(p),
                    unit: self.model.param_unit(p).into(),
                    to_report: 1.0,
                    nominal: self.model.value(p),
                    plausible_range: plausible_range(p),
                    lower: None,
                    upper: None,
                }
            })
            .collect()
    }

    /// Column order for rank detection: the spec's priority classes, model order within.
    pub fn priority_order(&self) -> Vec<usize> {
        let mut order: Vec<usize> = (0..self.free.len()).collect();
        order.sort_by_key(|&k| (self.model.params[self.free[k]].priority(), k));
        order
    }
}

impl Problem for MarkerProblem {
    fn residual_count(&self) -> usize {
        3 * self.rows.len()
    }

    fn unknown_count(&self) -> usize {
        self.free.len()
    }

    fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
        let model = self.model(x);
        let mut k = 0;
        for (i, s) in self.samples.iter().enumerate() {
            let pred = model.marker_positions(&s.state);
            while k < self.rows.len() && self.rows[k].0 == i {
                let m = self.rows[k].1;
                let e = pred[m] - s.points[m].unwrap_or(pred[m]);
                r[3 * k..3 * k + 3].copy_from_slice(e.as_slice());
                k += 1;
            }
        }
        Ok(())
    }

    fn jacobian(&self, x: &[f64], j: &mut DMatrix<f64>) -> Result<(), IdentifyError> {
        let model = self.model(x);
        let mut k = 0;
        let mut visible = Vec::new();
        for (i, s) in self.samples.iter().enumerate() {
            visible.clear();
            while k + visible.len() < self.rows.len() && self.rows[k + visible.len()].0 == i {
                visible.push(self.rows[k + visible.len()].1);
            }
            let mut row = 3 * k;
            model.marker_jacobians(&s.state, &visible, |_, _, buf| {
                for (c, &g) in self.free.iter().enumerate() {
                    for a in 0..3 {
                        j[(row + a, c)] = buf[g][a];
                    }
                }
                row += 3;
            });
            k += visible.len();
        }
        Ok(())
    }
}

/// Root-mean-square 3-D marker error (m): overall and per marker (`None` for a marker
/// never seen), of `model` against `samples`.
pub fn marker_rmse(model: &Humanoid, samples: &[MarkerSample]) -> (f64, Vec<Option<f64>>) {
    let n = model.markers.len();
    let (mut sum, mut cnt) = (vec![0.0; n], vec![0usize; n]);
    for s in samples {
        for (m, p) in model.marker_positions(&s.state).iter().enumerate() {
            if let Some(y) = s.points[m] {
                sum[m] += (p - y).norm_squared();
                cnt[m] += 1;
            }
        }
    }
    let total: usize = cnt.iter().sum();
    let overall = (sum.iter().sum::<f64>() / total.max(1) as f64).sqrt();
    let per = (0..n)
        .map(|m| (cnt[m] > 0).then(|| (sum[m] / cnt[m] as f64).sqrt()))
        .collect();
    (overall, per)
}

/// A closed-form starting base (or support foot) pose: the rigid fit of the model's marker
/// positions (at the current marker guesses) to the measured ones over all samples.
pub fn initial_base(model: &Humanoid, samples: &[MarkerSample]) -> Option<[f64; 6]> {
    let mut m = model.clone();
    m.base = [0.0; 6];
    let (mut from, mut to) = (Vec::new(), Vec::new());
    for s in samples {
        // With a zero base, the prediction is the point in the root frame (identify mode),
        // in the cluster frame before C (cluster mode), or in the foot frame (support mode).
        let mut st = s.state.clone();
        if matches!(m.base_mode, BaseMode::Cluster) {
            st.cluster = None;
        }
        let pred = m.marker_positions(&st);
        for (k, p) in s.points.iter().enumerate() {
            if let Some(y) = p {
                let y = match (&m.base_mode, &s.state.cluster) {
                    (BaseMode::Cluster, Some(c)) => c.inverse().apply(y),
                    _ => *y,
                };
                from.push(pred[k]);
                to.push(y);
            }
        }
    }
    kabsch(&from, &to).map(|f| f.to_xyzabc())
}

/// The rigid shape of a marker cluster and its pose in every sample.
#[derive(Debug, Clone, PartialEq)]
pub struct ClusterFit {
    /// Marker positions in the cluster frame (origin at their centroid).
    pub local: Vec<Vector3<f64>>,
    /// Pose of the cluster frame per sample (`None` when fewer than three markers are seen).
    pub poses: Vec<Option<Frame>>,
    /// RMS distance (m) between fitted and measured cluster markers.
    pub rms: f64,
}

/// Fit a rigid cluster to per-sample marker positions (`points[sample][marker]`): the shape
/// is the Procrustes mean of the complete samples, the frame axes its principal axes.
pub fn fit_cluster(points: &[Vec<Option<Vector3<f64>>>]) -> Option<ClusterFit> {
    let complete: Vec<Vec<Vector3<f64>>> = points
        .iter()
        .filter_map(|s| s.iter().copied().collect::<Option<Vec<_>>>())
        .collect();
    let first = complete.first()?;
    let n = first.len();
    if n < 3 {
        return None;
    }
    // Start from the first complete sample, then average aligned samples twice.
    let centre = |v: &[Vector3<f64>]| v.iter().sum::<Vector3<f64>>() / v.len() as f64;
    let c0 = centre(first);
    let mut shape: Vec<Vector3<f64>> = first.iter().map(|p| p - c0).collect();
    for _ in 0..2 {
        let mut acc = vec![Vector3::zeros(); n];
        for s in &complete {
            let t = kabsch(&shape, s)?;
            let back = t.inverse();
            for (a, p) in acc.iter_mut().zip(s) {
                *a += back.apply(p);
            }
        }
        let mean: Vec<Vector3<f64>> = acc.iter().map(|a| a / complete.len() as f64).collect();
        let c = centre(&mean);
        shape = mean.iter().map(|p| p - c).collect();
    }
    // Principal axes as the frame (a deterministic orientation of the shape).
    let mut cov = nalgebra::Matrix3::zeros();
    for p in &shape {
        cov += p * p.transpose();
    }
    let eig = cov.symmetric_eigen();
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let mut r = nalgebra::Matrix3::from_columns(&[
        eig.eigenvectors.column(idx[0]).into_owned(),
        eig.eigenvectors.column(idx[1]).into_owned(),
        eig.eigenvectors.column(idx[2]).into_owned(),
    ]);
    if r.determinant() < 0.0 {
        r.set_column(2, &(-r.column(2)));
    }
    let local: Vec<Vector3<f64>> = shape.iter().map(|p| r.transpose() * p).collect();
    let (mut sq, mut cnt) = (0.0, 0usize);
    let poses = points
        .iter()
        .map(|s| {
            let (l, w): (Vec<_>, Vec<_>) = s
                .iter()
                .enumerate()
                .filter_map(|(k, p)| p.map(|p| (local[k], p)))
                .unzip();
            let t = kabsch(&l, &w)?;
            for (a, b) in l.iter().zip(&w) {
                sq += (t.apply(a) - b).norm_squared();
                cnt += 1;
            }
            Some(t)
        })
        .collect();
    Some(ClusterFit {
        local,
        poses,
        rms: (sq / cnt.max(1) as f64).sqrt(),
    })
}
