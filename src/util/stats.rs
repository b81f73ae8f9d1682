//! Descriptive statistics used in every report (mean, median, std, quartiles, RMS).

use serde::{Deserialize, Serialize};

use super::serde_num::f64_or_nan;

/// Summary of a sample of non-negative errors or values, with its unit.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct Summary {
    /// Number of values.
    pub count: usize,
    /// Arithmetic mean.
    #[serde(deserialize_with = "f64_or_nan")]
    pub mean: f64,
    /// Median (average of the two middle values for an even count).
    #[serde(deserialize_with = "f64_or_nan")]
    pub median: f64,
    /// Sample standard deviation (n - 1 in the denominator; 0 for one value).
    #[serde(deserialize_with = "f64_or_nan")]
    pub std: f64,
    /// Smallest value.
    #[serde(deserialize_with = "f64_or_nan")]
    pub min: f64,
    /// Largest value.
    #[serde(deserialize_with = "f64_or_nan")]
    pub max: f64,
    /// Root mean square.
    #[serde(deserialize_with = "f64_or_nan")]
    pub rms: f64,
    /// Unit of every number above.
    pub unit: String,
}

impl Summary {
    /// Summarise `values` (which must not be empty) in `unit`.
    pub fn of(values: &[f64], unit: &str) -> Self {
        let n = values.len();
        let mean = mean(values);
        let std = if n > 1 {
            (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64).sqrt()
        } else {
            0.0
        };
        Self {
            count: n,
            mean,
            median: quantile(values, 0.5),
            std,
            min: values.iter().copied().fold(f64::INFINITY, f64::min),
            max: values.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            rms: (values.iter().map(|v| v * v).sum::<f64>() / n.max(1) as f64).sqrt(),
            unit: unit.to_string(),
        }
    }
}

/// Arithmetic mean (NaN for an empty slice).
pub fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// Quantile with linear interpolation between order statistics (numpy's default).
pub fn quantile(v: &[f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let h = (s.len() - 1) as f64 * p.clamp(0.0, 1.0);
    let lo = h.floor() as usize;
    let hi = h.ceil() as usize;
    s[lo] + (h - lo as f64) * (s[hi] - s[lo])
}

/// Five-number summary: min, first quartile, median, third quartile, max.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Quartiles {
    /// Smallest value.
    pub min: f64,
    /// 25th percentile.
    pub q1: f64,
    /// Median.
    pub median: f64,
    /// 75th percentile.
    pub q3: f64,
    /// Largest value.
    pub max: f64,
}

impl Quartiles {
    /// Quartiles of a non-empty sample.
    pub fn of(v: &[f64]) -> Self {
        Self {
            min: quantile(v, 0.0),
            q1: quantile(v, 0.25),
            median: quantile(v, 0.5),
            q3: quantile(v, 0.75),
            max: quantile(v, 1.0),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_hand_computed_values() {
        let s = Summary::of(&[1.0, 2.0, 3.0, 4.0], "mm");
        assert_eq!(s.mean, 2.5);
        assert_eq!(s.median, 2.5);
        assert!((s.std - (5.0f64 / 3.0).sqrt()).abs() < 1e-15);
        assert!((s.rms - 7.5f64.sqrt()).abs() < 1e-15);
        let q = Quartiles::of(&[1.0, 2.0, 3.0, 4.0, 5.0]);
        assert_eq!((q.q1, q.median, q.q3), (2.0, 3.0, 4.0));
    }
}
