//! DETMAX against the exhaustive optimum and against a straightforward implementation (a
//! fresh dense Cholesky of the information matrix for every candidate at every step).

use super::*;
use crate::util::NoMonitor;
use nalgebra::DMatrix;

thread_local! {
    /// Periodic rebuilds of the searches run on this thread (so a test can show it had some).
    pub(super) static REBUILDS: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
    /// The rebuild interval of the searches run on this thread.
    pub(super) static REBUILD_AFTER_TEST: std::cell::Cell<usize> =
        const { std::cell::Cell::new(super::REBUILD_AFTER) };
}

/// log det(sum of B_i^T B_i over `set` + ridge I), -inf if not positive definite.
fn dense_log_det(blocks: &[DMatrix<f64>], set: &[bool], ridge: f64) -> f64 {
    let m = blocks[0].ncols();
    let mut a = DMatrix::<f64>::identity(m, m) * ridge;
    for (b, _) in blocks.iter().zip(set).filter(|(_, s)| **s) {
        a += b.tr_mul(b);
    }
    a.cholesky().map_or(f64::NEG_INFINITY, |c| {
        c.l_dirty().diagonal().iter().map(|v| 2.0 * v.ln()).sum()
    })
}

/// Straightforward DETMAX: the same search as [`detmax`] (start, ridge, excursions,
/// acceptance), every greedy step choosing by the dense log det of each candidate's design.
/// Returns the selection, its log det and the improving excursions.
fn reference(blocks: &[DMatrix<f64>], opts: &DetmaxOptions) -> (Vec<usize>, f64, usize) {
    let (len, m) = (blocks.len(), blocks[0].ncols());
    let n = opts.n.min(len);
    let start = Rng::new(opts.seed).sample_indices(len, n);
    let trace: f64 = blocks.iter().map(|b| b.norm_squared()).sum();
    let ridge = 1e-9 * trace / (len * m) as f64;
    let mut set = vec![false; len];
    start.iter().for_each(|&i| set[i] = true);
    let greedy = |set: &mut Vec<bool>, add: bool| -> Option<f64> {
        let mut best: Option<(usize, f64)> = None;
        for i in 0..len {
            if set[i] == add {
                continue;
            }
            set[i] = add;
            let v = dense_log_det(blocks, set, ridge);
            set[i] = !add;
            if best.is_none_or(|b| v > b.1) {
                best = Some((i, v));
            }
        }
        let (i, v) = best?;
        set[i] = add;
        (v > f64::NEG_INFINITY).then_some(v)
    };
    let mut current = dense_log_det(blocks, &set, ridge);
    let min_rows = blocks.iter().map(|b| b.nrows().min(m)).min().unwrap_or(1);
    let (mut k, mut exchanges) = (1, 0);
    while k <= opts.max_excursion.max(1) {
        let mut improved = false;
        for up in [true, false] {
            if !up && n.saturating_sub(k) * min_rows < m {
                continue;
            }
            let mut d = set.clone();
            let mut ld = Some(current);
            'steps: for add in [up, !up] {
                for _ in 0..k {
                    ld = greedy(&mut d, add);
                    if ld.is_none() {
                        break 'steps;
                    }
                }
            }
            let Some(ld) = ld else { continue };
            if ld <= current + 1e-9 * current.abs().max(1.0) {
                continue;
            }
            let exact = if up {
                ld
            } else {
                dense_log_det(blocks, &d, 0.0)
            };
            if exact > current + 1e-9 * current.abs().max(1.0) {
                (set, current, improved) = (d, exact, true);
                break;
            }
        }
        if improved {
            exchanges += 1;
            k = 1;
        } else {
            k += 1;
        }
    }
    let selected: Vec<usize> = (0..len).filter(|&i| set[i]).collect();
    let ld = dense_log_det(blocks, &set, 0.0);
    (selected, ld, exchanges)
}

/// Blocks shaped like marker clusters: `clusters` groups of `markers` 3-row markers, each
/// cluster's rows touching its own `local` parameters and the `shared` (joint) ones, so the
/// information matrices have an arrow pattern (zeros between clusters).
fn cluster_blocks(
    rng: &mut Rng,
    count: usize,
    (clusters, markers, local, shared): (usize, usize, usize, usize),
) -> Vec<DMatrix<f64>> {
    let m = clusters * local + shared;
    (0..count)
        .map(|_| {
            DMatrix::from_fn(clusters * markers * 3, m, |r, c| {
                let cluster = r / (markers * 3);
                let own = c >= shared && (c - shared) / local == cluster;
                if c < shared || own { rng.normal() } else { 0.0 }
            })
        })
        .collect()
}

/// Large full-rank blocks with structural zeros go the information-matrix way, serial-like
/// 3-row blocks the thin way; both pick exactly the set the straightforward implementation
/// picks (pools not a multiple of the eight lanes), with its log det to 1e-9 relative.
#[test]
fn both_pool_kinds_pick_the_straightforward_set() {
    let mut rng = Rng::new(31);
    let cases = [
        (cluster_blocks(&mut rng, 45, (3, 2, 4, 8)), 6, 3, true),
        (cluster_blocks(&mut rng, 37, (2, 3, 5, 6)), 5, 4, true),
        (
            (0..60)
                .map(|_| DMatrix::from_fn(3, 9, |_, _| rng.normal()))
                .collect(),
            8,
            11,
            false,
        ),
    ];
    for (blocks, n, seed, large) in cases {
        let pool = Pool::from_blocks(&blocks);
        assert_eq!(pool.gram.is_some(), large);
        if let Some(g) = &pool.gram {
            let m = pool.params();
            assert!(
                g.env.len < m * (m + 1) / 2,
                "the zeros between clusters are skipped"
            );
        }
        for max_excursion in [2, 4] {
            let opts = DetmaxOptions {
                n,
                seed,
                max_excursion,
                path: true,
            };
            let (want, want_ld, want_exchanges) = reference(&blocks, &opts);
            let got = detmax(&pool, &opts, &NoMonitor).unwrap();
            assert_eq!(
                got.selected, want,
                "large {large}, excursions {max_excursion}"
            );
            assert_eq!(got.exchanges, want_exchanges);
            assert!(want_exchanges > 0, "the search moved");
            assert!((got.log_det - want_ld).abs() < 1e-9 * want_ld.abs().max(1.0));
            // The thin state (rank-k Woodbury updates) agrees on the large blocks too.
            if large {
                let thin = detmax(&Pool::thin(&blocks), &opts, &NoMonitor).unwrap();
                assert_eq!(thin.selected, want);
            }
        }
    }
}

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
        path: true,
    };
    let s = detmax(&pool, &opts, &NoMonitor).unwrap();
    assert!((s.log_det - best).abs() < 1e-9, "{} vs {}", s.log_det, best);
    let again = detmax(&pool, &opts, &NoMonitor).unwrap();
    assert_eq!(s.selected, again.selected);
    // The incremental determinant update agrees with a direct computation.
    let direct = pool.stacked(&s.selected).unwrap();
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
        path: true,
    };
    let s = detmax(&pool, &opts, &NoMonitor).unwrap();
    assert!((s.log_det - best).abs() < 1e-9, "{} vs {}", s.log_det, best);
}

fn last_gain(s: &Selection) -> f64 {
    s.history.last().map_or(0.0, |l| l.log_det) - s.history[0].log_det
}

/// Marker-cluster-like blocks (36 rows of rank 12, mixed with full-rank 5-row blocks):
/// the rank-reduced pool and the pool of information matrices pick exactly the set the
/// unreduced pool picks, with the same determinant to rounding.
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
    let reduced = Pool::thin(&blocks);
    let exact = Pool::exact(&blocks);
    let gram = Pool::from_blocks(&blocks);
    assert!((0..60).all(|i| reduced.block_rows(i) == if i % 4 == 3 { 5 } else { 12 }));
    assert!(gram.gram.is_some() && gram.stacked(&[0]).is_none());
    let opts = DetmaxOptions {
        n: 5,
        seed: 7,
        max_excursion: 4,
        path: true,
    };
    let a = detmax(&reduced, &opts, &NoMonitor).unwrap();
    let b = detmax(&exact, &opts, &NoMonitor).unwrap();
    assert_eq!(a.selected, b.selected);
    assert!((a.log_det - b.log_det).abs() < 1e-9 * b.log_det.abs().max(1.0));
    // Kept as information matrices (rows capped at the 24 parameters) the pool takes the
    // same path: the rank-deficient blocks leave the down-excursion rule unchanged here.
    let c = detmax(&gram, &opts, &NoMonitor).unwrap();
    assert_eq!(c.selected, b.selected);
    assert_eq!(c.exchanges, b.exchanges);
    assert!((c.log_det - b.log_det).abs() < 1e-9 * b.log_det.abs().max(1.0));
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

/// Uniform pools of 2, 3 and 6 rows take the fused lane path; it picks the set of the general
/// Woodbury path and of the straightforward implementation, with the same excursions and
/// history (pools not a multiple of the eight lanes; a rebuild every 16 toggles, so that the
/// searches rebuild).
#[test]
fn lane_path_picks_the_general_paths_set() {
    REBUILD_AFTER_TEST.with(|r| r.set(16));
    let before = REBUILDS.with(|r| r.get());
    let mut rng = Rng::new(17);
    for (r, count, m, n) in [
        (3, 61, 13, 9),
        (2, 43, 7, 6),
        (6, 30, 20, 5),
        (3, 150, 27, 40),
    ] {
        let blocks: Vec<DMatrix<f64>> = (0..count)
            .map(|_| DMatrix::from_fn(r, m, |_, _| rng.normal()))
            .collect();
        let lanes = Pool::from_blocks(&blocks);
        assert!(lanes.lanes.is_some(), "{r} rows take the lane path");
        let mut general = lanes.clone();
        general.lanes = None;
        for (seed, max_excursion) in [(3, 2), (4, 4)] {
            let opts = DetmaxOptions {
                n,
                seed,
                max_excursion,
                path: true,
            };
            let a = detmax(&lanes, &opts, &NoMonitor).unwrap();
            let b = detmax(&general, &opts, &NoMonitor).unwrap();
            let what = format!("{r} rows, {count} candidates, seed {seed}");
            assert_eq!(a.selected, b.selected, "{what}");
            assert_eq!(a.exchanges, b.exchanges, "{what}");
            assert!(a.exchanges > 0, "{what}: the search moved");
            assert!((a.log_det - b.log_det).abs() < 1e-9 * b.log_det.abs().max(1.0));
            let paths = a.history.iter().zip(&b.history);
            assert!(
                paths.clone().all(|(x, y)| x.selected == y.selected),
                "{what}"
            );
            if count < 100 {
                let (want, want_ld, _) = reference(&blocks, &opts);
                assert_eq!(a.selected, want, "{what}");
                assert!((a.log_det - want_ld).abs() < 1e-9 * want_ld.abs().max(1.0));
            }
        }
    }
    // The lane searches and the general ones rebuilt (four of the eight searches of each).
    assert!(REBUILDS.with(|r| r.get()) - before >= 8);
}

/// The lane pass ranks in single precision on blocks whitened by the pool's information: on a
/// pool whose columns are nearly collinear (each row a common value plus 1e-5 of its own:
/// condition ~1e11) and span four decades, it still picks the double-precision general
/// path's set, with the same excursions and determinant (a whitened block paired with an
/// unwhitened U picks another set after two exchanges).
#[test]
fn the_single_precision_ranking_survives_bad_conditioning() {
    let mut rng = Rng::new(41);
    let (r, count, m, n) = (3, 120, 18, 30);
    let blocks: Vec<DMatrix<f64>> = (0..count)
        .map(|_| {
            let common: Vec<f64> = (0..r).map(|_| rng.normal()).collect();
            DMatrix::from_fn(r, m, |x, c| {
                (common[x] + 1e-5 * rng.normal())
                    * 10f64.powf(-2.0 + 4.0 * c as f64 / (m - 1) as f64)
            })
        })
        .collect();
    let lanes = Pool::from_blocks(&blocks);
    assert!(lanes.lanes.is_some());
    let mut general = lanes.clone();
    general.lanes = None;
    for seed in [5, 6, 7] {
        let opts = DetmaxOptions {
            n,
            seed,
            max_excursion: 4,
            path: true,
        };
        let a = detmax(&lanes, &opts, &NoMonitor).unwrap();
        let b = detmax(&general, &opts, &NoMonitor).unwrap();
        assert!(b.exchanges > 0, "seed {seed}: the search moved");
        assert_eq!(a.selected, b.selected, "seed {seed}");
        assert_eq!(a.exchanges, b.exchanges, "seed {seed}");
        assert!((a.log_det - b.log_det).abs() < 1e-9 * b.log_det.abs().max(1.0));
    }
}

/// The AVX-512, AVX2 and portable lane kernels give the same selection, path and
/// determinants bit for bit (each lane sees the same operations in the same order; the
/// portable kernel does not fuse, so it is compared to 1e-9), and a search that does not
/// record its path picks the same set (and reports its determinant to rounding).
#[test]
fn every_kernel_width_picks_the_same_set() {
    use super::narrow::WIDEST;
    let mut rng = Rng::new(29);
    for (r, count, m, n) in [(3, 150, 27, 40), (2, 61, 9, 11), (6, 45, 20, 8)] {
        let blocks: Vec<DMatrix<f64>> = (0..count)
            .map(|_| DMatrix::from_fn(r, m, |_, _| rng.normal()))
            .collect();
        let pool = Pool::from_blocks(&blocks);
        let opts = DetmaxOptions {
            n,
            seed: 5,
            max_excursion: 4,
            path: true,
        };
        let run = |w: usize| {
            WIDEST.with(|c| c.set(w));
            let s = detmax(&pool, &opts, &NoMonitor).unwrap();
            WIDEST.with(|c| c.set(8));
            s
        };
        let (wide, avx2, portable) = (run(8), run(4), run(0));
        let what = format!("{r} rows, {count} candidates");
        assert!(wide.exchanges > 0, "{what}: the search moved");
        assert_eq!(wide.selected, avx2.selected, "{what}");
        assert_eq!(wide.log_det.to_bits(), avx2.log_det.to_bits(), "{what}");
        let steps = wide.history.iter().zip(&avx2.history);
        assert!(
            steps
                .clone()
                .all(|(a, b)| a.log_det.to_bits() == b.log_det.to_bits())
        );
        assert_eq!(wide.selected, portable.selected, "{what}");
        assert!((wide.log_det - portable.log_det).abs() < 1e-9 * wide.log_det.abs().max(1.0));
        let quiet = detmax(
            &pool,
            &DetmaxOptions {
                path: false,
                ..opts.clone()
            },
            &NoMonitor,
        );
        let quiet = quiet.unwrap();
        assert_eq!(quiet.selected, wide.selected, "{what}");
        // Its determinant is the one the search tracked (with the ridge, after the toggles
        // since the last rebuild), not the members' afresh: 5e-12 to 4e-11 relative apart
        // here (the search bounds the drift at 1e-6).
        assert!(
            (quiet.log_det - wide.log_det).abs() < 1e-9 * wide.log_det.abs().max(1.0),
            "{what}: {} vs {}",
            quiet.log_det,
            wide.log_det
        );
        assert!(quiet.log_det_start.is_nan() && wide.log_det_start.is_finite());
        assert!(quiet.history.is_empty() && wide.history.len() == wide.exchanges + 1);
    }
}

/// A pool large enough for the best-addition scan to run on two cores (information
/// matrices of 1,000 marker-cluster blocks) picks the candidate a dense Cholesky of every
/// candidate's design picks, with its log det, and the first of a tie: block 100 repeated
/// as block 900 (the other half of the scan) stands out and must win over its copy.
#[test]
fn the_two_core_scan_picks_the_dense_argmax() {
    let mut rng = Rng::new(5);
    let mut blocks = cluster_blocks(&mut rng, 1000, (4, 2, 10, 20));
    blocks[100] *= 3.0;
    blocks[900] = blocks[100].clone();
    let pool = Pool::from_blocks(&blocks);
    let g = pool.gram.as_ref().expect("kept as information matrices");
    assert!(g.n * g.env.len >= gram::PARALLEL_MIN_ENTRIES);
    let start: Vec<usize> = (0..8).map(|k| 37 * k + 3).collect();
    let trace: f64 = blocks.iter().map(|b| b.norm_squared()).sum();
    let ridge = 1e-9 * trace / (blocks.len() * pool.m) as f64;
    let mut design = gram::Design::new(g, &start, ridge).expect("regular start");
    let got = design.greedy(true, &mut gram::Memo::new()).expect("a step");
    let mut set = vec![false; blocks.len()];
    start.iter().for_each(|&i| set[i] = true);
    let mut best: Option<(usize, f64)> = None;
    for i in 0..blocks.len() {
        if set[i] {
            continue;
        }
        set[i] = true;
        let v = dense_log_det(&blocks, &set, ridge);
        set[i] = false;
        if best.is_none_or(|b| v > b.1) {
            best = Some((i, v));
        }
    }
    let (i, v) = best.expect("candidates");
    assert_eq!((got, i), (100, 100));
    assert!(
        (design.log_det - v).abs() < 1e-9 * v.abs(),
        "{} vs {v}",
        design.log_det
    );
}

/// The bounded scan for the best addition (candidates evaluated in order of an upper bound
/// on their log det, stopping when none left can beat the best found) picks the full scan's
/// candidate with its value bit for bit, on designs of several sizes of a marker-cluster
/// pool, and the first of a tie: block 41 repeated as block 251 must win over its copy.
#[test]
fn the_bounded_scan_equals_the_full_scan() {
    let mut rng = Rng::new(12);
    let mut blocks = cluster_blocks(&mut rng, 300, (4, 2, 10, 20));
    blocks[41] *= 3.0;
    blocks[251] = blocks[41].clone();
    let pool = Pool::from_blocks(&blocks);
    let g = pool.gram.as_ref().expect("kept as information matrices");
    let trace: f64 = blocks.iter().map(|b| b.norm_squared()).sum();
    let ridge = 1e-9 * trace / (blocks.len() * pool.m) as f64;
    let tie: Vec<usize> = (0..8).map(|k| 37 * k + 3).collect();
    let mut starts = vec![tie];
    starts
        .extend((0..5).map(|s| Rng::new(100 + s).sample_indices(blocks.len(), 8 + 3 * s as usize)));
    for (k, start) in starts.iter().enumerate() {
        let mut design = gram::Design::new(g, start, ridge).expect("regular start");
        let full = design.best_add_full().expect("a candidate");
        let bounded = design
            .best_add_bounded()
            .expect("M factors densely")
            .expect("a candidate");
        assert_eq!(full.0, bounded.0, "start {k}");
        assert_eq!(full.1.to_bits(), bounded.1.to_bits(), "start {k}");
        if k == 0 {
            assert_eq!(full.0, 41);
        }
    }
}
