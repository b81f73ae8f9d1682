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
    let mut pixels = Vec::with_capacity(spec.width * spec.height);
    for row in 0..spec.height {
        let dv = row as f64 - cv - ty;
        for col in 0..spec.width {
            let du = col as f64 - cu - tx;
            let xp = (c * du + s * dv) / p_px;
            let yp = (-s * du + c * dv) / p_px;
            let i = match &seq {
                None => {
                    0.5 + 0.25 * gx * (std::f64::consts::TAU * xp).cos()
                        + 0.25 * gy * (std::f64::consts::TAU * yp).cos()
                }
                Some(seq) => dot(seq, xp, yp),
            };
            let noisy = i * fs + spec.noise_frac * fs * rng.normal();
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

/// Intensity of the encoded pattern at (xp, yp) periods: the nearest dot's raised-cosine
/// bump (zero with zero slope at the cell's border) if that dot is present.
fn dot(seq: &[bool], xp: f64, yp: f64) -> f64 {
    let (i, j) = (xp.round(), yp.round());
    if !code::dot_present(seq, i as i64, j as i64) {
        return DOT_GROUND;
    }
    let bump = |d: f64| {
        let h = 0.5 * (1.0 + (std::f64::consts::TAU * d).cos());
        h * h
    };
    DOT_GROUND + (DOT_PEAK - DOT_GROUND) * bump(xp - i) * bump(yp - j)
}
