//! The lab's devices as operators see them: each device of each cell with what it is, where
//! it is reached, and a probe that asks it who it is. [`Lab::check`] probes every device
//! (the `calibd lab check` table and `GET /v1/lab`); the daemon re-checks in the
//! background, and a cell with a device that failed its last check is unavailable, with the
//! device, its address, the error and what to fix.

use std::future::Future;
use std::pin::Pin;
use std::sync::Mutex;
use std::time::Duration;

use serde::Serialize;

use super::Lab;

/// What a device said about itself.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Identity {
    /// One line for the table (name, version, live readings).
    pub summary: String,
    /// The typed identity as the driver reported it.
    pub details: serde_json::Value,
    /// What names the unit, none of its live state: the same device after a reconnect has
    /// the same fingerprint (automatic resume compares them).
    pub fingerprint: String,
}

/// Why a probe failed, and the fix when the device's identity names it.
#[derive(Debug, Clone, PartialEq)]
pub struct ProbeError {
    /// What went wrong.
    pub error: String,
    /// What to do (else derived from the error by [`fix_for`]).
    pub fix: Option<String>,
}

impl From<String> for ProbeError {
    fn from(error: String) -> Self {
        Self { error, fix: None }
    }
}

/// A probe's future.
pub type ProbeFuture = Pin<Box<dyn Future<Output = Result<Identity, ProbeError>> + Send>>;

/// The last check of a device.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum DeviceStatus {
    /// Not checked yet (the lab is connecting).
    Unchecked,
    /// It answered.
    Ok {
        /// What it said.
        identity: Identity,
        /// When (RFC 3339).
        checked_at: String,
    },
    /// It did not answer, or answered wrongly.
    Failed {
        /// What went wrong.
        error: String,
        /// What to do about it.
        fix: String,
        /// When (RFC 3339).
        checked_at: String,
    },
}

/// One device of a cell: name (queue lock), what it is, where, and how to probe it.
pub struct DeviceLink {
    /// Device name, `<cell>.<role>` (also the queue's lock).
    pub name: String,
    /// What it is, e.g. `ABB IRC5 (RWS 1.0)`.
    pub kind: &'static str,
    /// Where it is reached (`host:port`, serial port).
    pub address: String,
    probe: Box<dyn Fn() -> ProbeFuture + Send + Sync>,
    status: Mutex<DeviceStatus>,
    /// The identity of the last probe that succeeded, kept while the device fails.
    last_ok: Mutex<Option<Identity>>,
    /// One probe at a time per device (the background check and a refresh may meet).
    probing: tokio::sync::Mutex<()>,
}

impl std::fmt::Debug for DeviceLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DeviceLink")
            .field("name", &self.name)
            .field("address", &self.address)
            .finish_non_exhaustive()
    }
}

impl DeviceLink {
    /// A device; `probe` asks it who it is (read-only: it may run during a campaign).
    pub fn new(
        name: impl Into<String>,
        kind: &'static str,
        address: impl Into<String>,
        probe: impl Fn() -> ProbeFuture + Send + Sync + 'static,
    ) -> Self {
        Self {
            name: name.into(),
            kind,
            address: address.into(),
            probe: Box::new(probe),
            status: Mutex::new(DeviceStatus::Unchecked),
            last_ok: Mutex::new(None),
            probing: tokio::sync::Mutex::new(()),
        }
    }

    /// Mark the device failed before its first probe (`error`, e.g. its serial port does not
    /// exist), so its cell is unavailable from the start; the next probe replaces this.
    pub fn failed_from_start(self, error: String) -> Self {
        let fix = fix_for(self.kind, &self.address, &error);
        *self.status.lock().unwrap_or_else(|p| p.into_inner()) = DeviceStatus::Failed {
            error,
            fix,
            checked_at: crate::util::format_time(chrono::Utc::now()),
        };
        self
    }

    /// The last check.
    pub fn status(&self) -> DeviceStatus {
        self.status
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// What the device said it was the last time a probe succeeded (None: never yet).
    pub fn last_identity(&self) -> Option<Identity> {
        self.last_ok
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Probe now (at most `timeout`), keep and return the result.
    pub async fn check(&self, timeout: Duration) -> DeviceStatus {
        let _one = self.probing.lock().await;
        let r = match tokio::time::timeout(timeout, (self.probe)()).await {
            Ok(r) => r,
            Err(_) => Err(ProbeError::from(format!(
                "no answer within {} s",
                timeout.as_secs_f64()
            ))),
        };
        let checked_at = crate::util::format_time(chrono::Utc::now());
        if let Ok(identity) = &r {
            *self.last_ok.lock().unwrap_or_else(|p| p.into_inner()) = Some(identity.clone());
        }
        let s = match r {
            Ok(identity) => DeviceStatus::Ok {
                identity,
                checked_at,
            },
            Err(e) => DeviceStatus::Failed {
                fix: e
                    .fix
                    .unwrap_or_else(|| fix_for(self.kind, &self.address, &e.error)),
                error: e.error,
                checked_at,
            },
        };
        *self.status.lock().unwrap_or_else(|p| p.into_inner()) = s.clone();
        s
    }
}

/// What to do about a failed check, from the kind of failure.
pub fn fix_for(kind: &str, address: &str, error: &str) -> String {
    let e = error.to_ascii_lowercase();
    if e.contains("refused") {
        format!(
            "nothing listens at {address}: is the {kind} on, its server started, and the port right?"
        )
    } else if e.contains("no answer") || e.contains("timed out") || e.contains("timeout") {
        format!(
            "{address} does not answer: check the cable or network route and any firewall between calibd and the {kind}"
        )
    } else if e.contains("401") || e.contains("unauthori") || e.contains("digest") {
        "the device refused the credentials: check the user and the password file or variable"
            .into()
    } else if e.contains("no such file") || e.contains("not found") && address.starts_with('/') {
        format!(
            "{address} does not exist: plug the receiver in and name its port (ls /dev/serial/by-id/)"
        )
    } else if e.contains("not a typewriter") || e.contains("inappropriate ioctl") {
        format!("{address} is not a serial port: name the receiver's port (ls /dev/serial/by-id/)")
    } else if e.contains("permission denied") {
        format!("calibd may not open {address}: add the calibd user to the dialout group")
    } else if e.contains("resolve") || e.contains("lookup") || e.contains("name or service") {
        format!("the host of {address} is unknown: check the name or use the IP address")
    } else {
        format!("see the {kind}'s own diagnostics; the error above is what calibd received")
    }
}

/// One row of a lab check.
#[derive(Debug, Clone, Serialize)]
pub struct DeviceReport {
    /// The cell.
    pub cell: String,
    /// The device.
    pub device: String,
    /// What it is.
    pub kind: &'static str,
    /// Where.
    pub address: String,
    /// The last check.
    #[serde(flatten)]
    pub status: DeviceStatus,
}

impl Lab {
    /// Probe every device now (concurrently, each within `timeout`).
    pub async fn check(&self, timeout: Duration) -> Vec<DeviceReport> {
        let links: Vec<(&str, &DeviceLink)> = self
            .cells()
            .flat_map(|c| c.links().iter().map(move |l| (c.name(), l)))
            .collect();
        let statuses =
            futures_util::future::join_all(links.iter().map(|(_, l)| l.check(timeout))).await;
        links
            .iter()
            .zip(statuses)
            .map(|((cell, l), status)| report(cell, l, status))
            .collect()
    }

    /// The last check of every device, without probing.
    pub fn reports(&self) -> Vec<DeviceReport> {
        self.cells()
            .flat_map(|c| {
                c.links()
                    .iter()
                    .map(move |l| report(c.name(), l, l.status()))
            })
            .collect()
    }

    /// The devices named in `devices`, with their cells.
    pub fn links_for<'a>(&'a self, devices: &'a [String]) -> Vec<(&'a str, &'a DeviceLink)> {
        self.cells()
            .flat_map(|c| c.links().iter().map(move |l| (c.name(), l)))
            .filter(|(_, l)| devices.contains(&l.name))
            .collect()
    }

    /// Why `cell` cannot run a campaign now (a device failed its last check), if so.
    pub fn unavailable(&self, cell: &str) -> Option<String> {
        let c = self.cell(cell)?;
        c.links().iter().find_map(|l| match l.status() {
            DeviceStatus::Failed { error, fix, .. } => Some(format!(
                "cell `{cell}` is unavailable: {} at {}: {error} ({fix})",
                l.name, l.address
            )),
            _ => None,
        })
    }

    /// Why a job on `devices` cannot start now (a cell it uses is unavailable), if so.
    pub fn unavailable_for(&self, devices: &[String]) -> Option<String> {
        self.cells()
            .filter(|c| c.devices().iter().any(|d| devices.contains(d)))
            .find_map(|c| self.unavailable(c.name()))
    }

    /// Re-check every device until `stop`: every `down` while a device is failing, every
    /// `up` otherwise (probes are read-only requests, safe during a campaign; each may wait
    /// up to 10 s behind a move the device is executing before it counts as unanswered).
    pub async fn watch(
        self: std::sync::Arc<Self>,
        up: Duration,
        down: Duration,
        stop: tokio_util::sync::CancellationToken,
    ) {
        loop {
            let failed = self
                .check(Duration::from_secs(10))
                .await
                .iter()
                .filter(|r| matches!(r.status, DeviceStatus::Failed { .. }))
                .count();
            let wait = if failed > 0 { down } else { up };
            tokio::select! {
                _ = stop.cancelled() => return,
                _ = tokio::time::sleep(wait) => {}
            }
        }
    }
}

fn report(cell: &str, l: &DeviceLink, status: DeviceStatus) -> DeviceReport {
    DeviceReport {
        cell: cell.to_string(),
        device: l.name.clone(),
        kind: l.kind,
        address: l.address.clone(),
        status,
    }
}

/// The check as a table for a terminal: device, address, state, identity or error and fix.
pub fn table(reports: &[DeviceReport]) -> String {
    let mut out = String::new();
    let w_dev = reports
        .iter()
        .map(|r| r.device.len())
        .max()
        .unwrap_or(6)
        .max(6);
    let w_addr = reports
        .iter()
        .map(|r| r.address.len())
        .max()
        .unwrap_or(7)
        .max(7);
    out.push_str(&format!(
        "{:<w_dev$}  {:<w_addr$}  {:<6}  identity / error\n",
        "device", "address", "state"
    ));
    for r in reports {
        let (state, text) = match &r.status {
            DeviceStatus::Unchecked => ("?", "not checked".to_string()),
            DeviceStatus::Ok { identity, .. } => {
                ("ok", format!("{}: {}", r.kind, identity.summary))
            }
            DeviceStatus::Failed { error, fix, .. } => (
                "FAILED",
                format!(
                    "{}: {error}\n{:w$}  fix: {fix}",
                    r.kind,
                    "",
                    w = w_dev + w_addr + 10
                ),
            ),
        };
        out.push_str(&format!(
            "{:<w_dev$}  {:<w_addr$}  {:<6}  {text}\n",
            r.device, r.address, state
        ));
    }
    out
}
