//! Poisson-disc sampling of a 3-D box (Bridson, "Fast Poisson disk sampling in arbitrary
//! dimensions", SIGGRAPH 2007): well-spread joint sets for calibration, every pair at least
//! `radius` apart, every point of the box within `2 radius` of a sample, reproducible from a
//! seed.

use crate::util::Rng;

/// Why a sampling request cannot be met.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PoissonError {
    /// The box is empty, inverted or not finite.
    #[error("the box [{lower:?}, {upper:?}] must be finite with lower < upper on every axis")]
    BadBox {
        /// Lower corner.
        lower: [f64; 3],
        /// Upper corner.
        upper: [f64; 3],
    },
    /// A radius that is not a positive finite number.
    #[error("the radius {0} must be a positive finite number")]
    BadRadius(f64),
    /// No count of points was asked for.
    #[error("at least one point is needed")]
    NoPoints,
}

fn check_box(lower: &[f64; 3], upper: &[f64; 3]) -> Result<(), PoissonError> {
    let ok = (0..3).all(|k| lower[k].is_finite() && upper[k].is_finite() && lower[k] < upper[k]);
    if ok {
        Ok(())
    } else {
        Err(PoissonError::BadBox {
            lower: *lower,
            upper: *upper,
        })
    }
}

fn dist2(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum()
}

/// Bridson's algorithm in the box `[lower, upper]` with minimum distance `radius` and `k`
/// candidates per active sample (30 is the usual choice).
pub fn poisson_disc(
    lower: [f64; 3],
    upper: [f64; 3],
    radius: f64,
    k: usize,
    rng: &mut Rng,
) -> Result<Vec<[f64; 3]>, PoissonError> {
    check_box(&lower, &upper)?;
    if !(radius.is_finite() && radius > 0.0) {
        return Err(PoissonError::BadRadius(radius));
    }
    // Background grid: cells of side r / sqrt(3) hold at most one sample.
    let cell = radius / 3f64.sqrt();
    let dims: [usize; 3] =
        std::array::from_fn(|a| ((upper[a] - lower[a]) / cell).ceil().max(1.0) as usize);
    let mut grid: Vec<Option<usize>> = vec![None; dims[0] * dims[1] * dims[2]];
    let cell_of = |p: &[f64; 3]| -> [usize; 3] {
        std::array::from_fn(|a| (((p[a] - lower[a]) / cell) as usize).min(dims[a] - 1))
    };
    let index = |c: &[usize; 3]| (c[0] * dims[1] + c[1]) * dims[2] + c[2];
    let mut samples: Vec<[f64; 3]> = Vec::new();
    let mut active: Vec<usize> = Vec::new();
    let first: [f64; 3] = std::array::from_fn(|a| rng.range(lower[a], upper[a]));
    grid[index(&cell_of(&first))] = Some(0);
    samples.push(first);
    active.push(0);
    let r2 = radius * radius;
    while !active.is_empty() {
        let slot = rng.below(active.len());
        let centre = samples[active[slot]];
        let mut placed = false;
        for _ in 0..k {
            // Uniform in the spherical shell r <= |d| <= 2r.
            let dir = loop {
                let v = rng.in_ball(1.0);
                let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                if n > 1e-9 {
                    break v.map(|x| x / n);
                }
            };
            let rho = radius * rng.range(1.0, 8.0).cbrt();
            let p: [f64; 3] = std::array::from_fn(|a| centre[a] + rho * dir[a]);
            if (0..3).any(|a| p[a] < lower[a] || p[a] > upper[a]) {
                continue;
            }
            let c = cell_of(&p);
            let mut clear = true;
            'scan: for i in c[0].saturating_sub(2)..(c[0] + 3).min(dims[0]) {
                for j in c[1].saturating_sub(2)..(c[1] + 3).min(dims[1]) {
                    for l in c[2].saturating_sub(2)..(c[2] + 3).min(dims[2]) {
                        if let Some(s) = grid[index(&[i, j, l])]
                            && dist2(&samples[s], &p) < r2
                        {
                            clear = false;
                            break 'scan;
                        }
                    }
                }
            }
            if clear {
                grid[index(&c)] = Some(samples.len());
                active.push(samples.len());
                samples.push(p);
                placed = true;
                break;
            }
        }
        if !placed {
            active.swap_remove(slot);
        }
    }
    Ok(samples)
}

/// Exactly `n` well-spread points of the box from `seed`: the largest radius (by bisection,
/// relative to the box diagonal) whose Bridson set still has `n` points, then `n` of them
/// drawn at random (every pair stays at least that radius apart). Returns the points and the
/// radius.
pub fn poisson_disc_n(
    lower: [f64; 3],
    upper: [f64; 3],
    n: usize,
    seed: u64,
) -> Result<(Vec<[f64; 3]>, f64), PoissonError> {
    check_box(&lower, &upper)?;
    if n == 0 {
        return Err(PoissonError::NoPoints);
    }
    let diag = dist2(&lower, &upper).sqrt();
    let run = |r: f64| -> Result<Vec<[f64; 3]>, PoissonError> {
        poisson_disc(lower, upper, r, 30, &mut Rng::new(seed))
    };
    let (mut lo, mut hi) = (0.0, diag);
    let mut best = None;
    // The count falls as the radius grows; 40 halvings pin the radius to 1e-12 of the box.
    let mut r = diag / (n as f64).cbrt();
    for _ in 0..40 {
        let pts = run(r)?;
        if pts.len() >= n {
            lo = r;
            best = Some((pts, r));
        } else {
            hi = r;
        }
        r = 0.5 * (lo + hi);
        if r <= 0.0 {
            break;
        }
    }
    let (mut pts, r) = match best {
        Some(b) => b,
        None => {
            let r = diag * 1e-6;
            (run(r)?, r)
        }
    };
    let mut rng = Rng::new(seed ^ 0x5eed_5eed);
    let pick = rng.sample_indices(pts.len(), n);
    pts = pick.into_iter().map(|i| pts[i]).collect();
    Ok((pts, r))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_are_spread_inside_and_cover_the_box() {
        let (lo, hi) = ([-2.5e-3, -2.5e-3, -2.5e-3], [2.5e-3, 2.5e-3, 1.5e-3]);
        let r = 0.8e-3;
        let pts = poisson_disc(lo, hi, r, 30, &mut Rng::new(11)).expect("sampling");
        assert!(pts.len() > 50, "{} points", pts.len());
        for (i, a) in pts.iter().enumerate() {
            assert!((0..3).all(|k| a[k] >= lo[k] && a[k] <= hi[k]));
            for b in &pts[i + 1..] {
                assert!(dist2(a, b) >= r * r, "two samples closer than r");
            }
        }
        // Maximal: every probe of the box is within 2r of a sample.
        let mut rng = Rng::new(3);
        for _ in 0..2000 {
            let p: [f64; 3] = std::array::from_fn(|k| rng.range(lo[k], hi[k]));
            let near = pts
                .iter()
                .map(|s| dist2(s, &p))
                .fold(f64::INFINITY, f64::min);
            assert!(near < 4.0 * r * r, "a hole of radius {} > 2r", near.sqrt());
        }
        let again = poisson_disc(lo, hi, r, 30, &mut Rng::new(11)).expect("sampling");
        assert_eq!(pts, again, "same seed, same samples");
        let other = poisson_disc(lo, hi, r, 30, &mut Rng::new(12)).expect("sampling");
        assert_ne!(pts, other);
    }

    #[test]
    fn exactly_n_points_with_the_largest_radius() {
        let (lo, hi) = ([-2.5e-3; 3], [2.5e-3; 3]);
        let (pts, r) = poisson_disc_n(lo, hi, 155, 5).expect("sampling");
        assert_eq!(pts.len(), 155);
        let min = (0..pts.len())
            .flat_map(|i| (i + 1..pts.len()).map(move |j| (i, j)))
            .map(|(i, j)| dist2(&pts[i], &pts[j]).sqrt())
            .fold(f64::INFINITY, f64::min);
        assert!(min >= r);
        // Packing bound: 155 disjoint balls of diameter r fit in the cube grown by r/2
        // (density <= 0.7405), so r < 1.25 mm. Covering bound: balls of radius 2r around
        // the samples cover the cube, so 155 * 4/3 pi (2r)^3 >= 125 mm^3, r > 0.29 mm.
        assert!(r > 0.29e-3 && r < 1.25e-3, "radius {r}");
        assert_eq!(poisson_disc_n(lo, hi, 155, 5).expect("again").0, pts);
        assert!(matches!(
            poisson_disc_n(lo, lo, 5, 1),
            Err(PoissonError::BadBox { .. })
        ));
        assert!(matches!(
            poisson_disc(lo, hi, f64::NAN, 30, &mut Rng::new(1)),
            Err(PoissonError::BadRadius(_))
        ));
    }
}
