//! A QTM RT driver handle as a [`MarkerStream`]: the 3-D labels are read once, the labelled
//! 3-D stream is started on first use (the driver resumes it after a reconnect), and a
//! recording collects frames by the capture clock.

use std::time::Duration;

use calibd_drivers::qtm::{QtmHandle, StreamTransport};
use tokio::sync::broadcast::error::RecvError;

use super::serial::device_error;
use crate::procedures::{DeviceError, DeviceFuture, MarkerFrames, MarkerStream};

/// Longest wait for the next frame while recording.
const FRAME_TIMEOUT: Duration = Duration::from_secs(2);

/// A Qualisys system streaming labelled markers.
#[derive(Debug)]
pub struct QtmStream {
    handle: QtmHandle,
    name: String,
    labels: tokio::sync::Mutex<Option<Vec<String>>>,
    rename: std::collections::BTreeMap<String, String>,
}

impl QtmStream {
    /// Wrap a driver handle; `name` is the device name in errors.
    pub fn new(handle: QtmHandle, name: impl Into<String>) -> Self {
        Self {
            handle,
            name: name.into(),
            labels: tokio::sync::Mutex::new(None),
            rename: Default::default(),
        }
    }

    /// Report QTM label `k` as model marker `v` (labels not in the map keep their name).
    pub fn with_labels(mut self, rename: std::collections::BTreeMap<String, String>) -> Self {
        self.rename = rename;
        self
    }

    async fn labels(&self) -> Result<Vec<String>, DeviceError> {
        let mut l = self.labels.lock().await;
        if let Some(v) = &*l {
            return Ok(v.clone());
        }
        let s = self
            .handle
            .parameters_3d()
            .await
            .map_err(|e| device_error(&self.name, e))?;
        let labels: Vec<String> = s
            .labels
            .iter()
            .map(|q| self.rename.get(q).unwrap_or(q).clone())
            .collect();
        *l = Some(labels.clone());
        Ok(labels)
    }

    async fn collect(&self, duration: Duration) -> Result<MarkerFrames, DeviceError> {
        let labels = self.labels().await?;
        let mut rx = self.handle.frames();
        if !self.handle.state().borrow().streaming {
            self.handle
                .stream("3D", StreamTransport::Tcp)
                .await
                .map_err(|e| device_error(&self.name, e))?;
        }
        let mut out = MarkerFrames {
            labels,
            ..MarkerFrames::default()
        };
        let mut t0 = None;
        loop {
            let f = match tokio::time::timeout(FRAME_TIMEOUT, rx.recv()).await {
                Err(_) => {
                    return Err(DeviceError::Timeout {
                        device: self.name.clone(),
                        timeout_ms: FRAME_TIMEOUT.as_millis() as u64,
                    });
                }
                Ok(Err(RecvError::Lagged(_))) => continue,
                Ok(Err(RecvError::Closed)) => {
                    return Err(DeviceError::Disconnected {
                        device: self.name.clone(),
                    });
                }
                Ok(Ok(f)) => f,
            };
            let Some(markers) = f.markers_3d() else {
                continue;
            };
            if markers.len() != out.labels.len() {
                return Err(DeviceError::Protocol {
                    device: self.name.clone(),
                    message: format!(
                        "frame {} carries {} markers for {} labels",
                        f.frame_number,
                        markers.len(),
                        out.labels.len()
                    ),
                });
            }
            let t = f.timestamp_us as f64 * 1e-6;
            let start = *t0.get_or_insert(t);
            if t - start >= duration.as_secs_f64() {
                return Ok(out);
            }
            if out.t_s.last().is_some_and(|&last| t <= last) {
                continue; // a repeated or out-of-order frame
            }
            out.t_s.push(t);
            out.frames.push(
                markers
                    .iter()
                    .map(|p| {
                        p.iter().all(|v| v.is_finite()).then(|| {
                            [
                                f64::from(p[0]) * 1e-3,
                                f64::from(p[1]) * 1e-3,
                                f64::from(p[2]) * 1e-3,
                            ]
                        })
                    })
                    .collect(),
            );
        }
    }
}

impl MarkerStream for QtmStream {
    fn record(&self, duration: Duration) -> DeviceFuture<'_, MarkerFrames> {
        Box::pin(self.collect(duration))
    }
}
