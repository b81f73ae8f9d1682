//! The absolute position on the encoded pattern ([`super::code`]): the dots the phase fit
//! predicts in the image are read as present or missing (two-class threshold), the parity
//! of the centre dot's indices is the one under which the always-present dots are there and
//! each code bit agrees along its column or row, and the code bits read along each axis are
//! located in the sequence by their 12-bit windows (majority over all windows).

use std::f64::consts::TAU;

use super::code::{self, DEGREE};
use super::{GrayImage, PatternError, PatternPose, PhaseFit};

/// The absolute pose of the encoded pattern's origin (lengths in the unit of `period`);
/// theta must be within (-45, 45] deg of the truth.
pub fn decode_absolute(
    img: &GrayImage,
    fit: &PhaseFit,
    period: f64,
) -> Result<PatternPose, PatternError> {
    let near = fit.pose(period);
    let (a, b) = ([fit.x.a, fit.x.b], [fit.y.a, fit.y.b]);
    let det = a[0] * b[1] - a[1] * b[0];
    if !(det.abs() > 0.0) {
        return Err(PatternError::Code("degenerate lattice".into()));
    }
    // The centre dot: phases (2 pi m0, 2 pi n0) with m0, n0 the nearest integers.
    let [xc, yc] = fit.centre_periods();
    let (m0, n0) = (xc.round(), yc.round());
    let (cu, cv) = (
        (img.width as f64 - 1.0) / 2.0,
        (img.height as f64 - 1.0) / 2.0,
    );
    // Pixel position of dot (m0 + dm, n0 + dn): solve the two planes.
    let dot_px = |dm: i64, dn: i64| {
        let r1 = TAU * (m0 + dm as f64) - fit.x.c;
        let r2 = TAU * (n0 + dn as f64) - fit.y.c;
        let u = (r1 * b[1] - a[1] * r2) / det;
        let v = (a[0] * r2 - r1 * b[0]) / det;
        (u + cu, v + cv)
    };
    let period_px = fit.period_px();
    let reach = (img.width.max(img.height) as f64 / period_px).ceil() as i64 + 1;
    let mut dots = Vec::new();
    for dn in -reach..=reach {
        for dm in -reach..=reach {
            let (x, y) = dot_px(dm, dn);
            if let Some(v) = bilinear(img, x, y) {
                dots.push((dm, dn, v));
            }
        }
    }
    if dots.len() < 4 * DEGREE * DEGREE {
        return Err(PatternError::Code(format!(
            "only {} dots in view: at least {} periods along each axis are needed",
            dots.len(),
            2 * DEGREE + 2
        )));
    }
    let threshold = two_class_threshold(dots.iter().map(|d| d.2).collect());
    let present: Vec<(i64, i64, bool)> = dots
        .iter()
        .map(|&(m, n, v)| (m, n, v > threshold))
        .collect();
    // Parity hypotheses of (i0, j0), the centre dot's indices.
    let mut scored: Vec<(usize, usize, usize)> = (0..4usize)
        .map(|h| {
            let (pi, pj) = (h & 1, h >> 1);
            (parity_score(&present, pi, pj), pi, pj)
        })
        .collect();
    scored.sort();
    let (best, pi, pj) = scored[0];
    if best * 4 > present.len() / 20 || scored[1].0 < 3 * best.max(3) {
        return Err(PatternError::Code(format!(
            "the dots do not follow the code's layout ({} of {} misread at best, {} at second best)",
            best,
            present.len(),
            scored[1].0
        )));
    }
    let seq = code::sequence();
    let index = code::window_index(&seq);
    let i0 = axis_index(&present, pi, pj, true, &index)?;
    let j0 = axis_index(&present, pj, pi, false, &index)?;
    // The centre dot (i0, j0) is at `near`'s origin: move to the dot (0, 0).
    // Theta as labelled by the fit (X along i), not normalised: the indices follow it.
    let theta = fit.theta_rad();
    let (s, c) = theta.sin_cos();
    let (di, dj) = (i0 as f64 * period, j0 as f64 * period);
    Ok(PatternPose {
        x: near.x - (c * di - s * dj),
        y: near.y - (s * di + c * dj),
        theta_rad: theta,
    })
}

/// Misreads under the hypothesis that the centre dot's indices have parities (pi, pj):
/// always-present dots seen missing, plus code bits disagreeing with their column's (X
/// code) or row's (Y code) majority.
fn parity_score(dots: &[(i64, i64, bool)], pi: usize, pj: usize) -> usize {
    use std::collections::BTreeMap;
    let mut misses = 0;
    let mut xcols: BTreeMap<i64, (usize, usize)> = BTreeMap::new();
    let mut yrows: BTreeMap<i64, (usize, usize)> = BTreeMap::new();
    for &(m, n, on) in dots {
        let (i, j) = (m + pi as i64, n + pj as i64);
        let e = match (i.rem_euclid(2), j.rem_euclid(2)) {
            (1, 0) => xcols.entry(i).or_default(),
            (0, 1) => yrows.entry(j).or_default(),
            _ => {
                misses += usize::from(!on);
                continue;
            }
        };
        if on { e.0 += 1 } else { e.1 += 1 }
    }
    misses
        + xcols
            .values()
            .chain(yrows.values())
            .map(|&(a, b)| a.min(b))
            .sum::<usize>()
}

/// The index (in [-L, L)) of the centre dot along one axis: the code bits by majority
/// along the other axis, located in the sequence by every window of 12 consecutive bits.
fn axis_index(
    dots: &[(i64, i64, bool)],
    p_along: usize,
    p_across: usize,
    x_axis: bool,
    index: &[u16],
) -> Result<i64, PatternError> {
    use std::collections::BTreeMap;
    let mut votes: BTreeMap<i64, (usize, usize)> = BTreeMap::new();
    for &(m, n, on) in dots {
        let (along, across) = if x_axis { (m, n) } else { (n, m) };
        let (i, j) = (along + p_along as i64, across + p_across as i64);
        if i.rem_euclid(2) == 1 && j.rem_euclid(2) == 0 {
            let e = votes.entry(i).or_default();
            if on { e.0 += 1 } else { e.1 += 1 }
        }
    }
    // Bits by relative code position k = (i - 1)/2.
    let bits: BTreeMap<i64, bool> = votes
        .iter()
        .map(|(&i, &(on, off))| ((i - 1).div_euclid(2), on > off))
        .collect();
    let l = code::LEN as i64;
    let mut shifts: BTreeMap<i64, usize> = BTreeMap::new();
    let mut windows = 0;
    for &k in bits.keys() {
        let mut w = 0usize;
        let mut whole = true;
        for b in 0..DEGREE as i64 {
            match bits.get(&(k + b)) {
                Some(&bit) => w |= (bit as usize) << b,
                None => whole = false,
            }
        }
        if !whole {
            continue;
        }
        windows += 1;
        let pos = index[w];
        if pos != u16::MAX {
            *shifts.entry((pos as i64 - k).rem_euclid(l)).or_default() += 1;
        }
    }
    let axis = if x_axis { "X" } else { "Y" };
    let Some((&shift, &count)) = shifts.iter().max_by_key(|e| *e.1) else {
        return Err(PatternError::Code(format!(
            "fewer than {DEGREE} consecutive code bits along {axis} in view"
        )));
    };
    if count * 3 < windows * 2 {
        return Err(PatternError::Code(format!(
            "the {axis} code is inconsistent: {count} of {windows} windows agree"
        )));
    }
    // True code position = relative + shift, so i = i_rel + 2 shift.
    Ok(code::centred_index(p_along as i64 + 2 * shift))
}

/// Bilinear sample at pixel coordinates (x, y) (column, row); `None` within a pixel of
/// the border.
fn bilinear(img: &GrayImage, x: f64, y: f64) -> Option<f64> {
    if !(x >= 1.0 && y >= 1.0 && x <= img.width as f64 - 2.0 && y <= img.height as f64 - 2.0) {
        return None;
    }
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let p = |c: usize, r: usize| img.pixels[r * img.width + c] as f64;
    Some(
        (1.0 - fy) * ((1.0 - fx) * p(x0, y0) + fx * p(x0 + 1, y0))
            + fy * ((1.0 - fx) * p(x0, y0 + 1) + fx * p(x0 + 1, y0 + 1)),
    )
}

/// The threshold between two classes of values (iterated midpoint of the class means).
fn two_class_threshold(v: Vec<f64>) -> f64 {
    let (lo, hi) = v
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    let mut t = (lo + hi) / 2.0;
    for _ in 0..20 {
        let (mut s0, mut n0, mut s1, mut n1) = (0.0, 0usize, 0.0, 0usize);
        for &x in &v {
            if x > t {
                s1 += x;
                n1 += 1;
            } else {
                s0 += x;
                n0 += 1;
            }
        }
        if n0 == 0 || n1 == 0 {
            break;
        }
        t = (s0 / n0 as f64 + s1 / n1 as f64) / 2.0;
    }
    t
}
