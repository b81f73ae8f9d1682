//! RAPID literals used by the calibd RAPID module: `jointtarget` and `pos` values as RWS
//! reads and writes them.

/// `[[j1,...,j6],[9E9,...]]` with joints in degrees.
pub fn format_jointtarget(q_deg: &[f64; 6]) -> String {
    let j: Vec<String> = q_deg.iter().map(|v| format!("{v:.4}")).collect();
    format!("[[{}],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]]", j.join(","))
}

/// `[x,y,z]` in mm.
pub fn format_pos(p_mm: &[f64; 3]) -> String {
    format!("[{:.4},{:.4},{:.4}]", p_mm[0], p_mm[1], p_mm[2])
}

fn numbers(s: &str) -> Option<Vec<f64>> {
    s.split(',')
        .map(|x| x.trim().parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect()
}

/// Parses a jointtarget literal; returns the six robot joints (deg).
pub fn parse_jointtarget(s: &str) -> Option<[f64; 6]> {
    let inner = s.trim().strip_prefix("[[")?;
    let (rob, rest) = inner.split_once(']')?;
    let ext = rest.trim().strip_prefix(",[")?.strip_suffix("]]")?;
    numbers(ext).filter(|e| e.len() == 6)?;
    numbers(rob)?.try_into().ok()
}

/// Parses a pos literal `[x,y,z]`.
pub fn parse_pos(s: &str) -> Option<[f64; 3]> {
    let inner = s.trim().strip_prefix('[')?.strip_suffix(']')?;
    numbers(inner)?.try_into().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn literals_round_trip() {
        let q = [10.0, 0.0, 0.0, 0.0, 30.0, -1.5];
        assert_eq!(parse_jointtarget(&format_jointtarget(&q)), Some(q));
        assert_eq!(
            parse_jointtarget("[[10,0,0,0,30,0],[9E9,9E9,9E9,9E9,9E9,9E9]]"),
            Some([10.0, 0.0, 0.0, 0.0, 30.0, 0.0])
        );
        assert_eq!(
            parse_pos(&format_pos(&[1.0, -2.0, 0.5])),
            Some([1.0, -2.0, 0.5])
        );
        assert_eq!(parse_jointtarget("[[1,2,3],[9E9]]"), None);
        assert_eq!(parse_pos("[1,2]"), None);
        assert_eq!(parse_pos("[1,nan,2]"), None);
    }
}
