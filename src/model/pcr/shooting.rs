//! The 12 x 12 shooting system of the 3-PF robot in scaled unknowns, its exact Jacobian
//! (variational equations) and its derivatives with respect to the robot parameters.
//!
//! Unknowns `z`: scaled proximal wrenches `(nx, ny, m0)` of limbs 1..3 (indices 0..9), then
//! the platform pose `(x/L, y/L, theta)` for forward kinematics or the joints `q/L` for
//! inverse kinematics (9..12). Residuals: per limb the distal position (2, in L) and angle
//! mismatch (rad) (0..9), then the platform's force (2) and moment (1) balance (9..12).

use super::params::{E_INDEX, PcrParams, ROBOT_PARAMS};
use super::rod::{self, M, PHI, Rod, Seed, State, X, Y};
use super::setup::{Mode, Setup};

/// Integrates `R` rods (same step count and method) in lockstep from `y0`; returns the
/// distal states.
pub(crate) fn integrate<const R: usize>(
    rods: &[rod::Rod; R],
    y0: &[rod::State; R],
) -> [rod::State; R] {
    match rods.first().map(|r| r.integrator) {
        Some(super::Integrator::Taylor) => super::taylor::integrate(rods, y0),
        _ => rod::rk4(rods, y0),
    }
}

/// Integrates `R` rods in lockstep together with the variational equations of the `K`
/// seeds; returns the distal states and, per rod, the derivative of its distal state with
/// respect to each seed (exact derivatives of the discrete map of either method).
pub(crate) fn integrate_var<const R: usize, const K: usize>(
    rods: &[rod::Rod; R],
    y0: &[rod::State; R],
    seeds: [rod::Seed; K],
) -> ([rod::State; R], [[rod::State; K]; R]) {
    match rods.first().map(|r| r.integrator) {
        Some(super::Integrator::Taylor) => super::taylor::integrate_var(rods, y0, seeds),
        _ => rod::rk4_var(rods, y0, seeds),
    }
}

/// Number of unknowns and residuals.
pub(crate) const N: usize = 12;
/// A vector of unknowns or residuals.
pub(crate) type Vec12 = [f64; N];
/// A 12 x 12 matrix, row-major.
pub(crate) type Mat12 = [[f64; N]; N];

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

/// Per-limb quantities at `z`; `trig` = `(sin theta, cos theta)` of the platform angle
/// (computed once for the three limbs).
fn limb_eval(setup: &Setup, i: usize, z: &Vec12, q: &[f64; 3], trig: (f64, f64)) -> LimbEval {
    let l = &setup.limbs[i];
    let (s, c) = trig;
    let rb = [c * l.b[0] - s * l.b[1], s * l.b[0] + c * l.b[1]];
    let y0 = rod::start_state_tangent(
        l.a[0] + q[i] * l.u[0],
        l.a[1] + q[i] * l.u[1],
        l.phi0,
        l.tangent0,
        z[3 * i + 2],
    );
    let rod = Rod {
        n: [z[3 * i], z[3 * i + 1]],
        flex: l.flex,
        length: l.length,
        steps: setup.steps,
        integrator: setup.integrator,
    };
    LimbEval { y0, rod, rb }
}

/// The three limbs' quantities at `z`.
fn limb_evals(setup: &Setup, z: &Vec12, q: &[f64; 3], pose: &[f64; 3]) -> [LimbEval; 3] {
    let trig = pose[2].sin_cos();
    std::array::from_fn(|i| limb_eval(setup, i, z, q, trig))
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
    let es = limb_evals(setup, z, &q, &pose);
    for (i, e) in es.iter().enumerate() {
        let t = &tips[i];
        let tip = [e.y0[X] + t[0], e.y0[Y] + t[1], 0.0, 0.0, t[2], t[3]];
        limb_residual(setup, i, e, &tip, &pose, &mut r);
    }
    subtract_load(setup, &mut r);
    r
}

/// Shooting residual at `z` and the relative distal states.
pub(crate) fn residual_tips(setup: &Setup, mode: &Mode, z: &Vec12) -> (Vec12, Tips) {
    let (q, pose) = split(z, mode);
    let mut r = [0.0; N];
    let e = limb_evals(setup, z, &q, &pose);
    let tips = integrate(&e.each_ref().map(|e| e.rod), &e.each_ref().map(|e| e.y0));
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
    let e = limb_evals(setup, z, &q, &pose);
    let (tips, v) = integrate_var(
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
    let es = limb_evals(setup, z, &q, &pose);
    let (tips, vs) = integrate_var(
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
