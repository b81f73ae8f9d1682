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
#[inline(always)]
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
    /// The solution one more chord step on, unchecked: more accurate than `z` with a good
    /// inverse, for the trail's predictions only (which are checked by integrating).
    pub(crate) refined: Vec12,
    /// Iterations spent (integrations after the start's residual).
    pub(crate) iterations: usize,
    /// The last integrated point: `z` itself, or the point one chord step before it when
    /// the solution was accepted on its predicted residual (see [`newton`]).
    pub(crate) integrated: Vec12,
    /// Relative distal states at `integrated` (warm starts from there need no integration).
    pub(crate) tips: Tips,
    /// The inverse's convergence rate as last observed (for the next solve along a path).
    pub(crate) rate: Option<Rate>,
}

/// The convergence rate of chord steps with an inverse: the residual ratio after a step over
/// the ratio before it, and how many solves ago it was observed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Rate {
    /// Residual ratio after a step / before it.
    pub(crate) value: f64,
    /// Solves since it was observed (0: in this one).
    pub(crate) age: u8,
}

/// A rate carried to later solves is used this many times before a step must observe it
/// again (the Jacobian drifts along the path; the inverse follows by Broyden updates).
const MAX_RATE_AGE: u8 = 3;

/// A start for [`newton`]: unknowns and, when known, what was solved there.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Start<'a> {
    /// Unknowns.
    pub(crate) z: Vec12,
    /// Relative distal states at `z` with this setup's rods (then no integration is needed
    /// for the first residual).
    pub(crate) tips: Option<&'a Tips>,
    /// A predicted solution (`trail`), taken instead of the first Newton step when the two
    /// agree to half the step.
    pub(crate) predicted: Option<Vec12>,
    /// The convergence rate the start's inverse showed in an earlier solve: with it, a
    /// prediction whose residual is small enough is finished by one chord step without
    /// integrating again (see [`newton`]).
    pub(crate) rate: Option<Rate>,
}

/// The approximate inverse Jacobian a [`newton`] solve starts from and leaves behind: read
/// when `known`, updated in place (no copies); after a failed solve it is meaningless.
pub(crate) struct Inverse<'a> {
    /// The matrix, in and out.
    pub(crate) h: &'a mut Mat12,
    /// Whether `h` holds an inverse to start from (else a fresh one is computed).
    pub(crate) known: bool,
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
pub(crate) fn fresh_inverse(setup: &Setup, mode: &Mode, z: &Vec12) -> Result<Mat12, Failure> {
    let lu = Lu::factor(residual_jacobian(setup, mode, z).1).ok_or(Failure::Singular)?;
    if lu.pivot_ratio < 1e-13 {
        return Err(Failure::Singular);
    }
    let expected = setup.stable_sign[mode.index()];
    if expected != 0.0 && lu.det_sign != expected {
        return Err(Failure::SignChange);
    }
    Ok(lu.inverse())
}

/// `h v`, each row's dot product in four interleaved partial sums (vector lanes). Plain
/// loops, no closure: it is inlined into the AVX2 body and compiled with its features.
#[inline(always)]
fn mat_vec(h: &Mat12, v: &Vec12) -> Vec12 {
    let mut out = [0.0; N];
    for (o, row) in out.iter_mut().zip(h) {
        *o = row_dot(row, v);
    }
    out
}

/// One row's dot product with `v`, in four interleaved partial sums (vector lanes).
#[inline(always)]
fn row_dot(row: &[f64; N], v: &Vec12) -> f64 {
    let mut acc = [0.0; 4];
    for (r4, v4) in row.chunks_exact(4).zip(v.chunks_exact(4)) {
        for ((a, x), y) in acc.iter_mut().zip(r4).zip(v4) {
            *a += x * y;
        }
    }
    (acc[0] + acc[2]) + (acc[1] + acc[3])
}

/// Safety factor on the predicted residual of a solution accepted without integrating at
/// it: accepted when `SAFETY * predicted <= 1` (in units of the tolerance).
const SAFETY: f64 = 10.0;

/// "Good" Broyden update of an inverse Jacobian `h` with the step `s` and the change `y` of
/// the residual it caused: afterwards `h y = s`, and `h` is unchanged on vectors orthogonal
/// to `h^T s`. Skipped when the update is numerically meaningless.
#[inline(always)]
fn broyden(h: &mut Mat12, s: &Vec12, y: &Vec12) {
    // h y (as `mat_vec` sums) and s^T h (a sum of rows), in one pass over h.
    let mut hy = [0.0; N];
    let mut sh = [0.0; N];
    for ((o, row), si) in hy.iter_mut().zip(h.iter()).zip(s) {
        *o = row_dot(row, y);
        for (a, b) in sh.iter_mut().zip(row) {
            *a += si * b;
        }
    }
    let den: f64 = (0..N).map(|k| sh[k] * y[k]).sum();
    let ss: f64 = s.iter().map(|v| v * v).sum();
    if !(den.abs() > 1e-3 * ss) {
        return;
    }
    for ((row, si), hyi) in h.iter_mut().zip(s).zip(hy) {
        let f = (si - hyi) / den;
        for (v, w) in row.iter_mut().zip(sh) {
            *v += f * w;
        }
    }
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
///
/// The last integration is saved when the next one would only confirm: after a step that
/// reduced the residual ratio (residual over tolerance) from `rho_0` to `rho_1`, the chord
/// step from there reduces it again at least about as much (linear convergence at rate
/// `rho_1 / rho_0`, or faster), so the point one more step on has a predicted ratio of
/// `rho_1^2 / rho_0`. With `opts.accept_predicted` that point is returned when ten times
/// its prediction is within tolerance. The estimate is conservative in both regimes: with
/// a fixed inverse the rate stays about the same from step to step, and in the quadratic
/// regime the residual falls faster than the estimate. A rate observed with an inverse
/// that was then thrown away is not used. (Residuals at tolerance mean 1e-12 m; the
/// model's accuracy requirement is 1 nm.)
///
/// Along a path the start's prediction usually lands within a few tolerances, and the
/// inverse is the one the previous solves used (Broyden-updated): the rate it showed there
/// (`start.rate`) predicts the chord step after the prediction in the same way, so that
/// solve ends after one integration. Such a carried rate is used for at most
/// `MAX_RATE_AGE` solves in a row; then a step observes it again.
pub(crate) fn newton(
    setup: &Setup,
    mode: &Mode,
    start: &Start<'_>,
    inverse: Inverse<'_>,
    opts: &SolverOptions,
) -> Result<Solved, (Failure, usize)> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the processor has AVX2, the feature the function is compiled for.
        return unsafe { newton_avx2(setup, mode, start, inverse, opts) };
    }
    newton_body(setup, mode, start, inverse, opts)
}

/// [`newton`] compiled for AVX2: the 12 x 12 products and Broyden updates in 256-bit
/// vectors. No fused multiply-add, so the results are bit for bit the portable code's.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn newton_avx2(
    setup: &Setup,
    mode: &Mode,
    start: &Start<'_>,
    inverse: Inverse<'_>,
    opts: &SolverOptions,
) -> Result<Solved, (Failure, usize)> {
    newton_body(setup, mode, start, inverse, opts)
}

/// The body of [`newton`].
#[inline(always)]
fn newton_body(
    setup: &Setup,
    mode: &Mode,
    start: &Start<'_>,
    inverse: Inverse<'_>,
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
    let Inverse { h, known: mut have } = inverse;
    let mut predicted = start.predicted;
    let mut ratio = residual_ratio(setup, opts, &z, &r);
    let mut prev_ratio = f64::INFINITY;
    let mut prev_step = f64::INFINITY;
    let mut fresh = false;
    let mut taken = 0;
    // The rate as last observed (or carried in), returned for the next solve.
    let mut rate = start.rate.filter(|r| have && r.age < MAX_RATE_AGE);
    for it in 0..=opts.max_iterations {
        if !ratio.is_finite() {
            return Err((Failure::NotFinite, it));
        }
        if !have {
            fresh = true;
            // A new Newton sequence starts here.
            prev_step = f64::INFINITY;
            *h = fresh_inverse(&coarse, mode, &z).map_err(|f| (f, it))?;
            have = true;
        }
        let mut dz = mat_vec(h, &r.map(|v| -v));
        if ratio <= 1.0 {
            return Ok(Solved {
                z,
                refined: std::array::from_fn(|k| z[k] + dz[k]),
                iterations: it,
                integrated: z,
                tips,
                rate,
            });
        }
        if opts.accept_predicted && prev_ratio.is_finite() && SAFETY * ratio * ratio <= prev_ratio {
            let z1 = std::array::from_fn(|k| z[k] + dz[k]);
            return Ok(Solved {
                z: z1,
                refined: z1,
                iterations: it,
                integrated: z,
                tips,
                rate,
            });
        }
        if it == opts.max_iterations {
            break;
        }
        let step = dz.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        let motion = dz[9..].iter().fold(0.0_f64, |m, v| m.max(v.abs()));
        let too_far = prev_step.is_infinite() && motion > opts.max_step;
        let slow = step > 1e-9 && step > opts.contraction * prev_step;
        if too_far || slow {
            if !fresh {
                // A stale inverse: take no step, refresh it here (its convergence rate says
                // nothing about the new one's).
                have = false;
                rate = None;
                prev_ratio = f64::INFINITY;
                continue;
            }
            let failure = if too_far {
                Failure::TooFar(motion)
            } else {
                Failure::NotContracting
            };
            return Err((failure, it));
        }
        // A predicted solution replaces the Newton step when they agree (the prediction's
        // error is then below the step's own second-order error).
        let guess = match predicted.take() {
            Some(p) if (0..N).all(|k| (p[k] - z[k] - dz[k]).abs() <= 0.5 * step) => {
                dz = std::array::from_fn(|k| p[k] - z[k]);
                true
            }
            _ => false,
        };
        let z1: Vec12 = std::array::from_fn(|k| z[k] + dz[k]);
        let (r1, t1) = residual_tips(setup, mode, &z1);
        let ratio1 = residual_ratio(setup, opts, &z1, &r1);
        if guess && !(ratio1 < ratio) {
            // A poor prediction: take the Newton step instead.
            continue;
        }
        if !fresh && !(ratio1 < ratio) {
            // A stale inverse made things worse: reject the step, refresh the inverse.
            have = false;
            rate = None;
            prev_ratio = f64::INFINITY;
            continue;
        }
        // Along a path (a prediction was offered) the small last steps update too: they
        // carry the Jacobian's change since the inverse was made, which the next solve needs.
        if opts.broyden && (step > 1e-7 || start.predicted.is_some()) {
            let y: Vec12 = std::array::from_fn(|k| r1[k] - r[k]);
            broyden(h, &dz, &y);
        }
        // A prediction's reduction of the residual is no convergence rate of the iteration:
        // after one, the next chord step is judged by the rate carried in (when this solve
        // still uses the inverse that showed it); after a chord step, by the step's own.
        let rate_from = if guess {
            match rate.filter(|_| !fresh) {
                Some(r) => {
                    rate = Some(Rate {
                        value: r.value,
                        age: r.age + 1,
                    });
                    ratio1 / r.value
                }
                None => f64::INFINITY,
            }
        } else {
            rate = Some(Rate {
                value: ratio1 / ratio,
                age: 0,
            });
            ratio
        };
        (prev_ratio, z, r, tips, ratio) = (rate_from, z1, r1, t1, ratio1);
        // The second step also corrects the quadratic error of the first (a warm start is
        // one input step away), which a fresh Jacobian would not remove: judge the inverse
        // by the later steps' contraction only.
        taken += 1;
        if !fresh && taken > 2 && step > 1e-9 && step > opts.refresh_rate * prev_step {
            // Converging slowly on an old inverse: refresh it.
            have = false;
            rate = None;
        }
        fresh = false;
        prev_step = step;
    }
    Err((Failure::MaxIterations(ratio), opts.max_iterations))
}
