//! DETMAX (Mitchell 1974): choose n of N configurations to maximise det(J^T J) by exchanges
//! with excursions of growing size, from a seeded random start.
//!
//! Each configuration contributes a block B_i (rows x m) to the information matrix
//! M = sum B_i^T B_i. Adding i changes log det M by log det(I + B_i M^-1 B_i^T), removing it
//! by log det(I - B_i M^-1 B_i^T); both come from one Cholesky factor of M per sweep. Pools
//! of large blocks (see [`Pool`]) evaluate log det(M ± B_i^T B_i) afresh per candidate
//! instead, and reuse the scans of designs an excursion has visited before.

mod exchange;
mod gram;
mod kernels;
mod lanes;
mod narrow;
mod pool;
#[cfg(test)]
mod tests;

use serde::Serialize;

pub use pool::Pool;

use crate::util::{Monitor, Rng};

/// Settings of [`detmax`].
#[derive(Debug, Clone)]
pub struct DetmaxOptions {
    /// Number of configurations to select.
    pub n: usize,
    /// Seed of the random start.
    pub seed: u64,
    /// Largest excursion size tried before stopping.
    pub max_excursion: usize,
    /// Record the search's path in [`Selection::history`] (one exact determinant per
    /// improving excursion) and the start's determinant; off, the history is empty,
    /// [`Selection::log_det_start`] is NaN and [`Selection::log_det`] is the value the search
    /// tracked (log det(J^T J + ridge I), within ~1e-6 relative of the exact one, with no
    /// factorisation at the end): for a study that only wants the set.
    pub path: bool,
}

/// A selection and how it was found.
#[derive(Debug, Clone, Serialize)]
pub struct Selection {
    /// Selected configuration indices (sorted).
    pub selected: Vec<usize>,
    /// log det(J^T J) of the selection.
    pub log_det: f64,
    /// log det of the random start (NaN unless [`DetmaxOptions::path`]).
    pub log_det_start: f64,
    /// Improving excursions made.
    pub exchanges: usize,
    /// The search's path: the random start, then the design after each improving
    /// excursion (the last step is the selection); empty unless [`DetmaxOptions::path`].
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

/// The exchange state of either kind of pool.
enum Design<'a> {
    Thin(exchange::Design<'a>),
    Lanes(narrow::Design<'a>),
    Gram(gram::Design<'a>),
}

impl Clone for Design<'_> {
    fn clone(&self) -> Self {
        match self {
            Self::Thin(d) => Self::Thin(d.clone()),
            Self::Lanes(d) => Self::Lanes(d.clone()),
            Self::Gram(d) => Self::Gram(d.clone()),
        }
    }

    fn clone_from(&mut self, src: &Self) {
        match (self, src) {
            (Self::Lanes(a), Self::Lanes(b)) => a.clone_from(b),
            (this, src) => *this = src.clone(),
        }
    }
}

impl<'a> Design<'a> {
    fn new(pool: &'a Pool, start: &[usize], ridge: f64) -> Option<Self> {
        match &pool.gram {
            Some(g) => gram::Design::new(g, start, ridge).map(Self::Gram),
            None => match &pool.lanes {
                Some(lp) => narrow::Design::new(pool, lp, start, ridge).map(Self::Lanes),
                None => exchange::Design::new(pool, start, ridge).map(Self::Thin),
            },
        }
    }

    fn log_det(&self) -> f64 {
        match self {
            Self::Thin(d) => d.log_det,
            Self::Lanes(d) => d.log_det,
            Self::Gram(d) => d.log_det,
        }
    }

    fn selected(&self) -> Vec<usize> {
        match self {
            Self::Thin(d) => d.selected(),
            Self::Lanes(d) => d.selected(),
            Self::Gram(d) => d.selected(),
        }
    }

    fn greedy(&mut self, add: bool, memo: &mut gram::Memo) -> Option<usize> {
        match self {
            Self::Thin(d) => d.greedy(add),
            Self::Lanes(d) => {
                let (i, change) = d.best(add)?;
                (change > f64::NEG_INFINITY).then_some(())?;
                d.toggle(i, if add { 1.0 } else { -1.0 })?;
                Some(i)
            }
            Self::Gram(d) => d.greedy(add, memo),
        }
    }

    /// `src` with its greedy step taken, into this design's buffers: a lane design writes
    /// its updated state straight from `src`'s (no copy of the per-candidate state first);
    /// the others copy `src`, then step. On None this design is left in no useful state.
    fn greedy_from(&mut self, src: &Self, add: bool, memo: &mut gram::Memo) -> Option<usize> {
        match (&mut *self, src) {
            (Self::Lanes(d), Self::Lanes(s)) => {
                let (i, change) = s.best(add)?;
                (change > f64::NEG_INFINITY).then_some(())?;
                d.toggle_from(s, i, if add { 1.0 } else { -1.0 })?;
                Some(i)
            }
            _ => {
                self.clone_from(src);
                self.greedy(add, memo)
            }
        }
    }

    /// The last greedy step of an excursion, looked at before it is taken: the candidate and
    /// the log det after it. A lane design defers the toggle (most excursions are rejected);
    /// [`Design::commit`] takes it.
    fn peek(&mut self, add: bool, memo: &mut gram::Memo) -> Option<(usize, f64)> {
        match self {
            Self::Lanes(d) => {
                // Ranked on the tracked determinants, judged on the exact one.
                let (i, change) = d.best(add)?;
                (change > f64::NEG_INFINITY).then_some(())?;
                let change = d.exact_change(i, add);
                (change > f64::NEG_INFINITY).then_some((i, d.log_det + change))
            }
            _ => {
                let i = self.greedy(add, memo)?;
                Some((i, self.log_det()))
            }
        }
    }

    /// Take the step [`Design::peek`] looked at (a no-op for designs that took it then).
    fn commit(&mut self, i: usize, add: bool) -> Option<()> {
        match self {
            Self::Lanes(d) => d.toggle(i, if add { 1.0 } else { -1.0 }),
            _ => Some(()),
        }
    }

    /// log det(J^T J) of the design (no ridge), with the step `pending` [`Design::peek`]
    /// proposed (candidate, add) taken, whether or not the design has taken it yet.
    fn exact_log_det(&mut self, pool: &Pool, pending: Option<(usize, bool)>) -> f64 {
        match self {
            Self::Lanes(d) => d.exact_log_det(pending),
            _ => pool.log_det(&self.selected_after_pending(pending)),
        }
    }

    fn selected_after_pending(&self, pending: Option<(usize, bool)>) -> Vec<usize> {
        match pending {
            Some((i, add)) => self.selected_after(i, add),
            None => self.selected(),
        }
    }

    /// The member set with candidate `i` toggled as [`Design::peek`] proposed, whether or
    /// not the design has taken the step yet.
    fn selected_after(&self, i: usize, add: bool) -> Vec<usize> {
        let mut s = self.selected();
        match (self, add) {
            (Self::Lanes(_), true) => {
                let at = s.partition_point(|&x| x < i);
                s.insert(at, i);
            }
            (Self::Lanes(_), false) => s.retain(|&x| x != i),
            _ => {}
        }
        s
    }

    /// Recompute the tracked state from the member set when more than `every` updates were
    /// made since (the thin state drifts; the Gram state is recomputed at every step and
    /// never does); whether it did.
    fn rebuild(&mut self, pool: &Pool, ridge: f64, every: usize) -> Option<bool> {
        match self {
            Self::Thin(d) if d.updates > every => d.rebuild(ridge).map(|()| true),
            Self::Lanes(d) if d.updates > every => d.rebuild(pool, ridge).map(|()| true),
            _ => Some(false),
        }
    }
}

/// The step of `design` after `exchanges` improving excursions.
fn step(pool: &Pool, design: &mut Design<'_>, exchanges: usize) -> DetmaxStep {
    let selected = design.selected();
    DetmaxStep {
        exchanges,
        log_det: design.exact_log_det(pool, None),
        selected,
    }
}

/// Toggles after which a design's tracked state is computed afresh from its members. Every
/// toggle and every acceptance is computed from P in double precision (the lane designs'
/// single-precision D only ranks candidates), and an accepted exchange whose determinant
/// drifted rebuilds at once, so this only bounds the ranking's drift: 256 toggles of
/// ~1e-7 each, against determinant gaps of percents between the candidates a scan compares
/// (the twin's dispersion study picks the same 2,007 sets as with 64, a quarter of the
/// rebuilds: 0.16 CPU-s of 2.86).
const REBUILD_AFTER: usize = 256;

/// [`REBUILD_AFTER`], or what a test on this thread set.
fn rebuild_after() -> usize {
    #[cfg(test)]
    return tests::REBUILD_AFTER_TEST.with(|r| r.get());
    #[cfg(not(test))]
    REBUILD_AFTER
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
    let log_det_start = if opts.path {
        pool.log_det(&start)
    } else {
        f64::NAN
    };
    let mut current = design.log_det();
    let mut memo = gram::Memo::new();
    let min_rows = pool.rows.iter().copied().min().unwrap_or(1);
    let mut exchanges = 0;
    let mut history = Vec::new();
    if opts.path {
        history.push(step(pool, &mut design, 0));
    }
    // The trial designs of an excursion, their buffers reused from try to try. An excursion
    // of size k starts with the k - 1 greedy steps the one of size k - 1 took in the same
    // direction: `ahead[up]` keeps them (`ahead_k[up]` steps from `design`, None when not
    // valid), so each larger excursion takes one new step out, not k; a third takes the
    // steps back. Only lane designs look at their last step without taking it, so only they
    // can keep a size-1 excursion's step for the next size; the others have one trial design.
    let reuse = matches!(design, Design::Lanes(_));
    let n_ahead = if reuse { 2 } else { 1 };
    let mut trials = vec![design.clone(); n_ahead + usize::from(reuse)];
    let mut ahead_k: [Option<usize>; 2] = [None, None];
    let mut k = 1;
    let kmax = opts.max_excursion.max(1);
    while k <= kmax {
        if monitor.is_cancelled() {
            return Err(crate::identify::IdentifyError::Cancelled);
        }
        monitor.progress(k as f64 / (kmax + 1) as f64, "detmax");
        if design
            .rebuild(pool, ridge, rebuild_after())
            .ok_or_else(singular)?
        {
            #[cfg(test)]
            tests::REBUILDS.with(|r| r.set(r.get() + 1));
            ahead_k = [None, None];
        }
        // Excursion up (add k, then remove k); if it does not improve, down (remove k, then
        // add k) unless removing k would leave fewer equations than parameters. A move is
        // accepted on the exact determinant, and the tracked state is rebuilt if it drifted.
        let mut improved = false;
        for up in [true, false] {
            if !up && (n.saturating_sub(k)) * min_rows < pool.m {
                continue;
            }
            let (ahead, back) = trials.split_at_mut(n_ahead);
            let slot = if reuse { usize::from(up) } else { 0 };
            let (out, taken) = (&mut ahead[slot], &mut ahead_k[slot]);
            let mut steps = match *taken {
                Some(s) if reuse && s + 1 == k => s,
                // The first step out written from the design's state.
                _ if out.greedy_from(&design, up, &mut memo).is_some() => 1,
                _ => 0,
            };
            *taken = None;
            while (1..k).contains(&steps) && out.greedy(up, &mut memo).is_some() {
                steps += 1;
            }
            if steps < k {
                continue;
            }
            // The steps back, on a copy when the steps out are kept for the next size (the
            // first step back written from the steps out).
            // `back_taken`: the steps back taken so far (None: the first one failed).
            let (trial, back_taken) = match (k > 1, back.first_mut()) {
                (true, Some(d)) => {
                    let first = d.greedy_from(out, !up, &mut memo).is_some();
                    (d, first.then_some(1))
                }
                _ => (out, Some(0)),
            };
            if reuse {
                *taken = Some(k);
            }
            // The last step is looked at first and taken only if the excursion is accepted.
            let came_back = back_taken
                .is_some_and(|b| (b..k - 1).all(|_| trial.greedy(!up, &mut memo).is_some()));
            let Some((last, log_det)) = came_back.then(|| trial.peek(!up, &mut memo)).flatten()
            else {
                continue;
            };
            if log_det <= current + 1e-9 * current.abs().max(1.0) {
                continue;
            }
            // Up excursions never pass through a design with fewer rows than now; down ones
            // can come close to singular, so their gain is checked on the exact determinant.
            let exact = if up {
                log_det
            } else {
                trial.exact_log_det(pool, Some((last, !up)))
            };
            if exact > current + 1e-9 * current.abs().max(1.0) {
                trial.commit(last, !up).ok_or_else(singular)?;
                if (exact - trial.log_det()).abs() > 1e-6 * exact.abs().max(1.0) {
                    trial.rebuild(pool, ridge, 0).ok_or_else(singular)?;
                }
                std::mem::swap(&mut design, trial);
                ahead_k = [None, None];
                current = exact;
                improved = true;
                break;
            }
        }
        if improved {
            exchanges += 1;
            if opts.path {
                history.push(step(pool, &mut design, exchanges));
            }
            k = 1;
        } else {
            k += 1;
        }
    }
    let selected = design.selected();
    // With the path, from the members afresh (the last step's); else the tracked value (an
    // exact one costs a factorisation per search; 0.5-0.9 % of a dispersion study, which
    // only keeps the set).
    let log_det = if opts.path {
        pool.log_det(&selected)
    } else {
        design.log_det()
    };
    // The last step is the selection: its determinant computed afresh.
    if let Some(last) = history.last_mut() {
        last.log_det = log_det;
    }
    Ok(Selection {
        log_det,
        log_det_start,
        selected,
        exchanges,
        history,
    })
}
