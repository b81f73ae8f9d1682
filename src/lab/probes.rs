//! How each kind of device is asked who it is, for [`super::devices::DeviceLink`]: one
//! read-only exchange or two through the device's driver handle, summarised in one line
//! with the details kept as JSON.

use std::future::Future;
use std::sync::Arc;

use calibd_drivers::Stage;
use calibd_drivers::microscope::MicroscopeHandle;
use calibd_drivers::qtm::QtmHandle;
use calibd_drivers::rws::RwsHandle;
use calibd_drivers::uwave::{AxisMap, UwaveHandle};
use serde_json::json;

use super::devices::{Identity, ProbeFuture};
use crate::procedures::JointRobot;

/// A probe closure over a cloneable handle and the async function that asks it.
pub fn probe<H, F, Fut>(h: H, f: F) -> impl Fn() -> ProbeFuture + Send + Sync + 'static
where
    H: Clone + Send + Sync + 'static,
    F: Fn(H) -> Fut + Send + Sync + 'static,
    Fut: Future<Output = Result<Identity, String>> + Send + 'static,
{
    move || Box::pin(f(h.clone()))
}

fn text(e: impl std::fmt::Display) -> String {
    e.to_string()
}

/// The IRC5: controller state, operating mode, RAPID execution and the joints.
pub async fn rws(h: RwsHandle) -> Result<Identity, String> {
    let s = h.controller_state().await.map_err(text)?;
    let q = h.joints_deg().await.map_err(text)?;
    Ok(Identity {
        summary: format!(
            "motors {}, mode {}, RAPID {}; joints [{}] deg",
            s.ctrlstate,
            s.opmode,
            s.execstate,
            q.map(|v| format!("{v:.2}")).join(", ")
        ),
        details: json!({
            "ctrlstate": s.ctrlstate, "opmode": s.opmode, "execstate": s.execstate,
            "joints_deg": q,
        }),
    })
}

/// The U-WAVE-R receiver: its transmitters and a fresh reading of each configured axis.
pub async fn uwave(h: UwaveHandle, axes: [AxisMap; 3]) -> Result<Identity, String> {
    let t = h.transmitters().await.map_err(text)?;
    let mut readings = Vec::new();
    for a in axes {
        let r = h.fresh(a.channel).await.map_err(text)?;
        readings.push(r.value_mm());
    }
    Ok(Identity {
        summary: format!(
            "{} transmitters; channels {}, {}, {} read [{}] mm",
            t.len(),
            axes[0].channel,
            axes[1].channel,
            axes[2].channel,
            readings
                .iter()
                .map(|v| format!("{v:.4}"))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        details: json!({"transmitters": t.len(), "readings_mm": readings}),
    })
}

/// The stage controller: position and referencing of each joint's channel.
pub async fn stages(h: Arc<dyn Stage>, channels: [u8; 3]) -> Result<Identity, String> {
    let mut pos_m = Vec::new();
    let mut referenced = Vec::new();
    for c in channels {
        pos_m.push(h.position(c).await.map_err(text)? as f64 * 1e-12);
        referenced.push(h.status(c).await.map_err(text)?.referenced);
    }
    Ok(Identity {
        summary: format!(
            "channels {channels:?}: referenced {referenced:?}, at [{}] mm",
            pos_m
                .iter()
                .map(|v| format!("{:.4}", v * 1e3))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        details: json!({"channels": channels, "referenced": referenced, "positions_m": pos_m}),
    })
}

/// The microscope: its identification and one fresh pose.
pub async fn microscope(h: MicroscopeHandle) -> Result<Identity, String> {
    let id = h.id().await.map_err(text)?;
    let p = h.pose().await.map_err(text)?;
    Ok(Identity {
        summary: format!(
            "{id}; pose x {:.6} mm, y {:.6} mm, theta {:.5} deg",
            p.x_m * 1e3,
            p.y_m * 1e3,
            p.theta_rad.to_degrees()
        ),
        details: json!({"id": id, "x_m": p.x_m, "y_m": p.y_m, "theta_rad": p.theta_rad}),
    })
}

/// QTM: server version and the labelled 3-D markers.
pub async fn qtm(h: QtmHandle) -> Result<Identity, String> {
    let version = h.command("Version").await.map_err(text)?;
    let s = h.parameters_3d().await.map_err(text)?;
    Ok(Identity {
        summary: format!("{version}; {} labelled markers", s.labels.len()),
        details: json!({"version": version, "labels": s.labels}),
    })
}

/// The humanoid's joint interface: its joints and where they are.
pub async fn joints(h: Arc<dyn JointRobot>) -> Result<Identity, String> {
    let names = h.joint_names();
    let q = h.joints().await.map_err(text)?;
    Ok(Identity {
        summary: format!(
            "{} joints ({} ...)",
            names.len(),
            names.first().map_or("", |s| s)
        ),
        details: json!({"joints": names, "positions_rad": q}),
    })
}
