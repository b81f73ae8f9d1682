//! Camera mock speaking `calibd-frames/1`: each `FRAME?` asks a [`FrameModel`] (the hook
//! for a digital twin rendering what the camera sees) for a fresh image on the blocking
//! pool; `SET` stores the connection's exposure and frame rate; planned faults replace
//! replies.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use futures_util::{SinkExt, StreamExt};
use tokio_util::codec::Framed;

use super::codec::{Frame, Reply, Request, ServerCodec};
use crate::mock_kit::{BoxIo, Conn, Faults, Handler};

/// An image the model produced: size, bit depth and row-major pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Bits per pixel (8 or 16).
    pub bit_depth: u8,
    /// Pixels, below 2^bit_depth.
    pub pixels: Vec<u16>,
}

/// What the camera sees.
pub trait FrameModel: Send + 'static {
    /// A new image at `exposure_us`, or why there is none.
    fn image(&mut self, exposure_us: f64) -> Result<Image, String>;
}

/// The identification the mock reports.
pub const MOCK_ID: &str = "calibd-frames/1 simulated camera";

/// A handler around a frame model; the frame counter is shared by every connection.
pub fn handler_with(model: Arc<Mutex<dyn FrameModel>>, faults: Faults) -> Handler {
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

fn err(code: i64, text: impl Into<String>) -> Reply {
    Reply::Err {
        code,
        text: text.into(),
    }
}

async fn frame(model: &Arc<Mutex<dyn FrameModel>>, seq: &AtomicU64, exposure_us: f64) -> Reply {
    let m = model.clone();
    let image = tokio::task::spawn_blocking(move || match m.lock() {
        Ok(mut m) => m.image(exposure_us),
        Err(_) => Err("internal error".into()),
    })
    .await;
    match image {
        Ok(Ok(i)) => Reply::Frame(Frame {
            seq: seq.fetch_add(1, Ordering::SeqCst) + 1,
            width: i.width,
            height: i.height,
            bit_depth: i.bit_depth,
            exposure_us,
            pixels: i.pixels,
        }),
        Ok(Err(text)) => err(2, text),
        Err(_) => err(4, "internal error"),
    }
}

async fn session(
    io: BoxIo,
    conn: Conn,
    model: Arc<Mutex<dyn FrameModel>>,
    seq: Arc<AtomicU64>,
    faults: Faults,
) {
    let mut f = Framed::new(io, ServerCodec);
    let mut exposure_us = 1000.0;
    loop {
        let line = tokio::select! {
            _ = conn.token.cancelled() => return,
            l = f.next() => match l {
                Some(Ok(l)) => l,
                Some(Err(_)) => {
                    if f.send(err(1, "malformed request")).await.is_err() { return; }
                    continue;
                }
                None => return,
            },
        };
        let reply = match Request::parse(&line) {
            Some(Request::Id) => Reply::Id(MOCK_ID.into()),
            Some(Request::Set { exposure_us: e, .. }) => {
                exposure_us = e;
                Reply::Ok
            }
            Some(Request::Frame) => frame(&model, &seq, exposure_us).await,
            None => err(
                1,
                format!(
                    "unknown request {:?}",
                    line.chars().take(32).collect::<String>()
                ),
            ),
        };
        let busy = |_| err(3, "camera busy");
        if !faults
            .send(&mut f, &conn.token, reply, Reply::wire, busy)
            .await
        {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::{CameraConfig, CameraHandle};
    use crate::link::TcpConnector;
    use crate::mock_kit::{FaultKind, FaultSpec, start_with};
    use std::time::Duration;

    /// A ramp whose brightness is the exposure (us) and whose first pixel counts images.
    struct Ramp(u16);
    impl FrameModel for Ramp {
        fn image(&mut self, exposure_us: f64) -> Result<Image, String> {
            self.0 += 1;
            if self.0 > 4 {
                return Err("pattern left the field".into());
            }
            let mut pixels: Vec<u16> = (0..12).map(|i| i * exposure_us as u16).collect();
            pixels[0] = self.0;
            Ok(Image {
                width: 4,
                height: 3,
                bit_depth: 16,
                pixels,
            })
        }
    }

    #[tokio::test]
    async fn the_driver_sets_the_exposure_reads_frames_and_recovers_from_a_dropped_link() {
        let faults = Faults::new(vec![FaultSpec {
            kind: FaultKind::Drop,
            at: 4,
        }]);
        let model: Arc<Mutex<dyn FrameModel>> = Arc::new(Mutex::new(Ramp(0)));
        let m = start_with("127.0.0.1:0", handler_with(model, faults))
            .await
            .expect("mock");
        let cfg = CameraConfig {
            timeout: Duration::from_millis(500),
            exposure_us: 7.0,
            ..CameraConfig::default()
        };
        let h = CameraHandle::connect(TcpConnector::new(m.addr.clone()), cfg);
        // Replies 1 (OK to SET) and 2 (ID).
        assert_eq!(h.id().await.expect("id"), MOCK_ID);
        let f = h.frame().await.expect("frame");
        assert_eq!((f.seq, f.width, f.height, f.bit_depth), (1, 4, 3, 16));
        assert_eq!(f.pixels[1..4], [7, 14, 21], "exposure from the config");
        assert_eq!(f.exposure_us, 7.0);
        // Reply 4 is dropped: the link breaks, the next request reconnects (and sets again).
        assert!(h.frame().await.is_err());
        let f = h.frame().await.expect("frame after reconnecting");
        assert_eq!(f.pixels[0], 3);
        assert_eq!(f.pixels[1], 7);
        assert_eq!(f.seq, 3, "the counter grows over connections");
        h.frame().await.expect("frame 4");
        let e = h.frame().await.expect_err("the model has no fifth image");
        assert!(
            matches!(e, crate::DriverError::Device { code: 2, .. }),
            "{e}"
        );
        m.stop().await;
    }
}
