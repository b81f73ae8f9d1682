//! The 3-PF cell: the planar parallel continuum robot on three SmarAct stages (MCS2) under
//! a microscope (`calibd-pose/1`). In the simulated lab the robot's twin ([`PcrTwin`]:
//! true parameters and microscope noise) sits behind the MCS2 mock's stage model (it
//! learns where the stages settle) and behind the microscope mock's pose model (each image
//! is the true pose at the settled joints, read with noise).

use std::sync::{Arc, Mutex};

use calibd_drivers::microscope::mock::PoseModel;
use calibd_drivers::mock::{self, FaultSpec, Faults, RunningMock};
use calibd_drivers::smaract::mock::StageModel;

use super::with;
use crate::lab::{CellLink, LabError, PcrCellLink, StageBackend, StagesLink};
use crate::model::pcr::Equilibrium;
use crate::twin::PcrTwin;
use crate::util::Rng;

/// Settings of the simulated 3-PF cell.
#[derive(Debug, Clone)]
pub struct SimPcrOptions {
    /// Closed-loop speed of the simulated stages (mm/s).
    pub stage_speed_mm_s: f64,
    /// Largest closed-loop residual of a simulated stage move (nm, uniform +/-).
    pub stage_residual_nm: f64,
    /// Faults planned on the MCS2 mock's replies.
    pub stage_faults: Vec<FaultSpec>,
    /// Faults planned on the microscope mock's replies.
    pub microscope_faults: Vec<FaultSpec>,
}

impl Default for SimPcrOptions {
    fn default() -> Self {
        Self {
            stage_speed_mm_s: 200.0,
            stage_residual_nm: 2.0,
            stage_faults: Vec::new(),
            microscope_faults: Vec::new(),
        }
    }
}

/// The twin's state shared by the two mocks.
struct Sim {
    twin: PcrTwin,
    /// Where the stages settle (m).
    q: [f64; 3],
    last: Option<Equilibrium>,
    noise: Rng,
    residual: Rng,
}

type Shared = super::Shared<Sim>;

/// The robot's clamps on the MCS2 mock: each move settles a few nm from its target and
/// the twin's joints follow.
struct TwinStages {
    sim: Shared,
    range_pm: (i64, i64),
    speed_pm_s: f64,
    residual_pm: f64,
}

impl StageModel for TwinStages {
    fn channels(&self) -> u8 {
        3
    }
    fn range_pm(&self, _: u8) -> (i64, i64) {
        self.range_pm
    }
    fn speed_pm_s(&self, _: u8) -> f64 {
        self.speed_pm_s
    }
    fn referenced_at_start(&self) -> bool {
        true
    }
    fn settle(&self, ch: u8, target_pm: i64) -> i64 {
        let r = self.residual_pm;
        with(&self.sim, |s| {
            // The closed-loop residual never carries a stage past the joint range.
            let (lo, hi) = self.range_pm;
            let at = (target_pm + s.residual.range(-r, r).round() as i64).clamp(lo, hi);
            if let Some(q) = s.q.get_mut(usize::from(ch)) {
                *q = at as f64 * 1e-12;
            }
            at
        })
    }
}

/// The microscope over the twin: the true platform pose at the settled joints (solved
/// from the previous equilibrium), read with the twin's noise. The campaign reads only
/// after the stages report settled, so the image sees the settled robot.
struct TwinMicroscope {
    sim: Shared,
}

impl PoseModel for TwinMicroscope {
    fn image(&mut self) -> Option<[f64; 3]> {
        with(&self.sim, |s| {
            let eq = match &s.last {
                Some(prev) => s
                    .twin
                    .truth
                    .fk_from(prev, &s.q)
                    .or_else(|_| s.twin.truth.fk(&s.q)),
                None => s.twin.truth.fk(&s.q),
            }
            .ok()?;
            let z = s.twin.read(&eq.pose, &mut s.noise);
            s.last = Some(eq);
            Some([z.x, z.y, z.theta])
        })
    }
}

fn mock_err(device: &str, e: impl std::fmt::Display) -> LabError {
    LabError::Mock {
        device: device.into(),
        message: e.to_string(),
    }
}

/// Start the simulated 3-PF cell: the twin (true parameters from `seed`), an MCS2 mock and
/// a microscope mock on loopback ports, and driver actors connected to them.
pub(super) async fn start(
    seed: u64,
    o: &SimPcrOptions,
) -> Result<(CellLink, Vec<RunningMock>), LabError> {
    let (link, mocks) = start_at(seed, o, "127.0.0.1:0", "127.0.0.1:0").await?;
    Ok((CellLink::Pcr(link), mocks))
}

/// The 3-PF twin's nominal model file for `seed`: what a lab file must name for
/// `calibd mock lab` to serve it.
pub fn twin_model(seed: u64) -> Result<crate::model::pcr::PcrFile, LabError> {
    Ok(PcrTwin::nominal(seed)
        .map_err(|e| mock_err("pcr twin", e))?
        .file)
}

/// Start the simulated 3-PF cell's MCS2 stages at `stages_at` and microscope at `scope_at`.
pub async fn start_at(
    seed: u64,
    o: &SimPcrOptions,
    stages_at: &str,
    scope_at: &str,
) -> Result<(PcrCellLink, Vec<RunningMock>), LabError> {
    let twin = PcrTwin::nominal(seed).map_err(|e| mock_err("pcr twin", e))?;
    start_twin_at(twin, seed, o, stages_at, scope_at).await
}

/// Start the devices of a 3-PF cell around `twin` (a lab file's model with its truth drawn
/// around it) at `stages_at` and `scope_at`.
pub async fn start_twin_at(
    twin: PcrTwin,
    seed: u64,
    o: &SimPcrOptions,
    stages_at: &str,
    scope_at: &str,
) -> Result<(PcrCellLink, Vec<RunningMock>), LabError> {
    let file = twin.file.clone();
    let lim = file.limits();
    let lo = lim.iter().map(|l| l[0]).fold(f64::INFINITY, f64::min);
    let hi = lim.iter().map(|l| l[1]).fold(f64::NEG_INFINITY, f64::max);
    let sim: Shared = Arc::new(Mutex::new(Sim {
        twin,
        q: [0.0; 3],
        last: None,
        noise: Rng::new(seed ^ 0x00de_c0de),
        residual: Rng::new(seed ^ 0x0051_a9e5),
    }));
    let stages = TwinStages {
        sim: sim.clone(),
        range_pm: ((lo * 1e12).round() as i64, (hi * 1e12).round() as i64),
        speed_pm_s: o.stage_speed_mm_s.max(1e-3) * 1e9,
        residual_pm: o.stage_residual_nm.max(0.0) * 1e3,
    };
    let stage_mock = mock::start_with(
        stages_at,
        calibd_drivers::smaract::mock::mcs2_handler_with_model(
            Box::new(stages),
            Faults::new(o.stage_faults.clone()),
        ),
    )
    .await
    .map_err(|e| mock_err("mcs2", e))?;
    let scope: Arc<Mutex<dyn PoseModel>> = Arc::new(Mutex::new(TwinMicroscope { sim }));
    let scope_mock = mock::start_with(
        scope_at,
        calibd_drivers::microscope::mock::handler_with(
            scope,
            Faults::new(o.microscope_faults.clone()),
        ),
    )
    .await
    .map_err(|e| mock_err("microscope", e))?;
    let link = PcrCellLink {
        resume: Default::default(),
        name: "pcr3pf".into(),
        stages: StagesLink {
            backend: StageBackend::Mcs2(stage_mock.addr.clone()),
            channels: [0, 1, 2],
            pm_per_count: 1000,
        },
        microscope: scope_mock.addr.clone(),
        // The whole travel: the simulated cell moves between any two planned joint sets.
        max_stage_step_m: file
            .limits()
            .iter()
            .map(|[lo, hi]| hi - lo)
            .fold(0.0, f64::max),
        model: file,
    };
    Ok((link, vec![stage_mock, scope_mock]))
}
