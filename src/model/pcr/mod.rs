//! The planar parallel continuum robot 3-PF: three planar Kirchhoff rods pushed by linear
//! stages and clamped to a floating platform, solved by shooting (`../shared/spec/pcr.md`).
//!
//! - [`file`]: the JSON model file (`pcr3pf.json`), checked field by field.
//! - [`params`]: the 28 robot parameters, names and units.
//! - `rod`: the rod equations, RK4 integration (the reference) with variational equations.
//! - `taylor`: Taylor-series integration of the rods (the fast default).
//! - `setup`: the dimensionless robot and the inputs of a solve.
//! - `shooting`: residuals and Jacobians of the 12 x 12 shooting system.
//! - `newton`: the guarded chord-Newton solve.
//! - `track`: continuation between solved configurations, warm-start data.
//! - `trail`: the last solutions along a path of inputs, predicting the next one.
//! - [`sensitivity`]: the paper's Table 2 (finite differences per parameter type).
//! - `solve`: [`Pcr`]: forward and inverse kinematics with continuation and warm starts,
//!   pose Jacobians with respect to the parameters.
//!
//! Units are SI throughout: metres, radians, newtons, pascals.

pub mod file;
pub(crate) mod lu;
mod newton;
pub mod params;
mod rod;
pub mod sensitivity;
mod setup;
mod shooting;
mod solve;
mod taylor;
#[cfg(target_arch = "x86_64")]
mod taylor_x86;
#[cfg(test)]
mod tests;
mod track;
mod trail;

pub use file::PcrFile;
pub use params::{LimbParams, PcrParams, ROBOT_PARAMS, param_index, param_name, param_unit};
pub use solve::Pcr;

use crate::geometry::Pose2;

/// Errors of the 3-PF model: bad inputs and solutions that could not be trusted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PcrError {
    /// A joint value outside the model's limits.
    #[error("joint q{joint} = {value} m is outside its limits [{lower}, {upper}] m")]
    JointOutOfLimits {
        /// Joint number, 1-based.
        joint: usize,
        /// The value given or required (m).
        value: f64,
        /// Lower limit (m).
        lower: f64,
        /// Upper limit (m).
        upper: f64,
    },
    /// An input number is NaN or infinite.
    #[error("{what} is not a finite number ({value})")]
    NotFinite {
        /// Which input.
        what: String,
        /// The value.
        value: f64,
    },
    /// A robot parameter that cannot describe a robot.
    #[error("parameter `{name}` = {value}: {reason}")]
    InvalidParameter {
        /// Parameter name (`l_2`, `E`, ...).
        name: String,
        /// Its value.
        value: f64,
        /// What is wrong.
        reason: String,
    },
    /// Newton did not reach the tolerance.
    #[error(
        "shooting did not converge: {reason} (max residual {residual:e} after {iterations} Newton iterations)"
    )]
    NotConverged {
        /// What stopped it.
        reason: String,
        /// Newton iterations spent.
        iterations: usize,
        /// Largest scaled residual at the end.
        residual: f64,
    },
    /// The solution changes suddenly between neighbouring configurations (a fold, a snap to
    /// another equilibrium branch): no pose is returned rather than a pose on another branch.
    #[error(
        "branch jump: the equilibrium changes suddenly at {fraction:.6} of the way from the start to the target ({reason})"
    )]
    BranchJump {
        /// Where along the continuation path (0 = start, 1 = target).
        fraction: f64,
        /// What was seen (singular Jacobian, step too large, Newton not contracting).
        reason: String,
    },
    /// A commanded pose the robot cannot reach.
    #[error("pose x = {x} m, y = {y} m, theta = {theta} rad is unreachable: {reason}")]
    Unreachable {
        /// Commanded x (m).
        x: f64,
        /// Commanded y (m).
        y: f64,
        /// Commanded theta (rad).
        theta: f64,
        /// Why.
        reason: String,
    },
}

/// An external load applied at the origin of {P}, components in {W}.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Load {
    /// Force (N).
    pub force: [f64; 2],
    /// Moment about the z axis (N*m).
    pub moment: f64,
}

/// How the rods are integrated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[non_exhaustive]
pub enum Integrator {
    /// Order-13 Taylor series, four rods side by side (4 steps per rod: tip error about
    /// 1e-11 m on the 3-PF workspace).
    #[default]
    Taylor,
    /// Classical fixed-step RK4: the straightforward method, kept as the reference.
    Rk4,
}

/// Numerical settings of the shooting solver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolverOptions {
    /// How the rods are integrated.
    pub integrator: Integrator,
    /// Integration steps per rod for the residual (sets the accuracy of every result).
    pub steps: usize,
    /// Integration steps per rod for the Newton Jacobian. A coarser Jacobian only slows Newton from
    /// quadratic to fast linear convergence (rate about the relative Jacobian error) and
    /// never changes the solution, which is fixed by the residual.
    pub jacobian_steps: usize,
    /// Newton iterations allowed per continuation step.
    pub max_iterations: usize,
    /// Converged when every distal position residual is below this (m).
    pub tolerance_position: f64,
    /// Converged when every angle residual is below this (rad); the scaled force and moment
    /// balance (in E*I/L^2 and E*I/L) use it relative to the largest scaled wrench.
    pub tolerance_angle: f64,
    /// Largest first Newton step of the pose (FK) or joints (IK) accepted, in scaled units
    /// (lengths in the mean rod length L, angles in rad); larger means the start is too far
    /// and the continuation takes a shorter step.
    pub max_step: f64,
    /// Required contraction of successive Newton steps (Kantorovich-style branch guard).
    pub contraction: f64,
    /// An inherited inverse Jacobian is refreshed when a step is longer than this fraction
    /// of the previous one (slow convergence), from a solve's third step on (the second
    /// also corrects the first one's quadratic error, which no fresh Jacobian removes).
    pub refresh_rate: f64,
    /// Smallest continuation step (fraction of the path) before a branch jump is reported.
    pub min_fraction: f64,
    /// Continuation steps allowed for one solve.
    pub max_substeps: usize,
    /// Accept a solution one chord step past the last integrated point, without the
    /// integration that would confirm it, when ten times its predicted residual (from the
    /// observed convergence rate) is within the tolerances. False integrates at every
    /// solution returned.
    pub accept_predicted: bool,
    /// Broyden updates of the reused inverse Jacobian after every Newton step, so it follows
    /// the solution along a path and fresh Jacobians are needed less often.
    pub broyden: bool,
    /// Start a warm solve from the solution extrapolated (quintic) through the last six
    /// warm solves' when the inputs follow a smooth, evenly stepped path (`trail`).
    pub predict: bool,
}

impl Default for SolverOptions {
    fn default() -> Self {
        Self {
            integrator: Integrator::Taylor,
            steps: 4,
            jacobian_steps: 2,
            max_iterations: 12,
            tolerance_position: 1e-12,
            tolerance_angle: 1e-12,
            max_step: 0.2,
            contraction: 0.5,
            refresh_rate: 3e-3,
            min_fraction: 1e-4,
            max_substeps: 400,
            accept_predicted: true,
            broyden: true,
            predict: true,
        }
    }
}

/// A solved static equilibrium: joints, platform pose, proximal wrenches.
#[derive(Debug, Clone)]
pub struct Equilibrium {
    /// Joint values q1, q2, q3 (m).
    pub q: [f64; 3],
    /// Platform pose {P} in {W}.
    pub pose: Pose2,
    /// Per limb: internal force nx, ny (N) and moment m (N*m) at the proximal clamp, in {W}.
    pub wrenches: [[f64; 3]; 3],
    /// Newton iterations spent on this solve (all continuation steps).
    pub iterations: usize,
    /// Scaled proximal wrenches (n_x, n_y, m per limb), kept for warm starts.
    scaled: [f64; 9],
    /// The last factorised shooting Jacobian, reused by warm starts of the same kind.
    /// (boxed: an equilibrium is moved and returned by value, the warm data stays put).
    warm: Option<Box<track::Warm>>,
}
