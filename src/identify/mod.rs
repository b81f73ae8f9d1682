//! Least squares shared by every calibration method: the [`Problem`] trait, bounded
//! Levenberg-Marquardt with column scaling ([`lm`]), rank detection by pivoted QR
//! ([`rank`]), physical scales, effect sizes and degeneracy checks ([`trust`]), standard
//! deviations and conditioning ([`uncertainty`]), the rank -> LM -> covariance pipeline
//! with its report ([`solve`]), MAP with a Gaussian prior and a K-fold weight ([`prior`]),
//! gauge freedoms held at their nominal combination ([`gauge`]) and robust losses by IRLS
//! ([`robust`]), and the verdict on a result with its reasons ([`verdict`]: duplicated rows
//! in [`duplicates`], validation beyond the training range in [`extrapolation`]). No I/O.

mod blocked;
mod bounds;
pub mod coverage;
pub mod dense;
mod dots;
pub mod duplicates;
pub mod extrapolation;
pub mod gauge;
pub mod gauge_orbit;
mod householder;
mod lean;
pub mod lm;
mod lm_blocked;
pub mod prior;
pub mod prior_grid;
pub mod problem;
pub mod rank;
mod reduced;
pub mod robust;
pub mod solution;
pub mod solve;
pub mod trust;
pub mod uncertainty;
pub mod verdict;

pub use gauge::{Gauge, Gauged, null_directions};
pub use lm::{
    LmOptions, LmReport, LmStart, StopReason, levenberg_marquardt, levenberg_marquardt_from,
};
pub use prior::{Prior, PriorReport, PriorSpec, solve_map};
pub use problem::{Problem, Restricted};
pub use rank::{Pivoting, RankReport, rank_revealing, rank_revealing_scaled};
pub use robust::{Robust, RobustKind, RobustReport, solve_robust};
pub use solve::{
    Blocking, ParamReport, Solution, SolveOptions, Unknown, Unobservable, solve, solve_with,
};
pub use trust::{Degeneracy, NearDependent};
pub use uncertainty::{Uncertainty, uncertainty};
pub use verdict::{Assessment, Facts, Reason, Verdict, assess};

/// Errors of the least-squares layer.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IdentifyError {
    /// The model could not be evaluated (e.g. a shooting method did not converge).
    #[error("model evaluation failed: {0}")]
    Model(String),
    /// The residuals at the starting point are not finite.
    #[error("residual {index} is not finite at the starting point")]
    NonFinite {
        /// Row of the first offending residual.
        index: usize,
    },
    /// Fewer residuals than unknowns.
    #[error("{residuals} residuals cannot determine {unknowns} unknowns")]
    Underdetermined {
        /// Residual count.
        residuals: usize,
        /// Unknown count.
        unknowns: usize,
    },
    /// The work was cancelled through its monitor.
    #[error("cancelled")]
    Cancelled,
}
