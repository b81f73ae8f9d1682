//! Signal processing for measurement streams: Butterworth low-pass design and zero-phase
//! (forward-backward) filtering. Pure, no I/O.

pub mod butterworth;

pub use butterworth::{Filter, butterworth_lowpass, filtfilt};

/// Errors of the signal layer.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SignalError {
    /// A filter setting is out of range.
    #[error("filter: {0}")]
    Design(String),
    /// A signal is too short for the filter.
    #[error("signal of {len} samples is too short: the filter needs at least {needed}")]
    TooShort {
        /// Samples given.
        len: usize,
        /// Samples needed.
        needed: usize,
    },
}
