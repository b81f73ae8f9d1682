//! Camera frame sources for a microscope whose pose calibd computes itself: a network
//! source speaking `calibd-frames/1` (a lab's camera bridge, or the mock camera) and a
//! folder source reading numbered image files as they appear. Both hand out raw frames; the
//! pose is computed in calibd's lab layer (the phase method), never here.
//!
//! # Protocol (`calibd-frames/1`)
//!
//! Requests are ASCII lines ended by LF (a CR before it is ignored), at most 128 bytes; one
//! reply per request, in order:
//!
//! | request                          | reply                                                      |
//! |----------------------------------|------------------------------------------------------------|
//! | `ID?`                            | `ID <text>`                                                |
//! | `SET <exposure_us> <frame_rate_hz>` | `OK` (the camera now runs with these settings)          |
//! | `FRAME?`                         | `FRAME <seq> <width> <height> <bit_depth> <exposure_us>` then the pixels |
//! | anything                         | `ERR <code> <text>`                                        |
//!
//! A `FRAME` header line is followed by exactly `width * height` pixels, row after row,
//! one byte each for `bit_depth` 8, two bytes little-endian each for 9..=16 (values below
//! `2^bit_depth`). `seq` counts the camera's frames and grows with every reply (a repeated
//! `seq` is a stale frame); the frame is one acquired after the request arrived. Width and
//! height are 1..=16384. Error codes: `1` unknown request, `2` no frame (camera not
//! acquiring), `3` camera busy, `4` internal error, `5` settings refused.
//!
//! Example: `FRAME?\n` -> `FRAME 42 384 384 16 800\n` + 294912 bytes.

pub mod codec;
pub mod driver;
pub mod folder;
pub mod mock;

pub use codec::{CameraCodec, Frame, Reply, Request};
pub use driver::{CameraConfig, CameraHandle, CameraIdentity};
pub use folder::FolderCamera;

use crate::error::DriverError;
use crate::link::BoxFuture;

/// One frame as a source delivers it: raw pixels, or an image file's bytes (PNG/TIFF,
/// decoded by the caller).
#[derive(Debug, Clone, PartialEq)]
pub enum RawFrame {
    /// Pixels from the network source.
    Pixels(Frame),
    /// A file from the folder source.
    File {
        /// Frame number from the file name.
        seq: u64,
        /// The file's name.
        name: String,
        /// Its bytes.
        bytes: Vec<u8>,
    },
}

impl RawFrame {
    /// The frame counter.
    pub fn seq(&self) -> u64 {
        match self {
            RawFrame::Pixels(f) => f.seq,
            RawFrame::File { seq, .. } => *seq,
        }
    }
}

/// Where a microscope's frames come from.
pub trait FrameSource: Send + Sync + std::fmt::Debug {
    /// The next fresh frame.
    fn grab(&self) -> BoxFuture<'_, Result<RawFrame, DriverError>>;
}
