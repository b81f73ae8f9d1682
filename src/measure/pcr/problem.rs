//! [`PcrProblem`]: weighted pose residuals of 3-PF measurements as a least-squares problem
//! over the 34 unknowns (28 robot parameters, then the 6 extrinsics).
//!
//! Every evaluation solves the forward kinematics of each measurement warm-started from the
//! previous evaluation's equilibrium (parameters change little between Levenberg-Marquardt
//! evaluations), falling back to a cold solve from the home pose. The Jacobian is exact: the
//! implicit-function pose Jacobian of the shooting model and the analytic derivatives of
//! `W_T_Se * Z * M_T_P`.

use std::sync::Mutex;

use nalgebra::DMatrix;

use super::{PcrMeasurement, UNKNOWNS, measured_pose, measured_pose_jacobian, reading};
use crate::geometry::{Pose2, wrap_angle};
use crate::identify::{IdentifyError, Problem};
use crate::model::pcr::file::Extrinsics;
use crate::model::pcr::{Equilibrium, Pcr, PcrParams, ROBOT_PARAMS};

/// Solutions of the last evaluation, reused as warm starts.
#[derive(Debug, Default)]
struct Cache {
    /// Bits of the robot parameters the solutions belong to.
    key: Option<[u64; ROBOT_PARAMS]>,
    robot: Option<Pcr>,
    solutions: Vec<Option<Equilibrium>>,
}

/// The identification problem of a 3-PF robot and its microscope.
#[derive(Debug)]
pub struct PcrProblem {
    base: Pcr,
    measurements: Vec<PcrMeasurement>,
    weight: f64,
    threads: usize,
    cache: Mutex<Cache>,
}

/// Robot parameters from the unknown vector.
pub fn robot_params(x: &[f64]) -> PcrParams {
    PcrParams::from_slice(x)
}

/// Extrinsics from the unknown vector.
pub fn extrinsics(x: &[f64]) -> Extrinsics {
    let mut a = [0.0; 6];
    a.copy_from_slice(&x[ROBOT_PARAMS..UNKNOWNS]);
    Extrinsics::from_array(&a)
}

/// The unknown vector of a parameter set and extrinsics.
pub fn unknowns(p: &PcrParams, e: &Extrinsics) -> Vec<f64> {
    p.to_array().iter().copied().chain(e.to_array()).collect()
}

fn model_err(e: impl std::fmt::Display) -> IdentifyError {
    IdentifyError::Model(e.to_string())
}

/// `f` over `0..n` on up to `threads` scoped threads (contiguous chunks), in order; `None`
/// if a worker panicked.
fn parallel_map<R: Send>(
    n: usize,
    threads: usize,
    f: impl Fn(usize) -> R + Sync,
) -> Option<Vec<R>> {
    let threads = threads.clamp(1, n.max(1));
    if threads == 1 {
        return Some((0..n).map(f).collect());
    }
    let chunk = n.div_ceil(threads);
    let f = &f;
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|t| {
                s.spawn(move || {
                    (t * chunk..((t + 1) * chunk).min(n))
                        .map(f)
                        .collect::<Vec<R>>()
                })
            })
            .collect();
        let mut out = Vec::with_capacity(n);
        for h in handles {
            out.extend(h.join().ok()?);
        }
        Some(out)
    })
}

impl PcrProblem {
    /// A problem over `measurements` for robots like `base` (limits, solver options), with
    /// the angle residuals weighted by `weight` (m/rad: position over orientation
    /// repeatability). Evaluations use every available core (see [`PcrProblem::with_threads`]).
    pub fn new(base: Pcr, measurements: Vec<PcrMeasurement>, weight: f64) -> Self {
        let n = measurements.len();
        let threads = std::thread::available_parallelism().map_or(1, |v| v.get());
        Self {
            base,
            measurements,
            weight,
            threads,
            cache: Mutex::new(Cache {
                solutions: vec![None; n],
                ..Default::default()
            }),
        }
    }

    /// The same problem evaluated on at most `threads` threads.
    pub fn with_threads(mut self, threads: usize) -> Self {
        self.threads = threads.max(1);
        self
    }

    /// The measurements.
    pub fn measurements(&self) -> &[PcrMeasurement] {
        &self.measurements
    }

    /// The angle weight w (m/rad).
    pub fn weight(&self) -> f64 {
        self.weight
    }

    /// The robot with the parameters of `x` and the equilibrium of every measurement.
    pub fn solve(&self, x: &[f64]) -> Result<(Pcr, Vec<Equilibrium>), IdentifyError> {
        let p = robot_params(x);
        let key = p.to_array().map(f64::to_bits);
        let mut cache = self
            .cache
            .lock()
            .map_err(|_| model_err("solution cache poisoned"))?;
        if cache.key == Some(key)
            && let Some(robot) = &cache.robot
        {
            let sols: Option<Vec<Equilibrium>> = cache.solutions.iter().cloned().collect();
            if let Some(sols) = sols {
                return Ok((robot.clone(), sols));
            }
        }
        let robot = self.base.with_params(p).map_err(model_err)?;
        let prev = &cache.solutions;
        let solved = parallel_map(self.measurements.len(), self.threads, |j| {
            let q = &self.measurements[j].q;
            let warm = prev[j].as_ref().and_then(|s| robot.fk_from(s, q).ok());
            match warm {
                Some(eq) => Ok(eq),
                None => robot
                    .fk(q)
                    .map_err(|e| model_err(format!("measurement {}: {e}", j + 1))),
            }
        })
        .ok_or_else(|| model_err("a forward-kinematics worker thread panicked"))?;
        let out: Vec<Equilibrium> = solved.into_iter().collect::<Result<_, _>>()?;
        cache.key = Some(key);
        cache.robot = Some(robot.clone());
        cache.solutions = out.iter().cloned().map(Some).collect();
        Ok((robot, out))
    }

    /// Residuals at `x` from solved equilibria.
    fn fill_residuals(&self, x: &[f64], sols: &[Equilibrium], r: &mut [f64]) {
        let ext = extrinsics(x);
        for (j, (m, eq)) in self.measurements.iter().zip(sols).enumerate() {
            let meas = measured_pose(&ext, &m.z);
            r[3 * j] = self.weight * wrap_angle(eq.pose.theta - meas.theta);
            r[3 * j + 1] = eq.pose.x - meas.x;
            r[3 * j + 2] = eq.pose.y - meas.y;
        }
    }

    /// The Jacobian at `x`; with `consistent` the readings are replaced by the model's own
    /// predictions, so a motion of the frames that leaves every prediction unchanged (a
    /// gauge freedom) gives an exactly zero combination of columns even where the residuals
    /// are not zero. Rank detection uses that one.
    pub fn jacobian_at(
        &self,
        x: &[f64],
        consistent: bool,
        j: &mut DMatrix<f64>,
    ) -> Result<(), IdentifyError> {
        let (robot, sols) = self.solve(x)?;
        let ext = extrinsics(x);
        let w = self.weight;
        let rows = parallel_map(sols.len(), self.threads, |i| robot.pose_jacobian(&sols[i]))
            .ok_or_else(|| model_err("a Jacobian worker thread panicked"))?;
        for (i, ((m, eq), pj)) in self.measurements.iter().zip(&sols).zip(rows).enumerate() {
            let pj = pj.map_err(model_err)?;
            let z: Pose2 = if consistent {
                reading(&ext, &eq.pose)
            } else {
                m.z
            };
            let mj = measured_pose_jacobian(&ext, &z);
            for (row, (c, f)) in [(2, w), (0, 1.0), (1, 1.0)].into_iter().enumerate() {
                for k in 0..ROBOT_PARAMS {
                    j[(3 * i + row, k)] = f * pj[c][k];
                }
                for e in 0..6 {
                    j[(3 * i + row, ROBOT_PARAMS + e)] = -f * mj[c][e];
                }
            }
        }
        Ok(())
    }
}

impl Problem for PcrProblem {
    fn residual_count(&self) -> usize {
        3 * self.measurements.len()
    }

    fn unknown_count(&self) -> usize {
        UNKNOWNS
    }

    fn residuals(&self, x: &[f64], r: &mut [f64]) -> Result<(), IdentifyError> {
        let (_, sols) = self.solve(x)?;
        self.fill_residuals(x, &sols, r);
        Ok(())
    }

    fn jacobian(&self, x: &[f64], j: &mut DMatrix<f64>) -> Result<(), IdentifyError> {
        self.jacobian_at(x, false, j)
    }
}
