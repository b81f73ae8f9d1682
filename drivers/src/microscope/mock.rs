//! Microscope mock speaking `calibd-pose/1`: each `POSE?` takes a fresh image of a
//! [`PoseModel`] (the hook for a digital twin), `ID?` identifies the mock, anything else is
//! `ERR 1`. Planned faults (drop, stall, garbage, truncate, device error, delay) replace
//! replies. `calibd mock microscope` serves the [`Drifting`] model.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use futures_util::{SinkExt, StreamExt};
use tokio_util::codec::Framed;

use super::codec::{Reply, Request, ServerCodec};
use crate::mock_kit::{BoxIo, Conn, Faults, Handler};

/// What the microscope sees: the hook for a digital twin of the robot under the camera.
pub trait PoseModel: Send + 'static {
    /// The pattern's pose (x m, y m, theta rad) in a new image, or `None` when the pattern
    /// is not in the field of view.
    fn image(&mut self) -> Option<[f64; 3]>;
}

/// Default model: a pattern at rest at the origin.
#[derive(Debug, Clone, Copy, Default)]
pub struct AtRest;

impl PoseModel for AtRest {
    fn image(&mut self) -> Option<[f64; 3]> {
        Some([0.0; 3])
    }
}

/// The `calibd mock microscope` model: a pattern that drifts slowly on a small circle near
/// the origin (radius 100 µm, 1 mrad of rotation), seen through seeded uniform image noise
/// (±0.2 µm, ±10 µrad): the same seed gives the same poses.
#[derive(Debug, Clone)]
pub struct Drifting {
    images: u64,
    rng: u64,
}

impl Drifting {
    /// A drifting pattern whose image noise comes from `seed`.
    pub fn new(seed: u64) -> Self {
        Drifting {
            images: 0,
            rng: seed ^ 0x9e37_79b9_7f4a_7c15,
        }
    }

    /// Uniform in [-1, 1) (splitmix64).
    fn noise(&mut self) -> f64 {
        self.rng = self.rng.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.rng;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

impl PoseModel for Drifting {
    fn image(&mut self) -> Option<[f64; 3]> {
        self.images += 1;
        let a = self.images as f64 * 1e-3;
        let (sin, cos) = a.sin_cos();
        Some([
            1e-4 * cos + 2e-7 * self.noise(),
            1e-4 * sin + 2e-7 * self.noise(),
            1e-3 * sin + 1e-5 * self.noise(),
        ])
    }
}

/// The identification the mock reports.
pub const MOCK_ID: &str = "calibd-pose/1 simulated microscope";

/// A simulate-mode handler around any pose model; the image counter is shared by every
/// connection of the mock.
pub fn handler_with(model: Arc<Mutex<dyn PoseModel>>, faults: Faults) -> Handler {
    let seq = Arc::new(AtomicU64::new(0));
    Arc::new(move |io, conn| {
        Box::pin(session(
            io,
            conn,
            model.clone(),
            seq.clone(),
            faults.clone(),
        ))
    })
}

fn answer(line: &str, model: &Arc<Mutex<dyn PoseModel>>, seq: &AtomicU64) -> Reply {
    match Request::parse(line) {
        Some(Request::Id) => Reply::Id(MOCK_ID.into()),
        Some(Request::Pose) => {
            let image = match model.lock() {
                Ok(mut m) => m.image(),
                Err(_) => {
                    return Reply::Err {
                        code: 4,
                        text: "internal error".into(),
                    };
                }
            };
            let n = seq.fetch_add(1, Ordering::SeqCst) + 1;
            match image {
                Some([x_m, y_m, theta_rad]) => Reply::Pose {
                    seq: n,
                    x_m,
                    y_m,
                    theta_rad,
                },
                None => Reply::Err {
                    code: 2,
                    text: "pattern not found".into(),
                },
            }
        }
        None => Reply::Err {
            code: 1,
            text: format!(
                "unknown request {:?}",
                line.chars().take(32).collect::<String>()
            ),
        },
    }
}

async fn session(
    io: BoxIo,
    conn: Conn,
    model: Arc<Mutex<dyn PoseModel>>,
    seq: Arc<AtomicU64>,
    faults: Faults,
) {
    let mut f = Framed::new(io, ServerCodec);
    loop {
        let line = tokio::select! {
            _ = conn.token.cancelled() => return,
            l = f.next() => match l {
                Some(Ok(l)) => l,
                Some(Err(_)) => {
                    // Not a line of the protocol: say so and drop what was read.
                    let e = Reply::Err { code: 1, text: "malformed request".into() };
                    if f.send(e).await.is_err() { return; }
                    continue;
                }
                None => return,
            },
        };
        let reply = answer(&line, &model, &seq);
        let busy = |_| Reply::Err {
            code: 3,
            text: "camera busy".into(),
        };
        let wire = |r: &Reply| r.text().into_bytes();
        if !faults.send(&mut f, &conn.token, reply, wire, busy).await {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::TcpConnector;
    use crate::microscope::{MicroscopeConfig, MicroscopeHandle};
    use crate::mock_kit::{FaultKind, FaultSpec, start_with};
    use std::time::Duration;

    struct Walk(f64);
    impl PoseModel for Walk {
        fn image(&mut self) -> Option<[f64; 3]> {
            self.0 += 1e-6;
            (self.0 < 3.5e-6).then_some([self.0, -2.0 * self.0, 1e-4])
        }
    }

    #[tokio::test]
    async fn driver_reads_poses_recovers_from_faults_and_reports_device_errors() {
        let faults = Faults::new(vec![
            FaultSpec {
                kind: FaultKind::Garbage,
                at: 2,
            },
            FaultSpec {
                kind: FaultKind::DeviceError,
                at: 4,
            },
        ]);
        let model: Arc<Mutex<dyn PoseModel>> = Arc::new(Mutex::new(Walk(0.0)));
        let m = start_with("127.0.0.1:0", handler_with(model, faults))
            .await
            .expect("mock");
        let cfg = MicroscopeConfig {
            timeout: Duration::from_millis(500),
            ..MicroscopeConfig::default()
        };
        let h = MicroscopeHandle::connect(TcpConnector::new(m.addr.clone()), cfg);
        assert_eq!(h.id().await.expect("id"), MOCK_ID);
        // Reply 2 is garbage: a protocol error, then the driver reconnects.
        let e = h.pose().await.expect_err("garbage");
        assert!(matches!(e, crate::DriverError::Protocol { .. }), "{e}");
        let p = h.pose().await.expect("pose");
        assert_eq!(p.seq, 2);
        assert!((p.x_m - 2e-6).abs() < 1e-18 && (p.y_m + 4e-6).abs() < 1e-18);
        // Reply 4 is the device's own error.
        let e = h.pose().await.expect_err("busy");
        assert!(
            matches!(e, crate::DriverError::Device { code: 3, .. }),
            "{e}"
        );
        // The pattern left the field of view: ERR 2.
        let e = h.pose().await.expect_err("lost");
        assert!(
            matches!(e, crate::DriverError::Device { code: 2, .. }),
            "{e}"
        );
        m.stop().await;
    }
}
