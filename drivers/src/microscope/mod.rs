//! Microscope pose source: a camera over the robot's platform that reports the planar pose
//! of a pattern, spoken over a small TCP line protocol of calibd's design (the real
//! microscope's vision PC runs a server speaking it).
//!
//! # Protocol (`calibd-pose/1`)
//!
//! ASCII lines ended by LF (a CR before the LF is ignored), at most 128 bytes, one reply per
//! request, requests answered in order:
//!
//! | request   | reply                                   | meaning                                   |
//! |-----------|-----------------------------------------|-------------------------------------------|
//! | `ID?`     | `ID <text>`                             | identification (free text, printable)     |
//! | `POSE?`   | `POSE <seq> <x_m> <y_m> <theta_rad>`    | a fresh image's pose of the pattern       |
//! | anything  | `ERR <code> <text>`                     | the request failed                        |
//!
//! `seq` is the image counter (u64, grows by at least one per reply: a repeated `seq` is a
//! stale image); `x_m`, `y_m` are metres and `theta_rad` radians of the pattern frame in the
//! camera frame, as decimal floats (`1.25e-3` allowed). Error codes: `1` unknown request,
//! `2` pattern not found in the image, `3` camera busy or not ready, `4` internal error.
//!
//! Example: `POSE?\n` -> `POSE 17 1.0125e-3 -2.5e-4 0.00123\n`.

pub mod codec;
pub mod driver;
pub mod mock;

pub use codec::{MicroscopeCodec, Reply, Request};
pub use driver::{MicroscopeConfig, MicroscopeHandle, MicroscopeIdentity, PoseReading};
