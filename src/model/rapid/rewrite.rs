//! Rewriting a module text in place: replace byte spans, keep every other byte.

/// Replace `text[start..end]` by `with`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Edit {
    /// First byte replaced.
    pub start: usize,
    /// One past the last byte replaced.
    pub end: usize,
    /// The new text.
    pub with: String,
}

/// `src` with the edits applied (sorted here; they must not overlap).
pub fn apply(src: &str, edits: &[Edit]) -> String {
    let mut e: Vec<&Edit> = edits.iter().collect();
    e.sort_by_key(|e| (e.start, e.end));
    let mut out = String::with_capacity(src.len() + 64);
    let mut at = 0;
    for x in e {
        debug_assert!(x.start >= at, "overlapping edits");
        out.push_str(&src[at..x.start.max(at)]);
        out.push_str(&x.with);
        at = x.end.max(at);
    }
    out.push_str(&src[at..]);
    out
}

/// A number as RAPID text with at most `decimals` decimals, trailing zeros dropped
/// (`374.1`, `-0.5`, `0`, never `-0`).
pub fn number(v: f64, decimals: usize) -> String {
    let s = format!("{v:.decimals$}");
    let s = if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    };
    if s == "-0" { "0".into() } else { s }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edits_replace_spans_and_keep_the_rest() {
        let src = "a := [1.0, 2.0];";
        let e = [
            Edit {
                start: 11,
                end: 14,
                with: "-2.5".into(),
            },
            Edit {
                start: 6,
                end: 9,
                with: "1".into(),
            },
        ];
        assert_eq!(apply(src, &e), "a := [1, -2.5];");
        assert_eq!(number(-0.00000001, 5), "0");
        assert_eq!(number(374.10000, 5), "374.1");
        assert_eq!(number(-12.0, 5), "-12");
        assert_eq!(number(0.123456789, 9), "0.123456789");
    }
}
