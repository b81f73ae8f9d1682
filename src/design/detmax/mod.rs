//! DETMAX (Mitchell 1974): choose n of N configurations to maximise det(J^T J) by exchanges
//! with excursions of growing size, from a seeded random start.
//!
//! Each configuration contributes a block B_i (rows x m) to the information matrix
//! M = sum B_i^T B_i. Adding i changes log det M by log det(I + B_i M^-1 B_i^T), removing it
//! by log det(I - B_i M^-1 B_i^T); both come from one Cholesky factor of M per sweep.

mod exchange;
mod kernels;
mod pool;

use serde::Serialize;

pub use pool::Pool;

use crate::util::{Monitor, Rng};
use exchange::Design;

/// Settings of [`detmax`].
#[derive(Debug, Clone)]
pub struct DetmaxOptions {
    /// Number of configurations to select.
    pub n: usize,
    /// Seed of the random start.
    pub seed: u64,
    /// Largest excursion size tried before stopping.
    pub max_excursion: usize,
}

/// A selection and how it was found.
#[derive(Debug, Clone, Serialize)]
pub struct Selection {
    /// Selected configuration indices (sorted).
    pub selected: Vec<usize>,
    /// log det(J^T J) of the selection.
    pub log_det: f64,
    /// log det of the random start.
    pub log_det_start: f64,
    /// Improving excursions made.
    pub exchanges: usize,
    /// The search's path: the random start, then the design after each improving
    /// excursion (the last step is the selection).
    pub history: Vec<DetmaxStep>,
}

/// One design on DETMAX's path.
#[derive(Debug, Clone, Serialize)]
pub struct DetmaxStep {
    /// Improving excursions made before it (0: the random start).
    pub exchanges: usize,
    /// log det(J^T J) of the design (as [`Selection::log_det`]).
    pub log_det: f64,
    /// Its configuration indices (sorted).
    pub selected: Vec<usize>,
}

/// The step of `design` after `exchanges` improving excursions.
fn step(pool: &Pool, design: &Design<'_>, exchanges: usize) -> DetmaxStep {
    let selected = design.selected();
    DetmaxStep {
        exchanges,
        log_det: pool.log_det(&selected),
        selected,
    }
}

/// Select `opts.n` configurations of `pool` maximising det(J^T J).
pub fn detmax(
    pool: &Pool,
    opts: &DetmaxOptions,
    monitor: &dyn Monitor,
) -> Result<Selection, crate::identify::IdentifyError> {
    let n = opts.n.min(pool.len());
    let mut rng = Rng::new(opts.seed);
    let start = rng.sample_indices(pool.len(), n);
    // A tiny ridge keeps a possibly singular random start usable.
    let trace = pool.frobenius2();
    let ridge = 1e-9 * trace / (pool.len().max(1) * pool.m.max(1)) as f64;
    let singular = || {
        crate::identify::IdentifyError::Model("the pool's information matrix is singular".into())
    };
    let mut design = Design::new(pool, &start, ridge).ok_or_else(singular)?;
    let log_det_start = pool.log_det(&start);
    let mut current = design.log_det;
    let min_rows = pool.rows.iter().copied().min().unwrap_or(1);
    let mut exchanges = 0;
    let mut history = vec![step(pool, &design, 0)];
    let mut k = 1;
    let kmax = opts.max_excursion.max(1);
    while k <= kmax {
        if monitor.is_cancelled() {
            return Err(crate::identify::IdentifyError::Cancelled);
        }
        monitor.progress(k as f64 / (kmax + 1) as f64, "detmax");
        if design.updates > 64 {
            design.rebuild(ridge).ok_or_else(singular)?;
        }
        // Excursion up (add k, then remove k); if it does not improve, down (remove k, then
        // add k) unless removing k would leave fewer equations than parameters. A move is
        // accepted on the exact determinant, and the tracked state is rebuilt if it drifted.
        let mut improved = false;
        for up in [true, false] {
            if !up && (n.saturating_sub(k)) * min_rows < pool.m {
                continue;
            }
            let mut d = design.clone();
            let ok =
                (0..k).all(|_| d.greedy(up).is_some()) && (0..k).all(|_| d.greedy(!up).is_some());
            if !ok || d.log_det <= current + 1e-9 * current.abs().max(1.0) {
                continue;
            }
            // Up excursions never pass through a design with fewer rows than now; down ones
            // can come close to singular, so their gain is checked on the exact determinant.
            let exact = if up {
                d.log_det
            } else {
                pool.log_det(&d.selected())
            };
            if exact > current + 1e-9 * current.abs().max(1.0) {
                if (exact - d.log_det).abs() > 1e-6 * exact.abs().max(1.0) {
                    d.rebuild(ridge).ok_or_else(singular)?;
                }
                design = d;
                current = exact;
                improved = true;
                break;
            }
        }
        if improved {
            exchanges += 1;
            history.push(step(pool, &design, exchanges));
            k = 1;
        } else {
            k += 1;
        }
    }
    let selected = design.selected();
    Ok(Selection {
        log_det: pool.log_det(&selected),
        log_det_start,
        selected,
        exchanges,
        history,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::NoMonitor;
    use nalgebra::DMatrix;

    /// On a small pool the exhaustive optimum is known: DETMAX must find it, and it must be
    /// reproducible from the seed.
    #[test]
    fn finds_the_exhaustive_optimum_on_a_small_pool() {
        let mut rng = Rng::new(5);
        let blocks: Vec<DMatrix<f64>> = (0..12)
            .map(|_| DMatrix::from_fn(2, 3, |_, _| rng.normal()))
            .collect();
        let pool = Pool::from_blocks(&blocks);
        let n = 3;
        let mut best = f64::NEG_INFINITY;
        for a in 0..12 {
            for b in a + 1..12 {
                for c in b + 1..12 {
                    best = best.max(pool.log_det(&[a, b, c]));
                }
            }
        }
        let opts = DetmaxOptions {
            n,
            seed: 1,
            max_excursion: 3,
        };
        let s = detmax(&pool, &opts, &NoMonitor).unwrap();
        assert!((s.log_det - best).abs() < 1e-9, "{} vs {}", s.log_det, best);
        let again = detmax(&pool, &opts, &NoMonitor).unwrap();
        assert_eq!(s.selected, again.selected);
        // The incremental determinant update agrees with a direct computation.
        let direct = pool.stacked(&s.selected);
        let ld = (direct.transpose() * &direct).determinant().ln();
        assert!((ld - s.log_det).abs() < 1e-9);
    }

    /// Blocks of more than 8 rows (marker clusters) take the matrix-product path.
    #[test]
    fn large_blocks_reach_the_exhaustive_optimum() {
        let mut rng = Rng::new(8);
        let blocks: Vec<DMatrix<f64>> = (0..10)
            .map(|_| DMatrix::from_fn(9, 20, |_, _| rng.normal()))
            .collect();
        let pool = Pool::from_blocks(&blocks);
        let mut best = f64::NEG_INFINITY;
        for a in 0..10 {
            for b in a + 1..10 {
                for c in b + 1..10 {
                    best = best.max(pool.log_det(&[a, b, c]));
                }
            }
        }
        let opts = DetmaxOptions {
            n: 3,
            seed: 2,
            max_excursion: 3,
        };
        let s = detmax(&pool, &opts, &NoMonitor).unwrap();
        assert!((s.log_det - best).abs() < 1e-9, "{} vs {}", s.log_det, best);
    }

    fn last_gain(s: &Selection) -> f64 {
        s.history.last().map_or(0.0, |l| l.log_det) - s.history[0].log_det
    }

    /// Marker-cluster-like blocks (36 rows of rank 12, mixed with full-rank 5-row blocks):
    /// the rank-reduced pool picks exactly the set the unreduced pool picks, with the same
    /// determinant to rounding.
    #[test]
    fn reduced_blocks_pick_the_same_set_as_the_full_blocks() {
        let mut rng = Rng::new(11);
        let blocks: Vec<DMatrix<f64>> = (0..60)
            .map(|i| {
                if i % 4 == 3 {
                    DMatrix::from_fn(5, 24, |_, _| rng.normal())
                } else {
                    let base = DMatrix::from_fn(12, 24, |_, _| rng.normal());
                    DMatrix::from_fn(36, 12, |_, _| rng.normal()) * base
                }
            })
            .collect();
        let reduced = Pool::from_blocks(&blocks);
        let exact = Pool::exact(&blocks);
        assert!((0..60).all(|i| reduced.block_rows(i) == if i % 4 == 3 { 5 } else { 12 }));
        let opts = DetmaxOptions {
            n: 5,
            seed: 7,
            max_excursion: 4,
        };
        let a = detmax(&reduced, &opts, &NoMonitor).unwrap();
        let b = detmax(&exact, &opts, &NoMonitor).unwrap();
        assert_eq!(a.selected, b.selected);
        assert!((a.log_det - b.log_det).abs() < 1e-9 * b.log_det.abs().max(1.0));
        assert!(a.exchanges > 0, "the search moved from its random start");
        // The path: one step per improving excursion after the start, each better than the
        // one before, the last one the selection.
        assert_eq!(a.history.len(), a.exchanges + 1);
        assert!(
            a.history
                .windows(2)
                .all(|w| w[1].log_det > w[0].log_det - 1e-6 * w[0].log_det.abs())
        );
        assert!(last_gain(&a) > 0.0);
        let last = a.history.last().unwrap();
        assert_eq!((last.log_det, &last.selected), (a.log_det, &a.selected));
    }
}
