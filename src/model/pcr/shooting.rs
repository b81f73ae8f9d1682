//! The 12 x 12 shooting system of the 3-PF robot in scaled unknowns, its exact Jacobian
//! (variational equations), its derivatives with respect to the robot parameters, and a
//! guarded Newton iteration.
//!
//! Unknowns `z`: scaled proximal wrenches `(nx, ny, m0)` of limbs 1..3 (indices 0..9), then
//! the platform pose `(x/L, y/L, theta)` for forward kinematics or the joints `q/L` for
//! inverse kinematics (9..12). Residuals: per limb the distal position (2, in L) and angle
//! mismatch (rad) (0..9), then the platform's force (2) and moment (1) balance (9..12).

use super::lu::Lu;
use super::params::{E_INDEX, PcrParams, ROBOT_PARAMS};
use super::rod::{self, M, PHI, Rod, Seed, State, X, Y};
use super::{Load, SolverOptions};
use crate::geometry::wrap_angle;

/// Number of unknowns and residuals.
pub(crate) const N: usize = 12;
/// A vector of unknowns or residuals.
pub(crate) type Vec12 = [f64; N];
/// A 12 x 12 matrix, row-major.
pub(crate) type Mat12 = [[f64; N]; N];

/// Scaled, solver-ready geometry of one limb.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LimbSetup {
    /// Proximal clamp at q = 0 (in L).
    pub(crate) a: [f64; 2],
    /// Unit stage axis.
    pub(crate) u: [f64; 2],
    /// Proximal tangent angle gamma + alpha.
    pub(crate) phi0: f64,
    /// Bending flexibility relative to limb 1, (d_1 / d_i)^4.
    pub(crate) flex: f64,
    /// Rod length (in L).
    pub(crate) length: f64,
    /// Distal clamp in {P} (in L).
    pub(crate) b: [f64; 2],
    /// Distal tangent angle in {P}, unwrapped next to `phi0` (the rod makes no loop).
    pub(crate) beta: f64,
}

/// Everything the shooting residual needs apart from the unknowns and the inputs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Setup {
    /// The three limbs.
    pub(crate) limbs: [LimbSetup; 3],
    /// Scaled external load: force (E I_1 / L^2) and moment (E I_1 / L).
    pub(crate) load: [f64; 3],
    /// Reference length L (m).
    pub(crate) l_ref: f64,
    /// Bending stiffness E I_1 of limb 1 (N*m^2): the wrench scale.
    pub(crate) ei: f64,
    /// RK4 steps per rod.
    pub(crate) steps: usize,
    /// Sign of the determinant of the shooting Jacobian (forward, inverse) on the stable
    /// branch connected to the unloaded home configuration; 0 while unknown.
    pub(crate) stable_sign: [f64; 2],
}

impl Setup {
    /// Scaled setup of a parameter set.
    pub(crate) fn new(p: &PcrParams, load: &Load, l_ref: f64, steps: usize) -> Self {
        let d1 = p.limbs[0].d;
        let ei = p.e * std::f64::consts::PI * d1.powi(4) / 64.0;
        let limbs = std::array::from_fn(|i| {
            let lp = &p.limbs[i];
            let phi0 = lp.gamma + lp.alpha;
            let r2 = (d1 / lp.d) * (d1 / lp.d);
            LimbSetup {
                a: [lp.ax / l_ref, lp.ay / l_ref],
                u: [lp.gamma.cos(), lp.gamma.sin()],
                phi0,
                flex: r2 * r2,
                length: lp.l / l_ref,
                b: [lp.bx / l_ref, lp.by / l_ref],
                beta: phi0 + wrap_angle(lp.beta - phi0),
            }
        });
        let f = l_ref * l_ref / ei;
        let load = [
            load.force[0] * f,
            load.force[1] * f,
            load.moment * l_ref / ei,
        ];
        Self {
            limbs,
            load,
            l_ref,
            ei,
            steps,
            stable_sign: [0.0; 2],
        }
    }

    /// The same robot with straight unloaded rods at q = 0 and the platform at the origin:
    /// distal clamps moved to the tips of the straight rods. Its solution is known exactly
    /// (all wrenches zero, pose zero), which makes it the start of every continuation.
    pub(crate) fn relaxed(&self) -> Self {
        let mut s = *self;
        for l in &mut s.limbs {
            l.b = [
                l.a[0] + l.length * l.phi0.cos(),
                l.a[1] + l.length * l.phi0.sin(),
            ];
            l.beta = l.phi0;
        }
        s.load = [0.0; 3];
        s
    }

    /// Blend of two setups of the same robot that differ only in distal clamps and load.
    pub(crate) fn blend(&self, other: &Setup, t: f64) -> Setup {
        let mut s = *self;
        let lerp = |a: f64, b: f64| a + t * (b - a);
        for (l, o) in s.limbs.iter_mut().zip(&other.limbs) {
            l.b = [lerp(l.b[0], o.b[0]), lerp(l.b[1], o.b[1])];
            l.beta = lerp(l.beta, o.beta);
        }
        s.load = std::array::from_fn(|k| lerp(self.load[k], other.load[k]));
        s
    }
}

/// What is given: joints (forward kinematics) or the platform pose (inverse kinematics),
/// scaled (lengths in L).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Mode {
    /// Given joints q/L.
    Fk([f64; 3]),
    /// Given pose (x/L, y/L, theta).
    Ik([f64; 3]),
}

impl Mode {
    /// 0 for forward, 1 for inverse kinematics (index into [`Setup::stable_sign`]).
    pub(crate) fn index(&self) -> usize {
        match self {
            Mode::Fk(_) => 0,
            Mode::Ik(_) => 1,
        }
    }

    /// Straight-line blend between two inputs of the same kind.
    pub(crate) fn blend(&self, other: &Mode, t: f64) -> Mode {
        let lerp = |a: &[f64; 3], b: &[f64; 3]| std::array::from_fn(|k| a[k] + t * (b[k] - a[k]));
        match (self, other) {
            (Mode::Fk(a), Mode::Fk(b)) => Mode::Fk(lerp(a, b)),
            (Mode::Ik(a), Mode::Ik(b)) => Mode::Ik(lerp(a, b)),
            _ => *other,
        }
    }
}

/// Per-limb quantities shared by the residual and its derivatives.
struct LimbEval {
    y0: State,
    rod: Rod,
    /// R(theta) b.
    rb: [f64; 2],
}

fn split(z: &Vec12, mode: &Mode) -> ([f64; 3], [f64; 3]) {
    match mode {
        Mode::Fk(q) => (*q, [z[9], z[10], z[11]]),
        Mode::Ik(x) => ([z[9], z[10], z[11]], *x),
    }
}

fn limb_eval(setup: &Setup, i: usize, z: &Vec12, q: &[f64; 3], pose: &[f64; 3]) -> LimbEval {
    let l = &setup.limbs[i];
    let (s, c) = pose[2].sin_cos();
    let rb = [c * l.b[0] - s * l.b[1], s * l.b[0] + c * l.b[1]];
    let y0 = rod::start_state(
        l.a[0] + q[i] * l.u[0],
        l.a[1] + q[i] * l.u[1],
        l.phi0,
        z[3 * i + 2],
    );
    let rod = Rod {
        n: [z[3 * i], z[3 * i + 1]],
        flex: l.flex,
        length: l.length,
        steps: setup.steps,
    };
    LimbEval { y0, rod, rb }
}

fn limb_residual(
    setup: &Setup,
    i: usize,
    e: &LimbEval,
    tip: &State,
    pose: &[f64; 3],
    r: &mut Vec12,
) {
    let l = &setup.limbs[i];
    r[3 * i] = tip[X] - (pose[0] + e.rb[0]);
    r[3 * i + 1] = tip[Y] - (pose[1] + e.rb[1]);
    r[3 * i + 2] = tip[PHI] - pose[2] - l.beta;
    r[9] += e.rod.n[0];
    r[10] += e.rod.n[1];
    r[11] += e.rb[0] * e.rod.n[1] - e.rb[1] * e.rod.n[0] + tip[M];
}

fn subtract_load(setup: &Setup, r: &mut Vec12) {
    r[9] -= setup.load[0];
    r[10] -= setup.load[1];
    r[11] -= setup.load[2];
}

/// Distal state of each rod relative to its proximal clamp position: `(x - x0, y - y0, phi,
/// m)`. It depends on the wrenches and the rods, not on the joints, the platform pose, the
/// distal clamps or the load, so a residual for new inputs can be assembled from it without
/// integrating (the first step of every warm start is free).
pub(crate) type Tips = [[f64; 4]; 3];

/// Residual from relative distal states (no integration).
pub(crate) fn assemble(setup: &Setup, mode: &Mode, z: &Vec12, tips: &Tips) -> Vec12 {
    let (q, pose) = split(z, mode);
    let mut r = [0.0; N];
    for i in 0..3 {
        let e = limb_eval(setup, i, z, &q, &pose);
        let t = &tips[i];
        let tip = [e.y0[X] + t[0], e.y0[Y] + t[1], 0.0, 0.0, t[2], t[3]];
        limb_residual(setup, i, &e, &tip, &pose, &mut r);
    }
    subtract_load(setup, &mut r);
    r
}

/// Shooting residual at `z` and the relative distal states.
pub(crate) fn residual_tips(setup: &Setup, mode: &Mode, z: &Vec12) -> (Vec12, Tips) {
    let (q, pose) = split(z, mode);
    let mut r = [0.0; N];
    let e: [LimbEval; 3] = std::array::from_fn(|i| limb_eval(setup, i, z, &q, &pose));
    let tips = rod::integrate(&e.each_ref().map(|e| e.rod), &e.each_ref().map(|e| e.y0));
    for i in 0..3 {
        limb_residual(setup, i, &e[i], &tips[i], &pose, &mut r);
    }
    subtract_load(setup, &mut r);
    let rel = std::array::from_fn(|i| {
        let (t, y0) = (&tips[i], &e[i].y0);
        [t[X] - y0[X], t[Y] - y0[Y], t[PHI], t[M]]
    });
    (r, rel)
}

/// Fills the Jacobian entries of limb `i` from its variational columns `v` (seeds Nx, Ny, M0).
fn fill_limb_columns(
    setup: &Setup,
    mode: &Mode,
    i: usize,
    e: &LimbEval,
    v: &[State],
    jac: &mut Mat12,
) {
    for (k, vk) in v.iter().enumerate().take(3) {
        let c = 3 * i + k;
        jac[3 * i][c] = vk[X];
        jac[3 * i + 1][c] = vk[Y];
        jac[3 * i + 2][c] = vk[PHI];
        jac[11][c] = vk[M];
    }
    jac[9][3 * i] = 1.0;
    jac[10][3 * i + 1] = 1.0;
    jac[11][3 * i] -= e.rb[1];
    jac[11][3 * i + 1] += e.rb[0];
    match mode {
        Mode::Fk(_) => {
            jac[3 * i][9] = -1.0;
            jac[3 * i + 1][10] = -1.0;
            jac[3 * i][11] = e.rb[1];
            jac[3 * i + 1][11] = -e.rb[0];
            jac[3 * i + 2][11] = -1.0;
            jac[11][11] -= e.rb[0] * e.rod.n[0] + e.rb[1] * e.rod.n[1];
        }
        Mode::Ik(_) => {
            let u = setup.limbs[i].u;
            jac[3 * i][9 + i] = u[0];
            jac[3 * i + 1][9 + i] = u[1];
        }
    }
}

/// Shooting residual and its exact Jacobian (variational equations) at `z`.
pub(crate) fn residual_jacobian(setup: &Setup, mode: &Mode, z: &Vec12) -> (Vec12, Mat12) {
    let (q, pose) = split(z, mode);
    let mut r = [0.0; N];
    let mut jac = [[0.0; N]; N];
    let e: [LimbEval; 3] = std::array::from_fn(|i| limb_eval(setup, i, z, &q, &pose));
    let (tips, v) = rod::integrate_var(
        &e.each_ref().map(|e| e.rod),
        &e.each_ref().map(|e| e.y0),
        [Seed::Nx, Seed::Ny, Seed::M0],
    );
    for i in 0..3 {
        limb_residual(setup, i, &e[i], &tips[i], &pose, &mut r);
        fill_limb_columns(setup, mode, i, &e[i], &v[i], &mut jac);
    }
    subtract_load(setup, &mut r);
    (r, jac)
}

/// The Jacobian of the residual with respect to the unknowns and its derivatives with
/// respect to the 28 physical robot parameters (columns in [`PcrParams`] flat order), both at
/// `z` from one integration, for the implicit-function pose Jacobian.
pub(crate) fn jacobians(
    setup: &Setup,
    p: &PcrParams,
    mode: &Mode,
    z: &Vec12,
) -> (Mat12, [[f64; ROBOT_PARAMS]; N]) {
    let (q, pose) = split(z, mode);
    let lr = setup.l_ref;
    let (st, ct) = pose[2].sin_cos();
    let mut jac = [[0.0; N]; N];
    let mut g = [[0.0; ROBOT_PARAMS]; N];
    let d1 = p.limbs[0].d;
    let seeds = [Seed::Nx, Seed::Ny, Seed::M0, Seed::Phi0, Seed::Flex];
    let es: [LimbEval; 3] = std::array::from_fn(|i| limb_eval(setup, i, z, &q, &pose));
    let (tips, vs) = rod::integrate_var(
        &es.each_ref().map(|e| e.rod),
        &es.each_ref().map(|e| e.y0),
        seeds,
    );
    for i in 0..3 {
        let (e, v) = (&es[i], &vs[i]);
        fill_limb_columns(setup, mode, i, e, v, &mut jac);
        let f = rod::derivative(&e.rod, &tips[i]);
        let rows = [3 * i, 3 * i + 1, 3 * i + 2, 11];
        let comps = [X, Y, PHI, M];
        let col = |k: usize| 9 * i + k;
        let (n0, n1) = (e.rod.n[0], e.rod.n[1]);
        let u = setup.limbs[i].u;
        // Ax, Ay: the tip moves with the clamp.
        g[3 * i][col(0)] = 1.0 / lr;
        g[3 * i + 1][col(1)] = 1.0 / lr;
        // gamma: the clamp moves along the turned stage axis, and the tangent turns.
        g[3 * i][col(2)] = -q[i] * u[1];
        g[3 * i + 1][col(2)] = q[i] * u[0];
        for (row, comp) in rows.iter().zip(comps) {
            g[*row][col(2)] += v[3][comp];
            g[*row][col(3)] = v[3][comp];
            g[*row][col(7)] = f[comp] / lr;
        }
        // Bx, By: the target point and the lever of the rod's force on the platform.
        let (ex, ey) = ([ct, st], [-st, ct]);
        g[3 * i][col(4)] = -ex[0] / lr;
        g[3 * i + 1][col(4)] = -ex[1] / lr;
        g[11][col(4)] = (ex[0] * n1 - ex[1] * n0) / lr;
        g[3 * i][col(5)] = -ey[0] / lr;
        g[3 * i + 1][col(5)] = -ey[1] / lr;
        g[11][col(5)] = (ey[0] * n1 - ey[1] * n0) / lr;
        g[3 * i + 2][col(6)] = -1.0;
        // d: flex_i = (d_1 / d_i)^4.
        let flex = setup.limbs[i].flex;
        if i > 0 {
            for (row, comp) in rows.iter().zip(comps) {
                let dv = v[4][comp];
                g[*row][col(8)] += dv * (-4.0 * flex / p.limbs[i].d);
                g[*row][8] += dv * (4.0 * flex / d1);
            }
        }
    }
    // The load is scaled by E I_1: its scaled value depends on E and d_1.
    for k in 0..3 {
        g[9 + k][E_INDEX] = setup.load[k] / p.e;
        g[9 + k][8] += 4.0 * setup.load[k] / d1;
    }
    (jac, g)
}

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
