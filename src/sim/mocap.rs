//! The humanoid motion-capture cell: TALOS (its joint interface) in a Qualisys room. In the
//! simulated lab the TALOS twin ([`HumanoidTwin`], torso + left arm, constant waist) sits
//! behind the joint-interface mock's joint model (`calibd-joints/1`) and behind the QTM RT
//! mock's marker model; the lab's joint and QTM drivers reach both over the real protocols.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use calibd_drivers::joints::mock::JointModel;
use calibd_drivers::mock::{self, Faults, MockArgs, MockDevice, RunningMock};
use calibd_drivers::qtm::mock::MarkerModel;

use super::with;
use crate::design::playback::quintic;
use crate::lab::{CellLink, JointsLink, LabError, MocapCellLink};
use crate::model::humanoid::BaseMode;
use crate::twin::humanoid::{HumanoidTwin, TALOS_URDF, left_arm_spec};

/// Settings of the simulated motion-capture cell.
#[derive(Debug, Clone)]
pub struct SimMocapOptions {
    /// Capture rate of the QTM mock (frames per second).
    pub rate_hz: f64,
    /// Joint speed the lab asks of the robot (rad/s): a move lasts its largest joint change
    /// over this speed; the twin follows a quintic over that time.
    pub joint_speed_rad_s: f64,
    /// The next this-many moves fail with a controller fault (fault injection).
    pub failing_moves: Arc<AtomicUsize>,
}

impl Default for SimMocapOptions {
    fn default() -> Self {
        Self {
            rate_hz: 100.0,
            joint_speed_rad_s: 2.0,
            failing_moves: Arc::default(),
        }
    }
}

/// The twin and where its joints are now.
struct Room {
    twin: HumanoidTwin,
    q: Vec<f64>,
    seed: u64,
    frames: u64,
}

type Shared = super::Shared<Room>;

/// The twin's markers as the cameras see them: the true robot at its current joints, with
/// the twin's mocap noise (each frame its own seeded draw), in mm.
struct TwinMarkers {
    room: Shared,
    labels: Vec<String>,
}

impl MarkerModel for TwinMarkers {
    fn labels(&self) -> Vec<String> {
        self.labels.clone()
    }
    fn sample(&mut self, _t_s: f64, out: &mut Vec<[f32; 3]>) {
        out.clear();
        let s = with(&self.room, |r| {
            r.frames += 1;
            r.twin
                .samples(std::slice::from_ref(&r.q), r.seed.wrapping_add(r.frames))
        });
        for p in s.iter().flat_map(|s| s.points.iter()) {
            out.push(match p {
                Some(p) => [(p.x * 1e3) as f32, (p.y * 1e3) as f32, (p.z * 1e3) as f32],
                None => [f32::NAN; 3],
            });
        }
    }
}

/// The twin's joints as the joint-interface mock's robot: quintic moves over the duration
/// the driver asks for, the current joints shared with the marker model (the mock updates
/// them every few ms while a move runs); the next `failing` moves fail with a controller
/// fault (fault injection).
struct TwinJoints {
    room: Shared,
    names: Vec<String>,
    limits: Vec<[f64; 2]>,
    failing: Arc<AtomicUsize>,
}

impl JointModel for TwinJoints {
    fn robot(&self) -> String {
        "talos (digital twin)".into()
    }
    fn names(&self) -> Vec<String> {
        self.names.clone()
    }
    fn limits(&self) -> Vec<[f64; 2]> {
        self.limits.clone()
    }
    fn positions(&mut self) -> Vec<f64> {
        with(&self.room, |r| r.q.clone())
    }
    fn set_positions(&mut self, q: &[f64]) {
        with(&self.room, |r| r.q = q.to_vec());
    }
    fn begin_move(&mut self, _target: &[f64], _duration_s: f64) -> Result<(), String> {
        let taken = self
            .failing
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| n.checked_sub(1))
            .is_ok();
        if taken {
            return Err("joint controller fault (injected)".into());
        }
        Ok(())
    }
    fn profile(&self, start: &[f64], target: &[f64], duration_s: f64, t_s: f64) -> Vec<f64> {
        quintic(start, target, duration_s, t_s).0
    }
}

fn mock_err(device: &str, e: impl std::fmt::Display) -> LabError {
    LabError::Mock {
        device: device.into(),
        message: e.to_string(),
    }
}

/// Start the simulated motion-capture cell: the TALOS twin (true errors from `seed`), a
/// joint-interface mock moving its joints and a QTM RT mock streaming its markers, both on
/// loopback ports; the cell's description names their addresses.
pub(super) async fn start(
    seed: u64,
    o: &SimMocapOptions,
) -> Result<(CellLink, Vec<RunningMock>), LabError> {
    let (link, mocks) = start_at(seed, o, "127.0.0.1:0", "127.0.0.1:0").await?;
    Ok((CellLink::Mocap(link), mocks))
}

/// The TALOS twin's left-arm cell for `seed`: root link, measured joints (in order) and
/// markers, what a lab file must name for `calibd mock lab` to serve it (the URDF is
/// [`TALOS_URDF`]).
pub fn twin_cell(
    seed: u64,
) -> Result<(String, Vec<String>, Vec<crate::model::humanoid::MarkerDef>), LabError> {
    let twin = twin(seed)?;
    Ok((
        twin.spec.root.clone(),
        twin.nominal.variables.clone(),
        twin.spec.markers.clone(),
    ))
}

fn twin(seed: u64) -> Result<HumanoidTwin, LabError> {
    let mut spec = left_arm_spec(false);
    spec.base = BaseMode::Identify;
    HumanoidTwin::new(spec, seed).map_err(|e| mock_err("talos twin", e))
}

/// Start the simulated motion-capture cell's QTM server at `qtm_at` and joint interface at
/// `joints_at`.
pub async fn start_at(
    seed: u64,
    o: &SimMocapOptions,
    qtm_at: &str,
    joints_at: &str,
) -> Result<(MocapCellLink, Vec<RunningMock>), LabError> {
    start_twin_at(
        twin(seed)?,
        TALOS_URDF,
        &BTreeMap::new(),
        seed,
        o,
        qtm_at,
        joints_at,
    )
    .await
}

/// A twin around a lab file's humanoid cell: its URDF, root link, joints and markers (the
/// markers' guessed positions as nominal), true errors from `seed`.
pub fn twin_around(
    urdf: &str,
    root: &str,
    joints: &[String],
    markers: &[crate::model::humanoid::MarkerDef],
    seed: u64,
) -> Result<HumanoidTwin, LabError> {
    let mut spec = left_arm_spec(false);
    spec.base = BaseMode::Identify;
    spec.root = root.into();
    spec.joints = joints.to_vec();
    spec.markers = markers.to_vec();
    HumanoidTwin::with_urdf(urdf, spec, seed).map_err(|e| mock_err("humanoid twin", e))
}

/// Start the devices of a motion-capture cell around `twin` (whose robot `urdf` describes):
/// QTM at `qtm_at` streams each marker under its QTM label (`labels` maps QTM label to
/// model marker, as a lab file does; unmapped markers keep their name), the joint interface
/// at `joints_at` moves the twin.
pub async fn start_twin_at(
    twin: HumanoidTwin,
    urdf: &str,
    labels: &BTreeMap<String, String>,
    seed: u64,
    o: &SimMocapOptions,
    qtm_at: &str,
    joints_at: &str,
) -> Result<(MocapCellLink, Vec<RunningMock>), LabError> {
    let names = twin.nominal.variables.clone();
    let limits: Vec<[f64; 2]> = twin
        .nominal
        .limits()
        .iter()
        .map(|l| l.unwrap_or([-std::f64::consts::PI, std::f64::consts::PI]))
        .collect();
    let home: Vec<f64> = limits.iter().map(|[lo, hi]| lo.max(0.0).min(*hi)).collect();
    let markers = twin.spec.markers.clone();
    let root_link = twin.spec.root.clone();
    let streamed = markers
        .iter()
        .map(|m| {
            labels
                .iter()
                .find(|(_, marker)| **marker == m.name)
                .map_or_else(|| m.name.clone(), |(label, _)| label.clone())
        })
        .collect();
    let room: Shared = Arc::new(Mutex::new(Room {
        twin,
        q: home,
        seed: seed ^ 0x0c0ffee,
        frames: 0,
    }));
    let mut args = MockArgs::new(MockDevice::Qtm);
    args.rate_hz = o.rate_hz;
    let model: Arc<Mutex<dyn MarkerModel>> = Arc::new(Mutex::new(TwinMarkers {
        room: room.clone(),
        labels: streamed,
    }));
    let qtm_mock = mock::start_with(
        qtm_at,
        calibd_drivers::qtm::mock::handler_with(model, &args, Faults::default()),
    )
    .await
    .map_err(|e| mock_err("qtm", e))?;
    let joints: Arc<Mutex<dyn JointModel>> = Arc::new(Mutex::new(TwinJoints {
        room,
        names: names.clone(),
        limits: limits.clone(),
        failing: o.failing_moves.clone(),
    }));
    let joints_mock = match mock::start_with(
        joints_at,
        calibd_drivers::joints::mock::handler_with(joints, Faults::default()),
    )
    .await
    {
        Ok(m) => m,
        Err(e) => {
            qtm_mock.stop().await;
            return Err(mock_err("joints", e));
        }
    };
    let link = MocapCellLink {
        resume: Default::default(),
        record: None,
        name: "talos".into(),
        joints: JointsLink {
            address: joints_mock.addr.clone(),
            speed_rad_s: o.joint_speed_rad_s,
            max_step_rad: 2.0 * std::f64::consts::PI,
        },
        qtm: qtm_mock.addr.clone(),
        labels: labels.clone(),
        urdf: urdf.to_string(),
        root_link,
        joint_names: names,
        limits,
        markers,
    };
    Ok((link, vec![joints_mock, qtm_mock]))
}
