//! SmarAct MCS (MCS1) ASCII protocol: `:CMD<ch>,args\n` → one reply line in synchronous
//! mode (`:SCM0`); positions in nm; errors `:E<ch>,<code>` (devices.md §3a).

use super::identity::StageIdentity;
use super::line::{LineClient, LineState};
use super::stage::{Stage, StageConfig, StageStatus, wait_until};
use crate::error::DriverError;
use crate::link::{BoxFuture, Connect};

const DEVICE: &str = "mcs";

/// One parsed MCS reply.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum McsReply {
    /// `:E<ch>,<code>`: acknowledge (0) or error.
    Error {
        /// Channel, -1 for controller-wide.
        ch: i64,
        /// Error code, 0 = ok.
        code: i64,
    },
    /// Any other reply: mnemonic (`P`, `S`, `PPK`, `CLS`, ...), channel and values.
    Value {
        /// Upper-case mnemonic.
        mnemonic: String,
        /// Channel.
        ch: i64,
        /// Remaining values.
        values: Vec<i64>,
    },
}

/// Parses `:E0,0`, `:P0,1499998`, `:PPK0,1`, `:A0,5000,1`.
pub fn parse_reply(line: &str) -> Result<McsReply, DriverError> {
    let bad = || DriverError::Protocol {
        device: DEVICE,
        detail: format!("bad MCS reply {line:?}"),
    };
    let body = line.strip_prefix(':').ok_or_else(bad)?;
    let split = body
        .find(|c: char| !c.is_ascii_uppercase())
        .ok_or_else(bad)?;
    let (mnemonic, rest) = body.split_at(split);
    if mnemonic.is_empty() {
        return Err(bad());
    }
    let nums: Vec<i64> = rest
        .split(',')
        .map(|v| v.trim().parse().map_err(|_| bad()))
        .collect::<Result<_, _>>()?;
    let (&ch, values) = nums.split_first().ok_or_else(bad)?;
    if mnemonic == "E" {
        if values.len() != 1 {
            return Err(bad());
        }
        return Ok(McsReply::Error {
            ch,
            code: values[0],
        });
    }
    Ok(McsReply::Value {
        mnemonic: mnemonic.into(),
        ch,
        values: values.to_vec(),
    })
}

/// Text of an MCS error code.
pub fn error_text(code: i64) -> &'static str {
    match code {
        1 => "syntax error",
        2 => "invalid command",
        3 => "overflow",
        4 => "parse error",
        5 => "too few parameters",
        6 => "too many parameters",
        7 => "invalid parameter",
        8 => "wrong mode",
        129 => "no sensor present",
        140 => "sensor disabled",
        141 => "command overridden",
        142 => "end stop reached",
        143 => "wrong sensor type",
        144 => "could not find reference mark",
        145 => "wrong end effector type",
        146 => "movement locked",
        147 => "range limit reached",
        148 => "physical position unknown",
        150 => "command not processable",
        151 => "waiting for trigger",
        152 => "command not triggerable",
        153 => "command queue full",
        _ => "unknown error",
    }
}

/// Cheap, cloneable handle to an MCS controller.
#[derive(Debug, Clone)]
pub struct McsHandle {
    line: LineClient,
    cfg: StageConfig,
    /// Hold time after moves, ms (60000 = hold forever).
    pub hold_ms: u32,
}

impl McsHandle {
    /// Starts the actor; `:SCM0` (synchronous mode) is sent after every connect.
    pub fn connect<C: Connect>(connector: C, cfg: StageConfig) -> Self {
        let line = LineClient::start(
            DEVICE,
            connector,
            cfg.timeout,
            cfg.backoff,
            vec![":SCM0".into()],
            None,
        );
        McsHandle {
            line,
            cfg,
            hold_ms: 60000,
        }
    }

    /// Sends one command and returns its parsed reply; `:E<ch>,<code≠0>` is a device error.
    pub async fn command(&self, cmd: &str) -> Result<McsReply, DriverError> {
        let r = parse_reply(&self.line.query(cmd.to_string()).await?)?;
        match r {
            McsReply::Error { code, .. } if code != 0 => Err(DriverError::Device {
                device: DEVICE,
                code,
                message: format!("{} (after {cmd:?})", error_text(code)),
            }),
            other => Ok(other),
        }
    }

    async fn value(&self, cmd: &str, mnemonic: &str, ch: u8) -> Result<Vec<i64>, DriverError> {
        match self.command(cmd).await? {
            McsReply::Value {
                mnemonic: m,
                ch: c,
                values,
            } if m == mnemonic && c == i64::from(ch) && !values.is_empty() => Ok(values),
            other => Err(DriverError::Protocol {
                device: DEVICE,
                detail: format!("expected :{mnemonic}{ch} to {cmd:?}, got {other:?}"),
            }),
        }
    }

    async fn ack(&self, cmd: &str) -> Result<(), DriverError> {
        match self.command(cmd).await? {
            McsReply::Error { code: 0, .. } => Ok(()),
            other => Err(DriverError::Protocol {
                device: DEVICE,
                detail: format!("expected an acknowledge to {cmd:?}, got {other:?}"),
            }),
        }
    }

    async fn status_of(&self, ch: u8) -> Result<StageStatus, DriverError> {
        let code = self.value(&format!(":GS{ch}"), "S", ch).await?[0];
        let known = self.value(&format!(":GPPK{ch}"), "PPK", ch).await?[0] == 1;
        Ok(StageStatus {
            moving: !matches!(code, 0 | 3),
            referenced: known,
            fault: code == 8,
            raw: code,
        })
    }

    /// A controller-wide query (`:GSI`, `:GNC`) whose reply is `:<mnemonic><value>`.
    async fn system_value(&self, cmd: &str, mnemonic: &str) -> Result<i64, DriverError> {
        match self.command(cmd).await? {
            McsReply::Value {
                mnemonic: m,
                ch: v,
                values,
            } if m == mnemonic && values.is_empty() => Ok(v),
            other => Err(DriverError::Protocol {
                device: DEVICE,
                detail: format!("expected :{mnemonic}<value> to {cmd:?}, got {other:?}"),
            }),
        }
    }

    /// System id (`:GSI`), channel count (`:GNC`) and, per channel in `channels`, whether
    /// its physical position is known (`:GPPK`) and its position. Channels beyond the count
    /// are listed in [`StageIdentity::missing_channels`] without being queried.
    pub async fn identity(&self, channels: &[u8]) -> Result<StageIdentity, DriverError> {
        let system_id = self.system_value(":GSI", "ID").await?;
        let count = self.system_value(":GNC", "N").await?;
        let channel_count = u32::try_from(count).map_err(|_| DriverError::Protocol {
            device: DEVICE,
            detail: format!(":GNC = {count} is not a channel count"),
        })?;
        let (out, missing_channels) =
            super::identity::channels(self, channels, channel_count).await?;
        Ok(StageIdentity {
            controller: DEVICE,
            serial_number: system_id.to_string(),
            device_name: None,
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

impl Stage for McsHandle {
    fn move_absolute(&self, ch: u8, pos_pm: i64) -> BoxFuture<'_, Result<i64, DriverError>> {
        Box::pin(async move {
            let nm = (pos_pm as f64 / 1000.0).round() as i64;
            self.ack(&format!(":MPA{ch},{nm},{}", self.hold_ms)).await?;
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
            let nm = self.value(&format!(":GP{ch}"), "P", ch).await?[0];
            nm.checked_mul(1000).ok_or_else(|| DriverError::Protocol {
                device: DEVICE,
                detail: format!("position {nm} nm out of range"),
            })
        })
    }
    fn status(&self, ch: u8) -> BoxFuture<'_, Result<StageStatus, DriverError>> {
        Box::pin(self.status_of(ch))
    }
    fn reference(&self, ch: u8) -> BoxFuture<'_, Result<(), DriverError>> {
        Box::pin(async move {
            self.ack(&format!(":FRM{ch},0,{},1", self.hold_ms)).await?;
            let s = wait_until(
                DEVICE,
                &self.cfg,
                "the reference search",
                || self.status_of(ch),
                |s| s.raw != 7,
            )
            .await?;
            if !s.referenced {
                return Err(DriverError::Device {
                    device: DEVICE,
                    code: 144,
                    message: error_text(144).into(),
                });
            }
            Ok(())
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_system_id_and_channel_count_replies() {
        assert_eq!(
            parse_reply(":ID3118167526").unwrap(),
            McsReply::Value {
                mnemonic: "ID".into(),
                ch: 3_118_167_526,
                values: vec![]
            }
        );
        assert_eq!(
            parse_reply(":N3").unwrap(),
            McsReply::Value {
                mnemonic: "N".into(),
                ch: 3,
                values: vec![]
            }
        );
    }

    #[test]
    fn parses_documented_replies() {
        assert_eq!(
            parse_reply(":E-1,0").unwrap(),
            McsReply::Error { ch: -1, code: 0 }
        );
        assert_eq!(
            parse_reply(":E0,147").unwrap(),
            McsReply::Error { ch: 0, code: 147 }
        );
        assert_eq!(
            parse_reply(":P0,1499998").unwrap(),
            McsReply::Value {
                mnemonic: "P".into(),
                ch: 0,
                values: vec![1_499_998]
            }
        );
        assert_eq!(
            parse_reply(":PPK0,0").unwrap(),
            McsReply::Value {
                mnemonic: "PPK".into(),
                ch: 0,
                values: vec![0]
            }
        );
        assert_eq!(
            parse_reply(":A2,5000,-1").unwrap(),
            McsReply::Value {
                mnemonic: "A".into(),
                ch: 2,
                values: vec![5000, -1]
            }
        );
        for bad in ["P0,1", ":P", ":0,1", ":Pxx", ":E0", ":E0,1,2", ""] {
            assert!(parse_reply(bad).is_err(), "{bad}");
        }
    }
}
