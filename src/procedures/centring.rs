//! The centring loop (Algorithm 1 of the TriCal paper): drive the TCP onto a ball centre with
//! the indicator readings, bounded in iterations, step size and reading time; every abort
//! says why.

use std::time::Duration;

use serde::Serialize;

use super::devices::{DeviceError, Indicators, Robot};
use crate::util::Monitor;

/// Bounds of the loop.
#[derive(Debug, Clone, PartialEq)]
pub struct CentringOptions {
    /// Stop when |r| is below this (mm).
    pub epsilon_mm: f64,
    /// Give up after this many corrective moves.
    pub max_iterations: usize,
    /// A reading asking for a larger move means the ball was lost (mm); the indicators'
    /// half-travel is 6.35 mm.
    pub max_step_mm: f64,
    /// Wait after each move before reading.
    pub settle: Duration,
    /// A reading counts once the next one agrees with it within this (mm): a line produced
    /// while the arm still moved (or delivered late by a loaded link) is never taken.
    pub settle_tol_mm: f64,
    /// Most readings taken while waiting for two consecutive ones to agree.
    pub settle_readings: usize,
    /// Longest wait for one reading.
    pub reading_timeout: Duration,
    /// Largest joint change of one approach move (rad): a move to the start configuration
    /// is split into steps no larger than this.
    pub approach_step: f64,
}

impl Default for CentringOptions {
    fn default() -> Self {
        Self {
            epsilon_mm: 0.010,
            max_iterations: 20,
            max_step_mm: 6.0,
            settle: Duration::from_millis(200),
            settle_tol_mm: 0.002,
            settle_readings: 8,
            reading_timeout: Duration::from_secs(2),
            approach_step: 15f64.to_radians(),
        }
    }
}

/// A successful centring.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Centred {
    /// Joint values recorded at the end (rad).
    pub q: Vec<f64>,
    /// Corrective moves made.
    pub iterations: usize,
    /// |r| of the last reading (mm).
    pub residual_mm: f64,
    /// Every reading (mm), first to last.
    pub readings: Vec<[f64; 3]>,
}

/// Why a centring stopped without success.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CentringError {
    /// A device call failed.
    #[error("device: {0}")]
    Device(#[from] DeviceError),
    /// The reading asks for a move larger than allowed: the ball is not under the device.
    #[error(
        "ball lost: the reading asks for a {step_mm:.3} mm move, above the {limit_mm} mm limit"
    )]
    BallLost {
        /// Requested move.
        step_mm: f64,
        /// The limit.
        limit_mm: f64,
    },
    /// Consecutive readings never agreed: the arm or the ball still moves.
    #[error(
        "indicators not settled: {readings} readings, consecutive ones differ by up to {spread_mm:.4} mm (tolerance {tol_mm} mm)"
    )]
    NotSettled {
        /// Readings taken.
        readings: usize,
        /// Largest difference between consecutive readings.
        spread_mm: f64,
        /// The tolerance.
        tol_mm: f64,
    },
    /// No reading within the timeout.
    #[error("no indicator reading within {timeout_ms} ms")]
    ReadingTimeout {
        /// The limit.
        timeout_ms: u64,
    },
    /// Still not centred after the allowed iterations.
    #[error(
        "not centred after {iterations} moves: |r| = {residual_mm:.4} mm (epsilon {epsilon_mm} mm)"
    )]
    NotConverged {
        /// Moves made.
        iterations: usize,
        /// Last |r|.
        residual_mm: f64,
        /// Tolerance.
        epsilon_mm: f64,
    },
    /// Cancelled by the operator.
    #[error("cancelled")]
    Cancelled,
}

/// A settled reading: fresh readings until two consecutive ones agree within
/// `settle_tol_mm`; the later one is returned.
pub async fn read(ind: &dyn Indicators, opts: &CentringOptions) -> Result<[f64; 3], CentringError> {
    let mut last = read_once(ind, opts).await?;
    let mut spread: f64 = 0.0;
    for _ in 1..opts.settle_readings.max(2) {
        let r = read_once(ind, opts).await?;
        let d = (0..3).map(|k| (r[k] - last[k]).abs()).fold(0.0, f64::max);
        if d <= opts.settle_tol_mm {
            return Ok(r);
        }
        spread = spread.max(d);
        last = r;
    }
    Err(CentringError::NotSettled {
        readings: opts.settle_readings.max(2),
        spread_mm: spread,
        tol_mm: opts.settle_tol_mm,
    })
}

async fn read_once(
    ind: &dyn Indicators,
    opts: &CentringOptions,
) -> Result<[f64; 3], CentringError> {
    match tokio::time::timeout(opts.reading_timeout, ind.read()).await {
        Ok(r) => Ok(r?),
        Err(_) => Err(CentringError::ReadingTimeout {
            timeout_ms: opts.reading_timeout.as_millis() as u64,
        }),
    }
}

fn norm(r: &[f64; 3]) -> f64 {
    (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt()
}

/// Move to `q` (rad) in joint-space steps no larger than `max_step` (rad), checking for
/// cancellation before each step. Each step starts from the joints the robot reports, so a
/// move that went on after a lost reply is absorbed; the last step lands exactly on `q`.
pub async fn approach(
    robot: &dyn Robot,
    q: &[f64],
    max_step: f64,
    monitor: &dyn Monitor,
) -> Result<(), CentringError> {
    // A margin for the resolution of the joints the controller reports.
    let step = 0.99 * max_step;
    loop {
        if monitor.is_cancelled() {
            return Err(CentringError::Cancelled);
        }
        let now = robot.joints().await?;
        if now.len() != q.len() {
            return Err(CentringError::Device(DeviceError::Refused {
                device: "procedure".into(),
                reason: format!("{} joint values for a {}-joint robot", q.len(), now.len()),
            }));
        }
        let d = now
            .iter()
            .zip(q)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        if !(step > 0.0) || d <= step {
            robot.move_joints(q).await?;
            return Ok(());
        }
        let s = step / d;
        let t: Vec<f64> = now.iter().zip(q).map(|(a, b)| a + s * (b - a)).collect();
        robot.move_joints(&t).await?;
    }
}

/// Move to `q_d` (rad) and centre the TCP on the ball under the device.
pub async fn centre(
    robot: &dyn Robot,
    indicators: &dyn Indicators,
    q_d: &[f64],
    opts: &CentringOptions,
    monitor: &dyn Monitor,
) -> Result<Centred, CentringError> {
    if monitor.is_cancelled() {
        return Err(CentringError::Cancelled);
    }
    approach(robot, q_d, opts.approach_step, monitor).await?;
    tokio::time::sleep(opts.settle).await;
    let mut r = read(indicators, opts).await?;
    let mut readings = vec![r];
    let mut iterations = 0;
    while norm(&r) >= opts.epsilon_mm {
        if monitor.is_cancelled() {
            return Err(CentringError::Cancelled);
        }
        if iterations >= opts.max_iterations {
            return Err(CentringError::NotConverged {
                iterations,
                residual_mm: norm(&r),
                epsilon_mm: opts.epsilon_mm,
            });
        }
        if norm(&r) > opts.max_step_mm {
            return Err(CentringError::BallLost {
                step_mm: norm(&r),
                limit_mm: opts.max_step_mm,
            });
        }
        robot.move_tool(r).await?;
        iterations += 1;
        tokio::time::sleep(opts.settle).await;
        r = read(indicators, opts).await?;
        readings.push(r);
    }
    let q = robot.joints().await?;
    Ok(Centred {
        q,
        iterations,
        residual_mm: norm(&r),
        readings,
    })
}
