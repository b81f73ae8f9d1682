//! Pose (x, y, theta) of a periodic 2-D pattern seen by a camera, by the phase method
//! (Guelpa et al., Sensors 2014; Andre et al. 2020): the image's spectrum, its two
//! fundamental peaks, one phase plane per peak, and the pose from the planes. Pure maths on
//! pixels in memory; image files are read and written in [`codec`].
//!
//! # Conventions
//! - Camera frame: origin at the image centre ((W-1)/2, (H-1)/2 in pixel coordinates), x
//!   along increasing columns, y along increasing rows, theta from x toward y.
//! - The pose (x, y, theta) places the pattern point (X, Y) at (x, y) + R(theta)(X, Y).
//! - The pattern frame's origin is at an intensity maximum: where
//!   I = 0.5 + 0.25 cos(2 pi X/p) + 0.25 cos(2 pi Y/p) peaks, or a dot's centre.
//! - Positions are in the pattern's own length unit (the period `p` is the ruler; the pixel
//!   size only predicts where to look in the spectrum), so x, y are in um for `period_um`.
//! - A periodic pattern gives the position modulo the period and theta modulo 90 deg: the
//!   first image gets theta in (-45, 45] deg and the origin nearest the image centre; later
//!   images of a [`Track`] continue it without jumps (unwrapped position and angle).
//! - The encoded pattern ([`PatternKind::Encoded`]) gives the absolute position over its
//!   whole extent (see [`code`]); it must be seen with |theta| < 45 deg.

pub mod code;
pub mod codec;
pub mod decode;
pub mod phase;
pub mod reader;
pub mod render;
pub mod track;

#[cfg(test)]
mod tests;

pub use decode::decode_absolute;
pub use phase::{PhaseEstimator, PhaseFit};
pub use reader::{PatternSetup, PoseReader};
pub use render::{RenderSpec, render};
pub use track::Track;

/// Which pattern: a square grid of period p along both axes.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum PatternKind {
    /// I = 0.5 + 0.25 cos(2 pi X/p) + 0.25 cos(2 pi Y/p): position modulo the period.
    Periodic,
    /// Bright dots on a dark ground, some missing to code the period's index
    /// ([`code`]): absolute position.
    Encoded,
}

/// A grayscale image: `pixels` row after row, values in `0..=full_scale`.
#[derive(Debug, Clone, PartialEq)]
pub struct GrayImage {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// The value of a saturated pixel (255 for 8-bit, 65535 for 16-bit).
    pub full_scale: u16,
    /// Row-major pixel values.
    pub pixels: Vec<u16>,
}

/// A pose of the pattern frame in the camera frame.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PatternPose {
    /// x of the pattern origin (pattern length unit, e.g. um).
    pub x: f64,
    /// y of the pattern origin.
    pub y: f64,
    /// Rotation from camera x toward camera y (rad).
    pub theta_rad: f64,
}

/// What went wrong measuring a pattern.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PatternError {
    /// The image has no (square, periodic) pattern at the expected period.
    #[error("no periodic pattern: {0}")]
    NoPattern(String),
    /// Sizes, period or pixel size that cannot work.
    #[error("{0}")]
    Setup(String),
    /// An image file that cannot be decoded as 8/16-bit grayscale.
    #[error("{0}")]
    Decode(String),
    /// The code of an encoded pattern cannot be read.
    #[error("encoded pattern: {0}")]
    Code(String),
}

/// `a` wrapped into (-half, half] (`half` > 0).
pub(crate) fn wrap_half(a: f64, half: f64) -> f64 {
    let p = 2.0 * half;
    let r = a - p * (a / p).round();
    if r <= -half { r + p } else { r }
}
