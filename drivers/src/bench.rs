//! Driver benchmarks (printed by `cargo bench -p calibd-drivers --bench qtm`, or callable
//! from `calibd bench drivers`): QTM frame decoding with 60 markers on one core, and an
//! end-to-end 1 kHz stream through the QTM mock over loopback with gap accounting.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use bytes::BytesMut;
use tokio_util::codec::Decoder;

use crate::TcpConnector;
use crate::mock::{self, Faults, MockArgs, MockDevice};
use crate::qtm::mock::{CircleMarkers, MarkerModel, handler_with};
use crate::qtm::packet::{self, Component, DataFrame, Packet};
use crate::qtm::{QtmCodec, QtmConfig, QtmHandle, StreamTransport};

/// Result of the decoding benchmark.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodeFigures {
    /// Markers per frame.
    pub markers: usize,
    /// Bytes per encoded frame.
    pub frame_bytes: usize,
    /// Frames decoded.
    pub frames: u64,
    /// Frames per second on one core.
    pub frames_per_s: f64,
}

/// Result of the end-to-end stream benchmark.
#[derive(Debug, Clone, PartialEq)]
pub struct StreamFigures {
    /// TCP or UDP.
    pub transport: StreamTransport,
    /// Requested rate, Hz.
    pub rate_hz: f64,
    /// Markers per frame.
    pub markers: usize,
    /// Frames received by the subscriber.
    pub frames: u64,
    /// Frames missing by frame-number accounting (driver state).
    pub missed: u64,
    /// Frames the subscriber lost to a full broadcast buffer.
    pub lagged: u64,
    /// Received frames per second of wall time.
    pub achieved_hz: f64,
}

/// Decodes a stream of 60-marker frames for about `secs` seconds on the calling thread.
pub fn decode_60_markers(secs: f64) -> DecodeFigures {
    let mut model = CircleMarkers::new(60);
    let mut buf = Vec::new();
    let mut one = BytesMut::new();
    let mut stream = BytesMut::new();
    for i in 0..1000u32 {
        model.sample(f64::from(i) * 1e-3, &mut buf);
        let f = Packet::Data(DataFrame {
            timestamp_us: i64::from(i) * 1000,
            frame_number: i,
            components: vec![Component::Markers3d {
                drop_rate: 0,
                out_of_sync_rate: 0,
                markers: buf.clone(),
            }],
        });
        one.clear();
        packet::encode(&f, &mut one);
        stream.extend_from_slice(&one);
    }
    let frame_bytes = one.len();
    let start = Instant::now();
    let mut frames = 0u64;
    let mut checksum = 0.0f32;
    while start.elapsed().as_secs_f64() < secs {
        let mut b = stream.clone();
        while let Ok(Some(Packet::Data(f))) = QtmCodec.decode(&mut b) {
            if let Some(m) = f.markers_3d() {
                checksum += m[0][0];
            }
            frames += 1;
        }
    }
    std::hint::black_box(checksum);
    DecodeFigures {
        markers: 60,
        frame_bytes,
        frames,
        frames_per_s: frames as f64 / start.elapsed().as_secs_f64(),
    }
}

/// Streams `secs` seconds of `markers`-marker frames at `rate_hz` from the QTM mock over
/// loopback and counts what arrives.
pub async fn stream_through_mock(
    transport: StreamTransport,
    rate_hz: f64,
    markers: usize,
    secs: f64,
) -> Result<StreamFigures, String> {
    let mut args = MockArgs::new(MockDevice::Qtm);
    args.rate_hz = rate_hz;
    let model: Arc<Mutex<dyn MarkerModel>> = Arc::new(Mutex::new(CircleMarkers::new(markers)));
    let m = mock::start_with("127.0.0.1:0", handler_with(model, &args, Faults::default()))
        .await
        .map_err(|e| e.to_string())?;
    let cfg = QtmConfig {
        udp_bind: "127.0.0.1:0".into(),
        frame_buffer: 1 << 16,
        ..QtmConfig::default()
    };
    let h = QtmHandle::connect(TcpConnector::new(m.addr.clone()), cfg);
    let mut rx = h.frames();
    h.stream("3D", transport).await.map_err(|e| e.to_string())?;
    let (mut frames, mut lagged) = (0u64, 0u64);
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(secs);
    while Instant::now() < end {
        match tokio::time::timeout(Duration::from_millis(200), rx.recv()).await {
            Ok(Ok(_)) => frames += 1,
            Ok(Err(tokio::sync::broadcast::error::RecvError::Lagged(n))) => lagged += n,
            Ok(Err(_)) => break,
            Err(_) => {}
        }
    }
    let elapsed = start.elapsed().as_secs_f64();
    h.stop_stream().await.map_err(|e| e.to_string())?;
    let missed = h.state().borrow().missed_frames;
    m.stop().await;
    Ok(StreamFigures {
        transport,
        rate_hz,
        markers,
        frames,
        missed,
        lagged,
        achieved_hz: frames as f64 / elapsed,
    })
}

/// Runs both benchmarks (2 s decoding, 5 s TCP and UDP streams at 1 kHz with 60 markers) and
/// prints one line per figure: the body of `calibd bench drivers` and of the `qtm` bench.
pub fn run_and_print(out: &mut dyn std::io::Write) -> std::io::Result<()> {
    let d = decode_60_markers(2.0);
    writeln!(
        out,
        "qtm decode: {} markers/frame, {} bytes/frame, {} frames in 2 s: {:.0} frames/s on one core",
        d.markers, d.frame_bytes, d.frames, d.frames_per_s
    )?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    for t in [StreamTransport::Tcp, StreamTransport::Udp] {
        match rt.block_on(stream_through_mock(t, 1000.0, 60, 5.0)) {
            Ok(s) => writeln!(
                out,
                "qtm stream {:?} at {} Hz, {} markers, 5 s: {} frames received ({:.1} Hz), {} missed by frame number, {} lost to lag",
                s.transport, s.rate_hz, s.markers, s.frames, s.achieved_hz, s.missed, s.lagged
            )?,
            Err(e) => writeln!(out, "qtm stream {t:?}: failed: {e}")?,
        }
    }
    Ok(())
}
