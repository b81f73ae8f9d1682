//! Optimal calibration postures: `partialOptim` (a continuous, constrained optimisation of
//! the joint angles of chosen postures), COCP (the paper's Algorithm 1: re-optimise the
//! weakest posture until it comes back) and NOCP (Algorithm 2: blocks of random feasible
//! postures until O1 stops growing). Generic over a [`PostureModel`].

use serde::Serialize;

use super::postures::{PostureModel, PostureSet, log_det, worst_index};
use crate::identify::IdentifyError;
use crate::util::{Monitor, Rng};

/// Settings of the continuous optimisation.
#[derive(Debug, Clone)]
pub struct OptimOptions {
    /// Gradient steps per call.
    pub iterations: usize,
    /// First trial step, as a fraction of each joint's range.
    pub step: f64,
    /// Finite-difference step on the joints (rad).
    pub fd_step: f64,
}

impl Default for OptimOptions {
    fn default() -> Self {
        Self {
            iterations: 20,
            step: 0.1,
            fd_step: 1e-5,
        }
    }
}

/// `partialOptim`: raise O1 by moving the joint angles of postures `which`, the others fixed.
/// Projected gradient ascent on `log det(M)` (the log of O1 up to constants),
/// with the gradient from finite differences of the blocks, joint limits by projection and
/// the other constraints by backtracking (a step is taken only if every moved posture stays
/// feasible). Returns the O1 gain.
pub fn partial_optim(
    model: &dyn PostureModel,
    set: &mut PostureSet,
    which: &[usize],
    opts: &OptimOptions,
) -> f64 {
    let limits = model.limits();
    let range: Vec<f64> = limits.iter().map(|l| (l[1] - l[0]).max(1e-9)).collect();
    let start = set.o1();
    let mut f = log_det(&set.info);
    if !f.is_finite() {
        return 0.0;
    }
    let mut step = opts.step;
    for _ in 0..opts.iterations {
        // Gradient of f = log det M w.r.t. every moved joint: df = 2 <B M^-1, dB>.
        let Some(chol) = set.info.clone().cholesky() else {
            break;
        };
        let minv = chol.inverse();
        let mut grad: Vec<Vec<f64>> = Vec::with_capacity(which.len());
        for &p in which {
            let b = &set.blocks[p];
            let pm = b * &minv;
            let q = set.postures[p].clone();
            let g: Vec<f64> = (0..q.len())
                .map(|k| {
                    let h = opts.fd_step;
                    let (mut a, mut c) = (q.clone(), q.clone());
                    a[k] += h;
                    c[k] -= h;
                    let db = (model.block(&a) - model.block(&c)) / (2.0 * h);
                    // Scaled by the joint range: ascent in normalised joint space.
                    2.0 * pm.dot(&db) * range[k]
                })
                .collect();
            grad.push(g);
        }
        let gnorm = grad.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
        if !(gnorm > 0.0) {
            break;
        }
        // Backtracking along the projected gradient. A posture whose move would leave the
        // feasible set keeps its halved move (up to three halvings) or stays where it is, so
        // one constrained posture does not stall the others.
        let mut accepted = false;
        for _ in 0..8 {
            let mut trial = set.clone();
            let mut moved = false;
            for (w, &p) in which.iter().enumerate() {
                let mut s = step;
                for _ in 0..4 {
                    let q: Vec<f64> = set.postures[p]
                        .iter()
                        .enumerate()
                        .map(|(k, v)| {
                            (v + s * range[k] * grad[w][k] / gnorm)
                                .clamp(limits[k][0], limits[k][1])
                        })
                        .collect();
                    if model.feasible(&q) {
                        let b = model.block(&q);
                        trial.replace(p, q, b);
                        moved = true;
                        break;
                    }
                    s *= 0.5;
                }
            }
            if moved {
                let ft = log_det(&trial.info);
                if ft > f {
                    *set = trial;
                    f = ft;
                    accepted = true;
                    step = (step * 1.5).min(0.5);
                    break;
                }
            }
            step *= 0.5;
        }
        if !accepted {
            break;
        }
    }
    set.o1() - start
}

/// Draw a random feasible posture (up to `tries` draws within the limits).
pub fn random_feasible(model: &dyn PostureModel, rng: &mut Rng, tries: usize) -> Option<Vec<f64>> {
    let limits = model.limits();
    (0..tries).find_map(|_| {
        let q: Vec<f64> = limits.iter().map(|l| rng.range(l[0], l[1])).collect();
        model.feasible(&q).then_some(q)
    })
}

/// How COCP ended.
#[derive(Debug, Clone, Serialize)]
pub struct CocpReport {
    /// Postures re-optimised.
    pub iterations: usize,
    /// O1 before and after.
    pub o1_start: f64,
    /// O1 at the end.
    pub o1: f64,
    /// O1 at the start and after each re-optimised posture (the last is `o1`).
    pub history: Vec<f64>,
}

/// COCP (Algorithm 1): re-optimise the weakest posture until the same index comes back
/// twice in a row (the weakest posture is already optimal), or `max_iter` postures.
pub fn cocp(
    model: &dyn PostureModel,
    set: &mut PostureSet,
    opts: &OptimOptions,
    max_iter: usize,
    monitor: &dyn Monitor,
) -> Result<CocpReport, IdentifyError> {
    let o1_start = set.o1();
    let mut history = vec![o1_start];
    let mut last = None;
    let mut iterations = 0;
    while iterations < max_iter {
        if monitor.is_cancelled() {
            return Err(IdentifyError::Cancelled);
        }
        let Some(w) = worst_index(set) else { break };
        if last == Some(w) {
            break;
        }
        partial_optim(model, set, &[w], opts);
        history.push(set.o1());
        last = Some(w);
        iterations += 1;
    }
    Ok(CocpReport {
        iterations,
        o1_start,
        o1: set.o1(),
        history,
    })
}

/// Settings of NOCP.
#[derive(Debug, Clone)]
pub struct NocpOptions {
    /// Postures per block (Np, 4 in the paper).
    pub block: usize,
    /// Stop when O1 changes by less than this fraction.
    pub epsilon: f64,
    /// Never more postures than this.
    pub max_postures: usize,
    /// Seed of the random blocks.
    pub seed: u64,
    /// Continuous optimisation settings.
    pub optim: OptimOptions,
    /// Random draws per feasible posture before giving up.
    pub tries: usize,
}

impl Default for NocpOptions {
    fn default() -> Self {
        Self {
            block: 4,
            epsilon: 0.01,
            max_postures: 80,
            seed: 0,
            optim: OptimOptions::default(),
            tries: 2000,
        }
    }
}

/// One NOCP step, for the O1 history.
#[derive(Debug, Clone, Serialize)]
pub struct NocpStep {
    /// Postures in the set after this block.
    pub postures: usize,
    /// O1 after optimising the block and running COCP (0 while not full rank).
    pub o1: f64,
}

/// NOCP's result: the set where O1 stopped growing and its history.
#[derive(Debug, Clone)]
pub struct Nocp {
    /// The selected postures (without the last block, which changed O1 by less than epsilon).
    pub set: PostureSet,
    /// O1 after each block.
    pub history: Vec<NocpStep>,
    /// Whether the plateau was reached (else the posture cap stopped it).
    pub plateau: bool,
}

/// NOCP (Algorithm 2): add blocks of random feasible postures, optimise each new block, run
/// COCP, and stop at the first block that changes O1 by less than `epsilon` (relative).
pub fn nocp(
    model: &dyn PostureModel,
    opts: &NocpOptions,
    monitor: &dyn Monitor,
) -> Result<Nocp, IdentifyError> {
    let mut rng = Rng::new(opts.seed);
    let params = model.block(&vec![0.0; model.dof()]).ncols();
    let mut set = PostureSet::new(params);
    let mut history: Vec<NocpStep> = Vec::new();
    let mut previous: Option<PostureSet> = None;
    while set.len() + opts.block <= opts.max_postures.max(opts.block) {
        if monitor.is_cancelled() {
            return Err(IdentifyError::Cancelled);
        }
        monitor.progress(set.len() as f64 / opts.max_postures as f64, "nocp");
        let first = set.len();
        for _ in 0..opts.block {
            let q = random_feasible(model, &mut rng, opts.tries).ok_or_else(|| {
                IdentifyError::Model(format!(
                    "no feasible posture found in {} random draws: the constraints leave no room",
                    opts.tries
                ))
            })?;
            set.push(model, q);
        }
        let o1 = set.o1();
        if !(o1 > 0.0) {
            // Not all base parameters observable yet: keep adding blocks.
            history.push(NocpStep {
                postures: set.len(),
                o1: 0.0,
            });
            continue;
        }
        let block: Vec<usize> = (first..set.len()).collect();
        partial_optim(model, &mut set, &block, &opts.optim);
        let cap = 4 * set.len();
        cocp(model, &mut set, &opts.optim, cap, monitor)?;
        let o1 = set.o1();
        history.push(NocpStep {
            postures: set.len(),
            o1,
        });
        if let Some(prev) = &previous {
            let before = prev.o1();
            if (o1 - before).abs() < opts.epsilon * before {
                return Ok(Nocp {
                    set: prev.clone(),
                    history,
                    plateau: true,
                });
            }
        }
        previous = Some(set.clone());
    }
    Ok(Nocp {
        set,
        history,
        plateau: false,
    })
}

/// The O1 of postures given directly (e.g. a DETMAX selection).
pub fn o1_of_postures(model: &dyn PostureModel, postures: &[Vec<f64>]) -> f64 {
    PostureSet::from_postures(model, postures.to_vec()).o1()
}
