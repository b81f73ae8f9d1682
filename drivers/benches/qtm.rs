//! QTM benchmarks (issue 6): frame decoding with 60 markers on one core, and a 1 kHz stream
//! through the QTM mock over loopback with no frame lost.
//! Run: `cargo bench -p calibd-drivers --bench qtm`.
//!
//! Figures on the 2-core dev machine (release profile), 2026-11-22:
//!   qtm decode: 60 markers/frame, 760 bytes/frame: 4.13 M frames/s on one core
//!   qtm stream Tcp at 1000 Hz, 60 markers, 5 s: 5000 frames (1000.0 Hz), 0 missed, 0 lagged
//!   qtm stream Udp at 1000 Hz, 60 markers, 5 s: 5000 frames (1000.0 Hz), 0 missed, 0 lagged

fn main() {
    if let Err(e) = calibd_drivers::bench::run_and_print(&mut std::io::stdout()) {
        eprintln!("bench failed: {e}");
        std::process::exit(1);
    }
}
