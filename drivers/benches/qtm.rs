//! QTM benchmarks (issue 6): frame decoding with 60 markers on one core, and a 1 kHz stream
//! through the QTM mock over loopback with no frame lost.
//! Run: `cargo bench -p calibd-drivers --bench qtm`.
//!
//! Figures on the 2-core dev machine (release profile), 2026-11-22:
//!   qtm decode: 60 markers/frame, 760 bytes/frame: 4.13 M frames/s on one core
//!   qtm stream Tcp at 1000 Hz, 60 markers, 5 s: 5000 frames (1000.0 Hz), 0 missed, 0 lagged
//!   qtm stream Udp at 1000 Hz, 60 markers, 5 s: 5000 frames (1000.0 Hz), 0 missed, 0 lagged

use calibd_drivers::bench::{decode_60_markers, stream_through_mock};
use calibd_drivers::qtm::StreamTransport;

fn main() {
    let d = decode_60_markers(2.0);
    println!(
        "qtm decode: {} markers/frame, {} bytes/frame, {} frames in 2 s: {:.0} frames/s on one core",
        d.markers, d.frame_bytes, d.frames, d.frames_per_s
    );
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("no runtime: {e}");
            std::process::exit(1);
        }
    };
    for t in [StreamTransport::Tcp, StreamTransport::Udp] {
        match rt.block_on(stream_through_mock(t, 1000.0, 60, 5.0)) {
            Ok(s) => println!(
                "qtm stream {:?} at {} Hz, {} markers, 5 s: {} frames received ({:.1} Hz), {} missed by frame number, {} lost to lag",
                s.transport, s.rate_hz, s.markers, s.frames, s.achieved_hz, s.missed, s.lagged
            ),
            Err(e) => println!("qtm stream {t:?}: failed: {e}"),
        }
    }
}
