//! Digital Butterworth low-pass filters by the bilinear transform with pre-warping, and
//! zero-phase filtering: forward then backward through the filter, with odd-extension padding
//! and steady-state initial conditions (the scheme of MATLAB's and SciPy's `filtfilt`), so the
//! filtered signal has no lag and the gain is |H|^2.

use nalgebra::Complex;

use super::SignalError;

/// A digital filter as a cascade of second-order sections (biquads), each
/// `(b0 + b1 z^-1 + b2 z^-2) / (1 + a1 z^-1 + a2 z^-2)` with unit gain at DC. Unlike the
/// expanded transfer function `b(z) / a(z)`, whose coefficients lose the poles to rounding
/// as the order grows and the cutoff falls, each section holds one conjugate pole pair.
#[derive(Debug, Clone, PartialEq)]
pub struct Filter {
    /// `[b0, b1, b2, a1, a2]` per section (`a0 = 1`); a first-order section has `b2 = a2 = 0`.
    pub sections: Vec<[f64; 5]>,
}

/// Order-`order` Butterworth low-pass with cutoff `cutoff_hz` (-3 dB) at `rate_hz`: the
/// analog poles pre-warped and mapped by the bilinear transform, paired into sections.
pub fn butterworth_lowpass(
    order: usize,
    cutoff_hz: f64,
    rate_hz: f64,
) -> Result<Filter, SignalError> {
    if !(1..=10).contains(&order) {
        return Err(SignalError::Design(format!("order {order}: use 1..=10")));
    }
    if !(rate_hz > 0.0 && cutoff_hz > 0.0 && cutoff_hz < 0.5 * rate_hz) {
        return Err(SignalError::Design(format!(
            "cutoff {cutoff_hz} Hz must lie in (0, {}) for a {rate_hz} Hz rate",
            0.5 * rate_hz
        )));
    }
    Ok(Filter {
        sections: z_poles(order, cutoff_hz, rate_hz)
            .iter()
            .map(|p| {
                if p.im.abs() < 1e-300 {
                    // Real pole: (1 + z^-1) / (1 - p z^-1), unit DC gain.
                    let g = (1.0 - p.re) / 2.0;
                    [g, g, 0.0, -p.re, 0.0]
                } else {
                    // Conjugate pair: (1 + z^-1)^2 / (1 - 2 Re p z^-1 + |p|^2 z^-2).
                    let (a1, a2) = (-2.0 * p.re, p.norm_sqr());
                    let g = (1.0 + a1 + a2) / 4.0;
                    [g, 2.0 * g, g, a1, a2]
                }
            })
            .collect(),
    })
}

/// The digital poles in the upper half plane (one per section), the real pole last.
fn z_poles(order: usize, cutoff_hz: f64, rate_hz: f64) -> Vec<Complex<f64>> {
    let n = order as f64;
    let fs2 = 2.0 * rate_hz;
    // Pre-warped analog cutoff (rad/s).
    let wc = fs2 * (std::f64::consts::PI * cutoff_hz / rate_hz).tan();
    let mut poles: Vec<Complex<f64>> = (0..order.div_ceil(2))
        .map(|k| {
            let theta = std::f64::consts::PI * (2.0 * k as f64 + n + 1.0) / (2.0 * n);
            let mut s = Complex::new(theta.cos(), theta.sin()) * wc;
            if 2 * k + 1 == order {
                s.im = 0.0; // the real pole of an odd order, exactly on the axis
            }
            (Complex::new(fs2, 0.0) + s) / (Complex::new(fs2, 0.0) - s)
        })
        .collect();
    poles.sort_by(|a, b| b.im.abs().total_cmp(&a.im.abs()));
    poles
}

impl Filter {
    /// The filter's order (poles).
    pub fn order(&self) -> usize {
        self.sections
            .iter()
            .map(|s| if s[4] == 0.0 && s[2] == 0.0 { 1 } else { 2 })
            .sum()
    }

    /// Gain |H(e^{i w})| at `freq_hz` for sampling rate `rate_hz`.
    pub fn gain(&self, freq_hz: f64, rate_hz: f64) -> f64 {
        let w = 2.0 * std::f64::consts::PI * freq_hz / rate_hz;
        let z1 = Complex::from_polar(1.0, -w);
        let z2 = z1 * z1;
        self.sections
            .iter()
            .map(|s| {
                let num = z2 * s[2] + z1 * s[1] + s[0];
                let den = z2 * s[4] + z1 * s[3] + 1.0;
                (num / den).norm()
            })
            .product()
    }

    /// Run the cascade over `x` in place (direct form II transposed per section), each
    /// section starting in the steady state of a constant input `x0` (SciPy's
    /// `sosfilt_zi`: every section has unit DC gain, so each sees `x0`).
    fn run(&self, x: &mut [f64], x0: f64) {
        for s in &self.sections {
            let [b0, b1, b2, a1, a2] = *s;
            // Steady state of y = x = x0: z1 = (b2 - a2) x0, z0 = (b1 - a1) x0 + z1.
            let mut z1 = (b2 - a2) * x0;
            let mut z0 = (b1 - a1) * x0 + z1;
            for v in x.iter_mut() {
                let xi = *v;
                let y = b0 * xi + z0;
                z0 = b1 * xi - a1 * y + z1;
                z1 = b2 * xi - a2 * y;
                *v = y;
            }
        }
    }
}

/// Zero-phase filtering of `x` (SciPy's `sosfiltfilt`): odd-extension padding of
/// `3 * (order + 1)` samples at each end, forward pass from the steady state of the first
/// value, backward pass likewise.
pub fn filtfilt(f: &Filter, x: &[f64]) -> Result<Vec<f64>, SignalError> {
    let pad = 3 * (f.order() + 1);
    if x.len() <= pad {
        return Err(SignalError::TooShort {
            len: x.len(),
            needed: pad + 1,
        });
    }
    let n = x.len();
    let mut ext = Vec::with_capacity(n + 2 * pad);
    ext.extend((1..=pad).rev().map(|k| 2.0 * x[0] - x[k]));
    ext.extend_from_slice(x);
    ext.extend((1..=pad).map(|k| 2.0 * x[n - 1] - x[n - 1 - k]));
    let first = ext[0];
    f.run(&mut ext, first);
    ext.reverse();
    let first = ext[0];
    f.run(&mut ext, first);
    ext.reverse();
    Ok(ext[pad..pad + n].to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn design_has_the_butterworth_response() {
        let f = butterworth_lowpass(5, 5.0, 100.0).unwrap();
        assert_eq!((f.sections.len(), f.order()), (3, 5));
        assert!((f.gain(0.0, 100.0) - 1.0).abs() < 1e-12);
        // -3 dB at the cutoff (pre-warping makes it exact).
        assert!((f.gain(5.0, 100.0) - 0.5f64.sqrt()).abs() < 1e-12);
        // Maximally flat: |H|^2 = 1 / (1 + (tan(w/2) / tan(wc/2))^10).
        for fr in [1.0, 2.5, 10.0, 20.0, 40.0] {
            let r = (std::f64::consts::PI * fr / 100.0).tan() / (std::f64::consts::PI * 0.05).tan();
            let expect = 1.0 / (1.0 + r.powi(10)).sqrt();
            assert!((f.gain(fr, 100.0) - expect).abs() < 1e-10, "{fr} Hz");
        }
        // Every zero at z = -1: the numerators multiply out to gain x binomial(5, k).
        let mut num = vec![1.0];
        for s in &f.sections {
            let mut next = vec![0.0; num.len() + 2];
            for (k, v) in num.iter().enumerate() {
                for j in 0..3 {
                    next[k + j] += v * s[j];
                }
            }
            num = next;
        }
        let k = num[0];
        for (b, c) in num.iter().zip([1.0, 5.0, 10.0, 10.0, 5.0, 1.0, 0.0]) {
            assert!((b - k * c).abs() < 1e-15);
        }
        assert!(butterworth_lowpass(5, 60.0, 100.0).is_err());
    }

    #[test]
    fn filtfilt_is_zero_phase_with_squared_gain() {
        let f = butterworth_lowpass(5, 5.0, 100.0).unwrap();
        let t: Vec<f64> = (0..2000).map(|k| k as f64 / 100.0).collect();
        let sine = |fr: f64| -> Vec<f64> {
            t.iter()
                .map(|t| (2.0 * std::f64::consts::PI * fr * t).sin())
                .collect()
        };
        // In the middle (away from the ends): a 1 Hz sine passes with gain |H|^2 and no lag.
        let x = sine(1.0);
        let y = filtfilt(&f, &x).unwrap();
        let g2 = f.gain(1.0, 100.0).powi(2);
        for k in 500..1500 {
            assert!((y[k] - g2 * x[k]).abs() < 1e-6, "{k}: {} vs {}", y[k], x[k]);
        }
        // At the cutoff: amplitude 1/2 (-6 dB); at 25 Hz: gone.
        let y = filtfilt(&f, &sine(5.0)).unwrap();
        let amp = y[500..1500].iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!((amp - 0.5).abs() < 1e-3, "{amp}");
        let y = filtfilt(&f, &sine(25.0)).unwrap();
        assert!(y[100..1900].iter().all(|v| v.abs() < 1e-4));
        // A constant passes exactly, ends included (steady-state initial conditions).
        let y = filtfilt(&f, &vec![2.5; 50]).unwrap();
        assert!(y.iter().all(|v| (v - 2.5).abs() < 1e-9), "{y:?}");
        assert!(matches!(
            filtfilt(&f, &[1.0; 10]),
            Err(SignalError::TooShort { .. })
        ));
    }

    /// Order 10 at a cutoff of 1/1000 of the rate, where the expanded transfer function's
    /// coefficients no longer hold its poles: the sections keep the Butterworth response,
    /// a constant passes exactly and an in-band sine with gain |H|^2.
    #[test]
    fn high_order_low_cutoff_stays_exact_in_sections() {
        let rate = 1000.0;
        let f = butterworth_lowpass(10, 1.0, rate).unwrap();
        assert_eq!((f.sections.len(), f.order()), (5, 10));
        for s in &f.sections {
            // Stable: every pole pair inside the unit circle.
            assert!(s[4] < 1.0 && s[4] > 0.0, "{s:?}");
        }
        assert!((f.gain(1.0, rate) - 0.5f64.sqrt()).abs() < 1e-9);
        let r = (std::f64::consts::PI * 0.5 / rate).tan() / (std::f64::consts::PI / rate).tan();
        assert!((f.gain(0.5, rate) - 1.0 / (1.0 + r.powi(20)).sqrt()).abs() < 1e-9);
        let y = filtfilt(&f, &vec![-4.25; 400]).unwrap();
        assert!(y.iter().all(|v| (v + 4.25).abs() < 1e-9), "{:?}", &y[..4]);
        let t: Vec<f64> = (0..60_000).map(|k| k as f64 / rate).collect();
        let x: Vec<f64> = t
            .iter()
            .map(|t| (2.0 * std::f64::consts::PI * 0.3 * t).sin())
            .collect();
        let y = filtfilt(&f, &x).unwrap();
        let g2 = f.gain(0.3, rate).powi(2);
        // The slowest pole decays at 0.98 /s: 25 s from either end the transients are gone.
        for k in 25_000..35_000 {
            assert!((y[k] - g2 * x[k]).abs() < 1e-6, "{k}");
        }
    }
}
