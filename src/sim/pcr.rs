//! The 3-PF cell: the planar parallel continuum robot on three SmarAct stages (MCS2) under
//! a microscope (`calibd-pose/1`). In the simulated lab the robot's twin ([`PcrTwin`]:
//! true parameters and microscope noise) sits behind the MCS2 mock's stage model (it
//! learns where the stages settle) and behind the microscope mock's pose model (each image
//! is the true pose at the settled joints, read with noise).

use std::sync::{Arc, Mutex};

use calibd_drivers::camera::mock::{FrameModel, Image};
use calibd_drivers::microscope::mock::PoseModel;
use calibd_drivers::mock::{self, FaultSpec, Faults, RunningMock};
use calibd_drivers::smaract::mock::StageModel;

use super::with;
use crate::lab::{
    CameraLink, CellLink, FrameSourceLink, LabError, PcrCellLink, PoseSourceLink, StageBackend,
    StagesLink,
};
use crate::measure::pattern::{PatternPose, PatternSetup, RenderSpec, render};
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
    /// Side of the mock camera's square frames (px).
    pub camera_size_px: usize,
    /// Image noise of the mock camera (fraction of full scale).
    pub camera_noise_frac: f64,
}

impl Default for SimPcrOptions {
    fn default() -> Self {
        Self {
            stage_speed_mm_s: 200.0,
            stage_residual_nm: 2.0,
            stage_faults: Vec::new(),
            microscope_faults: Vec::new(),
            camera_size_px: 1024,
            camera_noise_frac: 0.01,
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
        with(&self.sim, |s| s.reading().map(|z| [z.x, z.y, z.theta]))
    }
}

impl Sim {
    /// The microscope's reading of the platform at the settled joints (solved from the
    /// previous equilibrium), with the twin's repeatability noise.
    fn reading(&mut self) -> Option<crate::geometry::Pose2> {
        let eq = match &self.last {
            Some(prev) => self
                .twin
                .truth
                .fk_from(prev, &self.q)
                .or_else(|_| self.twin.truth.fk(&self.q)),
            None => self.twin.truth.fk(&self.q),
        }
        .ok()?;
        let z = self.twin.read(&eq.pose, &mut self.noise);
        self.last = Some(eq);
        Some(z)
    }
}

/// The microscope's camera over the twin: the encoded pattern rendered at the reading the
/// pose server would send (the platform's true pose with the twin's repeatability), with
/// image noise of `noise_frac` of full scale.
struct TwinCamera {
    sim: Shared,
    setup: PatternSetup,
    size_px: usize,
    noise_frac: f64,
    frames: u64,
}

impl FrameModel for TwinCamera {
    fn image(&mut self, _exposure_us: f64) -> Result<Image, String> {
        let z = with(&self.sim, |s| s.reading())
            .ok_or_else(|| "the twin has no equilibrium at these joints".to_string())?;
        self.frames += 1;
        let img = render(&RenderSpec {
            kind: self.setup.kind,
            pose: PatternPose {
                x: z.x * 1e6,
                y: z.y * 1e6,
                theta_rad: z.theta,
            },
            period_um: self.setup.period_um,
            pixel_um: self.setup.pixel_um,
            width: self.size_px,
            height: self.size_px,
            bit_depth: 16,
            noise_frac: self.noise_frac,
            seed: self.frames ^ 0x00ca_3e2a,
        })
        .map_err(|e| e.to_string())?;
        Ok(Image {
            width: img.width as u32,
            height: img.height as u32,
            bit_depth: 16,
            pixels: img.pixels,
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
    let scope = PoseSourceLink::Server("127.0.0.1:0".into());
    let (link, mocks) = start_at(seed, o, "127.0.0.1:0", &scope).await?;
    Ok((CellLink::Pcr(link), mocks))
}

/// The 3-PF twin's nominal model file for `seed`: what a lab file must name for
/// `calibd mock lab` to serve it.
pub fn twin_model(seed: u64) -> Result<crate::model::pcr::PcrFile, LabError> {
    Ok(PcrTwin::nominal(seed)
        .map_err(|e| mock_err("pcr twin", e))?
        .file)
}

/// Start the simulated 3-PF cell's MCS2 stages at `stages_at` and its microscope as
/// `scope` says (a pose server, or a network camera, at the address given).
pub async fn start_at(
    seed: u64,
    o: &SimPcrOptions,
    stages_at: &str,
    scope: &PoseSourceLink,
) -> Result<(PcrCellLink, Vec<RunningMock>), LabError> {
    let twin = PcrTwin::nominal(seed).map_err(|e| mock_err("pcr twin", e))?;
    start_twin_at(twin, seed, o, stages_at, scope).await
}

/// Start the devices of a 3-PF cell around `twin` (a lab file's model with its truth drawn
/// around it) at `stages_at`, and the microscope as `scope` says: a `calibd-pose/1` server,
/// or a `calibd-frames/1` camera rendering the pattern (a folder camera is refused).
pub async fn start_twin_at(
    twin: PcrTwin,
    seed: u64,
    o: &SimPcrOptions,
    stages_at: &str,
    scope: &PoseSourceLink,
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
    let (microscope, scope_mock) = match scope {
        PoseSourceLink::Server(at) => {
            let model: Arc<Mutex<dyn PoseModel>> = Arc::new(Mutex::new(TwinMicroscope { sim }));
            let m = mock::start_with(
                at,
                calibd_drivers::microscope::mock::handler_with(
                    model,
                    Faults::new(o.microscope_faults.clone()),
                ),
            )
            .await
            .map_err(|e| mock_err("microscope", e))?;
            (PoseSourceLink::Server(m.addr.clone()), m)
        }
        PoseSourceLink::Camera(cam) => {
            let FrameSourceLink::Network(at) = &cam.source else {
                return Err(mock_err(
                    "camera",
                    "the simulated camera serves calibd-frames/1: set camera.source = \"network\"",
                ));
            };
            let model: Arc<Mutex<dyn FrameModel>> = Arc::new(Mutex::new(TwinCamera {
                sim,
                setup: cam.pattern,
                size_px: o.camera_size_px,
                noise_frac: o.camera_noise_frac,
                frames: 0,
            }));
            let m = mock::start_with(
                at,
                calibd_drivers::camera::mock::handler_with(
                    model,
                    Faults::new(o.microscope_faults.clone()),
                ),
            )
            .await
            .map_err(|e| mock_err("camera", e))?;
            let served = CameraLink {
                source: FrameSourceLink::Network(m.addr.clone()),
                ..cam.clone()
            };
            (PoseSourceLink::Camera(served), m)
        }
    };
    let link = PcrCellLink {
        resume: Default::default(),
        record: None,
        name: "pcr3pf".into(),
        stages: StagesLink {
            backend: StageBackend::Mcs2(stage_mock.addr.clone()),
            channels: [0, 1, 2],
            pm_per_count: 1000,
        },
        microscope,
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
