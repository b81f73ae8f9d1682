//! A sequence of images of one periodic pattern: the first pose is the origin nearest the
//! image centre with theta in (-45, 45] deg; each later pose is the lattice point and the
//! quarter-turn representative of theta nearest the previous pose (the same lattice point of
//! the pattern, followed from image to image), so the track is
//! continuous as long as the pattern moves less than half a period and turns less than
//! 45 deg between images.

use std::f64::consts::FRAC_PI_4;

use super::{PatternPose, wrap_half};

/// The unwrapped track.
#[derive(Debug, Clone, Default)]
pub struct Track {
    last: Option<PatternPose>,
}

impl Track {
    /// An empty track.
    pub fn new() -> Self {
        Self::default()
    }

    /// Continue the track with `raw`, a pose of any lattice point (pattern length unit)
    /// with any quarter-turn of theta; `period` in the same unit.
    pub fn push(&mut self, raw: PatternPose, period: f64) -> PatternPose {
        let pose = match self.last {
            None => raw,
            Some(prev) => {
                let theta = prev.theta_rad + wrap_half(raw.theta_rad - prev.theta_rad, FRAC_PI_4);
                let (s, c) = theta.sin_cos();
                let (dx, dy) = (raw.x - prev.x, raw.y - prev.y);
                // The step in the pattern's axes, taken to the nearest lattice point.
                let (px, py) = (
                    wrap_half(c * dx + s * dy, period / 2.0),
                    wrap_half(-s * dx + c * dy, period / 2.0),
                );
                PatternPose {
                    x: prev.x + c * px - s * py,
                    y: prev.y + s * px + c * py,
                    theta_rad: theta,
                }
            }
        };
        self.last = Some(pose);
        pose
    }
}
