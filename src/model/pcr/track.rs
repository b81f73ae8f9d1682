//! Continuation between solved configurations of the 3-PF robot, and what a solve leaves
//! behind for the next one (warm starts).
//!
//! A continuation follows straight blends of the setup and the inputs in steps; a step whose
//! Newton iteration starts too far away, stops contracting or meets a Jacobian of the wrong
//! sign is shortened; below `min_fraction` of the path the equilibrium is changing suddenly
//! (a fold, a bifurcation, a snap to another branch) and a [`PcrError::BranchJump`] is
//! returned instead of a pose.

use super::newton::{self, Failure, Inverse, Rate, Solved, Start};
use super::params::PcrParams;
use super::setup::{Mode, Setup};
use super::shooting::{Mat12, N, Tips, Vec12};
use super::trail::Trail;
use super::{Equilibrium, PcrError, SolverOptions};
use crate::geometry::Pose2;

/// What a solve leaves for the next one: an approximate inverse Jacobian and the distal
/// states of the rods, boxed in the solution (one copy per solve, into a new box).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Warm {
    /// True for a forward-kinematics solve (pose unknowns), false for inverse (joints).
    pub(crate) fk: bool,
    /// Fingerprint of the rods (parameters, scaling, steps) the tips were integrated with.
    pub(crate) key: u64,
    /// Approximate inverse Jacobian at the solution.
    pub(crate) inverse: Mat12,
    /// The last integrated point of the solve (the solution, or one chord step before it).
    pub(crate) integrated: Vec12,
    /// Relative distal states at `integrated`.
    pub(crate) tips: Tips,
    /// The solutions of the last consecutive solves with these rods, this one newest.
    pub(crate) trail: Trail,
    /// The convergence rate the inverse showed (see [`newton::newton`]).
    pub(crate) rate: Option<Rate>,
}

impl Warm {
    /// The warm data a solve from `prior` (if any) with the rods `key` fills: the prior's
    /// inverse Jacobian, and its trail when the rods are the same. It takes a `&Box`
    /// because `Box::clone` copies straight into the new allocation; a clone of the value
    /// would be built on the stack and moved, 2 kB more copying per solve.
    #[allow(clippy::borrowed_box)]
    pub(crate) fn from_prior(key: u64, prior: Option<&Box<Self>>) -> Box<Self> {
        match prior {
            Some(p) => {
                let mut w = p.clone();
                if w.key != key {
                    w.key = key;
                    w.trail = Trail::EMPTY;
                }
                w
            }
            None => Box::new(Self::new(key)),
        }
    }

    /// Warm-start data of the rods `key`, to be filled by a solve (no inverse known yet).
    pub(crate) fn new(key: u64) -> Self {
        Self {
            fk: false,
            key,
            inverse: [[0.0; N]; N],
            integrated: [0.0; N],
            tips: [[0.0; 4]; 3],
            trail: Trail::EMPTY,
            rate: None,
        }
    }
}

/// Scaled unknowns of a solved configuration for a given mode.
pub(crate) fn unknowns(eq: &Equilibrium, mode: &Mode, lr: f64) -> Vec12 {
    let mut z = [0.0; N];
    z[..9].copy_from_slice(&eq.scaled);
    let tail = match mode {
        Mode::Fk(_) => [eq.pose.x / lr, eq.pose.y / lr, eq.pose.theta],
        Mode::Ik(_) => eq.q.map(|v| v / lr),
    };
    z[9..].copy_from_slice(&tail);
    z
}

/// Fingerprint of what the rods' integration depends on.
pub(crate) fn fingerprint(p: &PcrParams, l_ref: f64, opts: &SolverOptions) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut h = std::collections::hash_map::DefaultHasher::new();
    for v in p.to_array() {
        v.to_bits().hash(&mut h);
    }
    l_ref.to_bits().hash(&mut h);
    opts.steps.hash(&mut h);
    opts.integrator.hash(&mut h);
    h.finish()
}

/// The equilibrium described by a converged solve; `warm` holds the approximate inverse
/// Jacobian the solve left behind and the trail before it (its other fields are filled here).
pub(crate) fn equilibrium(
    setup: &Setup,
    mode: &Mode,
    solved: Solved,
    mut warm: Box<Warm>,
) -> Equilibrium {
    let Solved {
        z,
        iterations,
        refined,
        integrated,
        tips,
        rate,
    } = solved;
    let lr = setup.l_ref;
    let (q, pose) = match mode {
        Mode::Fk(q) => (q.map(|v| v * lr), Pose2::new(z[9] * lr, z[10] * lr, z[11])),
        Mode::Ik(x) => (
            [z[9] * lr, z[10] * lr, z[11] * lr],
            Pose2::new(x[0] * lr, x[1] * lr, x[2]),
        ),
    };
    let (fs, ms) = (setup.ei / (lr * lr), setup.ei / lr);
    let wrenches = std::array::from_fn(|i| [z[3 * i] * fs, z[3 * i + 1] * fs, z[3 * i + 2] * ms]);
    let mut scaled = [0.0; 9];
    scaled.copy_from_slice(&z[..9]);
    warm.fk = matches!(mode, Mode::Fk(_));
    warm.integrated = integrated;
    warm.tips = tips;
    warm.rate = rate;
    warm.trail.push(mode.input(), refined);
    Equilibrium {
        q,
        pose,
        wrenches,
        iterations,
        scaled,
        warm: Some(warm),
    }
}

/// Continuation from a solved `(setup0, mode0, z0)` to `(setup1, mode1)` along straight
/// blends; returns the solution and the Newton iterations spent, and leaves the solution's
/// approximate inverse Jacobian in `inverse` (which holds the start's when `known`). The
/// start's prediction is tried on the first try at the target only.
pub(crate) fn track(
    setup0: &Setup,
    mode0: &Mode,
    start: Start<'_>,
    inverse: Inverse<'_>,
    setup1: &Setup,
    mode1: &Mode,
    opts: &SolverOptions,
) -> Result<Solved, PcrError> {
    let (mut t, mut dt) = (0.0_f64, 1.0_f64);
    let mut z = start.z;
    let mut tips = start.tips.copied();
    // The start's inverse, then the last solved step's (a failed try in place forgets it).
    let Inverse { h, mut known } = inverse;
    let mut iterations = 0;
    let mut last = String::new();
    let mut branch_signal: Option<String> = None;
    let mut subdivided = false;
    for _ in 0..opts.max_substeps {
        let t1 = (t + dt).min(1.0);
        let setup = setup0.blend(setup1, t1);
        let mode = mode0.blend(mode1, t1);
        let guess = Start {
            z,
            tips: tips.as_ref(),
            predicted: start.predicted.filter(|_| t1 >= 1.0 && !subdivided),
            rate: start.rate,
        };
        // Where the setup changes along the way (the load or the clamps are blended in) or
        // the path had to be subdivided, every solution is checked against a fresh Jacobian:
        // the warm solves' reused, Broyden-updated inverses never see the determinant's sign,
        // and a bifurcation (buckling) may lie on the way. That solve's own inverse is then
        // left in a scratch copy, so a failed check leaves `h` as it was.
        let checked = if setup0 == setup1 && !subdivided {
            let solved = newton::newton(&setup, &mode, &guess, Inverse { h: &mut *h, known }, opts);
            // A failed solve in place leaves no usable inverse: the next try makes a fresh one.
            known &= solved.is_ok();
            solved
        } else {
            let mut scratch = *h;
            let inv = Inverse {
                h: &mut scratch,
                known,
            };
            newton::newton(&setup, &mode, &guess, inv, opts).and_then(|s| {
                let coarse = Setup {
                    steps: opts.jacobian_steps,
                    ..setup
                };
                match newton::fresh_inverse(&coarse, &mode, &s.z) {
                    Ok(fresh) => {
                        *h = fresh;
                        Ok(s)
                    }
                    Err(f) => Err((f, s.iterations)),
                }
            })
        };
        match checked {
            Ok(s) => {
                iterations += s.iterations;
                t = t1;
                if t >= 1.0 {
                    return Ok(Solved { iterations, ..s });
                }
                z = s.integrated;
                tips = Some(s.tips);
                known = true;
                dt = (2.0 * dt).min(1.0);
            }
            Err((failure, it)) => {
                subdivided = true;
                iterations += it;
                let shrink = match failure {
                    Failure::TooFar(step) => (0.8 * opts.max_step / step).clamp(0.05, 0.5),
                    _ => 0.5,
                };
                if !matches!(failure, Failure::MaxIterations(_) | Failure::NotFinite) {
                    branch_signal = Some(describe(&failure));
                }
                last = describe(&failure);
                dt *= shrink;
                if dt < opts.min_fraction {
                    // The path cannot be followed past this point: a fold, a bifurcation or a
                    // jump of the solution if the Jacobian said so on the way, else plain
                    // non-convergence.
                    return Err(match (branch_signal, failure) {
                        (Some(reason), _) => PcrError::BranchJump {
                            fraction: t,
                            reason,
                        },
                        (None, Failure::MaxIterations(r)) => PcrError::NotConverged {
                            reason: "iteration budget spent".into(),
                            iterations,
                            residual: r,
                        },
                        (None, _) => PcrError::NotConverged {
                            reason: last,
                            iterations,
                            residual: f64::INFINITY,
                        },
                    });
                }
            }
        }
    }
    Err(PcrError::NotConverged {
        reason: format!(
            "{} continuation steps did not reach the target ({last})",
            opts.max_substeps
        ),
        iterations,
        residual: f64::NAN,
    })
}

fn describe(f: &Failure) -> String {
    match f {
        Failure::Singular => "singular shooting Jacobian".into(),
        Failure::SignChange => {
            "the shooting Jacobian changed sign: a fold or bifurcation (buckling) lies between the start and the target".into()
        }
        Failure::TooFar(s) => format!("Newton step {s:.3e} larger than allowed"),
        Failure::NotContracting => "Newton steps not contracting".into(),
        Failure::MaxIterations(r) => format!("residual {r:.3e} x tolerance after the iteration budget"),
        Failure::NotFinite => "residual not finite".into(),
    }
}
