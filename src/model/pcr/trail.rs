//! The last solutions of consecutive warm solves and the solution they predict for the next
//! input: a quintic through the last six in the distance travelled along the inputs' path.
//!
//! The degree is measured, not guessed (`calibd bench pcr`, residual of the prediction in
//! units of the solver's tolerance): along the 3 um joint path a quadratic is off by about
//! 3e3, a cubic by 7, a quartic by 1.5 and a quintic mostly by less than 1, so most warm
//! solves there need one integration; along the 47 um steps of the IK circle the quartic is
//! off by 300 and the quintic by a few. A sextic extrapolates the solutions' own rounding
//! (its weights reach 35) more than it removes truncation, and was slower on the joint path.
//! The points kept are the solutions one chord step on (`Solved::refined`), which are more
//! accurate than the tolerance asks; a poor prediction is caught by its residual.

use super::shooting::{N, Vec12};

/// Solutions kept (a quintic passes through six).
const KEEP: usize = 6;

/// One solved configuration: scaled inputs (joints or pose) and unknowns.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Point {
    input: [f64; 3],
    z: Vec12,
}

/// The solutions of the last consecutive solves, newest last.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Trail {
    len: usize,
    points: [Point; KEEP],
}

/// Largest distance between the new input and the inputs' extrapolated path, relative to the
/// new step: farther, the inputs do not follow a smooth path and no prediction is made.
const OFF_PATH: f64 = 0.05;

/// Steps along the path may differ by at most this factor from the new one (extrapolating
/// far beyond closely spaced points amplifies their errors).
const SPACING: f64 = 2.0;

fn distance(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

impl Trail {
    /// No solution yet.
    pub(crate) const EMPTY: Self = Self {
        len: 0,
        points: [Point {
            input: [0.0; 3],
            z: [0.0; N],
        }; KEEP],
    };

    /// Appends the solution `z` at the scaled inputs `input` (the oldest drops out).
    pub(crate) fn push(&mut self, input: [f64; 3], z: Vec12) {
        if self.len == KEEP {
            self.points.copy_within(1.., 0);
        } else {
            self.len += 1;
        }
        self.points[self.len - 1] = Point { input, z };
    }

    /// The unknowns at `input` extrapolated (Lagrange, in the distance along the inputs'
    /// path) from the kept solutions; `None` with fewer than six, or when the inputs do
    /// not follow a smooth, evenly stepped path to `input`.
    pub(crate) fn predict(&self, input: &[f64; 3]) -> Option<Vec12> {
        if self.len < KEEP {
            return None;
        }
        let p = &self.points;
        let step = distance(input, &p[KEEP - 1].input);
        // Abscissae: the newest solution at 0, older ones behind it, the new input ahead.
        let mut t = [0.0; KEEP];
        for k in (0..KEEP - 1).rev() {
            let gap = distance(&p[k + 1].input, &p[k].input);
            if !(gap * SPACING >= step && gap <= SPACING * step) {
                return None;
            }
            t[k] = t[k + 1] - gap;
        }
        if !(step > 0.0) {
            return None;
        }
        // Lagrange weights, one division each.
        let w: [f64; KEEP] = std::array::from_fn(|i| {
            let (mut num, mut den) = (1.0, 1.0);
            for j in (0..KEEP).filter(|&j| j != i) {
                num *= step - t[j];
                den *= t[i] - t[j];
            }
            num / den
        });
        let along: [f64; 3] =
            std::array::from_fn(|c| (0..KEEP).map(|i| w[i] * p[i].input[c]).sum());
        if distance(&along, input) > OFF_PATH * step {
            return None;
        }
        Some(std::array::from_fn(|c| {
            (0..KEEP).map(|i| w[i] * p[i].z[c]).sum()
        }))
    }
}
