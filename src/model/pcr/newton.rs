//! A guarded chord-Newton solve of the shooting system: reused (coarse) inverse Jacobians,
//! free first residuals from stored distal states, contraction and determinant-sign checks
//! that keep every solve on the branch it started from.

use super::SolverOptions;
use super::lu::Lu;
use super::setup::{Mode, Setup};
use super::shooting::{Mat12, N, Tips, Vec12, assemble, residual_jacobian, residual_tips};

/// Why a Newton solve was abandoned.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Failure {
    /// The Jacobian is singular or nearly so.
    Singular,
    /// The Jacobian's determinant has the sign opposite to the stable branch's.
    SignChange,
    /// The first step moves the pose or joints more than allowed: the start is too far.
    TooFar(f64),
    /// Successive steps do not contract: not in the basin of the start's branch.
    NotContracting,
    /// Iteration budget spent.
    MaxIterations(f64),
    /// A non-finite residual.
    NotFinite,
}

/// Largest residual relative to its tolerance (converged when <= 1). Positions and angles
/// use the absolute tolerances; the force and moment balance a tolerance relative to the
/// largest scaled wrench (at least 1), because their rounding noise grows with the forces.
pub(crate) fn residual_ratio(setup: &Setup, opts: &SolverOptions, z: &Vec12, r: &Vec12) -> f64 {
    let wrench = z[..9].iter().fold(1.0_f64, |m, v| m.max(v.abs()));
    let mut worst = 0.0_f64;
    for (k, v) in r.iter().enumerate() {
        let tol = match k {
            0..9 if k % 3 < 2 => opts.tolerance_position / setup.l_ref,
            0..9 => opts.tolerance_angle,
            _ => opts.tolerance_angle * wrench,
        };
        worst = worst.max(v.abs() / tol);
    }
    if r.iter().all(|v| v.is_finite()) {
        worst
    } else {
        f64::INFINITY
    }
}

/// Result of a converged Newton solve.
#[derive(Debug, Clone)]
pub(crate) struct Solved {
    /// The solution.
    pub(crate) z: Vec12,
    /// Iterations spent.
    pub(crate) iterations: usize,
    /// Approximate inverse Jacobian at the solution (reusable by the next solve).
    pub(crate) inverse: Mat12,
    /// Relative distal states at the solution.
    pub(crate) tips: Tips,
}

/// A start for [`newton`]: unknowns and, when known, what was solved there.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Start<'a> {
    /// Unknowns.
    pub(crate) z: Vec12,
    /// Relative distal states at `z` with this setup's rods (then no integration is needed
    /// for the first residual).
    pub(crate) tips: Option<&'a Tips>,
    /// Approximate inverse Jacobian near `z`.
    pub(crate) inverse: Option<&'a Mat12>,
}

/// Sign of the determinant of the (coarse) shooting Jacobian at `z`, if it is regular.
pub(crate) fn jacobian_sign(setup: &Setup, mode: &Mode, z: &Vec12) -> Option<f64> {
    Lu::factor(residual_jacobian(setup, mode, z).1)
        .filter(|lu| lu.pivot_ratio >= 1e-13)
        .map(|lu| lu.det_sign)
}

/// The inverse of the (coarse) Jacobian at `z`; a [`Failure::Singular`] if it is singular
/// or its determinant has the sign opposite to the stable branch's (a fold or bifurcation
/// was passed).
fn fresh_inverse(setup: &Setup, mode: &Mode, z: &Vec12) -> Result<Mat12, Failure> {
    let lu = Lu::factor(residual_jacobian(setup, mode, z).1).ok_or(Failure::Singular)?;
    if lu.pivot_ratio < 1e-13 {
        return Err(Failure::Singular);
    }
    let expected = setup.stable_sign[mode.index()];
    if expected != 0.0 && lu.det_sign != expected {
        return Err(Failure::SignChange);
    }
    let mut h = [[0.0; N]; N];
    for k in 0..N {
        let mut e = [0.0; N];
        e[k] = 1.0;
        let col = lu.solve(&e);
        for (row, v) in h.iter_mut().zip(col) {
            row[k] = v;
        }
    }
    Ok(h)
}

fn mat_vec(h: &Mat12, v: &Vec12) -> Vec12 {
    std::array::from_fn(|i| (0..N).map(|k| h[i][k] * v[k]).sum())
}

/// Guarded quasi-Newton solve from a start. The first step must move the pose (or joints)
/// by less than `opts.max_step`, and each step after a fresh Jacobian at most `opts.contraction` times the
/// previous step, so the solution found is the one connected to the start and not an
/// equilibrium of another branch.
///
/// Work is reused: the Jacobian comes from a coarser integration (`opts.jacobian_steps`) and
/// is inverted once; the start may bring an inverse from a nearby solution and the distal
/// states that make its first residual free; Broyden updates keep the inverse accurate along
/// the way. A new Jacobian is computed only when the steps stop shrinking fast.
pub(crate) fn newton(
    setup: &Setup,
    mode: &Mode,
    start: &Start<'_>,
    opts: &SolverOptions,
) -> Result<Solved, (Failure, usize)> {
    let coarse = Setup {
        steps: opts.jacobian_steps,
        ..*setup
    };
    let mut z = start.z;
    let (mut r, mut tips) = match start.tips {
        Some(t) => (assemble(setup, mode, &z, t), *t),
        None => residual_tips(setup, mode, &z),
    };
    let mut h: Option<Mat12> = start.inverse.copied();
    let mut ratio = residual_ratio(setup, opts, &z, &r);
    let mut prev_step = f64::INFINITY;
    let mut fresh = false;
    for it in 0..=opts.max_iterations {
        if !ratio.is_finite() {
            return Err((Failure::NotFinite, it));
        }
        let hm = match h.as_ref() {
            Some(hm) => hm,
            None => {
                fresh = true;
                // A new Newton sequence starts here.
                prev_step = f64::INFINITY;
                h.insert(fresh_inverse(&coarse, mode, &z).map_err(|f| (f, it))?)
            }
        };
        if ratio <= 1.0 {
            return Ok(Solved {
                z,
                iterations: it,
                inverse: *hm,
                tips,
            });
        }
        if it == opts.max_iterations {
            break;
        }
        let dz = mat_vec(hm, &r.map(|v| -v));
        let step = dz.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        let motion = dz[9..].iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        let too_far = prev_step.is_infinite() && motion > opts.max_step;
        let slow = step > 1e-9 && step > opts.contraction * prev_step;
        if too_far || slow {
            if !fresh {
                // A stale inverse: take no step, refresh it here.
                h = None;
                continue;
            }
            let failure = if too_far {
                Failure::TooFar(motion)
            } else {
                Failure::NotContracting
            };
            return Err((failure, it));
        }
        let z1: Vec12 = std::array::from_fn(|k| z[k] + dz[k]);
        let (r1, t1) = residual_tips(setup, mode, &z1);
        let ratio1 = residual_ratio(setup, opts, &z1, &r1);
        if !fresh && !(ratio1 < ratio) {
            // A stale inverse made things worse: reject the step, refresh the inverse.
            h = None;
            continue;
        }
        (z, r, tips, ratio) = (z1, r1, t1, ratio1);
        if !fresh && step > 1e-9 && step > opts.refresh_rate * prev_step {
            // Converging slowly on an old inverse: refresh it.
            h = None;
        }
        fresh = false;
        prev_step = step;
    }
    Err((Failure::MaxIterations(ratio), opts.max_iterations))
}
