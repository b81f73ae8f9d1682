//! SmarAct MCS2 SCPI-like protocol over TCP 55551: queries end with `?` and get one CRLF
//! line; set commands and actions are silent and checked with `:SYST:ERR:COUN?` /
//! `:SYST:ERR?`; positions in pm (devices.md §3b).
//!
//! Error attribution: the queue is shared by every client of the controller, so another
//! client's errors land in it at any time. The queue is drained (and what was in it logged)
//! after every connect; a checked command is sent between two `:SYST:ERR:COUN?` on one line,
//! so the entries queued before it are provably another client's (drained, logged, never
//! blamed), and those it added are its own. When another client reads the queue meanwhile
//! (the count shrinks or runs dry), the command is sent again (every checked command of this
//! driver is idempotent). Code 0 ("No error") is never an error.

use super::identity::StageIdentity;
use super::line::{ErrorQueue, LineClient, LineState};
use super::stage::{Stage, StageConfig, StageStatus, wait_until};
use crate::error::DriverError;
use crate::link::{BoxFuture, Connect};

const DEVICE: &str = "mcs2";

/// Channel state bits that mean a fault: movement failed, overload, over temperature,
/// positioner fault.
pub const FAULT_BITS: i64 = (1 << 11) | (1 << 13) | (1 << 14) | (1 << 17);

/// Cheap, cloneable handle to an MCS2 controller.
#[derive(Debug, Clone)]
pub struct Mcs2Handle {
    line: LineClient,
    cfg: StageConfig,
}

/// The MCS2 error queue (devices.md §3b).
const QUEUE: ErrorQueue = ErrorQueue {
    count: ":SYST:ERR:COUN?",
    next: ":SYST:ERR?",
    parse: parse_error,
};

/// Parses a `:SYST:ERR?` reply, SCPI style `<code>,"<text>"` (split at the first comma,
/// quotes dropped); `0,"No error"` is code 0.
pub fn parse_error(line: &str) -> Result<(i64, String), DriverError> {
    let (code, text) = line.split_once(',').unwrap_or((line, ""));
    let code = int(code, ":SYST:ERR?")?;
    Ok((code, text.trim().trim_matches('"').to_string()))
}

fn int(s: &str, what: &str) -> Result<i64, DriverError> {
    s.trim().parse().map_err(|_| DriverError::Protocol {
        device: DEVICE,
        detail: format!("{what}: {s:?} is not an integer"),
    })
}

impl Mcs2Handle {
    /// Starts the actor.
    pub fn connect<C: Connect>(connector: C, cfg: StageConfig) -> Self {
        let line = LineClient::start(
            DEVICE,
            connector,
            cfg.timeout,
            cfg.backoff,
            Vec::new(),
            Some(QUEUE),
        );
        Mcs2Handle { line, cfg }
    }

    /// A query (`...?`): the reply line; the error queue is not read.
    pub async fn query(&self, q: &str) -> Result<String, DriverError> {
        self.line.query(q.to_string()).await
    }

    /// A query whose errors are read right after it: an error it caused is a device error
    /// naming it.
    pub async fn checked_query(&self, q: &str) -> Result<String, DriverError> {
        self.line
            .checked(q.to_string(), true)
            .await?
            .ok_or(DriverError::Closed { device: DEVICE })
    }

    /// A set command or action, then the error queue is read: an error this command caused
    /// is a device error whose message names it.
    pub async fn set(&self, cmd: &str) -> Result<(), DriverError> {
        self.line.checked(cmd.to_string(), false).await.map(|_| ())
    }

    async fn status_of(&self, ch: u8) -> Result<StageStatus, DriverError> {
        let bits = int(
            &self.query(&format!(":CHAN{ch}:STAT?")).await?,
            "channel state",
        )?;
        Ok(StageStatus {
            moving: bits & 1 != 0 || bits & (1 << 3) != 0,
            referenced: bits & (1 << 7) != 0,
            fault: bits & FAULT_BITS != 0,
            raw: bits,
        })
    }

    /// Serial number, name, channel count and, per channel in `channels`, whether it is
    /// referenced (state bit 7) and its position. Channels beyond `:DEV:NOCH?` are listed in
    /// [`StageIdentity::missing_channels`] without being queried.
    pub async fn identity(&self, channels: &[u8]) -> Result<StageIdentity, DriverError> {
        let unquote = |s: String| s.trim().trim_matches('"').to_string();
        let serial_number = unquote(self.checked_query(":DEV:SNUM?").await?);
        let device_name = unquote(self.checked_query(":DEV:NAME?").await?);
        let noch = self.checked_query(":DEV:NOCH?").await?;
        let channel_count =
            u32::try_from(int(&noch, ":DEV:NOCH?")?).map_err(|_| DriverError::Protocol {
                device: DEVICE,
                detail: format!(":DEV:NOCH? = {noch:?} is not a channel count"),
            })?;
        let (out, missing_channels) =
            super::identity::channels(self, channels, channel_count).await?;
        Ok(StageIdentity {
            controller: DEVICE,
            serial_number,
            device_name: Some(device_name),
            channel_count,
            channels: out,
            missing_channels,
        })
    }

    /// Link state.
    pub fn state(&self) -> tokio::sync::watch::Receiver<LineState> {
        self.line.state()
    }
}

impl Stage for Mcs2Handle {
    fn move_absolute(&self, ch: u8, pos_pm: i64) -> BoxFuture<'_, Result<i64, DriverError>> {
        Box::pin(async move {
            self.set(&format!(":CHAN{ch}:MMOD 0")).await?;
            self.set(&format!(":MOVE{ch} {pos_pm}")).await?;
            wait_until(
                DEVICE,
                &self.cfg,
                "the move to finish",
                || self.status_of(ch),
                |s| !s.moving,
            )
            .await?;
            self.position(ch).await
        })
    }
    fn position(&self, ch: u8) -> BoxFuture<'_, Result<i64, DriverError>> {
        Box::pin(async move {
            // An invalid channel still gets a reply line; the error queue says why.
            let v = self.checked_query(&format!(":CHAN{ch}:POS?")).await?;
            int(&v, "position")
        })
    }
    fn status(&self, ch: u8) -> BoxFuture<'_, Result<StageStatus, DriverError>> {
        Box::pin(self.status_of(ch))
    }
    fn reference(&self, ch: u8) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(async move {
            self.set(&format!(":CHAN{ch}:REF:OPT 4")).await?;
            self.set(&format!(":REF{ch}")).await?;
            let s = wait_until(
                DEVICE,
                &self.cfg,
                "the reference search",
                || self.status_of(ch),
                |s| !s.moving,
            )
            .await?;
            if !s.referenced {
                return Err(DriverError::Device {
                    device: DEVICE,
                    code: s.raw,
                    message: "reference mark not found".into(),
                });
            }
            Ok(())
        })
    }
}
