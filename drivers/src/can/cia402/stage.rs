//! [`Stage`] for a CiA 402 drive: channel 0 only, positions scaled by `pm_per_count`,
//! referencing by homing mode 6; statusword bit 15 is read as "position referenced"
//! (manufacturer-specific in CiA 402, set by calibd's mock drive after homing).

use super::{Cia402Handle, DEVICE, sw};
use crate::error::DriverError;
use crate::link::BoxFuture;
use crate::smaract::{Stage, StageStatus};

impl Stage for Cia402Handle {
    fn move_absolute(&self, ch: u8, pos_pm: i64) -> BoxFuture<'_, Result<i64, DriverError>> {
        Box::pin(async move {
            check_channel(ch)?;
            let counts = pos_pm
                .checked_div(self.cfg.pm_per_count)
                .and_then(|c| i32::try_from(c).ok())
                .ok_or_else(|| DriverError::InvalidRequest {
                    device: DEVICE,
                    detail: format!(
                        "{pos_pm} pm at {} pm/count does not fit in i32 counts",
                        self.cfg.pm_per_count
                    ),
                })?;
            Ok(i64::from(self.move_to_counts(counts).await?).saturating_mul(self.cfg.pm_per_count))
        })
    }
    fn position(&self, ch: u8) -> BoxFuture<'_, Result<i64, DriverError>> {
        Box::pin(async move {
            check_channel(ch)?;
            Ok(i64::from(self.position_counts().await?).saturating_mul(self.cfg.pm_per_count))
        })
    }
    fn status(&self, ch: u8) -> BoxFuture<'_, Result<StageStatus, DriverError>> {
        Box::pin(async move {
            check_channel(ch)?;
            let s = self.statusword().await?;
            Ok(StageStatus {
                moving: s & 0x6F == 0x27 && s & sw::TARGET_REACHED == 0,
                referenced: s & (1 << 15) != 0,
                fault: s & sw::FAULT != 0,
                raw: i64::from(s),
            })
        })
    }
    fn reference(&self, ch: u8) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(async move {
            check_channel(ch)?;
            self.run_setpoint(6, None).await.map(|_| ())
        })
    }
}

fn check_channel(ch: u8) -> Result<(), DriverError> {
    if ch != 0 {
        return Err(DriverError::InvalidRequest {
            device: DEVICE,
            detail: format!("a CiA 402 drive has one channel (0), not {ch}"),
        });
    }
    Ok(())
}
