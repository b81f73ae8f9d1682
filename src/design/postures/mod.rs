//! Posture sets for calibration design (`../shared/spec/humanoid.md`): the [`PostureModel`]
//! a robot provides (a Jacobian block of base parameters per posture, joint limits, a
//! feasibility test), a set with its information matrix, its O1 index, and `worstIndex`.
//! The optimisers (partialOptim, COCP, NOCP) are in [`super::ocp`].

use nalgebra::DMatrix;

/// What posture design needs from a robot model.
pub trait PostureModel: Sync {
    /// Number of joint variables of a posture.
    fn dof(&self) -> usize;
    /// Lower and upper limit of each joint variable (rad).
    fn limits(&self) -> Vec<[f64; 2]>;
    /// The identification Jacobian block of one posture (rows x base parameters).
    fn block(&self, q: &[f64]) -> DMatrix<f64>;
    /// Whether a posture satisfies every constraint.
    fn feasible(&self, q: &[f64]) -> bool;
}

/// A posture set with its information matrix `M = sum B_p^T B_p`.
#[derive(Debug, Clone)]
pub struct PostureSet {
    /// Joint values of each posture.
    pub postures: Vec<Vec<f64>>,
    pub(crate) blocks: Vec<DMatrix<f64>>,
    pub(crate) info: DMatrix<f64>,
}

/// `log det(M)`, factored with `M` scaled to unit diagonal for accuracy; -inf when `M` is
/// numerically singular (a pivot of the scaled factor below 1e-10: some base parameter is not
/// observable by the set).
pub(crate) fn log_det(m: &DMatrix<f64>) -> f64 {
    let n = m.nrows();
    let d: Vec<f64> = (0..n).map(|k| m[(k, k)].sqrt()).collect();
    if d.iter().any(|v| !(*v > 0.0)) {
        return f64::NEG_INFINITY;
    }
    let s = DMatrix::from_fn(n, n, |i, j| m[(i, j)] / (d[i] * d[j]));
    match s.cholesky() {
        Some(c) => {
            let diag = c.l_dirty().diagonal();
            if diag.iter().any(|v| v * v < 1e-10) {
                return f64::NEG_INFINITY;
            }
            diag.iter().map(|v| 2.0 * v.ln()).sum::<f64>()
                + d.iter().map(|v| 2.0 * v.ln()).sum::<f64>()
        }
        None => f64::NEG_INFINITY,
    }
}

/// O1 = (s1 ... sNb)^(1/Nb) / sqrt(Nq) of an information matrix `M = J^T J` built from `nq`
/// postures: `exp(log det(M) / (2 Nb)) / sqrt(Nq)`. The blocks must already carry a fixed
/// column scaling (independent of the set, e.g. per-parameter RMS over a reference pool),
/// so that O1 measures information per posture and levels off as postures are added.
pub fn o1_of(info: &DMatrix<f64>, nq: usize) -> f64 {
    let nb = info.nrows().max(1) as f64;
    (log_det(info) / (2.0 * nb)).exp() / (nq.max(1) as f64).sqrt()
}

impl PostureSet {
    /// An empty set for a model with `params` base parameters.
    pub fn new(params: usize) -> Self {
        Self {
            postures: Vec::new(),
            blocks: Vec::new(),
            info: DMatrix::zeros(params, params),
        }
    }

    /// A set from postures.
    pub fn from_postures(model: &dyn PostureModel, postures: Vec<Vec<f64>>) -> Self {
        let params = model.block(&vec![0.0; model.dof()]).ncols();
        let mut s = Self::new(params);
        for q in postures {
            s.push(model, q);
        }
        s
    }

    /// Add a posture.
    pub fn push(&mut self, model: &dyn PostureModel, q: Vec<f64>) {
        let b = model.block(&q);
        self.info += b.tr_mul(&b);
        self.blocks.push(b);
        self.postures.push(q);
    }

    /// Replace posture `i`.
    pub fn replace(&mut self, i: usize, q: Vec<f64>, b: DMatrix<f64>) {
        self.info -= self.blocks[i].tr_mul(&self.blocks[i]);
        self.info += b.tr_mul(&b);
        self.blocks[i] = b;
        self.postures[i] = q;
    }

    /// Remove the last `k` postures.
    pub fn truncate(&mut self, len: usize) {
        while self.postures.len() > len {
            if let Some(b) = self.blocks.pop() {
                self.info -= b.tr_mul(&b);
            }
            self.postures.pop();
        }
    }

    /// Number of postures.
    pub fn len(&self) -> usize {
        self.postures.len()
    }

    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.postures.is_empty()
    }

    /// O1 of the set (0 when the base parameters are not all observable yet).
    pub fn o1(&self) -> f64 {
        o1_of(&self.info, self.len())
    }

    /// The stacked Jacobian of the set.
    pub fn stacked(&self) -> DMatrix<f64> {
        let rows: usize = self.blocks.iter().map(|b| b.nrows()).sum();
        let mut j = DMatrix::zeros(rows, self.info.ncols());
        let mut r = 0;
        for b in &self.blocks {
            j.rows_mut(r, b.nrows()).copy_from(b);
            r += b.nrows();
        }
        j
    }
}

/// `worstIndex`: the posture whose removal lowers O1 least (the set's weakest member).
pub fn worst_index(set: &PostureSet) -> Option<usize> {
    let n = set.len();
    (0..n)
        .map(|i| {
            let m = &set.info - set.blocks[i].tr_mul(&set.blocks[i]);
            (i, o1_of(&m, n - 1))
        })
        .fold(None, |acc: Option<(usize, f64)>, v| match acc {
            Some(a) if a.1 >= v.1 => Some(a),
            _ => Some(v),
        })
        .map(|v| v.0)
}

#[cfg(test)]
mod tests;
