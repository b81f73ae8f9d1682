//! Images of a pattern at a known pose, for tests, benchmarks and the twin: the cosine
//! pattern averaged over each pixel (100 % fill factor, exact for a cosine), or bright dots
//! sampled at pixel centres; Gaussian noise from a seed, quantised to 8 or 16 bits.

use super::{GrayImage, PatternError, PatternKind, PatternPose, code};
use crate::util::Rng;

/// What to render.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderSpec {
    /// Periodic (cosine) or encoded (dots).
    pub kind: PatternKind,
    /// Pose of the pattern frame in the camera frame (x, y in um).
    pub pose: PatternPose,
    /// Period of the pattern (um).
    pub period_um: f64,
    /// Pixel size in the object plane (um).
    pub pixel_um: f64,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// 8 or 16.
    pub bit_depth: u8,
    /// Standard deviation of the Gaussian noise as a fraction of full scale.
    pub noise_frac: f64,
    /// Seed of the noise.
    pub seed: u64,
}

/// Dark ground and bright dots of the encoded pattern (fractions of full scale).
const DOT_GROUND: f64 = 0.1;
const DOT_PEAK: f64 = 0.9;

/// Render `spec`.
pub fn render(spec: &RenderSpec) -> Result<GrayImage, PatternError> {
    let full_scale: u16 = match spec.bit_depth {
        8 => 255,
        16 => u16::MAX,
        b => return Err(PatternError::Setup(format!("bit depth {b}: 8 or 16"))),
    };
    if !(spec.period_um > 0.0 && spec.pixel_um > 0.0 && spec.noise_frac >= 0.0) {
        return Err(PatternError::Setup(
            "period, pixel size must be positive and noise not negative".into(),
        ));
    }
    if spec.width == 0 || spec.height == 0 {
        return Err(PatternError::Setup("empty image".into()));
    }
    let p_px = spec.period_um / spec.pixel_um;
    let (s, c) = spec.pose.theta_rad.sin_cos();
    // Pattern coordinates (in periods) of pixel (u, v) from the centre: R(-theta)((u, v) - t).
    let (tx, ty) = (spec.pose.x / spec.pixel_um, spec.pose.y / spec.pixel_um);
    let (cu, cv) = (
        (spec.width as f64 - 1.0) / 2.0,
        (spec.height as f64 - 1.0) / 2.0,
    );
    let seq = matches!(spec.kind, PatternKind::Encoded).then(code::sequence);
    // Pixel averages of cos(k . r): sinc of half the wave vector's components (rad/px).
    let k = std::f64::consts::TAU / p_px;
    let sinc = |z: f64| if z.abs() < 1e-12 { 1.0 } else { z.sin() / z };
    let gx = sinc(k * c / 2.0) * sinc(k * s / 2.0);
    let gy = sinc(-k * s / 2.0) * sinc(k * c / 2.0);
    let mut rng = Rng::new(spec.seed);
    let fs = full_scale as f64;
    let tau = std::f64::consts::TAU;
    // Along a row the pattern coordinates advance by (c, -s) / p_px per column, so the
    // cosines of 2 pi xp and 2 pi yp advance by a fixed rotation: two products per pixel
    // instead of two `cos` calls (each row starts from exact values; the drift over a row
    // is ~1e-13, far below the 16-bit quantum).
    let (dx, dy) = (c / p_px, -s / p_px);
    let (step_x, step_y) = (Turn::at(tau * dx), Turn::at(tau * dy));
    let mut pixels = Vec::with_capacity(spec.width * spec.height);
    for row in 0..spec.height {
        let dv = row as f64 - cv - ty;
        let du0 = -cu - tx;
        let (xp0, yp0) = ((c * du0 + s * dv) / p_px, (-s * du0 + c * dv) / p_px);
        let (mut wx, mut wy) = (Turn::at(tau * xp0), Turn::at(tau * yp0));
        for col in 0..spec.width {
            let du = col as f64 - cu - tx;
            let xp = (c * du + s * dv) / p_px;
            let yp = (-s * du + c * dv) / p_px;
            let i = match &seq {
                None => 0.5 + 0.25 * gx * wx.cos + 0.25 * gy * wy.cos,
                Some(seq) => dot(seq, xp, yp, wx.cos, wy.cos),
            };
            wx = wx.then(step_x);
            wy = wy.then(step_y);
            // A noiseless frame (the reader's bias correction renders them) draws nothing.
            let noise = if spec.noise_frac > 0.0 {
                spec.noise_frac * fs * rng.normal()
            } else {
                0.0
            };
            let noisy = i * fs + noise;
            pixels.push(noisy.round().clamp(0.0, fs) as u16);
        }
    }
    Ok(GrayImage {
        width: spec.width,
        height: spec.height,
        full_scale,
        pixels,
    })
}

/// A point on the unit circle: the cosine and sine of an angle, turned by products.
#[derive(Debug, Clone, Copy)]
struct Turn {
    cos: f64,
    sin: f64,
}

impl Turn {
    fn at(angle: f64) -> Self {
        let (sin, cos) = angle.sin_cos();
        Self { cos, sin }
    }

    /// This angle plus `step`'s.
    fn then(self, step: Turn) -> Self {
        Self {
            cos: self.cos * step.cos - self.sin * step.sin,
            sin: self.sin * step.cos + self.cos * step.sin,
        }
    }
}

/// Intensity of the encoded pattern at (xp, yp) periods, given cos(2 pi xp) and
/// cos(2 pi yp): the nearest dot's raised-cosine bump (zero with zero slope at the cell's
/// border) if that dot is present. The bump of the offset d = xp - i from the dot is
/// (1 + cos 2 pi d)^2 / 4, and cos 2 pi d = cos 2 pi xp for the integer i.
fn dot(seq: &[bool], xp: f64, yp: f64, cos_x: f64, cos_y: f64) -> f64 {
    if !code::dot_present(seq, nearest(xp), nearest(yp)) {
        return DOT_GROUND;
    }
    let bump = |c: f64| {
        let h = 0.5 * (1.0 + c);
        h * h
    };
    DOT_GROUND + (DOT_PEAK - DOT_GROUND) * bump(cos_x) * bump(cos_y)
}

/// The integer nearest `x` (halves away from zero, as `f64::round`), without a libm call.
fn nearest(x: f64) -> i64 {
    let t = x.abs() + 0.5;
    let n = t as i64;
    if x < 0.0 { -n } else { n }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rounds_as_f64_round() {
        for x in [
            -2.5,
            -1.5,
            -0.5,
            -0.49,
            0.0,
            0.49,
            0.5,
            1.5,
            2.5,
            3.7,
            -3.7,
            1e9 + 0.5,
        ] {
            assert_eq!(nearest(x), x.round() as i64, "{x}");
        }
    }

    #[test]
    fn turned_cosines_match_direct_ones_over_a_row() {
        let (x0, dx) = (-123.456_f64, 0.123_456_7_f64);
        let tau = std::f64::consts::TAU;
        let (mut w, step) = (Turn::at(tau * x0), Turn::at(tau * dx));
        for k in 0..4096 {
            let direct = (tau * (x0 + k as f64 * dx)).cos();
            assert!((w.cos - direct).abs() < 1e-11, "{k}: {} vs {direct}", w.cos);
            w = w.then(step);
        }
    }
}
