//! The 3-PF cell's driver actors behind the procedure traits: SmarAct stages (any
//! [`Stage`] backend, positions in pm) as [`LinearStages`] in metres, the microscope's
//! `calibd-pose/1` driver as a [`PoseSensor`].

use std::sync::Arc;

use calibd_drivers::Stage;
use calibd_drivers::microscope::MicroscopeHandle;

use super::serial::device_error;
use crate::procedures::{DeviceError, DeviceFuture, LinearStages, PoseSensor};

/// Picometres per metre.
const PM_PER_M: f64 = 1e12;

/// Three channels of one stage controller as the robot's joints q1..q3.
pub struct SmaractStages {
    stage: Arc<dyn Stage>,
    channels: [u8; 3],
    name: String,
}

impl std::fmt::Debug for SmaractStages {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SmaractStages")
            .field("name", &self.name)
            .field("channels", &self.channels)
            .finish()
    }
}

impl SmaractStages {
    /// Joint k is channel `channels[k]` of `stage`; `name` is the device name in errors.
    pub fn new(stage: Arc<dyn Stage>, channels: [u8; 3], name: impl Into<String>) -> Self {
        Self {
            stage,
            channels,
            name: name.into(),
        }
    }
}

fn to_pm(device: &str, q: f64) -> Result<i64, DeviceError> {
    let v = q * PM_PER_M;
    if !(v.is_finite() && v.abs() < 9e18) {
        return Err(DeviceError::Refused {
            device: device.into(),
            reason: format!("position {q} m is not a finite stage position"),
        });
    }
    Ok(v.round() as i64)
}

impl LinearStages for SmaractStages {
    fn move_to<'a>(&'a self, q: &'a [f64; 3]) -> DeviceFuture<'a, [f64; 3]> {
        Box::pin(async move {
            let t: [i64; 3] = [
                to_pm(&self.name, q[0])?,
                to_pm(&self.name, q[1])?,
                to_pm(&self.name, q[2])?,
            ];
            let c = self.channels;
            // The three moves run together; each returns once its channel stopped.
            let (a, b, d) = tokio::join!(
                self.stage.move_absolute(c[0], t[0]),
                self.stage.move_absolute(c[1], t[1]),
                self.stage.move_absolute(c[2], t[2]),
            );
            let err = |e| device_error(&self.name, e);
            Ok([
                a.map_err(err)? as f64 / PM_PER_M,
                b.map_err(err)? as f64 / PM_PER_M,
                d.map_err(err)? as f64 / PM_PER_M,
            ])
        })
    }

    fn positions(&self) -> DeviceFuture<'_, [f64; 3]> {
        Box::pin(async move {
            let mut out = [0.0; 3];
            for (o, &c) in out.iter_mut().zip(&self.channels) {
                let p = self
                    .stage
                    .position(c)
                    .await
                    .map_err(|e| device_error(&self.name, e))?;
                *o = p as f64 / PM_PER_M;
            }
            Ok(out)
        })
    }
}

named_adapter!(
    /// The microscope over `calibd-pose/1`.
    Microscope,
    MicroscopeHandle
);

impl PoseSensor for Microscope {
    fn read_pose(&self) -> DeviceFuture<'_, [f64; 3]> {
        Box::pin(async move {
            let p = self
                .handle
                .pose()
                .await
                .map_err(|e| device_error(&self.name, e))?;
            Ok([p.x_m, p.y_m, p.theta_rad])
        })
    }
}
