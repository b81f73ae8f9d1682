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
