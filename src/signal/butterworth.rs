//! Digital Butterworth low-pass filters by the bilinear transform with pre-warping, and
//! zero-phase filtering: forward then backward through the filter, with odd-extension padding
//! and steady-state initial conditions (the scheme of MATLAB's and SciPy's `filtfilt`), so the
//! filtered signal has no lag and the gain is |H|^2.

use nalgebra::{Complex, DMatrix, DVector};

use super::SignalError;

/// A digital filter `b(z) / a(z)` with `a[0] = 1`.
#[derive(Debug, Clone, PartialEq)]
pub struct Filter {
    /// Numerator coefficients.
    pub b: Vec<f64>,
    /// Denominator coefficients, `a[0] = 1`.
    pub a: Vec<f64>,
}

/// Product of (z - r_k) as polynomial coefficients, highest power first.
fn poly(roots: &[Complex<f64>]) -> Vec<Complex<f64>> {
    let mut c = vec![Complex::new(1.0, 0.0)];
    for r in roots {
        let mut next = vec![Complex::new(0.0, 0.0); c.len() + 1];
        for (k, v) in c.iter().enumerate() {
            next[k] += v;
            next[k + 1] -= v * r;
        }
        c = next;
    }
    c
}

/// Order-`order` Butterworth low-pass with cutoff `cutoff_hz` (-3 dB) at `rate_hz`.
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
    let n = order as f64;
    let fs2 = 2.0 * rate_hz;
    // Pre-warped analog cutoff (rad/s).
    let wc = fs2 * (std::f64::consts::PI * cutoff_hz / rate_hz).tan();
    let poles: Vec<Complex<f64>> = (0..order)
        .map(|k| {
            let theta = std::f64::consts::PI * (2.0 * k as f64 + n + 1.0) / (2.0 * n);
            let s = Complex::new(theta.cos(), theta.sin()) * wc;
            (Complex::new(fs2, 0.0) + s) / (Complex::new(fs2, 0.0) - s)
        })
        .collect();
    let a: Vec<f64> = poly(&poles).iter().map(|c| c.re).collect();
    let zeros = vec![Complex::new(-1.0, 0.0); order];
    let b0: Vec<f64> = poly(&zeros).iter().map(|c| c.re).collect();
    // Unit gain at DC (z = 1).
    let gain = a.iter().sum::<f64>() / b0.iter().sum::<f64>();
    Ok(Filter {
        b: b0.iter().map(|v| v * gain).collect(),
        a,
    })
}

impl Filter {
    /// Gain |H(e^{i w})| at `freq_hz` for sampling rate `rate_hz`.
    pub fn gain(&self, freq_hz: f64, rate_hz: f64) -> f64 {
        let w = 2.0 * std::f64::consts::PI * freq_hz / rate_hz;
        let eval = |c: &[f64]| -> Complex<f64> {
            c.iter()
                .enumerate()
                .map(|(k, v)| Complex::from_polar(*v, -w * k as f64))
                .sum()
        };
        (eval(&self.b) / eval(&self.a)).norm()
    }

    /// Direct form II transposed, from state `zi` (length = order).
    fn run(&self, x: &[f64], zi: &[f64]) -> Vec<f64> {
        let n = self.a.len().max(self.b.len());
        let coef = |v: &[f64], k: usize| v.get(k).copied().unwrap_or(0.0);
        let mut z: Vec<f64> = zi.to_vec();
        z.resize(n - 1, 0.0);
        x.iter()
            .map(|&xi| {
                let y = coef(&self.b, 0) * xi + z.first().copied().unwrap_or(0.0);
                for k in 1..n {
                    let next = if k < n - 1 { z[k] } else { 0.0 };
                    z[k - 1] = coef(&self.b, k) * xi - coef(&self.a, k) * y + next;
                }
                y
            })
            .collect()
    }

    /// Steady-state filter state for a unit step input (SciPy's `lfilter_zi`).
    fn step_state(&self) -> Vec<f64> {
        let n = self.a.len().max(self.b.len());
        let m = n - 1;
        if m == 0 {
            return Vec::new();
        }
        let coef = |v: &[f64], k: usize| v.get(k).copied().unwrap_or(0.0);
        // (I - A^T) zi = b[1:] - a[1:] b[0], A the companion matrix of a.
        let mut lhs = DMatrix::identity(m, m);
        for i in 0..m {
            lhs[(i, 0)] += coef(&self.a, i + 1);
            if i + 1 < m {
                lhs[(i, i + 1)] -= 1.0;
            }
        }
        let rhs = DVector::from_fn(m, |i, _| {
            coef(&self.b, i + 1) - coef(&self.a, i + 1) * coef(&self.b, 0)
        });
        lhs.lu()
            .solve(&rhs)
            .map_or(vec![0.0; m], |v| v.iter().copied().collect())
    }
}

/// Zero-phase filtering of `x`: odd-extension padding of `3 * (order + 1)` samples at each
/// end, forward pass from the steady state of the first value, backward pass likewise.
pub fn filtfilt(f: &Filter, x: &[f64]) -> Result<Vec<f64>, SignalError> {
    let pad = 3 * f.a.len().max(f.b.len());
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
    let zi = f.step_state();
    let scaled = |v: f64| zi.iter().map(|z| z * v).collect::<Vec<f64>>();
    let mut y = f.run(&ext, &scaled(ext[0]));
    y.reverse();
    let mut y = f.run(&y, &scaled(y[0]));
    y.reverse();
    Ok(y[pad..pad + n].to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn design_has_the_butterworth_response() {
        let f = butterworth_lowpass(5, 5.0, 100.0).unwrap();
        assert_eq!((f.b.len(), f.a.len()), (6, 6));
        assert!((f.gain(0.0, 100.0) - 1.0).abs() < 1e-12);
        // -3 dB at the cutoff (pre-warping makes it exact).
        assert!((f.gain(5.0, 100.0) - 0.5f64.sqrt()).abs() < 1e-12);
        // Maximally flat: |H|^2 = 1 / (1 + (tan(w/2) / tan(wc/2))^10).
        for fr in [1.0, 2.5, 10.0, 20.0, 40.0] {
            let r = (std::f64::consts::PI * fr / 100.0).tan() / (std::f64::consts::PI * 0.05).tan();
            let expect = 1.0 / (1.0 + r.powi(10)).sqrt();
            assert!((f.gain(fr, 100.0) - expect).abs() < 1e-10, "{fr} Hz");
        }
        // Numerator = gain x binomial(5, k).
        let k = f.b[0];
        for (b, c) in f.b.iter().zip([1.0, 5.0, 10.0, 10.0, 5.0, 1.0]) {
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
}
