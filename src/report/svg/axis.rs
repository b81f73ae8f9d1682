//! Axis arithmetic: linear and logarithmic scales, round ticks and their labels.

/// About `n` round tick values covering [lo, hi].
pub fn ticks(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
        return vec![lo];
    }
    let raw = (hi - lo) / n.max(1) as f64;
    let e = raw.log10().floor() as i32;
    // Scale by dividing for negative exponents: 6 / 10 is 0.6 exactly, 6 * 0.1 is not.
    let scale = |v: f64| {
        if e < 0 {
            v / 10f64.powi(-e)
        } else {
            v * 10f64.powi(e)
        }
    };
    let m = [1.0, 2.0, 2.5, 5.0, 10.0]
        .into_iter()
        .find(|m| scale(*m) >= raw)
        .unwrap_or(10.0);
    let step = scale(m);
    let first = (lo / step).ceil();
    let mut out = Vec::new();
    let mut k = 0;
    while scale((first + k as f64) * m) <= hi + step * 1e-9 && k < 100 {
        out.push(scale((first + k as f64) * m));
        k += 1;
    }
    out
}

/// Ticks of a logarithmic axis over [lo, hi] (both > 0): the powers of ten, with 2 and 5
/// times them when the range spans fewer than three decades.
pub fn log_ticks(lo: f64, hi: f64) -> Vec<f64> {
    if !(lo > 0.0 && hi > lo && hi.is_finite()) {
        return vec![lo];
    }
    let (a, b) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
    let mantissas: &[f64] = if b - a < 3 { &[1.0, 2.0, 5.0] } else { &[1.0] };
    let mut out = Vec::new();
    for e in a..=b {
        for m in mantissas {
            let v = if e < 0 {
                m / 10f64.powi(-e)
            } else {
                m * 10f64.powi(e)
            };
            if v >= lo * (1.0 - 1e-9) && v <= hi * (1.0 + 1e-9) {
                out.push(v);
            }
        }
    }
    out
}

/// A logarithmic axis range covering every positive finite value: whole decades around
/// the smallest and largest; `(0.1, 1)` when there is none.
pub fn log_range<'a>(values: impl IntoIterator<Item = &'a f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
    for v in values.into_iter().filter(|v| v.is_finite() && **v > 0.0) {
        lo = lo.min(*v);
        hi = hi.max(*v);
    }
    if hi <= 0.0 {
        return (0.1, 1.0);
    }
    let lo = 10f64.powf(lo.log10().floor());
    let mut hi = 10f64.powf(hi.log10().ceil());
    if hi <= lo {
        hi = lo * 10.0;
    }
    (lo, hi)
}

/// A tick label: plain decimals, exponent form outside [1e-3, 1e5).
pub fn label(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if !(1e-3..1e5).contains(&a) {
        format!("{v:.0e}")
    } else {
        let s = format!("{v:.4}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// How an axis maps data onto pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scale {
    /// Equal steps for equal differences.
    Linear,
    /// Equal steps for equal ratios (data must be > 0; smaller values sit on the axis).
    Log,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_and_cover_the_range() {
        assert_eq!(ticks(0.0, 1.0, 5), vec![0.0, 0.2, 0.4, 0.6, 0.8, 1.0]);
        assert_eq!(ticks(0.0, 0.37, 4), vec![0.0, 0.1, 0.2, 0.3]);
        assert_eq!(ticks(3.0, 3.0, 5), vec![3.0]);
        assert_eq!(log_ticks(0.001, 10.0), vec![0.001, 0.01, 0.1, 1.0, 10.0]);
        assert_eq!(
            log_ticks(0.1, 10.0),
            vec![0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0]
        );
        assert_eq!(log_range(&[0.0031, 0.0, 3.9]), (0.001, 10.0));
        assert_eq!(log_range(&[]), (0.1, 1.0));
    }
}
