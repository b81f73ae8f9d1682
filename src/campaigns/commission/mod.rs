//! Commissioning a ball-centring cell (TriCal paper, section 2.2), as campaigns on the
//! engine: the indicators' zero check on the coupling platform ([`zero`]), the TCP from four
//! centred configurations on one ball ([`tcp`]) and the balls in the robot frame with the
//! base frame they give ([`balls`]). Where the paper's operator acts (mate the device, jog
//! near a ball), the campaign pauses with a prompt ([`super::operator`]); the resume is the
//! confirmation, and it survives a daemon restart.

pub mod balls;
pub mod plan;
pub mod results;
pub mod solve;
pub mod tcp;
pub mod zero;
pub mod zero_plan;

use serde::{Deserialize, Serialize};

use super::engine::{Step, StepError};
use super::operator;
use super::trical::is_device_fault;
use crate::model::Chain;
use crate::model::dh::DhFile;
use crate::procedures::centring::{CentringError, CentringOptions, centre};
use crate::procedures::{Indicators, Journal, Robot};
use crate::util::Monitor;

/// One centred configuration of a guided step (the journal's format).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Centred {
    /// Journal index.
    pub index: usize,
    /// Ball (0-based).
    pub ball: usize,
    /// Joints where the operator left the robot (rad).
    pub q_jogged: Vec<f64>,
    /// Joints at the end of centring (rad).
    pub q: Vec<f64>,
    /// Final |r| (mm).
    pub residual_mm: f64,
    /// Corrective moves.
    pub iterations: usize,
}

/// Wait for the operator to jog the device onto a ball, then centre from where the robot
/// stands. The plan holds the ball (0-based) of each step.
pub struct GuidedCentring<'a> {
    /// The arm.
    pub robot: &'a dyn Robot,
    /// The centring device.
    pub indicators: &'a dyn Indicators,
    /// Loop bounds.
    pub options: &'a CentringOptions,
    /// The campaign's journal (operator markers).
    pub journal: &'a dyn Journal,
    /// What the steps are for, in the prompt (`configuration`, `ball`).
    pub what: &'static str,
    /// Steps in the plan (the prompt's "k/n").
    pub count: usize,
}

impl std::fmt::Debug for GuidedCentring<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GuidedCentring")
            .field("what", &self.what)
            .finish_non_exhaustive()
    }
}

impl GuidedCentring<'_> {
    fn prompt(&self, index: usize, k: usize, n: usize, ball: usize) -> String {
        format!(
            "{} {k}/{n} (step {index}): jog the robot until the three stems touch ball {}, then continue",
            self.what,
            ball + 1
        )
    }
}

impl Step for GuidedCentring<'_> {
    type Plan = usize;
    type Sample = Centred;
    const STAGE: &'static str = "commissioning";

    fn describe(&self, k: usize, n: usize, ball: &usize) -> String {
        format!("{} {k}/{n} (ball {})", self.what, ball + 1)
    }

    async fn measure(
        &self,
        index: usize,
        ball: &usize,
        monitor: &dyn Monitor,
    ) -> Result<Centred, StepError> {
        let prompt = self.prompt(index, index + 1, self.count, *ball);
        operator::confirm(self.journal, index, &prompt)?;
        let fault = |e: String| StepError::Fault(e);
        let q_jogged = self
            .robot
            .joints()
            .await
            .map_err(|e| fault(e.to_string()))?;
        match centre(
            self.robot,
            self.indicators,
            &q_jogged,
            self.options,
            monitor,
        )
        .await
        {
            Ok(c) => Ok(Centred {
                index,
                ball: *ball,
                q_jogged,
                q: c.q,
                residual_mm: c.residual_mm,
                iterations: c.iterations,
            }),
            Err(CentringError::Cancelled) => Err(StepError::Cancelled),
            Err(e) if is_device_fault(&e) => Err(fault(e.to_string())),
            Err(e) => Err(StepError::Wait(format!(
                "centring on ball {} failed ({e}): jog the robot until the three stems touch the ball, then continue",
                ball + 1
            ))),
        }
    }
}

/// The current model's chain, refusing a model not in millimetres (commissioning reports
/// in mm and writes the tool and base in the file's units).
pub fn chain_mm(file: &DhFile) -> Result<Chain, crate::run::JobError> {
    if file.units.length != "mm" {
        return Err(crate::run::JobError::CellMismatch {
            what: "model",
            message: format!(
                "commissioning needs a model with lengths in mm (the cell's model is in {})",
                file.units.length
            ),
        });
    }
    Ok(file.to_chain()?)
}

/// The flange pose (in {0}) of the centred joints on `chain`, with the model's static
/// deflection.
pub fn flange(chain: &Chain, q: &[f64]) -> crate::geometry::Frame {
    let tau = chain.static_torques(q);
    chain.flange(q, Some(&tau))
}
