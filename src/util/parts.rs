//! Large computations split into a fixed number of parts that the cores take one at a time.
//! A core slowed by another process then takes fewer parts instead of holding the others up
//! at the join (with one part per core, a large identification on a loaded machine ran at
//! the pace of its slowest core), and since the split does not depend on the number of
//! cores, neither does any sum over the parts: the same bits on 1, 2 or 64 cores.
//!
//! For long phases only: the caller works while its helpers start, and waits at the end for
//! a helper that has not yet had a core. Below a millisecond a phase is then slower under
//! load than one part per core (a 1,440-measurement identification's per-measurement
//! evaluations with one core busy: 8.0 -> 11 ms), so those keep one part per core; their
//! results are per item, so the split changes no bits.

use std::sync::{Mutex, PoisonError};

/// Parts a large computation is split into: enough that a core shared with another process
/// leaves the other core parts to take, few enough that the parts' accumulators stay small
/// (measured on a 100,000-measurement identification with one core busy: 0.50-0.52 s with
/// one part per core, 0.39-0.46 s with 8, no better with 16 or 32, whose accumulators
/// raise the peak memory from 80 to 83 and 93 MB).
pub const PARTS: usize = 8;

/// Contiguous ranges of `n` items in `parts` parts of `ceil(n / parts)` items (the last
/// shorter; fewer parts when `n` is small).
pub fn ranges(n: usize, parts: usize) -> Vec<std::ops::Range<usize>> {
    let chunk = n.div_ceil(parts.max(1)).max(1);
    (0..n)
        .step_by(chunk)
        .map(|s| s..(s + chunk).min(n))
        .collect()
}

/// `f` on every part, on up to as many scoped threads as there are cores (the caller's
/// among them), each taking the next part when it is done with one. A worker's panic is
/// passed on.
pub fn for_each<T: Send>(parts: Vec<T>, f: &(dyn Fn(T) + Sync)) {
    // One part asks nothing of the system (`available_parallelism` reads the cgroup's
    // files: 0.2 ms of a 2 ms identification when it was asked every time).
    let workers = match parts.len() {
        0 | 1 => 1,
        n => std::thread::available_parallelism().map_or(1, |c| c.get().min(n)),
    };
    if workers <= 1 {
        parts.into_iter().for_each(f);
        return;
    }
    let queue = Mutex::new(parts.into_iter());
    let take = || queue.lock().unwrap_or_else(PoisonError::into_inner).next();
    let work = || {
        while let Some(p) = take() {
            f(p);
        }
    };
    std::thread::scope(|s| {
        let handles: Vec<_> = (1..workers).map(|_| s.spawn(work)).collect();
        work();
        for h in handles {
            if let Err(e) = h.join() {
                std::panic::resume_unwind(e);
            }
        }
    });
}

/// `f` on every part as [`for_each`] runs it, the results in the parts' order.
pub fn map<T: Send, R: Send>(parts: Vec<T>, f: &(dyn Fn(T) -> R + Sync)) -> Vec<R> {
    let mut out: Vec<Option<R>> = Vec::new();
    out.resize_with(parts.len(), || None);
    let slots: Vec<(T, &mut Option<R>)> = parts.into_iter().zip(out.iter_mut()).collect();
    for_each(slots, &|(p, slot): (T, &mut Option<R>)| *slot = Some(f(p)));
    out.into_iter().flatten().collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// The ranges cover 0..n in order, without overlap, at most `parts` of them.
    #[test]
    fn ranges_tile_the_items() {
        for (n, parts) in [
            (0, 4),
            (1, 16),
            (15, 16),
            (16, 16),
            (17, 16),
            (1000, 16),
            (7, 1),
        ] {
            let r = ranges(n, parts);
            assert!(r.len() <= parts.max(1), "{n} {parts}");
            let flat: Vec<usize> = r.iter().flat_map(|r| r.clone()).collect();
            assert_eq!(flat, (0..n).collect::<Vec<_>>(), "{n} {parts}");
        }
    }

    /// Every part runs exactly once and `map` keeps the parts' order, whichever thread ran
    /// which part.
    #[test]
    fn every_part_runs_once_and_results_keep_their_order() {
        let runs = AtomicUsize::new(0);
        let out = map((0..100).collect(), &|k: usize| {
            runs.fetch_add(1, Ordering::Relaxed);
            k * k
        });
        assert_eq!(runs.load(Ordering::Relaxed), 100);
        assert_eq!(out, (0..100).map(|k| k * k).collect::<Vec<_>>());
        let mut cells = [0u32; 40];
        let parts: Vec<&mut u32> = cells.iter_mut().collect();
        for_each(parts, &|c: &mut u32| *c += 1);
        assert!(cells.iter().all(|&c| c == 1));
    }

    /// A panic in a part reaches the caller.
    #[test]
    fn a_panic_in_a_part_is_passed_on() {
        let r = std::panic::catch_unwind(|| {
            for_each((0..8).collect(), &|k: usize| assert!(k != 5, "part five"));
        });
        assert!(r.is_err());
    }
}
