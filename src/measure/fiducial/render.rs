//! A wide-field image of markers at known poses, for tests and the twin: the cells
//! averaged over each pixel (8 x 8 jittered samples: unbiased, where a regular grid would
//! put every edge on a 1/8 px step), a dark ground, Gaussian noise from a seed, 16-bit.

use super::{FiducialError, GRID, MarkerPose, cells};
use crate::measure::pattern::GrayImage;
use crate::util::Rng;

/// Ground and bright cells (fractions of full scale).
const GROUND: f64 = 0.1;
const BRIGHT: f64 = 0.9;
/// Samples per pixel side.
const SUB: usize = 8;

/// What to render.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldSpec {
    /// The markers.
    pub markers: Vec<MarkerPose>,
    /// Side of one cell (um).
    pub cell_um: f64,
    /// Pixel size (um).
    pub pixel_um: f64,
    /// Image frame position of pixel (0, 0)'s centre (um).
    pub origin_um: [f64; 2],
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Noise sigma, fraction of full scale.
    pub noise_frac: f64,
    /// Seed of the noise.
    pub seed: u64,
}

/// Render `spec` as a 16-bit image.
pub fn render_field(spec: &FieldSpec) -> Result<GrayImage, FiducialError> {
    if !(spec.cell_um > 0.0 && spec.pixel_um > 0.0 && spec.noise_frac >= 0.0) {
        return Err(FiducialError::Setup(
            "cell_um and pixel_um must be positive, noise_frac not negative".into(),
        ));
    }
    let fs = f64::from(u16::MAX);
    let mut rng = Rng::new(spec.seed);
    // The noisy ground first; the markers' light is added on top.
    let mut pixels: Vec<u16> = (0..spec.width * spec.height)
        .map(|_| {
            ((GROUND + spec.noise_frac * rng.normal()) * fs)
                .round()
                .clamp(0.0, fs) as u16
        })
        .collect();
    let half = spec.cell_um * GRID as f64 / 2.0;
    for m in &spec.markers {
        let c = cells(m.id)?;
        let (s, co) = m.theta_rad.sin_cos();
        // Pixels whose centre is within the marker's circumscribed circle (+1 px).
        let reach = half * std::f64::consts::SQRT_2 + spec.pixel_um;
        let px = |v: f64, o: f64| (v - o) / spec.pixel_um;
        let (c0, c1) = (
            px(m.x_um - reach, spec.origin_um[0]).floor().max(0.0) as usize,
            (px(m.x_um + reach, spec.origin_um[0]).ceil().max(0.0) as usize).min(spec.width),
        );
        let (r0, r1) = (
            px(m.y_um - reach, spec.origin_um[1]).floor().max(0.0) as usize,
            (px(m.y_um + reach, spec.origin_um[1]).ceil().max(0.0) as usize).min(spec.height),
        );
        for row in r0..r1 {
            for col in c0..c1 {
                let mut on = 0usize;
                for sy in 0..SUB {
                    for sx in 0..SUB {
                        let (jx, jy) = (rng.uniform(), rng.uniform());
                        let x = spec.origin_um[0]
                            + (col as f64 + (sx as f64 + jx) / SUB as f64 - 0.5) * spec.pixel_um;
                        let y = spec.origin_um[1]
                            + (row as f64 + (sy as f64 + jy) / SUB as f64 - 0.5) * spec.pixel_um;
                        let (dx, dy) = (x - m.x_um, y - m.y_um);
                        // Marker coordinates from its corner, in cells.
                        let u = (co * dx + s * dy + half) / spec.cell_um;
                        let v = (-s * dx + co * dy + half) / spec.cell_um;
                        if u >= 0.0 && v >= 0.0 && u < GRID as f64 && v < GRID as f64 {
                            on += usize::from(c[v as usize][u as usize]);
                        }
                    }
                }
                if on > 0 {
                    let f = on as f64 / (SUB * SUB) as f64;
                    let p = &mut pixels[row * spec.width + col];
                    *p = (f64::from(*p) + f * (BRIGHT - GROUND) * fs)
                        .round()
                        .clamp(0.0, fs) as u16;
                }
            }
        }
    }
    Ok(GrayImage {
        width: spec.width,
        height: spec.height,
        full_scale: u16::MAX,
        pixels,
    })
}
