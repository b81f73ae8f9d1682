//! The code of the encoded pattern: a maximum-length binary sequence (LFSR, degree 12,
//! 4095 bits) in which every window of 12 consecutive bits occurs once, so 12 bits read
//! along an axis give the period's index.
//!
//! Dot (i, j) of the grid (at X = i p, Y = j p) is present when i and j are both even or
//! both odd; dots at odd i, even j carry bit `s[(i-1)/2 mod L]` of the X code; dots at
//! even i, odd j carry bit `s[(j-1)/2 mod L]` of the Y code (1 = present). The pattern
//! spans i, j in [-L, L): 2L = 8190 periods along each axis.

/// Degree of the sequence: bits per window.
pub const DEGREE: usize = 12;
/// Length of the sequence (2^12 - 1).
pub const LEN: usize = (1 << DEGREE) - 1;

/// The sequence, from x^12 + x^6 + x^4 + x + 1 (primitive) and the all-ones start.
pub fn sequence() -> Vec<bool> {
    let mut s = vec![true; DEGREE];
    while s.len() < LEN {
        let k = s.len() - DEGREE;
        s.push(s[k + 6] ^ s[k + 4] ^ s[k + 1] ^ s[k]);
    }
    s
}

/// Position in the sequence of each 12-bit window (bit 0 = first bit); `u16::MAX` for the
/// all-zero window, which never occurs.
pub fn window_index(seq: &[bool]) -> Vec<u16> {
    let mut idx = vec![u16::MAX; 1 << DEGREE];
    for start in 0..seq.len() {
        idx[window_at(seq, start)] = start as u16;
    }
    idx
}

/// The window of `seq` (cyclic) starting at `start`, as an integer.
fn window_at(seq: &[bool], start: usize) -> usize {
    (0..DEGREE).fold(0, |acc, b| {
        acc | ((seq[(start + b) % seq.len()] as usize) << b)
    })
}

/// Whether dot (i, j) of the encoded pattern is present.
pub fn dot_present(seq: &[bool], i: i64, j: i64) -> bool {
    let l = seq.len() as i64;
    match (i.rem_euclid(2), j.rem_euclid(2)) {
        (1, 0) => seq[((i - 1) / 2).rem_euclid(l) as usize],
        (0, 1) => seq[((j - 1) / 2).rem_euclid(l) as usize],
        _ => true,
    }
}

/// An index of the grid taken into the pattern's span [-L, L).
pub fn centred_index(i: i64) -> i64 {
    let span = 2 * LEN as i64;
    (i + LEN as i64).rem_euclid(span) - LEN as i64
}
