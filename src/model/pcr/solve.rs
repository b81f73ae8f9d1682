//! [`Pcr`]: forward and inverse kinematics of the 3-PF robot by continuation from the home
//! configuration and warm starts (see `track`), and pose Jacobians with respect to the
//! parameters.

use super::lu::Lu;
use super::newton::{self, Inverse, Start};
use super::params::{PcrParams, ROBOT_PARAMS};
use super::setup::{Mode, Setup};
use super::shooting::{self, N};
use super::track::{Warm, equilibrium, fingerprint, track, unknowns};
use super::{Equilibrium, Load, PcrError, SolverOptions};
use crate::geometry::Pose2;

/// A 3-PF robot ready to solve: parameters, joint limits, load, solver settings and the
/// solved home configuration (q = 0).
#[derive(Debug, Clone)]
pub struct Pcr {
    params: PcrParams,
    limits: [[f64; 2]; 3],
    load: Load,
    options: SolverOptions,
    setup: Setup,
    key: u64,
    home: Equilibrium,
}

impl Pcr {
    /// A robot from its parameters and joint limits (m), unloaded, default solver options.
    /// Solves the home configuration, so an impossible robot is refused here.
    pub fn new(params: PcrParams, limits: [[f64; 2]; 3]) -> Result<Self, PcrError> {
        let l_ref = params.limbs.iter().map(|l| l.l).sum::<f64>() / 3.0;
        Self::build(
            params,
            limits,
            Load::default(),
            SolverOptions::default(),
            l_ref,
        )
    }

    fn build(
        params: PcrParams,
        limits: [[f64; 2]; 3],
        load: Load,
        options: SolverOptions,
        l_ref: f64,
    ) -> Result<Self, PcrError> {
        params.validate()?;
        for (k, [lo, hi]) in limits.iter().enumerate() {
            let ok = lo.is_finite() && hi.is_finite() && lo <= &0.0 && hi >= &0.0 && lo < hi;
            if !ok {
                return Err(PcrError::InvalidParameter {
                    name: format!("joint_limits[{k}]"),
                    value: if lo.is_finite() { *hi } else { *lo },
                    reason: format!("[{lo}, {hi}] must be finite, ordered and contain 0"),
                });
            }
        }
        check_finite("load force x", load.force[0])?;
        check_finite("load force y", load.force[1])?;
        check_finite("load moment", load.moment)?;
        if options.steps == 0 || options.jacobian_steps == 0 || options.max_iterations == 0 {
            return Err(PcrError::InvalidParameter {
                name: "solver options".into(),
                value: 0.0,
                reason: "steps, jacobian_steps and max_iterations must be positive".into(),
            });
        }
        let mut setup = Setup::new(&params, &load, l_ref, options.steps, options.integrator);
        let key = fingerprint(&params, l_ref, &options);
        // The unloaded straight configuration is stable: the sign of the Jacobian there marks
        // the stable branch for every later solve.
        let coarse = Setup {
            steps: options.jacobian_steps,
            ..setup.relaxed()
        };
        for (k, mode) in [Mode::Fk([0.0; 3]), Mode::Ik([0.0; 3])].iter().enumerate() {
            setup.stable_sign[k] =
                newton::jacobian_sign(&coarse, mode, &[0.0; N]).ok_or_else(|| {
                    PcrError::InvalidParameter {
                        name: "geometry".into(),
                        value: f64::NAN,
                        reason: "the straight home configuration is singular".into(),
                    }
                })?;
        }
        let relaxed = setup.relaxed();
        let mode = Mode::Fk([0.0; 3]);
        let start = Start {
            z: [0.0; N],
            tips: None,
            predicted: None,
            rate: None,
        };
        let mut warm = Box::new(Warm::new(key));
        let inverse = Inverse {
            h: &mut warm.inverse,
            known: false,
        };
        let solved = track(&relaxed, &mode, start, inverse, &setup, &mode, &options)?;
        let home = equilibrium(&setup, &mode, solved, warm);
        Ok(Self {
            params,
            limits,
            load,
            options,
            setup,
            key,
            home,
        })
    }

    /// The same robot with other parameters (keeps limits, load, options and scaling).
    pub fn with_params(&self, params: PcrParams) -> Result<Self, PcrError> {
        Self::build(
            params,
            self.limits,
            self.load,
            self.options,
            self.setup.l_ref,
        )
    }

    /// The same robot under an external load at the origin of {P}.
    pub fn with_load(&self, load: Load) -> Result<Self, PcrError> {
        Self::build(
            self.params,
            self.limits,
            load,
            self.options,
            self.setup.l_ref,
        )
    }

    /// The same robot with other solver settings.
    pub fn with_options(&self, options: SolverOptions) -> Result<Self, PcrError> {
        Self::build(
            self.params,
            self.limits,
            self.load,
            options,
            self.setup.l_ref,
        )
    }

    /// The robot parameters.
    pub fn params(&self) -> &PcrParams {
        &self.params
    }

    /// Joint limits [lower, upper] per joint (m).
    pub fn limits(&self) -> &[[f64; 2]; 3] {
        &self.limits
    }

    /// The reference length L of the scaled unknowns (m).
    #[cfg(test)]
    pub(crate) fn l_ref(&self) -> f64 {
        self.setup.l_ref
    }

    /// The solver settings.
    pub fn options(&self) -> &SolverOptions {
        &self.options
    }

    /// The solved home configuration (q = 0).
    pub fn home(&self) -> &Equilibrium {
        &self.home
    }

    /// Checks joint values against finiteness and the limits.
    pub fn check_joints(&self, q: &[f64; 3]) -> Result<(), PcrError> {
        for (k, v) in q.iter().enumerate() {
            if !v.is_finite() {
                // The name is formatted only for the error (this check runs on every solve).
                check_finite(&format!("joint q{}", k + 1), *v)?;
            }
            let [lower, upper] = self.limits[k];
            if *v < lower || *v > upper {
                return Err(PcrError::JointOutOfLimits {
                    joint: k + 1,
                    value: *v,
                    lower,
                    upper,
                });
            }
        }
        Ok(())
    }

    /// Forward kinematics, cold: continuation from the home configuration.
    pub fn fk(&self, q: &[f64; 3]) -> Result<Equilibrium, PcrError> {
        self.fk_from(&self.home, q)
    }

    /// Forward kinematics warm-started from a solved configuration of this robot (or of a
    /// robot with nearby parameters); continuation along the straight joint path from it.
    pub fn fk_from(&self, start: &Equilibrium, q: &[f64; 3]) -> Result<Equilibrium, PcrError> {
        self.check_joints(q)?;
        let lr = self.setup.l_ref;
        let from = Mode::Fk(start.q.map(|v| v / lr));
        let to = Mode::Fk(q.map(|v| v / lr));
        self.solve_from(start, &from, &to)
    }

    /// Inverse kinematics, cold: continuation from the home configuration.
    pub fn ik(&self, pose: &Pose2) -> Result<Equilibrium, PcrError> {
        self.ik_from(&self.home, pose)
    }

    /// Inverse kinematics warm-started from a solved configuration; the joints found must lie
    /// within the limits.
    pub fn ik_from(&self, start: &Equilibrium, pose: &Pose2) -> Result<Equilibrium, PcrError> {
        let unreachable = |reason: String| PcrError::Unreachable {
            x: pose.x,
            y: pose.y,
            theta: pose.theta,
            reason,
        };
        check_finite("pose x", pose.x)?;
        check_finite("pose y", pose.y)?;
        check_finite("pose theta", pose.theta)?;
        // A rod of length l reaches at most l away from its stage's line (`u`: the stage
        // axis, cos and sin of gamma computed once per robot).
        let (st, ct) = pose.theta.sin_cos();
        for (i, (l, ls)) in self.params.limbs.iter().zip(&self.setup.limbs).enumerate() {
            let p = [
                pose.x + ct * l.bx - st * l.by,
                pose.y + st * l.bx + ct * l.by,
            ];
            let [c, s] = ls.u;
            let off = -(p[0] - l.ax) * s + (p[1] - l.ay) * c;
            if off.abs() >= l.l {
                return Err(unreachable(format!(
                    "the distal clamp of limb {} is {:.6e} m from its stage axis, rod length {:.6e} m",
                    i + 1,
                    off.abs(),
                    l.l
                )));
            }
        }
        let lr = self.setup.l_ref;
        let from = Mode::Ik([start.pose.x / lr, start.pose.y / lr, start.pose.theta]);
        let to = Mode::Ik([pose.x / lr, pose.y / lr, pose.theta]);
        let eq = self
            .solve_from(start, &from, &to)
            .map_err(|e| unreachable(format!("no equilibrium connected to the start: {e}")))?;
        self.check_joints(&eq.q)
            .map_err(|e| unreachable(e.to_string()))?;
        Ok(eq)
    }

    /// Derivatives of the platform pose (x, y, theta) of a forward-kinematics solution with
    /// respect to the 28 robot parameters, by the implicit function theorem on the shooting
    /// system (exact derivatives of the discretised model).
    pub fn pose_jacobian(&self, eq: &Equilibrium) -> Result<[[f64; ROBOT_PARAMS]; 3], PcrError> {
        let lr = self.setup.l_ref;
        let mode = Mode::Fk(eq.q.map(|v| v / lr));
        self.solution_jacobian(eq, &mode, [lr, lr, 1.0])
    }

    /// Derivatives of the joints of an inverse-kinematics solution (pose held) with respect to
    /// the 28 robot parameters.
    pub fn joint_jacobian(&self, eq: &Equilibrium) -> Result<[[f64; ROBOT_PARAMS]; 3], PcrError> {
        let lr = self.setup.l_ref;
        let mode = Mode::Ik([eq.pose.x / lr, eq.pose.y / lr, eq.pose.theta]);
        self.solution_jacobian(eq, &mode, [lr; 3])
    }

    /// Continuation from a solved configuration `eq` (inputs `from`) to the inputs `to`,
    /// starting from what `eq` left behind when it was solved the same way: its inverse
    /// Jacobian and, with these rods, its last integrated point and distal states.
    fn solve_from(
        &self,
        eq: &Equilibrium,
        from: &Mode,
        to: &Mode,
    ) -> Result<Equilibrium, PcrError> {
        let fk = matches!(from, Mode::Fk(_));
        let prior = eq.warm.as_ref().filter(|w| w.fk == fk);
        let same_rods = prior.filter(|w| w.key == self.key);
        let start = Start {
            // With the same rods, start from the point integrated last (the solution or one
            // chord step before it): its distal states are known, its first residual free.
            z: same_rods.map_or_else(|| unknowns(eq, from, self.setup.l_ref), |w| w.integrated),
            tips: same_rods.map(|w| &w.tips),
            // Along a smooth path of inputs, the solution extrapolated from the last ones.
            predicted: same_rods
                .filter(|_| self.options.predict)
                .and_then(|w| w.trail.predict(&to.input())),
            rate: same_rods.and_then(|w| w.rate),
        };
        let mut warm = Warm::from_prior(self.key, prior);
        let inverse = Inverse {
            h: &mut warm.inverse,
            known: prior.is_some(),
        };
        let setup = &self.setup;
        let solved = track(setup, from, start, inverse, setup, to, &self.options)?;
        Ok(equilibrium(setup, to, solved, warm))
    }

    fn solution_jacobian(
        &self,
        eq: &Equilibrium,
        mode: &Mode,
        unscale: [f64; 3],
    ) -> Result<[[f64; ROBOT_PARAMS]; 3], PcrError> {
        let z = unknowns(eq, mode, self.setup.l_ref);
        let (jac, g) = shooting::jacobians(&self.setup, &self.params, mode, &z);
        let lu = Lu::factor(jac)
            .filter(|f| f.pivot_ratio > 1e-13)
            .ok_or(PcrError::BranchJump {
                fraction: 1.0,
                reason: "singular Jacobian".into(),
            })?;
        let mut out = [[0.0; ROBOT_PARAMS]; 3];
        for (k, row) in out.iter_mut().enumerate() {
            let mut e = [0.0; N];
            e[9 + k] = 1.0;
            let w = lu.solve_transpose(&e);
            for (p, v) in row.iter_mut().enumerate() {
                let dot: f64 = (0..N).map(|r| w[r] * g[r][p]).sum();
                *v = -dot * unscale[k];
            }
        }
        Ok(out)
    }
}

fn check_finite(what: &str, value: f64) -> Result<(), PcrError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(PcrError::NotFinite {
            what: what.to_string(),
            value,
        })
    }
}
