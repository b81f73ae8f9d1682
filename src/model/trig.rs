//! Joint sines and cosines remembered per configuration: an identification evaluates the
//! same configurations again and again, and a joint angle `q + offset + c * tau` often
//! comes back unchanged (the residuals and then the Jacobian at the same unknowns; joints
//! whose offset and compliance are not identified at every evaluation). A memo returns the
//! `sin_cos` of the last angle it saw when the angle is the same bit for bit, so results
//! are exactly those computed without it.

use std::sync::Mutex;

/// The sine and cosine of the last angle (rad) one joint of one configuration took.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrigMemo {
    theta: f64,
    sin: f64,
    cos: f64,
}

impl Default for TrigMemo {
    /// An empty memo (NaN: the first angle is computed).
    fn default() -> Self {
        Self {
            theta: f64::NAN,
            sin: f64::NAN,
            cos: f64::NAN,
        }
    }
}

impl TrigMemo {
    /// `theta.sin_cos()`, from the memo when `theta` is the angle it last saw.
    #[inline]
    pub fn sin_cos(&mut self, theta: f64) -> (f64, f64) {
        if theta.to_bits() != self.theta.to_bits() {
            let (sin, cos) = theta.sin_cos();
            *self = Self { theta, sin, cos };
        }
        (self.sin, self.cos)
    }
}

/// `theta.sin_cos()` through `memo` when there is one.
#[inline]
pub(crate) fn sin_cos(theta: f64, memo: Option<&mut TrigMemo>) -> (f64, f64) {
    match memo {
        Some(m) => m.sin_cos(theta),
        None => theta.sin_cos(),
    }
}

/// The memos of a set of configurations (`joints` per configuration, configuration-major),
/// shared by the evaluations of a problem. A caller that finds them in use by another
/// evaluation computes without them (the same values).
#[derive(Debug, Default)]
pub struct TrigMemos(Mutex<Vec<TrigMemo>>);

impl TrigMemos {
    /// Empty memos for `configurations` configurations of `joints` joints.
    pub fn new(configurations: usize, joints: usize) -> Self {
        Self(Mutex::new(vec![
            TrigMemo::default();
            configurations * joints
        ]))
    }

    /// The memos, unless another evaluation holds them.
    pub fn try_take(&self) -> Option<std::sync::MutexGuard<'_, Vec<TrigMemo>>> {
        self.0.try_lock().ok()
    }
}

impl Clone for TrigMemos {
    /// Memos of the same size (their contents copied when they are free, empty otherwise).
    fn clone(&self) -> Self {
        match self.0.try_lock() {
            Ok(v) => Self(Mutex::new(v.clone())),
            Err(_) => Self(Mutex::new(Vec::new())),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The memo returns `sin_cos` of the angle asked, bit for bit, whether it recomputes or
    /// remembers; a different angle (even by one ulp) is computed afresh.
    #[test]
    fn remembers_only_the_same_angle() {
        let mut m = TrigMemo::default();
        let a = 0.7_f64;
        let b = f64::from_bits(a.to_bits() + 1);
        for theta in [a, a, b, a, -0.0, 0.0, 3.0, 3.0] {
            let (s, c) = m.sin_cos(theta);
            let (s0, c0) = theta.sin_cos();
            assert_eq!((s.to_bits(), c.to_bits()), (s0.to_bits(), c0.to_bits()));
        }
        // Remembered: the stored angle is the last one asked.
        assert_eq!(m.theta, 3.0);
        let busy = TrigMemos::new(2, 3);
        let held = busy.try_take().expect("free");
        assert_eq!(held.len(), 6);
        assert!(busy.try_take().is_none(), "in use");
        assert!(busy.clone().try_take().is_some_and(|v| v.is_empty()));
    }
}
