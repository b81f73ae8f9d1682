//! The phase method on one image: a Hann-windowed real-to-complex 2-D FFT (planned once per
//! image size and reused), the two fundamental peaks in an annulus around the expected
//! frequency, and for each peak a block of the spectrum around it transformed back (the
//! inverse filter, demodulated and decimated: the phase map on a coarse grid), unwrapped by
//! carrier removal and fitted with a plane by weighted least squares. The planes give the
//! wave vectors (theta, period in pixels) and the phases at the image centre (position).

use std::f64::consts::{FRAC_PI_4, PI, TAU};
use std::sync::Arc;

use calibd_fft::{Complex, Fft, RealToComplex};

use super::{GrayImage, PatternError, PatternPose, wrap_half};

/// Peak power over the annulus's median power below which there is no pattern.
const MIN_PEAK_TO_MEDIAN: f32 = 1000.0;
/// The annulus searched: expected frequency times [1/RANGE, RANGE].
const RANGE: f64 = 1.5;

/// One phase plane: phase = a u + b v + c (rad, u and v in px from the image centre).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// d phase / d u (rad/px).
    pub a: f64,
    /// d phase / d v (rad/px).
    pub b: f64,
    /// Phase at the image centre (rad).
    pub c: f64,
    /// Weighted RMS of the residuals (rad).
    pub residual_rad: f64,
    /// Contrast of the peak: A / mean for a cosine of amplitude A (from the energy around
    /// the peak over the window's).
    pub contrast: f64,
}

/// The fit of one image: the planes of the pattern's X and Y axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhaseFit {
    /// The X axis: wave vector 2 pi/p (cos theta, sin theta).
    pub x: Plane,
    /// The Y axis: wave vector 2 pi/p (-sin theta, cos theta).
    pub y: Plane,
}

impl PhaseFit {
    /// Theta from both planes (rad, not normalised: near the axes' labels).
    pub fn theta_rad(&self) -> f64 {
        let t1 = self.x.b.atan2(self.x.a);
        let t2 = (-self.y.a).atan2(self.y.b);
        t1 + wrap_half(t2 - t1, PI) / 2.0
    }

    /// The measured period (px), mean of both axes.
    pub fn period_px(&self) -> f64 {
        let k = (self.x.a.hypot(self.x.b) + self.y.a.hypot(self.y.b)) / 2.0;
        TAU / k
    }

    /// Worst residual of both planes (rad).
    pub fn residual_rad(&self) -> f64 {
        self.x.residual_rad.max(self.y.residual_rad)
    }

    /// Smaller contrast of both peaks.
    pub fn contrast(&self) -> f64 {
        self.x.contrast.min(self.y.contrast)
    }

    /// Pattern coordinates of the image centre in periods (X/p, Y/p).
    pub fn centre_periods(&self) -> [f64; 2] {
        [self.x.c / TAU, self.y.c / TAU]
    }

    /// The pose of the pattern origin nearest the image centre, theta in (-45, 45] deg,
    /// lengths in the unit of `period`.
    pub fn pose(&self, period: f64) -> PatternPose {
        let theta = self.theta_rad();
        let [xc, yc] = self.centre_periods();
        let (dx, dy) = (wrap_half(xc, 0.5) * period, wrap_half(yc, 0.5) * period);
        let (s, c) = theta.sin_cos();
        // t = -R(theta)(X_c, Y_c): the origin seen from the centre; the lattice is invariant
        // under quarter turns, so theta is normalised afterwards without moving it.
        PatternPose {
            x: -(c * dx - s * dy),
            y: -(s * dx + c * dy),
            theta_rad: wrap_half(theta, FRAC_PI_4),
        }
    }
}

/// Planned FFTs and buffers for images of one size and one expected period.
pub struct PhaseEstimator {
    width: usize,
    height: usize,
    period_px: f64,
    wx: Vec<f32>,
    wy: Vec<f32>,
    r2c: Arc<dyn RealToComplex<f32>>,
    col_fft: Arc<dyn Fft<f32>>,
    block_fft: Arc<dyn Fft<f64>>,
    /// Columns of the spectrum computed (kx in 0..ncols).
    ncols: usize,
    /// Side of the block around a peak.
    m: usize,
    row_in: Vec<f32>,
    row_out: Vec<Complex<f32>>,
    row_scratch: Vec<Complex<f32>>,
    /// Spectrum, column-major: `spec[kx * height + ky]`.
    spec: Vec<Complex<f32>>,
    col_scratch: Vec<Complex<f32>>,
    block: Vec<Complex<f64>>,
    block_t: Vec<Complex<f64>>,
    block_scratch: Vec<Complex<f64>>,
    annulus: Vec<f32>,
    /// Sum of the squared 2-D window.
    w2: f64,
}

impl std::fmt::Debug for PhaseEstimator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PhaseEstimator")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("period_px", &self.period_px)
            .field("block", &self.m)
            .finish()
    }
}

impl PhaseEstimator {
    /// An estimator for `width` x `height` images of a pattern whose period is about
    /// `period_px` pixels (within a factor 1.5).
    pub fn new(width: usize, height: usize, period_px: f64) -> Result<Self, PatternError> {
        if !(period_px >= 4.0) {
            return Err(PatternError::Setup(format!(
                "the period is {period_px:.3} px: at least 4 px are needed (check period_um and pixel_um)"
            )));
        }
        let periods = width.min(height) as f64 / period_px;
        let m = if periods >= 48.0 {
            32
        } else if periods >= 24.0 {
            16
        } else {
            return Err(PatternError::Setup(format!(
                "{width} x {height} px holds {periods:.1} periods of {period_px:.3} px along its short side: at least 24 are needed"
            )));
        };
        let hann = |n: usize| -> Vec<f32> {
            (0..n)
                .map(|i| (PI * (i as f64 + 0.5) / n as f64).sin().powi(2) as f32)
                .collect()
        };
        let outer_kx = (RANGE * width as f64 / period_px).ceil() as usize + m / 2 + 2;
        let ncols = (width / 2 + 1).min(outer_kx);
        let r2c = calibd_fft::real_forward_f32(width);
        let col_fft = calibd_fft::forward_f32(height);
        let block_fft = calibd_fft::inverse_f64(m);
        let row_scratch = r2c.make_scratch_vec();
        let col_scratch = vec![Complex::default(); col_fft.get_inplace_scratch_len()];
        let block_scratch = vec![Complex::default(); block_fft.get_inplace_scratch_len()];
        Ok(Self {
            width,
            height,
            period_px,
            wx: hann(width),
            wy: hann(height),
            row_in: r2c.make_input_vec(),
            row_out: r2c.make_output_vec(),
            row_scratch,
            r2c,
            col_fft,
            block_fft,
            ncols,
            m,
            spec: vec![Complex::default(); ncols * height],
            col_scratch,
            block: vec![Complex::default(); m * m],
            block_t: vec![Complex::default(); m * m],
            block_scratch,
            annulus: Vec::new(),
            w2: 0.0,
        }
        .with_window_energy())
    }

    fn with_window_energy(mut self) -> Self {
        let sq = |w: &[f32]| w.iter().map(|&a| (a as f64).powi(2)).sum::<f64>();
        self.w2 = sq(&self.wx) * sq(&self.wy);
        self
    }

    /// The expected period (px).
    pub fn period_px(&self) -> f64 {
        self.period_px
    }

    /// Fit the phase planes of `img`.
    pub fn fit(&mut self, img: &GrayImage) -> Result<PhaseFit, PatternError> {
        if img.width != self.width || img.height != self.height {
            return Err(PatternError::Setup(format!(
                "image of {} x {} px where {} x {} were expected",
                img.width, img.height, self.width, self.height
            )));
        }
        if img.pixels.len() != img.width * img.height {
            return Err(PatternError::Setup(
                "pixel count does not match the size".into(),
            ));
        }
        let mean = self.spectrum(img);
        let (p1, p2) = self.peaks()?;
        let (px, py) = label_axes(p1, p2, self.width as f64, self.height as f64)?;
        Ok(PhaseFit {
            x: self.plane(px, mean)?,
            y: self.plane(py, mean)?,
        })
    }

    /// Window the image (minus its windowed mean) and fill `spec`; the windowed mean.
    fn spectrum(&mut self, img: &GrayImage) -> f64 {
        let (w, h) = (self.width, self.height);
        let inv = 1.0 / img.full_scale.max(1) as f32;
        let (mut sum, mut wsum) = (0.0f64, 0.0f64);
        for r in 0..h {
            let row = &img.pixels[r * w..(r + 1) * w];
            let s: f32 = row
                .iter()
                .zip(&self.wx)
                .map(|(&p, &wx)| p as f32 * wx)
                .sum();
            sum += s as f64 * self.wy[r] as f64;
        }
        for &a in &self.wy {
            wsum += a as f64;
        }
        wsum *= self.wx.iter().map(|&a| a as f64).sum::<f64>();
        let mean = (sum / wsum) as f32 * inv;
        for r in 0..h {
            let row = &img.pixels[r * w..(r + 1) * w];
            let wy = self.wy[r];
            for ((dst, &p), &wx) in self.row_in.iter_mut().zip(row).zip(&self.wx) {
                *dst = (p as f32 * inv - mean) * wx * wy;
            }
            // The lengths are those the plan made; process cannot fail on them.
            let _ = self.r2c.process_with_scratch(
                &mut self.row_in,
                &mut self.row_out,
                &mut self.row_scratch,
            );
            for kx in 0..self.ncols {
                self.spec[kx * h + r] = self.row_out[kx];
            }
        }
        self.col_fft
            .process_with_scratch(&mut self.spec, &mut self.col_scratch);
        mean as f64
    }

    /// Frequency (cycles/px) of bin (kx, ky) with ky signed.
    fn freq(&self, kx: i64, ky: i64) -> (f64, f64) {
        (
            kx as f64 / self.width as f64,
            ky as f64 / self.height as f64,
        )
    }

    fn signed_ky(&self, ky: usize) -> i64 {
        if 2 * ky >= self.height {
            ky as i64 - self.height as i64
        } else {
            ky as i64
        }
    }

    /// Spectrum at (kx, ky), either sign of kx (Hermitian symmetry).
    fn at(&self, kx: i64, ky: i64) -> Option<Complex<f64>> {
        let h = self.height as i64;
        let (kx, ky, conj) = if kx >= 0 {
            (kx, ky, false)
        } else {
            (-kx, -ky, true)
        };
        if kx as usize >= self.ncols {
            return None;
        }
        let v = self.spec[kx as usize * self.height + ky.rem_euclid(h) as usize];
        let v = Complex::new(v.re as f64, v.im as f64);
        Some(if conj { v.conj() } else { v })
    }

    /// The strongest peak in the annulus and the strongest one at 60..120 deg from it of
    /// the same frequency (within 10 %): bins (kx, ky signed).
    fn peaks(&mut self) -> Result<([i64; 2], [i64; 2]), PatternError> {
        let f0 = 1.0 / self.period_px;
        let (lo2, hi2) = ((f0 / RANGE).powi(2), (f0 * RANGE).powi(2));
        let mut best: Option<([i64; 2], f32)> = None;
        self.annulus.clear();
        for kx in 0..self.ncols {
            for ky in 0..self.height {
                let ks = self.signed_ky(ky);
                let (fx, fy) = self.freq(kx as i64, ks);
                let f2 = fx * fx + fy * fy;
                if f2 < lo2 || f2 > hi2 {
                    continue;
                }
                let p = self.spec[kx * self.height + ky].norm_sqr();
                self.annulus.push(p);
                if best.is_none_or(|b| p > b.1) {
                    best = Some(([kx as i64, ks], p));
                }
            }
        }
        let n = self.annulus.len();
        if n < 16 {
            return Err(PatternError::NoPattern(
                "the frequency annulus is empty".into(),
            ));
        }
        let median = *self
            .annulus
            .select_nth_unstable_by(n / 2, |a, b| a.total_cmp(b))
            .1;
        let Some((p1, pow1)) = best else {
            return Err(PatternError::NoPattern(
                "the frequency annulus is empty".into(),
            ));
        };
        let ratio = |p: f32| p / median.max(f32::MIN_POSITIVE);
        if !(ratio(pow1) >= MIN_PEAK_TO_MEDIAN) {
            return Err(PatternError::NoPattern(format!(
                "the strongest frequency near a period of {:.2} px stands only {:.0} times above the background (at least {MIN_PEAK_TO_MEDIAN:.0} needed)",
                self.period_px,
                ratio(pow1)
            )));
        }
        let (f1x, f1y) = self.freq(p1[0], p1[1]);
        let f1 = f1x.hypot(f1y);
        let mut second: Option<([i64; 2], f32)> = None;
        for kx in 0..self.ncols {
            for ky in 0..self.height {
                let ks = self.signed_ky(ky);
                let (fx, fy) = self.freq(kx as i64, ks);
                let f = fx.hypot(fy);
                if (f - f1).abs() > 0.1 * f1 || (fx * f1x + fy * f1y).abs() > 0.5 * f * f1 {
                    continue;
                }
                let p = self.spec[kx * self.height + ky].norm_sqr();
                if second.is_none_or(|b| p > b.1) {
                    second = Some(([kx as i64, ks], p));
                }
            }
        }
        match second {
            Some((p2, pow2)) if ratio(pow2) >= MIN_PEAK_TO_MEDIAN => Ok((p1, p2)),
            _ => Err(PatternError::NoPattern(format!(
                "a grating of period {:.2} px but no second one across it (not a square grid)",
                1.0 / f1
            ))),
        }
    }

    /// The phase plane of the peak at bin `k` (the block around it, inverse-transformed).
    fn plane(&mut self, k: [i64; 2], mean: f64) -> Result<Plane, PatternError> {
        let m = self.m;
        let half = (m / 2) as i64;
        for n in -half..half {
            for j in -half..half {
                let v = self.at(k[0] + j, k[1] + n).ok_or_else(|| {
                    PatternError::NoPattern("a peak too close to the spectrum's edge".into())
                })?;
                self.block[n.rem_euclid(m as i64) as usize * m + j.rem_euclid(m as i64) as usize] =
                    v;
            }
        }
        // The peak's energy (Parseval, unnormalised DFT: W H (A/2)^2 sum w^2 for a cosine of
        // amplitude A, whatever its sub-bin frequency), before the transform overwrites it.
        let energy: f64 = self.block.iter().map(|v| v.norm_sqr()).sum();
        // 2-D inverse FFT: rows, transpose, rows (result transposed: block_t[c * m + r]).
        self.block_fft
            .process_with_scratch(&mut self.block, &mut self.block_scratch);
        for r in 0..m {
            for c in 0..m {
                self.block_t[c * m + r] = self.block[r * m + c];
            }
        }
        self.block_fft
            .process_with_scratch(&mut self.block_t, &mut self.block_scratch);
        let z = |r: usize, c: usize| self.block_t[c * m + r];
        // Carrier removal: the mean phase steps along each axis, then the phase around them.
        let (mut sx, mut sy) = (Complex::<f64>::default(), Complex::<f64>::default());
        for r in 0..m {
            for c in 0..m {
                if c + 1 < m {
                    sx += z(r, c + 1) * z(r, c).conj();
                }
                if r + 1 < m {
                    sy += z(r + 1, c) * z(r, c).conj();
                }
            }
        }
        let (ax, ay) = (sx.arg(), sy.arg());
        let mut sref = Complex::<f64>::default();
        for r in 0..m {
            for c in 0..m {
                sref += z(r, c) * Complex::from_polar(1.0, -(ax * c as f64 + ay * r as f64));
            }
        }
        let aref = sref.arg();
        let (w, h) = (self.width as f64, self.height as f64);
        let (cu, cv) = ((w - 1.0) / 2.0, (h - 1.0) / 2.0);
        let (step_c, step_r) = (w / m as f64, h / m as f64);
        // Weighted least squares of phase = a u + b v + c, weights = modulus.
        let mut ata = [[0.0f64; 3]; 3];
        let mut atb = [0.0f64; 3];
        let mut samples = Vec::with_capacity(m * m);
        for r in 0..m {
            for c in 0..m {
                let v = z(r, c);
                let wgt = v.norm();
                let carrier = ax * c as f64 + ay * r as f64 + aref;
                let demod = carrier + wrap_half(v.arg() - carrier, PI);
                let (pc, pr) = (c as f64 * step_c, r as f64 * step_r);
                let phase = demod + TAU * (k[0] as f64 * pc / w + k[1] as f64 * pr / h);
                let row = [pc - cu, pr - cv, 1.0];
                for i in 0..3 {
                    for j in 0..3 {
                        ata[i][j] += wgt * row[i] * row[j];
                    }
                    atb[i] += wgt * row[i] * phase;
                }
                samples.push((row, phase, wgt));
            }
        }
        let sol = solve3(ata, atb).ok_or_else(|| {
            PatternError::NoPattern("the phase plane is degenerate (no signal at the peak)".into())
        })?;
        let (mut rss, mut wsum) = (0.0, 0.0);
        for (row, phase, wgt) in &samples {
            let e = phase - (sol[0] * row[0] + sol[1] * row[1] + sol[2]);
            rss += wgt * e * e;
            wsum += wgt;
        }
        Ok(Plane {
            a: sol[0],
            b: sol[1],
            c: sol[2],
            residual_rad: (rss / wsum.max(f64::MIN_POSITIVE)).sqrt(),
            contrast: if mean > 0.0 {
                2.0 * (energy / (self.w2 * (self.width * self.height) as f64)).sqrt() / mean
            } else {
                0.0
            },
        })
    }
}

/// Which of the peaks (or their conjugates) is the X axis (angle in (-45, 45] deg) and
/// which the Y axis (angle in (45, 135] deg).
fn label_axes(
    p1: [i64; 2],
    p2: [i64; 2],
    width: f64,
    height: f64,
) -> Result<([i64; 2], [i64; 2]), PatternError> {
    let (mut x, mut y) = (None, None);
    for p in [p1, p2] {
        let a = (p[1] as f64 / height).atan2(p[0] as f64 / width);
        let neg = [-p[0], -p[1]];
        let q = wrap_half(a, PI); // (-180, 180]
        if q > -FRAC_PI_4 && q <= FRAC_PI_4 {
            x = x.or(Some(p));
        } else if q > 3.0 * FRAC_PI_4 || q <= -3.0 * FRAC_PI_4 {
            x = x.or(Some(neg));
        } else if q > FRAC_PI_4 {
            y = y.or(Some(p));
        } else {
            y = y.or(Some(neg));
        }
    }
    match (x, y) {
        (Some(x), Some(y)) => Ok((x, y)),
        _ => Err(PatternError::NoPattern(
            "the two gratings are not a quarter turn apart".into(),
        )),
    }
}

/// Solve a symmetric 3 x 3 system (Cramer's rule); `None` if singular.
fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: &[[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(&a);
    let scale = a[0][0] * a[1][1] * a[2][2];
    if !(d.abs() > 1e-12 * scale.abs()) {
        return None;
    }
    let mut x = [0.0; 3];
    for (k, xk) in x.iter_mut().enumerate() {
        let mut m = a;
        for i in 0..3 {
            m[i][k] = b[i];
        }
        *xk = det(&m) / d;
    }
    Some(x)
}
