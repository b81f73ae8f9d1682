//! How each kind of device is asked who it is, for [`super::devices::DeviceLink`]: the
//! driver's typed `identity()` (read-only queries), turned into the check's summary and
//! details; problems the identity names (a RAPID module not loaded, an unreferenced
//! stage, a transmitter without readings, ...) fail the check with their fix.

use std::future::Future;
use std::sync::Arc;

use calibd_drivers::DriverError;
use calibd_drivers::can::Cia402Handle;
use calibd_drivers::identity::Identity as DriverIdentity;
use calibd_drivers::joints::JointsHandle;
use calibd_drivers::microscope::MicroscopeHandle;
use calibd_drivers::qtm::QtmHandle;
use calibd_drivers::rws::RwsHandle;
use calibd_drivers::smaract::{Mcs2Handle, McsHandle};
use calibd_drivers::uwave::UwaveHandle;

use super::devices::{Identity, ProbeError, ProbeFuture};

/// A probe closure over a cloneable handle and the async function that asks it.
pub fn probe<H, F, Fut>(h: H, f: F) -> impl Fn() -> ProbeFuture + Send + Sync + 'static
where
    H: Clone + Send + Sync + 'static,
    F: Fn(H) -> Fut + Send + Sync + 'static,
    Fut: Future<Output = Result<Identity, ProbeError>> + Send + 'static,
{
    move || Box::pin(f(h.clone()))
}

/// The check of a typed identity: its problems fail it (each names its fix).
fn checked<I: DriverIdentity>(r: Result<I, DriverError>) -> Result<Identity, ProbeError> {
    let d = r
        .map_err(|e| ProbeError::from(e.to_string()))?
        .device_identity();
    if d.problems.is_empty() {
        Ok(Identity {
            summary: d.summary,
            details: d.details,
            fingerprint: d.fingerprint,
        })
    } else {
        Err(ProbeError {
            error: format!("{} — but: {}", d.summary, d.problems.join("; ")),
            fix: Some(d.problems.join("; ")),
        })
    }
}

/// The IRC5: controller, RobotWare, the calib RAPID module, state.
pub async fn rws(h: RwsHandle, module: String) -> Result<Identity, ProbeError> {
    checked(h.identity(&module).await)
}

/// The U-WAVE-R receiver: a fresh reading of each of the cell's channels, then its id,
/// transmitters and those readings.
pub async fn uwave(h: UwaveHandle, channels: [u8; 3]) -> Result<Identity, ProbeError> {
    for c in channels {
        h.fresh(c).await.map_err(|e| {
            let error = format!("channel {c}: {e}");
            // A receiver that cannot be opened has its own fix (derived from the error).
            let fix = (!matches!(e, DriverError::Unreachable { .. })).then(|| {
                format!("no reading from channel {c}: check its U-WAVE-T is paired and on (press DATA, or set it to event mode)")
            });
            ProbeError { error, fix }
        })?;
    }
    checked(h.identity().await)
}

/// An MCS2: serial number, channels, referencing and positions of the cell's channels.
pub async fn mcs2(h: Arc<Mcs2Handle>, channels: [u8; 3]) -> Result<Identity, ProbeError> {
    checked(h.identity(&channels).await)
}

/// An MCS: system id, channels, referencing and positions of the cell's channels.
pub async fn mcs(h: Arc<McsHandle>, channels: [u8; 3]) -> Result<Identity, ProbeError> {
    checked(h.identity(&channels).await)
}

/// Three CiA 402 drives: each one's identity object and power state.
pub async fn cia402(drives: Arc<[Cia402Handle; 3]>) -> Result<Identity, ProbeError> {
    let mut summary = Vec::new();
    let mut details = Vec::new();
    let mut fingerprint = Vec::new();
    for d in drives.iter() {
        let i = checked(d.identity().await)?;
        summary.push(i.summary);
        details.push(i.details);
        fingerprint.push(i.fingerprint);
    }
    Ok(Identity {
        summary: summary.join("; "),
        details: serde_json::Value::Array(details),
        fingerprint: fingerprint.join("; "),
    })
}

/// The microscope: its identification and one fresh pose.
pub async fn microscope(h: MicroscopeHandle) -> Result<Identity, ProbeError> {
    checked(h.identity().await)
}

/// A network camera: its identification and one fresh frame's size.
pub async fn camera(h: calibd_drivers::camera::CameraHandle) -> Result<Identity, ProbeError> {
    checked(h.identity().await)
}

/// A frame folder: that it can be read, how many frames it holds and the latest.
pub async fn camera_folder(
    f: Arc<calibd_drivers::camera::FolderCamera>,
) -> Result<Identity, ProbeError> {
    let frames = f.frames().map_err(|e| ProbeError {
        error: format!("{}: {e}", f.dir().display()),
        fix: Some(format!(
            "create {} and point the camera's acquisition at it (numbered PNG or TIFF frames)",
            f.dir().display()
        )),
    })?;
    let latest = frames.last().map(|(n, p)| (*n, p.display().to_string()));
    Ok(Identity {
        summary: match &latest {
            Some((n, _)) => format!("{} frames, latest number {n}", frames.len()),
            None => "no frames yet (each pose waits for the next one written)".into(),
        },
        details: serde_json::json!({
            "folder": f.dir().display().to_string(),
            "frames": frames.len(),
            "latest": latest.map(|(n, p)| serde_json::json!({"number": n, "file": p})),
        }),
        // The folder is the unit: the same folder readable again is the same camera source.
        fingerprint: format!("frame folder {}", f.dir().display()),
    })
}

/// The markers a motion-capture cell measures: QTM label -> model marker (labels not listed
/// keep their name) and the model's marker names.
#[derive(Debug, Clone, PartialEq)]
pub struct CellMarkers {
    /// QTM label -> model marker name.
    pub labels: std::collections::BTreeMap<String, String>,
    /// The cell's markers (model names).
    pub markers: Vec<String>,
}

impl CellMarkers {
    /// The cell's markers that none of the stream's `labels` maps to.
    pub fn missing(&self, stream: &[String]) -> Vec<String> {
        let seen: std::collections::BTreeSet<&str> = stream
            .iter()
            .map(|l| self.labels.get(l).unwrap_or(l).as_str())
            .collect();
        self.markers
            .iter()
            .filter(|m| !seen.contains(m.as_str()))
            .cloned()
            .collect()
    }
}

/// QTM: versions, capture frequency and the labelled markers, which must include every
/// marker of the cell.
pub async fn qtm(h: QtmHandle, cell: Arc<CellMarkers>) -> Result<Identity, ProbeError> {
    let id = h
        .identity()
        .await
        .map_err(|e| ProbeError::from(e.to_string()))?;
    let missing = cell.missing(&id.labels);
    let i = checked::<calibd_drivers::qtm::QtmIdentity>(Ok(id))?;
    if !missing.is_empty() {
        return Err(ProbeError {
            error: format!(
                "{} — but {} of the cell's {} markers are not in the stream: {}",
                i.summary,
                missing.len(),
                cell.markers.len(),
                missing.join(", ")
            ),
            fix: Some(
                "label those markers in QTM (AIM model or manual labels), or map their QTM labels to them in the lab file's [cell.mocap] labels".into(),
            ),
        });
    }
    Ok(Identity {
        summary: format!(
            "{}; all {} cell markers labelled",
            i.summary,
            cell.markers.len()
        ),
        details: i.details,
        fingerprint: i.fingerprint,
    })
}

/// The humanoid's joint interface: the robot, its joints and their limits, which must
/// contain the cell's envelope (`want`: joint names and [lower, upper] in rad).
pub async fn joints(
    h: JointsHandle,
    want: Arc<(Vec<String>, Vec<[f64; 2]>)>,
) -> Result<Identity, ProbeError> {
    let (want, envelope) = (&want.0, &want.1);
    let id = h
        .hello()
        .await
        .map_err(|e| ProbeError::from(e.to_string()))?;
    let missing: Vec<&String> = want.iter().filter(|j| !id.joints.contains(j)).collect();
    let details = serde_json::to_value(&id).unwrap_or_default();
    if !missing.is_empty() {
        return Err(ProbeError {
            error: format!("{} does not drive {missing:?}", id.robot),
            fix: Some(
                "name the bridge's joints (--joints, --controller) as the lab file's joints.names"
                    .into(),
            ),
        });
    }
    let wider = beyond_interface(&id, want, envelope);
    if !wider.is_empty() {
        return Err(ProbeError {
            error: format!(
                "{}: the cell's envelope reaches beyond the interface's limits: {}",
                id.robot,
                wider.join("; ")
            ),
            fix: Some(
                "narrow the lab file's [cell.envelope] joint_limits_deg (or the URDF's limits) to the robot's, or correct the bridge's limits".into(),
            ),
        });
    }
    Ok(Identity {
        summary: format!(
            "{} ({}), {} joints; the cell's limits within the interface's",
            id.robot,
            id.protocol,
            id.joints.len()
        ),
        details,
        fingerprint: format!(
            "{} ({}), joints {}",
            id.robot,
            id.protocol,
            id.joints.join(" ")
        ),
    })
}

/// The cell's joints whose envelope [lower, upper] (rad) is not inside the interface's
/// limits (1e-9 rad of rounding allowed), each with both ranges in degrees.
fn beyond_interface(
    id: &calibd_drivers::joints::Identity,
    names: &[String],
    envelope: &[[f64; 2]],
) -> Vec<String> {
    names
        .iter()
        .zip(envelope)
        .filter_map(|(n, e)| {
            let k = id.joints.iter().position(|j| j == n)?;
            let r = id.limits_rad.get(k)?;
            (e[0] < r[0] - 1e-9 || e[1] > r[1] + 1e-9).then(|| {
                format!(
                    "{n}: envelope [{:.2}, {:.2}] deg, interface [{:.2}, {:.2}] deg",
                    e[0].to_degrees(),
                    e[1].to_degrees(),
                    r[0].to_degrees(),
                    r[1].to_degrees()
                )
            })
        })
        .collect()
}
