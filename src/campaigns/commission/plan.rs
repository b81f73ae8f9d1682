//! The commissioning kinds of a ball-centring cell, checked before anything moves:
//! `cell.zero_check` ([`super::zero`]), `cell.identify_tcp`
//! (the TCP from centred configurations on one ball) and `cell.locate_balls` (the balls in
//! the robot frame and the base frame). Each is a resumable campaign that pauses with an
//! operator prompt where the operator acts; see [`crate::campaigns::commission`].

use serde::Deserialize;
use serde_json::Value;

use crate::campaigns::spec::{CentringSpec, RetrySpec, default_cell};
use crate::run::{Inputs, JobError, parse_spec};

pub(super) fn positive(field: &str, v: f64) -> Result<(), JobError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(JobError::invalid(
            field,
            format!("{v} must be a positive number"),
        ))
    }
}

pub(super) fn check_retry(r: &RetrySpec) -> Result<(), JobError> {
    if r.attempts == 0 {
        return Err(JobError::invalid(
            "options.retry.attempts",
            "must be at least 1",
        ));
    }
    Ok(())
}

/// Options of `cell.identify_tcp`.
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct TcpOptions {
    /// Centring loop bounds.
    pub centring: CentringSpec,
    /// Retry of device faults.
    pub retry: RetrySpec,
    /// Refuse when the largest pairwise rotation is below this (deg).
    pub min_rotation_deg: f64,
    /// Refuse when the smallest singular value of the least-squares matrix is below this.
    pub min_singular_value: f64,
}

impl Default for TcpOptions {
    fn default() -> Self {
        Self {
            centring: CentringSpec::default(),
            retry: RetrySpec::default(),
            min_rotation_deg: 20.0,
            min_singular_value: 0.1,
        }
    }
}

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct TcpSpec {
    #[allow(dead_code)]
    kind: String,
    #[serde(default = "default_cell")]
    cell: String,
    #[serde(default = "one")]
    ball: usize,
    #[serde(default = "four")]
    configurations: usize,
    #[serde(default)]
    options: TcpOptions,
}

fn one() -> usize {
    1
}

fn four() -> usize {
    4
}

/// A validated `cell.identify_tcp` job.
#[derive(Debug)]
pub struct IdentifyTcpJob {
    /// The cell.
    pub cell: String,
    /// The ball (0-based).
    pub ball: usize,
    /// Configurations to centre.
    pub configurations: usize,
    /// Options.
    pub options: TcpOptions,
}

/// Validate a `cell.identify_tcp` job.
pub fn prepare_tcp(doc: &Value, _: &Inputs<'_>) -> Result<IdentifyTcpJob, JobError> {
    let s: TcpSpec = parse_spec(doc)?;
    if !(1..=3).contains(&s.ball) {
        return Err(JobError::invalid(
            "ball",
            format!("{}: expected 1, 2 or 3", s.ball),
        ));
    }
    if !(3..=20).contains(&s.configurations) {
        return Err(JobError::invalid(
            "configurations",
            format!("{} is not in 3..=20 (the paper uses 4)", s.configurations),
        ));
    }
    positive("options.min_rotation_deg", s.options.min_rotation_deg)?;
    positive("options.min_singular_value", s.options.min_singular_value)?;
    s.options.centring.validate("options.centring")?;
    check_retry(&s.options.retry)?;
    Ok(IdentifyTcpJob {
        cell: s.cell,
        ball: s.ball - 1,
        configurations: s.configurations,
        options: s.options,
    })
}

/// Options of `cell.locate_balls`.
#[derive(Debug, Clone, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct BallsOptions {
    /// Centring loop bounds.
    pub centring: CentringSpec,
    /// Retry of device faults.
    pub retry: RetrySpec,
    /// Standard deviation of a centred TCP position per coordinate (mm).
    pub centring_noise_mm: f64,
    /// The TCP's standard deviation (mm); by default the one `cell.identify_tcp` wrote
    /// into the model, else zero.
    pub tcp_std_mm: Option<[f64; 3]>,
}

impl Default for BallsOptions {
    fn default() -> Self {
        Self {
            centring: CentringSpec::default(),
            retry: RetrySpec::default(),
            centring_noise_mm: 0.005,
            tcp_std_mm: None,
        }
    }
}

#[derive(Debug, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub(crate) struct BallsSpec {
    #[allow(dead_code)]
    kind: String,
    #[serde(default = "default_cell")]
    cell: String,
    #[serde(default)]
    options: BallsOptions,
}

/// A validated `cell.locate_balls` job.
#[derive(Debug)]
pub struct LocateBallsJob {
    /// The cell.
    pub cell: String,
    /// Options.
    pub options: BallsOptions,
}

/// Validate a `cell.locate_balls` job.
pub fn prepare_balls(doc: &Value, _: &Inputs<'_>) -> Result<LocateBallsJob, JobError> {
    let s: BallsSpec = parse_spec(doc)?;
    if !(s.options.centring_noise_mm.is_finite() && s.options.centring_noise_mm >= 0.0) {
        return Err(JobError::invalid(
            "options.centring_noise_mm",
            "must be >= 0",
        ));
    }
    if s.options
        .tcp_std_mm
        .is_some_and(|t| t.iter().any(|v| !(v.is_finite() && *v >= 0.0)))
    {
        return Err(JobError::invalid(
            "options.tcp_std_mm",
            "every value must be >= 0",
        ));
    }
    s.options.centring.validate("options.centring")?;
    check_retry(&s.options.retry)?;
    Ok(LocateBallsJob {
        cell: s.cell,
        options: s.options,
    })
}

/// `Kind` of a commissioning campaign: resumable, on the TriCal cell's devices.
macro_rules! campaign_kind {
    ($job:ty, $run:path) => {
        impl $crate::run::Kind for $job {
            fn resumable(&self) -> bool {
                true
            }
            fn devices(&self) -> Vec<String> {
                $crate::campaigns::spec::trical_devices(&self.cell)
            }
            fn run(self: std::sync::Arc<Self>, cx: $crate::run::Cx) -> $crate::run::RunFuture {
                Box::pin($run(self, cx))
            }
        }
    };
}

pub(super) use campaign_kind;
