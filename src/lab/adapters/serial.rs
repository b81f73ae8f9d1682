//! The driver actors behind the procedure traits: an RWS controller as a [`Robot`], a
//! U-WAVE receiver as [`Indicators`], with driver errors mapped onto [`DeviceError`].

use std::sync::atomic::{AtomicBool, Ordering};

use calibd_drivers::DriverError;
use calibd_drivers::rws::RwsHandle;
use calibd_drivers::uwave::UwaveHandle;

use crate::procedures::{DeviceError, DeviceFuture, Indicators, ModuleLoader, Robot};

/// A driver error as the procedures see it: link trouble, timeouts, the device's own
/// errors, local refusals and garbled replies are told apart.
pub fn device_error(device: &str, e: DriverError) -> DeviceError {
    let device = device.to_string();
    match e {
        DriverError::Timeout { after_ms, .. } => DeviceError::Timeout {
            device,
            timeout_ms: after_ms,
        },
        DriverError::Device { code, message, .. } => DeviceError::Fault {
            device,
            message: format!("error {code}: {message}"),
        },
        DriverError::Safety { reason, .. } => DeviceError::Refused { device, reason },
        DriverError::InvalidRequest { detail, .. } => DeviceError::Refused {
            device,
            reason: detail,
        },
        DriverError::Protocol { detail, .. } => DeviceError::Protocol {
            device,
            message: detail,
        },
        DriverError::Stale { .. } => DeviceError::Protocol {
            device,
            message: e.to_string(),
        },
        _ => DeviceError::Disconnected { device },
    }
}

/// An RWS driver error as the procedures see it. The calib server's `calib_err = 2` (target
/// unreachable or outside the robot's limits) is the controller refusing one target, not a
/// faulty link: a campaign skips that configuration instead of pausing on it.
pub fn rws_error(device: &str, e: DriverError) -> DeviceError {
    match e {
        DriverError::Device {
            code: 2, message, ..
        } => DeviceError::Refused {
            device: device.into(),
            reason: format!("the controller refused the target ({message})"),
        },
        e => device_error(device, e),
    }
}

/// An ABB controller over RWS running the calibd RAPID module.
///
/// A move whose reply never came (timeout, dropped link) leaves the robot's state unknown:
/// the next move is sent only after the controller confirms that the previous command was
/// acknowledged (`calib_ack == calib_seq`), so a move is never stacked on a missing reply.
#[derive(Debug)]
pub struct RwsRobot {
    handle: RwsHandle,
    name: String,
    unconfirmed: AtomicBool,
}

impl RwsRobot {
    /// Wrap a driver handle; `name` is the device name in errors.
    pub fn new(handle: RwsHandle, name: impl Into<String>) -> Self {
        Self {
            handle,
            name: name.into(),
            unconfirmed: AtomicBool::new(false),
        }
    }

    fn err(&self, e: DriverError) -> DeviceError {
        rws_error(&self.name, e)
    }

    /// Before a move: if the last one got no reply, wait (up to 5 s) until the controller
    /// acknowledges it; a move is never stacked on a missing reply.
    async fn confirm_previous(&self) -> Result<(), DeviceError> {
        if !self.unconfirmed.load(Ordering::SeqCst) {
            return Ok(());
        }
        let (mut seq, mut ack) = (String::new(), String::new());
        for _ in 0..50 {
            seq = self
                .handle
                .read_rapid("calib_seq")
                .await
                .map_err(|e| self.err(e))?;
            ack = self
                .handle
                .read_rapid("calib_ack")
                .await
                .map_err(|e| self.err(e))?;
            if seq.trim() == ack.trim() {
                self.unconfirmed.store(false, Ordering::SeqCst);
                return Ok(());
            }
            tokio::time::sleep(std::time::Duration::from_millis(100)).await;
        }
        Err(DeviceError::Fault {
            device: self.name.clone(),
            message: format!(
                "the previous move (sequence {}) is not acknowledged (ack {}) after 5 s; no new move is sent",
                seq.trim(),
                ack.trim()
            ),
        })
    }

    /// After a move: remember whether its reply went missing.
    fn settle<T>(&self, r: Result<T, DriverError>) -> Result<(), DeviceError> {
        match r {
            Ok(_) => Ok(()),
            Err(e) => {
                let missing = !matches!(
                    e,
                    DriverError::Device { .. }
                        | DriverError::Safety { .. }
                        | DriverError::InvalidRequest { .. }
                );
                if missing {
                    self.unconfirmed.store(true, Ordering::SeqCst);
                }
                Err(self.err(e))
            }
        }
    }
}

impl Robot for RwsRobot {
    fn joints(&self) -> DeviceFuture<'_, Vec<f64>> {
        Box::pin(async move {
            let q = self.handle.joints_deg().await.map_err(|e| self.err(e))?;
            Ok(q.iter().map(|v| v.to_radians()).collect())
        })
    }

    fn move_joints<'a>(&'a self, q: &'a [f64]) -> DeviceFuture<'a, ()> {
        Box::pin(async move {
            let deg: [f64; 6] = q
                .iter()
                .map(|v| v.to_degrees())
                .collect::<Vec<_>>()
                .try_into()
                .map_err(|_| DeviceError::Refused {
                    device: self.name.clone(),
                    reason: format!("{} joint values for a 6-axis arm", q.len()),
                })?;
            self.confirm_previous().await?;
            self.settle(self.handle.move_abs_j(deg).await)
        })
    }

    fn move_tool(&self, offset_mm: [f64; 3]) -> DeviceFuture<'_, ()> {
        Box::pin(async move {
            self.confirm_previous().await?;
            self.settle(self.handle.move_rel_tool(offset_mm).await)
        })
    }
}

named_adapter!(
    /// The program modules of an IRC5 over RWS (file service and `loadmod`).
    RwsModules,
    RwsHandle
);

impl ModuleLoader for RwsModules {
    fn load_module<'a>(
        &'a self,
        file: &'a str,
        text: &'a str,
        stop: bool,
    ) -> DeviceFuture<'a, String> {
        Box::pin(async move {
            self.handle
                .load_module(file, text, stop)
                .await
                .map_err(|e| device_error(&self.name, e))
        })
    }
}

named_adapter!(
    /// Three indicators read through a U-WAVE-R receiver (the handle's axis map turns
    /// readings into tool-axis offsets).
    UwaveIndicators,
    UwaveHandle
);

impl Indicators for UwaveIndicators {
    fn read(&self) -> DeviceFuture<'_, [f64; 3]> {
        Box::pin(async move {
            self.handle
                .tool_axes_mm()
                .await
                .map_err(|e| device_error(&self.name, e))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn calib_err(code: i64) -> DriverError {
        DriverError::Device {
            device: "rws",
            code,
            message: "calib server: target unreachable or outside the robot's limits".into(),
        }
    }

    #[test]
    fn an_unreachable_target_is_a_refusal_and_other_controller_errors_are_faults() {
        let e = rws_error("irb120.rws", calib_err(2));
        assert!(
            matches!(&e, DeviceError::Refused { device, reason } if device == "irb120.rws" && reason.contains("unreachable")),
            "{e:?}"
        );
        let e = rws_error("irb120.rws", calib_err(1));
        assert!(matches!(e, DeviceError::Fault { .. }), "{e:?}");
    }
}
