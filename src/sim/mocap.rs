//! The humanoid motion-capture cell: TALOS (its joint interface) in a Qualisys room. In the
//! simulated lab the TALOS twin ([`HumanoidTwin`], torso + left arm, constant waist) sits
//! behind an in-process joint robot (there is no TALOS protocol among the drivers) and behind
//! the QTM RT mock's marker model, which the QTM driver reads over the real protocol.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use calibd_drivers::mock::{self, Faults, MockArgs, MockDevice, RunningMock};
use calibd_drivers::qtm::mock::MarkerModel;

use super::with;
use crate::design::playback::quintic;
use crate::lab::{CellLink, JointsLink, LabError, MocapCellLink};
use crate::model::humanoid::BaseMode;
use crate::procedures::{DeviceError, DeviceFuture, JointRobot};
use crate::twin::humanoid::{HumanoidTwin, TALOS_URDF, left_arm_spec};

/// Settings of the simulated motion-capture cell.
#[derive(Debug, Clone)]
pub struct SimMocapOptions {
    /// Capture rate of the QTM mock (frames per second).
    pub rate_hz: f64,
    /// Largest joint speed of the simulated robot (rad/s); moves are quintic.
    pub joint_speed_rad_s: f64,
    /// The next this-many moves fail with a device fault (fault injection).
    pub failing_moves: Arc<std::sync::atomic::AtomicUsize>,
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

/// The twin's joint interface: quintic moves at a bounded joint speed, the current joints
/// published to the marker model every 5 ms.
struct SimJointRobot {
    room: Shared,
    names: Vec<String>,
    limits: Vec<[f64; 2]>,
    speed: f64,
    failing: Arc<std::sync::atomic::AtomicUsize>,
    moving: tokio::sync::Mutex<()>,
}

const ROBOT: &str = "talos.joints";

impl SimJointRobot {
    fn target(&self, posture: &[(String, f64)]) -> Result<Vec<f64>, DeviceError> {
        let mut q = with(&self.room, |r| r.q.clone());
        for (name, v) in posture {
            let refuse = |reason: String| DeviceError::Refused {
                device: ROBOT.into(),
                reason,
            };
            let k = self
                .names
                .iter()
                .position(|n| n == name)
                .ok_or_else(|| refuse(format!("no joint `{name}`")))?;
            let [lo, hi] = self.limits[k];
            if !(v.is_finite() && *v >= lo && *v <= hi) {
                return Err(refuse(format!(
                    "{name} = {v} rad is outside its limits [{lo}, {hi}]"
                )));
            }
            q[k] = *v;
        }
        Ok(q)
    }

    async fn play(&self, posture: &[(String, f64)]) -> Result<(), DeviceError> {
        let _guard = self.moving.lock().await;
        let target = self.target(posture)?;
        let taken = self
            .failing
            .fetch_update(
                std::sync::atomic::Ordering::SeqCst,
                std::sync::atomic::Ordering::SeqCst,
                |n| n.checked_sub(1),
            )
            .is_ok();
        if taken {
            return Err(DeviceError::Fault {
                device: ROBOT.into(),
                message: "joint controller fault (injected)".into(),
            });
        }
        let start = with(&self.room, |r| r.q.clone());
        let travel = start
            .iter()
            .zip(&target)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        // A quintic's peak speed is 15/8 of its mean speed.
        let duration = (1.875 * travel / self.speed).max(0.01);
        let t0 = tokio::time::Instant::now();
        loop {
            let t = t0.elapsed().as_secs_f64();
            let q = quintic(&start, &target, duration, t).0;
            with(&self.room, |r| r.q = q);
            if t >= duration {
                return Ok(());
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    }
}

impl JointRobot for SimJointRobot {
    fn joint_names(&self) -> Vec<String> {
        self.names.clone()
    }
    fn joints(&self) -> DeviceFuture<'_, Vec<f64>> {
        Box::pin(async move { Ok(with(&self.room, |r| r.q.clone())) })
    }
    fn move_to<'a>(&'a self, posture: &'a [(String, f64)]) -> DeviceFuture<'a, ()> {
        Box::pin(self.play(posture))
    }
}

fn mock_err(device: &str, e: impl std::fmt::Display) -> LabError {
    LabError::Mock {
        device: device.into(),
        message: e.to_string(),
    }
}

/// Start the simulated motion-capture cell: the TALOS twin (true errors from `seed`), its
/// joint interface, a QTM RT mock on a loopback port streaming the twin's markers, and a
/// QTM driver actor connected to it.
pub(super) async fn start(
    seed: u64,
    o: &SimMocapOptions,
) -> Result<(CellLink, RunningMock), LabError> {
    let mut spec = left_arm_spec(false);
    spec.base = BaseMode::Identify;
    let twin = HumanoidTwin::new(spec, seed).map_err(|e| mock_err("talos twin", e))?;
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
    let labels = markers.iter().map(|m| m.name.clone()).collect();
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
        labels,
    }));
    let qtm_mock = mock::start_with(
        "127.0.0.1:0",
        calibd_drivers::qtm::mock::handler_with(model, &args, Faults::default()),
    )
    .await
    .map_err(|e| mock_err("qtm", e))?;
    let robot = SimJointRobot {
        room,
        names: names.clone(),
        limits: limits.clone(),
        speed: o.joint_speed_rad_s,
        failing: o.failing_moves.clone(),
        moving: tokio::sync::Mutex::new(()),
    };
    let link = MocapCellLink {
        name: "talos".into(),
        joints: JointsLink {
            address: "in process".into(),
            speed_rad_s: o.joint_speed_rad_s,
            max_step_rad: 2.0 * std::f64::consts::PI,
        },
        in_process: Some(Arc::new(robot)),
        qtm: qtm_mock.addr.clone(),
        labels: Default::default(),
        urdf: TALOS_URDF.to_string(),
        root_link,
        joint_names: names,
        limits,
        markers,
    };
    Ok((CellLink::Mocap(link), qtm_mock))
}
