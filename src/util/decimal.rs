//! Shortest round-trip decimal text of an `f64` in the style of `format!("{v}")` (no
//! exponent, `1` not `1.0`), from `ryu`'s digits: faster than the `fmt` machinery, which
//! dominated writing large CSV tables. Where two shortest digit strings round-trip, ryu
//! takes the one nearer the exact value and std sometimes the other (last digit differs).

/// Append the shortest round-trip positional decimal of `v` to `out`.
pub fn push_f64(out: &mut String, v: f64) {
    let mut buf = ryu::Buffer::new();
    match positional(&mut buf, v) {
        Ok(text) => out.push_str(text),
        Err(s) => {
            let mut b = Vec::with_capacity(64);
            exponent_form(&mut b, s);
            // Only ASCII digits, `-`, `0.` are written.
            out.push_str(std::str::from_utf8(&b).unwrap_or("NaN"));
        }
    }
}

/// Append the text of [`push_f64`] to a byte buffer (a CSV line being built).
pub fn push_f64_bytes(out: &mut Vec<u8>, v: f64) {
    let mut buf = ryu::Buffer::new();
    match positional(&mut buf, v) {
        Ok(text) => out.extend_from_slice(text.as_bytes()),
        Err(s) => exponent_form(out, s),
    }
}

/// The final text of `v` when ryu writes it positionally (1e-5 <= |v| < 1e16 with its
/// shortest digits: std's text but for the `.0` of a whole number) or it is not finite;
/// else ryu's `d.ddde±x` text to rewrite.
fn positional(buf: &mut ryu::Buffer, v: f64) -> Result<&str, &str> {
    if !v.is_finite() {
        return Ok(if v.is_nan() {
            "NaN"
        } else if v > 0.0 {
            "inf"
        } else {
            "-inf"
        });
    }
    let s = buf.format_finite(v);
    if s.contains('e') {
        Err(s)
    } else {
        Ok(s.strip_suffix(".0").unwrap_or(s))
    }
}

/// ryu's `d.ddde±x` text of a finite number, appended positionally.
fn exponent_form(out: &mut Vec<u8>, s: &str) {
    let (neg, s) = match s.strip_prefix('-') {
        Some(rest) => (true, rest),
        None => (false, s),
    };
    let (mantissa, exp) = match s.split_once('e') {
        // ryu writes a decimal exponent that always parses.
        Some((m, e)) => (m, e.parse::<i32>().unwrap_or(0)),
        None => (s, 0),
    };
    let (int, frac) = mantissa.split_once('.').unwrap_or((mantissa, ""));
    // digits d1 d2 ... with the decimal point after `point` of them.
    let mut digits = [0u8; 40];
    let mut n = 0;
    for b in int.bytes().chain(frac.bytes()) {
        if n < digits.len() {
            digits[n] = b;
            n += 1;
        }
    }
    let mut point = int.len() as i32 + exp;
    let lead = digits[..n].iter().take_while(|&&b| b == b'0').count();
    let digits = &digits[lead..n];
    point -= lead as i32;
    let end = digits.len() - digits.iter().rev().take_while(|&&b| b == b'0').count();
    let digits = &digits[..end];
    if neg {
        out.push(b'-');
    }
    if digits.is_empty() {
        out.push(b'0');
        return;
    }
    if point <= 0 {
        out.extend_from_slice(b"0.");
        out.extend(std::iter::repeat_n(b'0', (-point) as usize));
        out.extend_from_slice(digits);
    } else if point as usize >= digits.len() {
        out.extend_from_slice(digits);
        out.extend(std::iter::repeat_n(b'0', point as usize - digits.len()));
    } else {
        let (a, b) = digits.split_at(point as usize);
        out.extend_from_slice(a);
        out.push(b'.');
        out.extend_from_slice(b);
    }
}

#[cfg(test)]
mod tests {
    use super::{push_f64, push_f64_bytes};
    use crate::util::Rng;

    /// The text of `v`, checked to be the same through both entry points.
    fn text(v: f64) -> String {
        let mut s = String::new();
        push_f64(&mut s, v);
        let mut b = b"x".to_vec();
        push_f64_bytes(&mut b, v);
        assert_eq!(&b[1..], s.as_bytes());
        s
    }

    /// Reads back to the same bits and is never longer than the standard library's
    /// `Display` (the second method), and equals it but for the last digit, on edge values
    /// and on 200,000 random bit patterns and random values of every magnitude.
    #[test]
    fn agrees_with_display_everywhere() {
        let edge = [
            0.0,
            -0.0,
            1.0,
            -1.0,
            0.1,
            1e-7,
            1.5e-5,
            123456.789,
            1e15,
            1e16,
            1e21,
            1e22,
            1.7976931348623157e308,
            5e-324,
            2.2250738585072014e-308,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            0.30000000000000004,
            9007199254740993.0,
        ];
        for v in edge {
            assert_eq!(text(v), format!("{v}"), "{v:e}");
        }
        let mut differ = 0;
        let mut rng = Rng::new(11);
        for i in 0..200_000u32 {
            let v = if i % 2 == 0 {
                f64::from_bits(rng.next_u64())
            } else {
                (rng.uniform() - 0.5) * 10f64.powi((i % 40) as i32 - 20)
            };
            let (ours, std) = (text(v), format!("{v}"));
            if ours != std {
                differ += 1;
                let back: f64 = ours.parse().expect("a decimal");
                assert_eq!(back.to_bits(), v.to_bits(), "{ours} for {std}");
                assert_eq!(ours.len(), std.len(), "{ours} vs {std}");
                assert_eq!(
                    ours[..ours.len() - 1],
                    std[..std.len() - 1],
                    "{ours} vs {std}"
                );
            }
        }
        // Ties between two shortest forms are rare (213 of 200,000 here).
        assert!(differ < 2000, "{differ} of 200000 differ from Display");
    }
}
