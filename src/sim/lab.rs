//! `calibd mock lab --config FILE`: the devices of a lab file's cells served from the
//! digital twins, at the addresses the file names (a symlink to a pseudo-terminal at each
//! serial port path), in a process of their own. A daemon pointed at the same file then
//! drives them over the real protocols exactly as it would drive the lab's instruments.
//!
//! Each cell's twin is built around what the lab file says: its nominal is the file's model
//! (DH file, 3-PF file, URDF with the cell's joints and markers), its truth is drawn around
//! that nominal from the seed, the ball plate has the file's ballbar distances, the
//! indicators report on the file's channels with its signs and zeros, and QTM streams the
//! markers under the file's labels; with the indicators' `request` template the receiver
//! answers requests and streams nothing. So the shipped example lab runs as written, and a
//! daemon pointed at the same file calibrates a robot it does not know exactly.

use std::path::Path;

use calibd_drivers::mock::RunningMock;

use super::trical::Served;
use super::{SimPcrOptions, SimTricalOptions};
use crate::lab::config::Environment;
use crate::lab::{
    BallCentringCell, CellLink, LabError, MocapCellLink, PcrCellLink, PoseSourceLink, StageBackend,
};

/// One served device, for the ready lines.
#[derive(Debug, Clone, PartialEq)]
pub struct ServedDevice {
    /// `<cell>.<device>`.
    pub device: String,
    /// Where it is served.
    pub address: String,
}

/// The mock lab: its running servers.
#[derive(Debug)]
pub struct MockLab {
    /// The devices served.
    pub devices: Vec<ServedDevice>,
    mocks: Vec<RunningMock>,
    /// The operator's hands on each ball-centring cell's device, by cell.
    hands: Vec<(String, super::trical::Hands)>,
}

/// The operator's actions `calibd mock lab` reads on its standard input, one a line.
pub const OPERATOR_COMMANDS: &str = "mate CELL | unmate CELL | set CELL";

impl MockLab {
    /// Do what the operator's line says to a ball-centring cell's device (`mate CELL`: on
    /// its coupling platform; `unmate CELL`: back on the flange; `set CELL`: press the
    /// indicators' set buttons); what was done, or why not.
    pub fn command(&self, line: &str) -> Result<String, String> {
        let mut words = line.split_whitespace();
        let (Some(verb), Some(cell), None) = (words.next(), words.next(), words.next()) else {
            return Err(format!("{line:?}: give {OPERATOR_COMMANDS}"));
        };
        let Some((_, hands)) = self.hands.iter().find(|(c, _)| c == cell) else {
            let have: Vec<&str> = self.hands.iter().map(|(c, _)| c.as_str()).collect();
            return Err(format!(
                "{cell}: no ball-centring cell of that name here (have: {})",
                have.join(", ")
            ));
        };
        match verb {
            "mate" => {
                hands.mate();
                Ok(format!("{cell}: device mated on its coupling"))
            }
            "unmate" => {
                hands.unmate();
                Ok(format!("{cell}: device back on the flange"))
            }
            "set" => {
                let shown = hands.set();
                Ok(format!(
                    "{cell}: set buttons pressed, indicators show {:.3} {:.3} {:.3} mm",
                    shown[0], shown[1], shown[2]
                ))
            }
            other => Err(format!("{other:?}: give {OPERATOR_COMMANDS}")),
        }
    }

    /// Stop every server.
    pub async fn stop(self) {
        for m in self.mocks {
            m.stop().await;
        }
    }
}

fn refuse(cell: &str, message: String) -> LabError {
    LabError::Cell {
        cell: cell.into(),
        message,
    }
}

/// A fixed `host:port` (a mock lab serves where the file says; port 0 would leave the
/// daemon not knowing where).
fn fixed(cell: &str, key: &str, a: &str) -> Result<String, LabError> {
    if a.ends_with(":0") {
        return Err(refuse(
            cell,
            format!("{key} = {a}: give a fixed port to serve on"),
        ));
    }
    Ok(a.to_string())
}

/// Serve the cells of the lab file at `path` named in `only` (all when empty), from the
/// twins of `seed`.
pub async fn serve(
    path: &Path,
    only: &[String],
    seed: u64,
    env: &dyn Environment,
) -> Result<MockLab, LabError> {
    let cells = crate::lab::config::load(path, env)?;
    let name = |c: &CellLink| match c {
        CellLink::BallCentring(c) => c.name.clone(),
        CellLink::Pcr(c) => c.name.clone(),
        CellLink::Mocap(c) => c.name.clone(),
    };
    for o in only {
        if !cells.iter().any(|c| &name(c) == o) {
            return Err(refuse(o, format!("not in {}", path.display())));
        }
    }
    let mut lab = MockLab {
        devices: Vec::new(),
        mocks: Vec::new(),
        hands: Vec::new(),
    };
    for c in cells
        .iter()
        .filter(|c| only.is_empty() || only.contains(&name(c)))
    {
        let r = match c {
            CellLink::BallCentring(d) => trical(d, seed).await.map(|(dv, m, h)| {
                lab.hands.push((d.name.clone(), h));
                (dv, m)
            }),
            CellLink::Pcr(d) => pcr(d, seed).await,
            CellLink::Mocap(d) => mocap(d, seed).await,
        };
        match r {
            Ok((devices, mocks)) => {
                lab.devices.extend(devices);
                lab.mocks.extend(mocks);
            }
            Err(e) => {
                lab.stop().await;
                return Err(e);
            }
        }
    }
    Ok(lab)
}

async fn trical(
    d: &BallCentringCell,
    seed: u64,
) -> Result<(Vec<ServedDevice>, Vec<RunningMock>, super::trical::Hands), LabError> {
    // The twin's nominal is the lab file's model, its plate the file's ballbar; its
    // truth is drawn around them.
    let twin = crate::twin::SerialTwin::around(d.model.clone(), d.ballbar, seed)
        .map_err(|e| refuse(&d.name, format!("no twin around the lab file's cell: {e}")))?;
    let at = Served {
        rws: fixed(&d.name, "controller.address", &d.rws.address)?,
        uwave: Some(d.uwave.path.clone().into()),
        user: d.rws.user.clone(),
        password: d.rws.password.clone(),
    };
    // A lab file that requests readings gets a receiver that answers requests and streams
    // nothing (a recorded session then replays exactly; see docs/lab.md, recording).
    let requested = !d.uwave.request_template.is_empty();
    let o = SimTricalOptions {
        max_joint_step_deg: d.max_joint_step_deg,
        uwave_request: d.uwave.request_template.clone(),
        indicator_rate_hz: if requested {
            0.0
        } else {
            SimTricalOptions::default().indicator_rate_hz
        },
        ..SimTricalOptions::default()
    };
    let (link, mocks) = super::trical::start_twin_at(twin, seed, &o, &at, d.uwave.axes).await?;
    let hands = o
        .hands
        .get()
        .cloned()
        .ok_or_else(|| refuse(&d.name, "the simulated device's bench did not start".into()))?;
    Ok((
        vec![
            ServedDevice {
                device: format!("{}.rws", d.name),
                address: link.rws.address,
            },
            ServedDevice {
                device: format!("{}.uwave", d.name),
                address: link.uwave.path,
            },
        ],
        mocks,
        hands,
    ))
}

async fn pcr(
    d: &PcrCellLink,
    seed: u64,
) -> Result<(Vec<ServedDevice>, Vec<RunningMock>), LabError> {
    let twin = crate::twin::PcrTwin::new(&d.model, seed)
        .map_err(|e| refuse(&d.name, format!("no twin around the lab file's model: {e}")))?;
    let StageBackend::Mcs2(stages_at) = &d.stages.backend else {
        return Err(refuse(
            &d.name,
            "the twin's stages are an MCS2: set stages.controller = \"mcs2\"".into(),
        ));
    };
    if d.stages.channels != [0, 1, 2] {
        return Err(refuse(
            &d.name,
            "the twin's MCS2 drives q1..q3 on channels [0, 1, 2]".into(),
        ));
    }
    let stages_at = fixed(&d.name, "stages.address", stages_at)?;
    let key = match &d.microscope {
        PoseSourceLink::Server(_) => "microscope.address",
        PoseSourceLink::Camera(_) => "camera.address",
    };
    fixed(&d.name, key, &d.microscope.address())?;
    let (link, mocks) = super::pcr::start_twin_at(
        twin,
        seed,
        &SimPcrOptions::default(),
        &stages_at,
        &d.microscope,
    )
    .await?;
    Ok((
        vec![
            ServedDevice {
                device: format!("{}.stages", d.name),
                address: link.stages.backend.address(),
            },
            ServedDevice {
                device: format!("{}.microscope", d.name),
                address: link.microscope.address(),
            },
        ],
        mocks,
    ))
}

async fn mocap(
    d: &MocapCellLink,
    seed: u64,
) -> Result<(Vec<ServedDevice>, Vec<RunningMock>), LabError> {
    let twin = super::mocap::twin_around(&d.urdf, &d.root_link, &d.joint_names, &d.markers, seed)
        .map_err(|e| refuse(&d.name, format!("no twin around the lab file's cell: {e}")))?;
    let qtm_at = fixed(&d.name, "mocap.address", &d.qtm)?;
    let joints_at = fixed(&d.name, "joints.address", &d.joints.address)?;
    let o = super::SimMocapOptions {
        joint_speed_rad_s: d.joints.speed_rad_s,
        ..super::SimMocapOptions::default()
    };
    let (link, mocks) =
        super::mocap::start_twin_at(twin, &d.urdf, &d.labels, seed, &o, &qtm_at, &joints_at)
            .await?;
    Ok((
        vec![
            ServedDevice {
                device: format!("{}.joints", d.name),
                address: link.joints.address,
            },
            ServedDevice {
                device: format!("{}.qtm", d.name),
                address: link.qtm,
            },
        ],
        mocks,
    ))
}
