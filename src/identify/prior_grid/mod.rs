//! A prior the data choose: the two prior standard deviations (lengths and angles) picked
//! by K-fold cross-validation over a log-spaced 2-D grid that extends itself while the
//! optimum sits on its edge, so the answer is never an edge unless a limit stops it.
//!
//! Only `std / sqrt(weight)` enters the MAP objective, so the grid is over the two standard
//! deviations with the weight held at 1; every cell's held-out RMS is reported (the
//! sensitivity of the calibration to the prior).

use serde::{Deserialize, Serialize};

use super::IdentifyError;
use super::prior::{grouped_folds, held_out_rms};

/// One log-spaced axis: value `i` is `base * ratio^i`; cells `start..=end` are tried first,
/// the grid may grow to `min..=max`.
#[derive(Debug, Clone)]
pub struct LogAxis {
    /// Value at index 0.
    pub base: f64,
    /// Ratio of neighbouring values (> 1).
    pub ratio: f64,
    /// First index of the initial grid.
    pub start: i32,
    /// Last index of the initial grid.
    pub end: i32,
    /// Lowest index the grid may extend to.
    pub min: i32,
    /// Highest index the grid may extend to.
    pub max: i32,
}

impl LogAxis {
    /// The value at index `i`.
    pub fn value(&self, i: i32) -> f64 {
        self.base * self.ratio.powi(i)
    }

    /// The value at half-step `h` (index `h / 2`).
    fn half(&self, h: i32) -> f64 {
        self.base * self.ratio.powf(h as f64 / 2.0)
    }
}

/// Held-out RMS of one grid cell.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct GridCell {
    /// Value on the first axis.
    pub a: f64,
    /// Value on the second axis.
    pub b: f64,
    /// RMS of the held-out residuals over all folds (the score's units; infinite when a
    /// fold's fit failed).
    #[serde(deserialize_with = "crate::util::serde_num::f64_or_nan")]
    pub rms: f64,
}

/// The chosen cell and the whole grid.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct GridChoice {
    /// Chosen value on the first axis.
    pub a: f64,
    /// Chosen value on the second axis.
    pub b: f64,
    /// Its held-out RMS.
    pub rms: f64,
    /// Every cell evaluated, first axis outer, both ascending.
    pub cells: Vec<GridCell>,
    /// True when the optimum lies on the grid's edge and the limits stopped the extension.
    pub at_edge: bool,
    /// Rows and columns added beyond the initial grid.
    pub extensions: usize,
    /// Number of folds.
    pub folds: usize,
}

impl GridChoice {
    /// Smallest and largest finite held-out RMS over the grid (the sensitivity range).
    pub fn range(&self) -> (f64, f64) {
        self.cells
            .iter()
            .map(|c| c.rms)
            .filter(|v| v.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            })
    }
}

/// Choose `(a, b)` on the grid of `axes` by K-fold over items in groups (`group[i]` as in
/// [`grouped_folds`]): `score(a, b, train, test)` fits on `train` and returns the sum of
/// squared held-out residuals and their count. The grid grows by a row or column beyond any
/// edge that holds the optimum, within the axes' limits; then the eight half-step
/// neighbours of an interior optimum are tried too. The smallest RMS wins (the first on
/// ties). A fold whose fit fails scores infinity; cancellation stops at once.
pub fn choose_grid(
    axes: &[LogAxis; 2],
    group: &[usize],
    k: usize,
    seed: u64,
    mut score: impl FnMut(f64, f64, &[usize], &[usize]) -> Result<(f64, usize), IdentifyError>,
) -> Result<GridChoice, IdentifyError> {
    for ax in axes {
        if !(ax.base > 0.0 && ax.ratio > 1.0 && ax.min <= ax.start && ax.start + 2 <= ax.end)
            || ax.end > ax.max
        {
            return Err(IdentifyError::Model(format!(
                "grid axis {ax:?}: needs base > 0, ratio > 1, at least 3 values within limits"
            )));
        }
    }
    let parts = grouped_folds(group, k, seed);
    // Keys are half-steps: the coarse grid sits on even keys.
    let mut cells: std::collections::BTreeMap<(i32, i32), f64> = Default::default();
    let mut eval = |cells: &mut std::collections::BTreeMap<(i32, i32), f64>,
                    (h, g): (i32, i32)|
     -> Result<(), IdentifyError> {
        if !cells.contains_key(&(h, g)) {
            let (a, b) = (axes[0].half(h), axes[1].half(g));
            let rms = held_out_rms(&parts, |tr, te| score(a, b, tr, te))?;
            cells.insert((h, g), rms);
        }
        Ok(())
    };
    let (mut ra, mut rb) = ((axes[0].start, axes[0].end), (axes[1].start, axes[1].end));
    let mut extensions = 0;
    let best_of = |cells: &std::collections::BTreeMap<(i32, i32), f64>| {
        cells
            .iter()
            .filter(|(_, r)| r.is_finite())
            .min_by(|x, y| x.1.total_cmp(y.1))
            .map(|(&hg, &r)| (hg, r))
            .ok_or_else(|| IdentifyError::Model("every fold fit failed in every cell".into()))
    };
    let (bi, bj) = loop {
        for i in ra.0..=ra.1 {
            for j in rb.0..=rb.1 {
                eval(&mut cells, (2 * i, 2 * j))?;
            }
        }
        let ((h, g), _) = best_of(&cells)?;
        let (bi, bj) = (h / 2, g / 2);
        let mut grew = false;
        for (idx, range, ax) in [(bi, &mut ra, &axes[0]), (bj, &mut rb, &axes[1])] {
            if idx == range.0 && range.0 > ax.min {
                range.0 -= 1;
                grew = true;
            } else if idx == range.1 && range.1 < ax.max {
                range.1 += 1;
                grew = true;
            }
        }
        if !grew {
            break (bi, bj);
        }
        extensions += 1;
    };
    let at_edge = bi == ra.0 || bi == ra.1 || bj == rb.0 || bj == rb.1;
    if !at_edge {
        for dh in -1..=1 {
            for dg in -1..=1 {
                eval(&mut cells, (2 * bi + dh, 2 * bj + dg))?;
            }
        }
    }
    let ((h, g), rms) = best_of(&cells)?;
    Ok(GridChoice {
        a: axes[0].half(h),
        b: axes[1].half(g),
        rms,
        cells: cells
            .iter()
            .map(|(&(h, g), &rms)| GridCell {
                a: axes[0].half(h),
                b: axes[1].half(g),
                rms,
            })
            .collect(),
        at_edge,
        extensions,
        folds: parts.len(),
    })
}

/// The two axes of `scale: "auto"`: length std (mm) 0.25..4 then 0.001..256, angle std
/// (deg) 0.0625..1 then 0.00006..64, each step a factor 2.
pub fn auto_axes() -> [LogAxis; 2] {
    [
        LogAxis {
            base: 1.0,
            ratio: 2.0,
            start: -2,
            end: 2,
            min: -10,
            max: 8,
        },
        LogAxis {
            base: 1.0,
            ratio: 2.0,
            start: -4,
            end: 0,
            min: -14,
            max: 6,
        },
    ]
}

/// One cell of the automatic prior's grid.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AutoCell {
    /// Length std (mm).
    pub length_mm: f64,
    /// Angle std (deg).
    pub angle_deg: f64,
    /// Held-out marker RMS (mm), null when a fold failed.
    #[serde(deserialize_with = "crate::util::serde_num::f64_or_nan")]
    pub rms_mm: f64,
}

/// What `scale: "auto"` chose, and the held-out error over its grid (the sensitivity).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AutoPrior {
    /// `k_fold_grid`: K-fold over a self-extending grid of length and angle std.
    pub method: String,
    /// Chosen length std (mm); the weight is 1 (only std / sqrt(weight) matters).
    pub length_mm: f64,
    /// Chosen angle std (deg).
    pub angle_deg: f64,
    /// Held-out RMS of the chosen cell (mm).
    pub held_out_rms_mm: f64,
    /// Smallest and largest held-out RMS over the grid (mm).
    pub sensitivity_mm: [f64; 2],
    /// True when the optimum is on an edge the grid could not extend past.
    pub at_edge: bool,
    /// Why `at_edge` matters, when it is set.
    pub warning: Option<String>,
    /// Rows and columns added beyond the initial 5 x 5 grid.
    pub extensions: usize,
    /// Folds of the cross-validation.
    pub folds: usize,
    /// Every cell tried.
    pub grid: Vec<AutoCell>,
}

impl AutoPrior {
    /// The report of a grid whose axes are (length mm, angle deg) and RMS in mm.
    pub fn of(c: &GridChoice) -> AutoPrior {
        let (lo, hi) = c.range();
        AutoPrior {
            method: "k_fold_grid".into(),
            length_mm: c.a,
            angle_deg: c.b,
            held_out_rms_mm: c.rms,
            sensitivity_mm: [lo, hi],
            at_edge: c.at_edge,
            warning: c.at_edge.then(|| {
                format!(
                    "the held-out error is smallest at the grid's limit ({} mm, {} deg): \
                     the data hardly constrain the prior there; give default_std instead",
                    c.a, c.b
                )
            }),
            extensions: c.extensions,
            folds: c.folds,
            grid: c
                .cells
                .iter()
                .map(|x| AutoCell {
                    length_mm: x.a,
                    angle_deg: x.b,
                    rms_mm: x.rms,
                })
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests;
