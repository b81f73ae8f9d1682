//! The FFT plans calibd's phase method uses, as trait objects: the planners' generic code is
//! instantiated here, once, and callers only go through the `Fft` / `RealToComplex` vtables.

use std::sync::Arc;

pub use realfft::RealToComplex;
pub use rustfft::Fft;
pub use rustfft::num_complex::Complex;

/// A forward real-to-complex transform of `len` f32 samples (`len / 2 + 1` bins).
pub fn real_forward_f32(len: usize) -> Arc<dyn RealToComplex<f32>> {
    realfft::RealFftPlanner::<f32>::new().plan_fft_forward(len)
}

/// A forward complex transform of `len` f32 points.
pub fn forward_f32(len: usize) -> Arc<dyn Fft<f32>> {
    rustfft::FftPlanner::<f32>::new().plan_fft_forward(len)
}

/// An inverse (unnormalised) complex transform of `len` f64 points.
pub fn inverse_f64(len: usize) -> Arc<dyn Fft<f64>> {
    rustfft::FftPlanner::<f64>::new().plan_fft_inverse(len)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each plan against the direct sum of its definition on a seeded signal.
    #[test]
    fn plans_match_the_direct_transform() {
        let n = 12;
        let x: Vec<f64> = (0..n).map(|i| ((i * 7 + 3) % 11) as f64 - 5.0).collect();
        let dft = |sign: f64| -> Vec<Complex<f64>> {
            (0..n)
                .map(|k| {
                    (0..n)
                        .map(|j| {
                            let a = sign * std::f64::consts::TAU * (j * k) as f64 / n as f64;
                            Complex::new(x[j] * a.cos(), x[j] * a.sin())
                        })
                        .sum()
                })
                .collect()
        };
        let (fwd, inv) = (dft(-1.0), dft(1.0));

        let r2c = real_forward_f32(n);
        let mut input: Vec<f32> = x.iter().map(|&v| v as f32).collect();
        let mut out = r2c.make_output_vec();
        r2c.process(&mut input, &mut out)
            .expect("lengths match the plan");
        assert_eq!(out.len(), n / 2 + 1);
        for (a, b) in out.iter().zip(&fwd) {
            assert!((a.re as f64 - b.re).abs() < 1e-4 && (a.im as f64 - b.im).abs() < 1e-4);
        }

        let mut c: Vec<Complex<f32>> = x.iter().map(|&v| Complex::new(v as f32, 0.0)).collect();
        forward_f32(n).process(&mut c);
        for (a, b) in c.iter().zip(&fwd) {
            assert!((a.re as f64 - b.re).abs() < 1e-4 && (a.im as f64 - b.im).abs() < 1e-4);
        }

        let mut d: Vec<Complex<f64>> = x.iter().map(|&v| Complex::new(v, 0.0)).collect();
        inverse_f64(n).process(&mut d);
        for (a, b) in d.iter().zip(&inv) {
            assert!((a - b).norm() < 1e-12);
        }
    }
}
