//! The piezo stage capability shared by the SmarAct MCS, MCS2 and CANopen CiA 402 backends:
//! positions in picometres (MCS2's native unit; MCS nm and CAN counts are converted).

use std::time::Duration;

use crate::error::DriverError;
use crate::link::BoxFuture;

/// Status of one positioner channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StageStatus {
    /// A move or reference search is in progress.
    pub moving: bool,
    /// The physical position is known (reference mark found).
    pub referenced: bool,
    /// The controller reports a fault on this channel.
    pub fault: bool,
    /// Raw status code or bit field as reported.
    pub raw: i64,
}

/// One multi-channel stage controller. Object safe: use as `Arc<dyn Stage>`.
pub trait Stage: Send + Sync {
    /// Moves channel `ch` to `pos_pm` and waits until it stops.
    fn move_absolute(&self, ch: u8, pos_pm: i64) -> BoxFuture<'_, Result<i64, DriverError>>;
    /// Current position of `ch`, pm.
    fn position(&self, ch: u8) -> BoxFuture<'_, Result<i64, DriverError>>;
    /// Status of `ch`.
    fn status(&self, ch: u8) -> BoxFuture<'_, Result<StageStatus, DriverError>>;
    /// Finds the reference mark of `ch` and waits until done.
    fn reference(&self, ch: u8) -> BoxFuture<'_, Result<(), DriverError>>;
}

/// Settings common to the stage backends.
#[derive(Debug, Clone, PartialEq)]
pub struct StageConfig {
    /// Reply timeout of one command.
    pub timeout: Duration,
    /// Timeout of a whole move or reference search.
    pub move_timeout: Duration,
    /// Status poll period while waiting.
    pub poll: Duration,
    /// Reconnection back-off.
    pub backoff: crate::link::Backoff,
}

impl Default for StageConfig {
    fn default() -> Self {
        StageConfig {
            timeout: Duration::from_secs(2),
            move_timeout: Duration::from_secs(30),
            poll: Duration::from_millis(20),
            backoff: crate::link::Backoff::default(),
        }
    }
}

/// Polls `status` until `done` says so; errors on a fault or the timeout.
pub(crate) async fn wait_until<F, Fut>(
    device: &'static str,
    cfg: &StageConfig,
    what: &str,
    mut status: F,
    done: impl Fn(&StageStatus) -> bool,
) -> Result<StageStatus, DriverError>
where
    F: FnMut() -> Fut,
    Fut: std::future::Future<Output = Result<StageStatus, DriverError>>,
{
    let deadline = tokio::time::Instant::now() + cfg.move_timeout;
    loop {
        let s = status().await?;
        if s.fault {
            return Err(DriverError::Device {
                device,
                code: s.raw,
                message: format!("channel fault while waiting for {what} (status {})", s.raw),
            });
        }
        if done(&s) {
            return Ok(s);
        }
        if tokio::time::Instant::now() >= deadline {
            return Err(DriverError::Timeout {
                device,
                what: what.to_string(),
                after_ms: cfg.move_timeout.as_millis() as u64,
            });
        }
        tokio::time::sleep(cfg.poll).await;
    }
}
