//! Who the SmarAct drivers talk to: controller id, channel count and, per configured
//! channel, whether its physical position is known (referenced) and where it is.
//!
//! MCS2 (devices.md §3b): `:DEV:SNUM?`, `:DEV:NAME?`, `:DEV:NOCH?`, `:CHANn:STAT?` (bit 5
//! sensor present, bit 6 calibrated, bit 7 is referenced, fault bits 11/13/14/17) and
//! `:CHANn:POS?` (pm). MCS1 (§3a): `:GSI` (system id), `:GNC` (channel count), `:GPPK<ch>`
//! (physical position known), `:GS<ch>` (status code) and `:GP<ch>` (nm).

use serde::Serialize;

use crate::identity::{DeviceIdentity, Identity};

/// One configured positioner channel.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ChannelIdentity {
    /// Channel index (0-based).
    pub channel: u8,
    /// The physical position is known (reference mark found).
    pub referenced: bool,
    /// The controller reports a fault on this channel.
    pub fault: bool,
    /// Raw state: MCS2 channel state bits, MCS status code.
    pub state_raw: i64,
    /// Current position in picometres (MCS nm converted).
    pub position_pm: i64,
}

/// Identity of an MCS or MCS2 controller.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct StageIdentity {
    /// `mcs` or `mcs2`.
    pub controller: &'static str,
    /// Serial number (MCS2 `:DEV:SNUM?`) or system id (MCS `:GSI`).
    pub serial_number: String,
    /// Device name (MCS2 `:DEV:NAME?`; None for MCS, which has none).
    pub device_name: Option<String>,
    /// Number of channels the controller has.
    pub channel_count: u32,
    /// The configured channels that exist, in the order asked.
    pub channels: Vec<ChannelIdentity>,
    /// Configured channels the controller does not have.
    pub missing_channels: Vec<u8>,
}

impl Identity for StageIdentity {
    const DEVICE_KIND: &'static str = "smaract";

    fn fingerprint(&self) -> String {
        format!(
            "{} serial {} name {:?}, {} channels",
            self.controller, self.serial_number, self.device_name, self.channel_count
        )
    }

    fn summary(&self) -> String {
        let ch: Vec<String> = self
            .channels
            .iter()
            .map(|c| {
                format!(
                    "ch{} {} {:.3} mm",
                    c.channel,
                    if c.referenced { "ref" } else { "NOT ref" },
                    c.position_pm as f64 * 1e-9
                )
            })
            .collect();
        let name = self
            .device_name
            .as_ref()
            .map_or(String::new(), |n| format!(" \"{n}\""));
        format!(
            "SmarAct {} {}{name}, {} channels; {}",
            self.controller.to_ascii_uppercase(),
            self.serial_number,
            self.channel_count,
            ch.join(", ")
        )
    }

    fn problems(&self) -> Vec<String> {
        let mut p: Vec<String> = self
            .missing_channels
            .iter()
            .map(|c| {
                format!(
                    "channel {c} is configured but the controller has only {} channels: fix \
                     the channel in the lab config",
                    self.channel_count
                )
            })
            .collect();
        for c in &self.channels {
            if c.fault {
                p.push(format!(
                    "channel {} reports a fault (state {}): check the positioner cable and \
                     power-cycle the controller",
                    c.channel, c.state_raw
                ));
            }
            if !c.referenced {
                p.push(format!(
                    "channel {} is not referenced: run its reference search before calibrating",
                    c.channel
                ));
            }
        }
        p
    }

    /// The common row, with `device_kind` `mcs` or `mcs2` (the driver's device family).
    fn device_identity(&self) -> DeviceIdentity {
        DeviceIdentity {
            device_kind: self.controller,
            summary: self.summary(),
            problems: self.problems(),
            details: serde_json::to_value(self)
                .unwrap_or_else(|e| serde_json::json!({ "serialize_error": e.to_string() })),
            fingerprint: self.fingerprint(),
        }
    }
}

/// State and position of each of `channels` below the controller's `count`, and the
/// channels at or above it (not queried).
pub(crate) async fn channels(
    stage: &dyn crate::Stage,
    channels: &[u8],
    count: u32,
) -> Result<(Vec<ChannelIdentity>, Vec<u8>), crate::DriverError> {
    let (present, missing): (Vec<u8>, Vec<u8>) =
        channels.iter().partition(|c| u32::from(**c) < count);
    let mut out = Vec::with_capacity(present.len());
    for ch in present {
        let s = stage.status(ch).await?;
        out.push(ChannelIdentity {
            channel: ch,
            referenced: s.referenced,
            fault: s.fault,
            state_raw: s.raw,
            position_pm: stage.position(ch).await?,
        });
    }
    Ok((out, missing))
}
